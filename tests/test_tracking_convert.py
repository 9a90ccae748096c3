"""``starforge convert``: real vendor files to every format and back, what is kept and what is
named as lost, the family target, and hostile files (one line, exit 2)."""

from __future__ import annotations

import os
import struct
from pathlib import Path

import numpy as np
import pytest

from starforge.cli import main
from starforge.tracking.bodies import load_bodies
from starforge.tracking.convert import convert_to, read_records
from starforge.tracking.formats import FORMATS, sniff_format

VENDOR = Path(__file__).parent / "data" / "vendor"
QTM = VENDOR / "qtm_6d_settings.xml"
#: a folder of more real tracker files to run through the same checks (tests/data/vendor/README.md
#: names public NDI and Atracsys files that are not redistributed here)
EXTRA = os.environ.get("STARFORGE_VENDOR_DIR")
REAL = [QTM] + (sorted(p for p in Path(EXTRA).iterdir() if sniff_format(p)) if EXTRA else [])


def _tool(fmt: str, name: str) -> bytes:
    """One body of Qualisys' file as a file of format ``fmt`` that starforge writes."""
    return convert_to(read_records([QTM]), fmt).files[f"{name}{FORMATS[fmt].suffix}"]


def _write(conv, folder: Path) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    for rel, data in conv.files.items():
        (folder / rel).write_bytes(data)
    return [folder / rel for rel in conv.files]


def _round_trip(src: Path, via: str, tmp_path: Path):
    first = read_records([src])
    there = _write(convert_to(first, via), tmp_path / via)
    back_fmt = sniff_format(src)
    back = _write(convert_to(read_records(there), back_fmt), tmp_path / "back")
    return first, read_records(there), read_records(back)


def _dists(P):
    P = np.asarray(P, float)
    return np.linalg.norm(P[:, None] - P[None], axis=2)


def test_every_real_file_is_read_as_a_rigid_body():
    assert all(sniff_format(p) is not None for p in REAL)
    for p in REAL:
        for r in read_records([p]).records:
            assert len(r.points_mm) >= 3 and np.isfinite(r.points_mm).all()


@pytest.mark.parametrize("via", list(FORMATS))
@pytest.mark.parametrize("src", REAL, ids=[p.name for p in REAL])
def test_real_files_go_to_every_format_and_back(src, via, tmp_path):
    """Coordinates within 0.001 mm (exactly, through text formats; float32 through rom), marker
    order and body names kept, and every field both formats carry kept."""
    first, there, back = _round_trip(src, via, tmp_path)
    assert len(back.records) == len(first.records)
    src_fmt = sniff_format(src)
    for a, m, b in zip(first.records, there.records, back.records, strict=True):
        P = np.asarray(a.points_mm)
        expect = P.astype(np.float32).astype(float) if via == "rom" else P
        assert np.array_equal(np.asarray(b.points_mm), expect)  # exact to the formats' precision
        assert np.abs(np.asarray(b.points_mm) - P).max() <= 1e-3
        assert np.array_equal(np.asarray(m.points_mm), expect)
        if src_fmt not in ("rom", "atracsys") and via not in ("rom", "atracsys"):
            assert b.name == a.name  # both name the body inside the file
        both = FORMATS[src_fmt].carries & FORMATS[via].carries
        for f in both & {"marker_names", "body_id", "min_markers", "marker_mm"}:
            assert getattr(b, f) == getattr(a, f), f
        for f in both & set(a.tolerances):
            assert b.tolerances[f] == pytest.approx(a.tolerances[f], rel=1e-7), f
        if "normals" in both:
            assert np.allclose(b.normals, a.normals, atol=1e-7)


@pytest.mark.parametrize("via", list(FORMATS))
def test_the_lost_line_names_exactly_what_the_target_cannot_hold(via, tmp_path):
    (tmp_path / "Phone.rom").write_bytes(_tool("rom", "Phone"))  # normals, minimum markers, marker error
    (tmp_path / "Cup.ini").write_bytes(_tool("atracsys", "Cup"))  # an id
    src = read_records([QTM, tmp_path / "Phone.rom", tmp_path / "Cup.ini"])
    conv = convert_to(src, via)
    stated = set().union(*(r.carried() for r in src.records))
    assert set(conv.lost) == stated - FORMATS[via].carries
    line = conv.lost_line()
    assert (line is None) == (not conv.lost)
    if line:
        assert line.startswith(f"{via} cannot carry:") and "\n" not in line


