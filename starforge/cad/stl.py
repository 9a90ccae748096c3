"""Binary STL bytes straight from vertex and face arrays (mm), without a trimesh object.

The same layout trimesh writes (an 80-byte zero header, the triangle count, then per triangle
its unit normal, three corners as float32 and a zero attribute word), made from plain arrays:
an export builds each mesh once and writes it twice (a star's file and its plate), and
trimesh's cached properties cost more than the writing itself.
"""

from __future__ import annotations

import numpy as np

_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attr", "<u2")])


def face_normals(vertices, faces) -> np.ndarray:
    """(m, 3) unit normals of the triangles (right-hand rule); zero for a degenerate one."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    ok = length > 0
    n[ok] /= length[ok, None]
    n[~ok] = 0.0
    return n


def stl_bytes(vertices, faces) -> bytes:
    """A binary STL of the triangles ``faces`` (m, 3) int over ``vertices`` (n, 3) float, mm."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    rec = np.zeros(len(f), dtype=_RECORD)
    rec["normal"] = face_normals(v, f)
    rec["corners"] = v[f]
    return bytes(80) + np.uint32(len(f)).tobytes() + rec.tobytes()
