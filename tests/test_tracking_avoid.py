"""``stars --avoid``: several files after one flag (as the README shows) or the flag repeated give
the same bodies to avoid; a lab file's bodies with fewer than 3 markers are named in a warning."""

from __future__ import annotations

import pytest

from starforge.errors import StarforgeError
from tests.conftest import run_cli

QTM = (
    "<QTM_Settings><The_6D><Body><Name>wand</Name><Points>"
    '<Point X="0" Y="0" Z="0" Virtual="0"/><Point X="50" Y="0" Z="0" Virtual="0"/>'
    '<Point X="0" Y="35" Z="0" Virtual="0"/><Point X="0" Y="0" Z="22" Virtual="0"/>'
    "</Points></Body></The_6D></QTM_Settings>"
)
VSK = (
    '<KinematicModel><MarkerSet NAME="subject"><Markers>'
    '<Marker NAME="R1" SEGMENT="Root" POSITION="12 -5.5 0"/><Marker NAME="R2" SEGMENT="Root" POSITION="-40 0 10"/>'
    '<Marker NAME="R3" SEGMENT="Root" POSITION="0 25 -33"/>'
    '<Marker NAME="H1" SEGMENT="Hand" POSITION="0 -40 0"/><Marker NAME="H2" SEGMENT="Hand" POSITION="9 -61 3"/>'
    "</Markers></MarkerSet></KinematicModel>"
)


@pytest.fixture
def lab(tmp_path):
    (tmp_path / "A.xml").write_text(QTM)
    (tmp_path / "B.vsk").write_text(VSK)
    return tmp_path


@pytest.fixture
def captured(monkeypatch):
    """Stop ``stars`` where the family would be made and keep what it was given."""
    import starforge.stars.family as family

    seen = []

    def fake(spec, **kw):
        seen.append(kw["avoid_sources"])
        raise StarforgeError("stopped before the enumeration (test)")

    monkeypatch.setattr(family, "make_family", fake)  # the API looks the family maker up when it runs
    return seen


def _stars(tmp_path, *avoid):
    return run_cli(["stars", "--box", 16, 12, 24, "--delta", 2, *avoid, "--out", tmp_path / "o"])


def test_several_files_after_one_flag_equal_the_flag_repeated(lab, captured, capsys):
    assert _stars(lab, "--avoid", lab / "A.xml", lab / "B.vsk") == 2
    one_flag = capsys.readouterr().err
    assert _stars(lab, "--avoid", lab / "A.xml", "--avoid", lab / "B.vsk") == 2
    repeated = capsys.readouterr().err
    assert captured[0] == captured[1] and [s["file"] for s in captured[0]] == [
        str(lab / "A.xml"),
        str(lab / "B.vsk"),
    ]
    assert [s["bodies"] for s in captured[0]] == [1, 1]
    # the two-marker hand is no rigid body: named, not dropped silently
    for err in (one_flag, repeated):
        assert "warning:" in err and "Hand (2 markers)" in err
    assert _stars(lab, "--avoid", lab / "A.xml") == 2
    assert [s["file"] for s in captured[2]] == [str(lab / "A.xml")]


def test_stray_values_without_the_flag_are_refused(lab, captured, capsys):
    assert _stars(lab, lab / "A.xml") == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "unexpected extra argument" in err and err.count("\n") == 1
    assert not captured


def test_a_file_with_no_rigid_body_names_what_it_holds(tmp_path, captured, capsys):
    (tmp_path / "pair.csv").write_text("body,marker,x_mm,y_mm,z_mm\nt,1,0,0,0\nt,2,20,0,0\n")
    assert _stars(tmp_path, "--avoid", tmp_path / "pair.csv") == 2
    err = capsys.readouterr().err
    assert "no body with 3 or more markers" in err and "t (2 markers)" in err and not captured
