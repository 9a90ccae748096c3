"""build123d (OpenCascade) backend: a :class:`~starforge.cad.body.Body` -> one exact B-rep solid.

Direct API only (no builder contexts): every primitive is a ``Solid``; the body is the fuse of
the added primitives, cut by the subtracted ones, checked with OCCT's validity check and
required to be a single solid.  ``import build123d`` takes seconds: it happens inside these
functions, never at ``import starforge``.
"""

from __future__ import annotations

import numpy as np

from starforge.cad.body import Body
from starforge.cad.primitives import Box, Cylinder, Sphere
from starforge.errors import StarforgeError


def primitive_solid(p):
    """One primitive as a build123d Solid."""
    import build123d as bd

    if isinstance(p, Sphere):
        return bd.Solid.make_sphere(p.radius_mm, plane=bd.Plane(origin=p.centre))
    if isinstance(p, Box):
        sx, sy, sz = p.size
        c = np.array(p.centre) - np.array(p.size) / 2
        return bd.Solid.make_box(sx, sy, sz, plane=bd.Plane(origin=tuple(c)))
    if isinstance(p, Cylinder):
        p0, p1 = np.array(p.p0), np.array(p.p1)
        axis = p1 - p0
        h = float(np.linalg.norm(axis))
        plane = bd.Plane(origin=tuple(p0), z_dir=tuple(axis / h))
        if abs(p.r1 - p.radius_mm) > 1e-12:
            return bd.Solid.make_cone(p.radius_mm, p.r1, h, plane=plane)
        return bd.Solid.make_cylinder(p.radius_mm, h, plane=plane)
    raise TypeError(f"unknown primitive {type(p).__name__}")


def body_solid(body: Body):
    """The body as one valid build123d Solid, its ``label`` set to ``body.name``."""
    import build123d as bd

    adds = [primitive_solid(p) for p in body.add]
    shape = adds[0].fuse(*adds[1:]) if len(adds) > 1 else adds[0]
    if body.subtract:
        shape = shape.cut(*[primitive_solid(p) for p in body.subtract])
    shape = shape.clean()
    solids = shape.solids()
    if len(solids) != 1:
        raise StarforgeError(f"{body.name}: the STEP body has {len(solids)} solids, expected one")
    solid = solids[0]
    if not solid.is_valid:
        raise StarforgeError(f"{body.name}: OCCT's validity check failed for the solid")
    solid = bd.Solid(solid.wrapped)
    solid.label = body.name
    return solid


def placed(solid, T, name: str, colour) -> object:
    """``solid`` moved by the rigid transform ``T`` (4, 4) (a rotation about x by +90 deg plus a
    translation, as :func:`starforge.cad.plate.print_transform` makes), named and coloured."""
    import build123d as bd

    R = np.asarray(T, float)[:3, :3]
    if not np.allclose(R, [[1, 0, 0], [0, 0, -1], [0, 1, 0]]):
        raise ValueError("placed() takes the printing rotation (+90 deg about x) only")
    out = bd.Solid(solid.rotate(bd.Axis.X, 90).translate(tuple(np.asarray(T, float)[:3, 3])).wrapped)
    out.label = name
    out.color = bd.Color(*(c / 255 for c in colour))
    return out


def assembly(solids, translations, name: str):
    """A STEP assembly: copies of named, coloured ``solids`` moved by ``translations`` (4, 4)."""
    import build123d as bd

    children = []
    for s, T in zip(solids, translations, strict=True):
        c = bd.Solid(s.translate(tuple(np.asarray(T, float)[:3, 3])).wrapped)
        c.label, c.color = s.label, s.color
        children.append(c)
    return bd.Compound(children=children, label=name)


def write_step(solid, path) -> None:
    """Write one solid to a STEP file (mm).  The caller stages the path (atomic outputs)."""
    import build123d as bd

    ok = bd.export_step(solid, str(path), unit=bd.Unit.MM, timestamp="2000-01-01T00:00:00")
    if not ok:
        raise StarforgeError(f"could not write STEP file {path}")


def read_step(path):
    """The solids of a STEP file (list of build123d Solids)."""
    import build123d as bd

    return bd.import_step(str(path)).solids()
