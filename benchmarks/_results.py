"""The docs' results page (``docs/results.md``): each benchmark writes its own section.

A benchmark run with ``--write-docs`` turns its JSON figures into Markdown and calls
:func:`write_section`, which replaces the text between ``<!-- begin KEY -->`` and
``<!-- end KEY -->`` (or appends the section when the page has none yet), stamped with the
command, the date and the machine.  The other sections stay as they were, so each keeps the
date and machine of the run that measured it.  The page is written atomically.
"""

from __future__ import annotations

import os
import platform
import re
import sys
import time
from pathlib import Path

from starforge.io import atomic_write_text

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results.md"

HEADER = """# Results

Measured figures, each section written by the benchmark named in it (`python
benchmarks/<script>.py ... --write-docs`) with the date and the machine of that run.  Wall
times depend on the machine and its load; CPU seconds depend far less on the load.
"""


def machine() -> str:
    """One line describing this machine: CPU count, architecture, Python, and the load averages
    when the line is written (the 5- and 15-minute ones cover a run that just ended)."""
    try:
        load = Path("/proc/loadavg").read_text().split()[:3]
        load_text = f", load {'/'.join(load)} (1 / 5 / 15 min) when written"
    except OSError:
        load_text = ""
    return (
        f"{os.cpu_count()}-core {platform.machine()}, {platform.system()}, "
        f"Python {platform.python_version()}{load_text}"
    )


def table(header: list[str], rows: list[list]) -> str:
    """A Markdown table; cells are turned into text, pipes escaped."""

    def cell(x) -> str:
        return "" if x is None else str(x).replace("|", "\\|")

    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    lines += ["| " + " | ".join(cell(x) for x in row) + " |" for row in rows]
    return "\n".join(lines)


def write_section(key: str, title: str, body: str, command: str | None = None, path: Path = RESULTS) -> Path:
    """Put ``body`` under ``## title`` in the section ``key`` of the results page, stamped with
    ``command`` (default: this process's command line), today's date (UTC) and the machine."""
    args = [a for a in sys.argv[1:] if a != "--write-docs"]
    command = command or " ".join(["python", f"benchmarks/{Path(sys.argv[0]).name}", *args])
    stamp = f"*Written by `{command}` on {time.strftime('%Y-%m-%d', time.gmtime())}, {machine()}.*"
    block = f"<!-- begin {key} -->\n## {title}\n\n{stamp}\n\n{body.strip()}\n<!-- end {key} -->"
    text = path.read_text(encoding="utf-8") if path.exists() else HEADER
    pattern = re.compile(rf"<!-- begin {re.escape(key)} -->.*?<!-- end {re.escape(key)} -->", re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: block, text, count=1)
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    return atomic_write_text(path, text if text.endswith("\n") else text + "\n")


README = RESULTS.parents[1] / "README.md"
SPEED_HEADER = ["command", "seconds", "benchmark", "measured"]


def write_speed_row(command: str, seconds: float, benchmark: str, path: Path = README) -> Path:
    """Put ``command``'s row (``seconds``, the ``benchmark`` command that measured it, today's
    date) into the README's speed table, between ``<!-- begin speed-table -->`` and
    ``<!-- end speed-table -->``: the row whose command cell is ``command`` is replaced, a new
    command is appended; the other rows keep their own figures and dates.  Written atomically."""
    text = path.read_text(encoding="utf-8")
    pattern = re.compile(r"(<!-- begin speed-table -->\n)(.*?)(<!-- end speed-table -->)", re.S)
    found = pattern.search(text)
    if not found:
        raise SystemExit(f"{path} has no speed table (<!-- begin speed-table --> ... <!-- end speed-table -->)")
    rows = [
        [c.strip() for c in line.strip().strip("|").split(" | ")]
        for line in found.group(2).splitlines()[2:]
        if line.startswith("|")
    ]
    row = [command, f"{seconds:.2f}", f"`{benchmark}`", time.strftime("%Y-%m-%d", time.gmtime())]
    rows = [row if r[0] == command else r for r in rows]
    if row not in rows:
        rows.append(row)
    lines = ["| " + " | ".join(SPEED_HEADER) + " |", "| " + " | ".join("---" for _ in SPEED_HEADER) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    text = text[: found.start(2)] + "\n".join(lines) + "\n" + text[found.end(2):]
    return atomic_write_text(path, text)
