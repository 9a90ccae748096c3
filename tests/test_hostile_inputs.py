"""Hostile inputs across every command: one clear line, exit 2, nothing written, bounded memory.

Each case runs the real CLI in a child process whose address space is capped at 2 GiB
(``resource.setrlimit``) with starforge's own memory limit at 1 GiB and a 60 s wall clock, so a
case that tried to allocate or loop without bound would fail here instead of passing by
accident.  Each case asserts:

* the exit code (2 for a refusal; a few inputs are legitimate and give 0 with a correct result),
* stderr: exactly one line, ``error: ...``, matching the case's pattern, and no traceback,
* the output folder: byte-for-byte as it was (a sentinel file and an old output stay), and no
  stage or temp folder left beside it.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import textwrap
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import run_cli

CHILD = textwrap.dedent(
    """
    import sys
    sys.argv[0] = "starforge"  # as the console script: its file's name, seen from the first import on
    import starforge  # its signal handlers first, as the console script has them
    import atexit, os, resource, signal
    if os.environ.get("HOSTILE_AS_USER") and os.geteuid() == 0:  # file permissions hold, as for a user
        import ctypes
        caps = (ctypes.c_uint32 * 6)()  # effective, permitted, inheritable; twice (capabilities 0-63)
        head = (ctypes.c_uint32 * 2)(0x20080522, 0)
        libc = ctypes.CDLL(None, use_errno=True)
        libc.capget(head, caps)
        for i in range(3):
            caps[i] &= ~0b110  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH
        assert libc.capset(head, caps) == 0
    cap = int(os.environ.get("HOSTILE_AS_BYTES", 2 * 1024 ** 3))  # the address space a case may map
    resource.setrlimit(resource.RLIMIT_AS, (cap, cap))
    if os.environ.get("HOSTILE_FILE_BYTES"):  # a full disk: writes past this size fail (EFBIG)
        n = int(os.environ["HOSTILE_FILE_BYTES"])
        resource.setrlimit(resource.RLIMIT_FSIZE, (n, n))
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)

    def peak():  # the peak memory, for the benchmark's report
        with open(os.environ["HOSTILE_RSS_FILE"], "w") as fh:
            fh.write(str(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss))

    if os.environ.get("HOSTILE_RSS_FILE"):
        atexit.register(peak)
    from starforge.__main__ import run
    run()  # as the console script: it ends the process the way a user's run ends
    """
)
LIMIT_S = 60
#: the time budget of each case added with the bounded readers and the cluster client, s
#: (a refusal takes 1-3 s here; the budget leaves room for a loaded machine)
BUDGET_S = 20
#: set by benchmarks/bench_hostile.py: a JSON line per case (clean, seconds, peak memory) goes there
REPORT = os.environ.get("STARFORGE_HOSTILE_REPORT")


@dataclass(frozen=True)
class Case:
    id: str
    args: tuple
    pattern: str
    code: int = 2
    uses_out: bool = True
    env: dict = field(default_factory=dict)
    budget_s: float = LIMIT_S
    #: for a correct result (code 0): ``verify(out folder, stderr)`` checks what was written
    verify: object = None
    #: ``setup(work folder)``: what the user had made there before the run (old outputs, a file
    #: where a folder is expected...), part of what must be as it was afterwards
    setup: object = None
    #: what sort of case it is, for the benchmark's counts per kind
    kind: str = "input"


def left_in_session(sid: int) -> list[int]:
    """Processes still running (zombies excluded) in the session ``sid``: a command started with
    ``start_new_session`` leaves none once it has exited."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[3]) == sid and fields[0] != "Z":
            found.append(int(stat.parent.name))
    return found


@dataclass(frozen=True)
class ChildRun:
    """What a child run of the CLI did: its result, wall and CPU seconds (its own and its
    helpers' that it waited for), peak memory (kB, or None) and the processes it left."""

    res: subprocess.CompletedProcess
    seconds: float
    cpu_seconds: float
    peak_kb: int | None
    left: list


def run_child(args, cwd, env, budget_s: float) -> ChildRun:
    """Run the CLI in a child (its own session, address space capped) within ``budget_s``."""
    import resource

    rss = Path(cwd) / ".hostile-rss"
    usage0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with subprocess.Popen(
        [sys.executable, "-c", CHILD, *map(str, args)], cwd=cwd, env={**env, "HOSTILE_RSS_FILE": str(rss)},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    ) as proc:
        try:
            out, err = proc.communicate(timeout=budget_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, 9)
            proc.communicate()
            raise AssertionError(f"no answer within {budget_s} s: {list(args)[:6]}") from None
    seconds = time.perf_counter() - t0
    usage1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (usage1.ru_utime + usage1.ru_stime) - (usage0.ru_utime + usage0.ru_stime)
    time.sleep(0.05)  # a helper killed as the command ended is reaped by then
    peak = int(rss.read_text()) if rss.exists() else None
    rss.unlink(missing_ok=True)
    res = subprocess.CompletedProcess(proc.args, proc.returncode, out, err)
    return ChildRun(res, seconds, cpu, peak, left_in_session(proc.pid))


