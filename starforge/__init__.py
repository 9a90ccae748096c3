"""starforge: geometry of optical motion-capture markers.

Marker-star families (unique 4-sphere rigid bodies), printable bodies, prop marker
placement and tracker files.  ``import starforge`` stays light: heavy libraries
(build123d, trimesh, matplotlib) are imported where they are used.
"""

from __future__ import annotations

# first: when this process is the starforge command, a signal from here on ends it with one line
from starforge.runtime.stop import launched_as_command, stop_early_in_command

stop_early_in_command()
if launched_as_command():
    from starforge.runtime.threads import one_blas_thread

    one_blas_thread()  # before numpy loads

__version__ = "0.1.0"

__all__ = ["__version__", "cache_dir", "load_family", "StarforgeError"]

from starforge.errors import StarforgeError  # noqa: E402
from starforge.runtime.cache import cache_dir, point_numba_cache  # noqa: E402

point_numba_cache()


def load_family(path):
    """Read a ``family.json`` back into a :class:`starforge.stars.model.Family`.

    Parameters
    ----------
    path : str or Path
        A ``family.json`` file, or the folder that holds one.
    """
    from starforge.stars.model import load_family as _load

    return _load(path)
