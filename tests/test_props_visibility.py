"""Visibility: hand-worked cases and an independent brute-force re-check."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.props.rig import Camera, Poses, Rig, Volume, grid_positions, load_rig, make_poses
from starforge.props.visibility import compute_table, segment_occluded


def _identity_pose(at=(0.0, 0.0, 0.0)):
    return Poses(np.eye(3)[None], np.array([at], dtype=float), np.zeros(3))


def _rig(cams, pairs):
    return Rig(cameras=tuple(cams), pairs=tuple(pairs), volume=Volume((0, 0, 0), (0.1, 0.1, 0.1)))


@pytest.fixture(scope="module")
def box():
    import trimesh

    return trimesh.creation.box(extents=(0.4, 0.4, 0.4))  # centred at the origin, top at z = 0.2


def test_top_seen_from_above_bottom_by_none_out_of_view_by_none(box):
    above = [Camera((0.0, 0.0, 3.0), (0, 0, 0), 60), Camera((1.0, 0.0, 3.0), (0, 0, 0), 60)]
    aside = [Camera((3.0, 0.0, 0.0), (3.0, 5.0, 0.0), 30), Camera((3.0, 1.0, 0.0), (3.0, 5.0, 0.0), 30)]
    rig = _rig(above + aside, [(0, 1), (2, 3)])
    pts = np.array([[0.05, 0.02, 0.2], [0.05, 0.02, -0.2]])
    nrm = np.array([[0, 0, 1.0], [0, 0, -1.0]])
    seen = compute_table(box, pts, nrm, rig, _identity_pose()).seen[:, 0, :]
    # top marker: the pair above sees it; the pair looking away (+y, far to the side) does not
    assert seen[0].tolist() == [True, False]
    # bottom marker faces away from every camera: nobody sees it
    assert seen[1].tolist() == [False, False]


def test_marker_outside_field_of_view(box):
    # a pair straight above the box with a narrow 4 degree field of view aimed at its centre
    cams = [Camera((0.0, 0.0, 3.0), (0, 0, 0), 4), Camera((0.01, 0.0, 3.0), (0.01, 0, 0), 4)]
    rig = _rig(cams, [(0, 1)])
    pts = np.array([[0.18, 0.18, 0.2], [0.0, 0.0, 0.2]])  # a corner of the top face, and its centre
    # hand check: the corner is ~5.2 degrees off the optical axis, beyond the ~2 degree half-angle
    d = np.subtract(pts[0], cams[0].position)
    assert math.degrees(math.atan2(math.hypot(d[0], d[1]), -d[2])) > 5
    t = compute_table(box, pts, np.array([[0, 0, 1.0], [0, 0, 1.0]]), rig, _identity_pose())
    assert t.seen[:, 0, 0].tolist() == [False, True]


def test_occluded_by_the_prop_itself():
    import trimesh

    # a low slab with a tall wall on it; a marker on the slab at the foot of the wall
    slab = trimesh.creation.box(extents=(1.0, 1.0, 0.1))
    wall = trimesh.creation.box(extents=(0.1, 1.0, 1.0), transform=_tf((0.2, 0, 0.55)))
    prop = trimesh.util.concatenate([slab, wall])
    site = np.array([[0.0, 0.0, 0.05]])
    up = np.array([[0.0, 0.0, 1.0]])
    # cameras low on the far side of the wall (+x), looking at the marker: line of sight crosses the wall
    far = [Camera((3.0, 0.0, 0.6), (0, 0, 0.05), 60), Camera((3.0, 0.5, 0.6), (0, 0, 0.05), 60)]
    near = [Camera((-3.0, 0.0, 0.6), (0, 0, 0.05), 60), Camera((-3.0, 0.5, 0.6), (0, 0, 0.05), 60)]
    rig = _rig(far + near, [(0, 1), (2, 3)])
    seen = compute_table(prop, site, up, rig, _identity_pose(), grazing_limit_deg=89).seen[0, 0]
    assert seen.tolist() == [False, True]
    # the same cameras see it once the wall is gone (so the wall, not the field of view, blocked it)
    seen_open = compute_table(slab, site, up, rig, _identity_pose(), grazing_limit_deg=89).seen[0, 0]
    assert seen_open.tolist() == [True, True]
    # with occlusion switched off the wall is see-through: the frustum-and-facing model
    no_occ = compute_table(prop, site, up, rig, _identity_pose(), grazing_limit_deg=89, occlusion=False)
    assert no_occ.seen[0, 0].tolist() == [True, True] and no_occ.rays == 0


def test_switching_occlusion_off_only_adds_visibility():
    from starforge.props.builtin import builtin_mesh
    from starforge.props.sites import sample_sites

    rng = np.random.default_rng(0)
    mesh = builtin_mesh("hammer")
    rig = load_rig("default")
    sites = sample_sites(mesh, 120, rng)
    poses = make_poses(rig.volume, 2, 6, mesh.bounds.mean(axis=0), rng)
    on = compute_table(mesh, sites.points, sites.normals, rig, poses, 80.0).seen
    off = compute_table(mesh, sites.points, sites.normals, rig, poses, 80.0, occlusion=False).seen
    assert (off >= on).all() and off.sum() > on.sum()


def test_grazing_limit(box):
    # camera pair level with the top face, 20 degrees above its plane: normal-to-camera angle ~70 degrees
    cams = [
        Camera((3.0, 0.0, 0.2 + 3 * math.tan(math.radians(20))), (0, 0, 0.2), 60),
        Camera((3.0, 0.3, 0.2 + 3 * math.tan(math.radians(20))), (0, 0, 0.2), 60),
    ]
    rig = _rig(cams, [(0, 1)])
    args = (box, np.array([[0.0, 0.0, 0.2]]), np.array([[0, 0, 1.0]]), rig, _identity_pose())
    assert compute_table(*args, grazing_limit_deg=75).seen.all()
    assert not compute_table(*args, grazing_limit_deg=65).seen.any()


def _tf(t):
    m = np.eye(4)
    m[:3, 3] = t
    return m


def test_segment_occluded_is_a_segment_not_a_ray(box):
    o = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0]])
    tgt = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -2.0]])  # stops above the box / passes through it
    assert segment_occluded(box, o, tgt).tolist() == [False, True]


def _brute_force(mesh, pts, nrm, rig, poses, grazing_deg):
    """Independent re-check: world-frame geometry with angles, trimesh's numpy ray tracer."""
    from trimesh.ray.ray_triangle import RayMeshIntersector

    tracer = RayMeshIntersector(mesh)
    mats = poses.matrices()
    out = np.zeros((len(pts), len(poses), len(rig.pairs)), dtype=bool)
    for k, M in enumerate(mats):
        R, t = M[:3, :3], M[:3, 3]
        world = pts @ R.T + t
        wn = nrm @ R.T
        cam_ok = np.zeros((len(pts), len(rig.cameras)), dtype=bool)
        for c, cam in enumerate(rig.cameras):
            right, up, fwd = cam.basis()
            th, tv = cam.half_tangents
            for i in range(len(pts)):
                d = world[i] - np.asarray(cam.position)
                z = d @ fwd
                if z <= 0:
                    continue
                if math.atan2(abs(d @ right), z) > math.atan(th) or math.atan2(abs(d @ up), z) > math.atan(
                    tv
                ):
                    continue
                to_cam = -d / np.linalg.norm(d)
                if math.degrees(math.acos(np.clip(wn[i] @ to_cam, -1, 1))) > grazing_deg:
                    continue
                # occlusion in the prop frame: from the site towards the camera
                cam_local = R.T @ (np.asarray(cam.position) - t)
                o = pts[i] + 1e-6 * nrm[i]
                v = cam_local - o
                dist = np.linalg.norm(v)
                locs, _, _ = tracer.intersects_location([o], [v / dist])
                hits = np.linalg.norm(locs - o, axis=1) if len(locs) else np.zeros(0)
                cam_ok[i, c] = not np.any(hits < dist)
        for j, (a, b) in enumerate(rig.pairs):
            out[:, k, j] = cam_ok[:, a] & cam_ok[:, b]
    return out


