"""Print the README's commands, so that CI runs exactly what a newcomer reads.

    python .ci/readme_commands.py setup   # the first ```bash block of the README (the two set-up commands)
    python .ci/readme_commands.py tour    # the first ```bash block after the heading "## A five-minute tour"

One command per line, in order, each as written in the README with its trailing ``# comment``
removed (a ``#`` inside quotes or a word is kept); a line ending in ``\\`` continues on the next.
Exits 1 when the block is missing or empty, so that a README edit cannot make CI run nothing.
"""

from __future__ import annotations

import sys
from pathlib import Path

TOUR_HEADING = "## A five-minute tour"


def strip_comment(line: str) -> str:
    """``line`` without a trailing shell comment: a ``#`` that starts a word outside quotes."""
    quote = None
    prev = " "
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and prev.isspace():
            return line[:i].rstrip()
        prev = ch
    return line.rstrip()


def bash_block(lines: list[str], start: int) -> list[str]:
    """The commands of the first ```bash block at or after line ``start``."""
    i = start
    while i < len(lines) and lines[i].strip() != "```bash":
        i += 1
    commands: list[str] = []
    pending = ""
    for line in lines[i + 1:]:
        if line.strip().startswith("```"):
            break
        text = (pending + " " if pending else "") + strip_comment(line).strip()
        if text.endswith("\\"):
            pending = text[:-1].rstrip()
            continue
        pending = ""
        if text.strip():
            commands.append(text.strip())
    return commands


def readme_commands(readme: str, which: str) -> list[str]:
    """The commands of the README's set-up block (``which="setup"``) or of its tour (``"tour"``)."""
    lines = readme.splitlines()
    if which == "setup":
        return bash_block(lines, 0)
    if which == "tour":
        for k, line in enumerate(lines):
            if line.strip() == TOUR_HEADING:
                return bash_block(lines, k + 1)
        return []
    raise ValueError(f"which must be 'setup' or 'tour', got {which!r}")


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[1] not in ("setup", "tour"):
        sys.stderr.write("usage: readme_commands.py setup|tour\n")
        return 2
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    commands = readme_commands(readme, argv[1])
    if not commands:
        sys.stderr.write(f"error: README.md has no {argv[1]} commands\n")
        return 1
    sys.stdout.write("".join(c + "\n" for c in commands))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
