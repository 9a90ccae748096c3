"""Meshes as a 3D scanner delivers them (for the scan benchmark and tests): near-equilateral
triangles about ``step`` across all over the surface, every vertex moved along its normal by
Gaussian noise.

* :func:`scanned_bottle`: a body of revolution (a 70 mm bottle 260 mm tall, its shoulder a
  cosine blend into a 28 mm neck), meshed ring by ring, each ring with as many vertices as its
  circumference holds at ``step`` and stitched to the next by angle;
* :func:`scanned_carton`: a 70 x 70 x 200 mm box, each face split in four until its triangles
  are about ``step`` across (sharp edges, as a scanner that keeps them would);

in metres, with the noise (one standard deviation along the normal) drawn from ``seed``.
"""

from __future__ import annotations

import numpy as np


def _bottle_profile(step: float) -> tuple[np.ndarray, np.ndarray]:
    """(radius, height) of the bottle's profile every ``step`` of its length, bottom centre to top centre."""
    pts = [(0.0, 0.0)]
    pts += [(r, 0.0) for r in np.arange(step, 0.035, step)]
    pts += [(0.035, z) for z in np.arange(0.0, 0.18, step)]
    t = np.linspace(0.0, 1.0, 80)
    pts += list(zip(0.014 + 0.021 * (1 + np.cos(np.pi * t)) / 2, 0.18 + 0.04 * t, strict=True))
    pts += [(0.014, z) for z in np.arange(0.22, 0.26, step)]
    pts += [(r, 0.26) for r in np.arange(0.014, 0.0, -step)] + [(0.0, 0.26)]
    p = np.array(pts)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    at = np.append(np.arange(0.0, s[-1], step), s[-1])
    return np.interp(at, s, p[:, 0]), np.interp(at, s, p[:, 1])


def _stitch(a: tuple, b: tuple) -> list:
    """Triangles joining ring ``a`` to ring ``b`` (each ``(first vertex, count, angles)``), by angle."""
    (ia, na, aa), (ib, nb, ab) = a, b
    ta, tb = np.append(aa, aa[0] + 2 * np.pi), np.append(ab, ab[0] + 2 * np.pi)
    i = j = 0
    out = []
    while i < na or j < nb:
        if j >= nb or (i < na and ta[i + 1] <= tb[j + 1]):
            out.append((ia + i % na, ia + (i + 1) % na, ib + j % nb))
            i += 1
        else:
            out.append((ia + i % na, ib + (j + 1) % nb, ib + j % nb))
            j += 1
    return out


def scanned_bottle(noise_m: float, step: float = 0.001, seed: int = 1):
    """The bottle as a scan (see the module docstring), a ``trimesh.Trimesh``."""
    import trimesh

    radius, height = _bottle_profile(step)
    vertices, rings = [], []
    for k, (r, z) in enumerate(zip(radius, height, strict=True)):
        n = max(3, int(round(2 * np.pi * r / step))) if r > 1e-9 else 1
        a = np.linspace(0.0, 2 * np.pi, n, endpoint=False) + (np.pi / n) * (k % 2)
        rings.append((len(vertices), n, a))
        vertices += [(r * np.cos(x), r * np.sin(x), z) for x in a]
    faces = [f for k in range(len(rings) - 1) for f in _stitch(rings[k], rings[k + 1])]
    mesh = trimesh.Trimesh(np.array(vertices), np.array(faces), process=True)
    if mesh.volume < 0:
        mesh.invert()
    return _with_noise(mesh, noise_m, seed)


def scanned_carton(noise_m: float, step: float = 0.001, seed: int = 1):
    """The carton as a scan (see the module docstring), a ``trimesh.Trimesh``."""
    import trimesh

    mesh = trimesh.creation.box(extents=(0.07, 0.07, 0.2))
    v, f = mesh.vertices, mesh.faces
    while np.linalg.norm(v[f[:, 0]] - v[f[:, 1]], axis=1).max() > 2 * step:
        v, f = trimesh.remesh.subdivide(v, f)
    return _with_noise(trimesh.Trimesh(v, f, process=True), noise_m, seed)


def _with_noise(mesh, noise_m: float, seed: int):
    """``mesh`` with every vertex moved along its normal by Gaussian noise of ``noise_m``: a
    scanner's depth noise, which meshing from its points leaves in well-shaped triangles (a
    vertex jittered along the surface as well would fold the small triangles, a mesh no
    reconstruction delivers)."""
    import trimesh

    rng = np.random.default_rng(seed)
    shift = rng.normal(0.0, noise_m, len(mesh.vertices))[:, None] * np.asarray(mesh.vertex_normals)
    return trimesh.Trimesh(mesh.vertices + shift, mesh.faces, process=False)
