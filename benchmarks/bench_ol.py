"""Orientation lightmaps (thesis ch. 6, 8) against per-object lightmaps, a photon map and Cycles.

Usage (from the repository root):
    .venv/bin/python -m benchmarks.bench_ol            # full run
    .venv/bin/python -m benchmarks.bench_ol --quick    # tiny knobs, cheap references
Options: --scenes torus,cube  --out DIR  --no-charts  --skip-120k

Per scene of ol_scenes.py (torus, sphereflake, Menger sponge, cube), one
process with one bpy: the scene is built in Blender for a Cycles reference
(two halves, cached like references.py) and as an engine Scene for our
two-pass renders (per-object lightmaps, one OL, and for the sphereflake a root
OL with nine first-generation child OLs). Our renders are swept over photon
count, Cycles over samples; every point is scored against the reference over
the whole image and over the object's pixels alone. Also measured: lightmap
memory (per-object lightmaps, OLs, a photon map holding the same hits), the
setup time (exact per-primitive texel areas against stochastic area
estimation) and area estimation on a 120 000-primitive group.

Writes OUT/ol_results.json and OUT/charts/ol_*.png (the full run also
refreshes benchmarks/charts/ol_*.png) and prints the headline ratios.
"""
import argparse
import hashlib
import json
import math
import os
import pathlib
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from numba import njit, prange  # noqa: E402

from photon_lightmaps.engine.lightmaps import lightmap  # noqa: E402
from photon_lightmaps.engine.lightmaps import orientation_lightmap  # noqa: E402
from photon_lightmaps.engine.core import scene  # noqa: E402
from photon_lightmaps.engine.lightmaps.area_estimation import estimate_areas  # noqa: E402
from photon_lightmaps.engine.compile import compile_scene  # noqa: E402
from photon_lightmaps.engine.geometry.assembly import compile_geometry  # noqa: E402
from photon_lightmaps.engine.transport.photon_tracer import trace_photons  # noqa: E402
from photon_lightmaps.engine.geometry.raycast import STACK_WORDS, intersect_closest  # noqa: E402
from photon_lightmaps.engine.transport.renderer import camera_ray  # noqa: E402
from photon_lightmaps.engine.transport.renderer import render as render_image  # noqa: E402
from photon_lightmaps.export import export_scene  # noqa: E402

from benchmarks import methods  # noqa: E402
from benchmarks import ol_scenes  # noqa: E402
from benchmarks import photon_map  # noqa: E402
from benchmarks.quiet import quiet  # noqa: E402
from benchmarks.run_all import Scorer  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
CACHE = HERE / "cache"
COMMITTED = HERE / "references"
RENDER_SPP = 16          # our camera samples (direct light, anti-aliasing)
MODE = lightmap.MODE_BILINEAR

FULL = dict(scenes=list(ol_scenes.SCENES), width=128, height=128, ref_spp=512,
            photons=[10_000, 30_000, 100_000, 300_000, 1_000_000, 3_000_000],
            cycles_spp=[1, 4, 16, 64], big_parts=120_000, big_samples=20_000, big_exact="subset",
            big_exact_parts=1_000, skip=[])
QUICK = dict(scenes=list(ol_scenes.SCENES), width=64, height=64, ref_spp=32,
             photons=[3_000, 30_000], cycles_spp=[1, 4], big_parts=120_000, big_samples=20_000,
             big_exact="subset", big_exact_parts=200, skip=[])
LABEL = {"lightmaps": "per-object lightmaps", "ol": "one orientation lightmap",
         "ol9": "root OL + 9 child OLs", "cycles": "Cycles render"}


# --------------------------------------------------------------------------------------
# Cycles reference
# --------------------------------------------------------------------------------------

def ref_key(sp, cfg):
    h = hashlib.sha256()
    h.update(repr((sp.name, sp.kind, tuple(sp.params), sorted(sp.light.items()), sorted(sp.camera.items()),
                   sp.width, sp.height, ol_scenes.SPHERE_SEGMENTS, ol_scenes.TORUS_SEGMENTS, ol_scenes.FLOOR_ALBEDO,
                   ol_scenes.OBJECT_ALBEDO, ol_scenes.FLOOR_HALF, bpy.app.version_string, methods.MAX_BOUNCES,
                   cfg["ref_spp"])).encode())
    h.update(np.round(sp.transforms, 6).tobytes())
    return f"ol_{sp.name}_{h.hexdigest()[:16]}"


