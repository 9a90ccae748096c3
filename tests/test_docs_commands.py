"""Every command of every docs page's ```bash block runs as a reader types it.

Each page runs in a fresh folder, its commands in page order, through the real CLI (``starforge``
is ``python -m starforge`` of this tree), each with exit code 0 and no traceback.  The files a page
assumes the reader has (a mesh of their prop, their lab's tracker files, a recording) are made
first, honestly: meshes in mm from trimesh primitives, tracker files by ``starforge export`` and
``starforge convert`` from a small family, a recording by the project's C3D writer.  A command
that needs a file no earlier command writes and no maker below provides fails the test, naming
the file.  The README's two install commands (which CI runs first) are the only ones left out.
"""

from __future__ import annotations

import glob
import importlib.util
import os
import re
import resource
import shlex
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from starforge.tracking.formats.bodycsv import plain_csv
from starforge.tracking.recording import simulate_recording, write_c3d

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
_spec = importlib.util.spec_from_file_location("readme_commands", ROOT / ".ci" / "readme_commands.py")
readme_commands = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(readme_commands)

#: the README's set-up commands (pip install ...), which CI runs first in a fresh venv
INSTALLS = readme_commands.readme_commands((ROOT / "README.md").read_text(encoding="utf-8"), "setup")
#: the contributor's page: .ci/run runs its commands in the clone (this test among them)
DEVELOPMENT = DOCS / "development.md"
#: what a file argument ends with
FILE_SUFFIXES = (".stl", ".obj", ".ply", ".glb", ".off", ".rom", ".xml", ".vsk", ".ini", ".motive", ".csv",
                 ".tsv", ".c3d", ".json", ".toml")
#: options whose value is a file or folder a command writes
OUTPUT_OPTIONS = ("--out", ">")
#: a placeholder in a docs command -> what the test types for it
PLACEHOLDERS = {"HEAD": "127.0.0.1", "0.0.0.0": "127.0.0.1"}
#: commands that serve until stopped: started in the background, stopped after the page
BACKGROUND = ("dask scheduler", "dask worker")
#: the scheduler port in the docs, replaced by a free one
DASK_PORT = "8786"
#: the slowest command the test allows on a loaded 2-core machine, s
COMMAND_TIMEOUT_S = 600


def _pages() -> list[Path]:
    return [p for p in sorted(DOCS.rglob("*.md"))
            if p != DEVELOPMENT and any(readme_commands.page_commands(p.read_text(encoding="utf-8")))]


# --- the files the pages assume (mm, as the pages' --units mm says) ---------------------------------

def _union(parts: list[trimesh.Trimesh]) -> trimesh.Trimesh:
    return trimesh.boolean.union(parts, engine="manifold")


def _at(x: float, y: float, z: float, rotation=None) -> np.ndarray:
    T = np.eye(4) if rotation is None else rotation.copy()
    T[:3, 3] = (x, y, z)
    return T


def _quad(folder: Path) -> None:
    """A quadcopter frame, 290 mm motor to motor: a centre plate, two crossed arms, four motors."""
    parts = [trimesh.creation.box((100, 100, 24))]
    for angle in (np.pi / 4, -np.pi / 4):
        R = trimesh.transformations.rotation_matrix(angle, (0, 0, 1))
        parts.append(trimesh.creation.box((320, 18, 12), transform=_at(0, 0, 0, R)))
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(trimesh.creation.cylinder(14, 22, sections=48, transform=_at(sx * 103, sy * 103, 10)))
    _union(parts).export(folder / "quad.stl")


def _mallet(folder: Path) -> None:
    """A mallet as a scan would give it: a 260 mm handle and a 120 mm head (scan.obj)."""
    handle = trimesh.creation.cylinder(14, 260, sections=48, transform=_at(0, 0, 130))
    head = trimesh.creation.box((120, 45, 45), transform=_at(0, 0, 280))
    _union([handle, head]).export(folder / "scan.obj")


def _grip_area(folder: Path) -> None:
    """The mallet's striking face, where no marker may go (grip.stl)."""
    trimesh.creation.box((12, 55, 55), transform=_at(60, 0, 280)).export(folder / "grip.stl")


