"""Enumerate every star of an edge-length pool that fits a size limit, compiled and streamed.

Pipeline, per labelled candidate (no Python loop per star; numba, subsets spread over threads):

1. pool: ``l_min + k * delta`` (mm);
2. every 6-subset of the pool whose lengths differ pairwise by at least the tolerance (so that
   the tolerance holds within a star and within each face), each put on the tetrahedron in its
   30 distinct ways (:func:`starforge.geometry.tetra.canonical_assignments`): one entry per star up
   to relabelling and mirroring;
3. realisable: the trilateration of the paper (A at the origin, B on +x, C in the xy-plane, D
   above it) succeeds: triangle ABC valid and Cayley-Menger volume > 0;
4. deep enough: the tetrahedron's width (the smallest side of any box around its centres, in any
   orientation) is at least ``min_depth``;
5. necessary fit conditions: the width is at most the shortest limit side, and Ky Fan's bounds on
   the covariance eigenvalues (the k smallest sum to at most the sum of the k shortest limit sides
   squared over 4; variance along a direction is at most a quarter of the width squared);
6. the fit decision (:mod:`starforge.geometry.fit`): first a quick no-fit proof, a table
   lookup: a face (three pool lengths) that provably does not fit the limit widened by the
   slack (:func:`~starforge.geometry.faces.face_table`, decided once per spec and process for
   every triangle of the pool) rules the star out, and the search could only have said NO_FIT
   too: a star it calls FIT fits the limit, one it leaves UNDECIDED fits the limit plus the
   slack, and so would each face (the proof is in ``face_table``).  Then the search: proven to fit (a rotation is found), proven not to fit, or
   undecided (fits, if at all, with less than :data:`~starforge.geometry.fit.SLACK_MM` to
   spare).  ``box_method="covariance"`` replaces it with the paper's test (the covariance box
   must fit).

Candidates are the stars proven to fit.  The undecided ones are counted, and kept apart for
certified upper bounds (a bound over fitting + undecided covers every star that really fits).
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from starforge.errors import StarforgeError
from starforge.geometry.fit import SLACK_MM
from starforge.runtime.kernels import numba
from starforge.stars.classify import (
    BATCH_SUBSETS,
    DECIDE_SETS,
    FIT,
    KY_FAN,
    NECESSARY_OK,
    NO_FIT,
    TOO_THIN,
    TOO_WIDE,
    UNDECIDED,
    UNREALISABLE,
    assignment_table,
    covariance_fits,
    decide_left,
    edge_pool,
    first_pass,
    spec_faces,
    subsets_from,
)
from starforge.stars.estimate import (
    BYTES_PER_CANDIDATE,
    admissible_subsets,
    check_size,
    estimate,
    labelled_count,
)
from starforge.stars.spec import StarSpec


@dataclass(frozen=True)
class Candidates:
    """Stars that fit (and those undecided), as arrays (row i is one star).

    Attributes
    ----------
    pool_mm : (p,) float         the edge-length pool, mm
    index : (m, 6) int16         pool indices of (u, U, v, V, w, W) of the stars proven to fit
    box_volume : (m,) float      volume of the fitting box found for each, mm^3
    undecided : (q, 6) int16     pool indices of the undecided stars (kept for upper bounds)
    stats : dict                 counts per stage and seconds
    """

    pool_mm: np.ndarray
    index: np.ndarray
    box_volume: np.ndarray
    undecided: np.ndarray
    stats: dict

    def __len__(self) -> int:
        return len(self.index)

    @property
    def lengths(self) -> np.ndarray:
        """(m, 6) float, mm."""
        return self.pool_mm[self.index]


#: subsets per enumeration chunk (one task: about 4 M labelled candidates, 1-2 s on one core)
CHUNK_SUBSETS = BATCH_SUBSETS


def unrank_subset(rank: int, n: int, m: int) -> np.ndarray:
    """The admissible 6-subset of range(n) (elements >= m apart) of lexicographic ``rank``, (6,).

    Admissible subsets c and plain 6-subsets b of range(n - 5 (m - 1)) correspond one to one
    (``c_j = b_j + j (m - 1)``), in the same order; b is unranked in the combinatorial number
    system."""
    free = n - (m - 1) * 5
    r = int(rank)
    out = np.empty(6, dtype=np.int64)
    x = 0
    for i in range(6):
        while True:
            c = math.comb(free - x - 1, 5 - i)
            if r < c:
                out[i] = x + i * (m - 1)
                x += 1
                break
            r -= c
            x += 1
    return out


def chunks(spec: StarSpec, size: int | None = None) -> list[tuple[int, int]]:
    """(first rank, subsets) of each enumeration chunk (``size`` subsets, default
    :data:`CHUNK_SUBSETS`), in rank order."""
    size = int(size or CHUNK_SUBSETS)
    total = admissible_subsets(spec.pool_size, spec.grid_steps)
    return [(r, min(size, total - r)) for r in range(0, total, size)]


def spread_order(n: int) -> np.ndarray:
    """``0..n-1`` in bit-reversed order (those below ``n`` of the next power of two): every prefix
    of it is spread evenly over the range, e.g. 0, 4, 2, 6, 1, 5, 3 for ``n = 7``."""
    bits = max(int(n - 1).bit_length(), 1)
    ranks = np.arange(1 << bits)
    rev = np.zeros_like(ranks)
    for b in range(bits):
        rev |= ((ranks >> b) & 1) << (bits - 1 - b)
    return rev[rev < n]


def index_dtype(pool_size: int) -> type:
    """The narrowest integer type that holds pool indices: uint8 up to 256 lengths, else int16."""
    return np.uint8 if pool_size <= 256 else np.int16


def _where_code(codes: np.ndarray, code: int) -> tuple[np.ndarray, np.ndarray]:
    """(subset rows, assignment columns) of the entries of ``codes`` (s, 30) equal to ``code``,
    in row-major order: ``np.nonzero``'s result, from the flat positions (3x faster on a
    batch's 3.9 M codes)."""
    return np.divmod(np.flatnonzero(codes == code), codes.shape[1])


