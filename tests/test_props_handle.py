"""Handles from the prop's shape: a loop a hand closes round gets grips; a bottle or a cup does not."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from starforge.props.files import grip_lines
from starforge.props.grips import (
    HANDLE_SHARE,
    assign_grips,
    cut_directions,
    grip_distribution,
    held_part,
    under_hand,
)
from starforge.props.hand import inside_capsules
from starforge.props.handle import find_handle, has_tunnel
from starforge.props.heldout import hidden_share

T = trimesh.transformations


def _cylinder(r, h, z0=0.0):
    m = trimesh.creation.cylinder(radius=r, height=h, sections=48)
    m.apply_translation([0, 0, z0 + h / 2])
    return m


def _cup(r=0.042, h=0.1, wall=0.005):
    """An open cup: a cylinder less its cavity (a pocket, not a tunnel)."""
    return trimesh.boolean.difference([_cylinder(r, h), _cylinder(r - wall, h, wall)], engine="manifold")


def _handle(r=0.042, major=0.028, minor=0.006):
    """A ring in the xz plane straddling the cup's wall on +x."""
    ring = trimesh.creation.torus(major_radius=major, minor_radius=minor, major_sections=48, minor_sections=16)
    ring.apply_transform(T.rotation_matrix(math.pi / 2, [1, 0, 0]))
    ring.apply_translation([r + major - 2 * minor, 0, 0.05])
    return ring


def _mug(tilt_deg: float = 0.0):
    """The cup with its handle, and the handle alone (both turned by ``tilt_deg``)."""
    handle = _handle()
    mug = trimesh.boolean.union([_cup(), handle], engine="manifold")
    if tilt_deg:
        R = T.rotation_matrix(math.radians(tilt_deg), [1, 2, 0])
        mug.apply_transform(R)
        handle.apply_transform(R)
    return mug, handle


def _surface_distance(points, mesh, per_edge=12):
    """Brute force: each point's distance to the closest of a dense grid of points on every
    face of ``mesh`` (barycentric, ``per_edge`` steps a side)."""
    i, j = np.meshgrid(np.arange(per_edge + 1), np.arange(per_edge + 1), indexing="ij")
    keep = i + j <= per_edge
    u, v = i[keep] / per_edge, j[keep] / per_edge
    tri = np.asarray(mesh.triangles)
    grid = (tri[:, None, 0] * (1 - u - v)[None, :, None] + tri[:, None, 1] * u[None, :, None]
            + tri[:, None, 2] * v[None, :, None]).reshape(-1, 3)  # fmt: skip
    return np.array([np.linalg.norm(grid - p, axis=1).min() for p in np.atleast_2d(points)])


@pytest.mark.parametrize("tilt", [0.0, pytest.param(33.0, marks=pytest.mark.slow)])
def test_a_mug_gets_grips_on_its_handle_whatever_its_orientation(tilt):
    mug, handle = _mug(tilt)
    part, grips = grip_distribution(mug)
    assert part.handle is not None
    on = [g for g in grips if g.on_handle]
    assert len(on) == 6 and {g.hand for g in on} == {"right", "left"}
    total = sum(g.weight for g in grips)
    assert sum(g.weight for g in on) / total == pytest.approx(HANDLE_SHARE)
    # the fist's axis runs through the handle's bar: its middle is nearer the handle's surface
    # than the cup's (the axis is the bar's chord; towards its ends the curved bar runs into the cup)
    cup = trimesh.boolean.difference([mug, handle], engine="manifold")
    for g in on:
        fist = g.capsules[0]
        core = (np.asarray(fist.a) + np.asarray(fist.b))[None] / 2
        d_handle = _surface_distance(core, handle)
        assert d_handle.max() <= 0.006 + 2e-3  # the bar's radius and a margin
        assert (_surface_distance(core, cup) > d_handle).all()
        assert fist.radius == pytest.approx(part.handle.radius_m + 0.025, abs=1e-9)
        assert part.handle.radius_m == pytest.approx(0.006, abs=1.5e-3)
        # the wrist leaves away from the body: its far end is farther from the cup's axis than the fist
        wrist = g.capsules[1]
        axis = T.rotation_matrix(math.radians(tilt), [1, 2, 0])[:3, :3] @ np.array([0.0, 0.0, 1.0])

        def off_axis(p, axis=axis):
            p = np.asarray(p, float)
            return np.linalg.norm(p - (p @ axis) * axis)

        assert off_axis(wrist.b) > off_axis(fist.a) + 0.1


