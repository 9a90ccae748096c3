"""The STEP files hold the geometry the body describes, re-checked independently: each written
file is read back with build123d, and its volume and bounding box are compared with closed forms
(sphere, cylinder, box, Pappus's theorem for a solid of revolution) and with bounds sampled
from the primitives' rims, not with the primitives' own ``volume()`` / ``bounds()``."""

from __future__ import annotations

from pathlib import Path

import build123d as bd
import numpy as np
import pytest

from starforge.cad.body import BodySpec, body_bounds, build_body
from starforge.cad.brep import assembly, body_solid, placed, primitive_solid, read_step, write_step
from starforge.cad.mounts import load_mount
from starforge.cad.plate import layout_plates, print_transform
from starforge.cad.primitives import Box, Cylinder, Revolved, Sphere, fillet_profile
from starforge.stars.model import load_family

DATA = Path(__file__).parent / "data" / "cad" / "small_family.json"
BBOX_MM = 1e-3  # what a re-read bounding box may differ by (OCCT's tolerances on the edges)


def _bbox(shape) -> np.ndarray:
    """(2, 3) bounding box of a build123d shape, mm."""
    b = shape.bounding_box()
    return np.array([[b.min.X, b.min.Y, b.min.Z], [b.max.X, b.max.Y, b.max.Z]])


def _rim_bounds(p0, p1, radii_at) -> np.ndarray:
    """Bounds of circles about the axis p0 -> p1, sampled densely: ``radii_at`` is a list of
    (t along the axis, mm; radius, mm)."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    a = np.cross(u, [1.0, 0, 0] if abs(u[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    phi = np.linspace(0, 2 * np.pi, 20_000)
    pts = np.concatenate(
        [p0 + t * u + r * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b) for t, r in radii_at]
    )
    return np.array([pts.min(0), pts.max(0)])


def _pappus_volume(profile) -> float:
    """Volume of the region between the axis and a (t, r) polyline turned about the axis:
    2 pi x (centroid's distance from the axis) x (area), from the closed polygon's shoelace sums."""
    pr = np.array(profile, float)
    poly = np.vstack([[pr[0, 0], 0.0], pr, [pr[-1, 0], 0.0]])
    t, r = poly[:, 0], poly[:, 1]
    cross = t * np.roll(r, -1) - np.roll(t, -1) * r
    area = cross.sum() / 2
    r_bar = ((r + np.roll(r, -1)) * cross).sum() / (6 * area)
    return abs(2 * np.pi * r_bar * area)


def _round_trip(shape, path: Path):
    write_step(shape, path)
    back = read_step(path)
    assert len(back) == 1 and back[0].is_valid
    return back[0]


PRIMITIVES = {
    "sphere": (Sphere((1.0, -2.0, 3.5), 1.9), lambda p: 4 / 3 * np.pi * p.radius_mm**3),
    "tilted cylinder": (
        Cylinder((0.5, 0.0, -1.0), (2.0, 7.0, 1.5), 0.9),
        lambda p: np.pi * p.radius_mm**2 * np.linalg.norm(np.subtract(p.p1, p.p0)),
    ),
    "box": (Box((3.0, -1.0, 2.0), (10.0, 2.5, 7.0)), lambda p: 10.0 * 2.5 * 7.0),
    "fillet": (
        Revolved((0.0, -0.3, 0.0), (0.0, 1.2, 0.0), fillet_profile(0.9, 0.45, 0.3, inset_mm=0.05)),
        lambda p: _pappus_volume(p.profile),
    ),
    "tilted seat block": (
        Revolved((1.0, 2.0, 0.5), (1.8, 6.0, 1.2), ((0.0, 0.6), (1.5, 2.0), (3.0, 2.0))),
        lambda p: _pappus_volume(p.profile),
    ),
}


@pytest.mark.parametrize("name", list(PRIMITIVES))
def test_each_primitive_reads_back_with_its_closed_form_volume_and_bounds(name, tmp_path):
    p, volume = PRIMITIVES[name]
    solid = primitive_solid(p)
    solid.label = name.replace(" ", "_")  # a body's name: star_001
    back = _round_trip(solid, tmp_path / "p.step")
    assert bd.import_step(str(tmp_path / "p.step")).label == solid.label  # the STEP product's name
    assert back.volume == pytest.approx(volume(p), rel=1e-9)
    if isinstance(p, Sphere):
        want = np.array([np.subtract(p.centre, p.radius_mm), np.add(p.centre, p.radius_mm)])
    elif isinstance(p, Box):
        want = np.array([np.subtract(p.centre, np.divide(p.size, 2)), np.add(p.centre, np.divide(p.size, 2))])
    elif isinstance(p, Cylinder):
        want = _rim_bounds(p.p0, p.p1, [(0.0, p.radius_mm), (p.length_mm, p.radius_mm)])
    else:
        want = _rim_bounds(p.p0, p.p1, p.profile)
    assert np.abs(_bbox(back) - want).max() < BBOX_MM


@pytest.fixture(scope="module")
def bodies():
    fam = load_family(DATA)
    return [build_body(s.id, s.vertices, 4.0, load_mount("flat"), BodySpec()) for s in fam.stars[:2]]


def test_a_body_file_lies_where_its_printing_transform_puts_the_described_body(bodies, tmp_path):
    """The re-read solid's box is the union of the added primitives' rims (cuts stay inside the
    plate), moved by the printing transform: plate down on Z = 0, centred on the Z axis."""
    for b in bodies:
        T = print_transform(body_bounds(b, finished=True))
        back = _round_trip(placed(body_solid(b), T, b.name, (10, 20, 30)), tmp_path / f"{b.name}.step")
        lo, hi = body_bounds(b, finished=False)
        corners = np.array(
            [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
        )
        q = corners @ T[:3, :3].T + T[:3, 3]
        assert np.abs(_bbox(back) - [q.min(0), q.max(0)]).max() < BBOX_MM
        assert _bbox(back)[0, 2] == pytest.approx(0.0, abs=BBOX_MM)
        assert back.volume == pytest.approx(body_solid(b).volume, rel=1e-9)  # a rigid move


def test_a_plate_file_holds_each_body_moved_by_its_bed_translation(bodies, tmp_path):
    singles = []
    for b in bodies:
        T = print_transform(body_bounds(b, finished=True))
        singles.append(placed(body_solid(b), T, b.name, (200, 100, 0)))
    boxes = [_round_trip(s, tmp_path / f"{s.label}.step") for s in singles]
    (lay,) = layout_plates([_bbox(x) for x in boxes], (200.0, 200.0), 5.0)
    write_step(assembly([singles[i] for i in lay.members], lay.transforms, "plate"), tmp_path / "plate.step")
    plate = bd.import_step(str(tmp_path / "plate.step"))
    got = {c.label: c for c in plate.children}
    assert sorted(got) == sorted(b.name for b in bodies)
    for i, T in zip(lay.members, lay.transforms, strict=True):
        child = got[bodies[i].name]
        assert child.color is not None
        assert np.abs(_bbox(child) - (_bbox(boxes[i]) + T[:3, 3])).max() < BBOX_MM
        assert child.volume == pytest.approx(boxes[i].volume, rel=1e-9)
        # the footprint the layout reserved holds the body: gap_mm clear of the bed's edge
        fp = lay.footprints[list(lay.members).index(i)]
        assert (_bbox(child)[0, :2] >= fp[:2] - BBOX_MM).all() and (
            _bbox(child)[1, :2] <= fp[2:] + BBOX_MM
        ).all()
