"""L-systems through the directed cyclic scene graph (thesis ch. 7, 8.5): speed, ray
cost against the flattened instantiation, scale and memory.

Usage (from the repository root):
    .venv/bin/python -m benchmarks.bench_lsystem            # default: ~2 min warm, ~6 min with an empty numba cache
    .venv/bin/python -m benchmarks.bench_lsystem --quick    # small knobs, about a minute (warm cache)
    .venv/bin/python -m benchmarks.bench_lsystem --cold     # also time a cold run (empty numba cache, +minutes)
Options: --out DIR  --only e2e,rays,scale,memory  --samples N  --reps R  --full-memory

Sections (each a key of DIR/lsystem.json, lsystem_quick.json for --quick):

* ``e2e`` - the sympodial tree preset (thesis fig. 8.5; 41 983 segments, 17 OL stubs)
  in demo_scenes.lsystem_studio at 640 x 640, 100 000 photons, `samples` camera
  samples per pixel, 2000 area samples per orientation lightmap (one explicit OL
  over the tree, whose samples the 18 stub OLs inherit): session.compile /
  photon_pass / render, wall clock. The first run in this process is reported
  separately (it loads the numba cache; with an empty cache it compiles);
  `warm` is the best of `reps` further runs. --cold adds a run in a fresh
  process with an empty numba cache. Thesis: 700 s (2001 hardware); goal <= 10 s.
* ``rays`` - the same rays traced through the DCSG (an L-system prototype,
  compiled with geometry.compile_geometry, traced with raycast.trace_closest_batch,
  and the stand-alone dcsg_trace.trace_closest) and through the flattened primitives
  (Prototype(primitives=DCSG.flatten()), the two-level BVH), single-threaded,
  warm, best of `reps` interleaved. Rays start on a sphere around the object and
  aim at random points in the (1.5x enlarged) local boxes of random primitives.
  Agreement: both miss, or both hit with |t_dcsg - t_flat| <= 1e-9 |t_flat|.
  Goal: DCSG <= +30 % cost.
* ``scale`` - a grammar with >= 10^8 implicit primitives built as a DCSG in a fresh
  process and traced with 100 000 rays (aimed at points the graph draws): peak RSS
  (VmHWM; getrusage's max RSS, which bake/render.peak_rss_bytes reads, is kept too: in a
  child process it can be the parent's) against the RSS after imports, and what
  Cycles would need for its flattened instances (lsystem_stats.CYCLES_BYTES_PER_INSTANCE
  each; Cycles shows at most 6 nested instance levels).
* ``memory`` - DCSG bytes (DCSG.stats()["bytes"]: the graph plus its expansion cache,
  which Expansion Cache (MB) bounds; "graph_bytes" alone) against the flattened two-level
  BVH (Geometry.trace, the buffer the ray kernels read, plus the Geometry arrays
  outside it) at ~10^5 and ~10^6 primitives; --full-memory flattens the 10^6 one
  too, otherwise it is extrapolated per primitive from the 10^5 one (marked).
"""
import argparse
import json
import math
import os
import pathlib
import platform
import resource
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import photon_lightmaps.engine  # noqa: E402,F401  (sets the numba cache before numba loads)
import numba  # noqa: E402
import numpy as np  # noqa: E402

from photon_lightmaps.engine.geometry import dcsg  # noqa: E402
from photon_lightmaps.engine.geometry import dcsg_areas
from photon_lightmaps.engine.geometry import dcsg_trace
from photon_lightmaps.engine import demo_scenes  # noqa: E402
from photon_lightmaps.engine import lsystem_stats  # noqa: E402
from photon_lightmaps.engine.geometry import raycast  # noqa: E402
from photon_lightmaps.engine import session  # noqa: E402
from photon_lightmaps.engine.geometry.assembly import compile_geometry  # noqa: E402
from photon_lightmaps.engine.lsystem.presets import load_preset, preset_text  # noqa: E402
from photon_lightmaps.engine.geometry.primitives import KIND_IDS  # noqa: E402
from photon_lightmaps.engine.core.scene import (  # noqa: E402
    Instance, LSystem, Material, OrientationLightmap, Primitive, Prototype, Scene, SceneError)

HERE = pathlib.Path(__file__).resolve().parent
KIND_NAMES = {v: k for k, v in KIND_IDS.items()}