def _drill(folder: Path) -> None:
    """A cordless drill: motor body, chuck, handle and battery (drill.stl)."""
    Ry = trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0))
    parts = [trimesh.creation.cylinder(32, 170, sections=48, transform=_at(0, 0, 200, Ry)),
             trimesh.creation.cylinder(13, 45, sections=48, transform=_at(105, 0, 200, Ry)),
             trimesh.creation.box((40, 32, 160), transform=_at(-30, 0, 110)),
             trimesh.creation.box((90, 70, 40), transform=_at(-30, 0, 20))]
    _union(parts).export(folder / "drill.stl")


def _mug(folder: Path) -> None:
    """A mug: an 80 mm cup, its wall 4 mm, and a ring handle (mug.stl)."""
    cup = trimesh.boolean.difference(
        [trimesh.creation.cylinder(40, 95, sections=64, transform=_at(0, 0, 47.5)),
         trimesh.creation.cylinder(36, 95, sections=64, transform=_at(0, 0, 53.5))], engine="manifold",
    )  # fmt: skip
    Rx = trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0))
    handle = trimesh.creation.torus(30, 7, transform=_at(45, 0, 50, Rx))
    _union([cup, handle]).export(folder / "mug.stl")


def _wand_mm() -> np.ndarray:
    """A calibration-wand-like tool: five markers on a T, mm, not in one plane."""
    return np.array([[0, 0, 0], [140, 0, 0], [300, 0, 4], [0, 95, 0], [0, -180, 8]], dtype=float)


def _starforge(args: str, folder: Path) -> None:
    _run(f"starforge {args}", folder)


def _lab(folder: Path) -> None:
    """A lab's tracker files: three NDI tools (lab/probe.rom, frame.rom, pointer.rom), two more as
    QTM files in lab/tools/, the last of them also as a Vicon object (lab/tools.vsk), and a
    five-marker wand (lab/wand.xml), written by starforge's own writers."""
    _starforge("stars --box 60 40 90 --marker 9.5 --delta 6 --count 5 --name labfamily --out made -q", folder)
    _starforge("export made/family.json --format rom,qtm,vsk --noise 0.25 --out made/files -q", folder)
    (folder / "lab" / "tools").mkdir(parents=True)
    roms = sorted((folder / "made" / "files" / "rom").glob("*.rom"))
    for src, name in zip(roms, ("probe", "frame", "pointer"), strict=False):
        src.rename(folder / "lab" / f"{name}.rom")
    for src in sorted((folder / "made" / "files" / "qtm").glob("*.xml"))[3:]:
        src.rename(folder / "lab" / "tools" / src.name)
    sorted((folder / "made" / "files" / "vsk").glob("*.vsk"))[-1].rename(folder / "lab" / "tools.vsk")
    (folder / "made" / "wand.csv").write_text(plain_csv([("wand", _wand_mm())]), encoding="utf-8")
    _starforge("convert made/wand.csv --format qtm --out made/wand -q", folder)
    (folder / "made" / "wand" / "wand.xml").rename(folder / "lab" / "wand.xml")


def _session(folder: Path) -> None:
    """A 10 s, 100 Hz C3D recording of the wand (labels W1-W5) and three 4-marker tools (session.c3d)."""
    rng = np.random.default_rng(31)
    tools = [rng.uniform(-40, 40, (4, 3)) + np.arange(4)[:, None] * 15.0 for _ in range(3)]
    rec = simulate_recording([_wand_mm(), *tools], 1000, 0.1, 0.02, rng, rate_hz=100.0)
    labels = [f"W{int(lab.split('_M')[1])}" if lab.startswith("B1_") else lab for lab in rec.labels]
    write_c3d(folder / "session.c3d", labels, rec.points_mm, rec.rate_hz)


def _finger(folder: Path) -> None:
    """out/finger/: what the README's first command writes (`starforge stars`)."""
    _starforge("stars -q", folder)


def _finger25(folder: Path) -> None:
    """out/finger25/: the family the README's tour makes (its first command, without pictures)."""
    _starforge("stars --count 25 --name finger25 --mount flat -q", folder)


def _hammer(folder: Path) -> None:
    """out/hammer/: a placement on the built-in hammer."""
    _starforge("place --out out/hammer -q", folder)


