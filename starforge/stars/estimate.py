"""What an enumeration will cost, known before any work: labelled candidates, seconds (from a
pilot sample of the spec's own stars) and bytes, and the refusals of a spec past the memory or
time limit (one line naming what to change)."""

from __future__ import annotations

import math
import os
import time

import numpy as np

from starforge.runtime.kernels import numba
from starforge.stars.classify import (
    BATCH_SUBSETS,
    FIT,
    NECESSARY_OK,
    NO_FACES,
    SLACK_MM,
    assignment_table,
    classify,
    edge_pool,
    spec_faces,
)
from starforge.stars.sizing import require_stream
from starforge.stars.spec import StarSpec

#: wall seconds per labelled candidate on 2 cores, measured on uniformly drawn finger-case
#: subsets (2.2e-7; a first guess, replaced by a pilot measurement for any spec estimated to
#: take more than a few seconds: :func:`check_size`)
SECONDS_PER_LABELLED = 2e-7
#: bytes kept per fitting candidate (index, status, volume) and a generous share of fits
BYTES_PER_CANDIDATE = 32


def labelled_count(spec: StarSpec) -> int:
    """Labelled candidates the enumeration will look at: 30 per admissible 6-subset."""
    return 30 * admissible_subsets(spec.pool_size, spec.grid_steps)


def admissible_subsets(n: int, m: int) -> int:
    """6-subsets of range(n) whose elements differ pairwise by >= m (stars-and-bars)."""
    k = 6
    free = n - (m - 1) * (k - 1)
    return math.comb(free, k) if free >= k else 0


def estimate(spec: StarSpec) -> dict:
    """Labelled candidates, seconds (2 cores) and bytes the enumeration of ``spec`` needs."""
    labelled = labelled_count(spec)
    cores = max(1, min(os.cpu_count() or 1, numba.config.NUMBA_NUM_THREADS))
    seconds = labelled * SECONDS_PER_LABELLED * 2 / cores  # the rate was measured on 2 cores
    # working memory: one batch of codes and volumes, the subsets of a batch, and the kept fits
    # (at most a quarter of the labelled candidates, a generous bound seen on every spec tried)
    nbytes = BATCH_SUBSETS * 30 * 5 + labelled / 4 * BYTES_PER_CANDIDATE + 200e6
    return {"labelled": labelled, "seconds": seconds, "bytes": nbytes}


#: admissible 6-subsets drawn for the pilot timing of :func:`check_size`
PILOT_SUBSETS = 256


#: the pilot builds the face table (:func:`starforge.stars.classify.spec_faces`) for pools of up to this many admissible
#: triples (about 0.1-0.5 CPU s; the finger pool at delta 0.5: 105,995); past it the table costs
#: seconds (a 60 mm cube at delta 0.5: 1.0 M triples, 5.7 CPU s), and a spec refused by the size
#: check would wait for it
PILOT_FACE_TRIANGLES = 200_000


#: pilot measurements of this process, by (spec, samples, cpu): a ``stars`` run checks its size
#: up to three times (the command, the family, the enumeration) and measures once
_PILOTS: dict = {}


def pilot(spec: StarSpec, samples: int = PILOT_SUBSETS, cpu: bool = False) -> tuple[float, float]:
    """(wall seconds per labelled candidate, share of labelled candidates that fit), measured on
    ``samples`` admissible 6-subsets drawn uniformly (fixed seed) and classified exactly as the
    enumeration will.  The cost per candidate depends on the spec (how many stars reach the fit
    decision, how hard it is), so a fixed rate can be off by an order of magnitude; a pilot is
    not (within about 2x).  Measured once per spec in a process (later calls return the first
    measurement).

    ``cpu=True``: the rate is CPU seconds of one thread instead (the kernel run on one thread,
    timed with :func:`time.thread_time`), for work that runs one task per core (sweep cells):
    unlike wall time, it does not grow with the load of other jobs on the machine."""
    key = (spec, int(samples), bool(cpu))
    try:
        hash(key)
    except TypeError:  # a spec holding a list: measured every time
        return _pilot(spec, int(samples), bool(cpu))
    if key not in _PILOTS:
        _PILOTS[key] = _pilot(spec, int(samples), bool(cpu))
    return _PILOTS[key]


