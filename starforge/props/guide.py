"""What a prop team needs to stick the markers on: numbered markers measured from landmarks.

Every marker is located from the prop's axis-aligned bounding box, which a person can measure
with a ruler or a square: on each axis the distance (mm) from the nearer side of the box, and
the box face the marker lies on when its base is on that face (normal within
:data:`FACE_DEG` of the axis, within :data:`FACE_MM` of the side).  The prop is in its own
frame as given (z up for the built-ins).  The drawings are made by
:func:`starforge.render.props.draw_guide`; the prop with the bases merged by :func:`bases_mesh`.
"""

from __future__ import annotations

import math

import numpy as np

#: a marker whose normal is within this angle of an axis, and that lies within FACE_MM of the
#: box's side there, is "on" that box face
FACE_DEG = 5.0
FACE_MM = 1.0
AXES = "xyz"


def landmarks(mesh, points: np.ndarray, normals: np.ndarray) -> list[dict]:
    """Per marker: ``{"from": {"x": "min"|"max", ...}, "distance_mm": [dx, dy, dz], "face": "+z"
    or None, "text": "..."}`` (distances from the nearer side of the bounding box on each axis)."""
    lo, hi = np.asarray(mesh.bounds, float)
    out = []
    for p, n in zip(np.asarray(points, float), np.asarray(normals, float), strict=True):
        side, dist = {}, []
        for k, ax in enumerate(AXES):
            a, b = p[k] - lo[k], hi[k] - p[k]
            side[ax] = "min" if a <= b else "max"
            dist.append(round(float(min(a, b)) * 1000.0, 1) + 0.0)
        face = None
        k = int(np.argmax(np.abs(n)))
        if abs(n[k]) >= math.cos(math.radians(FACE_DEG)):
            sign = "+" if n[k] > 0 else "-"
            edge = hi[k] if n[k] > 0 else lo[k]
            if abs(p[k] - edge) * 1000.0 <= FACE_MM:
                face = f"{sign}{AXES[k]}"
        parts = [f"{d:.1f} mm from the {ax}-{side[ax]} side" for ax, d in zip(AXES, dist, strict=True)]
        text = ", ".join(parts) + (f"; on the {face} face of the box" if face else "")
        out.append({"from": side, "distance_mm": dist, "face": face, "text": text})
    return out


def bases_mesh(prop_mesh, points: np.ndarray, normals: np.ndarray, base_mm: float, height_mm: float = 1.0):
    """The prop with a flat pad under every marker (a cylinder of the base's diameter standing
    ``height_mm`` off the surface and sunk as deep into it), united with manifold3d: a
    3D-printed prop comes out with the seats on it.  Returns a ``trimesh.Trimesh`` (m)."""
    import trimesh

    from starforge.props.solids import union_solids

    h = height_mm / 1000.0
    parts = [prop_mesh.copy()]
    for p, n in zip(np.asarray(points, float), np.asarray(normals, float), strict=True):
        tf = trimesh.geometry.align_vectors([0, 0, 1], n)
        tf[:3, 3] = p
        parts.append(trimesh.creation.cylinder(radius=base_mm / 2000.0, height=2 * h, sections=32, transform=tf))
    merged = union_solids(parts)
    return merged if merged is not None else trimesh.util.concatenate(parts)