FULL = dict(size=640, photons=100_000, samples=1, area_samples=2000, reps=2,
            rays=200_000, ray_presets=[("sympodial_tree", None), ("sphereflake", 4), ("menger_sponge", 3)],
            scale=[("abop_1_24a", 2), ("abop_1_24a", 12), ("abop_1_24a", 13), ("menger_sponge", 6),
                   ("menger_sponge", 7)], scale_rays=100_000,
            memory=[("abop_1_24a", 7), ("abop_1_24a", 9)])
QUICK = dict(size=160, photons=20_000, samples=1, area_samples=2000, reps=1,
             rays=20_000, ray_presets=[("sympodial_tree", None), ("sphereflake", 4)],
             scale=[("abop_1_24a", 2), ("abop_1_24a", 12)], scale_rays=10_000,
             memory=[("abop_1_24a", 7), ("abop_1_24a", 9)])
THESIS_SECONDS = 700.0
GOAL_SECONDS = 10.0
GOAL_RAY_OVERHEAD = 0.30
RTOL = 1e-9
SECTIONS = ("e2e", "rays", "scale", "memory")


def getrusage_peak_bytes():
    """Peak resident memory as bake/render.peak_rss_bytes reads it (getrusage max RSS).
    On Linux a child keeps its parent's maximum across fork + exec, so in a worker
    process this can be the parent's peak."""
    r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(r) if sys.platform == "darwin" else int(r) * 1024


def _proc_status(key):
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def peak_rss_bytes():
    """Peak resident memory of this process: VmHWM, the high-water mark of this process's
    own address space (exec starts a new one), where /proc has it; else getrusage."""
    return _proc_status("VmHWM") or getrusage_peak_bytes()


def current_rss_bytes():
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except OSError:
        return 0


def log(*a):
    print(*a, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------- 1. end to end

def tree_scene(cfg):
    sc = demo_scenes.lsystem_studio(preset_text("sympodial_tree"), name="tree", width=cfg["size"],
                           height=cfg["size"])
    tree = len(sc.instances) - 1
    # one explicit OL over the tree: its stub OLs inherit its resolution and samples
    sc.orientation_lightmaps.append(OrientationLightmap("tree", instances=[tree],
                                                        samples=int(cfg["area_samples"])))
    return sc


def e2e_once(cfg):
    """One compile + photon pass + render of the sympodial tree -> dict of seconds and counts."""
    graph_area = [0.0, 0]
    orig = dcsg_areas.estimate_graph_areas

    def timed(*a, **k):                   # the graph part of area estimation, which the OL rows leave out
        t = time.perf_counter()
        try:
            return orig(*a, **k)
        finally:
            graph_area[0] += time.perf_counter() - t
            graph_area[1] += 1

    settings = session.Settings(photons=int(cfg["photons"]), samples=int(cfg["samples"]))
    t0 = time.perf_counter()
    sc = tree_scene(cfg)
    t1 = time.perf_counter()
    dcsg_areas.estimate_graph_areas = timed
    try:
        cs = session.compile(sc)
    finally:
        dcsg_areas.estimate_graph_areas = orig
    t2 = time.perf_counter()
    ps = session.render_photon_pass(cs, settings)
    t3 = time.perf_counter()
    img = session.render(cs, settings)
    t4 = time.perf_counter()
    rows = cs.info.get("orientation_lightmaps", [])
    return {"scene_build_s": t1 - t0, "compile_s": t2 - t1, "photon_pass_s": t3 - t2,
            "render_s": t4 - t3, "total_s": t4 - t1, "total_with_scene_s": t4 - t0,
            "compile_timings": {k: round(float(v), 4) for k, v in cs.timings.items()},
            "orientation_lightmaps": len(rows),
            "area_samples_per_ol": sorted({int(r["samples"]) for r in rows}),
            "ol_area_seconds_sum": float(sum(r.get("area_seconds", 0.0) for r in rows)),
            "graph_area_seconds": graph_area[0], "graph_area_calls": graph_area[1],
            "photons": int(ps.photons), "photon_rays": int(ps.rays),
            "image_mean": float(np.mean(img)), "image_finite": bool(np.all(np.isfinite(img)))}


def _round(d):
    return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in d.items()}


def cache_is_empty():
    p = pathlib.Path(os.environ.get("NUMBA_CACHE_DIR", ""))
    return not p.is_dir() or not any(p.rglob("*.nbi"))


