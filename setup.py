"""Builds a wheel whose kernels are compiled ahead of time (``starforge/kernels.zip``).

The project is configured in ``pyproject.toml``; this file only adds one step to ``build_py``:
after the package is copied into the build folder, :func:`starforge.runtime.kernels.prebuild` compiles
the kernels a ``starforge stars`` and a ``starforge place`` run load and packs them beside the
code, so that the first run after ``pip install .`` loads them instead of compiling (see
``starforge/runtime/kernels.py``).
Editable installs skip it (their kernels are compiled on first use and cached), as does
``STARFORGE_PREBUILD=0``; a build where it fails (no numba, say) still succeeds, without the zip.
"""

import os
import subprocess
import sys

from setuptools import setup
from setuptools.command.build_py import build_py


class BuildPyWithKernels(build_py):
    def run(self):
        super().run()
        out = os.path.abspath(os.path.join(self.build_lib, "starforge", "kernels.zip"))
        if os.path.exists(out):
            os.remove(out)  # an earlier build's zip in the build folder: never shipped with other code
        if getattr(self, "editable_mode", False) or os.environ.get("STARFORGE_PREBUILD", "1") == "0":
            return
        import shutil
        import tempfile

        scratch = tempfile.mkdtemp(prefix="starforge-build-")
        env = dict(os.environ, NUMBA_CACHE_DIR=scratch, STARFORGE_CACHE_DIR=scratch)  # prebuild's own
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [os.path.abspath(self.build_lib), env.get("PYTHONPATH")]))
        code = "from starforge.runtime.kernels import prebuild_main; prebuild_main()"
        try:
            res = subprocess.run([sys.executable, "-c", code, out], env=env, cwd=self.build_lib)
        finally:
            shutil.rmtree(scratch, ignore_errors=True)
        if res.returncode != 0:
            if os.path.exists(out):
                os.remove(out)
            sys.stderr.write("starforge: kernels not built ahead of time; the first run compiles them\n")


setup(cmdclass={"build_py": BuildPyWithKernels})