def enumerate_chunk(args: tuple) -> dict:
    """One task of the enumeration: the admissible subsets of ranks ``[rank, rank + count)``.

    ``args = (spec, rank, count, threads)``; ``threads``: compiled-kernel threads (None: every
    core).  Returns the stage counts (8,) int64 and, compactly, the fitting stars (pool indices
    (k, 6) in :func:`index_dtype`, 1 byte each for pools up to 256 lengths, and box volumes
    (k,) float64, kept exact: the selection orders by them) and the undecided ones (q, 6), in
    the order found; the caller sorts.  A pure function of its input."""
    spec, rank, count, threads = args
    pool = edge_pool(spec)
    lo = float(pool[0])
    step = float(spec.delta_mm)
    limit = np.sort(np.array(spec.centre_limit_mm, dtype=float))
    m = spec.grid_steps
    assign = assignment_table()
    mode = 0 if spec.box_method == "exact" else 1
    dt = index_dtype(len(pool))
    counts = np.zeros(8, dtype=np.int64)
    fit_idx, fit_vol, und_idx = [], [], []
    faces = spec_faces(spec, threads)
    start = unrank_subset(rank, len(pool), m)
    left = int(count)
    while left > 0:
        sub = subsets_from(len(pool), m, start, min(BATCH_SUBSETS, left))
        if not len(sub):
            break
        left -= len(sub)
        codes = np.empty((len(sub), len(assign)), dtype=np.int8)
        first_pass(sub, assign, lo, step, limit, spec.depth_mm, mode, codes, threads, faces=faces)
        # (count_nonzero per code is faster than np.bincount on int8)
        counts[: NO_FIT + 1] += [np.count_nonzero(codes == c) for c in range(NO_FIT + 1)]
        if mode == 1:
            counts[NECESSARY_OK] += np.count_nonzero(codes == NECESSARY_OK)
            s, a = _where_code(codes, NECESSARY_OK)
            idx = np.take_along_axis(sub[s], assign[a], axis=1)
            from starforge.geometry.tetra import vertices_from_lengths

            fits, vol = covariance_fits(vertices_from_lengths(pool[idx]), limit)
            counts[FIT] += int(fits.sum())
            counts[NO_FIT] += int((~fits).sum())
            fit_idx.append(idx[fits].astype(dt))
            fit_vol.append(vol[fits])
        else:
            pos, status, vol = decide_left(sub, assign, lo, step, limit, SLACK_MM, 100_000, codes, threads)
            counts[NO_FIT] += np.count_nonzero(status == 0)
            counts[UNDECIDED] += np.count_nonzero(status == -1)
            counts[FIT] += len(vol)
            # in the row-major order of the codes, as a scan of them would give
            s, a = np.divmod(pos[status == 1], len(assign))
            fit_idx.append(np.take_along_axis(sub[s], assign[a], axis=1).astype(dt))
            fit_vol.append(vol)
            s, a = np.divmod(pos[status == -1], len(assign))
            und_idx.append(np.take_along_axis(sub[s], assign[a], axis=1).astype(dt))
    return {
        "counts": counts,
        "fit": np.concatenate(fit_idx) if fit_idx else np.zeros((0, 6), dt),
        "volume": np.concatenate(fit_vol) if fit_vol else np.zeros(0),
        "undecided": np.concatenate(und_idx) if und_idx else np.zeros((0, 6), dt),
    }


