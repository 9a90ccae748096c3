"""Boolean union of watertight trimesh solids with manifold3d (guaranteed-manifold output)."""

from __future__ import annotations

import numpy as np


def union_solids(shells):
    """Boolean union of watertight shells with manifold3d; None when manifold refuses them."""
    import manifold3d
    import trimesh

    try:
        solids = [
            manifold3d.Manifold(
                manifold3d.Mesh(
                    vert_properties=np.asarray(s.vertices, dtype=np.float32),
                    tri_verts=np.asarray(s.faces, dtype=np.uint32),
                )
            )
            for s in shells
        ]
        if any(s.status() != manifold3d.Error.NoError or s.is_empty() for s in solids):
            return None
        out = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add).to_mesh()
    except Exception:  # manifold3d refuses some inputs; the caller keeps the shells as they are
        return None
    merged = trimesh.Trimesh(
        vertices=np.asarray(out.vert_properties[:, :3], dtype=float),
        faces=np.asarray(out.tri_verts, dtype=np.int64),
        process=False,
    )
    if len(merged.faces) == 0 or not merged.is_watertight:
        return None
    if merged.volume < 0:
        merged.invert()
    return merged