def _expert(folder: Path) -> None:
    """A hand-made layout on the built-in umbrella (expert.csv, metres, prop frame): six markers
    on its canopy, a sphere of radius 0.6 m about (0, 0, 0.3) m, at uneven polar and azimuth
    angles so that no two markers mirror each other, with the canopy's outward normals."""
    polar = np.radians([12.0, 24.0, 33.0, 41.0, 47.0, 52.0])
    azimuth = np.radians([0.0, 95.0, 160.0, 230.0, 290.0, 335.0])
    n = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    p = np.array([0.0, 0.0, 0.30]) + 0.60 * n
    rows = ["id,x_m,y_m,z_m,nx,ny,nz"] + [
        ",".join([str(i + 1), *(f"{v:.6f}" for v in (*pi, *ni))]) for i, (pi, ni) in enumerate(zip(p, n, strict=True))]
    (folder / "expert.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")


#: a file a page assumes -> its maker (a path under lab/ is made with the whole lab)
MAKERS = {"quad.stl": _quad, "scan.obj": _mallet, "grip.stl": _grip_area, "drill.stl": _drill, "mug.stl": _mug,
          "lab": _lab, "session.c3d": _session, "out/finger/family.json": _finger,
          "out/finger25/family.json": _finger25, "out/hammer/placement.json": _hammer,
          "expert.csv": _expert}


# --- running a page --------------------------------------------------------------------------------

def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env["SF_PYTHON"] = sys.executable
    env.setdefault("MPLBACKEND", "Agg")
    return env


#: `starforge` and `dask` as the reader's shell has them, from this tree and this interpreter
PRELUDE = ('set -e -o pipefail; starforge() { "$SF_PYTHON" -m starforge "$@"; }; '
           'dask() { "$SF_PYTHON" -m dask "$@"; }; ')


def _run(command: str, folder: Path) -> tuple[float, float]:
    """Run ``command`` in ``folder`` as the reader's shell would; (wall s, CPU s of its processes)."""
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(["bash", "-c", PRELUDE + command], cwd=folder, env=_env(), capture_output=True,
                          text=True, timeout=COMMAND_TIMEOUT_S)
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    assert proc.returncode == 0, f"`{command}` exited {proc.returncode}:\n{proc.stderr[-3000:]}"
    assert "Traceback" not in proc.stderr, f"`{command}` printed a traceback:\n{proc.stderr[-3000:]}"
    return wall, cpu


def _file_arguments(command: str) -> tuple[list[str], list[str]]:
    """(files the command reads, files or folders it writes), as the words of ``command`` name them."""
    words = shlex.split(command)
    reads, writes = [], []
    for i, word in enumerate(words):
        if i and words[i - 1] in OUTPUT_OPTIONS:
            writes.append(word)
        elif word.endswith(FILE_SUFFIXES) or (word.startswith("lab/") and word != "lab/"):
            reads.append(word)
    return reads, writes


def _provide(command: str, folder: Path) -> None:
    """Make the files ``command`` reads that no earlier command wrote; fail on one nothing makes."""
    reads, _ = _file_arguments(command)
    for word in reads:
        if glob.glob(str(folder / word)):
            continue
        key = "lab" if word.startswith("lab/") else word
        maker = MAKERS.get(key)
        assert maker is not None, (
            f"`{command}` reads {word}, which no earlier command on its page writes and the test cannot "
            f"make: add a maker for it to MAKERS in {Path(__file__).name}")
        t0 = time.perf_counter()
        maker(folder)
        print(f"{time.perf_counter() - t0:7.1f} s wall (made {word})", flush=True)
        assert glob.glob(str(folder / word)), f"the maker for {word} did not write it"


def _edits(page: str) -> dict[str, list[tuple[str, str]]]:
    """The edits a page asks of a file it has the reader write: ``cmd > X.toml`` followed in its
    block by comment lines ``#   key = value`` -> {X.toml: [(key, value), ...]}."""
    edits: dict[str, list[tuple[str, str]]] = {}
    target = None
    for line in page.splitlines():
        written = re.search(r">\s*(\S+\.toml)\s*$", line)
        edit = re.match(r"#\s+(\w+)\s*=\s*([^#\s]+)", line.strip())
        if written:
            target = written.group(1)
        elif edit and target:
            edits.setdefault(target, []).append(edit.groups())
        elif not line.strip().startswith("#"):
            target = None
    return edits


