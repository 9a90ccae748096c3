"""Placement on eight props that are not the built-ins, checked independently; JSON on stdout.

The props are made here with trimesh primitives united by manifold3d (their shapes, in metres:
a bottle, a box-and-cylinder torch, an open umbrella, a mug with a handle, a cordless drill, a
racket, a gable-top milk carton, a screwdriver).  Each is placed by ``run_placement`` (the
default spec, seed 0) and then checked by an evaluation that shares nothing with the optimizer
but the prop's mesh and the layout:

* its own room: 8 cameras on a ring 6 m across, 2.5 m up, looking at the middle of a 2 x 2 x
  1.6 m volume (0.2-1.8 m up), a 60 degree cone of view, no pairs: a marker is reconstructed
  when 2 of the surviving cameras see its ball centre;
* uniformly random rotations (normalised Gaussian quaternions) at uniform random positions,
  4 of the 8 cameras lost at random in each pose;
* a hand at a random grip, its own model: across any of the prop's three bounding-box axes,
  the palm (90 mm) centred at a uniformly random place (cross-sections every 5 mm, cut exactly
  from the mesh's edges) where every section under it fits in a circle at most 70 mm across
  (where any one does, when no palm fits anywhere; where the palm lies on the prop across its
  longest axis when none does); the fist is a band as long as the palm and 25 mm thicker than
  that circle, and a forearm (a capsule of 35 mm radius, 220 mm long) leaves it at a random
  angle around the axis; markers inside the fist are lost, sight lines through the fist or the
  forearm are blocked; with ``--standoff MM`` (every marker on a printed post), a marker whose
  post passes through the fist is lost too;
* sight lines to the prop: trimesh's ray queries from the ball centre to the camera.

A pose is tracked when >= 3 markers are reconstructed and they span a triangle 15 mm high (RMS
distance from their best-fit line >= sqrt(2)/3 x 15 mm).  Reported per prop: the chosen
layout's tracked fraction on ``POSES`` poses; the best of 200 random layouts of the same number
of markers on the same usable sites (markers at least the run's spacing apart) picked on those
poses (``best_random_same_poses``, an upward-biased maximum) and re-measured on fresh poses
(``best_random_fresh_poses``, beside ``chosen_fresh_poses``); the same poses with a marker on
every usable site (``every_site_fresh_poses``: an upper bound for any layout on these sites, so
a prop below the target there cannot reach it with markers stuck on its surface); how many of them a tracker
cannot flip (no two of their marker triangles, nor one and itself relabelled, within the run's
``avoid_tolerance_mm``: starforge's own rule, which its layouts keep) and the best of those on
fresh poses (``random_flip_proof``, ``best_flip_proof_random_fresh_poses``); the markers with less than the
placement error of room, recomputed by brute force over every face and sharp edge of the mesh
(for a marker on a clamp, the straight rod beyond its ring, from exact plane sections:
:func:`clamp_shortfall`) (``markers_below_margin``); the overlapping glyphs of the written guide.pdf as pdfminer.six reads
the file (``guide_text_overlaps``, :mod:`_pdftext`) and the glyphs off the page; in the guide's
views as drawn, the labels that cover another label or a marker's dot or a landmark's triangle
(``guide_label_clashes``, :mod:`_views`) and the landmarks the marker table names that no view
labels (``guide_landmarks_unlabelled``).

Run: ``python benchmarks/bench_props_real.py [--poses 600] [--props bottle,torch] [--room] [--standoff MM] [--write-docs]``
(``--room`` places each prop for this room, :func:`room_rig_toml`, instead of starforge's default
rig; ``--write-docs`` also writes the table into the docs' results page, ``docs/results.md``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

POSES = 600
RANDOM_LAYOUTS = 200
T = trimesh.transformations


def _union(parts):
    return trimesh.boolean.union(parts, engine="manifold")


def _cyl(r, h, z0, axis="z", xy=(0.0, 0.0), sections=48):
    m = trimesh.creation.cylinder(radius=r, height=h, sections=sections)
    m.apply_translation([0, 0, z0 + h / 2])
    if axis == "x":
        m.apply_transform(T.rotation_matrix(math.pi / 2, [0, 1, 0]))
    m.apply_translation([xy[0], xy[1], 0])
    return m


def _box(ext, centre):
    m = trimesh.creation.box(extents=ext)
    m.apply_translation(centre)
    return m


def props() -> dict:
    """name -> trimesh.Trimesh (m)."""
    out = {}
    shoulder = trimesh.creation.cone(radius=0.033, height=0.05, sections=48)
    shoulder.apply_translation([0, 0, 0.17])
    out["bottle"] = _union([_cyl(0.033, 0.18, 0.0), shoulder, _cyl(0.0135, 0.06, 0.19), _cyl(0.015, 0.015, 0.245)])
    out["torch"] = _union([_cyl(0.0175, 0.2, 0.0), _box((0.06, 0.06, 0.05), (0, 0, 0.225))])
    canopy = trimesh.creation.cone(radius=0.45, height=0.15, sections=8)
    canopy.apply_translation([0, 0, 0.62])
    out["umbrella"] = _union([_cyl(0.014, 0.12, 0.0), _cyl(0.006, 0.72, 0.11), canopy])
    cup = trimesh.boolean.difference([_cyl(0.04, 0.095, 0.0), _cyl(0.036, 0.095, 0.006)], engine="manifold")
    handle = trimesh.creation.torus(major_radius=0.03, minor_radius=0.007)
    handle.apply_transform(T.rotation_matrix(math.pi / 2, [1, 0, 0]))
    handle.apply_translation([0.045, 0, 0.05])
    out["mug"] = _union([cup, handle])
    out["drill"] = _union([
        _box((0.18, 0.05, 0.06), (0.03, 0, 0.17)), _cyl(0.02, 0.12, 0.04), _box((0.08, 0.07, 0.04), (0.0, 0, 0.02)),
        _cyl(0.015, 0.05, 0.12, axis="x").apply_translation([0, 0, 0.17]),
    ])  # fmt: skip
    ring = trimesh.creation.torus(major_radius=0.11, minor_radius=0.009)
    ring.apply_transform(T.scale_matrix(1.3, direction=[0, 1, 0]))
    ring.apply_transform(T.rotation_matrix(math.pi / 2, [1, 0, 0]))
    ring.apply_translation([0, 0, 0.38])
    out["racket"] = _union([_cyl(0.014, 0.2, 0.0), _cyl(0.008, 0.08, 0.195), ring])
    gable = trimesh.convex.convex_hull(np.array(
        [[x, y, 0.19] for x in (-0.035, 0.035) for y in (-0.035, 0.035)] + [[x, 0.0, 0.225] for x in (-0.035, 0.035)]
    ))  # fmt: skip
    out["milk_carton"] = _union([_box((0.07, 0.07, 0.19), (0, 0, 0.095)), gable, _box((0.07, 0.004, 0.015), (0, 0, 0.23))])
    out["screwdriver"] = _union([_cyl(0.016, 0.1, 0.0), _cyl(0.0035, 0.13, 0.095), _box((0.006, 0.001, 0.012), (0, 0, 0.23))])
    return out


def ring_cameras():
    """(8, 3) positions and (8, 3) unit view directions."""
    a = np.arange(8) * 2 * math.pi / 8
    pos = np.column_stack([3.0 * np.cos(a), 3.0 * np.sin(a), np.full(8, 2.5)])
    look = np.array([0.0, 0.0, 1.0]) - pos
    return pos, look / np.linalg.norm(look, axis=1, keepdims=True)


HALF_FOV = math.radians(30.0)


def room_rig_toml(mesh) -> str:
    """This room as a starforge rig file (``--room``): its 8 cameras (a square image whose 60
    degree view holds the cone), and a volume grown by half the prop's longest side, because
    this room keeps the mesh's origin, not its box's centre, anywhere in the volume."""
    pos, _ = ring_cameras()
    grow = float(max(mesh.extents))
    lines = ['name = "bench-room"', 'pairs = "auto"', "", "[volume]", "center = [0.0, 0.0, 1.0]",
             f"size = [{2.0 + grow:.4f}, {2.0 + grow:.4f}, {1.6 + grow:.4f}]", ""]
    for k, p in enumerate(pos):
        lines += ["[[cameras]]", f'name = "ring{k + 1}"', f"position = [{p[0]:.4f}, {p[1]:.4f}, {p[2]:.4f}]",
                  "target = [0.0, 0.0, 1.0]", f"fov_deg = {math.degrees(2 * HALF_FOV):.1f}", "resolution = [1024, 1024]", ""]
    return "\n".join(lines)
HAND_REACH = 1.2  # m: the hand lies within this of any marker (prop + forearm); sight lines are tested that far


def random_world(n, rng):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    R = T.quaternion_matrix(q[0])[:3, :3][None].repeat(n, 0)
    for k in range(n):
        R[k] = T.quaternion_matrix(q[k])[:3, :3]
    t = np.array([-1.0, -1.0, 0.2]) + rng.random((n, 3)) * np.array([2.0, 2.0, 1.6])
    return R, t


def seg_dist(p, q, a, b):
    """Distance between segments p-q (n, 3) and the fixed segment a-b, sampled finely."""
    s = np.linspace(0.0, 1.0, 256)
    pts = p[:, None] + s[None, :, None] * (q - p)[:, None]
    ab = b - a
    t = np.clip(((pts - a) @ ab) / max(ab @ ab, 1e-18), 0, 1)
    return np.linalg.norm(pts - (a + t[..., None] * ab), axis=2).min(axis=1)


SECTION_STEP = 0.005  # m between the cross-sections a hand is placed on
PALM = 0.09  # m
GRASPABLE = 0.07  # m: the widest section a fist closes around


def sections(mesh, ax):
    """The cross-sections of ``mesh`` across bounding-box axis ``ax`` every ``SECTION_STEP``: their
    heights, whether a fist closes around each (its points within a circle <= ``GRASPABLE``
    across), that circle's radius and centre (the other two coordinates), and whether the plane
    cuts the mesh at all.  A section's points are where the plane crosses the mesh's edges."""
    lo, hi = mesh.bounds
    others = [k for k in range(3) if k != ax]
    hs = np.arange(lo[ax] + SECTION_STEP, hi[ax] - SECTION_STEP / 2, SECTION_STEP)
    v = mesh.vertices
    e = mesh.edges_unique
    v0, v1 = v[e[:, 0]], v[e[:, 1]]
    ok, rad, cen, cut = [], [], [], []
    for h in hs:
        d0, d1 = v0[:, ax] - h, v1[:, ax] - h
        x = (d0 <= 0) != (d1 <= 0)
        if not x.any():
            ok.append(False), rad.append(0.0), cen.append(np.zeros(2)), cut.append(False)
            continue
        t = d0[x] / (d0[x] - d1[x])
        sl = (v0[x] + t[:, None] * (v1[x] - v0[x]))[:, others]
        c = (sl.max(0) + sl.min(0)) / 2
        r = float(np.linalg.norm(sl - c, axis=1).max())
        ok.append(2 * r <= GRASPABLE), rad.append(r), cen.append(c), cut.append(True)
    return hs, np.array(ok), np.array(rad), np.array(cen), np.array(cut)


def grip_places(mesh):
    """Where a hand may hold ``mesh``: (axis, height, section radius, section centre) for every
    section of every bounding-box axis with a palm's length of graspable sections around it;
    when there is none, every graspable section; when there is none of those either, every
    section across the longest axis with the palm on the prop."""
    palm, graspable, anywhere = [], [], []
    longest = int(np.argmax(mesh.extents))
    w = int(round(PALM / 2 / SECTION_STEP))
    for ax in range(3):
        hs, ok, rad, cen, cut = sections(mesh, ax)
        for k in range(len(hs)):
            place = (ax, float(hs[k]), float(rad[k]), cen[k])
            fits = w <= k < len(hs) - w
            if fits and ok[k - w : k + w + 1].all():
                palm.append(place)
            if ok[k]:
                graspable.append(place)
            if ax == longest and cut[k] and fits:
                anywhere.append(place)
    return palm or graspable or anywhere


def random_hands(mesh, n, rng):
    """Per pose: the fist, a band ``(centre, axis, radius, half length)``, and the forearm, a
    capsule ``(a, b, radius)``, in the prop frame, at a grip drawn uniformly from
    :func:`grip_places`."""
    places = grip_places(mesh)
    out = []
    for _ in range(n):
        ax, h, r, cen = places[int(rng.integers(len(places)))]
        others = [k for k in range(3) if k != ax]
        c = np.zeros(3)
        c[others] = cen
        c[ax] = h
        u = np.zeros(3)
        u[ax] = 1.0
        phi = rng.random() * 2 * math.pi
        radial = np.zeros(3)
        radial[others[0]], radial[others[1]] = math.cos(phi), math.sin(phi)
        w0 = c + (r + 0.035) * radial
        out.append(((c, u, r + 0.025, PALM / 2), (w0, w0 + 0.22 * radial, 0.035)))
    return out


def in_band(points, band):
    """Whether each of ``points`` (..., 3) lies inside the fist ``band``."""
    c, u, radius, half = band
    d = points - c
    along = d @ u
    return (np.abs(along) <= half) & (np.linalg.norm(d - along[..., None] * u, axis=-1) <= radius)


def band_blocks(p, q, band):
    """Whether the segment from each of ``p`` (n, 3) to ``q`` (n, 3) passes through ``band``, sampled finely."""
    s = np.linspace(0.0, 1.0, 256)
    return in_band(p[:, None] + s[None, :, None] * (q - p)[:, None], band).any(axis=1)


def seen_table(mesh, centres, normals, R, t, hands, rng, bases=None):
    """(P, s) int: cameras (of the surviving ones) that see each ball centre at each pose; with
    ``bases`` (s, 3), the feet of stand-off posts, a marker whose post the fist holds is lost."""
    cam, look = ring_cameras()
    P, S = len(R), len(centres)
    alive = np.zeros((P, 8), bool)
    for k in range(P):
        alive[k, rng.permutation(8)[:4]] = True
    counts = np.zeros((P, S), int)
    for k in range(P):
        w = centres @ R[k].T + t[k]
        qk = (cam - t[k]) @ R[k]  # cameras in the prop frame
        fist, (a, b, r) = hands[k]
        under = in_band(centres, fist)
        if bases is not None:
            under |= band_blocks(bases, centres, fist)
        for c in np.flatnonzero(alive[k]):
            d = w - cam[c]
            dist = np.linalg.norm(d, axis=1)
            inview = (d @ look[c]) / dist >= math.cos(HALF_FOV)
            idx = np.flatnonzero(inview & ~under)
            if not len(idx):
                continue
            dirs = qk[c] - centres[idx]
            dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
            hit = mesh.ray.intersects_any(centres[idx] + 1e-5 * dirs, dirs)
            near = centres[idx] + HAND_REACH * dirs
            free = ~hit & ~band_blocks(centres[idx], near, fist) & (seg_dist(centres[idx], near, a, b) > r)
            counts[k, idx[free]] += 1
    return counts


def tracked(counts, centres, sites):
    rec = counts[:, sites] >= 2
    n = rec.sum(1)
    c = centres[sites]
    out = np.zeros(len(rec), bool)
    need = (math.sqrt(2) / 3 * 0.015) ** 2
    for k in np.flatnonzero(n >= 3):
        p = c[rec[k]]
        ev = np.linalg.eigvalsh(np.cov((p - p.mean(0)).T, bias=True))
        out[k] = ev[0] + ev[1] >= need
    return out


def margin_shortfall(mesh, points, normals, base_r, error, sharp_deg=30.0):
    """Markers with less than ``error`` of room beyond the base radius to a face tilted more than
    ``sharp_deg`` from the marker's normal (not the far side of a thin wall) or a sharp edge:
    brute force over every face and edge."""
    tri = mesh.triangles
    fn = mesh.face_normals
    ang = mesh.face_adjacency_angles
    edges = mesh.vertices[mesh.face_adjacency_edges[ang > math.radians(sharp_deg)]]
    bad = 0
    rooms = []
    for p, n in zip(points, normals, strict=True):
        c = fn @ n
        cen = tri.mean(axis=1)
        tilted = (c < math.cos(math.radians(sharp_deg))) & ~((c < 0) & ((cen - p) @ n < 0))
        near = np.linalg.norm(cen - p, axis=1) < 0.05 + np.linalg.norm(tri - cen[:, None], axis=2).max(1)
        sel = np.flatnonzero(tilted & near)
        d = np.inf
        if len(sel):
            cp = trimesh.triangles.closest_point(tri[sel], np.repeat(p[None], len(sel), 0))
            d = float(np.linalg.norm(cp - p, axis=1).min())
        if len(edges):
            d = min(d, float(seg_dist(edges[:, 0], edges[:, 1], p, p).min()))
        rooms.append(d - base_r)
        bad += int(d - base_r < error - 1e-6)
    return bad, rooms


def _circle_fit(xy):
    """Centre (2,), radius and largest residual of the least-squares circle through points (k, 2)."""
    A = np.column_stack([xy, np.ones(len(xy))])
    a, b, c = np.linalg.lstsq(A, (xy**2).sum(axis=1), rcond=None)[0]
    centre = np.array([a / 2, b / 2])
    r = math.sqrt(max(c + centre @ centre, 0.0))
    return centre, r, float(np.abs(np.linalg.norm(xy - centre, axis=1) - r).max())


def _rod_section(mesh, origin, t, n, reach):
    """The points of the mesh's exact section by the plane through ``origin`` square to ``t``
    within ``reach`` of it, in the plane's (n, t x n) coordinates."""
    segs = trimesh.intersections.mesh_plane(mesh, t, origin)
    if not len(segs):
        return np.zeros((0, 2))
    q = segs.reshape(-1, 3)
    q = q[np.linalg.norm(q - origin, axis=1) <= reach]
    w = np.cross(t, n)
    return np.column_stack([(q - origin) @ n, (q - origin) @ w])


