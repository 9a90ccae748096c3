"""What a person sees while the long commands run: each one in a detached tmux pane, captured often.

Runs ``starforge stars --delta 1.0``, ``starforge export`` of a 25-star family with its plate (the
family made first with ``starforge stars --count 25 --mount flat``), ``starforge place run hammer``
and ``starforge check`` of that family.  Each command runs first with ``-q``, its output piped:
the lines it writes on stdout and on stderr (target: 0 and 0); that run also compiles the kernels
a first run compiles (a compiler holds Python's lock, so nothing on screen moves while it
works; the command says so in a note).  Then it runs in its own tmux session of a fixed size on
a private tmux server, its pane captured every ``--every`` seconds (``tmux capture-pane -p``)
while it runs, and JSON per command is printed:

- ``longest_still_s``: the longest time the screen did not change (target: at most 2 s);
- ``captures_naming_a_stage``: the share of the captures, from the command's first screen to
  the last that shows a stage (after it the command prints its result), that show the name of a
  stage (target: 1.0), and the stages seen; ``result_after_last_stage_s``: the time after it;
- ``first_screen_s``: when the pane first showed anything; ``total_s``: the command's time.

    python benchmarks/bench_screen.py [--only stars,export,place,check] [--delta 1.0] [--no-quiet]

Needs tmux on PATH.  Runs with the Python that runs it (``python -m starforge``) and its
environment, so a worktree's ``PYTHONPATH`` is kept.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: every stage name the library reports (starforge.runtime.progress), as a bar or a plain line shows it
STAGES = (
    "compile",
    "enumerate",
    "select",
    "verify",
    "render",
    "mesh",
    "STEP",
    "plate",
    "preview",
    "sheet",
    "sites",
    "rays",
    "optimise",
    "evaluate",
    "simulate",
    "curve",
    "load",
    "write",
)
#: a rich bar (the stage's name, then its bar) or a plain line (``starforge CMD: N s, NAME...``)
_STAGE_LINE = re.compile(
    r"^(?:starforge [a-z-]+: \d+ s, )?(" + "|".join(STAGES) + r")(?: +[━╸╺]|:| started)", re.M
)

WIDTH, HEIGHT = 120, 40


def _tmux(server: str, *args: str, check: bool = True) -> str:
    done = subprocess.run(["tmux", "-L", server, *args], capture_output=True, text=True, check=check)
    return done.stdout


def watch(server: str, name: str, argv: list[str], cwd: Path, every_s: float, dump: Path | None = None) -> dict:
    """Run ``argv`` in a detached tmux session of WIDTH x HEIGHT and capture its pane every
    ``every_s`` until it ends; the figures of :func:`main`'s docstring."""
    mark = cwd / f".{name}.rc"
    shell = f"{shlex.join(argv)}; echo $? > {shlex.quote(str(mark))}; sleep 3600"
    t0 = time.time()
    _tmux(server, "new-session", "-d", "-s", name, "-x", str(WIDTH), "-y", str(HEIGHT), "-c", str(cwd), shell)
    captures: list[tuple[float, str]] = []
    try:
        while not mark.exists() or not mark.read_text().strip():
            screen = _tmux(server, "capture-pane", "-p", "-t", name, check=False)
            captures.append((time.time() - t0, screen))
            time.sleep(every_s)
        total = time.time() - t0
        rc = int(mark.read_text())
        last = _tmux(server, "capture-pane", "-p", "-t", name, check=False)
        if dump is not None:
            dump.mkdir(parents=True, exist_ok=True)
            text = "".join(f"--- {t:.2f} s\n{s}" for t, s in captures)
            (dump / f"{name}.txt").write_text(text)
    finally:
        _tmux(server, "kill-session", "-t", name, check=False)
    return {"exit_code": rc, "total_s": round(total, 1), **screen_figures(captures, total), "last_screen": _tail(last)}


def _tail(screen: str, lines: int = 4) -> list[str]:
    return [ln.rstrip() for ln in screen.rstrip().splitlines()[-lines:]]


