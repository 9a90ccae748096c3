"""Selection for specs whose candidates do not fit in memory: the greedy, streamed.

At ``delta_mm = 0.5`` on the finger box the enumeration finds over 300 M fitting stars:
gathered with their key windows (:func:`starforge.stars.rules.window_rows`) they would need
tens of GB.  What the paper's greedy needs is much less: the stars in compactness order, one
after another, and which key windows are used so far.  So:

1. each enumeration chunk's result (:func:`starforge.stars.enumerate.enumerate_chunk`: pool
   indices 1 byte each, box volumes) is consumed as it arrives: stars filtered as the in-memory
   path filters them (:func:`~starforge.stars.rules.internal_ok`, the avoided faces), their face
   keys marked in a bitmap over pool triples (for the certified bound), and the stars appended to
   spill files on disk, one per range of box volume (:data:`BUCKETS` equal ranges);
2. the ranges are read back in order, each sorted in compactness order
   (:func:`ordered`, the permutation of :func:`starforge.stars.select.compactness_order`; its
   first key is the rounded volume, so the ranges concatenate to the global order) and run through the greedy with a bitmap of used key
   windows (:func:`greedy_windows`); a range too large for memory is split by volume again.

The family is the one the in-memory greedy gives on the same candidates, star for star
(``tests/test_stars_stream.py`` checks it), whatever order the chunks finished in.  The upper
bound is the same block bound, over the same distinct face keys.  The larger ``select = "max"``
steps (local search, iterated local search, exact solver) need every candidate in memory: here
they are skipped, and the family's summary says so.

Memory: the two bitmaps (a few MB), the spill buffers (:data:`SPILL_BUFFER_BYTES`), one volume
range being sorted, and the chunks in flight.  Disk: 14 bytes per fitting star (pool indices and
float64 volume), in a temporary folder removed afterwards.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from starforge.geometry.tetra import FACE_EDGES
from starforge.runtime.kernels import numba
from starforge.stars.rules import VERTEX_EDGES, internal_ok, key3, key_triples
from starforge.stars.sizing import (
    BUCKETS,
    SORT_BYTES_PER_STAR,
    SPILL_BUFFER_BYTES,
    STREAM_BASE_BYTES,
    bitmap_sizes,
    spill_dir,
)
from starforge.stars.spec import StarSpec


def _volume_max(spec: StarSpec) -> float:
    """Every fitting box lies inside the limit, so its volume is at most the limit's, mm^3."""
    return float(np.prod(np.asarray(spec.centre_limit_mm, dtype=float)))


def _bucket_of(volume: np.ndarray, vmax: float) -> np.ndarray:
    """Volume range of each star: monotone in the rounded volume the compactness order sorts by."""
    v = np.round(volume, 9)
    return np.clip((v * (BUCKETS / vmax)).astype(np.int64), 0, BUCKETS - 1)


def _face_codes(index: np.ndarray, p: int) -> np.ndarray:
    f = key_triples(index, "face")[:, :4].reshape(-1, 3).astype(np.int64)
    return (f[:, 0] * p + f[:, 1]) * p + f[:, 2]


