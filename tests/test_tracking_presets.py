"""Vendor presets: the TOML numbers reach the checks, each violation is named, hand-built cases."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from starforge.errors import StarforgeError
from starforge.stars.spec import StarSpec
from starforge.tracking.presets import check_rules, load_preset, preset_names, star_spec_overrides

PRESETS = Path(__file__).parents[1] / "templates" / "presets"
# six distances 40, 47, ..., 75 mm (all over 30 mm, 7 mm apart): a good ART target, chiral
GOOD = np.array([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0], [41.35, 53.983122, 0.0], [-3.8, 59.743302, 11.717416]])


def rules_of(v, body=None):
    return {x.rule for x in v if body is None or x.body == body}


def test_all_four_presets_ship():
    assert set(preset_names()) >= {"art", "ndi", "qualisys", "optitrack"}


@pytest.mark.parametrize("name", ["art", "ndi", "qualisys", "optitrack"])
def test_star_spec_overrides_come_from_the_toml(name):
    data = tomllib.loads((PRESETS / f"{name}.toml").read_text())
    assert star_spec_overrides(name) == data["stars"]
    # the overrides make a valid spec on a box big enough for them
    StarSpec(box_mm=(90.0, 90.0, 90.0), **star_spec_overrides(name))


def test_art_published_numbers():
    p = load_preset("art")
    assert (p.rules.equal_mm, p.rules.min_markers, p.rules.min_distance_mm, p.rules.distinct_mm) == (
        2.0,
        4,
        30.0,
        5.0,
    )
    assert star_spec_overrides("art") == {"delta_mm": 5.0, "tolerance_mm": 5.0, "l_min_mm": 31.0}


def test_unknown_preset_lists_known():
    with pytest.raises(StarforgeError, match=r"known \(starforge templates presets\): art, atracsys, ndi, optitrack, qualisys, vicon"):
        load_preset("vicon-magic")


def test_good_body_passes_every_preset():
    d = np.linalg.norm(GOOD[:, None] - GOOD[None], axis=2)[np.triu_indices(4, 1)]
    assert d.min() > 30 and np.diff(np.sort(d)).min() >= 5  # the ART numbers, checked by hand
    for name in ("art", "ndi", "qualisys", "optitrack"):
        assert check_rules(["good"], [GOOD], load_preset(name)) == []


def test_named_single_body_violations():
    art = load_preset("art")
    three = GOOD[:3]
    assert "too_few_markers" in rules_of(check_rules(["t"], [three], art))
    small = GOOD * 0.3  # smallest distance under 30 mm
    assert "min_distance" in rules_of(check_rules(["s"], [small], art))
    line = np.array([[0.0, 0, 0], [40, 0, 0], [95, 0, 0], [170, 0.2, 0]])
    assert "collinear" in rules_of(check_rules(["l"], [line], load_preset("qualisys")))
    seven = np.vstack([GOOD, GOOD[:3] + [200.0, 13.0, 7.0]])
    assert "too_many_markers" in rules_of(check_rules(["7"], [seven], load_preset("ndi")))
    square = np.array([[0.0, 0, 0], [50, 0, 0], [50, 50, 0], [0, 50, 0]])
    v = rules_of(check_rules(["sq"], [square], load_preset("optitrack")))
    assert {"symmetric", "equal_distances"} <= v


def test_mirror_images_collide_for_ndi_only():
    mirror = GOOD * np.array([-1.0, 1.0, 1.0])
    # same distances, but no proper rotation maps one onto the other (a chiral body)
    d = lambda P: np.linalg.norm(P[:, None] - P[None], axis=2)  # noqa: E731
    assert np.allclose(d(GOOD), d(mirror))
    ndi = check_rules(["a", "b"], [GOOD, mirror], load_preset("ndi"))
    assert "mirror_images" in rules_of(ndi, "a / b")
    qtm = check_rules(["a", "b"], [GOOD, mirror], load_preset("qualisys"))
    assert not ({"mirror_images", "congruent"} & rules_of(qtm))


def test_congruent_and_shared_triangles_between_bodies():
    moved = GOOD @ np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]).T + [300.0, 0, 0]
    v = check_rules(["a", "b"], [GOOD, moved], load_preset("optitrack"))
    assert "congruent" in rules_of(v, "a / b")
    other = GOOD.copy()
    other[3] = [20.0, 25.0, -50.0]
    v = check_rules(["a", "c"], [GOOD, other], load_preset("optitrack"))
    assert "shared_triangle" in rules_of(v, "a / c")
    assert "congruent" not in rules_of(v)
