"""setuptools' build backend, asking for numba and numpy when it builds a wheel: ``setup.py``
compiles the kernels ahead of time then (``starforge/runtime/kernels.py``).  Editable installs and
source distributions need neither."""

from setuptools import build_meta as _meta
from setuptools.build_meta import *  # noqa: F403  (the backend's hooks, unchanged)


def get_requires_for_build_wheel(config_settings=None):
    return [*_meta.get_requires_for_build_wheel(config_settings), "numba>=0.60", "numpy>=1.26"]
