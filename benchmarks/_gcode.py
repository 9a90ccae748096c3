"""G-code reading for bench_cad: extrusion segments per layer (absolute or relative E)."""

from __future__ import annotations

import re

import numpy as np

_WORD = re.compile(r"([XYZEF])(-?[0-9.]+)")


def extrusions(text: str) -> dict:
    """{layer Z (rounded to 0.001 mm): (n, 4) array of extruded segments x0, y0, x1, y1}."""
    x = y = z = e = 0.0
    relative = False
    out: dict = {}
    for line in text.splitlines():
        if not line or line[0] == ";":
            continue
        code = line.split(";", 1)[0].strip()
        if code.startswith("M83"):
            relative = True
        elif code.startswith("M82"):
            relative = False
        elif code.startswith("G92"):
            for k, v in _WORD.findall(code):
                if k == "E":
                    e = float(v)
        elif code.startswith(("G1 ", "G0 ")):
            w = dict(_WORD.findall(code))
            nx, ny = float(w.get("X", x)), float(w.get("Y", y))
            if "Z" in w:
                z = float(w["Z"])
            if "E" in w:
                ne = float(w["E"])
                extruding = ne > 0 if relative else ne > e + 1e-9
                if not relative:
                    e = ne
                if extruding and (nx != x or ny != y):
                    out.setdefault(round(z, 3), []).append((x, y, nx, ny))
            x, y = nx, ny
    return {k: np.array(v) for k, v in out.items()}


def covered(segments: np.ndarray, rect, inset: float = 0.05, samples: int = 9) -> bool:
    """Whether any point sampled along the segments lies inside ``rect`` (x0, x1, y0, y1) shrunk
    by ``inset`` (mm)."""
    if segments is None or len(segments) == 0:
        return False
    t = np.linspace(0.0, 1.0, samples)[None, :]
    px = segments[:, :1] + t * (segments[:, 2:3] - segments[:, :1])
    py = segments[:, 1:2] + t * (segments[:, 3:4] - segments[:, 1:2])
    x0, x1, y0, y1 = rect
    inside = (px > x0 + inset) & (px < x1 - inset) & (py > y0 + inset) & (py < y1 - inset)
    return bool(inside.any())