def test_the_mugs_body_is_held_without_its_handle():
    mug, _ = _mug()
    part, grips = grip_distribution(mug)
    # the cup (and the stubs where the handle meets it), not the cup and the handle (over 90 mm across)
    assert part.found and part.radius_m == pytest.approx(0.042, abs=4e-3)
    body = [g for g in grips if not g.on_handle]
    assert body and all(abs(np.asarray(g.capsules[0].a)[:2]).max() < 3e-3 for g in body)  # round the cup's axis
    text = "\n".join(grip_lines(part, grips))
    assert "on the handle" in text and f"{100 * HANDLE_SHARE:.0f} % of the poses" in text


@pytest.mark.parametrize(
    "mesh",
    [
        _cylinder(0.035, 0.2),
        _cup(),  # a cavity is a pocket: no way through it
        trimesh.boolean.union([_cylinder(0.033, 0.18), _cylinder(0.0135, 0.06, 0.18)], engine="manifold"),
    ],
    ids=["cylinder", "cup", "bottle"],
)
def test_a_prop_without_a_loop_gets_no_handle_and_the_same_grips(mesh):
    assert find_handle(mesh, cut_directions(np.asarray(mesh.vertices))) is None
    part, grips = grip_distribution(mesh)
    assert part.handle is None and all(g.weight == 1.0 for g in grips)
    assert part == held_part(mesh)
    assert not any("handle" in g.label for g in grips)


def test_a_hoop_too_wide_for_a_hand_is_no_handle():
    hoop = trimesh.creation.torus(major_radius=0.11, minor_radius=0.009)
    stick = _cylinder(0.014, 0.2, -0.3)
    racket = trimesh.boolean.union([hoop.apply_transform(T.rotation_matrix(math.pi / 2, [1, 0, 0])),
                                    stick.apply_translation([0, 0, 0.19])], engine="manifold")  # fmt: skip
    assert find_handle(racket, cut_directions(np.asarray(racket.vertices))) is None


def test_weighted_grips_get_poses_in_proportion_and_equal_weights_as_before():
    mug, _ = _mug()
    _, grips = grip_distribution(mug)
    got = assign_grips(1000, grips, np.random.default_rng(4))
    counts = np.bincount(got, minlength=len(grips))
    w = np.array([g.weight for g in grips])
    assert counts.sum() == 1000 and np.abs(counts - 1000 * w / w.sum()).max() < 1.0
    assert np.array_equal(assign_grips(1000, grips, np.random.default_rng(4)), got)
    plain = grip_distribution(_cylinder(0.035, 0.2))[1]
    assert np.array_equal(
        assign_grips(301, plain, np.random.default_rng(9)), assign_grips(301, len(plain), np.random.default_rng(9))
    )


def test_sites_under_the_handle_are_weighed_by_how_often_it_is_held():
    mug, handle = _mug()
    part, grips = grip_distribution(mug)
    bar = np.asarray(part.handle.centres)  # inside the handle's bar
    on = [g for g in grips if g.on_handle]
    fisted = inside_capsules(bar, [on[0].capsules[0]])
    assert fisted.any()  # the fist closes round the bar, and every handle grip's fist covers it there
    assert all(inside_capsules(bar[fisted], g.capsules[:1]).all() for g in on)
    assert under_hand(bar[fisted], bar[fisted], grips, share=0.5).all()  # held so in most poses
    # where only the body's fists cover the bar (by the cup), it is held so in too few poses
    body = [g for g in grips if g not in on]
    by_body = under_hand(bar, bar, body) & ~under_hand(bar, bar, on)
    assert by_body.any() and not under_hand(bar[by_body], bar[by_body], grips, share=0.5).any()