def test_table_matches_brute_force_on_hammer():
    from starforge.props.builtin import builtin_mesh
    from starforge.props.sites import sample_sites

    rng = np.random.default_rng(5)
    mesh = builtin_mesh("hammer")
    sites = sample_sites(mesh, 60, rng)
    rig = load_rig("default")
    poses = make_poses(rig.volume, 2, 2, mesh.bounds.mean(axis=0), rng)
    fast = compute_table(mesh, sites.points, sites.normals, rig, poses, 80.0).seen
    slow = _brute_force(mesh, sites.points, sites.normals, rig, poses, 80.0)
    assert fast.any() and not fast.all()
    # allow a handful of disagreements only where a ray grazes an edge (float32 embree vs float64)
    assert (fast != slow).mean() < 0.001


def test_rig_template_is_the_papers():
    rig = load_rig("default")
    assert len(rig.cameras) == 8 and len(rig.pairs) == 4
    assert sorted(i for p in rig.pairs for i in p) == list(range(8))
    assert all(c.fov_deg == 60 and c.position[2] == 2.5 for c in rig.cameras)
    assert rig.volume.size == (2.0, 2.0, 2.0)
    for a, b in rig.pairs:  # non-parallel views
        fa, fb = rig.cameras[a].basis()[2], rig.cameras[b].basis()[2]
        assert abs(fa @ fb) < 0.9
    pos = grid_positions(rig.volume, 4)
    assert len(pos) == 64
    lo = np.subtract(rig.volume.center, np.divide(rig.volume.size, 2))
    hi = np.add(rig.volume.center, np.divide(rig.volume.size, 2))
    assert np.all(pos > lo) and np.all(pos < hi)


