"""The export builds STEP solids in a second process: the files must be what a serial build
writes, bodies.json must not depend on it, progress must count every unit of work once, and a
failure on either side leaves no worker behind and no STEP file begun afterwards."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from starforge import load_family
from starforge.cad.body import BodySpec
from starforge.cad.export import export_family
from starforge.cad.mounts import load_mount

DATA = Path(__file__).parent / "data" / "cad" / "small_family.json"


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """Stars 1 and 2 exported as STEP + STL + 3MF (threaded), and as STL + 3MF alone."""
    fam = load_family(DATA)
    mount, spec = load_mount("flat"), BodySpec()
    full, mesh_only = tmp_path_factory.mktemp("full"), tmp_path_factory.mktemp("mesh")
    calls: list = []
    export_family(fam, full, mount, spec, ids=[1, 2], progress=lambda d, n: calls.append((d, n)))
    export_family(fam, mesh_only, mount, spec, formats=("stl", "3mf"), ids=[1, 2])
    return fam, mount, spec, full, mesh_only, calls


def test_progress_counts_meshes_and_step_solids_once(both):
    *_, calls = both
    assert [d for d, _ in calls] == [1, 2, 3, 4]  # 2 stars x (mesh files, STEP file), in order
    assert {n for _, n in calls} == {4}


SERIAL = """
import sys
from pathlib import Path
from starforge import load_family
from starforge.cad.body import BodySpec
from starforge.cad.export import export_family, family_bodies, print_layout
from starforge.cad.mounts import load_mount
from starforge.cad.brep import body_solid, placed, write_step
from starforge.colours import body_colour
fam, mount, spec = load_family(sys.argv[1]), load_mount("flat"), BodySpec()
out = Path(sys.argv[2])
if sys.argv[3] == "serial":  # one body after the other, as the export did before its STEP thread
    bodies = family_bodies(fam, [1, 2], mount, spec)
    transforms, _ = print_layout(bodies, (200.0, 200.0), 5.0)
    for b, T in zip(bodies, transforms, strict=True):
        write_step(placed(body_solid(b), T, b.name, body_colour(b.star_id - 1)), out / f"{b.name}.step")
elif sys.argv[3] == "launched":  # a fresh interpreter, where this process cannot fork
    from starforge.cad.step_worker import StepProcess

    worker = StepProcess(fork=False)
    assert not worker.forked
    export_family(fam, out, mount, spec, ids=[1, 2], plate=False, step_worker=worker)
else:
    export_family(fam, out, mount, spec, ids=[1, 2], plate=False)
"""


@pytest.mark.slow
def test_step_files_equal_a_serial_build(tmp_path):
    """Each in a fresh process: OCCT numbers some STEP entities with a process-wide counter, so
    a file depends on how many were written before it in the same process (and in which order)."""
    import subprocess
    import sys

    for how in ("serial", "threaded", "launched"):
        (tmp_path / how).mkdir()
        subprocess.run([sys.executable, "-c", SERIAL, str(DATA), str(tmp_path / how), how], check=True)
    for name in ("star_001.step", "star_002.step"):
        assert (tmp_path / "serial" / name).read_bytes() == (tmp_path / "threaded" / name).read_bytes()
        assert (tmp_path / "serial" / name).read_bytes() == (tmp_path / "launched" / name).read_bytes()


PLATE = """
import sys
from pathlib import Path
from starforge import load_family
from starforge.cad.body import BodySpec
from starforge.cad.export import export_family
from starforge.cad.mounts import load_mount
export_family(load_family(sys.argv[1]), Path(sys.argv[2]), load_mount("flat"), BodySpec(), formats=("step",),
              ids=[1, 2, 3])
