"""build123d (OpenCascade) backend: a :class:`~starforge.cad.body.Body` -> one exact B-rep solid.

Direct API only (no builder contexts): every primitive is a ``Solid``; the body is the fuse of
the added primitives, cut by the subtracted ones, checked with OCCT's validity check and
required to be a single solid.  ``import build123d`` takes seconds: it happens inside these
functions, never at ``import starforge``.
"""

from __future__ import annotations

import numpy as np

from starforge.cad.body import Body
from starforge.cad.primitives import Box, Cylinder, Revolved, Sphere
from starforge.errors import StarforgeError


def primitive_solid(p, axis=None):
    """One primitive as a build123d Solid.

    ``axis`` (3,) orients a sphere's pole along a stem: the stem then meets the sphere on one of
    its parallels (an iso-parametric circle), which OCCT intersects several times faster than a
    circle across the sphere's parametrisation.  The solid is the same either way.
    """
    import build123d as bd

    if isinstance(p, Sphere):
        z = (0.0, 0.0, 1.0) if axis is None else tuple(np.asarray(axis, float) / np.linalg.norm(axis))
        return bd.Solid.make_sphere(p.radius_mm, plane=bd.Plane(origin=p.centre, z_dir=z))
    if isinstance(p, Box):
        sx, sy, sz = p.size
        c = np.array(p.centre) - np.array(p.size) / 2
        return bd.Solid.make_box(sx, sy, sz, plane=bd.Plane(origin=tuple(c)))
    if isinstance(p, Cylinder):
        p0, p1 = np.array(p.p0), np.array(p.p1)
        axis = p1 - p0
        h = float(np.linalg.norm(axis))
        return bd.Solid.make_cylinder(p.radius_mm, h, plane=bd.Plane(origin=tuple(p0), z_dir=tuple(axis / h)))
    if isinstance(p, Revolved):
        return _revolved_solid(p)
    raise TypeError(f"unknown primitive {type(p).__name__}")


def _revolved_solid(p: Revolved):
    """The profile polygon (axis, polyline, axis) in a plane through the axis, turned 360 deg."""
    import build123d as bd
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakePolygon
    from OCP.BRepPrimAPI import BRepPrimAPI_MakeRevol
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt

    u = p.axis
    helper = np.array([1.0, 0, 0]) if abs(u[0]) < 0.9 else np.array([0, 1.0, 0])
    w = np.cross(u, helper)
    w /= np.linalg.norm(w)
    o = np.array(p.p0)
    pts = [o + p.profile[0][0] * u, *(o + t * u + r * w for t, r in p.profile), o + p.profile[-1][0] * u]
    poly = BRepBuilderAPI_MakePolygon()
    for q in pts:
        poly.Add(gp_Pnt(*map(float, q)))
    poly.Close()
    face = BRepBuilderAPI_MakeFace(poly.Wire(), True).Face()
    solid = BRepPrimAPI_MakeRevol(face, gp_Ax1(gp_Pnt(*map(float, o)), gp_Dir(*map(float, u))), 2 * np.pi).Shape()
    return bd.Solid(solid)


def _sphere_axes(body: Body) -> dict:
    """{index in body.add of a sphere: its stem's direction} (stems end at their sphere's centre)."""
    out = {}
    ends = {tuple(np.round(s.p1, 9)): np.subtract(s.p1, s.p0) for s in body.stems}
    for i, p in enumerate(body.add):
        if isinstance(p, Sphere):
            u = ends.get(tuple(np.round(p.centre, 9)))
            if u is not None:
                out[i] = u
    return out


def _disjoint(a, b) -> bool:
    """Whether two (2, 3) bounds are apart (a positive gap on some axis)."""
    return bool((a[0] > b[1] + 1e-6).any() or (b[0] > a[1] + 1e-6).any())


def body_solid(body: Body):
    """The body as one valid build123d Solid, its ``label`` set to ``body.name``.

    (union of ``add``) minus (union of ``subtract``), evaluated in the order that is fastest
    for OCCT and gives the same solid: a cut whose bounds meet only a plate's is made on that
    plate before the union ((A u B) - C = (A - C) u B when C misses B).
    """
    import build123d as bd

    axes = _sphere_axes(body)
    adds = [primitive_solid(p, axes.get(i)) for i, p in enumerate(body.add)]
    plates = [i for i, p in enumerate(body.add) if isinstance(p, Box)]
    others = [i for i in range(len(body.add)) if i not in plates]
    other_bounds = [body.add[i].bounds() for i in others]
    early: dict[int, list] = {i: [] for i in plates}
    late = []
    for c in body.subtract:
        cb = c.bounds()
        hit = [i for i in plates if not _disjoint(cb, body.add[i].bounds())]
        if len(hit) == 1 and all(_disjoint(cb, ob) for ob in other_bounds):
            early[hit[0]].append(primitive_solid(c))
        else:
            late.append(primitive_solid(c))
    for i in plates:
        if early[i]:
            adds[i] = adds[i].cut(*early[i])
    shape = adds[0].fuse(*adds[1:]) if len(adds) > 1 else adds[0]
    if late:
        shape = shape.cut(*late)
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
