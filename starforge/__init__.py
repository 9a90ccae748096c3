"""starforge: geometry of optical motion-capture markers.

Marker-star families (unique 4-sphere rigid bodies), printable bodies, prop marker
placement and tracker files.  ``import starforge`` stays light: heavy libraries
(build123d, trimesh, matplotlib) are imported where they are used.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["__version__", "cache_dir", "load_family", "StarforgeError"]

import os as _os

from starforge.errors import StarforgeError


def cache_dir() -> str:
    """starforge's cache folder: ``STARFORGE_CACHE_DIR``, else the user's cache folder
    (platformdirs), never inside the installed package (a reinstall would leave stale files
    there, and a leftover ``__pycache__`` folder would shadow an editable install)."""
    path = _os.environ.get("STARFORGE_CACHE_DIR")
    if not path:
        from platformdirs import user_cache_dir

        path = user_cache_dir("starforge", appauthor=False)
    return path


def _point_numba_cache() -> None:
    """Compiled kernels are cached under :func:`cache_dir` (``NUMBA_CACHE_DIR`` set by the user
    wins).  Runs before any starforge module imports numba."""
    if _os.environ.get("NUMBA_CACHE_DIR"):
        return
    path = _os.path.join(cache_dir(), "numba")
    _os.environ["NUMBA_CACHE_DIR"] = path
    import sys as _sys

    if "numba" in _sys.modules:  # imported before starforge: its config is already read
        _sys.modules["numba"].config.CACHE_DIR = path


_point_numba_cache()


def load_family(path):
    """Read a ``family.json`` back into a :class:`starforge.stars.model.Family`.

    Parameters
    ----------
    path : str or Path
        A ``family.json`` file, or the folder that holds one.
    """
    from starforge.stars.model import load_family as _load

    return _load(path)