"""


@pytest.mark.slow
def test_plate_step_files_are_the_same_from_run_to_run(tmp_path):
    """A plate's assembly written twice, each in a fresh process, is the same bytes (OCCT's writer
    lists the parts' colour styles in the order of their addresses; write_step puts them in the
    assembly's), and still names and colours every body as the export gave them."""
    import subprocess
    import sys

    import build123d

    from starforge.colours import body_colour

    for run in ("a", "b"):
        (tmp_path / run).mkdir()
        subprocess.run([sys.executable, "-c", PLATE, str(DATA), str(tmp_path / run)], check=True)
    plate = (tmp_path / "a" / "plate.step").read_bytes()
    assert plate == (tmp_path / "b" / "plate.step").read_bytes()
    assembly = build123d.import_step(tmp_path / "a" / "plate.step")
    got = {c.label: tuple(round(255 * x) for x in tuple(c.color)[:3]) for c in assembly.children}
    assert got == {f"star_{k:03d}": body_colour(k - 1) for k in (1, 2, 3)}
    assert plate.count(b"COLOUR_RGB") == 2 * 3  # a style per body and one per placed instance


@pytest.mark.slow
def test_a_plate_of_repeated_colours_is_the_same_from_run_to_run(tmp_path):
    """Bodies of one colour share its colour entity in the writer's output: the order of the
    styles still does not depend on the process, and every body keeps its name and colour."""
    import subprocess
    import sys

    import build123d

    for run in ("a", "b"):
        subprocess.run([sys.executable, "-c", BOXES, str(tmp_path / f"{run}.step")], check=True)
    assert (tmp_path / "a.step").read_bytes() == (tmp_path / "b.step").read_bytes()
    assembly = build123d.import_step(tmp_path / "a.step")
    got = [(c.label, tuple(round(255 * x) for x in tuple(c.color)[:3])) for c in assembly.children]
    assert got == [(f"box_{i}", BOX_COLOURS[i]) for i in range(len(BOX_COLOURS))]


BOX_COLOURS = [(0, 100, 200), (40, 100, 200), (0, 100, 200), (255, 0, 0), (40, 100, 200), (255, 0, 0)]
BOXES = f"""
import sys
import numpy as np
from starforge.cad.brep import PRINT_ROTATION, assembly, kernel, placed, write_step
bd = kernel()
T = np.eye(4)
T[:3, :3] = PRINT_ROTATION
boxes = [placed(bd.Solid.make_box(1.0 + i, 2.0, 3.0), T, f"box_{{i}}", c) for i, c in enumerate({BOX_COLOURS})]
beds = [np.eye(4) for _ in boxes]
for i, bed in enumerate(beds):
    bed[0, 3] = 10.0 * i
write_step(assembly(boxes, beds, "boxes"), sys.argv[1])
"""


def test_mesh_files_and_entries_do_not_depend_on_step(both):
    *_, full, mesh_only, _ = both
    for f in sorted(mesh_only.glob("*")):
        if f.suffix in (".stl", ".3mf"):
            assert f.read_bytes() == (full / f.name).read_bytes(), f.name
    a = json.loads((full / "bodies.json").read_text())
    b = json.loads((mesh_only / "bodies.json").read_text())
    for ea, eb in zip(a["bodies"], b["bodies"], strict=True):
        assert ea["files"] == [*eb["files"], f"{ea['name']}.step"]
        assert ea["step_volume_mm3"] == pytest.approx(ea["mesh_volume_mm3"], rel=1e-3)
        assert {k: v for k, v in ea.items() if k not in ("files", "step_volume_mm3")} == {
            k: v for k, v in eb.items() if k != "files"
        }


WORKER_ERROR = """
import sys
from pathlib import Path
from starforge import load_family
from starforge.cad import step_worker
from starforge.cad.body import BodySpec
from starforge.cad.export import family_bodies, print_layout
from starforge.cad.mounts import load_mount
from starforge.errors import StarforgeError

bodies = family_bodies(load_family(sys.argv[1]), [1], load_mount("flat"), BodySpec())
transforms, _ = print_layout(bodies, (200.0, 200.0), 5.0)
worker = step_worker.StepProcess(fork=sys.argv[3] == "forked")
job = step_worker.start(bodies, transforms, [(1, 2, 3)], Path(sys.argv[2]) / "missing", worker=worker)
try:
    job.result()
except StarforgeError as exc:
    print(job.forked, job.proc.returncode, exc)
"""