def reference(sp, cfg, full, log):
    k = ref_key(sp, cfg)
    for folder, src in ((CACHE, "cache"), (COMMITTED, "committed")):
        p = folder / f"{k}.npz"
        if p.exists():
            with np.load(p) as z:
                return {a: z[a].astype(np.float32) for a in z.files}, f"{src}:{p.name}", 0.0
    log(f"  [{sp.name}] rendering the Cycles reference ({k}): 2 x {cfg['ref_spp']} spp")
    out, secs = {}, 0.0
    for half, seed in (("A", 1001), ("B", 2002)):
        with quiet():
            img, t = methods.cycles_render(cfg["ref_spp"], seed)
        secs += t
        log(f"    half {half}: {t:.1f} s")
        out[f"render_{half}"] = img
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(CACHE / f"{k}.npz", **out)
    if full:
        COMMITTED.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(COMMITTED / f"{k}.npz", **{a: b.astype(np.float16) for a, b in out.items()})
    return out, "regenerated", secs


def check_same_scene(engine_sc, log):
    """The Blender scene, exported, must have the engine scene's light and camera."""
    sc, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    a, b = sc.lights[0], engine_sc.lights[0]
    ok = (abs(a.power - b.power) < 1e-6 * b.power and np.allclose(a.transform, b.transform, atol=1e-5)
          and abs(a.size - b.size) < 1e-6 and np.allclose(sc.camera.transform, engine_sc.camera.transform,
                                                          atol=1e-5)
          and abs(sc.camera.fov - engine_sc.camera.fov) < 1e-6
          and len(sc.instances) == len(engine_sc.instances))
    if not ok:
        raise RuntimeError("the Blender scene and the engine scene differ (light, camera or instance count)")
    log(f"  Blender and engine scenes agree: {len(sc.instances)} instances, light and camera identical")


# --------------------------------------------------------------------------------------
# Object pixels
# --------------------------------------------------------------------------------------

@njit(cache=True, parallel=True)
def _coverage(g, cam, first, n_sub, out):
    """Fraction of n_sub x n_sub sub-pixel rays whose first hit is an instance >= first."""
    w = cam.width
    for p in prange(cam.width * cam.height):
        stack = np.empty(STACK_WORDS, np.int32)
        x, y = p % w, p // w
        c = 0
        for i in range(n_sub):
            for j in range(n_sub):
                ox, oy, oz, dx, dy, dz = camera_ray(cam, x + (i + 0.5) / n_sub, y + (j + 0.5) / n_sub)
                hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
                    g, stack, ox, oy, oz, dx, dy, dz, 0.0, math.inf)
                if hit and inst >= first:
                    c += 1
        out[y, x] = c / (n_sub * n_sub)


def object_mask(cs, first):
    cov = np.zeros((cs.camera.height, cs.camera.width))
    _coverage(cs.geometry, cs.camera, int(first), 4, cov)
    return cov >= 1.0


# --------------------------------------------------------------------------------------
# Memory helpers
# --------------------------------------------------------------------------------------

def _texel_arrays(lm):
    return (lm.area, lm.coverage, lm.flux, lm.flux_sq, lm.hits, lm.irradiance, lm.state, lm.split)


def lightmap_bytes_of(cs, lids):
    """Bytes of the texel arrays of the given lightmaps (as orientation_lightmap.report counts)."""
    lm = cs.lightmaps
    per_texel = sum(a.nbytes / max(a.shape[0], 1) for a in _texel_arrays(lm))
    n = sum(int(lm.width[l]) * int(lm.height[l]) for l in lids)
    return int(round(n * per_texel)), n


def object_lightmap_ids(cs, ids):
    return [l for i in ids for l in cs.instance_lightmaps[int(i)]]


# --------------------------------------------------------------------------------------
# One scene
# --------------------------------------------------------------------------------------

def compile_timed(sc):
    t0 = time.perf_counter()
    cs = compile_scene(sc)
    return cs, time.perf_counter() - t0


def run_one(cs, t_compile, photons, seed):
    """Photon pass and render on a compiled scene (its lightmaps cleared first).

    The scene is compiled once per method (the per-object lightmaps' exact setup
    takes tens of seconds on thousands of primitives); every point's time is
    that compile time plus its own photon pass and render."""
    cs.reset_lightmaps()
    t0 = time.perf_counter()
    stats = trace_photons(cs, photons, seed=seed, max_bounces=methods.MAX_BOUNCES, record_direct=False)
    t_trace = time.perf_counter() - t0
    img = render_image(cs, samples=RENDER_SPP, seed=seed, mode=MODE, max_depth=methods.MAX_BOUNCES)
    t_render = time.perf_counter() - t0 - t_trace
    return stats, img[..., :3], dict(seconds=t_compile + t_trace + t_render, compile=t_compile,
                                     trace=t_trace, render=t_render)