def test_a_loop_is_looked_for_only_where_the_topology_allows_one():
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    ring = trimesh.creation.torus(major_radius=0.03, minor_radius=0.008)
    assert not has_tunnel(sphere) and has_tunnel(ring)
    two = trimesh.util.concatenate([sphere, ring.apply_translation([0.2, 0, 0])])  # 2 + 0 = 2, two bodies
    assert int(two.euler_number) == 2 and has_tunnel(two)
    assert not has_tunnel(trimesh.util.concatenate([sphere, sphere.copy().apply_translation([0.2, 0, 0])]))
    tube = _cylinder(0.035, 0.2)
    tube.update_faces(np.abs(tube.face_normals[:, 2]) < 0.5)  # open at both ends: searched, and none found
    assert has_tunnel(tube) and find_handle(tube, cut_directions(np.asarray(tube.vertices))) is None



def _inside_brute(points, capsules, samples=4001):
    """Each point within some capsule's radius of the closest of ``samples`` points on its core."""
    out = np.zeros(len(points), bool)
    for c in capsules:
        core = np.linspace(c.a, c.b, samples)
        d = np.array([np.linalg.norm(core - p, axis=1).min() for p in points])
        out |= d <= c.radius
    return out


def _inside_shapes(points, capsules):
    """Each point within some capsule's radius of its core segment (the textbook projection,
    clamped to the segment), a band (``flat``) cut square at its ends."""
    out = np.zeros(len(points), bool)
    for c in capsules:
        a, b = np.asarray(c.a), np.asarray(c.b)
        t = (points - a) @ (b - a) / ((b - a) @ (b - a))
        near = np.linalg.norm(points - (a + np.clip(t, 0, 1)[:, None] * (b - a)), axis=1) <= c.radius
        out |= near & ((t >= 0) & (t <= 1) if c.flat else True)
    return out


def test_the_share_of_poses_whose_hand_encloses_the_sites_is_weighed_by_the_grips():
    mug, _ = _mug()
    _, grips = grip_distribution(mug)
    v = np.asarray(mug.vertices)
    r = np.linalg.norm(v[:, :2], axis=1)
    wall = v[(np.abs(r - 0.042) < 1e-4) & (v[:, 2] > 0.02) & (v[:, 2] < 0.08)]  # the cup's outer wall
    sites = wall + 0.005 * np.column_stack([wall[:, :2] / 0.042, np.zeros(len(wall))])  # ball centres off it
    want = sum(g.weight for g in grips if (~_inside_brute(sites, g.capsules)).sum() < 3) / sum(g.weight for g in grips)
    assert hidden_share(sites, grips) == pytest.approx(want)
    assert 0 < want < 1  # the body's grips enclose the cup, the handle's do not
    assert hidden_share(sites, ()) == 0.0
    # balls on 30 mm posts stand clear of the fist, but the fist holds the posts: a marker whose
    # post (sampled densely here) passes through the hand is lost as well
    feet = wall[:: max(1, len(wall) // 30)]
    out = feet + 0.03 * np.column_stack([feet[:, :2] / 0.042, np.zeros(len(feet))])
    post = np.linspace(0.0, 1.0, 121)
    along = (feet[:, None] + post[None, :, None] * (out - feet)[:, None]).reshape(-1, 3)
    held = [_inside_shapes(along, g.capsules).reshape(len(feet), -1).any(axis=1) for g in grips]
    lost = sum(g.weight for g, h in zip(grips, held, strict=True) if (~h).sum() < 3) / sum(g.weight for g in grips)
    assert hidden_share(out, grips, feet) == pytest.approx(lost)
    assert hidden_share(out, grips) < lost  # the balls alone are out of the fist
