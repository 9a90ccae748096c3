"""Catalogs as data: named TOML templates shipped in ``templates/<kind>/<name>.toml``.

The folder is installed as the package ``starforge.templates`` (see pyproject), so names
resolve the same after an editable or a plain ``pip install .``.
"""

from __future__ import annotations

import contextlib
import re
import tomllib
from importlib import resources
from pathlib import Path

from starforge.errors import StarforgeError

KINDS = ("stars", "mounts", "rigs", "place", "presets", "markers")
#: the parameter (and the command line's option) that names a template of each kind
PARAMETERS = {"stars": "spec", "mounts": "mount", "rigs": "rig", "place": "spec", "presets": "preset",
              "markers": "marker"}


def _kind_dir(kind: str):
    if kind not in KINDS:
        raise StarforgeError(f"unknown template kind {kind!r}; known: {', '.join(KINDS)}")
    return resources.files("starforge.templates").joinpath(kind)


def list_templates(kind: str) -> list[str]:
    """Names (file stems) of the shipped templates of one kind, sorted."""
    folder = _kind_dir(kind)
    if not folder.is_dir():
        return []
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def read_toml(path: str | Path) -> dict:
    """Parse a TOML file with one-line errors for missing or corrupt files."""
    from starforge.io import check_input_file

    path = check_input_file(path, "spec file", "toml")
    try:
        return tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a byte-order mark (Windows editors) is fine
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise StarforgeError(f"spec file {path} is not valid TOML ({exc}); fix that line") from None


def is_path(name_or_path: str | Path) -> bool:
    """Whether a template argument names a file (``x.toml``, ``dir/x``) rather than a template."""
    text = str(name_or_path)
    return text.endswith(".toml") or "/" in text or "\\" in text


@contextlib.contextmanager
def values_from(name_or_path: str | Path, given=()):
    """A StarforgeError raised in the block (a value out of range, a key missing) names the TOML
    file the values came from, when ``name_or_path`` is a file and the line does not name it yet;
    not an error about one of the ``given`` keys (values an option set in place of the file's)."""
    try:
        yield
    except StarforgeError as exc:
        said = str(exc)
        key = re.match(r"\w+", said)
        ours = key is None or key.group(0) not in given
        if is_path(name_or_path) and ours and str(name_or_path) not in said:
            raise StarforgeError(f"{name_or_path}: {said}") from None
        raise


def unknown_name(parameter: str, kind: str, text: str, what: str = "a template name") -> StarforgeError:
    """The error for a name that is no template of ``kind``, led by the ``parameter`` that took it:
    an empty name said as such, the known names listed with the command that lists them."""
    known = f"known (starforge templates {kind}): {', '.join(list_templates(kind)) or '(none)'}"
    if not text.strip():
        return StarforgeError(f"{parameter} is empty: give {what} or a TOML file; {known}")
    return StarforgeError(f"{parameter} must be {what} or a TOML file, got {text!r}; {known}")


def load_template(kind: str, name_or_path: str | Path, parameter: str | None = None) -> tuple[str, dict]:
    """Resolve a template name (``finger``) or a TOML path; return ``(name, data)``.

    An unknown name raises StarforgeError led by ``parameter`` (default: the one that names a
    template of ``kind``, :data:`PARAMETERS`), listing the known names.
    """
    text = str(name_or_path)
    if is_path(text):
        path = Path(text)
        return path.stem, read_toml(path)
    known = list_templates(kind)
    if text not in known:
        raise unknown_name(parameter or PARAMETERS[kind], kind, text)
    res = _kind_dir(kind).joinpath(f"{text}.toml")
    try:
        return text, tomllib.loads(res.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:  # a shipped template is broken: still one clear line
        raise StarforgeError(f"template {kind}/{text} is not valid TOML: {exc}") from None