CRASHING_WORKER = """
import signal
import sys
from pathlib import Path
from starforge.cad import step_worker
from starforge.errors import StarforgeError

fork = sys.argv[3] == "forked"
idle = step_worker.StepProcess(fork=fork)
idle.kill()
worker = step_worker.StepProcess(fork=fork)
worker.proc.kill()
worker.send(step_worker.job_for([], [], [], Path(sys.argv[2])))
try:
    worker.result()
except StarforgeError as exc:
    print(idle.proc.returncode is not None, worker.forked, worker.proc.returncode == -signal.SIGKILL, exc)
"""


def _fresh(script: str, tmp_path, how: str) -> str:
    """The last line ``script`` prints, run in a fresh interpreter (a worker is forked only
    from a process without OCP loaded; this one may have it from other tests)."""
    import subprocess
    import sys

    res = subprocess.run(
        [sys.executable, "-c", script, str(DATA), str(tmp_path), how], check=True, capture_output=True, text=True
    )
    return res.stdout.strip().splitlines()[-1]


@pytest.mark.parametrize("how", ["forked", pytest.param("launched", marks=pytest.mark.slow)])
def test_a_worker_error_is_one_clear_error(tmp_path, how):
    """The worker's StarforgeError (here: an unwritable folder) comes back as the parent's."""
    forked, code, message = _fresh(WORKER_ERROR, tmp_path, how).split(" ", 2)
    assert forked == str(how == "forked") and code == "1"
    assert message.startswith("could not write STEP file")


@pytest.mark.parametrize("how", ["forked", pytest.param("launched", marks=pytest.mark.slow)])
def test_a_crashing_worker_is_reported_and_reaped(tmp_path, how):
    """A worker that dies without a word (here: killed before its job) is one clear error with
    its exit status, and nothing is left running; a worker never given a job is ended by kill()."""
    import signal

    line = _fresh(CRASHING_WORKER, tmp_path, how)
    assert line.startswith(f"True {how == 'forked'} True STEP export failed (exit status {-signal.SIGKILL})")


def test_a_fork_beside_a_loaded_kernel_is_refused():
    """A worker forked from a process with OCP loaded would inherit a kernel whose thread pool
    is gone: refused with the options that work."""
    from starforge.cad import step_worker
    from starforge.cad.brep import kernel

    kernel()
    with pytest.raises(ValueError, match="pass fork=False or None"):
        step_worker.StepProcess(fork=True)


def test_a_mesh_failure_stops_the_worker(tmp_path, monkeypatch):
    """When the mesh side fails, the worker is killed before the error leaves export_family."""
    import starforge.cad.export as export_mod
    from starforge.cad import step_worker
    from starforge.errors import StarforgeError

    jobs = []
    real_start = step_worker.start
    monkeypatch.setattr(step_worker, "start", lambda *a, **k: jobs.append(real_start(*a, **k)) or jobs[-1])

    def boom(*args, **kwargs):
        raise StarforgeError("mesh side failed")

    monkeypatch.setattr(export_mod, "_mesh_bodies", boom)
    with pytest.raises(StarforgeError, match="mesh side failed"):
        export_family(load_family(DATA), tmp_path, load_mount("flat"), BodySpec(), ids=[1, 2])
    assert len(jobs) == 1
    assert jobs[0].proc.returncode is not None  # ended (killed), not left running
    assert jobs[0].proc.returncode != 0 or jobs[0].finished


IMPORTS = """
import sys
from pathlib import Path
from starforge import load_family
from starforge.cad.body import BodySpec
from starforge.cad.export import export_family
from starforge.cad.mounts import load_mount
export_family(load_family(sys.argv[1]), Path(sys.argv[2]), load_mount("flat"), BodySpec(), ids=[1])
print(sorted(m for m in ("build123d", "OCP", "trimesh", "scipy") if m in sys.modules))
"""


@pytest.mark.slow
def test_the_exporting_process_loads_no_cad_kernel(tmp_path):
    """STEP, STL and 3MF of a star without build123d, OCP, trimesh or scipy in the exporting
    process (build123d takes seconds to import): the kernel loads in the STEP worker."""
    import subprocess
    import sys

    res = subprocess.run(
        [sys.executable, "-c", IMPORTS, str(DATA), str(tmp_path)], check=True, capture_output=True, text=True
    )
    assert res.stdout.strip().splitlines()[-1] == "[]"
    assert sorted(p.name for p in tmp_path.glob("star_001.*")) == ["star_001.3mf", "star_001.step", "star_001.stl"]


