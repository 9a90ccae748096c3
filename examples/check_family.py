"""How well a tracker tells a family's bodies apart, with one marker hidden and stray points.

    python examples/check_family.py [FAMILY_JSON]   # default: a small finger family made here
"""

import sys
import tempfile
from pathlib import Path

import starforge.api as sf

if len(sys.argv) > 1:
    source = Path(sys.argv[1])
else:
    source = sf.write_family(sf.make_family(sf.plan_family("finger", count=8)), Path(tempfile.mkdtemp()) / "f8")
res = sf.check([source], noise_mm=0.2, drop=1, ghosts=1, frames=500, seed=1)
print(f"rule {res.rule}: identified {100 * res.identified:.2f} %, wrong body {100 * res.wrong_body:.3f} %, "
      f"wrong pose {100 * res.wrong_pose:.3f} %, missed {100 * res.missed:.2f} %")
