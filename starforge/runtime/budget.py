"""Bounded cost: estimate memory and time before large work, refuse in one line past a limit.

Every command that allocates or loops in proportion to what the user typed calls
:func:`require_memory` / :func:`require_time` (or :func:`require_count`) with an estimate
*before* the work starts.  Past the limit it raises :class:`StarforgeError` naming the
estimate, the limit and what to change, which the CLI prints as one line with exit code 2.

The limits are the same for every command:

* memory: ``STARFORGE_MAX_MEMORY`` (``"2G"``, ``"1500M"``, bytes) or ``starforge --max-memory``;
  by default half of this machine's memory (the cgroup's limit where one is set);
* time: ``STARFORGE_MAX_SECONDS`` or ``starforge --max-seconds``; by default 2 hours.
  Work that may take longer than a few seconds also shows a progress bar.

Estimates are deliberately rough (within a factor of about 2); they exist to catch requests
that are orders of magnitude too large, not to meter the machine.
"""

from __future__ import annotations

import math
import os
import re
from pathlib import Path

from starforge.errors import StarforgeError

ENV_MEMORY = "STARFORGE_MAX_MEMORY"
ENV_SECONDS = "STARFORGE_MAX_SECONDS"
#: default share of the machine's memory one command may plan to use
MEMORY_FRACTION = 0.5
#: default wall-clock budget of one command, s
DEFAULT_SECONDS = 7200.0

_UNITS = {"": 1, "B": 1, "K": 1024, "KB": 1024, "KIB": 1024, "M": 1024**2, "MB": 1024**2, "MIB": 1024**2,
          "G": 1024**3, "GB": 1024**3, "GIB": 1024**3, "T": 1024**4, "TB": 1024**4, "TIB": 1024**4}


def parse_bytes(text: str, what: str = ENV_MEMORY) -> int:
    """``"2G"`` -> 2147483648; ``"1500M"``, ``"123456"``, ``"1.5GiB"`` also work (binary units)."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([A-Za-z]*)\s*", str(text))
    unit = m.group(2).upper() if m else None
    if m is None or unit not in _UNITS:
        raise StarforgeError(f"{what} must be a size such as 2G, 1500M or 123456 (bytes), got {text!r}")
    value = float(m.group(1)) * _UNITS[unit]
    if not math.isfinite(value) or value < 1024**2:
        raise StarforgeError(f"{what} must be at least 1M, got {text!r}")
    return int(value)


def format_bytes(n: float) -> str:
    """A byte count for people: ``17.6 GiB``, ``512 MiB``."""
    n = float(n)
    for unit, size in (("PiB", 1024**5), ("TiB", 1024**4), ("GiB", 1024**3), ("MiB", 1024**2), ("KiB", 1024)):
        if abs(n) >= size:
            return f"{n / size:.3g} {unit}" if n / size < 1e4 else f"{n / size:.3e} {unit}"
    return f"{n:.0f} B"


def format_seconds(s: float) -> str:
    """A duration for people: ``45 s``, ``12 min``, ``3.2 h``, ``4.1e+09 years``."""
    s = float(s)
    if s < 120:
        return f"{s:.3g} s"
    if s < 7200:
        return f"{s / 60:.3g} min"
    if s < 86400 * 3:
        return f"{s / 3600:.3g} h"
    if s < 86400 * 365 * 3:
        return f"{s / 86400:.3g} days"
    return f"{s / (86400 * 365):.3g} years"


def machine_memory_bytes() -> int:
    """Physical memory, or the cgroup (container) limit when that is smaller."""
    try:
        phys = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # pragma: no cover - non-POSIX
        phys = 8 * 1024**3
    for path in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            text = Path(path).read_text().strip()
        except OSError:
            continue
        if text.isdigit() and 0 < int(text) < phys:
            phys = int(text)
    return int(phys)


def memory_limit_bytes() -> int:
    """The memory one command may plan to use, bytes (see the module docstring)."""
    env = os.environ.get(ENV_MEMORY)
    if env:
        return parse_bytes(env)
    return int(MEMORY_FRACTION * machine_memory_bytes())


def time_limit_s() -> float:
    """The wall-clock budget of one command, s."""
    env = os.environ.get(ENV_SECONDS)
    if env:
        return parse_seconds(env, ENV_SECONDS)
    return DEFAULT_SECONDS


def parse_seconds(text, what: str = ENV_SECONDS) -> float:
    """A positive, finite number of seconds, or StarforgeError naming ``what`` (the variable or
    the option the user set)."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = float("nan")
    if not (math.isfinite(value) and value > 0):
        raise StarforgeError(f"{what} must be a positive, finite number of seconds, got {text!r}")
    return value


def _limit_source(env: str, flag: str) -> str:
    return f"set by {env} or starforge {flag}" if os.environ.get(env) else f"raise it with starforge {flag}"


def require_memory(nbytes: float, what: str, advice: str) -> None:
    """Refuse when ``what`` is estimated to need more than the memory limit.

    Parameters
    ----------
    nbytes : float
        Estimated peak memory of the work, bytes (may be astronomically large or inf).
    what : str
        The work, as the user would name it: ``"a visibility table of 5000 sites x 64000 poses"``.
    advice : str
        What to change: ``"lower --orientations or --resolution"``.
    """
    limit = memory_limit_bytes()
    if not (nbytes <= limit):  # also catches nan
        raise StarforgeError(
            f"{what} needs about {format_bytes(nbytes)} of memory, above the limit of {format_bytes(limit)} "
            f"({_limit_source(ENV_MEMORY, '--max-memory')}); {advice}"
        )


def require_time(seconds: float, what: str, advice: str) -> None:
    """Refuse when ``what`` is estimated to take longer than the time limit (same shape as
    :func:`require_memory`)."""
    limit = time_limit_s()
    if not (seconds <= limit):
        raise StarforgeError(
            f"{what} would take about {format_seconds(seconds)}, above the limit of {format_seconds(limit)} "
            f"({_limit_source(ENV_SECONDS, '--max-seconds')}); {advice}"
        )


def require_count(name: str, value: float, maximum: float, why: str = "") -> None:
    """A hard cap on a count the user typed (``ghosts``, ``frames``...), independent of the machine."""
    if not (value <= maximum):
        extra = f" ({why})" if why else ""
        raise StarforgeError(f"{name} must be at most {maximum:,g}, got {value:,g}{extra}")