def test_four_marker_tools_become_a_family_that_keeps_their_geometry_and_names(tmp_path):
    roms = [tmp_path / f"{n}.rom" for n in ("Phone", "Screen2", "Table")]
    for r in roms:
        r.write_bytes(_tool("rom", r.stem))
    rc = main(["convert", *map(str, roms), "--format", "family", "--out", str(tmp_path / "fam"), "-q"])
    assert rc == 0
    bs = load_bodies(tmp_path / "fam" / "family.json")  # verified as every family file
    assert bs.kind == "family" and bs.names == [p.stem for p in roms]
    for body, p in zip(bs.bodies, roms, strict=True):
        (P,) = read_records([p]).records
        assert np.abs(_dists(body.points_mm) - _dists(P.points_mm)).max() < 1e-6


def test_a_family_converts_to_vendor_files_with_its_star_names(small_family, tmp_path):
    fam, _ = small_family
    rc = main(["convert", str(fam), "--format", "vsk", "--out", str(tmp_path / "v"), "-q"])
    assert rc == 0
    bs = load_bodies(fam / "family.json")
    got = load_bodies(sorted((tmp_path / "v").glob("*.vsk")))
    assert sorted(got.names) == sorted(bs.names)
    table = {b.name: b.points_mm for b in bs.bodies}
    for b in got.bodies:
        assert np.array_equal(b.points_mm, table[b.name])


def test_existing_outputs_need_force_and_stay_untouched(tmp_path, cli_error):
    out = tmp_path / "o"
    args = ["convert", str(QTM), "--format", "vsk", "--out", str(out), "-q"]
    assert main(args) == 0
    before = (out / "Phone.vsk").read_bytes()
    (out / "Phone.vsk").write_bytes(b"mine")
    assert "--force" in cli_error(args)
    assert (out / "Phone.vsk").read_bytes() == b"mine"
    assert main([*args, "--force"]) == 0
    assert (out / "Phone.vsk").read_bytes() == before


def test_a_body_too_large_for_the_target_is_refused_before_writing(tmp_path, cli_error):
    rows = ["body,marker,x_mm,y_mm,z_mm"] + [
        f"big,{i + 1},{10.0 * i},{(i * i) % 7},{i % 3}" for i in range(7)
    ]
    (tmp_path / "big.csv").write_text("\n".join(rows) + "\n")
    err = cli_error(
        ["convert", str(tmp_path / "big.csv"), "--format", "atracsys", "--out", str(tmp_path / "o")]
    )
    assert "at most 6" in err and "--format" in err
    assert not (tmp_path / "o").exists()


def _rom(n: int, checksum_ok: bool = True, nan: bool = False) -> bytes:
    d = bytearray(_tool("rom", "Phone"))
    d[28] = n
    if nan:
        struct.pack_into("<f", d, 72, float("nan"))
    total = sum(d[6:]) & 0xFFFF
    struct.pack_into("<H", d, 4, total if checksum_ok else (total + 1) & 0xFFFF)
    return bytes(d)


BOMB = (
    '<?xml version="1.0"?><!DOCTYPE l [<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;">'
    '<!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;">]><QTM_Settings><The_6D><Body><Name>&c;</Name></Body>'
    "</The_6D></QTM_Settings>"
)
HOSTILE = {
    "truncated.rom": (lambda: _tool("rom", "Phone")[:400], "752 bytes"),
    "checksum.rom": (lambda: _rom(4, checksum_ok=False), "checksum"),
    "zero.rom": (lambda: _rom(0), "marker count 0"),
    "many.rom": (lambda: _rom(255), "marker count 255"),
    "nan.rom": (lambda: _rom(4, nan=True), "not finite"),
    "nan.xml": (
        lambda: QTM.read_text().replace('X="-67.927157"', 'X="nan"', 1).encode(),
        "not finite",
    ),
    "bomb.xml": (lambda: BOMB.encode(), "entities"),
    "cut.xml": (lambda: QTM.read_bytes()[:700], "not valid XML"),
    "empty_body.xml": (
        lambda: b"<QTM_Settings><The_6D><Body><Name>x</Name><Points/></Body></The_6D></QTM_Settings>",
        "3 or more markers",
    ),
    "count.ini": (lambda: b"[geometry]\ncount=255\nid=1\n", "count 255"),
    "many.xml": (
        lambda: (
            "<QTM_Settings><The_6D><Body><Name>b</Name><Points>"
            + "".join(f'<Point X="{i}" Y="{i % 7}" Z="{i % 5}"/>' for i in range(255))
            + "</Points></Body></The_6D></QTM_Settings>"
        ).encode(),
        "255 markers",
    ),
    "none.vsk": (
        lambda: b"<KinematicModel><MarkerSet NAME='x'><Markers/></MarkerSet></KinematicModel>",
        "no VSK marker",
    ),
    "none.motive": (lambda: b"<Profile><NodeAssets></NodeAssets></Profile>", "no Motive rigid body"),
    "nan.csv": (lambda: b"body,marker,x_mm,y_mm,z_mm\nb,1,0,0,0\nb,2,nan,0,0\nb,3,0,9,0\n", "not finite"),
    "latin1.csv": (
        lambda: "body,marker,x_mm,y_mm,z_mm\nK\u00f6rper,1,0,0,0\n".encode("latin-1"),
        "UnicodeDecodeError",
    ),
    "unicode.ini": (
        lambda: "[geometry]\ncount=3\nid=1\n[fiducial0]\nx=\u00e9\ny=0\nz=0\n".encode(),
        "Atracsys",
    ),
}