def test_no_pair_sees_the_volume():
    cams = [Camera((5.0, 0, 1), (10.0, 0, 1), 30), Camera((5.0, 1, 1), (10.0, 1, 1), 30)]
    rig = Rig(cameras=tuple(cams), pairs="auto")
    import trimesh

    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    with pytest.raises(StarforgeError, match="no camera pair sees the capture volume"):
        compute_table(
            box,
            np.zeros((1, 3)),
            np.array([[0, 0, 1.0]]),
            rig,
            make_poses(rig.volume, 2, 1, np.zeros(3), np.random.default_rng(0)),
        )


def test_pose_matrices_map_pivot_to_position():
    rng = np.random.default_rng(1)
    poses = make_poses(Volume(), 2, 3, np.array([0.1, 0.2, 0.3]), rng)
    M = poses.matrices()
    assert len(poses) == 24
    for k in range(len(poses)):
        R = M[k, :3, :3]
        assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
        assert np.allclose(M[k] @ np.array([0.1, 0.2, 0.3, 1.0]), [*poses.translations[k], 1.0])


def test_fallback_tracer_agrees_with_embree(box, monkeypatch):
    import sys

    from starforge.props.rays import RayScene

    rng = np.random.default_rng(0)
    o = rng.uniform(-1, 1, (200, 3)) * [1, 1, 0.1] + [0, 0, 1.0]
    t = rng.uniform(-1, 1, (200, 3)) * [1, 1, 0.1] - [0, 0, 1.0]
    fast = segment_occluded(box, o, t)
    monkeypatch.setitem(sys.modules, "embreex", None)  # import embreex now fails
    slow = RayScene(box.vertices, box.faces).blocked(o, t)
    assert fast.any() and not fast.all()
    assert np.array_equal(fast, slow)


def test_the_scene_is_trimeshs_and_is_built_again_when_the_mesh_changes():
    """Segments blocked by the scene equal those blocked by trimesh's own embree scene (the
    one the tables were computed with before), to the bit; a trimesh mesh changed in place gets
    a new scene."""
    from starforge.props.builtin import builtin_mesh
    from starforge.props.rays import ray_scene

    mesh = builtin_mesh("hammer")
    rng = np.random.default_rng(5)
    o = mesh.sample(3000, seed=1) + rng.normal(size=(3000, 3)) * 1e-3
    t = rng.normal(size=(3000, 3)) * 2.0
    wrap = mesh.ray._scene  # trimesh's scaled embreex scene
    vec = t - o
    dist = np.linalg.norm(vec, axis=1)
    want = np.asarray(wrap.run(o, vec / dist[:, None], dists=(dist * wrap.scale).astype(np.float32), query="OCCLUDED")) != -1
    assert 0.05 < want.mean() < 0.95
    assert np.array_equal(segment_occluded(mesh, o, t), want)
    import trimesh

    box = trimesh.creation.box(extents=(0.1, 0.2, 0.3))
    before = ray_scene(box)
    assert ray_scene(box) is before
    box.vertices = box.vertices * 2.0
    assert ray_scene(box) is not before and ray_scene(box).size == pytest.approx(2.0 * before.size)


def test_kernel_dot_is_the_fused_blas_sum():
    """The kernels' 3-vector dot product: round(x0*y0), then two fused multiply-adds, each
    rounded once (what OpenBLAS's ddot computes on an FMA machine), re-checked in exact
    rational arithmetic."""
    from fractions import Fraction as F

    from starforge.props.visibility import _dot3

    def fma(a, b, c):
        return float(F(a) * F(b) + F(c))  # exact product and sum, one rounding

    rng = np.random.default_rng(11)
    for x, y in zip(rng.normal(size=(400, 3)) * rng.lognormal(size=(400, 1)), rng.normal(size=(400, 3)), strict=True):
        want = fma(x[2], y[2], fma(x[1], y[1], float(F(x[0]) * F(y[0]))))
        assert _dot3(*x, *y) == want


