"""Markers on a prop: the built-in hammer, or a mesh file given in metres.

    python examples/place_on_prop.py [MESH] [OUT]   # default: the built-in hammer -> out/examples/hammer
"""

import sys
from pathlib import Path

import starforge.api as sf

prop = sys.argv[1] if len(sys.argv) > 1 else "hammer"
out = Path(sys.argv[2] if len(sys.argv) > 2 else "out/examples/hammer")
res = sf.place_markers(prop, seed=0)
sf.write_placement(res, out, force=True)
print(f"{len(res.marker_points)} markers on {prop}; files in {out}")
for i, (p, n) in enumerate(zip(res.marker_points, res.marker_normals, strict=True), 1):
    print(f"  marker {i}: at ({', '.join(f'{1000 * x:.1f}' for x in p)}) mm, facing ({', '.join(f'{x:.2f}' for x in n)})")
