"""The two things every picture needs: matplotlib's pyplot on the Agg backend (imported only
when a picture is drawn) and a byte-stable, atomic PNG write."""

from __future__ import annotations

import io
from pathlib import Path


def pyplot():
    """matplotlib.pyplot with the non-interactive Agg backend.  A character its fonts lack (a
    CJK prop or file name in a title) is drawn as a box without a warning per glyph on stderr:
    the name itself is written in full in the text outputs."""
    import warnings

    import matplotlib

    warnings.filterwarnings("ignore", message=r"Glyph \d+ .* missing from font", category=UserWarning)
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path: str | Path, dpi: int = 100) -> Path:
    """Write ``fig`` as PNG atomically; no 'Software' metadata, so the same figure gives the same bytes."""
    from starforge.io import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    return atomic_write_bytes(path, buf.getvalue())
