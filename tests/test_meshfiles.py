"""Mesh files written from arrays (starforge.meshfiles) read back by trimesh's own readers, and
the prop's marker mesh that `place` writes with them."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from starforge.meshfiles import glb_bytes, stl_bytes


def _chunks(data: bytes):
    magic, version, length = struct.unpack("<4sII", data[:12])
    out, at = [], 12
    while at < len(data):
        size, kind = struct.unpack("<II", data[at : at + 8])
        out.append((kind, data[at + 8 : at + 8 + size]))
        at += 8 + size
    return magic, version, length, out


def test_a_glb_reads_back_as_its_meshes_with_their_colours():
    import trimesh

    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    ball = trimesh.creation.icosphere(2, 0.05)
    ball.apply_translation((0.3, 0, 0))
    data = glb_bytes([("box", box.vertices, box.faces, (0.5, 0.5, 0.5, 1.0)), ("none", np.zeros((0, 3)), np.zeros((0, 3), int), (0, 0, 0, 1)), ("ball", ball.vertices, ball.faces, (1.0, 0.0, 0.0, 1.0))])
    # the container as glTF 2.0 lays it out: a 12-byte header, a JSON chunk padded with spaces to
    # 4 bytes, a binary chunk padded with zeros, every buffer view on a 4-byte boundary
    magic, version, length, chunks = _chunks(data)
    assert (magic, version, length) == (b"glTF", 2, len(data)) and len(data) % 4 == 0
    (k1, text), (k2, blob) = chunks
    assert (k1, k2) == (0x4E4F534A, 0x004E4942) and len(text) % 4 == 0 and len(blob) % 4 == 0
    doc = json.loads(text)
    assert doc["asset"]["version"] == "2.0" and doc["buffers"][0]["byteLength"] <= len(blob)
    assert all(v["byteOffset"] % 4 == 0 for v in doc["bufferViews"])
    assert [m["name"] for m in doc["meshes"]] == ["box", "ball"]  # a mesh without faces is left out
    for acc in doc["accessors"]:
        if "min" in acc:
            view = doc["bufferViews"][acc["bufferView"]]
            pts = np.frombuffer(blob[view["byteOffset"] : view["byteOffset"] + view["byteLength"]], "<f4").reshape(-1, 3)
            assert acc["min"] == pts.min(axis=0).tolist() and acc["max"] == pts.max(axis=0).tolist()
    # trimesh's reader: the same triangles (float32 corners) and colours
    scene = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="glb")
    for name, mesh, rgba in (("box", box, (128, 128, 128, 255)), ("ball", ball, (255, 0, 0, 255))):
        back = scene.geometry[name]
        np.testing.assert_allclose(back.vertices[back.faces], mesh.vertices[mesh.faces], atol=1e-7)
        assert back.is_watertight and back.volume == pytest.approx(mesh.volume, rel=1e-5)
        assert np.abs(np.asarray(back.visual.material.baseColorFactor, int) - rgba).max() <= 1


def test_a_props_watertight_flag_is_trimeshs():
    import trimesh

    from starforge.props.mesh import PropMesh

    box = trimesh.creation.box()
    open_box = trimesh.Trimesh(box.vertices, box.faces[1:], process=False)
    fin = trimesh.Trimesh(np.vstack([box.vertices, [[2.0, 2.0, 2.0]]]), np.vstack([box.faces, [[0, 1, 8]]]), process=False)
    empty = trimesh.Trimesh(box.vertices, np.zeros((0, 3), int), process=False)
    for mesh in (box, open_box, fin, trimesh.creation.icosphere(1), empty):
        prop = PropMesh("p", "x.stl", "m", np.asarray(mesh.vertices), np.asarray(mesh.faces), np.arange(len(mesh.faces)))
        assert "mesh" not in prop.__dict__ and prop.watertight == mesh.is_watertight


def test_the_markers_sit_on_their_sites_as_closed_balls_on_discs():
    import trimesh

    from starforge.props.files import marker_mesh, marker_parts
    from starforge.props.mesh import load_prop
    from starforge.props.spec import load_spec

    seat = load_spec("default").marker_seat()
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(3, 3)) * 0.1
    nrm = rng.normal(size=(3, 3))
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    v, f = marker_parts(pts, nrm, seat)
    parts = trimesh.Trimesh(v, f, process=False).split(only_watertight=False)
    assert len(parts) == 6 and all(p.is_watertight and p.volume > 0 for p in parts)  # wound outward

    def thickness(part):  # its extent along its thinnest principal direction
        c = part.vertices - part.vertices.mean(axis=0)
        return float(np.ptp(c @ np.linalg.svd(c, full_matrices=False)[2][-1]))

    balls = [p for p in parts if thickness(p) > 0.002]
    discs = [p for p in parts if thickness(p) <= 0.002]
    assert len(balls) == len(discs) == 3
    for p, n in zip(pts, nrm, strict=True):
        centre = p + seat.centre_height_m * n
        ball = min(balls, key=lambda b: np.linalg.norm(b.vertices.mean(axis=0) - centre))
        r = np.linalg.norm(ball.vertices - centre, axis=1)
        # manifold3d keeps its vertices in float32: a tenth of a micrometre here
        assert r.max() == pytest.approx(seat.ball_radius_m, abs=1e-7) and r.min() > 0.95 * seat.ball_radius_m
        disc = min(discs, key=lambda d: np.linalg.norm(d.vertices.mean(axis=0) - p))
        along = (disc.vertices - p) @ n  # from the site to 1 mm up its normal
        assert along.min() == pytest.approx(0.0, abs=1e-7) and along.max() == pytest.approx(0.001, abs=1e-7)
        across = np.linalg.norm((disc.vertices - p) - along[:, None] * n, axis=1)
        assert across.max() == pytest.approx(seat.base_radius_m, abs=1e-7)
    # the STL and GLB hold the prop and these parts
    prop = load_prop("box")
    stl = trimesh.load(trimesh.util.wrap_as_stream(marker_mesh(prop, pts, nrm, seat, "stl")), file_type="stl")
    assert len(stl.faces) == len(prop.faces) + len(f)
    glb = trimesh.load(trimesh.util.wrap_as_stream(marker_mesh(prop, pts, nrm, seat)), file_type="glb")
    assert sorted(glb.geometry) == ["markers", "prop"] and len(glb.geometry["markers"].faces) == len(f)
    assert len(stl_bytes(v, f)) == 84 + 50 * len(f)
