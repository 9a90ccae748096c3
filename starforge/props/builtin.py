"""Built-in props generated in code at realistic sizes (metres), so no files are needed.

Each prop is a union of simple solids (boolean union with manifold3d), in its own frame:
z up, the grip or the base at the bottom.  ``hammer`` is the CLI default.
"""

from __future__ import annotations

import numpy as np

from starforge.errors import StarforgeError

BUILTIN = ("hammer", "racket", "sword", "bottle", "box", "shield", "umbrella")
DESCRIPTIONS = {
    "hammer": "claw-less hammer: 30 cm wooden handle (diameter 30 mm) and a 12 cm steel head",
    "racket": "table-tennis racket: 15 cm blade, 6 mm thick, and a 10 cm handle",
    "sword": "sword: 75 cm blade, 20 cm cross-guard, grip and pommel, about 1 m long",
    "bottle": "bottle: 30 cm tall, 74 mm body diameter, narrow neck",
    "box": "cardboard box: 40 x 30 x 25 cm",
    "shield": "round shield: 60 cm diameter, 2 cm thick, with a boss and a handle bar at the back",
    "umbrella": "umbrella-like canopy: 1 m spherical-cap canopy (3 mm thick) on a 94 cm shaft",
}


def _box(extents, center):
    import trimesh

    return trimesh.creation.box(extents=extents, transform=_translate(center))


def _cylinder(radius, height, center, axis="z", sections=32):
    import trimesh

    tf = _translate(center)
    if axis == "x":
        tf = tf @ trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])
    elif axis == "y":
        tf = tf @ trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])
    return trimesh.creation.cylinder(radius=radius, height=height, sections=sections, transform=tf)


def _translate(center):
    tf = np.eye(4)
    tf[:3, 3] = center
    return tf


def _revolve(profile, sections=48):
    """Solid of revolution about z from a closed (r, z) profile, metres."""
    import trimesh

    prof = np.asarray(profile, dtype=float)
    return trimesh.creation.revolve(prof, sections=sections)


def _parts(name: str) -> list:
    import trimesh

    if name == "hammer":
        return [
            _cylinder(0.015, 0.30, (0, 0, 0.15)),
            _box((0.12, 0.035, 0.035), (0.01, 0, 0.31)),
        ]
    if name == "racket":
        blade = _cylinder(0.075, 0.006, (0, 0, 0.175), axis="y", sections=48)
        return [blade, _box((0.025, 0.03, 0.10), (0, 0, 0.05)), _box((0.04, 0.012, 0.03), (0, 0, 0.1))]
    if name == "sword":
        blade = _box((0.05, 0.008, 0.70), (0, 0, 0.55))
        tip = trimesh.Trimesh(
            vertices=[
                [-0.025, -0.004, 0.9],
                [0.025, -0.004, 0.9],
                [0.025, 0.004, 0.9],
                [-0.025, 0.004, 0.9],
                [0, 0, 0.97],
            ],
            faces=[[0, 2, 1], [0, 3, 2], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]],
        )
        return [
            blade,
            tip,
            _box((0.20, 0.03, 0.025), (0, 0, 0.19)),
            _cylinder(0.015, 0.16, (0, 0, 0.10)),
            trimesh.creation.icosphere(subdivisions=2, radius=0.025).apply_translation((0, 0, 0.02)),
        ]
    if name == "bottle":
        prof = [
            (0, 0),
            (0.037, 0),
            (0.037, 0.19),
            (0.030, 0.22),
            (0.015, 0.25),
            (0.013, 0.29),
            (0.015, 0.292),
            (0.015, 0.30),
            (0, 0.30),
            (0, 0),
        ]
        return [_revolve(prof)]
    if name == "box":
        return [_box((0.40, 0.30, 0.25), (0, 0, 0.125))]
    if name == "shield":
        boss = trimesh.creation.icosphere(subdivisions=3, radius=0.07).apply_translation((0, -0.03, 0.30))
        return [
            _cylinder(0.30, 0.02, (0, 0, 0.30), axis="y", sections=64),
            boss,
            _box((0.14, 0.03, 0.025), (0, 0.035, 0.30)),
            _box((0.03, 0.04, 0.025), (-0.06, 0.02, 0.30)),
            _box((0.03, 0.04, 0.025), (0.06, 0.02, 0.30)),
        ]
    if name == "umbrella":
        ang = np.linspace(0.0, np.radians(55.0), 24)
        r_out, r_in = 0.60, 0.597
        outer = np.column_stack([r_out * np.sin(ang), 0.30 + r_out * np.cos(ang)])
        inner = np.column_stack([r_in * np.sin(ang[::-1]), 0.30 + r_in * np.cos(ang[::-1])])
        canopy = np.vstack([outer, inner, outer[:1]])
        return [
            _revolve(canopy, sections=64),
            _cylinder(0.008, 0.94, (0, 0, 0.47)),  # the tip pokes 4 cm through the canopy
            _cylinder(0.014, 0.12, (0, 0, 0.06)),
        ]
    raise StarforgeError(f"unknown built-in prop {name!r}; known: {', '.join(BUILTIN)}")


def builtin_mesh(name: str):
    """The named built-in prop as one watertight ``trimesh.Trimesh`` in metres, normals outward."""
    import trimesh

    from starforge.props.solids import union_solids

    parts = _parts(name)
    for p in parts:
        if p.volume < 0:
            p.invert()
    mesh = parts[0] if len(parts) == 1 else union_solids(parts)
    if mesh is None:  # pragma: no cover - the shipped parts are valid solids
        mesh = trimesh.util.concatenate(parts)
    # manifold3d works in float32: snap its round-off (~1e-8 m) back to 0.1 micrometre
    return trimesh.Trimesh(vertices=np.round(mesh.vertices, 7) + 0.0, faces=mesh.faces, process=False)


def builtin_arrays(name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (v, 3) float m, faces (f, 3) int)`` of :func:`builtin_mesh`, kept in the cache
    folder (:func:`starforge.runtime.stored.stored`) by starforge's code and the trimesh and
    manifold3d versions that build it: a later run reads the arrays without importing either."""
    from starforge.runtime.stored import content_key, stored

    if name not in BUILTIN:
        raise StarforgeError(f"unknown built-in prop {name!r}; known: {', '.join(BUILTIN)}")

    def build():
        mesh = builtin_mesh(name)
        return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)

    return stored("builtin", content_key("builtin", name, libraries=("numpy", "trimesh", "manifold3d")), build)[0]