def bench_e2e(cfg, cold):
    out = {"preset": "sympodial_tree", "width": cfg["size"], "height": cfg["size"],
           "photons": cfg["photons"], "samples_per_pixel": cfg["samples"],
           "area_samples_per_ol": cfg["area_samples"], "thesis_s": THESIS_SECONDS, "goal_s": GOAL_SECONDS}
    if cold:
        out["cold"] = cold_run(cfg)
    out["numba_cache_empty_at_start"] = cache_is_empty()
    log("e2e: first run in this process ...")
    out["first_in_process"] = _round(e2e_once(cfg))
    runs = []
    for r in range(cfg["reps"]):
        log(f"e2e: warm run {r + 1}/{cfg['reps']} ...")
        runs.append(e2e_once(cfg))
    best = min(runs, key=lambda x: x["total_s"])
    out["warm"] = _round(best)
    out["warm_totals_s"] = [round(x["total_s"], 3) for x in runs]
    out["speedup_over_thesis"] = round(THESIS_SECONDS / best["total_s"], 1)
    if cfg["samples"] == 1:
        log("e2e: warm run at 2 spp ...")
        out["warm_2spp"] = _round(e2e_once(dict(cfg, samples=2)))
    out["meets_goal"] = best["total_s"] <= GOAL_SECONDS
    return out


def cold_run(cfg):
    """The first run in a fresh process with an empty numba cache (everything compiles)."""
    log("e2e: cold run in a fresh process (empty numba cache; minutes) ...")
    with tempfile.TemporaryDirectory(prefix="nc_cold_") as d:
        env = dict(os.environ, NUMBA_CACHE_DIR=d)
        t = time.perf_counter()
        res = _worker(["e2e", json.dumps(cfg)], env)
        res["process_wall_s"] = round(time.perf_counter() - t, 3)
    return res


def _worker(args, env=None):
    p = subprocess.run([sys.executable, "-m", "benchmarks.bench_lsystem", "--worker", *args], cwd=ROOT,
                       env=env or dict(os.environ), capture_output=True, text=True)
    if p.returncode != 0:
        return {"error": (p.stderr or p.stdout).strip().splitlines()[-1:]}
    return json.loads(p.stdout.strip().splitlines()[-1])


# --------------------------------------------------------------------------- 2. ray cost

def flat_primitives(flat, material=0):
    return [Primitive(KIND_NAMES[int(k)], transform=xf, material=material, params=tuple(float(x) for x in p))
            for k, p, xf in zip(flat.kind, flat.params, flat.transform)]


def lsystem_scene(name, steps):
    sc = Scene(n_bands=1)
    sc.add_material(Material(diffuse=0.5))
    sc.prototypes.append(Prototype(name=name, lsystems=[LSystem(preset_text(name), name=name, steps=steps)]))
    sc.instances.append(Instance(0, name=name))
    return sc


def flat_scene(flat):
    sc = Scene(n_bands=1)
    sc.add_material(Material(diffuse=0.5))
    sc.prototypes.append(Prototype(name="flat", primitives=flat_primitives(flat)))
    sc.instances.append(Instance(0, name="flat"))
    return sc


def aimed_rays(targets, lo, hi, seed=1):
    """Origins uniform on a sphere around the box (1.5x its half diagonal), aimed at `targets`."""
    rng = np.random.default_rng(seed)
    n = targets.shape[0]
    c = 0.5 * (lo + hi)
    rad = 1.5 * 0.5 * float(np.linalg.norm(hi - lo))
    u = rng.normal(size=(n, 3))
    o = c + rad * u / np.linalg.norm(u, axis=1, keepdims=True)
    d = targets - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return np.ascontiguousarray(o), np.ascontiguousarray(d)


def targets_near(flat, n, seed=1):
    """Random points in random primitives' local boxes enlarged 1.5x, in object space."""
    rng = np.random.default_rng(seed + 17)
    k = rng.integers(0, flat.kind.shape[0], n)
    q = rng.uniform(-1.5, 1.5, (n, 3))
    xf = flat.transform[k]
    return np.einsum("nij,nj->ni", xf[:, :, :3], q) + xf[:, :, 3]


def best_interleaved(fns, reps):
    """{name: best wall seconds}, the functions run A, B, C, A, B, C, ... `reps` times."""
    best = {k: math.inf for k in fns}
    res = {}
    for _ in range(reps):
        for k, fn in fns.items():
            t = time.perf_counter()
            res[k] = fn()
            best[k] = min(best[k], time.perf_counter() - t)
    return best, res


