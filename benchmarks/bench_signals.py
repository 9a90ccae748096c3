"""SIGTERM and SIGINT at seeded random moments of every long command, as one figure.

Each trial starts a command (the real CLI in a child of its own session, as the hostile suite
runs it), waits a seeded random delay drawn from the command's window (start-up included) and
sends SIGTERM or SIGINT (alternately per round).  A trial is clean when the command

* exits within 2 s of the signal with the signal's code (128 + signal) and the one line
  ``terminated; no output was changed`` / ``interrupted; ...`` (progress lines aside), or, for
  a signal that came while the outputs were renamed into place, ``terminated after its outputs
  were written to OUT`` with the outputs there; no traceback and no warning on stderr,
* leaves no process behind: none in its session, and none anywhere that descends from it (this
  script makes itself the child subreaper, so an orphan that left the session is reparented
  here and found),
* leaves no staging folder and the working folder byte for byte as it was, or with only the new
  outputs added when its line says so (after a 1 s grace, in which a helper that outlived the
  command would have written).

The commands run as the hostile suite's cases do (``tests.test_hostile_inputs.CHILD``), with an
address-space cap of :data:`ADDRESS_SPACE_BYTES` instead of the cases' 2 GiB: ``stars --delta 1.0``
needs more than 2 GiB of address space, and a trial measures the signal, not a run out of memory.

A command that had already ended when its signal was due counts as ``ended_first`` (clean when
it exited 0 with nothing left behind) and is not a signal trial.  A signal that arrives while the
interpreter itself starts, before the first line of starforge runs (``import starforge`` sets the
command's handlers first), meets Python's own handling: SIGTERM or an early SIGINT ends the
process by the signal's default action (no line); a SIGINT while Python imports its ``site``
module or the launcher reaches ``import starforge`` ends in CPython's own ``KeyboardInterrupt``
report, with no frame of starforge in it.  Those trials are counted in ``before_starforge`` (with
their outcomes) and are clean when the process exits within 2 s and leaves nothing: no program
can handle a signal before its first line runs.

Prints JSON: signal trials clean / total, the slowest exit after a signal, the not-clean trials
(command, signal, delay, what was wrong), the CPU seconds of all trials and the load average.

Run from the repository root: ``python benchmarks/bench_signals.py [--trials 100] [--seed 0]
[--only stars,check]``.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from tests.test_hostile_inputs import CHILD, left_in_session, snapshot  # noqa: E402

#: command -> (arguments, the window the signal's delay is drawn from, s); each runs well past
#: its window on an idle machine, so the signal lands in the work, start-up included
COMMANDS = {
    "stars": (("stars", "--delta", "1.0"), 8.0),
    "export": (("export", "{family}", "--allow-oversize", "--preview", "--format", "step,stl,qtm"), 8.0),
    "place": (("place", "run", "hammer"), 3.0),
    "place-batch": (("place-batch", "hammer", "hammer", "--workers", "2"), 7.0),
    "check": (("check", "{family}", "--frames", "200000"), 8.0),
    "sweep-local-cluster": (
        ("sweep", "--delta", "1:3:0.5", "--cube", "18:30:3", "--samples", "20000", "--workers", "2"), 16.0),
}
#: the address space each command may map (``ulimit -v``), bytes
ADDRESS_SPACE_BYTES = 8 * 1024**3
EXIT_WITHIN_S = 2.0
GRACE_S = 1.0
#: what a command says while it works (progress, where it runs): not the line about the signal
PROGRESS = re.compile(r"^(starforge [a-z-]+|stars|export|place|place-batch|check|sweep): ")


def main() -> None:
    import numpy as np

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--only", default=None, help="comma-separated commands (default: all)")
    opts = ap.parse_args()
    names = opts.only.split(",") if opts.only else list(COMMANDS)
    # a shell starts a background job with Ctrl-C ignored, and a child inherits that; the
    # commands are measured as a terminal starts them
    signal.signal(signal.SIGINT, signal.default_int_handler)
    _become_subreaper()
    rng = np.random.default_rng(opts.seed)
    rows = []
    cpu0 = os.times()
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-signals-") as d:
        family = _family(Path(d))
        for t in range(opts.trials):
            name = names[t % len(names)]
            sig = signal.SIGTERM if (t // len(names)) % 2 == 0 else signal.SIGINT
            args, window = COMMANDS[name]
            delay = float(rng.uniform(0.05, window))
            row = _trial(Path(d) / f"t{t}", [a.format(family=family) for a in args], sig, delay)
            rows.append({"trial": t, "command": name, "signal": sig.name, "delay_s": round(delay, 2), **row})
            print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    cpu1 = os.times()
    signalled = [r for r in rows if not r["ended_first"]]
    slowest = max(signalled, key=lambda r: r["exit_s"], default=None)
    print(json.dumps({
        "signal_trials_clean": sum(r["clean"] for r in signalled),
        "signal_trials": len(signalled),
        "ended_first": len(rows) - len(signalled),
        "ended_first_clean": sum(r["clean"] for r in rows if r["ended_first"]),
        "before_starforge": sum(r["before_starforge"] for r in signalled),
        "before_starforge_outcomes": sorted({r["outcome"] for r in signalled if r["before_starforge"]}),
        "worst_exit_s": round(slowest["exit_s"], 2) if slowest else None,
        "worst_exit_case": {k: slowest[k] for k in ("command", "signal", "delay_s")} if slowest else None,
        "not_clean": [{k: r[k] for k in ("trial", "command", "signal", "delay_s", "problems")}
                      for r in rows if not r["clean"]],
        "per_command": {n: f"{sum(r['clean'] for r in signalled if r['command'] == n)}/"
                           f"{sum(1 for r in signalled if r['command'] == n)}" for n in names},
        "cpu_seconds_children": round(cpu1.children_user + cpu1.children_system
                                      - cpu0.children_user - cpu0.children_system, 1),
        "wall_seconds": round(time.perf_counter() - t_start, 1),
        "load_average": os.getloadavg(),
        "seed": opts.seed,
    }, indent=2))


def _become_subreaper() -> None:
    """Orphans of a trial's command are reparented to this process (Linux PR_SET_CHILD_SUBREAPER),
    so a helper that left the command's session is still found."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0)