def _apply_edits(path: Path, edits: list[tuple[str, str]]) -> None:
    """Set each ``key = value`` in the TOML file, as the reader does in an editor."""
    text = path.read_text(encoding="utf-8")
    for key, value in edits:
        text, n = re.subn(rf"(?m)^\s*#?\s*{key}\s*=.*$", f"{key} = {value}", text, count=1)
        assert n == 1, f"{path.name} has no `{key} =` line for the page's edit"
    path.write_text(text, encoding="utf-8")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, proc: subprocess.Popen, timeout_s: float = 60.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        assert proc.poll() is None, f"the dask scheduler exited {proc.returncode}"
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    raise AssertionError(f"the dask scheduler did not listen on port {port} in {timeout_s} s")


def _stop(proc: subprocess.Popen) -> None:
    """End a background command's session: SIGTERM, then SIGKILL after 30 s."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _typed(command: str, port: int) -> str:
    """The command as the test types it: placeholders filled in, the free port for the docs' one."""
    for word, value in PLACEHOLDERS.items():
        command = command.replace(word, value)
    return command.replace(DASK_PORT, str(port))


@pytest.mark.slow
@pytest.mark.parametrize("page", _pages(), ids=lambda p: str(p.relative_to(DOCS)))
def test_every_command_of_the_page_runs(page, tmp_path):
    text = page.read_text(encoding="utf-8")
    commands = [c for block in readme_commands.page_commands(text) for c in block]
    commands = [c for c in commands if c not in INSTALLS]
    assert commands, f"{page.name} has ```bash blocks but no command the test runs"
    edits = _edits(text)
    port = _free_port()
    background: list[subprocess.Popen] = []
    try:
        for command in commands:
            typed = _typed(command, port)
            if typed.startswith(BACKGROUND):
                with open(tmp_path / f"background-{len(background)}.log", "wb") as log:
                    proc = subprocess.Popen(["bash", "-c", PRELUDE + typed], cwd=tmp_path, env=_env(),
                                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
                background.append(proc)
                if typed.startswith("dask scheduler"):
                    _wait_for_port(port, proc)
                continue
            _provide(typed, tmp_path)
            wall, cpu = _run(typed, tmp_path)
            print(f"{wall:7.1f} s wall {cpu:7.1f} s CPU  {page.relative_to(DOCS)}: {command}", flush=True)
            for written, changes in edits.items():
                if written in _file_arguments(command)[1]:
                    _apply_edits(tmp_path / written, changes)
        for proc in background:
            assert proc.poll() is None, f"a background command exited {proc.returncode}"
    finally:
        for proc in background:
            _stop(proc)


def test_the_install_commands_the_pages_leave_out_are_the_readmes():
    """The pages' install commands are the README's, which CI runs in a fresh venv."""
    for page in _pages():
        for block in readme_commands.page_commands(page.read_text(encoding="utf-8")):
            for command in block:
                assert "pip install" not in command or command in INSTALLS, (page.name, command)



@pytest.mark.slow
def test_the_readmes_docs_server_serves(tmp_path):
    """The README's ``mkdocs serve`` (after ``pip install -e ".[docs]"``, which CI's development
    step has run) builds the site and answers its home page."""
    import urllib.request

    pytest.importorskip("mkdocs", reason="the docs extra is not installed")
    port = _free_port()
    with open(tmp_path / "serve.log", "wb") as log:
        proc = subprocess.Popen(["mkdocs", "serve", "--dev-addr", f"127.0.0.1:{port}"], cwd=ROOT, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        t0, page = time.monotonic(), b""
        while time.monotonic() - t0 < COMMAND_TIMEOUT_S and proc.poll() is None and not page:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=5) as res:
                    page = res.read() if res.status == 200 else b""
            except OSError:
                time.sleep(0.5)
        said = (tmp_path / "serve.log").read_text(errors="replace")[-2000:]
        assert b"starforge" in page.lower(), f"mkdocs serve gave no home page (exit {proc.poll()}): {said}"
    finally:
        _stop(proc)