def _room_along(mesh, p, n, r, t, width, error, wall, tol):
    """The straight rod (m) beyond the ring's half-width on the shorter side, along ``t``."""
    origin = p - r * n
    axis = _circle_fit(_rod_section(mesh, origin, t, n, r + wall))[0]  # where the axis crosses
    if abs(math.hypot(r - axis[0], axis[1]) - r) > tol:  # the mark (at (r, 0) here) is off that circle
        return -np.inf
    reach = []
    for side in (1.0, -1.0):
        s = 0.0
        while s <= width / 2 + error + 0.006:
            xy = _rod_section(mesh, origin + side * s * t, t, n, r + wall)
            if len(xy) < 6:
                break
            c, rr, res = _circle_fit(xy)
            if abs(rr - r) > tol or res > tol or np.linalg.norm(c - axis) > tol:
                break
            s += 2.5e-4
        reach.append(s - 2.5e-4)
    return min(reach) - width / 2


def clamp_shortfall(mesh, points, normals, rods_mm, width, error, wall=0.003):
    """For markers on clamps: the room (m) along the rod beyond the ring's half-width, by exact
    plane sections.  The section through the marker's mark square to the rod's axis is the
    roundest circle of the stated diameter: the direction in the tangent plane (every degree)
    that makes it so, then every half degree within 10 degrees of it, is tried as the axis, and
    the one along which the rod stays straight longest is kept (a bent tube's roundest section
    need not be square to its centre line).  Along it, sections every 0.25 mm must stay that
    circle (the mark on it, its centre where the first one's is, radius within 3 %, every section
    point within the ring's wall of the rod on the circle: nothing else of the prop there).
    Independent of starforge's ray chords, fitted axis and sampled circles."""
    from starforge.geometry.frames import perpendicular_basis

    bad, rooms = 0, []
    for p, n, d in zip(points, normals, rods_mm, strict=True):
        r = d / 2000.0
        tol = max(1e-4, 0.03 * r)
        u, v = perpendicular_basis(n)

        def along(deg, u=u, v=v):
            return math.cos(math.radians(deg)) * u + math.sin(math.radians(deg)) * v

        best = None
        for deg in range(180):
            xy = _rod_section(mesh, p - r * n, along(deg), n, r + wall)
            if len(xy) < 6:
                continue
            _, rr, res = _circle_fit(xy)
            if best is None or res + abs(rr - r) < best[0]:
                best = (res + abs(rr - r), deg)
        room = -np.inf
        if best is not None:
            room = max(
                _room_along(mesh, p, n, r, along(best[1] + k / 2), width, error, wall, tol) for k in range(-20, 21)
            )
        rooms.append(room)
        bad += int(room < error - 1e-6)
    return bad, rooms


