"""The triangles of bodies a lab already owns, read from their files, for ``--avoid``.

New stars (:func:`starforge.stars.avoid.avoid_mask`) and prop layouts stay distinguishable from
every marker triangle of these bodies.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from starforge.errors import StarforgeError
from starforge.stars.avoid import body_triangles
from starforge.tracking.bodies import load_bodies

#: triangles read from --avoid files at most (a 20-marker prop has 1,140; a 400-star family 1,600)
MAX_TRIANGLES = 1_000_000


def faces_to_avoid(paths) -> tuple[np.ndarray, list[dict]]:
    """Every triangle of every body in ``paths`` (family, placement or tracker files).

    Returns (faces (k, 3) sorted sides in mm, sources: one record per file for family.json).
    """
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