def snapshot(folder: Path) -> dict:
    return {
        str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None)
        for p in sorted(folder.rglob("*"))
    }


@pytest.fixture(scope="module")
def files(tmp_path_factory, small_family):
    """Hostile input files, made once: families edited by hand, meshes in the wrong units..."""
    d = tmp_path_factory.mktemp("hostile")
    _, fam = small_family

    def family(name, edit):
        doc = json.loads(json.dumps(fam))
        edit(doc)
        p = d / f"{name}.json"
        p.write_text(json.dumps(doc))
        return p

    def scale(k):
        def edit(doc):
            s = doc["stars"][0]
            s["vertices"] = (np.asarray(s["vertices"]) * k).tolist()
            s["lengths"] = {n: v * k for n, v in s["lengths"].items()}

        return edit

    def contradict(doc):
        doc["stars"][0]["vertices"][3][2] += 5.0

    def coincide(doc):
        s = doc["stars"][0]
        s["vertices"][1] = list(s["vertices"][0])

    def inch(doc):
        doc["units"] = "inch"

    out = {
        "good": family("good", lambda doc: None),
        "x300": family("x300", scale(300.0)),
        "x1e6": family("x1e6", scale(1e6)),
        "contradict": family("contradict", contradict),
        "coincident": family("coincident", coincide),
        "inch": family("inch", inch),
        "no_stars": family("no_stars", lambda doc: doc.update(stars=[])),
    }
    (d / "corrupt.json").write_text('{"format": "starforge.family", "stars": [')
    out["corrupt"] = d / "corrupt.json"
    (d / "list.json").write_text("[1, 2, 3]")
    out["list"] = d / "list.json"
    (d / "garbage.stl").write_bytes(b"solid x\nthis is not an stl\n" * 10)
    out["garbage_stl"] = d / "garbage.stl"
    (d / "empty.obj").write_text("")
    out["empty_obj"] = d / "empty.obj"
    (d / "bad.toml").write_text("box_mm = [20.8, 12.6\n")
    out["bad_toml"] = d / "bad.toml"
    (d / "wrongtype.toml").write_text('box_mm = [20.8, 12.6, 48.3]\ncount = "many"\n')
    out["wrongtype_toml"] = d / "wrongtype.toml"
    (d / "unknownkey.toml").write_text("box_mm = [20.8, 12.6, 48.3]\nsize = 3\n")
    out["unknownkey_toml"] = d / "unknownkey.toml"

    import trimesh

    # a 100 x 200 x 50 mm box saved in millimetres (read as metres unless --units mm)
    trimesh.creation.box(extents=(100.0, 200.0, 50.0)).export(d / "box_mm.stl")
    out["box_mm"] = d / "box_mm.stl"
    trimesh.creation.box(extents=(0.16e-3, 0.1e-3, 0.1e-3)).export(d / "speck.stl")
    out["speck"] = d / "speck.stl"
    (d / "far.csv").write_text("id,x_m,y_m,z_m\n1,100,0,0\n2,100,0.1,0\n3,100,0,0.1\n4,100.1,0,0\n")
    out["far_csv"] = d / "far.csv"
    # a spec saved by a Windows editor (byte-order mark); its box is too small, refused after reading
    (d / "bom.toml").write_bytes(b"\xef\xbb\xbfbox_mm = [3, 3, 3]\n")
    out["bom_toml"] = d / "bom.toml"
    os.mkfifo(d / "fifo")
    out["fifo"] = d / "fifo"
    out["id_negative"] = family("id_negative", lambda doc: doc["stars"][0].update(id=-1))
    out["id_huge"] = family("id_huge", lambda doc: doc["stars"][0].update(id=1e30))

    def many(doc):  # about 10,000 stars: the star list repeated, ids renumbered
        stars = doc["stars"]
        doc["stars"] = [{**stars[k % len(stars)], "id": k + 1} for k in range(10_000)]

    out["family_10k"] = family("family_10k", many)
    big = trimesh.creation.box(extents=(0.1, 0.2, 0.05))
    big.apply_scale(1e30)
    big.export(d / "x1e30.stl")
    out["mesh_x1e30"] = d / "x1e30.stl"
    small = trimesh.creation.capsule(height=0.3, radius=0.03)
    small.apply_scale(0.001)
    small.export(d / "x0.001.stl")
    out["mesh_x0001"] = d / "x0.001.stl"
    # a binary STL that says it holds 5 M faces (250 MB, sparse: no disk used): refused from its size
    with open(d / "faces5m.stl", "wb") as fh:
        fh.write(b"\0" * 80 + (5_000_000).to_bytes(4, "little"))
        fh.truncate(84 + 50 * 5_000_000)
    out["mesh_5m"] = d / "faces5m.stl"
    # 1.5 GB files of every kind a reader takes (sparse: no disk used), refused from their size
    for key, name in (("big_json", "big.json"), ("big_toml", "big.toml"), ("big_csv", "big.csv"),
                      ("big_mask", "big_mask.txt"), ("big_xml", "big.xml")):
        with open(d / name, "wb") as fh:
            fh.truncate(1500 * 2**20)
        out[key] = d / name
    (d / "loop_a").symlink_to(d / "loop_b")
    (d / "loop_b").symlink_to(d / "loop_a")
    (d / "loop.json").symlink_to(d / "loop_a")
    (d / "loop.stl").symlink_to(d / "loop_a")
    out["loop_json"], out["loop_stl"] = d / "loop.json", d / "loop.stl"
    (d / "underscore.xml").write_text(
        '<QTM_Body_File_Ver_1.00><Bodies><Body><Name>probe</Name><Points><Point X="1_0" Y="0" Z="0"/>'
        '<Point X="50" Y="0" Z="0"/><Point X="0" Y="35" Z="0"/><Point X="0" Y="0" Z="22"/></Points></Body>'
        "</Bodies></QTM_Body_File_Ver_1.00>"
    )
    out["qtm_underscore"] = d / "underscore.xml"
    (d / "collinear.csv").write_text(
        "body,marker,x_mm,y_mm,z_mm\nA,1,0,0,0\nA,2,10,0,0\nA,3,25,0,0\n"
        "B,1,0,0,0\nB,2,12,0,0\nB,3,12,20,0\nB,4,0,5,30\n"
    )
    out["collinear_csv"] = d / "collinear.csv"
    sock = socket.socket()  # a port nothing listens on (bound, then released)
    sock.bind(("127.0.0.1", 0))
    out["closed_port"] = Path(f"127.0.0.1:{sock.getsockname()[1]}")
    sock.close()
    return out