def geometry_bytes(g):
    """Geometry.trace plus every Geometry array that is not a view into it."""
    extra = 0
    for name, a in g._asdict().items():
        if name == "trace" or not isinstance(a, np.ndarray):
            continue
        if not np.may_share_memory(a, g.trace):
            extra += a.nbytes
    return int(g.trace.nbytes), int(extra)


def bench_rays_one(name, steps, n_rays, reps):
    log(f"rays: {name} (steps {steps}) ...")
    graph = dcsg.DCSG(load_preset(name), steps)
    t = time.perf_counter()
    flat = graph.flatten()
    t_flat = time.perf_counter() - t
    t = time.perf_counter()
    gd, _ = compile_geometry(lsystem_scene(name, steps))
    t_cd = time.perf_counter() - t
    t = time.perf_counter()
    gf, _ = compile_geometry(flat_scene(flat))
    t_cf = time.perf_counter() - t
    lo, hi = graph.bounds()
    o, d = aimed_rays(targets_near(flat, n_rays), lo, hi)
    numba.set_num_threads(1)
    for fn in (lambda: raycast.trace_closest_batch(gd, o[:256], d[:256]),
               lambda: raycast.trace_closest_batch(gf, o[:256], d[:256]),
               lambda: dcsg_trace.trace_closest(graph, o[:256], d[:256])):
        fn()                                                    # warm (load / compile)
    best, res = best_interleaved({
        "dcsg_scene": lambda: raycast.trace_closest_batch(gd, o, d),
        "flat_bvh": lambda: raycast.trace_closest_batch(gf, o, d),
        "dcsg_standalone": lambda: dcsg_trace.trace_closest(graph, o, d)}, reps)
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    t_d, _, shape_d = res["dcsg_scene"]
    t_f, _, shape_f = res["flat_bvh"]
    t_s, p_s, h_s, _, _ = res["dcsg_standalone"]
    t_s = np.where(p_s >= 0, t_s, np.inf)

    def agree(a, b):
        both_miss = ~np.isfinite(a) & ~np.isfinite(b)
        both_hit = np.isfinite(a) & np.isfinite(b)
        close = np.zeros_like(both_hit)
        close[both_hit] = np.abs(a[both_hit] - b[both_hit]) <= RTOL * np.abs(b[both_hit])
        return both_miss | close

    ok_d = agree(t_d, t_f)
    ok_s = agree(t_s, t_f)
    # the address of the flattened primitive hit (shapes are in BVH leaf order: found by
    # their transform) against the graph's address
    hit_f = shape_f >= 0
    row = {flat.transform[i].tobytes(): i for i in range(flat.kind.shape[0])}
    addr_f = np.zeros(n_rays, np.uint64)
    xf = np.ascontiguousarray(gf.prim_xf, np.float64).reshape(-1, 3, 4)
    for i in np.flatnonzero(hit_f):
        k = row.get(xf[gf.shape_index[shape_f[i]]].tobytes())
        addr_f[i] = flat.address[k] if k is not None else 0
    both = hit_f & (p_s >= 0)
    out = {"preset": name, "steps": graph.steps, "primitives": graph.implicit_primitives,
           "dcsg_nodes": len(graph.nodes), "rays": int(n_rays), "threads": 1,
           "flatten_s": round(t_flat, 3), "compile_dcsg_s": round(t_cd, 3), "compile_flat_s": round(t_cf, 3),
           "hit_fraction": round(float(np.isfinite(t_f).mean()), 4)}
    for k, v in best.items():
        out[f"{k}_mrays_per_s"] = round(n_rays / v / 1e6, 4)
        out[f"{k}_s"] = round(v, 4)
    out["dcsg_scene_cost_over_flat"] = round(best["dcsg_scene"] / best["flat_bvh"], 3)
    out["dcsg_standalone_cost_over_flat"] = round(best["dcsg_standalone"] / best["flat_bvh"], 3)
    out["meets_goal"] = best["dcsg_scene"] / best["flat_bvh"] <= 1.0 + GOAL_RAY_OVERHEAD
    out["t_agreement_dcsg_scene"] = round(float(ok_d.mean()), 6)
    out["t_agreement_dcsg_standalone"] = round(float(ok_s.mean()), 6)
    out["t_disagreements"] = int((~ok_d).sum())
    out["hit_miss_mismatches"] = int((np.isfinite(t_d) != np.isfinite(t_f)).sum())
    fin = np.isfinite(t_d) & np.isfinite(t_f)
    out["t_max_rel_diff"] = float((np.abs(t_d[fin] - t_f[fin]) / t_f[fin]).max()) if fin.any() else 0.0
    out["address_agreement"] = round(float((h_s[both] == addr_f[both]).mean()), 6) if both.any() else None
    out["bytes_dcsg"] = graph.stats()["bytes"]
    out["expansion_cache"] = {k: v for k, v in graph.stats().items() if k.startswith("cache_")}
    tb, xb = geometry_bytes(gf)
    out["bytes_flat_trace"], out["bytes_flat_other_arrays"] = tb, xb
    return out


