"""Locating a mark from noisy readings, solved by brute force (for the rigging guide's figures).

A technician reads the distances from three landmarks to the mark, each off by the tape model
of :mod:`starforge.props.guide` (``TAPE_MM`` + ``TAPE_REL`` of the distance, one standard
deviation), and sets the mark where the distances fit best.  Here that is done by brute force:
the readings are drawn at random, and the solution is the point of a dense sample of the
surface round the mark (its faces within ``RADIUS_M`` that face within ``FACING_DEG`` of the
mark: the guide names the way the mark faces) whose distances fit them best in the readings'
standard deviations.  Nothing of the guide's first-order model or its own surface sample is
used.
"""

from __future__ import annotations

import numpy as np

from starforge.props.guide import FACING_DEG, TAPE_MM, TAPE_REL

RADIUS_M = 0.04
SAMPLES = 60_000


def patch(mesh, p, n, seed: int) -> np.ndarray:
    """(SAMPLES, 3) points sampled uniformly on the faces of ``mesh`` that come within
    ``RADIUS_M`` of ``p`` and face within ``FACING_DEG`` of ``n`` (a long face counts whole)."""
    import trimesh

    tri = mesh.triangles
    near = np.linalg.norm(trimesh.triangles.closest_point(tri, np.tile(p, (len(tri), 1))) - p, axis=1) < RADIUS_M
    near &= mesh.face_normals @ n >= np.cos(np.radians(FACING_DEG))
    sub = mesh.submesh([np.flatnonzero(near)], append=True)
    return trimesh.sample.sample_surface(sub, SAMPLES, seed=seed)[0]


def solved_offsets(mesh, p, n, landmarks_m, rng, trials: int = 150) -> np.ndarray:
    """(trials,) mm: how far from ``p`` the mark is set from ``trials`` sets of noisy readings
    of its distances to ``landmarks_m`` (k, 3) m."""
    lp = np.asarray(landmarks_m, float)
    true = np.linalg.norm(lp - p, axis=1) * 1000.0
    sigma = TAPE_MM + TAPE_REL * true
    cand = patch(mesh, p, n, int(rng.integers(1 << 30)))
    dist = np.linalg.norm(cand[:, None, :] - lp[None], axis=2) * 1000.0
    got = [cand[int(np.argmin((((dist - (true + rng.normal(0.0, sigma))) / sigma) ** 2).sum(axis=1)))] for _ in range(trials)]
    return np.linalg.norm(np.array(got) - p, axis=1) * 1000.0