def _cases(f) -> list[Case]:
    fam = str(f["good"])
    return [
        # stars
        Case("stars-delta-denormal", ("stars", "--delta", "1e-310"), r"delta"),
        Case("stars-delta-negative", ("stars", "--delta", "-1.5"), r"--delta must be > 0"),
        Case("stars-delta-nan", ("stars", "--delta", "nan"), r"delta"),
        Case("stars-delta-tiny", ("stars", "--delta", "0.01"), r"(memory|would take|pool)"),
        Case("stars-box-too-small", ("stars", "--box", "3", "3", "3"), r"too small"),
        Case("stars-box-huge", ("stars", "--box", "1e300", "1e300", "1e300"), r"(box|pool|memory|would take)"),
        Case("stars-marker-zero", ("stars", "--marker", "0"), r"marker"),
        Case("stars-name-escapes", ("stars", "--name", "../x"), r"name must be"),
        Case("stars-tolerance-huge", ("stars", "--tolerance", "1000"), r"tolerance"),
        Case("stars-count-impossible", ("stars", "--count", "100000"), r"count"),
        Case("stars-spec-devnull", ("stars", "--spec", "/dev/null"), r"not a regular file"),
        Case("stars-spec-missing", ("stars", "--spec", "nope/missing.toml"), r"not found"),
        Case("stars-spec-corrupt", ("stars", "--spec", str(f["bad_toml"])), r"not valid TOML"),
        Case("stars-spec-wrong-type", ("stars", "--spec", str(f["wrongtype_toml"])), r"count"),
        Case("stars-spec-unknown-key", ("stars", "--spec", str(f["unknownkey_toml"])), r"size"),
        Case("stars-rule-unknown", ("stars", "--rule", "triangle"), r"rule"),
        Case("stars-unknown-template", ("stars", "--spec", "thumb"), r"--spec must be a template name"),
        Case("stars-count-not-int", ("stars", "--count", "lots"), r"count"),
        # the tolerance in pool steps cubes the selection's windows: refused from a pilot sample
        Case("stars-tolerance-windows", ("stars", "--delta", "0.5", "--tolerance", "6", "--min-depth", "0"),
             r"selecting among about .* fitting stars .* memory"),
        # the time estimate comes from a pilot sample of the spec's own stars (several times the 3 s given here)
        Case("stars-pilot-time", ("--max-seconds", "3", "stars", "--delta", "1.0"), r"would take about",
             env={"STARFORGE_MAX_MEMORY": "8G"}),
        # a tolerance of 8 pool steps: the pilot's fitting share times 512 windows per face
        Case("stars-tolerance-8-steps", ("stars", "--delta", "0.5", "--tolerance", "4", "--min-depth", "0"),
             r"selecting among about .* memory", env={"STARFORGE_MAX_MEMORY": "8G"}),
        # export (CAD and tracker files)
        Case("export-missing", ("export", "nope.json"), r"not found"),
        Case("export-corrupt", ("export", str(f["corrupt"])), r"not valid JSON"),
        Case("export-not-object", ("export", str(f["list"])), r"JSON object"),
        Case("export-inch", ("export", str(f["inch"])), r"units"),
        Case("export-contradicting-vertices", ("export", str(f["contradict"])), r"(vertices|lengths)"),
        Case("export-coincident-markers", ("export", str(f["coincident"])), r"(coincid|overlap|distinct|lengths)"),
        Case("export-scaled-x300", ("export", str(f["x300"])), r"(size limit|box|memory|lengths)"),
        Case("export-scaled-x1e6", ("export", str(f["x1e6"])), r"within 100 m"),
        Case("export-no-stars", ("export", str(f["no_stars"])), r"no stars"),
        Case("export-unknown-format", ("export", fam, "--format", "dwg"), r"format"),
        Case("export-unknown-mount", ("export", fam, "--mount", "velcro"), r"mount"),
        Case("export-unknown-id", ("export", fam, "--ids", "999"), r"999"),
        # check
        Case("check-ghosts-200", ("check", fam, "--ghosts", "200", "--frames", "1"), r"ghosts"),
        Case("check-ghosts-million", ("check", fam, "--ghosts", "1000000"), r"ghosts"),
        Case("check-frames-1e20", ("check", fam, "--frames", "100000000000000000000"), r"frames"),
        Case("check-frames-float", ("check", fam, "--frames", "1e20"), r"frames"),
        Case("check-noise-negative", ("check", fam, "--noise", "-1"), r"noise"),
        Case("check-inch-family", ("check", str(f["inch"])), r"units"),
        Case("check-not-a-body-file", ("check", str(f["list"])), r"JSON object"),
        # place
        Case("place-missing-mesh", ("place", "run", "nope.stl"), r"(not found|unknown)"),
        Case("place-garbage-mesh", ("place", "run", str(f["garbage_stl"])), r"(mesh|read|load|faces)"),
        Case("place-empty-mesh", ("place", "run", str(f["empty_obj"])), r"(empty|mesh|faces)"),
        Case("place-mm-as-metres", ("place", "run", str(f["box_mm"])), r"--units mm"),
        Case("place-speck", ("place", "run", str(f["speck"])), r"(--units|smaller than)"),
        Case("place-units-unknown", ("place", "run", "--units", "furlong"), r"units"),
        Case("place-huge-table", ("place", "run", "--resolution", "64", "--orientations", "1000"), r"memory"),
        Case("place-markers-zero", ("place", "run", "--markers", "0"), r"markers"),
        Case("place-standoff-long", ("place", "run", "--standoff", "100"), r"--standoff\) must be in \[0"),
        Case("place-standoff-short", ("place", "run", "--marker", "12.7mm-m3", "--standoff", "3"), r"--standoff 7\.2 or more"),
        Case("place-score-far", ("place", "score", "hammer", str(f["far_csv"])), r"(surface|off)", uses_out=False),
        # sweep, templates, mounts, global limits
        Case("sweep-huge", ("sweep", "--delta", "0.01:0.02:0.01", "--cube", "10:2000:1"), r"cube has 1991 values; at most"),
        # refused up front, for memory or (cells too large to enumerate become intervals) for time
        Case("sweep-pool-memory", ("sweep", "--delta", "0.01:0.02:0.01", "--cube", "40:60:20"),
             r"(memory|would take about [0-9.]+ h, above the limit)"),
        Case("templates-unknown-kind", ("templates", "wands"), r"unknown template kind", uses_out=False),
        Case("mounts-unknown", ("mounts", "velcro"), r"velcro", uses_out=False),
        Case("max-memory-garbage", ("--max-memory", "lots", "stars"), r"--max-memory", uses_out=False),
        # degenerate numbers, encodings, ids and special files
        Case("stars-marker-denormal", ("stars", "--marker", "1e-320"), r"marker diameter must be in \[1, 50\] mm, got 1e-320"),
        *[Case(f"max-seconds-{v}", ("--max-seconds", v, "stars"), r"^error: --max-seconds must be a positive",
               uses_out=False) for v in ("nan", "-1", "inf", "0")],
        Case("stars-spec-bom", ("stars", "--spec", str(f["bom_toml"])), r"--box \[3.0, 3.0, 3.0\] is too small"),
        Case("check-noise-1e308", ("check", fam, "--noise", "1e308"), r"noise must be at most 100 mm"),
        Case("check-same-file-twice", ("check", fam, fam), r"given twice"),
        Case("export-star-id-negative", ("export", str(f["id_negative"]), "--format", "qtm"),
             r"stars\[0\]\.id must be an integer from 1"),
        Case("export-star-id-1e30", ("export", str(f["id_huge"]), "--format", "qtm"), r"from 1 to 999,999, got 1e\+30"),
        Case("export-ids-missing-summarised", ("export", fam, "--ids", "1-1000000"),
             r"(ids .* name 1,000,000 stars; a family holds at most|and [0-9,]+ more not in the family)"),
        Case("export-ids-missing-1000", ("export", fam, "--ids", "1-1000"), r"star ids \d+, .* and [0-9,]+ more not in"),
        Case("preview-ids-huge", ("preview", fam, "--ids", "1-99999999"), r"99,999,999 stars; a family holds at most"),
        *[Case(f"family-10k-{cmd[0]}", ("--max-seconds", "10", *cmd), r"verifying the 10,000 stars .* would take")
          for cmd in (("export", str(f["family_10k"]), "--format", "qtm,csv"), ("check", str(f["family_10k"])),
                      ("preview", str(f["family_10k"])), ("stars", "--box", "16", "12", "24", "--delta", "2", "--avoid", str(f["family_10k"])))],
        Case("place-score-dev-zero", ("place", "score", "hammer", "/dev/zero"), r"markers file /dev/zero is not a regular",
             uses_out=False),
        Case("place-score-fifo", ("place", "score", "hammer", str(f["fifo"])), r"markers file .*fifo is not a regular",
             uses_out=False),
        Case("place-mesh-fifo", ("place", "run", str(f["fifo"])), r"prop mesh .*fifo is not a regular"),
        Case("place-forbid-mesh-missing", ("place", "run", "hammer", "--forbid-mesh", "nope.stl"),
             r"--forbid-mesh file not found: nope.stl"),
        Case("place-forbid-mesh-fifo", ("place", "run", "hammer", "--forbid-mesh", str(f["fifo"])),
             r"--forbid-mesh file .*fifo is not a regular"),
        Case("place-mesh-x1e30", ("place", "run", str(f["mesh_x1e30"])), r"m across read as m: no prop is that large"),
        Case("place-mesh-x0.001", ("place", "run", str(f["mesh_x0001"])), r"smaller than four markers \(38 mm\)"),
        Case("place-5m-faces-64-orientations", ("place", "run", str(f["mesh_5m"]), "--orientations", "64"),
             r"prop mesh .*faces5m.stl \(250 MB\) needs about .* memory"),
        Case("sweep-cube-nan", ("sweep", "--cube", "nan:40:5"), r"cube must hold finite numbers, got 'nan'"),
    ] + [replace(c, budget_s=BUDGET_S, kind="bounded") for c in _bounded_cases(f)]


