"""What the streamed selection (:mod:`starforge.stars.stream`) needs: memory and spill disk.

The size check (:func:`starforge.stars.estimate.check_size`) asks :func:`require_stream` before
any work whether a spec too large for memory fits the streamed path.
"""

from __future__ import annotations

import os
import shutil
import tempfile

from starforge.errors import StarforgeError
from starforge.runtime.budget import format_bytes, require_memory
from starforge.stars.spec import StarSpec

#: equal ranges of box volume the fitting stars are spilled into
BUCKETS = 1024
#: spill buffers are written out when they hold this much
SPILL_BUFFER_BYTES = 128 * 2**20
#: bytes per fitting star while one volume range is sorted (indices, volume, the sort's keys
#: and permutation), and a generous skew: a range may hold this many times its even share
SORT_BYTES_PER_STAR = 96
BUCKET_SKEW = 16
#: base memory of the streamed path (interpreter, kernels, chunk results in flight)
STREAM_BASE_BYTES = 400e6


def bitmap_sizes(spec: StarSpec) -> tuple[int, int]:
    """(face-key bitmap, window bitmap) lengths: pool^3 and 2 (pool + m)^3."""
    p, m = spec.pool_size, spec.grid_steps
    return p**3, 2 * (p + m) ** 3


def stream_bytes(spec: StarSpec, fits: float) -> float:
    """Peak memory of the streamed path for about ``fits`` fitting stars, bytes."""
    faces, windows = bitmap_sizes(spec)
    per_range = fits / BUCKETS * BUCKET_SKEW * SORT_BYTES_PER_STAR
    return faces + windows + SPILL_BUFFER_BYTES + min(per_range, fits * SORT_BYTES_PER_STAR) + STREAM_BASE_BYTES


def spill_dir() -> str:
    """Where the spill files go: ``STARFORGE_SPILL_DIR``, else the system's temporary folder."""
    return os.environ.get("STARFORGE_SPILL_DIR") or tempfile.gettempdir()


def require_stream(spec: StarSpec, labelled: float, fits: float) -> None:
    """Refuse in one line when the streamed path would not fit the memory limit or the spill
    folder's free disk (``fits``: fitting stars estimated from the pilot sample; twice that is
    asked of the disk, the pilot's share being a sample)."""
    require_memory(
        stream_bytes(spec, fits),
        f"the streamed selection among about {fits:,.0f} fitting stars (of {labelled:,.0f} labelled candidates)",
        "raise delta_mm, gap_mm or tolerance_mm, or raise the memory limit",
    )
    disk = 2 * fits * 14
    where = spill_dir()
    free = shutil.disk_usage(where).free
    if disk > free:
        raise StarforgeError(
            f"the streamed selection among about {fits:,.0f} fitting stars spills about {format_bytes(disk)} "
            f"to {where}, which has {format_bytes(free)} free; set STARFORGE_SPILL_DIR to a larger folder "
            f"or raise delta_mm"
        )
