"""The streamed selection for specs whose candidates do not fit in memory: the same family as the
in-memory greedy, star for star, whatever order the chunks arrive in; the path is chosen and
bounded before any work; what it cannot do is refused in one line."""

from __future__ import annotations

from collections import namedtuple

import numpy as np
import pytest

from starforge.catalog import load_template
from starforge.errors import StarforgeError
from starforge.stars import enumerate as E
from starforge.stars import estimate
from starforge.stars import sizing as Z
from starforge.stars import stream as S
from starforge.stars.bounds import block_bound
from starforge.stars.family import make_family
from starforge.stars.rules import internal_ok, key_triples, window_rows
from starforge.stars.select import compactness_order, csr_rows, greedy
from starforge.stars.spec import StarSpec, spec_from_mapping

SPEC = StarSpec(box_mm=(16, 12, 24), delta_mm=1.0, select="greedy")  # 133k candidates
_RUN_CHUNKS = E.run_chunks
_CHUNKS: dict[str, list] = {}


def _replay(spec, consume, *args, **kw):
    """run_chunks from a memo: each enumeration runs once per module (the chunk results depend on
    the pool, tolerance and limit, not on the rule or the selection)."""
    from dataclasses import replace

    key = repr(replace(spec, rule="face", select="max", count=None))
    if key not in _CHUNKS:
        got: list = []
        _CHUNKS[key] = [got, _RUN_CHUNKS(spec, lambda i, r: got.append((i, r)), *args, **kw)]
    got, n = _CHUNKS[key]
    for i, r in got:
        consume(i, r)
    return n


@pytest.fixture(autouse=True)
def replay(monkeypatch):
    monkeypatch.setattr(E, "run_chunks", _replay)


@pytest.fixture(scope="module")
def cands():
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(E, "run_chunks", _replay)
        return E.enumerate_candidates(SPEC)


def _in_memory_greedy(cands, rule, m):
    """The in-memory path's greedy family (pool indices, lexicographic) and block bound."""
    ok = internal_ok(cands.index, rule, m)
    index, volume = cands.index[ok], cands.box_volume[ok]
    star_of, row, n_rows = window_rows(index, rule, m, len(cands.pool_mm))
    ptr, rows = csr_rows(star_of, row, len(index))
    chosen = index[greedy(compactness_order(index, cands.pool_mm, volume), ptr, rows, n_rows)]
    und = cands.undecided[internal_ok(cands.undecided, rule, m)]
    bound = block_bound(np.concatenate([index, und]), m)
    return chosen[np.lexsort(chosen.T[::-1])], bound, len(index), len(und)


def _assert_family(got, cands, rule, m):
    want, bound, n, n_und = _in_memory_greedy(cands, rule, m)
    assert got["index"].tobytes() == want.astype(np.int16).tobytes()
    assert got["bound"] == bound and got["candidates"] == n and got["undecided"] == n_und
    stats = {k: v for k, v in cands.stats.items() if k != "seconds"}
    assert got["stats"] == stats
    # independent check: no two family keys of one type within m - 1 steps in every side
    keys = key_triples(got["index"], rule)
    for t in (slice(0, 4), slice(4, 8)):
        k = keys[:, t].reshape(-1, 3).astype(int)
        if len(k):
            d = np.abs(k[:, None] - k[None]).max(axis=2)
            assert (d + np.eye(len(k), dtype=int) * m >= m).all()


@pytest.mark.parametrize("rule,tol", [("face", 1.0), ("pair", 1.0), ("face", 2.0), ("pair", 2.0)])
def test_streamed_greedy_is_the_in_memory_greedy(cands, monkeypatch, rule, tol):
    from dataclasses import replace

    spec = replace(SPEC, rule=rule, tolerance_mm=tol)
    m = spec.grid_steps
    c = cands if m == 1 else E.enumerate_candidates(spec)
    # few volume ranges and a small sorting cap: ranges are split by volume again, recursively
    monkeypatch.setattr(S, "BUCKETS", 5)
    monkeypatch.setattr(S, "range_cap", lambda held=0.0: 3000)
    _assert_family(S.stream_family(spec), c, rule, m)


@pytest.mark.slow
def test_streamed_family_does_not_depend_on_the_completion_order(cands, monkeypatch):
    def backwards(spec, consume, *args, **kw):  # every chunk first collected, then fed in reverse
        got = []
        n = _replay(spec, lambda i, r: got.append((i, r)), *args, **kw)
        for i, r in reversed(got):
            consume(i, r)
        return n

    a = S.stream_family(SPEC)
    monkeypatch.setattr(E, "run_chunks", backwards)
    b = S.stream_family(SPEC)
    assert a["index"].tobytes() == b["index"].tobytes() and a["bound"] == b["bound"]
    _assert_family(b, cands, "face", 1)