def bench_rays(cfg):
    return [bench_rays_one(n, s, cfg["rays"], max(cfg["reps"], 2) + 1) for n, s in cfg["ray_presets"]]


# --------------------------------------------------------------------------- 3. scale

def graph_points(graph, n, seed=3):
    """n points the graph draws: random descents (uniform child at each rule node) to a
    terminal, a random point in its primitive's local box, in object space."""
    rng = np.random.default_rng(seed)
    pts = np.empty((n, 3))
    for i in range(n):
        node, m = graph.root, np.eye(4)
        while node.prim is None:
            kids = node.alts[0][1]
            c, to_parent, _ = kids[rng.integers(len(kids))]
            m = m @ to_parent
            node = c
        xf = np.eye(4)
        xf[:3] = node.prim[2]
        q = np.append(rng.uniform(-1.0, 1.0, 3), 1.0)
        pts[i] = (m @ xf @ q)[:3]
    return pts


def scale_once(name, steps, n_rays):
    """In a fresh process: build the graph, trace n_rays through the scene path -> dict."""
    base = current_rss_bytes()
    base_peak = peak_rss_bytes()
    t = time.perf_counter()
    try:
        graph = dcsg.DCSG(load_preset(name), steps)
    except SceneError as exc:
        return {"preset": name, "steps": steps, "error": str(exc)}
    t_build = time.perf_counter() - t
    st = graph.stats()
    out = {"preset": name, "steps": steps, "primitives": st["primitives"], "dcsg_nodes": st["dcsg_nodes"],
           "depth": st["depth"], "dcsg_bytes": st["bytes"], "dcsg_graph_bytes": st["graph_bytes"],
           "build_s": round(t_build, 3)}
    pts = graph_points(graph, 2048)
    lo, hi = graph.bounds()
    rng = np.random.default_rng(5)
    tgt = pts[rng.integers(0, pts.shape[0], n_rays)]
    o, d = aimed_rays(tgt, lo, hi)
    try:
        t = time.perf_counter()
        g, _ = compile_geometry(lsystem_scene(name, steps))
        out["compile_s"] = round(time.perf_counter() - t, 3)
    except SceneError as exc:
        out["error"] = str(exc)
        out["peak_rss_bytes"] = peak_rss_bytes()
        out["getrusage_maxrss_bytes"] = getrusage_peak_bytes()
        return out
    raycast.trace_closest_batch(g, o[:64], d[:64])
    t = time.perf_counter()
    tt, _, shape = raycast.trace_closest_batch(g, o, d)
    out["trace_s"] = round(time.perf_counter() - t, 3)
    out["rays"] = int(n_rays)
    out["threads"] = numba.get_num_threads()
    out["mrays_per_s"] = round(n_rays / max(out["trace_s"], 1e-9) / 1e6, 4)
    out["hit_fraction"] = round(float((shape >= 0).mean()), 4)
    out["rss_after_imports_bytes"] = base
    out["peak_rss_after_imports_bytes"] = base_peak
    out["peak_rss_bytes"] = peak_rss_bytes()
    out["getrusage_maxrss_bytes"] = getrusage_peak_bytes()
    out["geometry_trace_bytes"] = int(g.trace.nbytes)
    return out