def run_scene(name, cfg, full, log):
    sp = ol_scenes.spec(name, cfg["width"], cfg["height"])
    t_build = time.perf_counter()
    ol_scenes.blender_scene(sp)
    t_build = time.perf_counter() - t_build
    scenes = {m: ol_scenes.engine_scene(sp, m) for m in ol_scenes.METHODS[name] if f"{name}:{m}" not in cfg["skip"]}
    ids = ol_scenes.engine_scene(sp, "lightmaps")[1]
    log(f"[{name}] {ids.size} {sp.kind} instances; Blender scene built in {t_build:.1f} s")
    check_same_scene(ol_scenes.engine_scene(sp, "lightmaps")[0], log)
    ref, src, ref_secs = reference(sp, cfg, full, log)
    log(f"  reference from {src}")
    points, images = [], {}

    # Warm-ups: kernels from the numba cache (on a one-instance copy, so the exact
    # setup of thousands of primitives is not paid twice), Cycles' kernels and sync.
    for m, (sc, _) in scenes.items():
        small = ol_scenes.engine_scene(ol_scenes.Spec(sp.name, sp.kind, sp.transforms[:10], sp.branch[:10], sp.generation[:10],
                                      sp.params, sp.light, sp.camera, 8, 8), "lightmaps" if m == "lightmaps"
                               else "ol")[0]
        run_one(compile_scene(small), 0.0, 1000, 0)
    with quiet():
        methods.cycles_render(1, 0)

    compiled = {}
    for m, (sc, _) in scenes.items():
        compiled[m] = compile_timed(sc)
        log(f"  compile_scene ({m}): {compiled[m][1]:.2f} s, lightmap setup "
            f"{compiled[m][0].timings['lightmap_setup']:.3f} s")
    cs0 = next(iter(compiled.values()))[0]
    mask = object_mask(cs0, int(ids[0]))
    mask3 = np.repeat(mask[..., None], 3, axis=-1)
    score_all = Scorer(ref["render_A"], ref["render_B"])
    score_obj = Scorer(ref["render_A"], ref["render_B"], mask) if mask.any() else score_all
    images["reference"] = 0.5 * (ref["render_A"] + ref["render_B"])
    images["mask"] = mask
    info = dict(scene=name, kind=sp.kind, instances=int(ids.size), object_pixels=int(mask.sum()),
                reference=src, reference_seconds=ref_secs, exact_area=ol_scenes.exact_area(sp),
                noise_floor_all=score_all.noise_floor(), noise_floor_object=score_obj.noise_floor())
    del mask3

    def add(method, knob_name, knob, seconds, img, **extra):
        a, o = score_all(img), score_obj(img)
        p = dict(scene=name, method=method, knob_name=knob_name, knob=knob, seconds=float(seconds),
                 rel_rmse=o["rel_rmse"], rel_rmse_raw=o["rel_rmse_raw"], mean_error=o["mean_error"],
                 rel_rmse_image=a["rel_rmse"], mean_error_image=a["mean_error"], **extra)
        points.append(p)
        log(f"  {method:10s} {knob_name}={knob:<10,} {seconds:7.2f} s  object relRMSE {o['rel_rmse']:.4f} "
            f"bias {o['mean_error']:+.4f} | image relRMSE {a['rel_rmse']:.4f}")
        return p

    setup = {}
    for m, (sc, _) in scenes.items():
        cs, t_compile = compiled[m]
        for n_ph in cfg["photons"]:
            stats, img, t = run_one(cs, t_compile, n_ph, 7)
            extra = dict(compile_seconds=t["compile"], trace_seconds=t["trace"], render_seconds=t["render"],
                         lightmap_setup_seconds=float(cs.timings["lightmap_setup"]),
                         lightmap_bytes_scene=int(cs.lightmap_bytes()))
            if m == "lightmaps":
                nb, nt = lightmap_bytes_of(cs, object_lightmap_ids(cs, ids))
                extra.update(memory_bytes=nb, texels=nt)
            else:
                rows = orientation_lightmap.report(cs)
                extra.update(memory_bytes=int(sum(r["memory_bytes"] for r in rows)),
                             texels=int(sum(r["bins"] for r in rows)),
                             ol_photons=int(rows[0]["photons"]),
                             area_seconds=float(sum(r["area_seconds"] for r in rows)))
            add(m, "photons", n_ph, t["seconds"], img, **extra)
            images.setdefault(m, {})[n_ph] = (t["seconds"], img)
        # setup and OL details from the last (largest) run
        if m == "lightmaps":
            setup[m] = dict(lightmap_setup_seconds=float(cs.timings["lightmap_setup"]),
                            geometry_seconds=float(cs.timings["geometry"]))
        else:
            rows = orientation_lightmap.report(cs)
            setup[m] = dict(lightmap_setup_seconds=float(cs.timings["lightmap_setup"]),
                            geometry_seconds=float(cs.timings["geometry"]),
                            area_seconds=float(sum(r["area_seconds"] for r in rows)))
            info.setdefault("ol_rows", {})[m] = [
                {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in r.items()
                 if k not in ("bin_rel_error", "flux")} for r in rows]
            for r in rows:
                for w in r.get("warnings", []):
                    log(f"  warning ({m}): {w}")
    info["setup"] = setup

    # A photon map holding the hits on the object, at the largest photon count
    # (same tracer, same seed: the photons one OL receives, kept as points).
    n_ph = max(cfg["photons"])
    # With one OL (one level) every hit on the object is recorded once, on the OL.
    cs = compiled["ol"][0]
    cs.reset_lightmaps()
    t0 = time.perf_counter()
    stats = trace_photons(cs, n_ph, seed=7, max_bounces=methods.MAX_BOUNCES, record_direct=False, keep_points=True)
    pts = np.asarray(stats.points)
    on_floor = (np.abs(pts[:, 2]) < 1e-6) & (pts[:, 5] > 0.9999)
    stats.points, stats.point_power = pts[~on_floor], np.asarray(stats.point_power)[~on_floor]
    pm = photon_map.build(stats)
    info["photon_map"] = dict(photons_traced=n_ph, stored_photons=pm.n_photons,
                              bytes_measured=pm.bytes_measured(), bytes_20B=pm.bytes_compact(),
                              seconds=time.perf_counter() - t0)
    log(f"  photon map of the object's hits at {n_ph:,} photons: {pm.n_photons:,} photons, "
        f"{pm.bytes_measured() / 1e6:.2f} MB measured, {pm.bytes_compact() / 1e6:.2f} MB at 20 B")
    del pm, stats, pts

    for spp in cfg["cycles_spp"]:
        with quiet():
            img, t = methods.cycles_render(spp, 11)
        add("cycles", "samples", spp, t, img)
        images.setdefault("cycles", {})[spp] = (t, img)
    return points, info, images


