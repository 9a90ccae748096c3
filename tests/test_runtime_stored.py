"""Values kept in the cache folder by content (starforge.runtime.stored): keys that change with
every input, values read back equal to what was computed, and a placement that is the same with
an empty cache folder as with one its earlier run filled."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from starforge.runtime import stored as st


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("STARFORGE_CACHE_DIR", str(folder))
    return folder


@dataclass(frozen=True)
class _Pair:
    a: float
    b: tuple


def test_the_key_changes_with_every_part_of_the_content():
    x = np.arange(12, dtype=np.int64)
    key = st.content_key(x, _Pair(1.0, ("q", 2)), {"k": None})
    assert key == st.content_key(x.copy(), _Pair(1.0, ("q", 2)), {"k": None})  # by value, not identity
    others = [
        st.content_key(np.where(x == 5, 6, x), _Pair(1.0, ("q", 2)), {"k": None}),  # one element
        st.content_key(x.view(np.float64), _Pair(1.0, ("q", 2)), {"k": None}),  # same bytes, other dtype
        st.content_key(x.reshape(3, 4), _Pair(1.0, ("q", 2)), {"k": None}),  # same bytes, other shape
        st.content_key(x, _Pair(1.0 + 2**-52, ("q", 2)), {"k": None}),  # the last bit of a float
        st.content_key(x, _Pair(1.0, ["q", 2]), {"k": None}),  # a list is not a tuple
        st.content_key(x, _Pair(1.0, ("q", 2)), {"k": 0}),
        st.content_key(x, _Pair(1.0, ("q", 2))),
    ]
    assert len({key, *others}) == len(others) + 1


def test_a_part_without_a_content_key_is_refused():
    with pytest.raises(TypeError, match="no content key"):
        st.content_key(object())


def test_a_value_is_computed_once_and_read_back_equal(cache):
    calls = []

    def compute():
        calls.append(1)
        return {"masks": np.arange(5, dtype=np.uint64) << np.uint64(60), "n": 3}

    key = st.content_key("t", 1)
    first, kept_first = st.stored("kind", key, compute)
    again, kept_again = st.stored("kind", key, compute)
    assert (kept_first, kept_again, len(calls)) == (False, True, 1)
    assert np.array_equal(first["masks"], again["masks"]) and again["masks"].dtype == np.uint64
    assert again["n"] == 3
    other, kept_other = st.stored("kind", st.content_key("t", 2), compute)
    assert not kept_other and len(calls) == 2


def test_a_damaged_entry_is_computed_again_and_an_unwritable_folder_only_computes(cache, tmp_path, monkeypatch):
    key = st.content_key("damaged")
    st.stored("kind", key, lambda: [1, 2, 3])
    (entry,) = (cache / "stored" / "kind").glob("*.pkl")
    entry.write_bytes(entry.read_bytes()[:5])
    assert st.stored("kind", key, lambda: [1, 2, 3]) == ([1, 2, 3], False)
    assert st.stored("kind", key, lambda: [9]) == ([1, 2, 3], True)  # written again whole
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("STARFORGE_CACHE_DIR", str(blocker))
    assert st.stored("kind", key, lambda: [4]) == ([4], False)
    assert st.stored("kind", key, lambda: [5]) == ([5], False)


def test_old_entries_beyond_the_limit_are_removed(cache, monkeypatch):
    monkeypatch.setattr(st, "KEEP_PER_KIND", 3)
    for i in range(5):
        st.stored("kind", st.content_key("many", i), lambda i=i: i)
    assert len(list((cache / "stored" / "kind").glob("*.pkl"))) == 3


def test_a_prepared_placement_read_back_is_the_one_computed(cache, monkeypatch):
    """prepare() on an empty cache folder, then again with its work disabled: the same sites,
    seats, grips and table, and the generator left in the same state."""
    from starforge.props import prepare as pr
    from starforge.props.mesh import load_prop
    from starforge.props.spec import load_spec, with_overrides

    prop = load_prop("box")
    spec = with_overrides(load_spec("default"), sites=150, resolution=1, orientations=6)
    rng = np.random.default_rng(4)
    computed = pr.prepare(prop, spec, rng, seed=4)
    after = rng.random(4)
    assert computed.key

    def fail(*a, **k):
        raise AssertionError("computed again")

    monkeypatch.setattr(pr, "_prepare", fail)
    rng = np.random.default_rng(4)
    read = pr.prepare(prop, spec, rng, seed=4)
    assert np.array_equal(rng.random(4), after)
    assert read.key == computed.key and read.removed == computed.removed
    for a, b in [
        (read.sites.points, computed.sites.points),
        (read.sites.normals, computed.sites.normals),
        (read.table.masks, computed.table.masks),
        (read.seat_report.margin_m, computed.seat_report.margin_m),
        (read.poses.rotations, computed.poses.rotations),
        (read.pose_grip, computed.pose_grip),
    ]:
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert [g.capsules for g in read.grips] == [g.capsules for g in computed.grips]
    with pytest.raises(AssertionError, match="computed again"):  # another seed is not read back
        pr.prepare(prop, spec, np.random.default_rng(5), seed=5)


@pytest.mark.slow
def test_a_placement_is_the_same_from_an_empty_and_a_filled_cache(cache, tmp_path):
    from starforge.api.place import place_markers, write_placement

    def files(folder):
        res = place_markers("box", sites=150, resolution=1, orientations=6, seed=2)
        write_placement(res, folder, pictures=False)
        doc = json.loads((folder / "placement.json").read_text())
        doc.pop("timings")
        return doc, {p.name: p.read_bytes() for p in folder.iterdir() if p.name != "placement.json"}

    empty = files(tmp_path / "empty")
    assert len(list((cache / "stored").rglob("*.pkl"))) >= 2  # the preparation and held-out tables
    filled = files(tmp_path / "filled")
    assert empty == filled