def bench_scale(cfg):
    rows = []
    for name, steps in cfg["scale"]:
        log(f"scale: {name} at {steps} steps (fresh process) ...")
        r = _worker(["scale", name, str(steps), str(cfg["scale_rays"])])
        n = r.get("primitives")
        if n:
            r["cycles_flattened_bytes"] = int(n * lsystem_stats.CYCLES_BYTES_PER_INSTANCE)
            r["cycles_bytes_per_instance"] = lsystem_stats.CYCLES_BYTES_PER_INSTANCE
            r["cycles_max_nesting"] = lsystem_stats.CYCLES_MAX_NESTING
            r["cycles_over_dcsg_bytes"] = round(r["cycles_flattened_bytes"] / r["dcsg_bytes"], 1)
            if r.get("peak_rss_bytes"):
                r["cycles_over_peak_rss"] = round(r["cycles_flattened_bytes"] / r["peak_rss_bytes"], 1)
        rows.append(r)
    # the first row is a tiny grammar through the same steps: the engine's own footprint
    base = rows[0].get("peak_rss_bytes") if rows else None
    for r in rows[1:]:
        if base and r.get("peak_rss_bytes"):
            r["peak_rss_over_tiny_grammar_bytes"] = r["peak_rss_bytes"] - base
    return rows


# --------------------------------------------------------------------------- 4. memory

def memory_one(name, steps, flatten=True, per_prim=None):
    graph = dcsg.DCSG(load_preset(name), steps)
    st = graph.stats()
    out = {"preset": name, "steps": steps, "primitives": st["primitives"], "dcsg_nodes": st["dcsg_nodes"],
           "dcsg_bytes": st["bytes"], "dcsg_graph_bytes": st["graph_bytes"],
           "dcsg_cache_bytes": st["bytes"] - st["graph_bytes"]}
    if not flatten:
        out["measured"] = False
        out["flat_bytes"] = int(round(per_prim * st["primitives"]))
        out["note"] = "flattened size extrapolated per primitive from the smaller grammar (not flattened)"
    else:
        log(f"memory: flattening {name} at {steps} steps ({st['primitives']:,} primitives) ...")
        t = time.perf_counter()
        flat = graph.flatten(limit=max(2_000_000, st["primitives"]))
        out["flatten_s"] = round(time.perf_counter() - t, 3)
        t = time.perf_counter()
        g, _ = compile_geometry(flat_scene(flat))
        out["compile_flat_s"] = round(time.perf_counter() - t, 3)
        tb, xb = geometry_bytes(g)
        out["measured"] = True
        out["flat_trace_bytes"], out["flat_other_array_bytes"] = tb, xb
        out["flat_bytes"] = tb + xb
        del g, flat
    out["flat_bytes_per_primitive"] = round(out["flat_bytes"] / st["primitives"], 1)
    out["flat_over_dcsg"] = round(out["flat_bytes"] / st["bytes"], 1)
    out["flat_over_dcsg_graph"] = round(out["flat_bytes"] / st["graph_bytes"], 1)
    out["cycles_flattened_bytes"] = int(st["primitives"] * lsystem_stats.CYCLES_BYTES_PER_INSTANCE)
    return out


def bench_memory(cfg, full):
    (n1, s1), (n2, s2) = cfg["memory"]
    small = memory_one(n1, s1)
    big = memory_one(n2, s2, flatten=full, per_prim=small["flat_bytes_per_primitive"])
    return [small, big]


# --------------------------------------------------------------------------- report

