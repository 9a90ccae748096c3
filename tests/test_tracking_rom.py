"""NDI tool definitions (.rom): what starforge writes, read back by an independent reader of the
public layout (written here from the layout notes, separately from starforge's reader), exact to
float32; a file laid out the way NDI's own files are (built here byte by byte from the public
layout: NDI's files themselves are not redistributable) read by starforge; corrupt files refused
in one line."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from starforge.errors import StarforgeError
from starforge.tracking.bodies import load_bodies
from starforge.tracking.export import write_rigid_bodies
from starforge.tracking.formats import rom
from tests.conftest import run_cli


def independent_rom(data: bytes) -> dict:
    """The public layout, read with struct only: 752 bytes, 'NDI', uint16 checksum at 4 (sum of
    bytes 6..), marker count at 28, minimum markers at 32, max marker error f32 at 36, 20 xyz f32
    positions at 72, 20 xyz f32 normals at 312, manufacturer at 580 (12), part number at 592 (20),
    marker type at 655, face normals at 656."""
    assert len(data) == 752 and data[0:3] == b"NDI"
    assert struct.unpack("<H", data[4:6])[0] == sum(data[6:]) % 65536
    n = data[28]
    xyz = np.frombuffer(data, dtype="<f4", count=60, offset=72).reshape(20, 3)
    nrm = np.frombuffer(data, dtype="<f4", count=60, offset=312).reshape(20, 3)
    assert not xyz[n:].any() and not nrm[n:].any()  # unused slots stay zero
    return {
        "points": xyz[:n].astype(float),
        "normals": nrm[:n].astype(float),
        "min_markers": data[32],
        "max_error": float(np.frombuffer(data, dtype="<f4", count=1, offset=36)[0]),
        "manufacturer": data[580:592].rstrip(b"\0").decode(),
        "part": data[592:612].rstrip(b"\0").decode(),
        "marker_type": data[655],
        "faces": list(data[613 : 613 + n]),
        "face_normal": np.frombuffer(data, dtype="<f4", count=3, offset=656).astype(float),
    }


def test_every_rom_written_reads_back_as_the_family(small_family, tmp_path):
    out, doc = small_family
    summary = write_rigid_bodies(out / "family.json", ["rom"], tmp_path, noise_mm=0.2)
    truth = {b.name: b.points_mm for b in load_bodies(out / "family.json").bodies}
    files = sorted((tmp_path / "rom").glob("*.rom"))
    assert len(files) == len(doc["stars"]) == len(truth)
    for f in files:
        got = independent_rom(f.read_bytes())
        want = truth[f.stem].astype(np.float32).astype(float)
        assert np.array_equal(got["points"], want)  # exact to float32
        assert got["part"] == f.stem[:20] and got["manufacturer"] == "starforge"
        assert got["min_markers"] == 3 and got["marker_type"] == 41 and got["faces"] == [1] * len(want)
        assert np.allclose(got["normals"], [0, 0, 1]) and np.allclose(got["face_normal"], [0, 0, 1])
        assert got["max_error"] == pytest.approx(summary["tolerances"]["max_marker_error_mm"], rel=1e-6)
        # starforge's own reader: every field
        tool = rom.read_tool(f)
        assert (
            np.array_equal(tool.points_mm, want) and tool.main_type == 4 and tool.part_number == f.stem[:20]
        )
        # the distances a tracker compares differ from the family's by float32 rounding only
        i, j = np.triu_indices(len(want), 1)
        d0 = np.linalg.norm(truth[f.stem][i] - truth[f.stem][j], axis=1)
        d1 = np.linalg.norm(got["points"][i] - got["points"][j], axis=1)
        assert np.abs(d0 - d1).max() < 1e-4


@settings(max_examples=30, deadline=None)
@given(
    n=st.integers(3, 20),
    seed=st.integers(0, 2**16),
    scale=st.floats(5.0, 500.0),
)
def test_any_tool_round_trips_through_the_layout(n, seed, scale):
    rng = np.random.default_rng(seed)
    P = rng.normal(0.0, scale, size=(n, 3))
    N = rng.normal(size=(n, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    data = rom.rom_bytes(P, N, part_number="tool-x", max_marker_error_mm=0.5, min_markers=3)
    got = independent_rom(data)
    assert np.array_equal(got["points"], P.astype(np.float32).astype(float))
    assert np.array_equal(got["normals"], N.astype(np.float32).astype(float))
    assert got["part"] == "tool-x" and got["min_markers"] == 3


def ndi_style_rom(points, part: str) -> bytes:
    """A tool definition laid out as NDI's own passive reference tools are (as seen in NDI-made
    files kept in public repositories: normals +x, face normal -z, 4 minimum markers, 0.75 mm
    maximum marker error, main type 1 'reference', sub type 0, a date), built byte by byte from
    the public layout, independently of starforge's writer."""
    d = bytearray(752)
    d[0:3] = b"NDI"
    d[8] = 1
    d[12], d[15] = 0, 1
    d[20:24] = bytes([1, 20, 128, 52])  # sequence 1, a date in 2005
    d[24], d[28], d[32] = 90, len(points), 4
    d[36:40] = struct.pack("<f", 0.75)
    d[64:68] = struct.pack("<f", 10.0)
    for k, p in enumerate(points):
        d[72 + 12 * k : 84 + 12 * k] = struct.pack("<3f", *p)
        d[312 + 12 * k : 324 + 12 * k] = struct.pack("<3f", 1.0, 0.0, 0.0)
        d[552 + k] = k
        d[613 + k] = d[633 + k] = 1
    d[572:577] = bytes([31, 31, 31, 31, 9])
    d[580:583] = b"NDI"
    d[592 : 592 + len(part)] = part.encode()
    d[612], d[653], d[655] = 9, 128, 41
    d[656:668] = struct.pack("<3f", 0.0, 0.0, -1.0)
    d[4:6] = struct.pack("<H", sum(d[6:]) % 65536)
    return bytes(d)