def chunk_bytes(count: int) -> float:
    """Peak memory of one enumeration chunk of ``count`` subsets, bytes: a batch's codes and
    volumes, the positions of the candidates left for the fit decision (9 bytes each, all of
    them at worst) and one block of their points and rotations (:data:`DECIDE_SETS`), its
    subsets, and the kept stars (at most a quarter of its labelled candidates, the generous
    share :func:`estimate` uses)."""
    b = min(count, BATCH_SUBSETS)
    return b * 30 * (9 + 9) + DECIDE_SETS * 400 + b * 12 + count * 30 / 4 * BYTES_PER_CANDIDATE


def run_chunks(spec: StarSpec, consume, progress=None, workers: int | None = None, scheduler: str | None = None):
    """Run every enumeration chunk of ``spec`` on the engine and hand each result (a dict of
    :func:`enumerate_chunk`) to ``consume(i, result)`` as it arrives, in any order.  Returns
    the labelled candidates looked at.  See :func:`enumerate_candidates` for the options."""
    from starforge.runtime import engine

    total = labelled_count(spec)
    parts = chunks(spec)
    est = estimate(spec)
    cores = max(1, min(os.cpu_count() or 1, numba.config.NUMBA_NUM_THREADS))
    # without a scheduler the chunks run in this process: the compiled kernel already uses every
    # core, and its memory is one batch plus the kept stars, as on a cluster's client; a local
    # cluster would only add its start-up
    remote = engine.scheduler_address(scheduler) is not None
    seconds = est["seconds"] * cores if remote else 0.0
    p = engine.plan(len(parts), seconds, workers, scheduler)
    threads = workers if p.mode == "serial" else 1
    # the chunks run in a spread order (every prefix samples the whole rank range): their cost
    # grows with the rank, so in rank order the rate measured early says little of the rate
    # later, and the progress's time left would be several times too short
    run_order = spread_order(len(parts))
    parts = [parts[k] for k in run_order]
    tick = None
    if progress is not None:
        sizes = np.cumsum([c for _, c in parts]) * 30

        def tick(done, _n):
            progress(int(sizes[done - 1]), total)

    def consume_ranked(i, res):
        consume(int(run_order[i]), res)

    task_bytes = [chunk_bytes(c) for _, c in parts]
    # in process, two chunks at once where two fit in memory: one chunk's numpy work between
    # its kernels (a single thread) runs beside the other's kernels instead of leaving a core idle
    overlap = 1
    if p.mode == "serial" and (threads is None or threads > 1) and task_bytes:
        overlap = 2 if 2 * max(task_bytes) <= p.usable_bytes else 1
    engine.map_tasks(
        enumerate_chunk,
        [(spec, r, c, threads) for r, c in parts],
        task_bytes=task_bytes,
        seconds=seconds,
        workers=workers,
        scheduler=scheduler,
        progress=tick,
        what=f"enumerating {total:,} labelled candidates",
        advice="raise delta_mm or tolerance_mm, or use workers with more memory",
        consume=consume_ranked,
        overlap=overlap,
    )
    return int(sum(c for _, c in parts) * 30)


