"""Print the commands of the README and of the docs pages, so that CI runs exactly what a reader reads.

    python .ci/readme_commands.py setup       # the first ```bash block of the README (the two set-up commands)
    python .ci/readme_commands.py tour        # the first ```bash block after the heading "## A five-minute tour"
    python .ci/readme_commands.py docs PAGE   # every command of every ```bash / ```sh block of a docs page

One command per line, in order, each as written with its trailing ``# comment`` removed (a ``#``
inside quotes or a word is kept) and lines that are only a comment dropped; a line ending in ``\\``
continues on the next.  Exits 1 when there are no commands, so that an edit cannot make CI run nothing.
tests/test_docs_commands.py imports this module to run the docs pages' commands.
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


#: the fence languages whose blocks are shell commands a reader types
SHELL_LANGUAGES = ("bash", "sh", "shell")


def block_commands(block: list[str]) -> list[str]:
    """The commands of a fenced block's lines (the fences excluded)."""
    commands: list[str] = []
    pending = ""
    for line in block:
        text = (pending + " " if pending else "") + strip_comment(line).strip()
        if text.endswith("\\"):
            pending = text[:-1].rstrip()
            continue
        pending = ""
        if text.strip():
            commands.append(text.strip())
    if pending:
        commands.append(pending)
    return commands


def fenced_blocks(lines: list[str], start: int = 0) -> list[tuple[str, list[str]]]:
    """Every fenced block at or after line ``start``: (its language, "" when none; its lines)."""
    blocks: list[tuple[str, list[str]]] = []
    i = start
    while i < len(lines):
        fence = lines[i].strip()
        if fence.startswith("```"):
            body: list[str] = []
            i += 1
            while i < len(lines) and not lines[i].strip().startswith("```"):
                body.append(lines[i])
                i += 1
            blocks.append((fence[3:].strip().lower(), body))
        i += 1
    return blocks


def bash_block(lines: list[str], start: int) -> list[str]:
    """The commands of the first ```bash block at or after line ``start``."""
    for language, body in fenced_blocks(lines, start):
        if language == "bash":
            return block_commands(body)
    return []


def page_commands(page: str) -> list[list[str]]:
    """The commands of each ```bash / ```sh block of a docs page, block by block, in page order."""
    return [block_commands(body) for language, body in fenced_blocks(page.splitlines())
            if language in SHELL_LANGUAGES]


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
    if len(argv) == 3 and argv[1] == "docs":
        commands = [c for block in page_commands(Path(argv[2]).read_text(encoding="utf-8")) for c in block]
        source = argv[2]
    elif len(argv) == 2 and argv[1] in ("setup", "tour"):
        readme = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
        commands = readme_commands(readme, argv[1])
        source = f"README.md's {argv[1]}"
    else:
        sys.stderr.write("usage: readme_commands.py setup|tour|docs PAGE\n")
        return 2
    if not commands:
        sys.stderr.write(f"error: {source} has no commands\n")
        return 1
    sys.stdout.write("".join(c + "\n" for c in commands))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