# --------------------------------------------------------------------------------------
# Area estimation on a 120k-primitive group
# --------------------------------------------------------------------------------------

def big_group(n, layout):
    """n small spheres in a jittered grid: as n instances of one sphere prototype
    ('instances') or as one instance of a prototype holding n spheres ('one_object')."""
    rng = np.random.default_rng(5)
    side = int(math.ceil(n ** (1 / 3)))
    g = np.stack(np.meshgrid(*(np.arange(side),) * 3, indexing="ij"), -1).reshape(-1, 3)[:n]
    c = (g + 0.5 + rng.uniform(-0.2, 0.2, g.shape)) * (4.0 / side)
    r = rng.uniform(0.2, 0.4, n) * (4.0 / side)
    sc = scene.Scene(n_bands=3, name=f"big_{layout}")
    mat = sc.add_material(scene.Material("m", diffuse=0.7))
    sc.lights.append(scene.Light("point", power=100.0, transform=scene.translate(2, 2, 8)))
    if layout == "instances":
        sc.prototypes.append(scene.Prototype("sphere", primitives=[scene.Primitive("sphere", material=mat)]))
        for i in range(n):
            xf = np.zeros((3, 4))
            xf[:, :3] = np.eye(3) * r[i]
            xf[:, 3] = c[i]
            sc.instances.append(scene.Instance(0, xf, name=f"s{i}"))
    else:
        prims = []
        for i in range(n):
            xf = np.zeros((3, 4))
            xf[:, :3] = np.eye(3) * r[i]
            xf[:, 3] = c[i]
            prims.append(scene.Primitive("sphere", transform=xf, material=mat))
        sc.prototypes.append(scene.Prototype("spheres", primitives=prims))
        sc.instances.append(scene.Instance(0, scene.identity(), name="spheres"))
    return sc, float((4 * math.pi * r * r).sum())