@pytest.mark.parametrize("name", list(HOSTILE))
def test_hostile_files_give_one_line_and_exit_2(name, tmp_path, cli_error):
    make, words = HOSTILE[name]
    (tmp_path / name).write_bytes(make())
    err = cli_error(["convert", str(tmp_path / name), "--format", "csv", "--out", str(tmp_path / "o")])
    assert words in err and name in err
    assert not (tmp_path / "o").exists()


def test_a_huge_file_is_refused_before_it_is_read(tmp_path, cli_error):
    p = tmp_path / "huge.xml"
    with open(p, "wb") as fh:
        fh.write(b"<QTM_Settings>")
        fh.truncate(65 * 1024**2)  # sparse: no 65 MB written
    err = cli_error(["convert", str(p), "--format", "csv", "--out", str(tmp_path / "o")])
    assert "at most" in err


def test_unicode_body_and_marker_names_round_trip_through_xml_formats(tmp_path):
    name = "K\u00f6rper \u4e2d"
    marks = ["\u00e9 1", "\u00e9 2", "\u00e9 3", "\u00e9 4"]
    pts = "".join(
        f'<Point X="{x}" Y="{y}" Z="{z}" Name="{m}"/>'
        for m, (x, y, z) in zip(marks, [(0, 0, 0), (50, 0, 0), (0, 37, 0), (0, 0, 71)], strict=True)
    )
    src = tmp_path / "u.xml"
    src.write_text(
        f"<QTM_Settings><The_6D><Body><Name>{name}</Name><Points>{pts}</Points></Body></The_6D></QTM_Settings>"
    )
    for via in ("vsk", "qtm", "motive"):
        _, there, back = _round_trip(src, via, tmp_path / via)
        assert back.records[0].name == name
        if via != "motive":
            assert list(back.records[0].marker_names) == marks


def test_an_existing_tool_is_rebuilt_as_a_printable_body(tmp_path):
    """A tool's .rom -> family.json -> export: bodies within the family's limit whose sphere
    centres have the tool's distances."""
    import json

    import trimesh

    roms = [tmp_path / "Phone.rom"]
    roms[0].write_bytes(_tool("rom", "Phone"))
    assert main(["convert", *map(str, roms), "--format", "family", "--out", str(tmp_path / "f"), "-q"]) == 0
    assert main(["export", str(tmp_path / "f"), "--format", "stl", "--out", str(tmp_path / "e"), "-q"]) == 0
    report = json.loads((tmp_path / "e" / "bodies.json").read_text())
    assert [b["fits"] for b in report["bodies"]] == [True]
    for b, p in zip(report["bodies"], roms, strict=True):
        (tool,) = read_records([p]).records
        assert np.abs(_dists(b["centres_mm"]) - _dists(tool.points_mm)).max() < 1e-4
        mesh = trimesh.load(tmp_path / "e" / f"{b['name']}.stl")
        assert mesh.is_watertight and mesh.volume > 0


def test_an_unknown_format_lists_the_known_ones(tmp_path, cli_error):
    err = cli_error(["convert", QTM, "--format", "fbx", "--out", tmp_path / "o"])
    assert "fbx" in err and all(f in err for f in [*FORMATS, "family"])
    assert not (tmp_path / "o").exists()
