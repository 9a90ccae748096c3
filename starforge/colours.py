"""One colour per body, the same in every file starforge writes (tracker bodies, STEP, 3MF)."""

from __future__ import annotations

import colorsys


def body_colour(k: int) -> tuple[int, int, int]:
    """A distinct colour for body ``k`` (0-based): hues spread by the golden angle, (r, g, b) 0..255."""
    h = (k * 0.618033988749895) % 1.0
    r, g, b = colorsys.hsv_to_rgb(h, 0.85, 0.95)
    return int(round(255 * r)), int(round(255 * g)), int(round(255 * b))