def test_segment_distance_matches_dense_sampling():
    from starforge.props.visibility import _seg_seg_dist2

    rng = np.random.default_rng(12)
    t = np.linspace(0.0, 1.0, 801)
    for k in range(40):
        p0, p1, q0, q1 = rng.normal(size=(4, 3))
        if k % 10 == 0:
            p1 = p0.copy()  # a point against a segment
        if k % 10 == 1:
            q1 = q0.copy()
        if k % 10 == 2:
            q1 = q0 + 2.0 * (p1 - p0)  # parallel segments
        a = p0 + t[:, None] * (p1 - p0)
        b = q0 + t[:, None] * (q1 - q0)
        brute = float((((a[:, None] - b[None]) ** 2).sum(axis=2)).min())
        got = _seg_seg_dist2(*p0, *p1, *q0, *q1)
        step = (np.linalg.norm(p1 - p0) + np.linalg.norm(q1 - q0)) / 800 / 2  # farthest from a grid point
        assert got <= brute + 1e-12
        assert brute - got <= 2 * math.sqrt(got) * step + step**2 + 1e-12


def test_ray_hits_agree_with_trimesh_with_and_without_embree(monkeypatch):
    """The sight lines the guide casts (embree called on the arrays) against trimesh's own numpy
    ray tracer, an independent implementation, on rays from all round the hammer; and the same
    without embree installed."""
    import sys

    from trimesh.ray.ray_triangle import RayMeshIntersector

    from starforge.props.builtin import builtin_mesh
    from starforge.props.rays import RayScene

    mesh = builtin_mesh("hammer")
    rng = np.random.default_rng(3)
    origins = mesh.bounds.mean(axis=0) + rng.normal(size=(400, 3)) * 0.1
    outside = ~mesh.contains(origins)
    origins = origins[outside]
    aims = mesh.sample(len(origins), seed=4) + rng.normal(size=(len(origins), 3)) * 0.01  # near the surface
    dirs = aims - origins
    want = RayMeshIntersector(mesh).intersects_any(origins, dirs)
    assert 0.1 < want.mean() < 0.9
    scene = RayScene(mesh.vertices, mesh.faces)
    assert scene.size == mesh.scale
    assert np.array_equal(scene.hits(origins, dirs), want)
    monkeypatch.setitem(sys.modules, "embreex", None)  # import embreex now fails
    assert np.array_equal(RayScene(mesh.vertices, mesh.faces).hits(origins, dirs), want)
    assert scene.hits(np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


def test_first_hits_are_trimeshs_to_the_bit_from_one_scene():
    """The seat's first hits (the scene's first triangle, trimesh's plane intersection) against
    trimesh's own intersects_id on rays that hit, miss and graze the hammer; a PropMesh and its
    built mesh share one scene."""
    from starforge.props.builtin import builtin_mesh
    from starforge.props.mesh import PropMesh
    from starforge.props.rays import ray_scene
    from starforge.props.visibility import first_hits

    mesh = builtin_mesh("hammer")
    rng = np.random.default_rng(8)
    n = 4000
    o = mesh.sample(n, seed=2) + rng.normal(size=(n, 3)) * 0.004
    d = -rng.normal(size=(n, 3)) - (o - mesh.bounds.mean(axis=0))
    d /= np.linalg.norm(d, axis=1)[:, None]
    tri, ray, loc = mesh.ray.intersects_id(o, d, multiple_hits=False, return_locations=True)
    want_d = np.full(n, np.inf)
    want_f = np.full(n, -1)
    want_d[ray] = np.einsum("ij,ij->i", loc - o[ray], d[ray])
    want_f[ray] = tri
    dist, face = first_hits(mesh, o, d)
    assert 0.2 < (face >= 0).mean() < 0.98
    assert np.array_equal(face, want_f) and np.array_equal(dist, want_d)
    prop = PropMesh.of(mesh, "h", "x.stl", "m", np.arange(len(mesh.faces)))
    assert ray_scene(prop) is ray_scene(mesh)


def test_first_hits_without_embree_are_the_numpy_tracers(monkeypatch):
    """Where embreex is not installed the first hits come from trimesh's numpy tracer: the same
    faces as its intersects_id, the distances to a micrometre's millionth."""
    import sys

    from trimesh.ray.ray_triangle import RayMeshIntersector

    from starforge.props.builtin import builtin_mesh
    from starforge.props.visibility import first_hits

    monkeypatch.setitem(sys.modules, "embreex", None)  # import embreex now fails
    mesh = builtin_mesh("box")
    rng = np.random.default_rng(9)
    o = mesh.sample(500, seed=3) + rng.normal(size=(500, 3)) * 0.01
    d = mesh.bounds.mean(axis=0) - o + rng.normal(size=(500, 3)) * 0.1
    d /= np.linalg.norm(d, axis=1)[:, None]
    tri, ray, loc = RayMeshIntersector(mesh).intersects_id(o, d, multiple_hits=False, return_locations=True)
    want_f = np.full(len(o), -1)
    want_f[ray] = tri
    dist, face = first_hits(mesh, o, d)
    assert (face >= 0).mean() > 0.5 and np.array_equal(face, want_f)
    np.testing.assert_allclose(dist[ray], np.einsum("ij,ij->i", loc - o[ray], d[ray]), rtol=0, atol=1e-12)