def area_estimation_study(cfg, log):
    n, s = cfg["big_parts"], cfg["big_samples"]
    out = {}
    for layout in ("instances", "one_object"):
        t0 = time.perf_counter()
        sc, exact = big_group(n, layout)
        g, _ = compile_geometry(sc)
        t_geo = time.perf_counter() - t0
        ids = np.arange(len(sc.instances))
        estimate_areas(g, ids, ol_scenes.OL_RESOLUTION, 1000, 0)      # warm (numba cache load)
        runs, runs_no_open = [], []
        for rep in range(3):
            e = estimate_areas(g, ids, ol_scenes.OL_RESOLUTION, s, rep)
            runs.append((e.seconds, e.total, e.total_rel_error, e.openness, e.parts))
            t1 = time.perf_counter()
            estimate_areas(g, ids, ol_scenes.OL_RESOLUTION, s, rep, openness_samples=0)
            runs_no_open.append(time.perf_counter() - t1)
        secs = [r[0] for r in runs]
        err = [abs(r[1] / exact - 1.0) for r in runs]
        row = dict(parts=int(runs[0][4]), samples=s, seconds_median=float(np.median(secs)),
                   seconds_min=float(min(secs)), seconds_no_openness_median=float(np.median(runs_no_open)),
                   total_exact=exact, total_estimates=[r[1] for r in runs],
                   total_abs_rel_error=err, total_rel_error_estimated=[r[2] for r in runs],
                   openness=runs[0][3], geometry_seconds=t_geo)
        log(f"  area estimation, {row['parts']:,} spheres ({layout}), {s:,} samples: "
            f"{row['seconds_median']:.3f} s median ({row['seconds_no_openness_median']:.3f} s without the "
            f"openness rays); total area error {np.mean(err) * 100:.2f} % "
            f"(estimated {np.mean(row['total_rel_error_estimated']) * 100:.2f} %)")
        out[layout] = row
    # Setup of a whole scene: one OL over all n, and exact per-primitive texel
    # areas, which cost the same for every sphere (a Python loop over instances):
    # measured on the first n_exact spheres and scaled by n / n_exact.
    sc, _ = big_group(n, "instances")
    sc.orientation_lightmaps.append(scene.OrientationLightmap("big", instances=list(range(n)),
                                                          resolution=ol_scenes.OL_RESOLUTION, samples=s))
    cs = compile_scene(sc)
    t_ol = float(cs.timings["lightmap_setup"])
    n_exact = n if cfg["big_exact"] == "all" else min(n, cfg["big_exact_parts"])
    sc = scene.Scene(n_bands=3, materials=sc.materials, prototypes=sc.prototypes,
                  instances=sc.instances[:n_exact], lights=sc.lights)
    cs = compile_scene(sc)
    t_exact = float(cs.timings["lightmap_setup"]) * n / n_exact
    out["setup"] = dict(exact_lightmap_setup_seconds=t_exact, exact_measured_parts=n_exact,
                        exact_extrapolated=n_exact < n, ol_lightmap_setup_seconds=t_ol,
                        texels_exact_measured=int(cs.lightmaps.area.shape[0]))
    log(f"  {n:,} instances, compile_scene lightmap setup: one OL {t_ol:.2f} s; exact per-primitive "
        f"{t_exact:.1f} s{f' (measured on {n_exact:,}, scaled)' if n_exact < n else ''} -> {t_ol / t_exact:.5f}")
    return out


# --------------------------------------------------------------------------------------
# Headlines
# --------------------------------------------------------------------------------------

def err_at_time(curve, t):
    """Error of a (seconds, error) curve at time t, piecewise log-log; None outside its range."""
    xs = np.log([p["seconds"] for p in curve])
    ys = np.log([max(p["rel_rmse"], 1e-6) for p in curve])
    order = np.argsort(xs)
    xs, ys = xs[order], ys[order]
    lt = math.log(t)
    if lt < xs[0] or lt > xs[-1]:
        return None
    return float(math.exp(np.interp(lt, xs, ys)))


