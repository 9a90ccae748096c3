"""manifold3d backend: a :class:`~starforge.cad.body.Body` -> one watertight, manifold mesh.

Booleans run in batches (the cuts that meet only a plate on that plate, then one union of
every added part, minus the union of the remaining cuts), so the result is manifold by
construction; :func:`body_arrays` checks the status and the
triangles anyway.  Tessellation: spheres and cylinders get ``BodySpec.sphere_segments`` /
``cylinder_segments`` around, fine enough that volumes agree with the exact STEP solid
within 1 %.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from starforge.cad.body import Body
from starforge.cad.primitives import Box, Cylinder, Revolved, Sphere, merge_coaxial, plate_cuts
from starforge.errors import StarforgeError
from starforge.geometry.frames import perpendicular_basis


class MeshArrays(NamedTuple):
    """A triangle mesh as plain arrays (what the STL / 3MF writers and the thumbnails take)."""

    vertices: np.ndarray  # (n, 3) float, mm
    faces: np.ndarray  # (m, 3) int


def _frame(axis: np.ndarray) -> np.ndarray:
    """A rotation (3, 3) taking +z to the unit vector ``axis``."""
    z = axis / np.linalg.norm(axis)
    return np.column_stack([*perpendicular_basis(z), z])


@lru_cache(maxsize=16)
def _sphere_scale(segments: int) -> float:
    """Radius factor giving a tessellated sphere the exact sphere's volume."""
    from manifold3d import Manifold

    v = Manifold.sphere(1.0, int(segments)).volume()
    return float((4.0 / 3.0 * np.pi / v) ** (1.0 / 3.0))


def _placement(axis, origin) -> np.ndarray:
    """(3, 4) affine map taking +z to ``axis``'s direction and the origin to ``origin``."""
    m = np.zeros((3, 4))
    m[:, :3] = _frame(np.asarray(axis, float))
    m[:, 3] = origin
    return m


#: largest gap (mm) between a tessellated circle and the exact one, for large radii (a saddle's
#: 11 mm channel): a fixed segment count is too coarse for them to keep volumes within 0.01 %
MAX_SAGITTA_MM = 0.002


def circle_segments(radius_mm: float, minimum: int) -> int:
    """Segments for a circle of ``radius_mm``: at least ``minimum``, more where a chord would
    stray more than :data:`MAX_SAGITTA_MM` from the circle (at most 720)."""
    r = float(radius_mm)
    if r <= MAX_SAGITTA_MM:
        return int(minimum)
    n = int(np.ceil(np.pi / np.arccos(1.0 - MAX_SAGITTA_MM / r)))
    return int(min(720, max(int(minimum), n)))


def _circle_scale(segments: int) -> float:
    """Radius factor giving a regular ``segments``-gon the area of its circle."""
    n = int(segments)
    return float(np.sqrt(2 * np.pi / (n * np.sin(2 * np.pi / n))))


def primitive_manifold(p, sphere_segments: int = 64, cylinder_segments: int = 32, unit_sphere=None):
    """One primitive as a manifold3d Manifold.

    Curved primitives are tessellated volume-preserving: the polygon's radius is scaled so
    that a sphere (cylinder) mesh holds the exact sphere's (cylinder's) volume; the surface
    stays within ``radius * (1 - cos(pi / segments))`` of the exact one.  ``unit_sphere``: a
    ``Manifold.sphere(1, sphere_segments)`` to scale and place instead of tessellating again.
    """
    from manifold3d import CrossSection, Manifold

    if isinstance(p, Sphere):  # the unit sphere (made here unless given), scaled and placed
        r = p.radius_mm * _sphere_scale(sphere_segments)
        unit = unit_sphere if unit_sphere is not None else Manifold.sphere(1.0, int(sphere_segments))
        return unit.scale([r, r, r]).translate(p.centre)
    if isinstance(p, Box):
        return Manifold.cube(p.size, center=True).translate(p.centre)
    if isinstance(p, Cylinder):
        p0, p1 = np.array(p.p0), np.array(p.p1)
        h = float(np.linalg.norm(p1 - p0))
        n = circle_segments(p.radius_mm, cylinder_segments)
        r = p.radius_mm * _circle_scale(n)
        return Manifold.cylinder(h, r, r, n).transform(_placement(p1 - p0, p0))
    if isinstance(p, Revolved):
        n = circle_segments(max(r for _, r in p.profile), cylinder_segments)
        k = _circle_scale(n)
        pts = [(0.0, p.profile[0][0]), *((r * k, t) for t, r in p.profile), (0.0, p.profile[-1][0])]
        solid = CrossSection([pts]).revolve(n)
        return solid.transform(_placement(np.subtract(p.p1, p.p0), np.array(p.p0)))
    raise TypeError(f"unknown primitive {type(p).__name__}")


#: a tessellated primitive may stand out of its exact bounds by its volume-preserving scale
#: (radius x 1.002 at 16 segments and less above): cuts this close to a part are made last
CUT_MARGIN_MM = 0.05


