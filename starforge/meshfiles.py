"""Mesh files as bytes straight from vertex and face arrays, without a trimesh object: binary
STL (:func:`stl_bytes`) and binary glTF (:func:`glb_bytes`).

The STL is the layout trimesh writes (an 80-byte zero header, the triangle count, then per
triangle its unit normal, three corners as float32 and a zero attribute word): an export builds
each mesh once and writes it twice (a star's file and its plate), and trimesh's cached
properties cost more than the writing itself.  The GLB holds each mesh as one node with its
positions, its triangles and a plain colour; a viewer shades it with flat normals, as glTF 2.0
asks of a mesh that carries none.  Coordinates are written as given (glTF reads them as metres).
"""

from __future__ import annotations

import numpy as np

_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attr", "<u2")])


def face_cross(vertices, faces) -> np.ndarray:
    """(m, 3) each triangle's normal (right-hand rule) times twice its area: the cross product
    of its two edges from its first corner."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def face_normals(vertices, faces) -> np.ndarray:
    """(m, 3) unit normals of the triangles (right-hand rule); zero for a degenerate one."""
    n = face_cross(vertices, faces)
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    ok = length > 0
    n[ok] /= length[ok, None]
    n[~ok] = 0.0
    return n


def stl_bytes(vertices, faces) -> bytes:
    """A binary STL of the triangles ``faces`` (m, 3) int over ``vertices`` (n, 3) float (mm
    for a body, m for a prop)."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    rec = np.zeros(len(f), dtype=_RECORD)
    rec["normal"] = face_normals(v, f)
    rec["corners"] = v[f]
    return bytes(80) + np.uint32(len(f)).tobytes() + rec.tobytes()


#: glTF 2.0 constants: component types, buffer-view targets, chunk types
_FLOAT, _UINT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_JSON, _BIN = 0x4E4F534A, 0x004E4942


def glb_bytes(meshes, generator: str = "starforge") -> bytes:
    """A binary glTF 2.0 file of ``meshes``: ``(name, vertices (n, 3) float, faces (m, 3) int,
    rgba (4,) float in [0, 1])`` each, one node per mesh in one scene; a mesh without triangles
    is left out."""
    import json

    blob = bytearray()
    views, accessors, gl_meshes, materials, nodes = [], [], [], [], []

    def view(data: bytes, target: int) -> int:
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data), "target": target})
        blob.extend(data)
        blob.extend(bytes(-len(blob) % 4))  # every view starts on a 4-byte boundary
        return len(views) - 1

    for name, vertices, faces, rgba in meshes:
        v = np.ascontiguousarray(vertices, dtype="<f4").reshape(-1, 3)
        f = np.ascontiguousarray(faces, dtype="<u4").reshape(-1, 3)
        if not len(f):
            continue
        accessors.append({
            "bufferView": view(v.tobytes(), _ARRAY_BUFFER), "componentType": _FLOAT, "count": len(v), "type": "VEC3",
            "min": [float(x) for x in v.min(axis=0)], "max": [float(x) for x in v.max(axis=0)],
        })  # fmt: skip
        accessors.append({"bufferView": view(f.tobytes(), _ELEMENT_ARRAY_BUFFER), "componentType": _UINT, "count": f.size, "type": "SCALAR"})
        materials.append({
            "name": name, "doubleSided": False,
            "pbrMetallicRoughness": {"baseColorFactor": [float(x) for x in rgba], "metallicFactor": 0.0, "roughnessFactor": 1.0},
        })  # fmt: skip
        prim = {"attributes": {"POSITION": len(accessors) - 2}, "indices": len(accessors) - 1, "material": len(materials) - 1, "mode": 4}
        gl_meshes.append({"name": name, "primitives": [prim]})
        nodes.append({"name": name, "mesh": len(gl_meshes) - 1})
    doc = {
        "asset": {"version": "2.0", "generator": generator},
        "scene": 0,
        "scenes": [{"nodes": list(range(len(nodes)))}],
        "nodes": nodes,
        "meshes": gl_meshes,
        "materials": materials,
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(blob)}],
    }
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)  # the JSON chunk is padded with spaces, the binary with zeros
    chunks = _words(len(text), _JSON) + text + _words(len(blob), _BIN) + bytes(blob)
    return b"glTF" + _words(2, 12 + len(chunks)) + chunks


def _words(*words: int) -> bytes:
    """Little-endian unsigned 32-bit words."""
    return np.asarray(words, dtype="<u4").tobytes()