def _orphans(skip: int) -> list[int]:
    """Live processes whose parent is this script (other than ``skip``), after reaping zombies."""
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            break
        if pid == 0:
            break
    me, found = os.getpid(), []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == me and fields[0] != "Z" and int(stat.parent.name) != skip:
            found.append(int(stat.parent.name))
    return found


def _family(d: Path) -> str:
    """A small family.json made by the CLI, for export and check."""
    out = d / "family"
    subprocess.run([sys.executable, "-m", "starforge", "-q", "stars", "--box", "16", "12", "24", "--delta", "2",
                    "--out", str(out)], check=True, env={**os.environ, "PYTHONPATH": str(ROOT)})
    return str(out / "family.json")


def _trial(work: Path, argv: list[str], sig: signal.Signals, delay: float) -> dict:
    out = work / "out"
    out.mkdir(parents=True)
    (out / "keep.txt").write_text("a file the user had")
    before = snapshot(work)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1",
           "HOSTILE_AS_BYTES": str(ADDRESS_SPACE_BYTES)}
    proc = subprocess.Popen([sys.executable, "-c", CHILD, *argv, "--out", str(out), "--force"], cwd=work,
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    said: list[str] = []
    reader = threading.Thread(target=lambda: said.extend(proc.stderr), daemon=True)
    reader.start()
    problems: list[str] = []
    t_sig = time.monotonic() + delay
    while time.monotonic() < t_sig and proc.poll() is None:
        time.sleep(0.01)
    ended_first = proc.poll() is not None
    exit_s = 0.0
    if not ended_first:
        os.kill(proc.pid, sig)
        t0 = time.perf_counter()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            problems.append("no exit within 30 s")
        exit_s = time.perf_counter() - t0
        if exit_s > EXIT_WITHIN_S:
            problems.append(f"exit {exit_s:.2f} s after the signal")
    reader.join(5)
    time.sleep(GRACE_S)
    left = left_in_session(proc.pid)
    orphans = _orphans(proc.pid)
    if left or orphans:
        problems.append(f"processes left: session {left}, orphans {orphans}")
        for pid in set(left) | set(orphans):
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
    err = "".join(said)
    lines = [line for line in err.splitlines() if not PROGRESS.match(line)]
    early = not ended_first and _before_starforge(proc.returncode, sig, err, lines)
    if "Warning" in err or ("Traceback" in err and not early):
        problems.append("traceback or warning: " + " | ".join(lines[-3:])[:300])
    stages = [str(p.relative_to(work)) for p in work.rglob("*.staging")]
    if stages:
        problems.append(f"staging folders left: {stages}")
    if ended_first:
        if proc.returncode != 0:
            problems.append(f"ended before the signal with exit {proc.returncode}: {lines[-1:]}")
    elif early:
        if snapshot(work) != before:
            problems.append("the working folder changed")
    else:
        word = "terminated" if sig == signal.SIGTERM else "interrupted"
        if proc.returncode != 128 + sig:
            problems.append(f"exit {proc.returncode}, not {128 + sig}")
        after = snapshot(work)
        if lines == [f"{word} after its outputs were written to {out}"]:  # signalled while publishing
            if {k: after.get(k) for k in before} != before or len(after) == len(before):
                problems.append("said the outputs were written, but the working folder says otherwise")
        elif lines != [f"{word}; no output was changed"]:
            problems.append(f"stderr {lines[:3]}"[:300])
        elif after != before:
            problems.append("the working folder changed")
    outcome = f"exit {proc.returncode}: " + (lines[-1][:60] if lines else "no line")
    return {"clean": not problems, "ended_first": ended_first, "exit_s": round(exit_s, 3), "code": proc.returncode,
            "before_starforge": early, "outcome": outcome, "problems": problems}


def _before_starforge(code: int, sig: signal.Signals, err: str, lines: list[str]) -> bool:
    """Whether the signal ended the process before the first line of starforge ran: the signal's
    default action with nothing said, or CPython's own report of a KeyboardInterrupt (while it
    imports ``site``, or before the launcher's ``import starforge`` ran) without a starforge frame."""
    if code == -sig and not lines:
        return True
    frames = re.findall(r'File "([^"]+)"', err)
    return (sig == signal.SIGINT and code in (1, -sig) and lines[-1:] == ["KeyboardInterrupt"]
            and not any("/starforge/" in f for f in frames))


if __name__ == "__main__":
    main()
