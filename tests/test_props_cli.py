"""``starforge place``: the default-command group, outputs, determinism, one-line errors."""

from __future__ import annotations

import contextlib
import csv
import io
import itertools
import json
import re
import shutil

import numpy as np
import pytest

from starforge.cli import main

FAST = ["--sites", "250", "--resolution", "2", "--restarts", "2"]
OUTPUTS = ("placement.json", "markers.csv", "prop_markers.glb", "convergence.png", "layout.png", "guide.png", "guide.pdf")


def _run(args, capsys):
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def hammer_run(tmp_path_factory):
    """``place hammer`` with the FAST settings, run once through the CLI: (folder, stdout)."""
    out = tmp_path_factory.mktemp("hammer") / "o"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(["place", "hammer", *FAST, "--out", str(out)])
    assert code == 0
    return out, stdout.getvalue()


def test_place_default_command_writes_everything(tmp_path, capsys):
    from starforge.props import load_placement

    out = tmp_path / "o"
    code, stdout, err = _run(["place", "hammer", *FAST, "--seed", "4", "--out", str(out)], capsys)
    assert code == 0, err
    for name in OUTPUTS:
        assert (out / name).is_file() and (out / name).stat().st_size > 0
    assert "markers:" in stdout
    doc = json.loads((out / "placement.json").read_text())
    for key in (
        "format",
        "version",
        "prop",
        "settings",
        "seed",
        "rig",
        "poses",
        "markers",
        "marker_diameter_m",
        "cost",
        "history",
        "timings",
    ):
        assert key in doc
    assert doc["format"] == "starforge.placement" and doc["version"] == 1 and doc["seed"] == 4
    assert doc["prop"]["name"] == "hammer" and doc["prop"]["units"] == "m"
    assert len(doc["rig"]["cameras"]) == 8 and len(doc["rig"]["pairs"]) == 4
    # the default models a prop in use: positions x orientations spread over the rotation group
    assert doc["poses"]["count"] == 8 * 24 and len(doc["poses"]["matrices"]) == 8 * 24
    assert doc["objective"] == "tracked" and doc["marker_diameter_m"] == pytest.approx(0.0095)
    assert doc["history"]["restarts"] == 2 and len(doc["history"]["run_costs"]) == 2
    for k in ("total", "visibility", "count", "overlap", "symmetry", "near_symmetry"):
        assert k in doc["cost"]
    tr = doc["tracked"]
    # never behind the baselines it reports on the held-out ranking: tracked fraction, then cost
    sel = tr["baselines"]["selection"]
    won = sel["candidates"][sel["winner"]]
    assert len(won["sites"]) == len(doc["markers"])
    for name in ("greedy_local_search", "best_of_random"):
        c = sel["candidates"][name]
        assert (-won["validation_tracked"], won["selection_cost"]) <= (-c["validation_tracked"], c["selection_cost"] + 1e-9)
    for name in ("greedy_local_search", "best_of_random"):
        assert len(tr["layouts"][name]["sites"]) >= 4  # the baselines' layouts are recorded
    ev = doc["evaluation"]
    assert {"default", "greedy_local_search", "best_of_random"} <= set(ev)
    n = len(doc["markers"])
    assert 4 <= n <= 20
    rows = list(csv.reader((out / "markers.csv").read_text().splitlines()))
    assert rows[0] == ["id", "x_m", "y_m", "z_m", "nx", "ny", "nz"] and len(rows) == n + 1
    pl = load_placement(out)
    assert np.allclose(pl.positions_m, [[float(v) for v in r[1:4]] for r in rows[1:]])
    # re-check: markers lie on the hammer's surface with unit normals, visibility in [0, 1];
    # the balls' centres on the seat's axis, the catalogue's 5.2 mm above the base
    from starforge.props.builtin import builtin_mesh

    mesh = builtin_mesh("hammer")
    _, dist, _ = mesh.nearest.on_surface(pl.positions_m)
    assert dist.max() < 1e-6
    assert np.allclose(np.linalg.norm(pl.normals, axis=1), 1)
    assert np.all((pl.visibility >= 0) & (pl.visibility <= 1))
    assert pl.total_cost == pytest.approx(doc["cost"]["total"])
    centres = np.array(tr["marker_centres_m"])
    assert doc["seat"]["name"] == "9.5mm-m3" and doc["seat"]["base_mm"] == 7.0
    assert np.allclose(centres, pl.positions_m + 0.0052 * pl.normals, atol=1e-9)
    # every marker seated: re-checked with closest points (not the rays the library casts):
    # >= 90 % of the base disc within 0.3 mm of the surface, and no marker under the hand
    from starforge.props.seat import disc_offsets, tangent_frames

    u, v = tangent_frames(pl.normals)
    off = disc_offsets() * 0.0035
    for i in range(n):
        q = pl.positions_m[i] + off[:, :1] * u[i] + off[:, 1:] * v[i]
        gap = mesh.nearest.on_surface(q)[1]
        assert (gap <= 0.0003 + 1e-9).mean() >= 0.9
        m = doc["markers"][i]
        assert m["number"] == i + 1 and m["base_contact"] >= 0.9 and m["edge_distance_mm"] >= 3.5 - 1e-9
    # ... where most grips hold it: inside the fists of at most half of the grips
    held = np.zeros(n)
    for grip in doc["grips"]["grips"]:
        fist = grip["capsules"][0]
        a, b = np.array(fist["a"]), np.array(fist["b"])
        s = np.clip((pl.positions_m - a) @ (b - a) / max((b - a) @ (b - a), 1e-18), 0, 1)
        held += np.linalg.norm(pl.positions_m - (a + s[:, None] * (b - a)), axis=1) <= fist["radius"]
    assert (held <= 0.5 * len(doc["grips"]["grips"])).all()