def enumeration_stats(spec: StarSpec, counts: np.ndarray, labelled: int, fitting: int) -> dict:
    """The enumeration's counts per stage (the ``stats`` of :class:`Candidates`, less seconds)."""
    mode = 0 if spec.box_method == "exact" else 1
    return {
        "pool_size": spec.pool_size,
        "tolerance_steps": spec.grid_steps,
        "labelled": labelled,
        "realisable": int(labelled - counts[UNREALISABLE]),
        "deep_enough": int(labelled - counts[: TOO_THIN + 1].sum()),
        "width_ok": int(labelled - counts[: TOO_WIDE + 1].sum()),
        "kyfan_ok": int(labelled - counts[: KY_FAN + 1].sum()),
        "no_fit": int(counts[NO_FIT]),
        "undecided": int(counts[UNDECIDED]),
        "fitting": int(fitting),
        "fit_test": "exact" if mode == 0 else "covariance",
        "fit_slack_mm": SLACK_MM if mode == 0 else None,
    }


def no_pool_error(spec: StarSpec) -> StarforgeError:
    return StarforgeError(
        f"the edge-length pool ({spec.pool_size} lengths) holds no 6 lengths that differ pairwise by the "
        f"tolerance {spec.tol_mm:g} mm; lower tolerance_mm or enlarge the box"
    )


def enumerate_candidates(
    spec: StarSpec, progress=None, workers: int | None = None, scheduler: str | None = None
) -> Candidates:
    """Every star (up to relabelling and mirroring) whose centres provably fit ``spec``'s limit.

    The admissible 6-subsets are cut into chunks of consecutive ranks (:func:`chunks`), each one
    task of :func:`starforge.runtime.engine.map_tasks` (:func:`enumerate_chunk`): in this process (the
    compiled kernel runs on every core), or on the cluster at ``scheduler`` (or
    ``STARFORGE_SCHEDULER``).  The result is sorted, so it does not depend on where or in which
    order the chunks ran.  (Specs whose candidates do not fit in memory go through
    :mod:`starforge.stars.stream` instead.)

    Parameters
    ----------
    spec : StarSpec
    progress : callable or None
        ``progress(done, total)`` in labelled candidates, after each chunk.
    workers : int or None
        Threads in process (default: every core).  The result does not depend on it.
    scheduler : str or None
        Address of a dask scheduler (default: ``STARFORGE_SCHEDULER``; unset: this machine).
    """
    t0 = time.perf_counter()
    check_size(spec)
    pool = edge_pool(spec)
    results: dict[int, dict] = {}

    def keep(i, res):
        results[i] = res

    done = run_chunks(spec, keep, progress, workers, scheduler)
    rs = [results[i] for i in sorted(results)]
    counts = np.sum([r["counts"] for r in rs], axis=0) if rs else np.zeros(8, np.int64)
    index = np.concatenate([r["fit"] for r in rs]).astype(np.int16) if rs else np.zeros((0, 6), np.int16)
    volume = np.concatenate([r["volume"] for r in rs]) if rs else np.zeros(0)
    undecided = np.concatenate([r["undecided"] for r in rs]).astype(np.int16) if rs else np.zeros((0, 6), np.int16)
    order = np.lexsort(index.T[::-1])  # deterministic: lexicographic on pool indices
    stats = enumeration_stats(spec, counts, done, len(index))
    stats["seconds"] = time.perf_counter() - t0
    if not len(index) and not stats["labelled"]:
        raise no_pool_error(spec)
    undecided = undecided[np.lexsort(undecided.T[::-1])] if len(undecided) else undecided
    # np.take gathers whole rows (12 bytes each) about 3 x faster than fancy indexing does
    return Candidates(
        pool_mm=pool, index=np.take(index, order, axis=0), box_volume=volume[order], undecided=undecided, stats=stats
    )
