"""The one exception type a user ever sees as a message (never as a traceback)."""

from __future__ import annotations


class StarforgeError(ValueError):
    """Bad input or an impossible request: the CLI prints it as one line and exits with code 2.

    It subclasses ValueError so library callers can catch the usual type; messages name the
    parameter and the allowed range, e.g. ``delta_mm must be > 0, got -1.5``.
    """


class NoStarError(StarforgeError):
    """A spec that admits no star at all (an answer, not a failure: a capacity sweep records 0)."""
