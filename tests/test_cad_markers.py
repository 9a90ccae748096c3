"""The marker catalogue (templates/markers) and its resolver: every entry cites a source and
says whether its base geometry is published or starforge's default; names and numbers resolve
to diameters; bad input is one clear error naming the catalogue or the range."""

from __future__ import annotations

import math

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.markers import THREADS, load_marker, marker_diameter_mm, marker_names


def test_the_catalogue_holds_the_sizes_labs_buy_each_with_a_source():
    names = marker_names()
    sizes = sorted(load_marker(n).diameter_mm for n in names)
    for d in (4.0, 6.4, 9.5, 12.7, 14.0):
        assert d in sizes
    kinds = {load_marker(n).attach for n in names}
    assert kinds == {"glue", "post", "screw", "insert"}  # flat base, press fit, bore, heat-set insert
    for n in names:
        m = load_marker(n)
        assert len(m.source) > 40
        # a cited page, or an explicit statement that the numbers are starforge's own
        assert "http" in m.source or "starforge's default" in m.source
        assert m.dimensions in ("vendor", "default")
        if m.dimensions == "default":
            assert "starforge's default" in m.source
        if m.thread is not None:
            assert m.thread in THREADS


@pytest.mark.parametrize(
    ("text", "mm"),
    [("12.7", 12.7), (9.5, 9.5), ("4mm", 4.0), (" 6.4 ", 6.4), ("14mm-m4", 14.0), ("4mm-flat", 4.0)],
)
def test_resolver_takes_numbers_and_names(text, mm):
    assert marker_diameter_mm(text) == pytest.approx(mm)


def test_resolver_agrees_with_every_entry():
    for n in marker_names():
        assert marker_diameter_mm(n) == load_marker(n).diameter_mm


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("bogus", "marker must be a catalogue marker or a TOML file, got 'bogus'; known .*: 12.7mm-m3, 14mm-m4, 4mm-flat, 6.4mm-post, 9.5mm-m3"),
        ("nan", r"must be in \[1, 50\] mm"),
        ("0.2", r"must be in \[1, 50\] mm"),
        ("1e9", r"must be in \[1, 50\] mm"),
        (True, "a diameter in mm or a catalogue name"),
        ("missing/marker.toml", "not found"),
    ],
)
def test_resolver_refuses_with_one_clear_line(text, message):
    with pytest.raises(StarforgeError, match=message):
        marker_diameter_mm(text)


def test_a_measured_marker_file_overrides_the_defaults(tmp_path):
    p = tmp_path / "mine.toml"
    p.write_text(
        'diameter_mm = 7.9\nattach = "post"\nhole_mm = 2.2\nhole_depth_mm = 3.5\nbase_mm = 5\n'
        'centre_height_mm = 4.1\nsource = "measured with calipers, lab notebook p. 12"\ndimensions = "vendor"\n'
    )
    assert marker_diameter_mm(str(p)) == 7.9
    m = load_marker(p)
    assert m.hole_mm == 2.2 and m.name == "mine"
    p.write_text('diameter_mm = 7.9\nattach = "post"\nsource = "x"\n')
    with pytest.raises(StarforgeError, match="a post needs hole_mm and hole_depth_mm"):
        load_marker(p)


def test_post_pin_is_shorter_than_the_hole_so_the_marker_seats_on_the_shoulder():
    from starforge.cad.body import BodySpec, build_body
    from starforge.cad.mounts import load_mount
    from starforge.cad.primitives import Cylinder
    from starforge.markers import POST_PLAY_MM

    mt = load_marker("6.4mm-post")
    d = mt.diameter_mm
    c = np.array([[0, 0, 0], [4.0 * d, 0.5 * d, 0], [0, 0.3 * d, 4.5 * d], [4.2 * d, 0.9 * d, 4.0 * d]])
    b = build_body(1, c, d, load_mount("flat", {"holes": 0}), BodySpec(marker="6.4mm-post", label=False))
    pins = [p for p in b.add if isinstance(p, Cylinder) and math.isclose(2 * p.radius_mm, mt.hole_mm - mt.fit_mm)]
    assert len(pins) == 4
    for pin, centre in zip(pins, c, strict=True):
        u = (np.array(pin.p1) - np.array(pin.p0)) / pin.length_mm
        seat = centre - mt.centre_height_mm * u
        reach = float((np.array(pin.p1) - seat) @ u)  # how far the pin enters the marker's hole
        assert reach == pytest.approx(mt.hole_depth_mm - POST_PLAY_MM)
        assert reach < mt.hole_depth_mm