def _assert_same_outputs(a_dir, b_dir):
    """Every output file the same bytes; placement.json the same apart from its timings."""
    for name in OUTPUTS:
        a, b = a_dir / name, b_dir / name
        if name == "placement.json":
            da, db = json.loads(a.read_text()), json.loads(b.read_text())
            da.pop("timings"), db.pop("timings")
            assert da == db
        else:
            assert a.read_bytes() == b.read_bytes(), name


@pytest.mark.slow
def test_same_seed_same_bytes(tmp_path, capsys):
    outs = []
    for k in range(2):
        out = tmp_path / f"o{k}"
        assert _run(["place", "run", "bottle", *FAST, "--seed", "9", "--out", str(out)], capsys)[0] == 0
        outs.append(out)
    _assert_same_outputs(*outs)


@pytest.mark.slow  # a placement run, then two scorings through the CLI
def test_score_subcommand_rescores_a_layout(tmp_path, capsys):
    out = tmp_path / "o"
    assert _run(["place", "box", *FAST, "--out", str(out)], capsys)[0] == 0
    doc = json.loads((out / "placement.json").read_text())
    code, stdout, err = _run(
        ["place", "score", "box", str(out / "markers.csv"), "--resolution", "2", "--json"], capsys
    )
    assert code == 0, err
    scored = json.loads(stdout)
    assert scored["total"] == pytest.approx(doc["cost"]["total"], abs=1e-6)
    assert scored["markers"] == len(doc["markers"])
    # an expert-style layout without normals: normals come from the surface
    (tmp_path / "expert.csv").write_text(
        "id,x_m,y_m,z_m\n0,0,0,0.25\n1,0.1,0.05,0.25\n2,-0.2,0,0.1\n3,0.05,-0.15,0.2\n4,0.2,0.1,0.05\n"
    )
    code, stdout, err = _run(
        ["place", "score", "box", str(tmp_path / "expert.csv"), "--resolution", "2"], capsys
    )
    assert code == 0, err and "cost" in stdout


@pytest.mark.slow
def test_refuses_to_overwrite_without_force(hammer_run, tmp_path, capsys):
    out = tmp_path / "o"
    shutil.copytree(hammer_run[0], out)
    before = {n: (out / n).read_bytes() for n in OUTPUTS}
    code, _, err = _run(["place", "hammer", *FAST, "--seed", "5", "--out", str(out)], capsys)
    assert code == 2 and "--force" in err and err.count("\n") == 1
    assert {n: (out / n).read_bytes() for n in OUTPUTS} == before
    assert _run(["place", "hammer", *FAST, "--seed", "5", "--out", str(out), "--force"], capsys)[0] == 0


def _write(path, text):
    path.write_text(text)
    return str(path)


