"""Hostile inputs on the tracker readers (NDI .rom, OptiTrack .motive, QTM, VSK, Atracsys,
body CSV), non-finite and absurd numbers in every numeric option, file names in other scripts,
a full disk, and many runs on one output folder.

The cases run as in :mod:`tests.test_hostile_inputs` (in process, and slow ones in a child of
their own session with a capped address space and a CPU budget): one ``error:`` line and exit 2,
or a correct result; the user's files as they were; no stage, no traceback, no warning.
"""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import run_cli
from tests.test_hostile_inputs import (
    BUDGET_S,
    CHILD,
    REPORT,
    Case,
    left_in_session,
    run_case_in_child,
    run_case_in_process,
)

ROM_SIZE = 752


def _rom_with(data: bytes, **fields) -> bytes:
    """An NDI .rom image with bytes changed (offset -> bytes) and its checksum made right again."""
    d = bytearray(data)
    for offset, value in fields.values():
        d[offset:offset + len(value)] = value
    d[4:6] = struct.pack("<H", sum(d[6:ROM_SIZE]) & 0xFFFF)
    return bytes(d)


BOMB = (
    '<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY lol "lol">'
    + "".join(f'<!ENTITY lol{i} "{("&lol" + (str(i - 1) if i > 1 else "") + ";") * 10}">' for i in range(1, 10))
    + "]>\n<{root}>&lol9;</{root}>\n"
)
XXE = '<?xml version="1.0"?>\n<!DOCTYPE x [<!ENTITY e SYSTEM "file:///etc/passwd">]>\n<{root}>&e;</{root}>\n'


