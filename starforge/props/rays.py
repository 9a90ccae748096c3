"""Rays against a prop's triangles: embree (embreex) called on the mesh's arrays.

:func:`ray_scene` builds one :class:`RayScene` per mesh (a
:class:`~starforge.props.mesh.PropMesh` or a ``trimesh.Trimesh``: anything with ``vertices``
and ``faces``) and keeps it while the mesh lives, so that a placement read back from the cache
casts its sight lines and its fresh-pose rays without building a ``trimesh.Trimesh``.  The
scene is the one trimesh builds (``trimesh.ray.ray_pyembree``): the vertices moved to their
box's lowest corner and scaled to about 100 units, where embree's float32 keeps the precision,
so every answer is trimesh's.  Without embreex (a platform it has no wheel for) the queries go
to trimesh's numpy ray tracer.
"""

from __future__ import annotations

import weakref

import numpy as np

from starforge.props.mesh import face_bounds

#: the bounding-box diagonal the scene is scaled to (trimesh's choice)
SCENE_SIZE = 100.0


class RayScene:
    """Ray queries against the triangles ``faces`` (f, 3) int over ``vertices`` (v, 3), m.

    Attributes
    ----------
    size : float
        The diagonal of the box round the vertices the faces use, m (trimesh's ``mesh.scale``:
        1 for a mesh of no extent).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self._vertices = np.asarray(vertices, dtype=float)
        self._faces = np.asarray(faces, dtype=np.int64)
        box = np.ptp(face_bounds(self._vertices, self._faces), axis=0)
        size = float((box**2).sum() ** 0.5)  # as trimesh's mesh.scale, to the last bit
        self.size = size if size >= 1e-13 else 1.0
        self._embree = None
        self._numpy = None
        try:
            from embreex import rtcore_scene
            from embreex.mesh_construction import TriangleMesh
        except ImportError:  # no embree on this platform: trimesh's tracer, built on first use
            return
        self._origin = self._vertices.min(axis=0) if len(self._vertices) else np.zeros(3)
        self._scale = SCENE_SIZE / self.size
        self._embree = rtcore_scene.EmbreeScene()
        TriangleMesh(
            scene=self._embree,
            vertices=((self._vertices - self._origin) * self._scale).astype(np.float32),
            indices=self._faces.astype(np.int32),
        )

    def _tracer(self):
        if self._numpy is None:
            import trimesh
            from trimesh.ray.ray_triangle import RayMeshIntersector

            self._numpy = RayMeshIntersector(trimesh.Trimesh(vertices=self._vertices, faces=self._faces, process=False))
        return self._numpy

    def _run(self, origins: np.ndarray, directions: np.ndarray, **kwargs) -> np.ndarray:
        scaled = (np.asarray(origins, dtype=float) - self._origin) * self._scale
        return np.asarray(self._embree.run(scaled.astype(np.float32), directions.astype(np.float32), **kwargs))

    def first(self, origins: np.ndarray, unit: np.ndarray) -> np.ndarray:
        """(n,) int: the first triangle each ray from ``origins`` along the unit directions
        ``unit`` hits, -1 for a miss."""
        origins = np.asarray(origins, dtype=float).reshape(-1, 3)
        unit = np.asarray(unit, dtype=float).reshape(-1, 3)
        if not len(origins):
            return np.zeros(0, dtype=np.int64)
        if self._embree is None:
            return np.asarray(self._tracer().intersects_first(origins, unit), dtype=np.int64)
        return self._run(origins, unit).astype(np.int64)

    def hits(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(n,) bool: the ray from each origin along its direction hits a triangle."""
        origins = np.asarray(origins, dtype=float).reshape(-1, 3)
        directions = np.asarray(directions, dtype=float).reshape(-1, 3)
        if not len(origins):
            return np.zeros(0, dtype=bool)
        if self._embree is None:
            return np.asarray(self._tracer().intersects_any(origins, directions), dtype=bool)
        unit = directions / np.linalg.norm(directions, axis=1)[:, None]
        return self._run(origins, unit) != -1

    def blocked(self, origins: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """(n,) bool: the segment from each origin to its target crosses a triangle (an embree
        occlusion query with the segment's length; the numpy tracer's first hit along the ray
        against that length without embree)."""
        origins = np.asarray(origins, dtype=float).reshape(-1, 3)
        vec = np.asarray(targets, dtype=float).reshape(-1, 3) - origins
        if not len(origins):
            return np.zeros(0, dtype=bool)
        dist = np.linalg.norm(vec, axis=1)
        dirs = vec / np.where(dist > 0, dist, 1.0)[:, None]
        if self._embree is not None:
            return self._run(origins, dirs, dists=(dist * self._scale).astype(np.float32), query="OCCLUDED") != -1
        _, ray_idx, loc = self._tracer().intersects_id(origins, dirs, multiple_hits=True, return_locations=True)
        out = np.zeros(len(origins), dtype=bool)
        if len(ray_idx):
            d = np.einsum("ij,ij->i", loc - origins[ray_idx], dirs[ray_idx])
            ok = (d > 0) & (d < dist[ray_idx])
            out[ray_idx[ok]] = True
        return out


#: each mesh's scene, with the content hash it was built for (a trimesh mesh can change)
_SCENES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def ray_scene(mesh) -> RayScene:
    """The :class:`RayScene` of ``mesh`` (anything with ``vertices`` and ``faces``: a
    :class:`~starforge.props.mesh.PropMesh`, a ``trimesh.Trimesh``), built on the first call and
    kept while the mesh lives and its hash stays the same (a PropMesh hashes by identity, being
    immutable; a trimesh mesh by its content).  A PropMesh whose ``trimesh.Trimesh`` is built
    shares that mesh's scene."""
    built = getattr(mesh, "__dict__", {}).get("mesh")
    if built is not None:  # a PropMesh whose trimesh is built: one scene for the two
        mesh = built
    tag = hash(mesh)
    kept = _SCENES.get(mesh)
    if kept is not None and kept[0] == tag:
        return kept[1]
    scene = RayScene(mesh.vertices, mesh.faces)
    _SCENES[mesh] = (tag, scene)
    return scene