def _bounded_cases(f) -> list[Case]:
    """The cases of the bounded readers, the cluster client and the checks before work."""
    fam = str(f["good"])
    return [
        # every reader sizes its file first: a limit per kind, named with the file
        Case("export-json-1.5GB", ("export", str(f["big_json"])), r"big.json is 1,500 MB, above the 128 MB a json input"),
        Case("check-json-1.5GB", ("check", str(f["big_json"])), r"big.json is 1,500 MB, above the 128 MB a json input"),
        Case("stars-toml-1.5GB", ("stars", "--spec", str(f["big_toml"])), r"big.toml is 1,500 MB, above the 1 MB a toml"),
        Case("stars-marker-toml-1.5GB", ("stars", "--marker", str(f["big_toml"])), r"above the 1 MB a toml input"),
        Case("mounts-marker-toml-1.5GB", ("mounts", "--marker", str(f["big_toml"])), r"above the 1 MB a toml input",
             uses_out=False),
        Case("place-score-csv-1.5GB", ("place", "score", "hammer", str(f["big_csv"])), r"above the 64 MB a csv input",
             uses_out=False),
        Case("place-mask-1.5GB", ("place", "run", "hammer", "--mask", str(f["big_mask"])), r"above the 128 MB a mask"),
        Case("check-xml-1.5GB", ("check", str(f["big_xml"])), r"above the 128 MB a tracker input"),
        Case("stars-avoid-json-1.5GB", ("stars", "--box", "16", "12", "24", "--avoid", str(f["big_json"])),
             r"--avoid file .*big.json is 1,500 MB"),
        # symbolic-link loops, wherever a file is read
        *[Case(f"symlink-loop-{name}", args, r"loop.(json|stl) is a symbolic link that loops back on itself")
          for name, args in (("export", ("export", str(f["loop_json"]))), ("check", ("check", str(f["loop_json"]))),
                             ("stars-avoid", ("stars", "--avoid", str(f["loop_json"]))),
                             ("place-avoid", ("place", "run", "hammer", "--avoid", str(f["loop_json"]))),
                             ("place-mesh", ("place", "run", str(f["loop_stl"]))),
                             ("place-forbid-mesh", ("place", "run", "hammer", "--forbid-mesh", str(f["loop_stl"]))))],
        # values: plain decimal numbers, finite, in range; bodies a tracker can hold
        Case("check-qtm-underscore-number", ("check", str(f["qtm_underscore"])), r"probe point X is not a number \('1_0'\)"),
        Case("check-collinear-markers", ("check", str(f["collinear_csv"])), r"body A's markers lie on one line"),
        *[Case(f"check-tip-{v}", ("check", fam, "--tip", f"{v},0,0"), r"tip must be three finite numbers within")
          for v in ("nan", "inf", "1e308")],
        Case("mounts-marker-1e308", ("mounts", "--marker", "1e308"), r"marker diameter must be in \[1, 50\] mm",
             uses_out=False),
        # the scheduler address: parsed before anything connects, one line naming the accepted forms
        *[Case(f"scheduler-{name}", ("--scheduler", addr, "stars"),
               r"--scheduler '.*': .*expected tcp://HOST:PORT, HOST:PORT or HOST")
          for name, addr in (("tls", "tls://127.0.0.1:8786"), ("ucx", "ucx://127.0.0.1:8786"), ("inproc", "inproc://x"),
                             ("port-abc", "tcp://127.0.0.1:abc"), ("port-5000-digits", "127.0.0.1:" + "9" * 5000),
                             ("port-0", "127.0.0.1:0"), ("ipv6-bare", "::1"))],
        Case("scheduler-after-stars", ("stars", "--scheduler", "tls://h:1"), r"tls:// is not supported"),
        Case("scheduler-after-sweep", ("sweep", "--scheduler", "h:abc"), r"the port must be a number"),
        Case("scheduler-after-place-batch", ("place-batch", "hammer", "--scheduler", "ucx://h:1"), r"ucx:// is not supported"),
        Case("scheduler-env-garbage", ("stars",), r"^error: STARFORGE_SCHEDULER 'a b': not a scheduler address",
             env={"STARFORGE_SCHEDULER": "a b"}),
        Case("scheduler-closed-port", ("--scheduler", str(f["closed_port"]), "stars"),
             r"cannot reach the dask scheduler at tcp://127.0.0.1:\d+: nothing listens there"),
        # place-batch reads every prop before a job starts
        Case("place-batch-bad-mesh", ("place-batch", "hammer", str(f["garbage_stl"])), r"garbage.stl"),
        Case("place-batch-missing-mesh", ("place-batch", "hammer", "nope.stl"), r"not found: nope.stl"),
        Case("place-batch-standoff-short", ("place-batch", "hammer", "--standoff", "3"), r"--standoff 6\.5 or more"),
    ]