@pytest.fixture(scope="module")
def tracker_files(tmp_path_factory, small_family):
    """Hostile tracker files, made once from a small family's good ones (convert writes those)."""
    d = tmp_path_factory.mktemp("hostile-trackers")
    fam = small_family[0] / "family.json"
    for fmt in ("rom", "motive", "csv", "qtm"):
        assert run_cli(["-q", "convert", fam, "--format", fmt, "--out", d / fmt]) == 0
    rom = next((d / "rom").glob("*.rom")).read_bytes()
    motive = next((d / "motive").glob("*.motive")).read_text()
    csv = next((d / "csv").glob("*.csv")).read_text()
    out = {"family": fam}

    def put(name: str, data) -> None:
        p = d / name
        p.write_bytes(data) if isinstance(data, bytes) else p.write_text(data, encoding="utf-8")
        out[name] = p

    put("truncated.rom", rom[:100])
    put("empty.rom", b"")
    put("checksum.rom", rom[:100] + bytes([rom[100] ^ 0xFF]) + rom[101:])
    put("zero-markers.rom", _rom_with(rom, n=(28, b"\0")))
    put("255-markers.rom", _rom_with(rom, n=(28, b"\xff")))
    put("nan.rom", _rom_with(rom, x=(72, struct.pack("<f", float("nan")))))
    put("inf.rom", _rom_with(rom, x=(72, struct.pack("<f", float("inf")))))
    with open(d / "100MB.rom", "wb") as fh:  # sparse: no disk used
        fh.write(rom)
        fh.truncate(100 * 2**20)
    out["100MB.rom"] = d / "100MB.rom"
    first = motive.split("<position>")[1].split("</position>")[0]
    put("nan.motive", motive.replace(first, "nan,0,0", 1))
    put("1e308.motive", motive.replace(first, "1e308,0,0", 1))
    put("underscore.motive", motive.replace(first, "1_0,0,0", 1))
    put("truncated.motive", motive[: len(motive) // 2])
    put("no-bodies.motive", '<?xml version="1.0"?>\n<Profile version="1"><NodeAssets/></Profile>\n')
    put("bomb.motive", BOMB.format(root="Profile"))
    put("xxe.motive", XXE.format(root="Profile"))
    put("bomb.xml", BOMB.format(root="QTM_Body_File_Ver_1.00"))
    put("xxe.xml", XXE.format(root="QTM_Body_File_Ver_1.00"))
    put("garbage.vsk", "this is not a vicon skeleton\n" * 20)
    put("garbage.ini", "[geometry]\ncount=banana\n")
    head, *rows = csv.splitlines()
    put("nan.csv", "\n".join([head, rows[0].rsplit(",", 1)[0] + ",nan", *rows[1:]]) + "\n")
    put("1e308.csv", "\n".join([head, rows[0].rsplit(",", 1)[0] + ",1e308", *rows[1:]]) + "\n")
    put("header-only.csv", head + "\n")
    put("no-columns.csv", "a,b\n1,2\n")
    with open(d / "big.motive", "wb") as fh:
        fh.truncate(300 * 2**20)
    out["big.motive"] = d / "big.motive"
    # a body named in Chinese, in a file named in Chinese: a correct result, with no font warnings
    name = rows[0].split(",")[0]
    put("把手.csv", csv.replace(name, "把手"))
    return out


#: the hostile tracker files, with what the one line says about each
TRACKER_CASES = {
    "truncated.rom": r"truncated.rom is not an NDI tool definition",
    "empty.rom": r"empty.rom (is not an NDI tool definition|is empty)",
    "checksum.rom": r"checksum.rom: NDI checksum \d+ does not match",
    "zero-markers.rom": r"zero-markers.rom: NDI marker count 0 is outside 1..20",
    "255-markers.rom": r"255-markers.rom: NDI marker count 255 is outside 1..20",
    "nan.rom": r"nan.rom: NDI marker positions or normals are not finite",
    "inf.rom": r"inf.rom: NDI marker positions or normals are not finite",
    "100MB.rom": r"100MB.rom is 100 MiB; a tracker body file is at most 64 MiB",
    "nan.motive": r"nan.motive: .* is not (finite|a number)",
    "1e308.motive": r"1e308.motive: .*(not finite|beyond 100 m of its origin|disagree)",
    "underscore.motive": r"underscore.motive: .* is not a number \('1_0'\)",
    "truncated.motive": r"truncated.motive is not valid XML",
    "no-bodies.motive": r"no-bodies.motive",
    "bomb.motive": r"bomb.motive declares XML entities",
    "xxe.motive": r"xxe.motive declares XML entities",
    "bomb.xml": r"bomb.xml declares XML entities",
    "xxe.xml": r"xxe.xml declares XML entities",
    "garbage.vsk": r"garbage.vsk",
    "garbage.ini": r"garbage.ini",
    "nan.csv": r"nan.csv",
    "1e308.csv": r"1e308.csv: body .* has markers beyond 100 m of its origin",
    "header-only.csv": r"header-only.csv",
    "no-columns.csv": r"no-columns.csv",
    "big.motive": r"big.motive is 300 MB, above the \d+ MB a (tracker|file) input may be",
}
TRACKER_COMMANDS = {
    "check": ("check", "{file}", "--frames", "200"),
    "convert": ("convert", "{file}", "--format", "qtm"),
    "drawing": ("drawing", "{file}"),
}

#: numeric options of every command, each given values no one means: not a number, infinite,
#: beyond any size a marker, body, room or noise has
NUMERIC_OPTIONS = [
    ("stars", (), "--delta"), ("stars", (), "--gap"), ("stars", (), "--tolerance"), ("stars", (), "--min-depth"),
    ("stars", (), "--noise"), ("stars", (), "--marker"),
    ("export", ("{family}", "--allow-oversize"), "--nozzle-mm"), ("export", ("{family}", "--allow-oversize"), "--coating-mm"),
    ("export", ("{family}", "--allow-oversize"), "--stem-mm"), ("export", ("{family}", "--allow-oversize"), "--min-stem-mm"),
    ("export", ("{family}", "--allow-oversize"), "--post-mm"), ("export", ("{family}", "--allow-oversize"), "--gap"), ("export", ("{family}", "--allow-oversize"), "--noise"),
    ("preview", ("{family}",), "--nozzle-mm"), ("preview", ("{family}",), "--coating-mm"),
    ("preview", ("{family}",), "--stem-mm"), ("preview", ("{family}",), "--post-mm"),
    ("check", ("{family}",), "--noise"), ("check", ("{family}",), "--presence"),
    ("check", ("{family}",), "--ambiguity"), ("check", ("{family}",), "--match"), ("check", ("{family}",), "--residual"),
    ("place", ("run", "hammer"), "--base-mm"), ("place", ("run", "hammer"), "--placement-error"),
    ("place", ("run", "hammer"), "--cameras-lost"),
    ("convert", ("{family}", "--format", "qtm"), "--noise"),
    ("sweep", (), "--marker"), ("sweep", (), "--min-depth"), ("sweep", (), "--delta"), ("sweep", (), "--cube"),
    ("mounts", (), "--marker"),
]
BAD_NUMBERS = ("nan", "inf", "-inf", "1e308")


def _cases(f) -> list[Case]:
    cases = []
    for name, pattern in TRACKER_CASES.items():
        for cmd, args in TRACKER_COMMANDS.items():
            cases.append(Case(f"{cmd}-{name}", tuple(a.format(file=f[name]) for a in args), pattern, budget_s=BUDGET_S,
                              kind="tracker-file"))
    for cmd, before, option in NUMERIC_OPTIONS:
        stem = option.lstrip("-").removesuffix("-mm").replace("-", "[ _-]")
        for v in BAD_NUMBERS:
            args = (cmd, *(a.format(family=f["family"]) for a in before), option, v)
            cases.append(Case(f"{cmd}{option}={v}", args, rf"(?i){stem}", uses_out=cmd != "mounts", budget_s=BUDGET_S,
                              kind="number"))
    cases += [
        Case("drawing-cjk-names", ("drawing", str(f["把手.csv"])), "", code=0, verify=_drawn("把手"), budget_s=BUDGET_S,
             kind="name"),
        Case("convert-cjk-names", ("convert", str(f["把手.csv"]), "--format", "motive"), "", code=0,
             verify=_converted("把手"), budget_s=BUDGET_S, kind="name"),
    ]
    return cases


def _drawn(body: str):
    def verify(out: Path, err: str) -> None:
        assert (out / "drawing.pdf").read_bytes().startswith(b"%PDF")
        pngs = list(out.glob("*.png"))  # named after the body, in the characters a file name may hold
        assert len(pngs) == 1 and pngs[0].read_bytes().startswith(b"\x89PNG")
        assert "Glyph" not in err and "missing from" not in err, err

    return verify


def _converted(body: str):
    def verify(out: Path, err: str) -> None:
        made = list(out.glob("*.motive"))
        assert len(made) == 1 and body in made[0].read_text(encoding="utf-8")

    return verify


_KEYS = ["family", *TRACKER_CASES, "把手.csv"]


def _case_ids() -> list[str]:
    return [c.id for c in _cases({k: Path(k) for k in _KEYS})]


@pytest.mark.parametrize("case_id", [i for i in _case_ids() if not i.endswith("inf")])  # inf: in the slow twin
def test_hostile_reader_or_value_in_process(case_id, tracker_files, tmp_path, monkeypatch, capsys):
    run_case_in_process({c.id: c for c in _cases(tracker_files)}[case_id], tmp_path, monkeypatch, capsys)


@pytest.mark.slow
@pytest.mark.parametrize("case_id", _case_ids())
def test_hostile_reader_or_value(case_id, tracker_files, tmp_path):
    run_case_in_child({c.id: c for c in _cases(tracker_files)}[case_id], tmp_path)


# --- a full disk: every command that writes, with writes past 256 bytes refused (EFBIG) ----------

FULL_DISK = {
    "stars": ("stars", "--box", "16", "12", "24", "--delta", "2"),
    "export": ("export", "{family}", "--ids", "1", "--format", "stl,qtm", "--allow-oversize"),
    "check": ("check", "{family}", "--frames", "200", "--curve", "0"),
    "convert": ("convert", "{family}", "--format", "motive"),
    "drawing": ("drawing", "{family}"),
    "preview": ("preview", "{family}", "--ids", "1", "--allow-oversize"),
    "place": ("place", "run", "hammer", "--resolution", "1", "--orientations", "4", "--sites", "150",
              "--restarts", "1"),
}


@pytest.mark.slow
@pytest.mark.parametrize("command", list(FULL_DISK))
def test_a_full_disk_is_one_line_and_leaves_nothing(command, tracker_files, tmp_path):
    args = tuple(a.format(family=tracker_files["family"]) for a in FULL_DISK[command])
    case = Case(f"full-disk-{command}", args, r"cannot write the outputs for .*out: File too large",
                env={"HOSTILE_FILE_BYTES": "256"}, kind="full-disk")  # the CPU budget counts; the wall clock guards a hang
    run_case_in_child(case, tmp_path)


# --- many runs on one output folder ------------------------------------------------------------


@pytest.mark.slow
def test_concurrent_runs_on_one_out_leave_one_whole_result(small_family, tmp_path):
    """Eight `stars` runs at once on one --out, with --force: each ends with 0 or one line; the
    folder then holds one whole family (the same bytes every run makes), no stage, no process."""
    out = tmp_path / "out"
    argv = ["stars", "--box", "16", "12", "24", "--delta", "2", "--out", str(out), "--force", "-q"]
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "STARFORGE_MAX_MEMORY": "1G"}
    procs = [subprocess.Popen([sys.executable, "-c", CHILD, *argv], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, start_new_session=True) for _ in range(8)]
    results = [(p.pid, *p.communicate(timeout=300), p.returncode) for p in procs]
    clean = False
    try:
        for _, _, err, code in results:
            assert code == 0 or (code == 2 and len(err.strip().splitlines()) == 1), err
            assert "Traceback" not in err and "Warning" not in err, err
        assert any(code == 0 for *_, code in results)
        ref = tmp_path / "ref"
        ref.mkdir()
        from tests.conftest import family_files

        family_files(ref, {"box_mm": [16.0, 12.0, 24.0], "delta_mm": 2.0})
        assert json.loads((out / "family.json").read_text()) == json.loads((ref / "family.json").read_text())
        assert (out / "family.csv").read_text() == (ref / "family.csv").read_text()
        assert not [p for p in tmp_path.rglob("*") if ".staging" in p.name or p.name.startswith(".out.")]
        assert not any(left_in_session(pid) for pid, *_ in results)
        clean = True
    finally:
        if REPORT:
            with open(REPORT, "a") as fh:
                fh.write(json.dumps({"case": "concurrent-8-stars-one-out", "kind": "concurrent", "clean": clean, "seconds": None,
                                     "cpu_seconds": None, "peak_kb": None}) + "\n")


def test_an_error_raised_while_a_writer_cleans_up_after_a_full_disk_is_a_full_disk(tmp_path):
    """matplotlib's PDF writer, closed after a write failed for lack of room, raises a zlib error
    of its own: the one line still says the outputs could not be written, and nothing is left."""
    import errno

    from starforge.errors import StarforgeError
    from starforge.io import staged_output

    out = tmp_path / "out"
    with pytest.raises(StarforgeError, match=r"cannot write the outputs for .*out: File too large"):
        with staged_output(out) as stage:
            (stage / "drawing.pdf").write_text("half")
            try:
                raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))
            finally:
                raise RuntimeError("Error -2 while flushing: inconsistent stream state")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RuntimeError, match="not a disk error"):  # any other error passes as it is
        with staged_output(out):
            raise RuntimeError("not a disk error")
