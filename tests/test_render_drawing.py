"""``starforge drawing``: a page and a picture per body, and dimensions that re-measure the file."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pytest

from starforge.cli import main
from starforge.tracking.convert import convert_to, read_records
from starforge.tracking.formats import read_file

VENDOR = Path(__file__).parent / "data" / "vendor"


@pytest.mark.slow
def test_drawings_of_a_lab_file_and_a_tool(tmp_path, cli_error):
    one = convert_to(read_records([VENDOR / "qtm_6d_settings.xml"]), "qtm").files["Table.xml"]
    (tmp_path / "Table.xml").write_bytes(one)  # a QTM file of one body, with its point names
    rom = convert_to(read_records([VENDOR / "qtm_6d_settings.xml"]), "rom").files["Cup.rom"]
    (tmp_path / "Cup.rom").write_bytes(rom)  # a 5-marker tool as an NDI file
    files = [tmp_path / "Table.xml", tmp_path / "Cup.rom"]
    out = tmp_path / "d"
    assert main(["drawing", *map(str, files), "--out", str(out), "-q"]) == 0
    truth = read_file(files[0]) | read_file(files[1])
    pdf = (out / "drawing.pdf").read_bytes()
    assert pdf.startswith(b"%PDF") and len(re.findall(rb"/Type\s*/Page\b(?!s)", pdf)) == len(truth)
    for name in truth:
        png = (out / f"{name}.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n"
        w, h = int.from_bytes(png[16:20], "big"), int.from_bytes(png[20:24], "big")
        assert w > h > 500  # landscape page
    rows = list(csv.DictReader((out / "dimensions.csv").read_text().splitlines()))
    for name, P in truth.items():
        marks = [r for r in rows if r["body"] == name and r["kind"] == "marker"]
        got = np.array([[float(r[c]) for c in ("x_mm", "y_mm", "z_mm")] for r in marks])
        assert np.abs(got - P).max() <= 5e-7
        dist = {
            (int(r["a"]), int(r["b"])): float(r["distance_mm"])
            for r in rows
            if r["body"] == name and r["kind"] == "distance"
        }
        assert len(dist) == len(P) * (len(P) - 1) // 2
        for (a, b), d in dist.items():
            assert abs(d - float(np.sqrt(((P[a - 1] - P[b - 1]) ** 2).sum()))) <= 5e-7
    names = [r["b"] for r in rows if r["body"] == "Table" and r["kind"] == "marker"]
    assert names == [f"Table - {i}" for i in range(1, 5)]
    assert "--force" in cli_error(["drawing", str(files[1]), "--out", str(out)])