def screen_figures(captures: list[tuple[float, str]], total_s: float) -> dict:
    """The longest still time (from the first screen to the end), the share of the captures from
    the first screen on that name a stage, and the stages seen."""
    shown = [(t, s) for t, s in captures if s.strip()]
    if not shown:
        return {"first_screen_s": None, "longest_still_s": round(total_s, 1), "captures_naming_a_stage": 0.0}
    still, since, before = 0.0, shown[0][0], shown[0][1]
    worst_at = since
    for t, s in shown[1:]:
        if s != before:
            if t - since > still:
                still, worst_at = t - since, since
            since, before = t, s
    if total_s - since > still:
        still, worst_at = total_s - since, since
    named = [_STAGE_LINE.findall(s) for _, s in shown]
    # after the last bar the command prints its result: the work is over
    last = max((k for k, n in enumerate(named) if n), default=len(named) - 1)
    working = named[: last + 1]
    blank = [round(t, 1) for (t, _), n in zip(shown[: last + 1], working, strict=True) if not n]
    return {
        "first_screen_s": round(shown[0][0], 2),
        "longest_still_s": round(still, 2),
        "longest_still_from_s": round(worst_at, 1),
        "captures": len(shown),
        "captures_naming_a_stage": round(sum(bool(n) for n in working) / len(working), 3),
        "result_after_last_stage_s": round(total_s - shown[last][0], 2),
        "captures_without_a_stage_at_s": blank[:12],
        "stages_seen": sorted({x for n in named for x in n}, key=STAGES.index),
    }


def quiet_lines(argv: list[str], cwd: Path) -> dict:
    """``argv`` with ``-q``, stdout and stderr piped: its exit code and the lines on each."""
    done = subprocess.run([*argv, "-q"], cwd=cwd, capture_output=True, text=True)
    return {
        "exit_code": done.returncode,
        "stdout_lines": len(done.stdout.splitlines()),
        "stderr_lines": len(done.stderr.splitlines()),
        "stderr_head": done.stderr.splitlines()[:3],
    }


def commands(tmp: Path, delta: float) -> dict[str, list[str]]:
    sf = [sys.executable, "-m", "starforge"]
    fam = tmp / "fam25" / "family.json"
    return {
        "stars": [*sf, "stars", "--delta", f"{delta:g}", "--out", str(tmp / "stars"), "--force"],
        "export": [*sf, "export", str(fam), "--out", str(tmp / "bodies"), "--force"],
        "place": [*sf, "place", "run", "hammer", "--out", str(tmp / "place"), "--force"],
        "check": [*sf, "check", str(fam), "--out", str(tmp / "check"), "--force"],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", default="stars,export,place,check", help="comma list of the commands to watch")
    ap.add_argument("--delta", type=float, default=1.0)
    ap.add_argument("--every", type=float, default=0.25, help="seconds between two captures")
    ap.add_argument("--no-quiet", action="store_true", help="skip the piped -q runs")
    ap.add_argument("--dump", type=Path, help="write every capture of each command to DUMP/<command>.txt")
    args = ap.parse_args()
    if shutil.which("tmux") is None:
        sys.exit("bench_screen needs tmux on PATH")
    server = f"starforge-bench-{os.getpid()}"
    out: dict = {"pane": f"{WIDTH}x{HEIGHT}", "every_s": args.every}
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        if {"export", "check"} & set(args.only.split(",")):
            subprocess.run(
                [sys.executable, "-m", "starforge", "-q", "stars", "--count", "25", "--mount", "flat", "--out", str(tmp / "fam25")],
                check=True,
            )
        cmds = commands(tmp, args.delta)
        try:
            for name in args.only.split(","):
                out[name] = {"command": shlex.join(["starforge", *cmds[name][3:]])}
                if not args.no_quiet:  # first: a first run's kernels compile here, not on screen
                    out[name]["quiet_piped"] = quiet_lines(cmds[name], tmp)
                out[name]["screen"] = watch(server, name, cmds[name], tmp, args.every, args.dump)
                print(json.dumps({name: out[name]}), file=sys.stderr, flush=True)
        finally:
            _tmux(server, "kill-server", check=False)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
