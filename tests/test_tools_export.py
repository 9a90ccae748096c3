"""A lab's tools of any marker count, read from tracker files, as printable bodies."""

from __future__ import annotations

import json
import re
import shutil
import subprocess

import numpy as np
import pytest
import trimesh

from starforge import api
from starforge.cad.tools import MAX_MARKERS, tool_set
from starforge.errors import StarforgeError


def _tool(n: int, seed: int) -> np.ndarray:
    """n marker centres, mm, spread on a tool about 80 mm across (no two closer than 12 mm)."""
    rng = np.random.default_rng(seed)
    pts: list = []
    while len(pts) < n:
        p = rng.uniform([-40, -30, -8], [40, 30, 8])
        if all(np.linalg.norm(p - q) >= 12 for q in pts):
            pts.append(p)
    # an arbitrary pose, as a tracker file states a body in its own frame
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return np.array(pts) @ q.T + rng.uniform(-100, 100, 3)


def _csv(path, tools: dict) -> None:
    rows = ["body,marker,x_mm,y_mm,z_mm"]
    for name, P in tools.items():
        rows += [f"{name},{i + 1},{float(x)!r},{float(y)!r},{float(z)!r}" for i, (x, y, z) in enumerate(P)]
    path.write_text("\n".join(rows) + "\n")


def _distances(P) -> np.ndarray:
    P = np.asarray(P, float)
    return np.linalg.norm(P[:, None] - P[None], axis=-1)


@pytest.mark.parametrize("n", [3, 5, 6, 8])
def test_tool_placement_is_rigid_with_the_thinnest_side_up(n):
    P = _tool(n, seed=n)
    tools = tool_set([("t", P, None, None)], name="lab")
    V = tools.stars[0].vertices
    # every distance between markers is the file's (brute force over all pairs)
    assert np.allclose(_distances(V), _distances(P), atol=1e-9)
    # and the frame is a proper rotation (no mirror): a signed volume keeps its sign
    if n >= 4:
        vol = lambda X: np.linalg.det(np.stack([X[1] - X[0], X[2] - X[0], X[3] - X[0]]))  # noqa: E731
        assert np.sign(vol(V)) == np.sign(vol(P))
    ext = np.ptp(V, axis=0)
    assert ext[1] <= ext.min() + 1e-9  # the plate's normal is the tool's thinnest side


def test_tool_refusals_name_the_way_out():
    with pytest.raises(StarforgeError, match="3 to 16"):
        tool_set([("big", _tool(MAX_MARKERS + 1, 1) * 3, None, None)], name="lab")
    close = np.array([[0, 0, 0], [3, 0, 0], [0, 40, 0], [30, 30, 5.0]])
    with pytest.raises(StarforgeError, match="smaller --marker"):
        tool_set([("close", close, None, None)], name="lab")
    tools = tool_set([("close", close, None, None)], name="lab", marker_mm=2.5)
    assert tools.spec.marker_mm == 2.5
    # ids: the files' when distinct, else 1, 2, ...
    two = [("a", _tool(4, 2), 7, None), ("b", _tool(4, 3), 7, None)]
    assert [t.id for t in tool_set(two, name="lab").stars] == [1, 2]
    assert [t.id for t in tool_set([two[0], ("b", two[1][1], 9, None)], name="lab").stars] == [7, 9]


def test_export_prints_a_tool_of_each_marker_count(tmp_path):
    tools = {f"tool{n}": _tool(n, seed=10 + n) for n in (3, 5, 6)}
    src = tmp_path / "lab.csv"
    _csv(src, tools)
    res = api.export_bodies(src, tmp_path / "out", formats=("stl",), plate=False)
    assert res.bodies == 3
    doc = json.loads((tmp_path / "out" / "bodies.json").read_text())
    for entry in doc["bodies"]:
        P = tools[entry["name"]]
        C = np.array(entry["centres_mm"])
        assert np.allclose(_distances(C), _distances(P), atol=1e-6)
        mesh = trimesh.load(tmp_path / "out" / f"{entry['name']}.stl")
        assert mesh.is_watertight and mesh.volume > 0
        # each marker's sphere is in the printed file where bodies.json says (print frame):
        # its centre and points just inside its surface are inside the solid
        T = np.array(entry["placement_to_print"])
        Cp = C @ T[:3, :3].T + T[:3, 3]
        r = doc["family"]["marker_mm"] / 2 - 0.25
        probes = np.concatenate([Cp, Cp + [0, 0, r], Cp + [r, 0, 0], Cp - [r, 0, 0]])
        assert mesh.contains(probes).all(), entry["name"]


def test_export_command_takes_a_tracker_file(tmp_path, capsys):
    from conftest import run_cli

    src = tmp_path / "wand.csv"
    _csv(src, {"wand": _tool(5, seed=4)})
    assert run_cli(["export", src, "--format", "stl", "--no-plate", "--out", tmp_path / "o", "-q"]) == 0
    assert (tmp_path / "o" / "wand.stl").stat().st_size > 1000
    # a tracker file of a body the printer cannot hold: one line, exit 2, nothing written
    _csv(src, {"wand": np.array([[0, 0, 0], [1, 0, 0], [0, 40, 0], [30, 30, 5.0]])})
    code = run_cli(["export", src, "--format", "stl", "--out", tmp_path / "p"])
    err = capsys.readouterr().err
    assert code == 2 and "smaller --marker" in err and "Traceback" not in err
    assert not (tmp_path / "p").exists()


@pytest.mark.skipif(shutil.which("slic3r") is None, reason="Slic3r is not installed here (Debian: apt-get install slic3r)")
def test_slic3r_slices_a_six_marker_tool_without_a_warning(tmp_path):
    src = tmp_path / "tool.csv"
    _csv(src, {"tool": _tool(6, seed=21)})
    api.export_bodies(src, tmp_path / "out", formats=("stl",), plate=False)
    res = subprocess.run(
        ["slic3r", str(tmp_path / "out" / "tool.stl"), "--layer-height", "0.2", "--first-layer-height", "0.2",
         "--nozzle-diameter", "0.4", "--export-svg", "-o", str(tmp_path / "slices.svg")],
        capture_output=True, text=True, timeout=240, cwd=tmp_path,
    )
    assert res.returncode == 0 and (tmp_path / "slices.svg").stat().st_size > 0, res.stderr[-2000:]
    assert not [ln for ln in (res.stdout + res.stderr).splitlines() if re.search(r"warn|unable|error", ln, re.I)]