KERNEL = """
import sys
from starforge.cad.brep import kernel
bd = kernel()
heavy = ("build123d", "sklearn", "ezdxf", "scipy.optimize", "scipy.spatial", "IPython", "requests", "threejs_materials")
slim = sorted(m for m in heavy if m in sys.modules)
# deferred names work at their first use: a convex hull (scipy.spatial) of two circles
circles = [bd.Edge.make_circle(1.0), bd.Edge.make_circle(1.0).moved(bd.Location((5.0, 0.0, 0.0)))]
hull = bd.Wire.make_convex_hull(circles)
import scipy.optimize
real = callable(scipy.optimize.minimize_scalar) and type(scipy.optimize).__name__ == "module"
import build123d
same = all(getattr(build123d, n) is getattr(bd, n) for n in ("Solid", "Compound", "Location", "export_step"))
print(slim, same, type(bd).__name__, round(hull.length, 6), real)
"""


@pytest.mark.slow
def test_the_worker_kernel_is_build123d_without_its_package_init():
    """kernel() in a fresh interpreter loads the build123d modules the bodies use and not the
    package's other importers (scikit-learn, ezdxf) nor the modules its kernel modules import
    for calls the bodies never make (scipy's optimiser and hulls, IPython, requests); a deferred
    name still works when used (a convex hull: two circles of radius 1, centres 5 apart, wrapped
    by two half circles and two segments), a later ``import scipy.optimize`` is the real module,
    and a later ``import build123d`` gives the very same classes."""
    import math
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-c", KERNEL], check=True, capture_output=True, text=True)
    slim, rest = res.stdout.strip().splitlines()[-1].split("] ")
    assert slim == "["
    same, kind, length, real = rest.split()
    assert (same, kind, real) == ("True", "SimpleNamespace", "True")
    assert math.isclose(float(length), 2 * math.pi + 10, rel_tol=1e-3)


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["export", "fam"], True),
        (["-q", "export", "fam", "--out", "o"], True),
        (["export", "fam", "--format", "stl,STEP"], True),
        (["export", "fam", "--format=step"], True),
        (["export", "fam", "--format", "step", "--format", "stl,3mf"], False),  # the last one counts
        (["export", "fam", "--format", "stl,3mf,qtm"], False),
        (["export", "--help"], False),
        (["export", "fam", "-h"], False),
        (["stars", "--count", "25"], False),
        (["--scheduler", "host", "export", "fam"], False),  # a root option's value: judged no
        ([], False),
    ],
)
def test_the_console_script_starts_a_step_worker_only_for_step_exports(argv, expected):
    from starforge.__main__ import exports_step

    assert exports_step(argv) is expected


EARLY = """
import sys
from pathlib import Path
from starforge.cad import step_worker
step_worker.start_early()
step_worker.start_early()  # one early worker, however often asked
early = step_worker._early[0]
first, second = step_worker.launch(), step_worker.launch()
print(first is early, second is not early, first.forked)
from starforge import load_family
from starforge.cad.body import BodySpec
from starforge.cad.export import export_family
from starforge.cad.mounts import load_mount
second.kill()
rep = export_family(load_family(sys.argv[1]), Path(sys.argv[2]), load_mount("flat"), BodySpec(), ids=[1],
                    plate=False, step_worker=first)
print(sorted(rep.files))
"""


@pytest.mark.slow
def test_the_early_worker_is_handed_out_once_and_builds_the_export(tmp_path):
    """start_early() launches one worker, the first launch() hands it out (a later one launches a
    new worker), and the early worker writes the export's STEP file."""
    import subprocess
    import sys

    res = subprocess.run(
        [sys.executable, "-c", EARLY, str(DATA), str(tmp_path)], check=True, capture_output=True, text=True
    )
    flags, files = res.stdout.strip().splitlines()[-2:]
    assert flags == "True True True"
    assert files == str(["bodies.json", "star_001.3mf", "star_001.step", "star_001.stl"])
