"""starforge's cache folder, and numba's cache inside it (values kept there by content:
:mod:`starforge.runtime.stored`)."""

from __future__ import annotations

import os
import sys


def cache_dir() -> str:
    """starforge's cache folder: ``STARFORGE_CACHE_DIR``, else the user's cache folder
    (platformdirs), never inside the installed package (a reinstall would leave stale files
    there, and a leftover ``__pycache__`` folder would shadow an editable install)."""
    path = os.environ.get("STARFORGE_CACHE_DIR")
    if not path:
        from platformdirs import user_cache_dir

        path = user_cache_dir("starforge", appauthor=False)
    return path


def point_numba_cache() -> None:
    """Compiled kernels are cached under :func:`cache_dir` (``NUMBA_CACHE_DIR`` set by the user
    wins).  Runs before any starforge module imports numba."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    path = os.path.join(cache_dir(), "numba")
    os.environ["NUMBA_CACHE_DIR"] = path
    if "numba" in sys.modules:  # imported before starforge: its config is already read
        sys.modules["numba"].config.CACHE_DIR = path