def write_docs(out: dict) -> None:
    """The figures of ``out`` as the results page's section on props no one on the project made."""
    from _results import table, write_section

    rows = [
        [name, f'{v["markers"]}' + (f' ({v["markers_on_clamps"]} on clamps)' if v.get("markers_on_clamps") else ""), v["usable_sites"], v["grips"], v["chosen_fresh_poses"], v["best_random_fresh_poses"],
         f'{v["best_flip_proof_random_fresh_poses"]} ({v["random_flip_proof"]})', v["every_site_fresh_poses"], v["optimizer_own_evaluation"], v["min_margin_mm"], v["guide_text_overlaps"], v["guide_label_clashes"], v["seconds"]]
        for name, v in out["props"].items()
    ]  # fmt: skip
    body = (
        "Eight props made from primitives (not the built-ins), each placed by `starforge place` at the default "
        "spec and seed 0, then checked by an evaluation that shares nothing with the optimizer but the mesh and "
        "the layout: its own ring of 8 cameras, uniform random rotations, 4 of the 8 cameras lost in each pose, "
        "and its own hand, a palm-long fist at a uniformly random place where a palm fits around the prop's "
        f"cross-sections (see the script's docstring).  Tracked: the share of {out['poses']} fresh poses with >= 3 "
        "markers reconstructed spanning a 15 mm triangle; best random: the best of 200 random layouts of as many "
        "markers on the same sites, picked on other poses and measured on these; flip-proof random: the best of "
        "those a tracker cannot flip (starforge's rule for its own layouts; how many of the 200 in brackets); "
        "every site: a marker on every usable site, the most any layout on these sites can track; "
        "own: starforge's own "
        "evaluation of its layout (its grips, its rig); margin: the least room, beyond the base, that any "
        "marker has to an edge or a surface tilted more than 30 degrees (brute force over the mesh).\n\n"
        + table(["prop", "markers", "usable sites", "grips", "tracked", "best random", "flip-proof random", "every site", "own", "margin (mm)",
                 "guide text overlaps", "guide label clashes", "seconds"], rows)
    )  # fmt: skip
    if out.get("standoff_mm"):
        body = (f"Every marker on a printed {out['standoff_mm']:g} mm post (`place --standoff "
                f"{out['standoff_mm']:g}`), in every layout compared; the evaluation's fist also holds a post that "
                "passes through it, and its marker is then lost.  Where a post's foot finds no seat on a rod 2-25 mm "
                "thick, it stands on a clamp round the rod; such a marker's margin is the straight rod beyond the "
                "ring, re-measured from exact plane sections of the mesh (`clamp_shortfall`).\n\n" + body)
        write_section("props-real-standoff", f"Props no one on the project made, markers on {out['standoff_mm']:g} mm posts", body)
    elif out.get("placed_for", "").startswith("this room"):
        body = ("Placed for the evaluation's room instead (`--room`): its cameras as a rig file, the volume "
                "grown by the prop's longest side, since the room keeps the mesh's origin anywhere in it.\n\n" + body)
        write_section("props-real-room", "Props no one on the project made, placed for the room", body)
    else:
        write_section("props-real", "Props no one on the project made", body)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--poses", type=int, default=POSES)
    ap.add_argument("--props", default="")
    ap.add_argument("--room", action="store_true",
                    help="place each prop for this room (its rig file, room_rig_toml) instead of starforge's default rig")
    ap.add_argument("--standoff", type=float, default=0.0,
                    help="place every marker on a printed post this long (mm, `place --standoff`); a post the fist holds loses its marker")
    ap.add_argument("--write-docs", action="store_true", help="also write the table into docs/results.md")
    args = ap.parse_args(argv)
    from _pdftext import glyph_boxes, off_page, overlapping_glyphs
    from _views import guide_view_report

    from starforge.props.distinct import own_triangles
    from starforge.props.placement import run_placement
    from starforge.render.guide import GUIDE_VIEWS, guide_files, guide_pages
    from starforge.render.prop_views import plot_data

    meshes = props()
    wanted = [p for p in args.props.split(",") if p] or list(meshes)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in wanted:
            path = Path(tmp) / f"{name}.stl"
            meshes[name].export(path)
            t0 = time.perf_counter()
            rig = {}
            if args.room:
                (Path(tmp) / f"{name}-room.toml").write_text(room_rig_toml(meshes[name]), encoding="utf-8")
                rig = {"rig": str(Path(tmp) / f"{name}-room.toml")}
            if args.standoff:
                rig["standoff_mm"] = args.standoff
            res = run_placement(str(path), seed=0, **rig)
            sec = time.perf_counter() - t0
            mesh = res.prop.mesh
            every = np.arange(len(res.sites))
            centres, normals = res.centres(every), res.sites.normals
            chosen = list(res.marker_sites)
            rng = np.random.default_rng(123)
            R, t = random_world(args.poses, rng)
            bases = res.sites.points if args.standoff else None
            counts = seen_table(mesh, centres, normals, R, t, random_hands(mesh, args.poses, rng), rng, bases)
            R2, t2 = random_world(args.poses, rng)
            counts2 = seen_table(mesh, centres, normals, R2, t2, random_hands(mesh, args.poses, rng), rng, bases)
            lay_rng = np.random.default_rng(7)
            best, best_f = None, -1.0
            tol_mm = res.spec.track.avoid_tolerance_mm
            proof, proof_f = [], -1.0  # the best random layout a tracker cannot flip (starforge's rule)
            flip_proof = 0
            for _ in range(RANDOM_LAYOUTS):
                order = lay_rng.permutation(len(every))
                lay = []
                for s in order:
                    if all(np.linalg.norm(centres[s] - centres[q]) >= res.spacing_m for q in lay):
                        lay.append(int(s))
                        if len(lay) == len(chosen):
                            break
                f = float(tracked(counts, centres, lay).mean())
                if f > best_f:
                    best, best_f = lay, f
                if own_triangles(1000.0 * centres[lay], tol_mm)[0] == 0:
                    flip_proof += 1
                    if f > proof_f:
                        proof, proof_f = lay, f
            err = res.spec.seat.placement_error_mm / 1000.0
            rods = res.marker_rods_mm
            foot = rods <= 0
            below, rooms = margin_shortfall(mesh, res.marker_points[foot], res.marker_normals[foot], res.seat.base_radius_m, err)
            below_c, rooms_c = clamp_shortfall(
                mesh, res.marker_points[~foot], res.marker_normals[~foot], rods[~foot], 2 * res.seat.base_radius_m, err
            )
            below, rooms = below + below_c, rooms + rooms_c
            folder = Path(tmp) / name
            folder.mkdir()
            guide_files(res, folder)
            data = plot_data(res)
            views = guide_view_report(guide_pages(data)[0], GUIDE_VIEWS, [n for n, _ in data.features])
            pages = glyph_boxes(folder / "guide.pdf")
            overlaps = sum(len(overlapping_glyphs([b for _, b in g])) for _, g in pages)
            off = sum(len(off_page(p)) for p in pages)
            rows[name] = {
                "faces": len(mesh.faces),
                "extents_mm": [round(1000 * e, 1) for e in mesh.extents],
                "grips": len(res.grips),
                "held_part": None if res.part is None else res.part.to_json(),
                "markers": len(chosen),
                "markers_on_clamps": int((~foot).sum()),
                "usable_sites": len(res.sites),
                "chosen_tracked": round(float(tracked(counts, centres, chosen).mean()), 4),
                "best_random_same_poses": round(best_f, 4),
                "chosen_fresh_poses": round(float(tracked(counts2, centres, chosen).mean()), 4),
                "best_random_fresh_poses": round(float(tracked(counts2, centres, best).mean()), 4),
                # a marker on every usable site: no layout on these sites tracks more of these poses
                "every_site_fresh_poses": round(float(tracked(counts2, centres, list(every)).mean()), 4),
                "random_flip_proof": flip_proof,
                "best_flip_proof_random_fresh_poses": round(float(tracked(counts2, centres, proof).mean()), 4) if proof else None,
                "optimizer_own_evaluation": round(res.evaluation.get("default", {}).get("tracked", float("nan")), 4),
                "markers_below_margin": below,
                "min_margin_mm": round(1000 * min(rooms), 2),
                "guide_text_overlaps": overlaps,
                "guide_glyphs_off_page": off,
                "guide_label_clashes": len(views["clashes"]),
                "guide_landmarks_unlabelled": len(views["unlabelled"]),
                "guide_pages": len(pages),
                "seconds": round(sec, 1),
            }
            print(name, rows[name], file=sys.stderr)
    vals = list(rows.values())
    out = {
        "evaluation": "own 8-camera ring, uniform random rotations, 4 of 8 cameras lost, a random-grip hand (see the docstring)",
        "placed_for": "this room (--room)" if args.room else "starforge's default rig",
        "standoff_mm": args.standoff,
        "poses": args.poses,
        "props": rows,
        "targets": {
            "tracked_at_least_0.99": all(v["chosen_tracked"] >= 0.99 for v in vals),
            # props that no layout on their usable sites takes to 0.99 of the fresh poses
            "unreachable_on_usable_sites": [n for n, v in rows.items() if v["every_site_fresh_poses"] < 0.99],
            "at_least_best_of_200_random_same_poses": all(v["chosen_tracked"] >= v["best_random_same_poses"] for v in vals),
            "at_least_best_of_200_random_fresh_poses": all(
                v["chosen_fresh_poses"] >= v["best_random_fresh_poses"] for v in vals
            ),
            "markers_below_margin": sum(v["markers_below_margin"] for v in vals),
            "guide_text_overlaps": sum(v["guide_text_overlaps"] for v in vals),
            "guide_glyphs_off_page": sum(v["guide_glyphs_off_page"] for v in vals),
            "guide_label_clashes": sum(v["guide_label_clashes"] for v in vals),
            "guide_landmarks_unlabelled": sum(v["guide_landmarks_unlabelled"] for v in vals),
        },
    }
    sys.stdout.write(json.dumps(out, indent=1) + "\n")
    if args.write_docs:
        write_docs(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