@pytest.mark.slow
def test_make_family_streamed_equals_in_memory(monkeypatch):
    a = make_family(SPEC)
    monkeypatch.setattr(estimate, "check_size", lambda spec, allow_stream=False: "stream")
    b = make_family(SPEC)
    assert [s.to_json() for s in a.stars] == [s.to_json() for s in b.stars]
    assert b.summary["upper_bound"] == a.summary["upper_bound"]
    assert b.summary["enumeration"] == a.summary["enumeration"]
    assert "streamed" in b.summary["selection"]
    m = make_family(StarSpec(box_mm=(16, 12, 24), delta_mm=1.0))  # select = "max": says what it skipped
    assert "max_skipped" in m.summary["selection"] and len(m) == len(a)
    with pytest.raises(StarforgeError, match="--count needs every candidate in memory"):
        make_family(StarSpec(box_mm=(16, 12, 24), delta_mm=1.0, count=5))


@pytest.fixture(scope="module")
def half():
    _, data = load_template("stars", "finger")
    data = {k: v for k, v in data.items() if k != "tolerance_mm"}  # faces apart by the pool step
    return spec_from_mapping({**data, "delta_mm": 0.5})


def test_finger_at_half_a_millimetre_is_streamed_and_bounded(half, monkeypatch):
    monkeypatch.setenv("STARFORGE_MAX_SECONDS", "1e6")
    monkeypatch.delenv("STARFORGE_MAX_MEMORY", raising=False)
    assert E.check_size(half, allow_stream=True) == "stream"
    with pytest.raises(StarforgeError, match="memory"):  # gathered in memory it is refused
        E.check_size(half)
    # the streamed path's own memory estimate is refused in one line past the limit
    monkeypatch.setenv("STARFORGE_MAX_MEMORY", "300M")
    with pytest.raises(StarforgeError, match=r"^the streamed selection among about .* memory") as err:
        E.check_size(half, allow_stream=True)
    assert "\n" not in str(err.value)
    # and so is a spill folder without room for it
    monkeypatch.delenv("STARFORGE_MAX_MEMORY")
    Usage = namedtuple("Usage", "total used free")
    monkeypatch.setattr(Z.shutil, "disk_usage", lambda p: Usage(10**9, 10**9 - 10**6, 10**6))
    with pytest.raises(StarforgeError, match=r"spills about .* set STARFORGE_SPILL_DIR") as err:
        E.check_size(half, allow_stream=True)
    assert "\n" not in str(err.value)
    assert Z.stream_bytes(half, 280e6) < 4 * 2**30  # the estimate behind the run in the README


def test_ordered_is_the_compactness_order(cands):
    rng = np.random.default_rng(0)
    idx, vol, pool = cands.index, cands.box_volume.copy(), cands.pool_mm
    want = compactness_order(idx, pool, vol)
    assert np.array_equal(S.ordered(idx, pool, vol), want)
    # many ties in the rounded volume: the full key decides among them
    vol = np.round(rng.integers(0, 50, len(idx)) * 1.25 + rng.random(len(idx)) * 1e-11, 12)
    assert np.array_equal(S.ordered(idx, pool, vol), compactness_order(idx, pool, vol))


@pytest.mark.slow
def test_the_spill_folder_is_removed_after_success_and_failure(tmp_path, monkeypatch):
    monkeypatch.setenv("STARFORGE_SPILL_DIR", str(tmp_path))
    seen = []
    add = S._Spill.add

    def spy(self, *a):
        seen.append(sorted(p.name for p in tmp_path.iterdir()))
        return add(self, *a)

    monkeypatch.setattr(S._Spill, "add", spy)
    S.stream_family(SPEC)
    assert seen and seen[0][0].startswith("starforge-spill-") and not list(tmp_path.iterdir())

    def boom(self, *a):
        raise RuntimeError("disk gone")

    monkeypatch.setattr(S._Spill, "add", boom)
    with pytest.raises(RuntimeError, match="disk gone"):
        S.stream_family(SPEC)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("rule", ["face", "pair"])
@pytest.mark.parametrize("m", [1, 2, 3])
def test_greedy_windows_is_the_brute_force_greedy(rule, m):
    """The window kernel (the streamed greedy's, and the sweep's sampled cells') keeps exactly the
    stars a plain greedy keeps: none of its keys within m - 1 pool steps, in every side, of a key
    of the same type (face or vertex) of a star kept before it."""
    rng = np.random.default_rng(7 + m)
    p = 24
    idx = np.array([rng.choice(p, 6, replace=False) for _ in range(1500)], dtype=np.int64)
    order = rng.permutation(len(idx)).astype(np.int64)
    keys = key_triples(idx, rule)
    want, face_kept, vert_kept = [], np.zeros((0, 3), np.int64), np.zeros((0, 3), np.int64)
    for i in order:
        f, v = keys[i, :4], keys[i, 4:]
        hit = lambda ks, kept: len(kept) and (np.abs(ks[:, None] - kept[None]).max(axis=2) <= m - 1).any()  # noqa: E731
        if hit(f, face_kept) or (rule == "pair" and hit(v, vert_kept)):
            continue
        want.append(i)
        face_kept = np.vstack([face_kept, f])
        if rule == "pair":
            vert_kept = np.vstack([vert_kept, v])
    keep = S.window_greedy(rule, p, m)
    half = len(order) // 2  # in two pieces: the used windows carry over
    got = np.concatenate([order[:half][keep(idx, order[:half])], order[half:][keep(idx, order[half:])]])
    assert 0 < len(want) < len(idx)
    assert got.tolist() == want
