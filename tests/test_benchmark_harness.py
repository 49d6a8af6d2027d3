"""The speed-against-accuracy harness (benchmarks/run_all.py) end to end, tiny knobs.

Runs `python -m benchmarks.run_all --quick` in a subprocess (it resets Blender's
scene, which must not leak into other tests) on the Cornell room, then checks
that the JSON holds every method and that error falls as effort rises. Not a
timing test: seconds are recorded, never asserted.
"""
import json
import os
import pathlib
import subprocess
import sys

import pytest

import bpy  # noqa: E402,F401  (all three are in requirements.txt: missing, they fail)
import matplotlib  # noqa: E402,F401
import scipy  # noqa: E402,F401

ROOT = pathlib.Path(__file__).resolve().parents[1]
METHODS = {"ours_bake", "photon_map", "cycles_bake", "ours_render_constant", "ours_render_bilinear",
           "cycles_render"}
FIELDS = {"method", "knob", "seconds", "rel_rmse", "mean_error", "memory_bytes"}
# The worst (least effort) relative RMSE each method had in the quick run when these
# bounds were set (`python -m benchmarks.run_all --quick`); every point must stay
# within 1.5x of it (seeded runs repeat to a few %).
MEASURED_WORST = {"ours_bake": 0.70, "ours_bake_gather": 0.044, "ours_bake_cache": 0.032,
                  "photon_map": 0.23, "cycles_bake": 0.74, "ours_render_constant": 0.52,
                  "ours_render_bilinear": 0.43, "ours_render_gather": 0.19, "cycles_render": 0.93}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    env = dict(os.environ)
    env.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))
    proc = subprocess.run([sys.executable, "-m", "benchmarks.run_all", "--quick", "--out", str(out)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    with open(out / "results.json") as f:
        return json.load(f), out, proc.stdout


def test_json_has_every_method_with_all_fields(quick_run):
    res, _, _ = quick_run
    pts = res["points"]
    assert {p["method"] for p in pts} >= METHODS
    for p in pts:
        assert FIELDS <= set(p), p
        # every method lands at a real error: not zero (that would be the reference
        # itself), and near what it measured (a broken method or a mismatched
        # reference is far above)
        assert p["seconds"] > 0 and p["rel_rmse"] > 1e-4, p
        if p["method"] in MEASURED_WORST:
            assert p["rel_rmse"] < 1.5 * MEASURED_WORST[p["method"]], p
    for m in ("ours_bake", "photon_map"):
        assert all(p["memory_bytes"] > 0 and p["memory_compact_bytes"] > 0 for p in pts if p["method"] == m)


def test_error_falls_as_effort_rises(quick_run):
    res, _, _ = quick_run
    for m in METHODS:
        c = sorted((p for p in res["points"] if p["method"] == m), key=lambda p: p["knob"])
        assert len(c) >= 2, m
        errs = [p["rel_rmse"] for p in c]
        # Overall: the most effort beats the least by a clear margin.
        assert errs[-1] < 0.8 * errs[0], (m, errs)
        # Step by step: never clearly worse (Monte Carlo noise allowed).
        for a, b in zip(errs, errs[1:]):
            assert b < 1.25 * a + 0.01, (m, errs)


def test_headlines_and_charts(quick_run):
    res, out, stdout = quick_run
    h = res["headlines"]["cornell"]
    sp = h["speedup_vs_cycles_bake"]
    # the ratio is Cycles' time at our error over ours, and our point is a swept one
    assert sp["ratio"] == pytest.approx(sp["cycles_seconds_at_equal_error"] / sp["ours_seconds"], rel=1e-12)
    ours = [p for p in res["points"] if p["method"] == "ours_bake" and p["scene"] == "cornell"]
    assert any(p["seconds"] == sp["ours_seconds"] and p["rel_rmse"] == sp["ours_rel_rmse"] for p in ours)
    cyc = sorted(p["rel_rmse"] for p in res["points"] if p["method"] == "cycles_bake" and p["scene"] == "cornell")
    assert sp["extrapolated"] or cyc[0] <= sp["ours_rel_rmse"] <= cyc[-1]
    assert -0.8 < h["error_vs_photons"]["slope_low_photons"] < -0.3
    assert "Headline ratios" in stdout
    charts = {p.name for p in (out / "charts").glob("*.png")}
    assert {"cornell_error_vs_time.png", "cornell_error_map.png", "memory_vs_error.png",
            "error_vs_photons.png", "failure_cases.png"} <= charts


def test_the_stored_references_match_the_scene_builders():
    """Each room's committed Cycles reference (benchmarks/references/) is found under
    the key of the scene its builder makes now. A scene field added to the engine
    changes that key unless benchmarks/scenes.KEY_NEUTRAL leaves it out; then
    run_all would regenerate every reference (many minutes) instead of reading it."""
    code = ("import photon_lightmaps\n"
            "from photon_lightmaps import registration\n"
            "from benchmarks import references, run_all, scenes\n"
            "registration.is_registered() or photon_lightmaps.register()\n"
            "for name in ('cornell', 'window', 'baffle'):\n"
            "    scenes.build(name, 128, 128)\n"
            "    ref, src = references.load_or_make(name, run_all.FULL['ref'], print, allow_make=False)\n"
            "    print(name, src)\n")
    env = dict(os.environ)
    env.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    found = dict(line.split(" ", 1) for line in proc.stdout.splitlines() if line.split(" ")[0] in
                 ("cornell", "window", "baffle"))
    assert set(found) == {"cornell", "window", "baffle"}, proc.stdout
    assert all(src.startswith(("committed:", "cache:")) for src in found.values()), found