def _case_ids():
    return [c.id for c in _cases({k: Path(k) for k in _FILE_KEYS})]


_FILE_KEYS = (
    "good x300 x1e6 contradict coincident inch no_stars corrupt list garbage_stl empty_obj bad_toml "
    "wrongtype_toml unknownkey_toml box_mm speck far_csv bom_toml fifo id_negative id_huge family_10k "
    "mesh_x1e30 mesh_x0001 mesh_5m big_json big_toml big_csv big_mask big_xml loop_json loop_stl qtm_underscore "
    "collinear_csv closed_port"
).split()
#: the plain progress lines a command prints every few seconds when stderr is not a terminal
PROGRESS = r"^starforge [a-z]+: \d+ s, "


def user_folder(tmp_path: Path, setup=None) -> tuple[Path, Path, dict]:
    """A working folder whose output folder already holds the user's files (and what ``setup``
    makes in it): (work, out, snapshot)."""
    work = tmp_path / "work"
    out = work / "out"
    out.mkdir(parents=True)
    (out / "keep.txt").write_text("a file the user had")
    (out / "mine").mkdir()
    (out / "mine" / "notes.txt").write_text("more of the user's files")
    if setup is not None:
        setup(work)
    return work, out, snapshot(work)


def check_refusal(case: Case, code: int, err: str, work: Path, before: dict) -> str | None:
    """The case's exit code; for a refusal one ``error: ...`` line matching its pattern and the
    working folder byte-for-byte as it was (returns the line); for a correct result (exit 0) the
    user's files as they were, no stage left and the case's own check of what was written (returns
    None); never a traceback."""
    import re

    assert "Traceback" not in err, err
    assert code == case.code, (code, err)
    if case.code == 2:
        lines = [line for line in err.splitlines() if not re.match(PROGRESS, line)]
        assert len(lines) == 1 and lines[0].startswith("error: "), err
        assert re.search(case.pattern, lines[0]), lines[0]
        said = lines[0].split("e.g. starforge ")[0]  # a command to copy may be long: the words may not
        assert len(said) < 400, f"a long error line ({len(said)} characters)"
        assert snapshot(work) == before
        return lines[0]
    after = snapshot(work)
    assert {k: after.get(k) for k in before} == before, "the user's files changed"
    assert not [k for k in after if ".staging" in k or ".tmp" in k], after.keys()
    if case.verify is not None:
        case.verify(work / "out", err)
    return None