class _Spill:
    """Stars appended to one pair of files per volume range (indices, float64 volumes)."""

    def __init__(self, folder: Path, dtype):
        self.folder, self.dtype = folder, dtype
        self.buf: dict[int, list] = {}
        self.held = 0
        self.rows = np.zeros(BUCKETS, dtype=np.int64)

    def add(self, bucket: np.ndarray, index: np.ndarray, volume: np.ndarray) -> None:
        if not len(bucket):
            return
        order = np.argsort(bucket, kind="stable")
        b, index, volume = bucket[order], index[order], volume[order]
        cuts = np.flatnonzero(np.diff(b)) + 1
        for lo, hi in zip(np.concatenate([[0], cuts]).tolist(), np.concatenate([cuts, [len(b)]]).tolist(), strict=True):
            k = int(b[lo])
            self.buf.setdefault(k, []).append((index[lo:hi].copy(), volume[lo:hi].copy()))
            self.rows[k] += hi - lo
        self.held += index.nbytes + volume.nbytes
        if self.held >= SPILL_BUFFER_BYTES:
            self.flush()

    def flush(self) -> None:
        for k, parts in self.buf.items():
            with open(self.folder / f"{k:05d}.idx", "ab") as f:
                for idx, _ in parts:
                    f.write(np.ascontiguousarray(idx, dtype=self.dtype).tobytes())
            with open(self.folder / f"{k:05d}.vol", "ab") as f:
                for _, vol in parts:
                    f.write(np.ascontiguousarray(vol, dtype=np.float64).tobytes())
        self.buf.clear()
        self.held = 0

    def load(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        n = int(self.rows[k])
        if not n:
            return np.zeros((0, 6), self.dtype), np.zeros(0)
        idx = np.fromfile(self.folder / f"{k:05d}.idx", dtype=self.dtype).reshape(n, 6)
        vol = np.fromfile(self.folder / f"{k:05d}.vol", dtype=np.float64)
        return idx, vol


@numba.njit(cache=True)
def greedy_windows(index, order, used, edges, n_keys, m, base):
    """The greedy over stars ``index[order]``: keep each star none of whose key windows is
    used, then mark them.  ``used`` (2 base^3,) bool carries over between calls.  A key
    (sorted pool-index triple s, type t: 0 face, 1 vertex) lies in the windows anchored at
    ``s - o + m`` for every offset o in [0, m)^3, code ``((t base + a0) base + a1) base + a2``,
    as in :func:`starforge.stars.rules.window_rows`.  Returns the kept positions of ``order``."""
    out = np.zeros(len(order), dtype=np.bool_)
    keys = np.empty((8, 3), dtype=np.int64)
    for q in range(len(order)):
        i = order[q]
        for k in range(n_keys):
            keys[k, 0], keys[k, 1], keys[k, 2] = key3(index, i, edges, k)
        if _windows(keys, n_keys, m, base, used, False):
            out[q] = True
            _windows(keys, n_keys, m, base, used, True)
    return out


def window_greedy(rule: str, pool_size: int, m: int):
    """The greedy over key windows (:func:`greedy_windows`) as ``keep(index, order)`` -> the kept
    positions of ``order`` (bool); the used windows carry over from call to call, so stars may
    come in pieces, in compactness order."""
    used = np.zeros(2 * (pool_size + m) ** 3, dtype=np.bool_)
    edges = np.concatenate([FACE_EDGES, VERTEX_EDGES]).astype(np.int64)
    n_keys = 4 if rule == "face" else 8

    def keep(index: np.ndarray, order: np.ndarray) -> np.ndarray:
        return greedy_windows(index, np.asarray(order, dtype=np.int64), used, edges, n_keys, m, pool_size + m)

    return keep


@numba.njit(cache=True, inline="always")
def _windows(keys, n_keys, m, base, used, mark):
    """Every key window of the star's ``keys`` (see :func:`greedy_windows`): with ``mark``,
    set them in ``used`` and return True; else whether none of them is used yet."""
    for k in range(n_keys):
        t = 0 if k < 4 else 1
        for o0 in range(m):
            for o1 in range(m):
                for o2 in range(m):
                    code = ((t * base + keys[k, 0] - o0 + m) * base + keys[k, 1] - o1 + m) * base + keys[k, 2] - o2 + m
                    if mark:
                        used[code] = True
                    elif used[code]:
                        return False
    return True


def range_cap(held: float = 0.0) -> int:
    """Stars one volume range may hold when it is sorted: a third of what the memory limit
    leaves beside ``held`` bytes and the base (a larger range is split by volume again)."""
    from starforge.runtime.budget import memory_limit_bytes

    return max(1, int((memory_limit_bytes() - STREAM_BASE_BYTES - held) // (3 * SORT_BYTES_PER_STAR)))


def ordered(idx: np.ndarray, pool: np.ndarray, vol: np.ndarray) -> np.ndarray:
    """:func:`starforge.stars.select.compactness_order` (one sort by rounded volume, then the
    full key only among stars of equal rounded volume)."""
    from starforge.stars.select import compactness_order

    return compactness_order(idx, pool, vol)


def _ordered_pieces(idx, vol, pool, lo: float, hi: float, cap: int):
    """(index, volume) of the stars in volume range [lo, hi), in compactness order, as pieces of at
    most about ``cap`` stars: a range above the cap is split into 16 equal volume ranges again
    (all stars of one rounded volume stay together, so the pieces concatenate in order)."""
    if len(idx) <= cap or not hi > lo:
        order = ordered(idx, pool, vol)
        yield idx[order], vol[order]
        return
    v = np.round(vol, 9)
    sub = np.clip(((v - lo) * (16 / (hi - lo))).astype(np.int64), 0, 15)
    if (sub == sub[0]).all() and np.unique(v).size == 1:
        order = ordered(idx, pool, vol)
        yield idx[order], vol[order]
        return
    w = (hi - lo) / 16
    for j in range(16):
        sel = np.flatnonzero(sub == j)
        if len(sel):
            yield from _ordered_pieces(idx[sel], vol[sel], pool, lo + j * w, lo + (j + 1) * w, cap)


def stream_family(
    spec: StarSpec,
    progress=None,
    avoid_faces_mm: np.ndarray | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
) -> dict:
    """Enumerate ``spec`` on the engine and select its family by the streamed greedy.

    Returns a dict: ``index`` (k, 6) int16 pool indices of the family (lexicographic order),
    ``stats`` (the enumeration's counts, as :class:`~starforge.stars.enumerate.Candidates`),
    ``candidates`` and ``undecided`` (stars after the rule's and the avoided faces' filter),
    ``bound`` (the certified block bound), ``info`` (selection notes) and ``seconds``
    (enumerate, select).  The spill folder is removed afterwards, also after an error or a
    signal (:func:`starforge.io.scratch_folder`).
    """
    from starforge.io import scratch_folder
    from starforge.stars.avoid import avoid_mask
    from starforge.stars.bounds import count_blocks
    from starforge.stars.classify import edge_pool
    from starforge.stars.enumerate import enumeration_stats, index_dtype, no_pool_error, run_chunks

    t0 = time.perf_counter()
    pool = edge_pool(spec)
    p, m = len(pool), spec.grid_steps
    faces_seen = np.zeros(p**3, dtype=np.bool_)
    vmax = _volume_max(spec)
    counts = np.zeros(8, dtype=np.int64)
    tally = {"fitting": 0, "candidates": 0, "undecided": 0, "chunks": 0}
    with scratch_folder("starforge-spill-", spill_dir()) as folder:
        spill = _Spill(folder, index_dtype(p))

        def consume(_i, res):
            nonlocal counts
            counts = counts + res["counts"]
            fit, vol, und = res["fit"], res["volume"], res["undecided"]
            tally["fitting"] += len(fit)
            ok = internal_ok(fit, spec.rule, m) & avoid_mask(fit, pool, avoid_faces_mm, spec.tol_mm)
            fit, vol = fit[ok], vol[ok]
            if len(und):
                und = und[internal_ok(und, spec.rule, m) & avoid_mask(und, pool, avoid_faces_mm, spec.tol_mm)]
            tally["candidates"] += len(fit)
            tally["undecided"] += len(und)
            if len(fit):
                faces_seen[_face_codes(fit, p)] = True
            if len(und):
                faces_seen[_face_codes(und, p)] = True
            spill.add(_bucket_of(vol, vmax), fit, vol)
            tally["chunks"] += 1

        labelled = run_chunks(spec, consume, progress, workers, scheduler)
        spill.flush()
        t_enum = time.perf_counter() - t0
        stats = enumeration_stats(spec, counts, labelled, tally["fitting"])
        if not tally["fitting"] and not labelled:
            raise no_pool_error(spec)
        # the greedy, range by range in compactness order
        t1 = time.perf_counter()
        keep_of = window_greedy(spec.rule, p, m)
        cap = range_cap(bitmap_sizes(spec)[1] + faces_seen.nbytes)  # the windows' bitmap, 1 byte each
        chosen = []
        width = vmax / BUCKETS
        for k in range(BUCKETS):
            idx, vol = spill.load(k)
            if not len(idx):
                continue
            for pidx, _pvol in _ordered_pieces(idx, vol, pool, k * width, (k + 1) * width, cap):
                chosen.append(pidx[keep_of(pidx, np.arange(len(pidx)))].astype(np.int16))
        index = np.concatenate(chosen) if chosen else np.zeros((0, 6), np.int16)
        index = index[np.lexsort(index.T[::-1])]
        t_sel = time.perf_counter() - t1
    # the certified bound: the block bound over the distinct face keys of every star that fits
    # or is undecided (the same set block_bound sees in memory)
    codes = np.flatnonzero(faces_seen)
    faces = np.stack([codes // (p * p), (codes // p) % p, codes % p], axis=1)
    bound = count_blocks(faces, m) // 4 if len(faces) else 0
    info = {
        "greedy": int(len(index)),
        "greedy_s": round(t_sel, 3),
        "block_bound": int(bound),
        "bound_from": "blocks",
        "streamed": (
            f"{tally['candidates']:,} candidates selected from {BUCKETS} volume ranges spilled to disk "
            f"(too many to hold in memory)"
        ),
    }
    if spec.select == "max":
        info["max_skipped"] = (
            "local search, iterated local search and the exact solver need every candidate in memory: "
            "family from the streamed greedy (most compact first), bound from blocks"
        )
    return {
        "index": index,
        "stats": stats,
        "candidates": int(tally["candidates"]),
        "undecided": int(tally["undecided"]),
        "bound": int(bound),
        "info": info,
        "seconds": {"enumerate": t_enum, "select": t_sel},
    }