def body_manifold(body: Body, sphere_segments: int = 64, cylinder_segments: int = 32):
    """The body as one Manifold: (union of ``add``) minus (union of ``subtract``).

    Evaluated as OCCT does (:func:`starforge.cad.brep.body_solid`): a vertical stem with its
    fillet is one solid of revolution, a cut that meets only a plate is made on that plate
    before the one batch union (:func:`~starforge.cad.primitives.plate_cuts`), the rest after.
    """
    from manifold3d import Manifold, OpType

    parts = merge_coaxial(body.add)
    # one unit sphere per body, scaled and placed for each of its spheres.  Not one per process:
    # manifold3d orders a boolean's triangles by the ids its meshes were created with, so a
    # sphere shared between bodies (created once, before the rest) would give the second export
    # in a process other triangle orders than the first
    unit = Manifold.sphere(1.0, int(sphere_segments))
    adds = [primitive_manifold(p, sphere_segments, cylinder_segments, unit) for p in parts]
    early: dict[int, list] = {}
    late = []
    for c, plate in zip(body.subtract, plate_cuts(parts, [c.bounds() for c in body.subtract], CUT_MARGIN_MM), strict=True):
        m = primitive_manifold(c, sphere_segments, cylinder_segments)
        (late if plate is None else early.setdefault(plate, [])).append(m)
    for i, tools in early.items():
        adds[i] = adds[i] - Manifold.batch_boolean(tools, OpType.Add)
    solid = Manifold.batch_boolean(adds, OpType.Add)
    if late:
        solid = solid - Manifold.batch_boolean(late, OpType.Add)
    status = solid.status()
    if str(status).split(".")[-1] != "NoError":
        raise StarforgeError(f"{body.name}: mesh boolean failed ({status})")
    return solid


def manifold_arrays(solid) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3) float mm, faces (m, 3) int) of a Manifold."""
    mesh = solid.to_mesh()
    v = np.asarray(mesh.vert_properties, dtype=float)[:, :3]
    f = np.asarray(mesh.tri_verts, dtype=np.int64)
    return v, f


def body_arrays(body: Body, sphere_segments: int = 64, cylinder_segments: int = 32, check: bool = True):
    """The body as (vertices (n, 3) float mm, faces (m, 3) int): one watertight volume, no
    degenerate triangles (what :func:`body_mesh` wraps; an export works on these arrays and
    needs no trimesh).

    Raises StarforgeError when the mesh is not a single watertight volume (a mount feature
    that split the body, say).  ``check=False`` skips :func:`check_shell` here, for a caller
    that checks the mesh as it will be written (moved into its printing orientation: the
    float32 rounding it checks depends on where the vertices end up).
    """
    solid = body_manifold(body, sphere_segments, cylinder_segments)
    pieces = len(solid.decompose())
    if pieces != 1:
        raise StarforgeError(f"{body.name}: the body falls apart into {pieces} pieces")
    v, f = manifold_arrays(solid)
    # manifold3d output is closed and oriented by construction; slivers are the one thing left
    # to check (a zero-area triangle would upset some slicers)
    e1, e2 = v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    area2 = np.linalg.norm(np.cross(e1, e2), axis=1)
    if (area2 <= 1e-12).any():
        solid = solid.simplify(1e-6)
        v, f = manifold_arrays(solid)
    if check:
        check_shell(v, f, body.name)
    return v, f


def body_mesh(body: Body, sphere_segments: int = 64, cylinder_segments: int = 32, check: bool = True):
    """The body as a trimesh.Trimesh (:func:`body_arrays`), named ``body.name``."""
    import trimesh

    v, f = body_arrays(body, sphere_segments, cylinder_segments, check)
    mesh = trimesh.Trimesh(v, f, process=False)
    mesh.metadata["name"] = body.name
    return mesh


def mesh_volume(vertices, faces) -> float:
    """Enclosed volume of a closed, outward-oriented triangle mesh, mm^3 (the divergence
    theorem: the sum of the signed tetrahedra from the origin, as trimesh's mass properties
    compute it, without the inertia they compute too).

    Parameters
    ----------
    vertices : (n, 3) float, mm ; faces : (m, 3) int
    """
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def check_shell(vertices, faces, name: str) -> None:
    """Raise StarforgeError naming ``name`` when :func:`shell_defects` finds anything."""
    bad = shell_defects(vertices, faces)
    if any(bad.values()):
        found = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in bad.items() if v)
        raise StarforgeError(f"{name}: the mesh is not a closed 2-manifold once written as float32 ({found})")


def shell_defects(vertices, faces) -> dict:
    """What a reader of the written file would find wrong, after rounding to float32 (STL) and
    welding equal vertices: edges used by more than two faces, edges used by one face
    (holes), and faces whose corners weld together.  All zero for a closed 2-manifold.

    Parameters
    ----------
    vertices : (n, 3) float, mm ; faces : (m, 3) int
    """
    # weld: equal float32 triples get one id (one lexsort of the bit patterns; +0.0 turns -0.0
    # into 0.0, which compare equal), as np.unique(axis=0) would, 5-10x faster
    v32 = np.ascontiguousarray(np.asarray(vertices, dtype=np.float32) + np.float32(0.0))
    bits = v32.view(np.uint32).reshape(-1, 3).astype(np.uint64)
    order = np.lexsort((bits[:, 2], (bits[:, 0] << np.uint64(32)) | bits[:, 1]))
    sb = bits[order]
    new = np.ones(len(sb), dtype=bool)
    new[1:] = (sb[1:] != sb[:-1]).any(axis=1)
    inv = np.empty(len(sb), dtype=np.int64)
    inv[order] = np.cumsum(new) - 1
    f = inv[np.asarray(faces, dtype=np.int64)]
    degenerate = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    g = f[~degenerate]
    e = np.sort(np.concatenate([g[:, [0, 1]], g[:, [1, 2]], g[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e[:, 0] * (len(sb) + 1) + e[:, 1], return_counts=True)  # one key per edge
    return {
        "edges_over_two_faces": int((counts > 2).sum()),
        "open_edges": int((counts == 1).sum()),
        "collapsed_faces": int(degenerate.sum()),
    }
