"""A family of marker stars for a finger phalanx, made for the flat mount, and its printable bodies.

    python examples/finger_family.py [OUT]     # default OUT: out/examples/finger

Writes OUT/family.json (the source of truth), family.csv, and OUT/bodies/ with one STL per star.
"""

import sys
from pathlib import Path

import starforge.api as sf

out = Path(sys.argv[1] if len(sys.argv) > 1 else "out/examples/finger")
plan = sf.plan_family("finger", count=6, mount="flat", name="finger6")
family = sf.make_family(plan)
sf.write_family(family, out, force=True)
bodies = sf.export_bodies(family, out / "bodies", formats=("stl",), plate=False, force=True)
best = family.stars[0]
print(f"{len(family)} stars in a {' x '.join(f'{x:g}' for x in family.spec.box_mm)} mm box")
print(f"star {best.id}: edge lengths {', '.join(f'{x:.1f}' for x in best.lengths)} mm")
print(f"{bodies.bodies} printable bodies in {bodies.folder}")
