"""Fuzz sample: generated broken scenes either run cleanly or
raise SceneError; no crash, hang, NaN/inf, energy-audit failure or flux above
what was emitted. Meaningful under NUMBA_BOUNDSCHECK=1 too: an out-of-bounds
index then raises IndexError in a kernel, which the runner counts as a failure.

Select with `-m fuzz` (or this file). FUZZ_CASES / FUZZ_START / FUZZ_WORKERS
override the sample.
"""
import os

import pytest

from photon_lightmaps.benchmarks import fuzz

pytestmark = pytest.mark.fuzz

N_CASES = int(os.environ.get("FUZZ_CASES", "200"))
START = int(os.environ.get("FUZZ_START", "0"))
WORKERS = int(os.environ.get("FUZZ_WORKERS", "2"))


def test_fuzz_sample_has_no_failures():
    results, seconds = fuzz.run_cases(range(START, START + N_CASES), workers=WORKERS, timeout=120.0)
    summary = fuzz.summarize(results, seconds, START)
    bad = {k: v for k, v in summary["failure_ids"].items() if v}
    detail = "\n".join(f"case {i}: {m}" for i, m in list(summary["messages"].items())[:20])
    assert not bad, f"fuzz failures {bad} ({summary['seconds']} s)\n{detail}"
    # the sample must actually exercise the engine, not only be refused
    assert summary["outcomes"].get("ok", 0) > N_CASES // 2


def test_case_generation_is_reproducible():
    a, ta, sa = fuzz.make_case(17)
    b, tb, sb = fuzz.make_case(17)
    assert ta == tb and sa == sb and repr(a) == repr(b)