@pytest.mark.parametrize(
    "case",
    [
        "missing",
        "corrupt",
        "empty",
        "markers3",
        "markers21",
        "negative_weight",
        "all_forbidden",
        "blind_rig",
        "unknown_prop",
        "bad_units",
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, case):
    out = tmp_path / "o"
    args = ["place", "hammer", *FAST, "--out", str(out)]
    if case == "missing":
        args[1] = str(tmp_path / "nope.stl")
    elif case == "corrupt":
        args[1] = _write(tmp_path / "c.stl", "solid broken\nthis is not an stl\n")
    elif case == "empty":
        args[1] = _write(tmp_path / "e.obj", "")
    elif case == "markers3":
        args += ["--markers", "3"]
    elif case == "markers21":
        args += ["--markers", "21"]
    elif case == "negative_weight":
        spec = tmp_path / "s.toml"
        spec.write_text("[costs]\nw_overlap = -1.0\n")
        args += ["--spec", str(spec)]
    elif case == "all_forbidden":
        spec = tmp_path / "s.toml"
        spec.write_text("[[constraints.boxes]]\nmin = [-9, -9, -9]\nmax = [9, 9, 9]\n")
        args += ["--spec", str(spec)]
    elif case == "blind_rig":
        rig = tmp_path / "r.toml"
        rig.write_text(
            'pairs = "auto"\n[[cameras]]\nposition = [5, 0, 1]\ntarget = [10, 0, 1]\n'
            "[[cameras]]\nposition = [5, 1, 1]\ntarget = [10, 1, 1]\n"
        )
        args += ["--rig", str(rig)]
    elif case == "unknown_prop":
        args[1] = "teapot"
    elif case == "bad_units":
        args += ["--units", "furlong"]
    code, _, err = _run(args, capsys)
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    assert not out.exists()
    assert not list(tmp_path.glob(".o.*"))  # no staging folder left behind


@pytest.mark.slow  # a placement run through the CLI
def test_constraints_from_the_cli(tmp_path, capsys):
    import trimesh

    slab = trimesh.creation.box(extents=(1, 1, 0.2))  # covers the bottom 10 cm of the box prop
    slab.export(tmp_path / "slab.stl")
    out = tmp_path / "o"
    code, stdout, err = _run(
        ["place", "box", *FAST, "--forbid-mesh", str(tmp_path / "slab.stl"), "--out", str(out)], capsys
    )
    assert code == 0, err
    doc = json.loads((out / "placement.json").read_text())
    st = doc["sites"]
    assert st["forbidden"] > 0 and st["usable"] + st["forbidden"] + st["under_hand"] + st["unseated"] == 250
    assert all(m["position"][2] > 0.1 for m in doc["markers"])
    assert f"({doc['sites']['forbidden']} constrained, " in stdout


@pytest.mark.slow
def test_orientations_and_help(tmp_path, capsys):
    out = tmp_path / "o"
    code, _, err = _run(["place", "racket", *FAST, "--orientations", "3", "--out", str(out)], capsys)
    assert code == 0, err
    doc = json.loads((out / "placement.json").read_text())
    assert doc["poses"]["count"] == 24
    M = np.array(doc["poses"]["matrices"])
    assert np.allclose(M[:, :3, :3] @ np.transpose(M[:, :3, :3], (0, 2, 1)), np.eye(3), atol=1e-9)
    code, stdout, _ = _run(["place", "--help"], capsys)
    assert code == 0 and "score" in stdout


@pytest.mark.slow
def test_hammer_is_the_default_prop_and_custom_rigs(tmp_path, capsys):
    out = tmp_path / "o"
    code, _, err = _run(["place", *FAST, "--rig", "small4", "--out", str(out)], capsys)
    assert code == 0, err
    doc = json.loads((out / "placement.json").read_text())
    assert doc["prop"]["name"] == "hammer"
    assert len(doc["rig"]["cameras"]) == 4 and sorted(i for p in doc["rig"]["pairs"] for i in p) == [
        0,
        1,
        2,
        3,
    ]
    # a custom rig in TOML: two cameras above the volume, pair given explicitly
    rig = tmp_path / "two.toml"
    rig.write_text(
        "pairs = [[0, 1]]\n[volume]\ncenter = [0, 0, 1]\nsize = [1, 1, 1]\n"
        "[[cameras]]\nposition = [3, 0, 2.5]\ntarget = [0, 0, 1]\nfov_deg = 50\n"
        "[[cameras]]\nposition = [0, 3, 2.5]\ntarget = [0, 0, 1]\nfov_deg = 50\n"
    )
    out2 = tmp_path / "o2"
    code, _, err = _run(["place", "box", *FAST, "--rig", str(rig), "--out", str(out2)], capsys)
    assert code == 0, err
    doc = json.loads((out2 / "placement.json").read_text())
    assert doc["rig"]["pairs"] == [[0, 1]] and doc["rig"]["cameras"][0]["fov_deg"] == 50


@pytest.mark.slow
def test_pictures_drawn_in_a_child_process_are_identical(tmp_path, capsys):
    from starforge.props.files import write_outputs
    from starforge.props.mesh import load_prop
    from starforge.props.placement import place
    from starforge.props.spec import load_spec, with_overrides

    out = tmp_path / "cli"
    assert _run(["place", "shield", *FAST, "--seed", "6", "--out", str(out)], capsys)[0] == 0
    from starforge.api.place import NOISE_MM, distinct_tolerance_mm

    spec = with_overrides(load_spec("default"), sites=250, resolution=2, restarts=2)
    spec = with_overrides(spec, distinct_mm=distinct_tolerance_mm(spec, None, NOISE_MM))  # as the CLI designs it
    early = []
    res = place(load_prop("shield"), spec, seed=6, on_layout=early.append)
    # the CLI draws from the result handed over before the evaluation: same layout, no evaluation yet
    (first,) = early
    assert first.marker_sites == res.marker_sites and not first.evaluation and res.evaluation
    here = tmp_path / "here"
    here.mkdir()
    from starforge.render.props import BackgroundRenderer

    write_outputs(res, here, renderer=BackgroundRenderer(enabled=False))  # drawn in this process, from the final result
    for name in ("convergence.png", "layout.png", "guide.png", "guide.pdf", "markers.csv", "prop_markers.glb"):
        assert (out / name).read_bytes() == (here / name).read_bytes(), name
    assert not list(out.glob(".render*"))


@pytest.mark.slow
def test_guide_pdf_in_standard_fonts_unless_a_text_needs_more(tmp_path):
    """guide.pdf names PDF's standard fonts and embeds none; a prop name outside Latin-1 keeps
    the embedded fonts (the standard ones cannot draw it)."""
    from dataclasses import replace

    from starforge.props.placement import run_placement
    from starforge.render.guide import guide_files
    from starforge.render.prop_views import plot_data

    data = plot_data(run_placement("box", sites=150, resolution=1, orientations=6))
    guide_files(data, tmp_path)
    pdf = (tmp_path / "guide.pdf").read_bytes()
    assert b"/Helvetica" in pdf and b"DejaVu" not in pdf
    guide_files(replace(data, name="box \u03a9"), tmp_path)
    pdf = (tmp_path / "guide.pdf").read_bytes()
    assert b"/Helvetica" not in pdf and b"DejaVu" in pdf


_SPLIT = """
import sys
from pathlib import Path

import starforge.render.guide as guide
from starforge.props.placement import run_placement
from starforge.render.prop_views import plot_data

forks = []
fork = guide.fork_helper
guide.fork_helper = lambda *a, **k: forks.append(1) or fork(*a, **k)
data = plot_data(run_placement("box", sites=150, resolution=1, orientations=6))
one, split = Path(sys.argv[1]) / "one", Path(sys.argv[1]) / "split"
guide.guide_files(data, one)
assert not forks
guide.guide_files(data, split, split=True)
assert len(forks) == 1, forks
for name in ("guide.png", "guide.pdf"):
    assert (one / name).read_bytes() == (split / name).read_bytes(), name
"""


@pytest.mark.slow
def test_the_guide_split_over_two_processes_is_the_same_bytes(tmp_path):
    """guide_files(split=True) writes the PDF from a forked copy while it writes the PNG: the same
    files as one after the other (run in a process of its own, where forking is allowed)."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _SPLIT, str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "split").iterdir()) == ["guide.pdf", "guide.png"]


@pytest.mark.slow
def test_grip_no_hand_and_bases_stl(tmp_path, capsys):
    """--grip places the hand where asked, --no-hand removes it, --bases-stl writes a watertight
    prop with one pad per marker, and the guide names every marker."""
    import trimesh

    out = tmp_path / "g"
    args = ["place", "box", "--sites", "150", "--resolution", "1", "--orientations", "6", "--bases-stl",
            "--grip", "-0.1,0,0.25,0.1,0,0.25,0.01", "--out", str(out)]  # fmt: skip
    code, stdout, err = _run(args, capsys)
    assert code == 0, err
    doc = json.loads((out / "placement.json").read_text())
    (hand,) = doc["hand"]
    assert hand["radius"] == pytest.approx(0.035) and hand["a"][2] == pytest.approx(0.25)
    assert hand["flat"] and sorted([hand["a"][0], hand["b"][0]]) == pytest.approx([-0.1, 0.1])  # a band over the segment
    stl = trimesh.load(out / "prop_bases.stl")
    assert stl.is_watertight and stl.volume > 0.4 * 0.3 * 0.25
    assert (out / "guide.pdf").read_bytes()[:5] == b"%PDF-"
    code, stdout, err = _run(["place", "box", "--sites", "150", "--resolution", "1", "--orientations", "6",
                              "--no-hand", "--out", str(tmp_path / "n")], capsys)  # fmt: skip
    assert code == 0, err
    doc = json.loads((tmp_path / "n" / "placement.json").read_text())
    assert doc["hand"] == [] and doc["sites"]["under_hand"] == 0


@pytest.fixture
def avoid_seen(monkeypatch):
    """Stop ``place`` where the files to avoid are read; keep the prop and the files it was given."""
    import starforge.props.mesh as mesh
    import starforge.tracking.avoid as av
    from starforge.errors import StarforgeError

    seen = []

    def fake_load(prop, units, smooth=True):
        seen.append(("prop", prop))
        return object()

    def fake_faces(paths):
        seen.append(("avoid", [str(p) for p in paths]))
        raise StarforgeError("stopped before the placement (test)")

    monkeypatch.setattr(mesh, "load_prop", fake_load)
    monkeypatch.setattr(av, "faces_to_avoid", fake_faces)
    return seen


@pytest.mark.parametrize(
    "args,prop,files",
    [
        (["--avoid", "A.json", "B.xml"], "hammer", ["A.json", "B.xml"]),  # B is a file, not PROP
        (["--avoid", "A.json", "--avoid", "B.xml"], "hammer", ["A.json", "B.xml"]),
        (["box", "--avoid", "A.json", "B.xml", "C.vsk"], "box", ["A.json", "B.xml", "C.vsk"]),
        (["--avoid", "A.json", "B.xml", "-q", "racket"], "racket", ["A.json", "B.xml"]),  # an option ends the list
        (["--avoid=A.json", "B.xml"], "hammer", ["A.json", "B.xml"]),
    ],
)
def test_avoid_takes_every_value_up_to_the_next_option(tmp_path, capsys, monkeypatch, avoid_seen, args, prop, files):
    monkeypatch.chdir(tmp_path)  # the files exist (they are checked before any work); their reading is faked
    for name in ("A.json", "B.xml", "C.vsk"):
        (tmp_path / name).write_text("{}")
    code, _, err = _run(["place", *args, "--out", str(tmp_path / "o")], capsys)
    assert code == 2 and "stopped before the placement" in err
    assert avoid_seen == [("prop", prop), ("avoid", files)]


def test_spread_flag_leaves_other_arguments_alone():
    from starforge.cli._multi import spread_flag

    args = ["hammer", "--out", "o", "--seed", "3", "-q"]
    assert spread_flag("--avoid", args) == args
    assert spread_flag("--avoid", ["--avoid", "A", "--", "B"]) == ["--avoid", "A", "--", "B"]


_FORK_CHECK = """
import os, threading
from starforge.cli._progress import Plain
from starforge.render.props import BackgroundRenderer
stop = Plain("place", interval_s=0.01).close
try:
    assert BackgroundRenderer()._fork
    with BackgroundRenderer() as r:  # forks beside a heartbeat printing every 10 ms
        assert r._pid is not None
    other = threading.Thread(target=threading.Event().wait, args=(0.5,), daemon=True)
    other.start()
    assert not BackgroundRenderer()._fork
    other.join()
finally:
    stop()
print("ok")
"""


@pytest.mark.slow
def test_render_processes_fork_beside_the_heartbeat_only():
    """Off a terminal the CLI's heartbeat thread runs; it holds its print lock across forks, so the
    pictures still get their render processes; any other thread keeps them in-process.  Run in a
    fresh interpreter: threads that earlier tests leave behind (a dask client's, a pool's) would
    rightly keep the renderer in-process here."""
    import os
    import subprocess
    import sys

    if not hasattr(os, "fork"):
        pytest.skip("no os.fork")
    res = subprocess.run([sys.executable, "-c", _FORK_CHECK], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip().endswith("ok"), res.stderr[-2000:]


_SIGNALS_FORK_CHECK = """
import os, signal, time
import starforge.runtime.process as process
from starforge.render.props import BackgroundRenderer
done, undo = process._install_signals()
try:
    assert BackgroundRenderer()._fork  # the signal watcher is safe to fork beside
    with BackgroundRenderer() as r:
        time.sleep(0.5)
        os.kill(r._pid, signal.SIGTERM)  # a signal meant for the render process only
        time.sleep(0.5)
    assert process._stopped_by[0] is None, process._stopped_by  # never reached the parent's watcher
finally:
    undo()
print("ok")
"""


@pytest.mark.slow
def test_render_processes_fork_beside_the_signal_watcher_and_leave_its_pipe():
    """The CLI's last-resort signal watcher (a thread) does not keep the pictures in-process
    (they are drawn off the critical path, in a forked process); a render process stops writing
    into the watcher's wakeup pipe, so a signal sent to it alone is not taken for the command's own."""
    import os
    import subprocess
    import sys

    if not hasattr(os, "fork"):
        pytest.skip("no os.fork")
    res = subprocess.run([sys.executable, "-c", _SIGNALS_FORK_CHECK], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip().endswith("ok"), res.stderr[-2000:]


@pytest.mark.slow
def test_place_as_a_process_ends_without_the_teardown_and_writes_the_same(tmp_path, capsys):
    """``python -m starforge place`` ends with os._exit after its atexit handlers (no module
    teardown) and runs with the cyclic garbage collector paused: its stdout still
    arrives in full, its exit code is the command's, its files are the bytes an in-process run
    (collector paused, then on again) writes (placement.json but for its timings)."""
    import os
    import subprocess
    import sys

    args = ["place", "box", *FAST, "--seed", "3"]
    res = subprocess.run(
        [sys.executable, "-m", "starforge", *args, "--out", str(tmp_path / "p")],
        capture_output=True, text=True, timeout=300, env={**os.environ, "COLUMNS": "200"},
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    assert "markers:" in res.stdout and res.stdout.rstrip().endswith("guide.pdf"), res.stdout
    import gc

    assert gc.isenabled()
    assert _run([*args, "--out", str(tmp_path / "i")], capsys)[0] == 0
    assert gc.isenabled()  # place pauses the cyclic collector for its run only
    _assert_same_outputs(tmp_path / "p", tmp_path / "i")
    bad = subprocess.run(
        [sys.executable, "-m", "starforge", *args, "--out", str(tmp_path / "p")], capture_output=True, text=True, timeout=300
    )  # the outputs exist and no --force: the one-line refusal, exit 2
    last = bad.stderr.strip().splitlines()[-1]  # after any heartbeat lines of a slow machine
    assert bad.returncode == 2 and last.startswith("error: ") and "--force" in last, bad.stderr


def test_quick_exit_runs_the_atexit_handlers_and_only_when_allowed_and_safe(monkeypatch):
    """:func:`starforge.runtime.process.end_process`: atexit handlers, then os._exit with the code, after a
    command that allowed it; the ordinary sys.exit otherwise, under a tracer, or while a
    non-daemon thread runs."""
    import atexit
    import os
    import sys
    import threading

    from starforge.runtime import process
    from starforge.runtime.process import _quick_exit

    calls = []
    monkeypatch.setattr(atexit, "_run_exitfuncs", lambda: calls.append("atexit"))
    monkeypatch.setattr(os, "_exit", lambda code: calls.append(("_exit", code)))
    monkeypatch.setattr(sys, "gettrace", lambda: None)
    monkeypatch.setattr(sys, "getprofile", lambda: None)
    before = _quick_exit[0]
    _quick_exit[0] = True
    try:
        process.end_process(3)
        assert calls == ["atexit", ("_exit", 3)]
        calls.clear()
        release = threading.Event()
        th = threading.Thread(target=release.wait, daemon=False)
        th.start()
        try:
            with pytest.raises(SystemExit) as e:
                process.end_process(4)  # the interpreter would wait for that thread: so does the exit
            assert e.value.code == 4 and calls == []
        finally:
            release.set()
            th.join()
        monkeypatch.setattr(sys, "gettrace", lambda: (lambda *a: None))
        with pytest.raises(SystemExit):
            process.end_process(0)  # coverage writes its data at the teardown
        monkeypatch.setattr(sys, "gettrace", lambda: None)
        _quick_exit[0] = False
        with pytest.raises(SystemExit):
            process.end_process(0)  # a command that did not allow it
        assert calls == []
    finally:
        _quick_exit[0] = before


def test_the_guide_has_landmarks_calipers_and_no_overlapping_text(hammer_run):
    """Every marker in placement.json has a face, landmarks and caliper distances (re-measured
    from the ball centres); the guide's pages, drawn, have no two text boxes overlapping and
    every text inside the page; the template page's scale bar is 50 mm of the prop at its scale."""
    from starforge.props.placement import run_placement
    from starforge.render._mpl import text_boxes
    from starforge.render.guide import guide_pages, overlapping_texts

    out, _ = hammer_run
    doc = json.loads((out / "placement.json").read_text())
    names = {f["name"] for f in doc["guide"]["landmarks"]}
    for m in doc["markers"]:
        assert m["landmark"]["face"]["kind"] in ("flat", "curved")
        measured = m["landmark"]["measure_from"]
        assert len(measured) in (1, 3) and {x["name"] for x in measured} <= names
        assert len(measured) == 3 or "towards" in measured[0]  # one: set off it in a direction
        # the readings place it within the placement error, or the line sends it to the drawings
        err = m["landmark"]["locating_error_mm"]
        within = err is not None and err <= doc["settings"]["seat"]["placement_error_mm"]
        assert within == ("place it by the drawings" not in m["landmark"]["text"])
        assert m["seat_margin_mm"] >= doc["settings"]["seat"]["placement_error_mm"] - 1e-9
    centres = np.array(doc["tracked"]["marker_centres_m"])
    pairs = doc["guide"]["caliper"]
    assert len(pairs) == len(centres) * (len(centres) - 1) // 2
    for q in pairs:
        assert q["centre_mm"] == pytest.approx(1000 * np.linalg.norm(centres[q["a"] - 1] - centres[q["b"] - 1]), abs=0.06)
    res = run_placement("hammer", sites=250, resolution=2, orientations=6)
    pages = guide_pages(res)
    assert len(pages) == 2
    for fig in pages:
        assert overlapping_texts(fig) == []
        W, H = fig.bbox.width, fig.bbox.height
        for t, (x0, y0, x1, y1) in text_boxes(fig):
            assert x0 >= -0.5 and y0 >= -0.5 and x1 <= W + 0.5 and y1 <= H + 0.5, t
    text = " ".join(t for t, _ in text_boxes(pages[0]))
    for i in range(1, len(res.marker_sites) + 1):
        assert f"{i:>2}. on " in text


def test_the_printed_template_measures_the_prop_at_its_scale(hammer_run):
    """guide.pdf's template page as a printer at 100 % lays it down (pdfminer.six reads the
    file's strokes, 1 pt = 1/72 inch): its crosshairs, 3 mm strokes crossing at each marker's base
    centre, lie as far apart as the markers on the prop in the view the heading names, over the
    heading's scale; the scale bar is 50 mm of the prop at that scale."""
    from pdfminer.high_level import extract_pages
    from pdfminer.layout import LTLine, LTTextContainer

    from starforge.render.prop_views import VIEWS

    out, _ = hammer_run
    page = list(extract_pages(out / "guide.pdf"))[1]
    pt = 25.4 / 72.0  # mm per point
    heading = next(t.get_text() for t in page if isinstance(t, LTTextContainer) and "Template" in t.get_text())
    view, k = heading.split(", ")[1], int(heading.split("scale 1:")[1].split(":")[0])
    lines = [(np.array([x.x0, x.y0]), np.array([x.x1, x.y1])) for x in page if isinstance(x, LTLine)]
    strokes = [(a + b) / 2 for a, b in lines if abs(np.linalg.norm(b - a) * pt - 3.0) < 0.05]
    centres = np.array([p for p in strokes if sum(np.linalg.norm(p - q) < 0.01 for q in strokes) == 2])[::2]
    doc = json.loads((out / "placement.json").read_text())
    on_prop = np.array([m["position"] for m in doc["markers"]]) @ VIEWS[view][:2].T * 1000.0
    assert len(centres) == len(on_prop) >= 4

    def spans(p):
        return np.sort([np.linalg.norm(p[i] - p[j]) for i, j in itertools.combinations(range(len(p)), 2)])

    assert spans(centres) * pt == pytest.approx(spans(on_prop) / k, abs=0.1)  # 0.1 mm printed
    bar = max((np.linalg.norm(b - a) for a, b in lines if abs(a[1] - b[1]) < 1e-6), default=0.0)
    assert bar * pt == pytest.approx(50.0 / k, abs=0.05)


def test_the_written_guide_pdf_has_no_overlapping_text(hammer_run, tmp_path):
    """guide.pdf as a reader sees it (pdfminer.six parses the file, :mod:`benchmarks._pdftext`):
    no glyph overlaps another and every glyph lies on its page.  The reader is checked on a PDF
    with two strings drawn over each other."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks._pdftext import glyph_boxes, off_page, overlapping_glyphs

    fig = plt.figure(figsize=(4, 3))
    fig.text(0.1, 0.5, "Hello world")
    fig.text(0.15, 0.505, "overlap text")
    fig.savefig(tmp_path / "clash.pdf")
    plt.close(fig)
    ((_, clash),) = glyph_boxes(tmp_path / "clash.pdf")
    assert overlapping_glyphs([b for _, b in clash])

    out, _ = hammer_run
    pages = glyph_boxes(out / "guide.pdf")
    assert len(pages) == 2
    for page in pages:
        assert len(page[1]) > 100
        assert overlapping_glyphs([b for _, b in page[1]]) == []
        assert off_page(page) == []


@pytest.mark.slow
def test_the_run_prints_its_grips_and_pins_one_by_number(hammer_run, tmp_path, capsys):
    """Every run lists the grips it assumed (numbered as --grip takes them) and placement.json
    holds them; --grip N scores the layout under that grip alone, and out of range is refused."""
    out, stdout = hammer_run
    doc = json.loads((out / "placement.json").read_text())
    grips = doc["grips"]["grips"]
    assert len(grips) > 1 and {g["hand"] for g in grips} == {"left", "right"}
    flat = " ".join(stdout.split())
    from starforge.props.grips import WRAPS

    assert f"hand: {len(grips)} grip(s)" in flat
    # every grip is listed once, numbered as --grip takes it, with its hand
    listed = {}
    for a, b, hand in re.findall(r"(\d+)(?:-(\d+))?:? (right|left) hand", flat.split("(--grip N pins grip N):")[1]):
        for n in range(int(a), int(b or a) + 1):
            assert n not in listed
            listed[n] = hand
    assert listed == {n + 1: g["hand"] for n, g in enumerate(grips)}
    assert all(f"{w:g}" in flat for w in WRAPS)
    assert len(doc["hand"]) == sum(len(g["capsules"]) for g in grips)
    code, stdout, err = _run(["place", "hammer", *FAST, "--grip", "2", "--out", str(tmp_path / "p")], capsys)
    assert code == 0, err
    pinned = json.loads((tmp_path / "p" / "placement.json").read_text())["grips"]["grips"]
    assert pinned == [grips[1]]
    code, _, err = _run(["place", "hammer", *FAST, "--grip", str(len(grips) + 1), "--out", str(tmp_path / "q")], capsys)
    assert code == 2 and "numbered 1 to" in err and not (tmp_path / "q").exists()


def test_smaller_points_marker_names_sites_help_symmetry_line(capsys, monkeypatch):
    from starforge.catalog import load_template
    from starforge.errors import StarforgeError
    from starforge.props.files import ranking_note, symmetry_line
    from starforge.props.spec import load_spec, with_overrides

    # an unknown catalogue-looking name is refused listing the catalogue; a plain number is a diameter
    with pytest.raises(StarforgeError, match="no catalogue marker is 9 mm.*--marker 9"):
        with_overrides(load_spec("default"), marker_mm="9mm")
    assert with_overrides(load_spec("default"), marker_mm="9").marker_seat().name == "9 mm ball"
    assert with_overrides(load_spec("default"), marker_mm="9.5mm").track.marker_mm == 9.5  # a catalogue size
    # the --sites help quotes the default template's value
    monkeypatch.setenv("COLUMNS", "200")
    code, out, _ = _run(["place", "run", "--help"], capsys)
    assert code == 0
    assert f"{load_template('place', 'default')[1]['sites']} in `default`" in " ".join(out.split())
    # a margin at the search's cap is a floor, not a measurement
    assert symmetry_line(0.005, 5.0).startswith("near-symmetry margin: >= 5 mm")
    assert "below the 5 mm target" in symmetry_line(0.0031, 5.0)
    # a winner costing more than greedy says why; one costing less says nothing
    cand = {"winner": {"cost": 0.3, "validation_tracked": 0.999}, "greedy_local_search": {"cost": 0.2, "validation_tracked": 0.99}}
    assert "99.90 %" in ranking_note({"selection": {"winner": "winner", "candidates": cand}})
    cand["winner"]["cost"] = 0.1
    assert ranking_note({"selection": {"winner": "winner", "candidates": cand}}) == ""


@pytest.mark.slow
def test_the_guide_render_process_loads_every_font_the_guide_draws_in():
    """Every visible text of the guide's pages is in one of the styles its render process loads
    beforehand (:func:`starforge.render.guide.load_fonts`): size, weight and family."""
    from matplotlib.text import Text

    from starforge.props.placement import run_placement
    from starforge.render.guide import TEXT_STYLES, guide_pages

    def style(size, weight="normal", family="sans-serif"):
        return float(size), str(weight), family

    loaded = {style(kw["fontsize"], kw.get("weight", "normal"), kw.get("family", "sans-serif"))
              for kw in TEXT_STYLES.values()}  # fmt: skip
    res = run_placement("box", sites=150, resolution=1, orientations=6, seed=1)
    drawn = {
        style(t.get_fontsize(), t.get_weight(), t.get_family()[0])
        for fig in guide_pages(res)
        for t in fig.findobj(Text)
        if t.get_visible() and t.get_text().strip()
    }
    assert drawn and drawn <= loaded, drawn - loaded