def table(report):
    lines = []
    e = report.get("e2e")
    if e:
        w = e["warm"]
        lines.append(f"sympodial tree {e['width']}x{e['height']}, {e['photons']:,} photons, "
                     f"{e['samples_per_pixel']} spp, {e['area_samples_per_ol']} area samples x "
                     f"{w['orientation_lightmaps']} OLs")
        lines.append(f"  warm: compile {w['compile_s']:.2f} s + photons {w['photon_pass_s']:.2f} s + render "
                     f"{w['render_s']:.2f} s = {w['total_s']:.2f} s (goal <= {GOAL_SECONDS:g} s, thesis "
                     f"{THESIS_SECONDS:g} s: x{e['speedup_over_thesis']})")
        if "warm_2spp" in e:
            w2 = e["warm_2spp"]
            lines.append(f"  warm at 2 spp: {w2['compile_s']:.2f} + {w2['photon_pass_s']:.2f} + "
                         f"{w2['render_s']:.2f} = {w2['total_s']:.2f} s")
        f = e["first_in_process"]
        lines.append(f"  first run in process: {f['total_s']:.2f} s (numba cache empty at start: "
                     f"{e['numba_cache_empty_at_start']})")
        if "cold" in e:
            c = e["cold"]
            lines.append(f"  cold (empty cache, fresh process): {c.get('total_s', float('nan')):.1f} s "
                         f"(process {c.get('process_wall_s', float('nan')):.1f} s)" if "total_s" in c
                         else f"  cold: {c}")
    for r in report.get("rays", []):
        lines.append(f"rays {r['preset']:>15} ({r['primitives']:,} prims, 1 thread): DCSG "
                     f"{r['dcsg_scene_mrays_per_s']:.3f} Mrays/s, flat BVH {r['flat_bvh_mrays_per_s']:.3f}: "
                     f"cost x{r['dcsg_scene_cost_over_flat']:.2f} (stand-alone x"
                     f"{r['dcsg_standalone_cost_over_flat']:.2f}); t agree {100 * r['t_agreement_dcsg_scene']:.3f} %"
                     f", hits {100 * r['hit_fraction']:.1f} %")
    for r in report.get("scale", []):
        if "trace_s" in r:
            lines.append(f"scale {r['preset']} n={r['steps']}: {r['primitives']:.3g} prims, DCSG "
                         f"{r['dcsg_bytes'] / 1e3:.1f} kB, {r['rays']:,} rays {r['trace_s']:.2f} s, peak RSS "
                         f"{r['peak_rss_bytes'] / 2**20:.0f} MiB (after imports {r['rss_after_imports_bytes'] / 2**20:.0f}"
                         f"), Cycles ~{r['cycles_flattened_bytes'] / 1e9:.3g} GB flattened; graph depth "
                         f"{r['depth']} (Cycles shows {r['cycles_max_nesting']} nested levels)")
        else:
            lines.append(f"scale {r.get('preset')} n={r.get('steps')}: {r.get('error')}")
    for r in report.get("memory", []):
        lines.append(f"memory {r['preset']} n={r['steps']}: {r['primitives']:,} prims, DCSG {r['dcsg_bytes']:,} B "
                     f"(graph {r['dcsg_graph_bytes']:,} + expansion cache {r['dcsg_cache_bytes']:,}), "
                     f"flat BVH {r['flat_bytes']:,} B ({'measured' if r['measured'] else 'extrapolated'}): "
                     f"x{r['flat_over_dcsg']:,} (graph alone x{r['flat_over_dcsg_graph']:,})")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--cold", action="store_true", help="also time a run with an empty numba cache")
    ap.add_argument("--full-memory", action="store_true", help="flatten the ~10^6 grammar too")
    ap.add_argument("--only", default=",".join(SECTIONS))
    ap.add_argument("--samples", type=int, default=None, help="camera samples per pixel (default 1)")
    ap.add_argument("--reps", type=int, default=None)
    ap.add_argument("--out", default=str(HERE / "out"))
    ap.add_argument("--worker", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        kind = a.worker[0]
        if kind == "e2e":
            res = _round(e2e_once(json.loads(a.worker[1])))
        else:
            res = scale_once(a.worker[1], int(a.worker[2]), int(a.worker[3]))
        print(json.dumps(res))
        return
    cfg = dict(QUICK if a.quick else FULL)
    if a.samples is not None:
        cfg["samples"] = a.samples
    if a.reps is not None:
        cfg["reps"] = a.reps
    only = set(a.only.split(","))
    t0 = time.perf_counter()
    report = {"machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                          "numba_threads": numba.config.NUMBA_NUM_THREADS, "numba": numba.__version__,
                          "load_avg_start": os.getloadavg()[0]},
              "config": {k: v for k, v in cfg.items()}, "quick": a.quick}
    if "e2e" in only:
        report["e2e"] = bench_e2e(cfg, a.cold)
    if "rays" in only:
        report["rays"] = bench_rays(cfg)
    if "scale" in only:
        report["scale"] = bench_scale(cfg)
    if "memory" in only:
        report["memory"] = bench_memory(cfg, a.full_memory)
    report["machine"]["load_avg_end"] = os.getloadavg()[0]
    report["seconds"] = round(time.perf_counter() - t0, 1)
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / ("lsystem_quick.json" if a.quick else "lsystem.json")
    if only != set(SECTIONS) and path.exists():
        # a subset refreshes its sections of the last report and keeps the others
        try:
            old = json.loads(path.read_text())
        except ValueError:
            old = {}
        for k in SECTIONS:
            if k not in only and k in old:
                report[k] = old[k]
        report["refreshed"] = sorted(only)
    path.write_text(json.dumps(report, indent=2))
    print(table(report))
    print(f"wrote {path} ({report['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