def test_an_ndi_style_tool_is_read_with_every_field(tmp_path):
    pts = [[0.0, 0.0, 0.0], [0.0, 28.59, 41.02], [0.0, 0.0, 88.0], [0.0, -44.32, 40.45]]
    path = tmp_path / "reference.rom"
    path.write_bytes(ndi_style_rom(pts, "8700339"))
    tool = rom.read_tool(path)
    assert np.array_equal(tool.points_mm, np.array(pts, dtype=np.float32).astype(float))
    assert tool.manufacturer == "NDI" and tool.part_number == "8700339" and tool.main_type == 1
    assert tool.min_markers == 4 and tool.max_marker_error_mm == 0.75 and tool.marker_type == 41
    assert np.array_equal(tool.normals, np.tile([1.0, 0, 0], (4, 1)))
    (b,) = load_bodies(path).bodies
    assert b.name == "reference" and b.n_markers == 4


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda d: d[:100], "not an NDI tool definition"),
        (lambda d: b"XYZ" + d[3:], "not an NDI tool definition"),
        (lambda d: d[:80] + bytes([d[80] ^ 1]) + d[81:], "checksum"),
        (lambda d: d[:28] + b"\x00" + d[29:], "checksum"),
    ],
)
def test_corrupt_rom_files_give_one_line(tmp_path, mutate, message):
    good = rom.rom_bytes([[0, 0, 0], [50, 0, 0], [0, 35, 0], [0, 0, 22]], part_number="t")
    path = tmp_path / "bad.rom"
    path.write_bytes(mutate(good))
    with pytest.raises(StarforgeError, match=message) as exc:
        load_bodies(path)
    assert "\n" not in str(exc.value)


def test_rom_refuses_more_markers_than_the_layout_holds(tmp_path, capsys):
    pos = (np.random.default_rng(3).normal(0, 0.05, size=(21, 3))).tolist()
    doc = {
        "format": "starforge.placement",
        "version": 1,
        "prop": {"name": "big"},
        "markers": [{"position": p, "normal": [0, 0, 1]} for p in pos],
    }
    src = tmp_path / "placement.json"
    src.write_text(json.dumps(doc))
    rc = run_cli(["export", src, "--format", "rom", "--out", tmp_path / "o"])
    err = capsys.readouterr().err
    assert rc == 2 and "at most 20 markers" in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()