#: CPU seconds a case may take (the command and the helpers it waited for): the issue's 10 s,
#: counted in CPU time so that a loaded machine does not fail a case
CPU_BUDGET_S = 10.0


def run_case_in_child(case: Case, tmp_path: Path) -> str | None:
    """A case as a user meets it: its own process, address space capped at 2 GiB, at most
    :data:`CPU_BUDGET_S` CPU seconds and ``case.budget_s`` wall seconds, no process left, no
    traceback or warning; its figures go to the benchmark's report (``REPORT``).  Returns the
    refusal's line (None for a correct result)."""
    work, out, before = user_folder(tmp_path, case.setup)
    args = list(case.args)
    if case.uses_out:
        args += ["--out", str(out)]
    env = {
        **os.environ,
        "STARFORGE_MAX_MEMORY": "1G",
        "OPENBLAS_NUM_THREADS": "1",
        "OMP_NUM_THREADS": "1",
        **case.env,
    }
    clean, run, why, line = False, None, "", None
    try:
        run = run_child(args, work, env, case.budget_s)
        assert "Warning" not in run.res.stderr, run.res.stderr
        line = check_refusal(case, run.res.returncode, run.res.stderr.strip(), work, before)
        assert not run.left, f"processes left running: {run.left}"
        assert run.cpu_seconds <= CPU_BUDGET_S, f"{run.cpu_seconds:.1f} CPU s"
        clean = True
    except AssertionError as exc:
        why = str(exc).splitlines()[0][:300] if str(exc) else "assertion"
        raise
    finally:
        if REPORT:
            row = {"case": case.id, "kind": case.kind, "clean": clean, "seconds": run and run.seconds,
                   "cpu_seconds": run and run.cpu_seconds, "peak_kb": run and run.peak_kb,
                   "code": run and run.res.returncode,
                   "said": run and run.res.stderr.strip().splitlines()[-1:][0][:300] if run and run.res.stderr.strip()
                   else "", "why": why}
            with open(REPORT, "a") as fh:
                fh.write(json.dumps(row) + "\n")
    return line