def headlines(points, infos, area):
    h = {}
    for info in infos:
        sc = info["scene"]
        P = [p for p in points if p["scene"] == sc]
        cur = {m: sorted((p for p in P if p["method"] == m), key=lambda p: p["knob"])
               for m in {p["method"] for p in P}}
        lm = cur["lightmaps"][-1] if "lightmaps" in cur else dict(memory_bytes=math.nan, texels=None)
        lm_setup = info["setup"].get("lightmaps", {}).get("lightmap_setup_seconds", math.nan)
        row = dict(lightmaps_bytes=lm["memory_bytes"], lightmaps_texels=lm["texels"],
                   photon_map_bytes_measured=info["photon_map"]["bytes_measured"],
                   photon_map_bytes_20B=info["photon_map"]["bytes_20B"],
                   photon_map_photons=info["photon_map"]["stored_photons"],
                   exact_setup_seconds=lm_setup)
        for m in ("ol", "ol9"):
            if m not in cur:
                continue
            c = cur[m]
            top = c[-1]
            r = dict(bytes=top["memory_bytes"], texels=top["texels"],
                     memory_vs_lightmaps=top["memory_bytes"] / lm["memory_bytes"],
                     memory_vs_photon_map_measured=top["memory_bytes"] / info["photon_map"]["bytes_measured"],
                     memory_vs_photon_map_20B=top["memory_bytes"] / info["photon_map"]["bytes_20B"],
                     setup_seconds=info["setup"][m]["lightmap_setup_seconds"],
                     area_seconds=info["setup"][m]["area_seconds"],
                     setup_vs_exact=info["setup"][m]["lightmap_setup_seconds"] / max(lm_setup, 1e-9),
                     warnings=[w for rr in info["ol_rows"][m] for w in rr["warnings"]])
            eq = []
            for p in c:
                e_lm = err_at_time(cur["lightmaps"], p["seconds"]) if "lightmaps" in cur else None
                eq.append(dict(photons=p["knob"], seconds=p["seconds"], ol_rel_rmse=p["rel_rmse"],
                               lightmaps_rel_rmse_at_same_time=e_lm,
                               ratio_lightmaps_over_ol=(e_lm / max(p["rel_rmse"], 1e-6)) if e_lm else None))
            r["error_at_equal_time"] = eq
            r["best_rel_rmse"] = min(p["rel_rmse"] for p in c)
            row[m] = r
        row["lightmaps_best_rel_rmse"] = min((p["rel_rmse"] for p in cur.get("lightmaps", [])), default=None)
        if "cycles" in cur:
            row["cycles_best_rel_rmse"] = min(p["rel_rmse"] for p in cur["cycles"])
        h[sc] = row
    if area:
        h["area_estimation_120k"] = {k: dict(seconds=v["seconds_median"], parts=v["parts"],
                                             total_abs_rel_error=float(np.mean(v["total_abs_rel_error"])))
                                     for k, v in area.items() if k != "setup"}
        if "setup" in area:
            s = area["setup"]
            h["area_estimation_120k"]["setup_ratio"] = s["ol_lightmap_setup_seconds"] / s["exact_lightmap_setup_seconds"]
            h["area_estimation_120k"]["setup"] = s
    return h


def print_headlines(h, log):
    log("\n=== Orientation lightmaps: headline ratios ===")
    for sc, v in h.items():
        if sc == "area_estimation_120k":
            for k, r in v.items():
                if isinstance(r, dict) and "seconds" in r:
                    log(f"[120k] area estimation ({k}): {r['seconds']:.3f} s for {r['parts']:,} parts "
                        f"(goal <= 1 s; thesis 180 s), total area off by {r['total_abs_rel_error'] * 100:.2f} %")
            if "setup_ratio" in v:
                s = v["setup"]
                log(f"[120k] lightmap setup: OL {s['ol_lightmap_setup_seconds']:.2f} s vs exact "
                    f"{s['exact_lightmap_setup_seconds']:.2f} s -> {v['setup_ratio']:.4f} (thesis 5/600 = 0.0083)")
            continue
        for m in ("ol", "ol9"):
            if m not in v:
                continue
            r = v[m]
            e = r["error_at_equal_time"][-1]
            eq = (f"lightmaps at the same {e['seconds']:.1f} s: {e['lightmaps_rel_rmse_at_same_time']:.4f}"
                  if e["lightmaps_rel_rmse_at_same_time"] else "lightmaps: not measured at that time")
            log(f"[{sc}] {m}: memory {r['bytes'] / 1e3:.1f} kB = {r['memory_vs_lightmaps'] * 100:.2f} % of "
                f"per-object lightmaps ({v['lightmaps_bytes'] / 1e6:.2f} MB), "
                f"{r['memory_vs_photon_map_measured'] * 100:.3f} % of the photon map "
                f"({v['photon_map_bytes_measured'] / 1e6:.1f} MB; {r['memory_vs_photon_map_20B'] * 100:.3f} % at 20 B/photon); "
                f"setup {r['setup_seconds']:.3f} s vs exact {v['exact_setup_seconds']:.3f} s "
                f"({r['setup_vs_exact']:.3f}); error {e['ol_rel_rmse']:.4f} at {e['photons']:,} photons, {eq}")



