"""The first-run helper compiles exactly the kernels ``stars`` then loads: on a fresh cache,
after the helper, the enumeration's first pass and the selection's kernels come from the cache
(no compile) when called the way ``stars`` calls them; it reports each group as it lands; and
nothing is left running."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

HELPER = (
    "from starforge.stars import warmup\n"
    "cold = warmup.cache_is_cold()\n"
    "p = warmup.start()\n"
    "said = [p.wait_for(g, 300) for g in ('enumerate', 'select')] if p else []\n"
    "warmup.finish(p, 300)\n"
    "print(cold, p is not None, p.returncode if p else None, warmup.cache_is_cold(), all(said))\n"
)

AFTER = """
import json
import numpy as np
from starforge.stars import classify as C, enumerate as E, packing as K, select as S
from starforge.stars.rules import window_rows
from starforge.stars.spec import StarSpec

spec = StarSpec(box_mm=(16, 12, 24), delta_mm=2.0, box_method="covariance")  # no fit search
res = E.enumerate_chunk((spec, 0, 64, None))
idx = res["fit"][:40]
star_of, row, n_rows = window_rows(idx, "face", 1, spec.pool_size)
ptr, rows = S.csr_rows(star_of, row, len(idx))
order = np.arange(len(idx))
g = S.greedy(order, ptr, rows, n_rows)
g, _ = S.local_search(g, order, ptr, rows, n_rows)
S.ils(g, order, ptr, rows, n_rows, iterations=20)
out = {}
for f in (C.classify_range, C.subsets_from, S._greedy, K._csc,
          K._search):
    out[f.py_func.__name__] = [sum(f.stats.cache_hits.values()), sum(f.stats.cache_misses.values())]
print(json.dumps(out))
"""


@pytest.mark.slow
def test_helper_fills_the_cache_stars_then_loads(tmp_path):
    env = dict(os.environ, STARFORGE_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("NUMBA_CACHE_DIR", None)
    first = subprocess.run([sys.executable, "-c", HELPER], env=env, capture_output=True, text=True, check=True)
    cold, started, rc, cold_after, reported = first.stdout.split()
    if (os.cpu_count() or 1) < 2:
        assert started == "False"
        return
    # the helper reported both groups of kernels (what the run waits for instead of compiling)
    assert (cold, started, rc, cold_after, reported) == ("True", "True", "0", "False", "True")
    after = subprocess.run([sys.executable, "-c", AFTER], env=env, capture_output=True, text=True, check=True)
    stats = json.loads(after.stdout.strip().splitlines()[-1])
    for name, (hits, misses) in stats.items():
        assert hits >= 1 and misses == 0, (name, hits, misses)


def test_ready_without_a_helper_returns_at_once():
    from starforge.stars import warmup

    assert warmup._active[0] is None
    warmup.ready("enumerate", timeout_s=1e6)  # no helper: nothing to wait for
    warmup.ready("select", timeout_s=1e6)


def test_finish_closes_the_helpers_pipe():
    """A helper's report pipe is closed when it is finished (left to the garbage collector, it
    would raise a ResourceWarning, an error under the test run's warning filter)."""
    import subprocess
    import sys

    from starforge.stars import warmup

    proc = subprocess.Popen(
        [sys.executable, "-c", "print('enumerate'); print('select')"], stdout=subprocess.PIPE, text=True
    )
    helper = warmup.Helper(proc)
    assert helper.wait_for("select", 30)
    warmup.finish(helper)
    assert proc.returncode == 0 and proc.stdout.closed


COLD = """
from starforge.stars import warmup
from starforge.stars.classify import classify_range
f = classify_range._cache._cache_file
here = classify_range.targetctx.codegen().magic_tuple()
out = [warmup.cache_is_cold()]
f._save_index({("sig", ("x86_64-unknown-linux-gnu", "another-cpu", "+avx"), ("h", "h")): "x.1.nbc"})
out.append(warmup.cache_is_cold())  # only another machine's entry: numba would compile
f._save_index({("sig", here, ("h", "h")): "x.1.nbc"})
out.append(warmup.cache_is_cold())
print(out)
"""


def test_cache_is_cold_until_it_holds_an_entry_for_this_machine(tmp_path):
    env = dict(os.environ, STARFORGE_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("NUMBA_CACHE_DIR", None)
    res = subprocess.run([sys.executable, "-c", COLD], env=env, capture_output=True, text=True, check=True)
    assert res.stdout.split("\n")[0] == "[True, True, False]"