def run_case_in_process(case: Case, tmp_path: Path, monkeypatch, capsys) -> str | None:
    """A case through the in-process entry point, with the same memory limit and the same
    checks (the process and its address-space cap are what :func:`run_case_in_child` adds).
    Returns the refusal's line (None for a correct result)."""
    from starforge.runtime import budget

    work, out, before = user_folder(tmp_path, case.setup)
    args = list(case.args)
    if case.uses_out:
        args += ["--out", str(out)]
    # set through monkeypatch, so that what --max-memory / --max-seconds write is undone after
    monkeypatch.setenv(budget.ENV_MEMORY, "1G")
    monkeypatch.setenv(budget.ENV_SECONDS, repr(budget.DEFAULT_SECONDS))
    for k, v in case.env.items():
        monkeypatch.setenv(k, v)
    monkeypatch.chdir(work)
    code = run_cli(args)
    return check_refusal(case, code, capsys.readouterr().err.strip(), work, before)


@pytest.mark.slow
@pytest.mark.parametrize("case_id", _case_ids())
def test_hostile_input(case_id, files, tmp_path):
    run_case_in_child({c.id: c for c in _cases(files)}[case_id], tmp_path)


@pytest.mark.parametrize("case_id", _case_ids())
def test_hostile_input_in_process(case_id, files, tmp_path, monkeypatch, capsys):
    run_case_in_process({c.id: c for c in _cases(files)}[case_id], tmp_path, monkeypatch, capsys)