# --------------------------------------------------------------------------------------
# Charts (matplotlib, Agg; like charts.py)
# --------------------------------------------------------------------------------------

STYLE = {"lightmaps": dict(color="C0", marker="o"), "ol": dict(color="C1", marker="D"),
         "ol9": dict(color="C2", marker="s"), "cycles": dict(color="C3", marker="^")}


def _knob_label(p):
    k = p["knob"]
    if p["knob_name"] == "samples":
        return f"{k} spp"
    return f"{k / 1e6:g}M" if k >= 1e6 else f"{k / 1e3:g}k"


def make_charts(result, images, out):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    from benchmarks.charts import _save, _srgb

    out = pathlib.Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    pts = result["points"]
    infos = result["scenes"]

    # 1. error against time, object pixels (solid) and whole image (dotted)
    n = len(infos)
    cols = min(n, 2)
    rows = int(math.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5.2 * cols, 3.9 * rows), squeeze=False)
    for ax, info in zip(axes.flat, infos):
        sc = info["scene"]
        for m in ("lightmaps", "ol", "ol9", "cycles"):
            c = sorted((p for p in pts if p["scene"] == sc and p["method"] == m), key=lambda p: p["knob"])
            if not c:
                continue
            xs = [p["seconds"] for p in c]
            ax.loglog(xs, [max(p["rel_rmse"], 1e-4) for p in c], label=LABEL[m], **STYLE[m])
            ax.loglog(xs, [max(p["rel_rmse_image"], 1e-4) for p in c], ls=":", lw=1, color=STYLE[m]["color"])
            for p in (c[0], c[-1]):
                ax.annotate(_knob_label(p), (p["seconds"], max(p["rel_rmse"], 1e-4)), fontsize=6,
                            textcoords="offset points", xytext=(3, 3))
        ax.axhline(info["noise_floor_object"], color="0.6", ls="--", lw=0.8, label="reference noise (removed)")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("wall-clock seconds (compile + photons + render; 2 cores)", fontsize=8)
        ax.set_ylabel("relative RMSE vs Cycles", fontsize=8)
        ax.set_title(f"{sc} ({info['instances']:,} {info['kind']}{'s' if info['instances'] > 1 else ''}): "
                     "object pixels (solid), whole image (dotted)", fontsize=8)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.tight_layout()
    _save(fig, out / "ol_error_vs_time.png", files)

    # 2. memory and setup time
    h = result["headlines"]
    scenes = [i["scene"] for i in infos]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4))
    bars = [("per-object lightmaps", lambda v: v["lightmaps_bytes"], "C0"),
            ("one OL", lambda v: v.get("ol", {}).get("bytes"), "C1"),
            ("root + 9 child OLs", lambda v: v.get("ol9", {}).get("bytes"), "C2"),
            ("photon map, same hits, measured", lambda v: v["photon_map_bytes_measured"], "C4"),
            ("photon map, same hits, 20 B/photon", lambda v: v["photon_map_bytes_20B"], "C5")]
    w = 0.8 / len(bars)
    for j, (lab, f, col) in enumerate(bars):
        xs, ys = [], []
        for i, sc in enumerate(scenes):
            y = f(h[sc])
            if y:
                xs.append(i + (j - len(bars) / 2 + 0.5) * w)
                ys.append(y)
        a1.bar(xs, ys, w, label=lab, color=col)
    a1.set_yscale("log")
    a1.set_xticks(range(len(scenes)), scenes)
    a1.set_ylabel("bytes (engine texel arrays)")
    a1.set_title(f"memory of the object's stored light (photon map at {max(result['config']['photons']):,} "
                 "photons)", fontsize=9)
    a1.legend(fontsize=6)
    a1.grid(True, axis="y", which="both", alpha=0.3)
    labels, exact, olt = list(scenes), [h[sc]["exact_setup_seconds"] for sc in scenes], \
        [h[sc].get("ol", {}).get("setup_seconds", np.nan) for sc in scenes]
    ae = h.get("area_estimation_120k", {})
    if "setup" in ae:
        labels.append("120k spheres")
        exact.append(ae["setup"]["exact_lightmap_setup_seconds"])
        olt.append(ae["setup"]["ol_lightmap_setup_seconds"])
    x = np.arange(len(labels))
    a2.bar(x - 0.2, exact, 0.4, label="exact per-primitive texel areas", color="C0")
    a2.bar(x + 0.2, olt, 0.4, label="one OL: stochastic area estimation (20 000 samples)", color="C1")
    for k, v in ae.items():
        if isinstance(v, dict) and "seconds" in v:
            a2.axhline(v["seconds"], color="C1" if k == "instances" else "C2", ls=":", lw=1,
                       label=f"area estimation alone, 120k spheres ({k.replace('_', ' ')})")
    a2.axhline(1.0, color="k", ls="--", lw=0.8, label="goal: 1 s")
    a2.set_yscale("log")
    a2.set_xticks(x, labels)
    a2.set_ylabel("seconds (compile_scene lightmap setup)")
    a2.set_title("lightmap setup time", fontsize=9)
    a2.legend(fontsize=6)
    a2.grid(True, axis="y", which="both", alpha=0.3)
    fig.tight_layout()
    _save(fig, out / "ol_memory_setup.png", files)

    # 3. images: reference, renders at the largest photon count, |error| maps
    meths = ["lightmaps", "ol", "ol9"]
    fig, axes = plt.subplots(n, 1 + 2 * len(meths), figsize=(2.0 * (1 + 2 * len(meths)), 2.1 * n),
                             squeeze=False)
    for r, info in enumerate(infos):
        sc = info["scene"]
        im = images[sc]
        ref = im["reference"]
        scale = max(np.percentile(ref, 99), 1e-9)
        tiles = [(f"{sc}: Cycles reference", _srgb(ref / scale), None)]
        for m in meths:
            if m not in im:
                continue
            nph = max(im[m])
            t, img = im[m][nph]
            tiles.append((f"{m}, {nph / 1e6:g}M photons, {t:.1f} s", _srgb(img / scale), None))
        for m in meths:
            if m not in im:
                continue
            img = im[m][max(im[m])][1]
            e = np.abs(img - ref).mean(-1) / max(ref[im["mask"]].mean() if im["mask"].any() else ref.mean(), 1e-9)
            tiles.append((f"|error| {m}", e, "err"))
        for c, ax in enumerate(axes[r]):
            ax.axis("off")
            if c < len(tiles):
                title, a, kind = tiles[c]
                if kind:
                    ax.imshow(a, cmap="magma", vmin=0, vmax=0.5, interpolation="nearest")
                else:
                    ax.imshow(a, interpolation="nearest")
                ax.set_title(title, fontsize=6)
    fig.suptitle("renders at the largest photon count (|error| / object mean, scale 0..0.5)", fontsize=8)
    fig.tight_layout()
    _save(fig, out / "ol_images.png", files, dpi=64)
    return files

