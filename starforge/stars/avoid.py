"""Bodies a lab already owns, as the triangles new stars must stay distinguishable from.

A tracker tells bodies apart by the triangles their markers span; under the face rule a new star
may not have a face whose sorted sides all lie within the tolerance of any triangle of an
existing body (each body's every marker triple, since a tracker may see any three).
"""

from __future__ import annotations

import hashlib
import itertools
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError

#: triangles read from --avoid files at most (a 20-marker prop has 1,140; a 400-star family 1,600)
MAX_TRIANGLES = 1_000_000


def body_triangles(points_mm: np.ndarray) -> np.ndarray:
    """Sorted side lengths (t, 3), mm, of every marker triple of one body (n, 3)."""
    P = np.asarray(points_mm, dtype=float)
    tri = np.array(list(itertools.combinations(range(len(P)), 3)), dtype=np.intp).reshape(-1, 3)
    if not len(tri):
        return np.zeros((0, 3))
    a = np.linalg.norm(P[tri[:, 0]] - P[tri[:, 1]], axis=1)
    b = np.linalg.norm(P[tri[:, 1]] - P[tri[:, 2]], axis=1)
    c = np.linalg.norm(P[tri[:, 0]] - P[tri[:, 2]], axis=1)
    return np.sort(np.stack([a, b, c], axis=1), axis=1)


def faces_to_avoid(paths) -> tuple[np.ndarray, list[dict]]:
    """Every triangle of every body in ``paths`` (family, placement or tracker files).

    Returns (faces (k, 3) sorted sides in mm, sources: one record per file for family.json).
    """
    from starforge.tracking.bodies import load_bodies

    faces, sources = [], []
    total = 0
    for p in paths:
        bs = load_bodies([Path(p)])
        tris = [body_triangles(b.points_mm) for b in bs.bodies]
        n = sum(len(t) for t in tris)
        total += n
        if total > MAX_TRIANGLES:
            raise StarforgeError(
                f"--avoid files hold more than {MAX_TRIANGLES:,} marker triangles; give fewer bodies"
            )
        faces.extend(tris)
        digest = hashlib.sha256(Path(bs.sources[0]).read_bytes()).hexdigest()[:16]
        rec = {"file": str(p), "kind": bs.kind, "bodies": len(bs.bodies), "triangles": n, "sha256_16": digest}
        if bs.warnings:
            rec["warnings"] = list(bs.warnings)  # bodies left out (fewer than 3 markers), named
        sources.append(rec)
    F = np.concatenate(faces) if faces else np.zeros((0, 3))
    return F, sources