def test_a_good_family_still_exports_under_the_same_limits(files, tmp_path):
    """The limits refuse what is absurd, not what is normal (same child settings)."""
    out = tmp_path / "out"
    res = subprocess.run(
        [sys.executable, "-c", CHILD, "export", str(files["good"]), "--ids", "1", "--format", "stl,qtm", "--allow-oversize", "--out", str(out)],
        env={**os.environ, "STARFORGE_MAX_MEMORY": "1G", "OPENBLAS_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
        timeout=LIMIT_S,
    )
    assert res.returncode == 0, res.stderr
    assert any(p.suffix == ".stl" for p in out.rglob("*"))


def test_cli_in_process_agrees(files, tmp_path):
    """The in-process entry point used by the other tests reports the same refusal."""
    assert run_cli(["export", files["inch"], "--out", tmp_path / "o"]) == 2
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
@pytest.mark.parametrize(
    "args, signame",
    [
        # --delta 1.0 enumerates far longer than the finger default, so 4 s in, the signal lands
        # inside the compiled enumeration
        (("stars", "--delta", "1.0"), "SIGINT"),
        (("place", "run", "hammer", "--orientations", "256", "--sites", "2000"), "SIGINT"),  # long past 4 s
        (("check", "{family}", "--frames", "200000"), "SIGINT"),
        (("stars", "--delta", "1.0"), "SIGTERM"),
        (("export", "{family}", "--allow-oversize", "--preview"), "SIGTERM"),  # signalled once staging
    ],
    ids=["stars", "place", "check", "stars-sigterm", "export-sigterm"],
)
def test_ctrl_c_exits_within_2_s_and_leaves_the_output_as_it_was(args, signame, files, tmp_path):
    """SIGINT (exit 130) or SIGTERM (exit 143) in the middle of the work (after start-up, long
    before the end; inside a compiled kernel for stars): the process ends within 2 s with one
    line, the old outputs untouched (even with --force) and no staging folder left."""
    import signal

    work = tmp_path / "work"
    out = work / "out"
    out.mkdir(parents=True)
    (out / "keep.txt").write_text("a file the user had")
    before = snapshot(work)
    argv = [a.format(family=files["good"]) for a in args] + ["--out", str(out), "--force"]
    with subprocess.Popen(
        [sys.executable, "-c", CHILD, *argv],
        cwd=work,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as proc:
        try:
            if args[0] == "export":  # a few seconds of work: signalled while it writes
                deadline = time.monotonic() + LIMIT_S
                while not any(p.is_dir() for p in work.glob(".out.*.staging")) and time.monotonic() < deadline:
                    time.sleep(0.02)
            else:
                time.sleep(4.0)
            assert proc.poll() is None, "the work ended before it could be interrupted"
            sig = getattr(signal, signame)
            t0 = time.perf_counter()
            proc.send_signal(sig)
            _, err = proc.communicate(timeout=LIMIT_S)
            seconds = time.perf_counter() - t0
        finally:
            if proc.poll() is None:
                proc.kill()
    assert proc.returncode == 128 + sig, err
    assert seconds < 2.0, f"stopped {seconds:.2f} s after {signame}"
    assert "Traceback" not in err
    word = "terminated" if sig == signal.SIGTERM else "interrupted"
    lines = [line for line in err.splitlines() if not line.startswith("starforge ")]  # progress lines
    assert lines == [f"{word}; no output was changed"], err
    assert snapshot(work) == before


@pytest.mark.slow
def test_a_swallowed_ctrl_c_still_changes_nothing(tmp_path, monkeypatch):
    """numba compiles inside ctypes callbacks, which print a KeyboardInterrupt and carry on (seen
    on a fresh install: Ctrl-C during `place`'s first compile, and the run went on to exit 0).
    The CLI's SIGINT handler remembers the Ctrl-C, so nothing is published and the exit is 130."""
    import signal

    import starforge.stars.family as fam

    real = fam.make_family

    def swallowing(*args, **kwargs):
        out = real(*args, **kwargs)
        try:
            os.kill(os.getpid(), signal.SIGINT)  # delivered to the CLI's handler, in this thread
            time.sleep(0.1)
        except KeyboardInterrupt:
            pass  # what the ctypes callback does
        return out

    monkeypatch.setattr(fam, "make_family", swallowing)
    import starforge.runtime.process


    # the last resort (exit 1 s after the signal) is tested in a child process, not in this one
    monkeypatch.setattr(starforge.runtime.process, "STOP_DEADLINE_S", 60.0)
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("a file the user had")
    before = snapshot(out)
    handler = signal.getsignal(signal.SIGINT)  # Python's, or SIG_IGN in a job a shell started in the background
    assert run_cli(["stars", "--box", "16", "12", "24", "--delta", "2", "--out", out, "--force"]) == 130
    assert snapshot(out) == before
    assert not list(tmp_path.glob("*.staging"))
    assert signal.getsignal(signal.SIGINT) is handler  # restored after the run


@pytest.mark.slow
@pytest.mark.parametrize("existing", [False, True], ids=["new-folder", "into-a-folder"])
def test_a_signal_during_the_publish_says_the_outputs_were_written(existing, tmp_path, monkeypatch, capsys):
    """SIGTERM while the outputs are renamed into place (the new folder renamed, or the first file
    moved into an existing one) waits for the renames: the outputs are then whole, the user's
    other files as they were, and the one line says where the outputs were written."""
    import signal

    import starforge.runtime.process

    monkeypatch.setattr(starforge.runtime.process, "STOP_DEADLINE_S", 60.0)
    out = tmp_path / "out"
    if existing:
        out.mkdir()
        (out / "keep.txt").write_text("a file the user had")
        (out / "family.json").write_text("an old family")
    name = "replace" if existing else "rename"
    real = getattr(os, name)
    sent = []

    def move_then_signal(src, dst, *args, **kwargs):
        real(src, dst, *args, **kwargs)
        if not sent and (Path(dst) == out or Path(dst).parent == out):
            sent.append(dst)
            os.kill(os.getpid(), signal.SIGTERM)  # the publish is mid-way: it finishes first

    monkeypatch.setattr(os, name, move_then_signal)
    capsys.readouterr()
    args = ["stars", "--box", "16", "12", "24", "--delta", "2", "--out", out, *(["--force"] if existing else [])]
    assert run_cli(args) == 128 + signal.SIGTERM
    said = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("starforge ")]
    assert sent and said == [f"terminated after its outputs were written to {out}"]
    doc = json.loads((out / "family.json").read_text())  # the new family, whole
    assert len((out / "family.csv").read_text().strip().splitlines()) > len(doc["stars"]) > 0
    assert not existing or (out / "keep.txt").read_text() == "a file the user had"
    assert not [p for p in tmp_path.iterdir() if p.name.endswith((".staging", ".old"))]


def test_force_does_not_replace_a_read_only_file(files, tmp_path):
    """--force over a read-only output refuses in one line (a read-only file means "keep this")."""
    out = tmp_path / "out"
    out.mkdir()
    locked = out / "family.json"
    locked.write_text("the user's family")
    locked.chmod(0o444)
    before = snapshot(out)
    res = subprocess.run(
        [sys.executable, "-c", CHILD, "stars", "--box", "16", "12", "24", "--delta", "2", "--out", str(out), "--force"],
        env={**os.environ, "STARFORGE_MAX_MEMORY": "1G"}, capture_output=True, text=True, timeout=LIMIT_S,
    )
    assert res.returncode == 2, res.stderr
    assert res.stderr.strip().splitlines() == [
        f"error: {out} holds read-only family.json; --force does not replace read-only files "
        "(make them writable, e.g. chmod u+w, or choose another --out)"
    ]
    assert snapshot(out) == before
    assert not list(tmp_path.glob(".*staging"))


def test_a_full_disk_names_the_output(tmp_path):
    """ENOSPC while the outputs are written: the message names the output (the OS error names no
    path), nothing is published and no stage is left."""
    import errno

    from starforge.errors import StarforgeError
    from starforge.io import staged_output

    out = tmp_path / "out"
    with pytest.raises(StarforgeError, match=r"cannot write the outputs for .*out: No space left on device"):
        with staged_output(out) as stage:
            (stage / "a.txt").write_text("half")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []
