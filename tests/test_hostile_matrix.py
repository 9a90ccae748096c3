"""Hostile cases generated as a matrix: every file a command reads x every way a file goes wrong,
every numeric option x every value no one means, every list and choice option x malformed text,
every output folder x what a user or a disk puts in its way.

Each case is one command a user or a broken disk could produce; its id says what differs
(``<command>[-<option>]-<kind>-<fault>``).  They run as :mod:`tests.test_hostile_inputs` runs its
cases: in a child of its own session (address space capped at 2 GiB, a CPU budget, no process
left; ``-m slow`` and ``benchmarks/bench_hostile.py``), and a sample of them in process in the
default run.  A refusal is one ``error:`` line naming the file or the option, exit 2, and the
working folder byte for byte as it was; the line names what the user typed and a way out, as
:func:`tests.test_cli_refusals.says_the_way_out` checks every refusal of the hostile suites.
"""

from __future__ import annotations

import json
import re
import struct
from pathlib import Path

import numpy as np
import pytest

import templates
from starforge.io import INPUT_LIMITS
from tests.conftest import run_cli
from tests.test_cli_refusals import says_the_way_out
from tests.test_hostile_inputs import BUDGET_S, Case, run_case_in_child, run_case_in_process

TEMPLATES = Path(templates.__file__).parent

# --- what a file can be ----------------------------------------------------------------------

#: faults of any file: found by the path checks before a byte is parsed
PATH_FAULTS = ("missing", "folder", "loop", "dangling", "empty", "huge", "unreadable")
#: faults of a file's content
TEXT_FAULTS = ("truncated", "garbage", "utf16", "latin1", "nan", "count")
BINARY_FAULTS = ("truncated", "garbage", "nan", "count")
#: what the one line says for each path fault (the file's name is in the line for every fault)
SAYS = {
    "missing": r"not found",
    "folder": r"(is a folder|holds no|not found: .*/)",  # a folder may hold the file it names
    "loop": r"loops back on itself",
    "dangling": r"(symbolic link to a missing file|not found)",
    "empty": r"is empty",
    "huge": r"above the [0-9,]+ [MG]B a \w+ input may be",
    "unreadable": r"(Permission denied|is not readable)",
}

#: kind -> (file suffix, size-limit kind of starforge.io.INPUT_LIMITS, binary?)
KINDS = {
    "family": (".json", "json", False),
    "stars-spec": (".toml", "toml", False),
    "marker": (".toml", "toml", False),
    "preset": (".toml", "toml", False),
    "mount": (".toml", "toml", False),
    "place-spec": (".toml", "toml", False),
    "rig": (".toml", "toml", False),
    "mesh": (".stl", "mesh", True),
    "markers-csv": (".csv", "csv", False),
    "mask": (".txt", "mask", False),
    "qtm": (".xml", "tracker", False),
    "vsk": (".vsk", "tracker", False),
    "atracsys": (".ini", "tracker", False),
    "body-csv": (".csv", "tracker", False),
}
TOML_TEMPLATES = {"stars-spec": "stars/finger.toml", "marker": "markers/4mm-flat.toml", "preset": "presets/art.toml",
                  "mount": "mounts/flat.toml", "place-spec": "place/default.toml", "rig": "rigs/small4.toml"}

#: every file a command reads: id -> (kind, arguments with {f} for the file, {fam} for a good family)
READERS = {
    "export": ("family", ("export", "{f}", "--format", "qtm")),
    "check": ("family", ("check", "{f}", "--frames", "200")),
    "preview": ("family", ("preview", "{f}", "--ids", "1", "--allow-oversize")),
    "convert": ("family", ("convert", "{f}", "--format", "qtm")),
    "drawing": ("family", ("drawing", "{f}")),
    "stars--avoid": ("family", ("stars", "--box", "16,12,24", "--delta", "2", "--avoid", "{f}")),
    "place--avoid": ("family", ("place", "run", "hammer", "--avoid", "{f}")),
    "place-batch--avoid": ("family", ("place-batch", "hammer", "--avoid", "{f}")),
    "stars--spec": ("stars-spec", ("stars", "--spec", "{f}")),
    "stars--marker": ("marker", ("stars", "--box", "16,12,24", "--marker", "{f}")),
    "stars--preset": ("preset", ("stars", "--box", "16,12,24", "--preset", "{f}")),
    "check--preset": ("preset", ("check", "{fam}", "--frames", "200", "--preset", "{f}")),
    "place--preset": ("preset", ("place", "run", "hammer", "--preset", "{f}")),
    "export--mount": ("mount", ("export", "{fam}", "--format", "stl", "--mount", "{f}")),
    "preview--mount": ("mount", ("preview", "{fam}", "--ids", "1", "--allow-oversize", "--mount", "{f}")),
    "convert--mount": ("mount", ("convert", "{fam}", "--format", "family", "--mount", "{f}")),
    "export--marker": ("marker", ("export", "{fam}", "--format", "stl", "--marker", "{f}")),
    "mounts--marker": ("marker", ("mounts", "--marker", "{f}")),
    "place--marker": ("marker", ("place", "run", "hammer", "--marker", "{f}")),
    "place--spec": ("place-spec", ("place", "run", "hammer", "--spec", "{f}")),
    "place-batch--spec": ("place-spec", ("place-batch", "hammer", "--spec", "{f}")),
    "place-score--spec": ("place-spec", ("place", "score", "hammer", "{markers}", "--spec", "{f}")),
    "place--rig": ("rig", ("place", "run", "hammer", "--rig", "{f}")),
    "place-batch--rig": ("rig", ("place-batch", "hammer", "--rig", "{f}")),
    "place": ("mesh", ("place", "run", "{f}")),
    "place--forbid-mesh": ("mesh", ("place", "run", "hammer", "--forbid-mesh", "{f}")),
    "place-batch": ("mesh", ("place-batch", "{f}")),
    "place-score-mesh": ("mesh", ("place", "score", "{f}", "{markers}")),
    "place-score": ("markers-csv", ("place", "score", "hammer", "{f}")),
    "place--mask": ("mask", ("place", "run", "hammer", "--mask", "{f}")),
    **{f"check-{kind}": (kind, ("check", "{f}", "--frames", "200")) for kind in ("qtm", "vsk", "atracsys", "body-csv")},
}
#: the tracker files' content faults also through the other commands that read them (their path
#: faults meet the same checks as in ``check``)
CONTENT_READERS = {f"{cmd}-{kind}": (kind, (cmd, "{f}", *more)) for kind in ("qtm", "vsk", "atracsys", "body-csv")
                   for cmd, more in (("convert", ("--format", "motive")), ("drawing", ()))}
#: (reader, fault) pairs that are cases of tests/test_hostile_inputs.py already
COVERED = {
    *((r, "loop") for r in ("export", "check", "stars--avoid", "place--avoid", "place", "place--forbid-mesh")),
    *((r, "huge") for r in ("export", "check", "stars--spec", "stars--marker", "mounts--marker", "place-score",
                            "place--mask", "check-qtm", "stars--avoid")),
    ("export", "missing"), ("export", "truncated"), ("stars--spec", "missing"), ("stars--spec", "truncated"),
    ("place", "missing"), ("place", "garbage"), ("place--forbid-mesh", "missing"), ("place-batch", "garbage"),
    ("place-batch", "missing"),
}
#: commands that print and write nothing (no --out)
NO_OUT = ("mounts", "place score")


def _faults(kind: str) -> tuple[str, ...]:
    binary = KINDS[kind][2]
    faults = PATH_FAULTS + (BINARY_FAULTS if binary else TEXT_FAULTS)
    if kind in TOML_TEMPLATES and not re.search(EDITS["toml"][1], (TEMPLATES / TOML_TEMPLATES[kind]).read_text()):
        faults = tuple(f for f in faults if f != "count")  # no list of numbers to make short
    if kind == "mask":  # a mask cut short is a mask one value short (its count fault)
        faults = tuple(f for f in faults if f != "truncated")
    return faults


def _file_name(kind: str, fault: str) -> str:
    return f"{kind}-{fault}{KINDS[kind][0]}"


def reader_cases(f: dict) -> list[Case]:
    cases = []
    for reader, (kind, argv) in {**READERS, **CONTENT_READERS}.items():
        for fault in _faults(kind) if reader in READERS else TEXT_FAULTS:
            if (reader, fault) in COVERED:
                continue
            name = _file_name(kind, fault)
            args = tuple(a.format(f=f[name], fam=f["family.json"], markers=f["markers.csv"]) for a in argv)
            says = rf"(?=.*{re.escape(name)})" + (rf"(?=.*{SAYS[fault]})" if fault in SAYS else "")
            cases.append(Case(f"{reader}-{kind}-{fault}", args, says, uses_out=" ".join(argv[:2]) not in NO_OUT
                              and argv[0] not in NO_OUT, budget_s=BUDGET_S,
                              env={"HOSTILE_AS_USER": "1"} if fault == "unreadable" else {}, kind=f"file-{fault}"))
    return cases


# --- the files, made once ----------------------------------------------------------------------


def _truncated(kind: str, text: str) -> str:
    """The text cut short, as by a full disk or an interrupted copy: a TOML file inside its first
    list or string past its first third, any other text at half its length."""
    if KINDS[kind][1] == "toml":
        m = re.compile(r'= \[|= "').search(text, len(text) // 3) or re.compile(r'= \[|= "').search(text)
        return text[: m.end()]
    return text[: len(text) // 2]


#: kind -> (the first value to make not-a-number, after the prefix in group 1; what to change
#: for a wrong count; its replacement, None for a TOML list made one value short)
EDITS = {
    "toml": (r"(?m)^(\w+ *= *)-?\d+(\.\d+)?", r"\[(\s*-?[\d.]+\s*,)+\s*-?[\d.]+\s*\]", None),
    "markers-csv": (r"(?m)^(0,)[-\d.]+", r"(?m)^(0,)[^\n]*", r"\g<1>0.1,0.2"),
    "body-csv": (r"(?m)^([^,\n]+,1,)[-\d.]+", r"(?m)^([^,\n]+,1,)[^\n]*", r"\g<1>1.0,2.0"),
    "mask": (r"^()0", r"0\n$", ""),
    "qtm": (r'(X=")[^"]*', r'\s+Z="[^"]*"', ""),
    "vsk": (r'(VALUE=")[^"]*', r'\s*<Parameter NAME="M1_[^"]*_Z"[^>]*>', ""),
    "atracsys": (r"(?m)^(x=)[-\d.]+", r"count=4", "count=5"),
}


def _edit(kind: str, fault: str, good: str) -> str:
    """The good text with its first value not a number (``nan``), or with one value too few or a
    count that disagrees with what follows (``count``)."""
    if kind == "family":  # JSON: the first star's first vertex, or one vertex too few
        doc = json.loads(good)
        star = doc["stars"][0]
        if fault == "nan":
            star["vertices"][0][0] = float("nan")
        else:
            star["vertices"] = star["vertices"][:3]
        return json.dumps(doc, indent=2)
    nan, count, repl = EDITS["toml" if KINDS[kind][1] == "toml" else kind]
    if fault == "nan":
        return re.sub(nan, r"\g<1>nan", good, count=1)
    if repl is None:  # a TOML list one value short
        return re.sub(count, lambda m: m.group(0).rsplit(",", 1)[0] + "]", good, count=1)
    return re.sub(count, repl, good, count=1)


def _content(kind: str, fault: str, good) -> bytes:
    rng = np.random.default_rng(sum(map(ord, kind + fault)))
    if fault == "garbage":
        return rng.integers(0, 256, 4096, dtype=np.uint8).tobytes()
    if KINDS[kind][2]:  # a binary STL: 80-byte header, face count, 50 bytes a face
        data = bytearray(good)
        if fault == "truncated":
            return bytes(data[: len(data) // 2])
        if fault == "nan":
            data[84 + 12: 84 + 16] = struct.pack("<f", float("nan"))  # the first vertex's x
            return bytes(data)
        data[80:84] = struct.pack("<I", 1000 * struct.unpack("<I", data[80:84])[0])  # fault == "count"
        return bytes(data)
    if fault == "truncated":
        return _truncated(kind, good).encode()
    if fault == "utf16":
        return good.encode("utf-16")
    if fault == "latin1":  # a name in a Windows editor's encoding
        return _latin1(kind, good)
    return _edit(kind, fault, good).encode()


def _latin1(kind: str, good: str) -> bytes:
    if kind in TOML_TEMPLATES:
        return ("# Grüße aus Köln\n" + good).encode("latin-1", errors="replace")
    if kind == "mask":
        return ("0 0 0 # Größe\n" + good).encode("latin-1", errors="replace")
    if kind == "family":
        return good.replace('"name": "custom"', '"name": "Größe"', 1).encode("latin-1", errors="replace")
    # tracker and CSV files: the first body's name
    return re.sub(r"(<Name>|NAME=\"|^)[A-Za-z_]", r"\1Ö", good, count=1, flags=re.M).encode(
        "latin-1", errors="replace")


def make_files(d: Path, small_family) -> dict:
    """Every file of every kind and fault in ``d``; returns name -> path (names as ``_file_name``)."""
    import trimesh

    out = {}
    fam_dir, fam = small_family
    out["family.json"] = fam_dir / "family.json"
    good = {"family": (fam_dir / "family.json").read_text()}
    for kind, rel in TOML_TEMPLATES.items():
        good[kind] = (TEMPLATES / rel).read_text(encoding="utf-8")
    mesh = trimesh.creation.box(extents=(0.3, 0.05, 0.04))
    good["mesh"] = mesh.export(file_type="stl")
    good["markers-csv"] = "id,x_m,y_m,z_m,nx,ny,nz\n" + "".join(
        f"{i},{x:.3f},0.000,0.020,0,0,1\n" for i, x in enumerate((-0.12, -0.05, 0.03, 0.1)))
    good["mask"] = "0\n" * len(mesh.faces)
    trackers = d / "trackers"
    for fmt in ("qtm", "vsk", "atracsys", "csv"):
        assert run_cli(["-q", "convert", out["family.json"], "--format", fmt, "--out", trackers / fmt]) == 0
        first = sorted((trackers / fmt).iterdir())[0]
        good["body-csv" if fmt == "csv" else fmt] = first.read_text(encoding="utf-8")
    markers = d / "markers.csv"
    markers.write_text(good["markers-csv"])
    out["markers.csv"] = markers
    for kind, (suffix, limit_kind, _) in KINDS.items():
        for fault in _faults(kind):
            p = d / _file_name(kind, fault)
            out[p.name] = p
            if fault == "folder":
                p.mkdir()
            elif fault == "loop":
                p.symlink_to(p)
            elif fault == "dangling":
                p.symlink_to(d / f"gone{suffix}")
            elif fault == "empty":
                p.touch()
            elif fault == "huge":  # sparse: no disk used
                with open(p, "wb") as fh:
                    fh.truncate(INPUT_LIMITS[limit_kind] + 2**20)
            elif fault == "unreadable":
                data = good[kind]
                p.write_bytes(data if isinstance(data, bytes) else data.encode())
                p.chmod(0)
            elif fault != "missing":
                data = _content(kind, fault, good[kind])
                assert data != good[kind] and data != str(good[kind]).encode(), (kind, fault)  # a real fault
                p.write_bytes(data)
    return out


_FILE_NAMES = ["family.json", "markers.csv", *(_file_name(k, x) for k in KINDS for x in _faults(k))]


# --- values: numbers, lists, choices -------------------------------------------------------------

FAM = "{fam}"
#: the small family's bodies on the default mount exceed its size limit: not the fault a case is about
OVERSIZE = "--allow-oversize"
#: every numeric option: (command and arguments before it, option, values outside its range);
#: beside these, each takes a non-number (``abc``); not-a-number, infinite and 1e308 values of
#: the float options are cases of tests/test_hostile_readers.py
NUMBERS = [
    (("stars",), "--delta", ("0",)), (("stars",), "--gap", ("-1",)), (("stars",), "--tolerance", ("-1",)),
    (("stars",), "--min-depth", ("-1",)), (("stars",), "--noise", ("-1",)), (("stars",), "--marker", ("-1",)),
    (("stars",), "--count", ("-1", "0", "1.5")), (("stars",), "--work", ("-1", "0", "1e3")),
    (("export", FAM, OVERSIZE), "--nozzle-mm", ("-1", "0")), (("export", FAM, OVERSIZE), "--coating-mm", ("-1",)),
    (("export", FAM, OVERSIZE), "--stem-mm", ("-1", "0")), (("export", FAM, OVERSIZE), "--min-stem-mm", ("-1", "0")),
    (("export", FAM, OVERSIZE), "--post-mm", ("-1", "0")), (("export", FAM, OVERSIZE), "--gap", ("-1",)),
    (("export", FAM, "--format", "qtm"), "--noise", ("-1",)), (("export", FAM, "--format", "atracsys"), "--id-start", ("-1", "1e9")),
    (("preview", FAM, OVERSIZE), "--nozzle-mm", ("-1", "0")), (("preview", FAM, OVERSIZE), "--coating-mm", ("-1",)),
    (("preview", FAM, OVERSIZE), "--stem-mm", ("-1", "0")), (("preview", FAM, OVERSIZE), "--min-stem-mm", ("-1", "0")),
    (("preview", FAM, OVERSIZE), "--post-mm", ("-1", "0")),
    (("check", FAM), "--noise", ()), (("check", FAM), "--presence", ("-1", "0", "2")),
    (("check", FAM), "--ambiguity", ("-1", "0")), (("check", FAM), "--match", ("-1", "0")),
    (("check", FAM), "--residual", ("-1", "0")), (("check", FAM), "--drop", ("-1", "4")),
    (("check", FAM), "--ghosts", ("-1", "21")), (("check", FAM), "--frames", ("-1", "0")),
    (("check", FAM), "--seed", ("-1",)), (("check", FAM), "--curve", ("-1", "1000000")),
    (("convert", FAM, "--format", "qtm"), "--noise", ("-1", "0")), (("convert", FAM, "--format", "qtm"), "--id-start", ("-1",)),
    (("place", "run", "hammer"), "--base-mm", ("-1",)), (("place", "run", "hammer"), "--placement-error", ("-1",)),
    (("place", "run", "hammer"), "--cameras-lost", ("-1", "1.5")), (("place", "run", "hammer"), "--noise", ("-1",)),
    (("place", "run", "hammer"), "--markers", ("-1", "3", "13")), (("place", "run", "hammer"), "--resolution", ("-1", "0")),
    (("place", "run", "hammer"), "--orientations", ("-1", "0")), (("place", "run", "hammer"), "--sites", ("-1", "0", "3")),
    (("place", "run", "hammer"), "--restarts", ("-1", "1000000")), (("place", "run", "hammer"), "--seed", ("-1",)),
    (("place", "run", "hammer"), "--marker", ("-1", "0", "1e308")),
    (("place", "score", "hammer", "{markers}"), "--resolution", ("-1", "0")),
    (("place", "score", "hammer", "{markers}"), "--orientations", ("-1", "0")),
    (("place-batch", "hammer"), "--copies", ("-1", "0", "1000")), (("place-batch", "hammer"), "--frames", ("-1", "0")),
    (("place-batch", "hammer"), "--noise", ("-1", "nan")), (("place-batch", "hammer"), "--workers", ("-1",)),
    (("place-batch", "hammer"), "--seed", ("-1",)),
    (("sweep",), "--samples", ("-1", "0")), (("sweep",), "--workers", ("-1",)), (("sweep",), "--seed", ("-1",)),
    (("measure", "{recording}"), "--rigid", ("-1", "0", "nan")), (("measure", "{recording}"), "--noise", ("-1", "nan")),
]
#: options that take a list or a pattern: (command and arguments before it, option, malformed values)
LISTS = [
    (("stars",), "--box", ("16,12", "16,12,24,30", "nan,12,24", "a,b,c", "-16,12,24", "16,,24")),
    (("stars",), "--tip", ("0,0", "nan,0,0", "a,b,c", "1e308,0,0")),
    (("stars",), "--reserve", ("1,2", "nan,0,0", "-1,0,0", "a,b,c", "1e308,0,0")),
    (("check", FAM), "--tip", ("0,0", "a,b,c", "0,0,0,0")),
    (("place", "run", "hammer"), "--grip", ("1,2", "nan,0,0,0.1,0,0", "0,0,0,0,0,0.1,-1", "9999", "-1", "a,b,c,d,e,f")),
    (("export", FAM, OVERSIZE), "--bed", ("0x200", "-5x200", "nanx200", "200", "axb", "1e308x1e308")),
    (("export", FAM, OVERSIZE), "--ids", ("0", "a-b", "5-1", "1,,2", "-3")),
    (("preview", FAM, OVERSIZE), "--ids", ("0", "a-b", "5-1")),
    (("export", FAM, OVERSIZE), "--set", ("holes=abc", "nokey=1", "holes", "holes=nan", "holes=99")),
    (("sweep",), "--delta", ("3:0.5:0.5", "1:2:0", "1:2:-0.5", "a,b", "1:2", "-1,2")),
    (("sweep",), "--cube", ("50:10:5", "10:50:0", "inf:50:5", "10,x")),
    (("measure", "{recording}"), "--body", ("A=", "=M1,M2,M3", "A=M1,M2", "A=M1,M1,M2")),
]
#: options that take a name from a list: (command and arguments before it, option, wrong names)
CHOICES = [
    (("stars",), "--rule", ("Face", "把手")), (("stars",), "--select", ("best", "")),
    (("stars",), "--box-method", ("obb", "")), (("stars",), "--seat", ("nail", "")),
    (("stars",), "--mount", ("", "把手")), (("stars",), "--preset", ("", "motionanalysis")),
    (("stars",), "--spec", ("", "fingers")), (("stars",), "--marker", ("", "3mm-m2")),
    (("export", FAM, OVERSIZE), "--format", ("", "stl,dwg", "STEP;stl")), (("export", FAM, OVERSIZE), "--seat", ("nail", "")),
    (("export", FAM, OVERSIZE), "--mount", ("Flat",)), (("export", FAM, OVERSIZE), "--marker", ("", "3mm-m2")),
    (("preview", FAM, OVERSIZE), "--seat", ("nail",)), (("preview", FAM, OVERSIZE), "--mount", ("magnets",)),
    (("check", FAM), "--world", ("half", "")), (("check", FAM), "--choose", ("best", "")),
    (("check", FAM), "--preset", ("", "motionanalysis")),
    (("convert", FAM), "--format", ("", "fbx")), (("convert", FAM, "--format", "family"), "--mount", ("velcro",)),
    (("place", "run", "hammer"), "--mesh-format", ("obj", "")), (("place", "run", "hammer"), "--units", ("", "inch")),
    (("place", "run", "hammer"), "--preset", ("", "motionanalysis")), (("place", "run", "hammer"), "--rig", ("", "huge")),
    (("place", "run", "hammer"), "--spec", ("", "fast")), (("place", "run", "hammer"), "--marker", ("", "3mm-m2")),
    (("place-batch", "hammer"), "--units", ("inch",)), (("place-batch", "hammer"), "--rig", ("huge",)),
    (("place-batch", "hammer"), "--preset", ("motionanalysis",)), (("place-batch", "hammer"), "--spec", ("fast",)),
    (("sweep",), "--rule", ("", "face,tri")), (("sweep",), "--exhaustive", ("some", "-1")),
    (("templates",), "--show", ("nope",)), (("templates", "stars"), "--show", ("nope",)),
]


def _slug(v: str) -> str:
    return {"": "empty", "-1": "minus1", "-inf": "minus-inf"}.get(v, v.replace(",", "_").replace(":", "_"))


def value_cases(f: dict) -> list[Case]:
    cases = []
    # stars --count takes a word in tests/test_hostile_inputs.py
    rows = [(b, o, (*vs, *(() if o == "--count" else ("abc",))), "number") for b, o, vs in NUMBERS]
    rows += [(*row, "list") for row in LISTS] + [(*row, "choice") for row in CHOICES]
    for before, option, values, kind in rows:
        stem = option.lstrip("-").removesuffix("-mm").replace("-", "[ _-]")
        for v in values:
            cmd = " ".join(before[:2]) if before[0] in ("place", "templates") else before[0]
            args = (*(a.format(fam=f["family.json"], markers=f["markers.csv"], recording=f["recording.csv"])
                      for a in before), option, v)
            # the line names the option, the field it sets, the key of KEY=VALUE, or quotes the value
            named = [stem, re.escape(option), re.escape(repr(v))] + ([re.escape(v.split("=")[0])] if "=" in v else [])
            where = "-".join(a for a in before if not a.startswith("{") and a != OVERSIZE)
            cases.append(Case(f"{where}{option}={_slug(v)}", args, rf"(?i)({'|'.join(named)})",
                              uses_out=cmd not in NO_OUT and before[0] != "templates", budget_s=BUDGET_S, kind=kind))
    return cases


# --- the output folder --------------------------------------------------------------------------

#: a file each command writes (for a case that finds it there from an earlier run)
OUTPUT = {"stars": "family.json", "export": "trackers.json", "check": "check.json", "convert": "custom_001.xml",
          "drawing": "drawing.pdf", "preview": "preview/star_001.png", "measure": "bodies.csv", "sweep": "sweep.csv",
          "place": "placement.json", "place-batch": "batch.csv"}
WRITERS = {
    "stars": ("stars", "--box", "16,12,24", "--delta", "2"),
    "export": ("export", FAM, "--format", "qtm"),
    "check": ("check", FAM, "--frames", "200", "--curve", "0"),
    "convert": ("convert", FAM, "--format", "qtm"),
    "drawing": ("drawing", FAM),
    "preview": ("preview", FAM, "--ids", "1", OVERSIZE),
    "measure": ("measure", "{recording}"),
    "sweep": ("sweep", "--delta", "2", "--cube", "20", "--rule", "face"),
    "place": ("place", "run", "hammer", "--resolution", "1", "--orientations", "4", "--sites", "150"),
    "place-batch": ("place-batch", "hammer", "--workers", "1"),
}


def _out_faults(cmd: str):
    def earlier_run(work: Path) -> None:
        old = work / "target" / OUTPUT[cmd]
        old.parent.mkdir(parents=True)
        old.write_text("what an earlier run wrote")

    def file_there(work: Path) -> None:
        (work / "target").write_text("a file the user had, where the output folder would go")

    def read_only(work: Path) -> None:
        (work / "target").mkdir()
        (work / "target" / "old.txt").write_text("a file the user had")
        (work / "target").chmod(0o555)

    def loop(work: Path) -> None:
        (work / "target").symlink_to(work / "target")

    return {  # fault -> (--out, setup, what the line says, extra env)
        "out-holds-old-outputs": ("target", earlier_run, rf"target.* {re.escape(OUTPUT[cmd])}.*--force", {}),
        "out-is-a-file": ("target", file_there, r"target", {}),
        "out-under-a-file": ("target/sub", file_there, r"target", {}),
        "out-read-only": ("target", read_only, r"(target.*Permission denied|Permission denied.*target)",
                          {"HOSTILE_AS_USER": "1"}),
        "out-symlink-loop": ("target", loop, r"target", {}),
        "out-in-dev-null": ("/dev/null/out", None, r"/dev/null", {}),
    }


def out_cases(f: dict) -> list[Case]:
    cases = []
    for cmd, argv in WRITERS.items():
        args = tuple(a.format(fam=f["family.json"], recording=f["recording.csv"]) for a in argv)
        for fault, (out, setup, says, env) in _out_faults(cmd).items():
            cases.append(Case(f"{cmd}-{fault}", (*args, "--out", out), says, uses_out=False, setup=setup, env=env,
                              budget_s=BUDGET_S, kind="out-folder"))
    return cases


# --- the cases ----------------------------------------------------------------------------------


def all_cases(f: dict) -> list[Case]:
    return reader_cases(f) + value_cases(f) + out_cases(f)


_KEYS = [*_FILE_NAMES, "recording.csv"]


def _case_ids() -> list[str]:
    return [c.id for c in all_cases({k: Path(k) for k in _KEYS})]


#: the sample that runs in process in the default run: every reader on its own kind's parse
#: fault, every path fault once, a few values (the full matrix runs with ``-m slow``)
def _sample_ids() -> list[str]:
    ids = _case_ids()
    return ids[::12]


@pytest.fixture(scope="module")
def matrix_files(tmp_path_factory, small_family):
    d = tmp_path_factory.mktemp("hostile-matrix")
    out = make_files(d, small_family)
    rec = d / "recording.csv"  # a Vicon export: two frames of three markers
    rec.write_text("Trajectories\n100\n,,A:M1,,,A:M2,,,A:M3,,\nFrame,Sub Frame,X,Y,Z,X,Y,Z,X,Y,Z\n,,mm,mm,mm,mm,mm,mm,"
                   "mm,mm,mm\n1,0,0,0,0,30,0,0,0,40,0\n2,0,0,0,0,30,0,0,0,40,0\n")
    out["recording.csv"] = rec
    return out


def test_case_ids_are_distinct_and_name_what_differs():
    ids = _case_ids()
    assert len(ids) == len(set(ids))
    for case in all_cases({k: Path(k) for k in _KEYS}):
        assert case.args not in ((), None)


@pytest.fixture(scope="module")
def matrix(matrix_files) -> dict:
    """Every case of the matrix by id."""
    return {c.id: c for c in all_cases(matrix_files)}


# file permissions do not hold for root in process: those cases run in the child, as a user
@pytest.mark.parametrize("case_id", [i for i in _sample_ids() if "unreadable" not in i and "read-only" not in i])
def test_hostile_matrix_in_process(case_id, matrix, tmp_path, monkeypatch, capsys):
    line = run_case_in_process(matrix[case_id], tmp_path, monkeypatch, capsys)
    if line is not None:
        says_the_way_out(matrix[case_id], line)


@pytest.mark.slow
@pytest.mark.parametrize("case_id", _case_ids())
def test_hostile_matrix(case_id, matrix, tmp_path):
    line = run_case_in_child(matrix[case_id], tmp_path)
    if line is not None:
        says_the_way_out(matrix[case_id], line)


# --- the pieces the matrix leans on ------------------------------------------------------------


def test_a_bad_value_names_the_file_it_came_from_not_an_option_that_replaced_it(tmp_path):
    from starforge.catalog import values_from
    from starforge.errors import StarforgeError
    from starforge.spec import from_mapping
    from starforge.tracking.presets import Preset

    path = tmp_path / "lab.toml"
    with pytest.raises(StarforgeError, match=rf"^{re.escape(str(path))}: holes must be"):
        with values_from(path):
            raise StarforgeError("holes must be in [0, 2], got 9")
    with pytest.raises(StarforgeError, match=r"^holes must be"):  # --set holes=9 gave it
        with values_from(path, given={"holes"}):
            raise StarforgeError("holes must be in [0, 2], got 9")
    with pytest.raises(StarforgeError, match=r"^holes must be"):  # a template name is not a file
        with values_from("flat"):
            raise StarforgeError("holes must be in [0, 2], got 9")
    for v in (float("nan"), float("inf"), -float("inf")):  # an integer field: one line, not int()'s error
        with pytest.raises(StarforgeError, match=r"rules.min_markers must be an integer"):
            from_mapping(Preset, {"name": "p", "rules": {"min_markers": v}})


def test_convert_and_export_take_the_same_id_range(small_family, tmp_path):
    """Numeric ids a tracker file holds: from 0 up to a signed 32-bit integer, the same for
    ``convert`` and ``export``; a negative first id is refused by both in one line."""
    fam = small_family[0] / "family.json"
    n = len(small_family[1]["stars"])
    for cmd in (["convert", fam, "--format", "atracsys"], ["export", fam, "--format", "atracsys"]):
        for first, code in ((-1, 2), (2**31 - n, 2), (2**31 - 1 - n, 0), (0, 0)):
            out = tmp_path / f"{cmd[0]}{first}"
            assert run_cli([*cmd, "--id-start", first, "--out", out, "-q"]) == code, (cmd[0], first)
            assert len(list(out.rglob("*.ini"))) == (n if code == 0 else 0)  # a geometry per body, or nothing


def test_a_print_bed_is_two_finite_sizes_within_bounds():
    from starforge.api.bodies import MAX_BED_MM, parse_bed
    from starforge.errors import StarforgeError

    assert parse_bed("200x250") == (200.0, 250.0)
    assert parse_bed(f"{MAX_BED_MM:g}x1") == (MAX_BED_MM, 1.0)
    for bad in ("nanx200", "infx200", "1e308x1e308", "0x200", f"{MAX_BED_MM * 1.01:g}x200", "200", "200x200x200"):
        with pytest.raises(StarforgeError, match=r"--bed must be WIDTHxDEPTH in mm"):
            parse_bed(bad)