def _pilot(spec: StarSpec, samples: int, cpu: bool) -> tuple[float, float]:
    n, m = spec.pool_size, spec.grid_steps
    free = n - (m - 1) * 5
    if free < 6:
        return SECONDS_PER_LABELLED, 0.0
    rng = np.random.default_rng(0)
    draws = np.sort(np.array([rng.choice(free, 6, replace=False) for _ in range(samples)]), axis=1)
    sub = (draws + np.arange(6) * (m - 1)).astype(np.int16)
    assign = assignment_table()
    limit = np.sort(np.array(spec.centre_limit_mm, dtype=float))
    mode = 0 if spec.box_method == "exact" else 1
    lo = float(edge_pool(spec)[0])
    codes = np.empty((len(sub), len(assign)), dtype=np.int8)
    vols = np.empty((len(sub), len(assign)))
    args = (assign, lo, float(spec.delta_mm), limit, spec.depth_mm, SLACK_MM, 100_000, mode)
    # the table is kept for the enumeration (not part of the rate); one of many triangles takes
    # seconds, and the pilot runs before any refusal: then it measures without (a higher rate)
    n_tri = math.comb(max(0, n - 2 * (m - 1)), 3)
    faces = spec_faces(spec) if n_tri <= PILOT_FACE_TRIANGLES else NO_FACES
    classify(sub[:1], *args, codes[:1], vols[:1], faces=faces)  # compile or load the kernel, untimed
    if cpu:
        t = time.thread_time()
        classify(sub, *args, codes, vols, threads=1, faces=faces)
        rate = max(2 * SECONDS_PER_LABELLED, (time.thread_time() - t) / codes.size)
    else:
        t = time.perf_counter()
        classify(sub, *args, codes, vols, chunk=16, faces=faces)  # on every thread, as the enumeration runs
        rate = max(SECONDS_PER_LABELLED, (time.perf_counter() - t) / codes.size)
    return rate, float(np.isin(codes, (FIT, NECESSARY_OK)).mean())


#: tolerance in pool steps up to which a spec whose candidates do not fit in memory is selected
#: by the streamed greedy (:mod:`starforge.stars.stream`): it checks ``m**3`` key windows per key
#: of every fitting star, so its time grows with the cube of the tolerance in steps
STREAM_MAX_STEPS = 2


def check_memory(spec: StarSpec, allow_stream: bool = False) -> dict:
    """Refuse, before any work, an enumeration past the memory limit (one line); returns
    :func:`estimate`.  No compiled code runs (:func:`check_size` adds the time).  With
    ``allow_stream`` a spec the streamed greedy may take (tolerance up to
    :data:`STREAM_MAX_STEPS` pool steps) is left to :func:`check_size`, which decides after its
    pilot."""
    from starforge.runtime.budget import require_memory

    est = estimate(spec)
    if not (allow_stream and spec.grid_steps <= STREAM_MAX_STEPS):
        require_memory(est["bytes"], *_what_advice(spec, est))
    return est


def check_size(spec: StarSpec, allow_stream: bool = False) -> str:
    """Refuse, before any work, an enumeration past the memory or time limit (one line).  The
    time is the labelled count times a rate measured on a pilot sample of the spec's own stars.

    Returns where the candidates go: ``"memory"`` (gathered, then selected in memory) or, with
    ``allow_stream``, ``"stream"`` when they would not fit in memory but the streamed greedy
    (:func:`starforge.stars.stream.stream_family`) holds them within the memory and disk limits.
    """
    from starforge.runtime.budget import memory_limit_bytes, require_memory, require_time
    from starforge.stars.rules import window_bytes

    est = estimate(spec)
    fits, piloted = None, False
    if est["labelled"] and est["seconds"] > 2.0:  # cheap specs need no pilot
        rate, fit_share = pilot(spec)
        est["seconds"] = est["labelled"] * rate
        fits = est["labelled"] * fit_share
        piloted = True
    # the selection's key windows grow with the cube of the tolerance in pool steps
    in_memory = est["bytes"] <= memory_limit_bytes() and (
        fits is None or window_bytes(fits, spec.rule, spec.grid_steps) <= memory_limit_bytes()
    )
    path = "memory"
    if not in_memory and allow_stream and piloted and spec.grid_steps <= STREAM_MAX_STEPS:
        require_stream(spec, est["labelled"], fits)
        path = "stream"
    else:
        require_memory(est["bytes"], *_what_advice(spec, est))
        if fits is not None:
            require_memory(
                window_bytes(fits, spec.rule, spec.grid_steps),
                f"selecting among about {fits:,.0f} fitting stars (a pilot sample) with a tolerance of "
                f"{spec.grid_steps} pool steps ({spec.grid_steps**3:,} key windows per face)",
                "lower tolerance_mm or raise delta_mm",
            )
    require_time(est["seconds"], *_what_advice(spec, est))
    return path


def _what_advice(spec: StarSpec, est: dict) -> tuple[str, str]:
    lo, hi = spec.pool_bounds_mm
    what = (
        f"enumerating {est['labelled']:,} labelled candidates (a pool of {spec.pool_size} lengths, "
        f"{lo:.2f}..{hi:.2f} mm in {spec.delta_mm:g} mm steps)"
    )
    advice = "raise delta_mm, gap_mm or tolerance_mm, or shrink box_mm"
    return what, advice