# --------------------------------------------------------------------------------------

def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny knobs and cheap references")
    ap.add_argument("--scenes", default=None, help="comma-separated subset of " + ",".join(ol_scenes.SCENES))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out"))
    ap.add_argument("--no-charts", action="store_true")
    ap.add_argument("--skip-120k", action="store_true", help="skip the 120k-primitive area estimation")
    args = ap.parse_args(argv)
    cfg = dict(QUICK if args.quick else FULL)
    if args.scenes:
        cfg["scenes"] = [s.strip() for s in args.scenes.split(",") if s.strip()]
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def log(msg):
        print(msg, flush=True)

    t0 = time.perf_counter()
    points, infos, images = [], [], {}
    for name in cfg["scenes"]:
        p, info, im = run_scene(name, cfg, not args.quick, log)
        points += p
        infos.append(info)
        images[name] = im
    area = None
    if not args.skip_120k:
        log("[120k] area estimation on a 120 000-primitive group")
        area = area_estimation_study(cfg, log)
    h = headlines(points, infos, area)
    result = dict(quick=bool(args.quick), config=cfg, render_spp=RENDER_SPP, lookup="bilinear",
                  ol_resolution=ol_scenes.OL_RESOLUTION, ol_samples=ol_scenes.OL_SAMPLES, blender=bpy.app.version_string,
                  scenes=infos, points=points, area_estimation=area, headlines=h, seconds_total=None)
    print_headlines(h, log)
    if not args.no_charts:
        files = make_charts(result, images, out / "charts")
        if not args.quick and not args.scenes:
            files += make_charts(result, images, ROOT / "benchmarks" / "charts")
        log("charts: " + ", ".join(sorted({pathlib.Path(f).name for f in files})))
    result["seconds_total"] = time.perf_counter() - t0
    with open(out / "ol_results.json", "w") as f:
        json.dump(result, f, indent=1, default=float)
    log(f"wrote {out / 'ol_results.json'} ({len(points)} points) in {result['seconds_total']:.0f} s")
    return result


if __name__ == "__main__":
    main()
