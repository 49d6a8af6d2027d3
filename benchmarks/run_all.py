"""Speed against accuracy: photon lightmaps, a photon map and Cycles on the same scenes.

Usage (from the repository root):
    .venv/bin/python -m benchmarks.run_all            # full run (about 15 minutes on 2 cores)
    .venv/bin/python -m benchmarks.run_all --quick    # tiny knobs, cornell only (about a minute)
Options: --scenes cornell,window  --out DIR  --charts DIR  --no-charts
         --csg (then also benchmarks/bench_csg.py: exact CSG, its own JSON and charts)
With pyluxcore installed (benchmarks/requirements.txt), also luxcore_path and
luxcore_photongi: LuxCore's path tracer without and with its PhotonGI cache
(luxcore_peer.py), renders scored like Cycles'.
With pyoidn installed, also ours_bake_oidn and ours_render_gather_oidn: the
same runs denoised (engine/transport/denoise.py), scored the same way, so a denoiser's
bias shows as an error floor and in mean_error.

Writes DIR/results.json (every measured point) and PNG charts, and prints the
headline ratios. Errors are scored against converged Cycles references
(references.py): baked lightmaps texel by texel on the Lightmap UV layer,
renders pixel by pixel.
"""
import argparse
import json
import math
import os
import pathlib
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import photon_lightmaps  # noqa: E402
from photon_lightmaps import registration  # noqa: E402
from photon_lightmaps.engine.transport import denoise  # noqa: E402
from photon_lightmaps.engine.lightmaps import lightmap  # noqa: E402
from photon_lightmaps.engine.compile import compile_scene  # noqa: E402
from photon_lightmaps.engine.session import Settings  # noqa: E402
from photon_lightmaps.engine.transport.photon_tracer import trace_photons  # noqa: E402

from benchmarks import luxcore_peer  # noqa: E402
from benchmarks import methods  # noqa: E402
from benchmarks import photon_map  # noqa: E402
from benchmarks import references  # noqa: E402
from benchmarks import scenes  # noqa: E402
from benchmarks.quiet import quiet  # noqa: E402

# Our default bakes: the add-on's default photon counts (a lookup bake traces
# Photons, a gathered one Bake Photons), and 32 texels per side (16 texels/m, the
# default density, on the 2 m walls).
DEFAULT_PHOTONS = Settings().photons
DEFAULT_BAKE_PHOTONS = Settings().bake_photons
DEFAULT_RES = 32
RENDER_SPP = 16       # our camera samples: direct light and anti-aliasing only
# The *_oidn curves (the same bakes and renders plus OIDN, its time added) need pyoidn.
OIDN = denoise.available()
# The luxcore_* render curves need pyluxcore (benchmarks/requirements.txt).
LUXCORE = luxcore_peer.available()


def pm_k(n_photons):
    """Neighbours per photon-map estimate, 50..200, growing like sqrt(N).

    At a fixed k the estimate's relative noise stays near 1/sqrt(k) whatever N is
    (more photons only shrink the disc), so k must grow with N for the error to fall.
    """
    return int(np.clip(round(0.2 * math.sqrt(n_photons)), 50, 200))

FULL = dict(
    scenes=list(scenes.SCENES), ref=references.FULL, width=128, height=128,
    bake_photons=[10_000, 30_000, 100_000, 300_000, 1_000_000, 3_000_000, 10_000_000],
    render_photons=[10_000, 100_000, 1_000_000, 3_000_000],
    # (photons, camera samples, gather rays per sample) of the final-gather renders
    render_gather=[(10_000, 4, 4), (100_000, 16, 4), (300_000, 64, 4), (1_000_000, 256, 4)],
    pm_photons=[10_000, 30_000, 100_000, 300_000, 1_000_000, 3_000_000],
    cycles_bake_spp=[1, 4, 16, 64, 256, 1024],
    # Cycles baked at 8x the resolution and averaged down (texel means, as the
    # reference): the same samples per texel as 64..4096 spp at the texel resolution
    cycles_bake_ss=8, cycles_bake_ss_spp=[1, 4, 16, 64],
    cycles_render_spp=[1, 4, 16, 64, 256],
    # LuxCore PATHCPU over spp, and with PhotonGI over spp on one cache: LuxCore
    # traces cache photons in steps of 2M (a smaller photon.maxcount still traces
    # 2M, about 6 s on cornell), so the cache's cost is fixed and spp is the knob.
    luxcore_path_spp=[4, 16, 64, 256],
    luxcore_photongi=[(2_000_000, 4), (2_000_000, 16), (2_000_000, 64), (2_000_000, 256)],
    fine_res=[16, 32, 64, 128], fine_photons=4_000_000,
)
QUICK = dict(
    scenes=["cornell"], ref=references.QUICK, width=64, height=64,
    bake_photons=[3_000, 30_000, 300_000],
    render_photons=[3_000, 100_000],
    render_gather=[(3_000, 4, 4), (100_000, 16, 4)],
    pm_photons=[3_000, 30_000, 300_000],
    cycles_bake_spp=[1, 4, 32],
    cycles_bake_ss=2, cycles_bake_ss_spp=[1, 8],
    cycles_render_spp=[1, 8],
    luxcore_path_spp=[4, 16],
    luxcore_photongi=[(2_000_000, 4)],
    fine_res=[16, 32], fine_photons=300_000,
)


# --------------------------------------------------------------------------------------
# Scoring
# --------------------------------------------------------------------------------------

class Scorer:
    """Relative RMSE and mean error of an estimate against a two-half reference.

    rel_rmse = sqrt(max(mse - var_ref, 0)) / mean(ref): the estimate's own error,
    with the reference's noise (from its halves) taken out; rel_rmse_raw keeps it.
    """

    def __init__(self, A, B, mask=None):
        A, B = np.asarray(A, np.float64), np.asarray(B, np.float64)
        self.mask = np.ones(A.shape[:-1], bool) if mask is None else mask
        a, b = A[self.mask], B[self.mask]
        self.full = 0.5 * (A + B)
        self.ref = 0.5 * (a + b)
        self.var_ref = float(np.mean((a - b) ** 2) / 4.0)
        self.mean = float(self.ref.mean())

    def noise_floor(self):
        return math.sqrt(self.var_ref) / self.mean

    def __call__(self, x):
        x = np.asarray(x, np.float64)
        d = x[self.mask] - self.ref
        mse = float(np.mean(d * d))
        out = dict(rel_rmse=math.sqrt(max(mse - self.var_ref, 0.0)) / self.mean,
                   rel_rmse_raw=math.sqrt(mse) / self.mean,
                   mean_error=float(d.mean()) / self.mean)
        if self.mask.ndim == 3:
            # baked maps, one per object: the worst object's mean against the reference's
            errs = [float(x[i][m].mean() / r[m].mean() - 1.0) for i, (m, r) in enumerate(zip(self.mask, self.full))
                    if m.any() and r[m].mean() > 0.0]
            out["worst_object_error"] = max(errs, key=abs) if errs else 0.0
        return out


def stack_maps(maps, names):
    return np.stack([np.asarray(maps[n])[..., :3] for n in names])


# --------------------------------------------------------------------------------------
# One scene
# --------------------------------------------------------------------------------------

def run_scene(name, cfg, log):
    scenes.build(name, cfg["width"], cfg["height"])
    objs = scenes.mesh_objects()
    names = [o.name for o in objs]
    res = DEFAULT_RES
    ref, src = references.load_or_make(name, cfg["ref"], log)
    log(f"[{name}] {len(objs)} objects, reference from {src}")
    points = []

    def add(kind, method, knob_name, knob, seconds, score, memory=None, **extra):
        p = dict(scene=name, kind=kind, method=method, knob_name=knob_name, knob=knob,
                 seconds=float(seconds), memory_bytes=memory, **score, **extra)
        points.append(p)
        log(f"  {kind:6s} {method:22s} {knob_name}={knob:<10,} {seconds:7.2f} s  "
            f"relRMSE {score['rel_rmse']:.4f} (raw {score['rel_rmse_raw']:.4f})  bias {score['mean_error']:+.4f}")

    # Warm-ups: numba kernels from the cache, Cycles' kernels and scene sync.
    methods.ours_bake(objs, 1000, 0, res)
    methods.ours_bake(objs, 1000, 0, res, indirect="GATHER")
    methods.ours_bake(objs, 1000, 0, res, indirect="GATHER", irradiance_cache=True)
    methods.ours_render(1000, 1, 0)
    methods.ours_render_gather(1000, 1, 0, denoise=OIDN)
    with quiet():
        methods.cycles_bake(objs, 8, 1, 0)
        methods.cycles_render(1, 0)

    # Scored texels: centre inside a UV triangle and fully covered texel (at chart
    # borders our texels average partly-outside area, and Cycles samples the centre).
    geo = {o.name: methods.texel_points(o, res) for o in objs}
    maps0, _, _, _, _ = methods.ours_bake(objs, 1000, 0, res)
    mask = np.stack([geo[n][2] & (maps0[n][..., 3] >= 0.999) for n in names])
    ref_A = stack_maps({n: ref[f"bake_A/{n}"] for n in names}, names)
    ref_B = stack_maps({n: ref[f"bake_B/{n}"] for n in names}, names)
    bake_score = Scorer(ref_A, ref_B, mask)
    render_score = Scorer(ref["render_A"], ref["render_B"])
    n_texels = int(mask.sum())
    info = dict(scene=name, objects=names, scored_texels=n_texels, reference=src,
                bake_noise_floor=bake_score.noise_floor(), render_noise_floor=render_score.noise_floor())
    images = dict(ref_bake=0.5 * (ref_A + ref_B), mask=mask, names=names,
                  ref_render=0.5 * (ref["render_A"] + ref["render_B"]))

    # Photon lightmaps, baked (constant and bilinear coincide at texel centres).
    for n_ph in cfg["bake_photons"]:
        maps, t, nbytes, stats, job = methods.ours_bake(objs, n_ph, 7, res)
        x = stack_maps(maps, names)
        add("bake", "ours_bake", "photons", n_ph, t, bake_score(x), nbytes,
            memory_compact_bytes=12 * len(names) * res * res,
            photons_per_texel=stats.records / max(len(names) * res * res, 1))
        if OIDN:
            dmaps, t_dn = methods.oidn_bake(job)
            add("bake", "ours_bake_oidn", "photons", n_ph, t + t_dn, bake_score(stack_maps(dmaps, names)),
                nbytes, memory_compact_bytes=12 * len(names) * res * res, seconds_denoise=t_dn)
        gmaps, t_g, nbytes_g, _, gjob = methods.ours_bake(objs, n_ph, 7, res, indirect="GATHER")
        add("bake", "ours_bake_gather", "photons", n_ph, t_g, bake_score(stack_maps(gmaps, names)), nbytes_g,
            memory_compact_bytes=12 * len(names) * res * res, gather_rays_per_texel=256)
        cmaps, t_c, nbytes_c, _, cjob = methods.ours_bake(objs, n_ph, 7, res, indirect="GATHER", irradiance_cache=True)
        add("bake", "ours_bake_cache", "photons", n_ph, t_c, bake_score(stack_maps(cmaps, names)), nbytes_c,
            memory_compact_bytes=12 * len(names) * res * res, gather_rays_per_record=256,
            irradiance_cache=cjob.result.irradiance_cache)
        if OIDN:
            dmaps, t_dn = methods.oidn_bake(gjob)
            add("bake", "ours_bake_gather_oidn", "photons", n_ph, t_g + t_dn,
                bake_score(stack_maps(dmaps, names)), nbytes_g, memory_compact_bytes=12 * len(names) * res * res,
                gather_rays_per_texel=256, seconds_denoise=t_dn)
        if n_ph == min(cfg["bake_photons"]):
            images["ours_low"] = (n_ph, x)
        if n_ph == DEFAULT_PHOTONS or (n_ph == cfg["bake_photons"][-1] and "ours_default" not in images):
            images["ours_default"] = (n_ph, x)

    # Photon map over the same photons (same tracer, hits kept as points).
    pos = np.stack([geo[n][0] for n in names])[mask]
    nrm = np.stack([geo[n][1] for n in names])[mask]
    for n_ph in cfg["pm_photons"]:
        job = methods.bake.prepare_bake(bpy.context, objs, photons=n_ph, seed=7, resolution=res)
        t0 = time.perf_counter()
        cs = compile_scene(job.scene)
        stats = trace_photons(cs, n_ph, seed=7, max_bounces=methods.MAX_BOUNCES, record_direct=True,
                              keep_points=True)
        pm = photon_map.build(stats)
        k = pm_k(n_ph)
        e = photon_map.irradiance(pm, pos, nrm, k=k)
        t = time.perf_counter() - t0
        x = np.zeros(mask.shape + (3,))
        x[mask] = e[:, :3] / math.pi
        add("bake", "photon_map", "photons", n_ph, t, bake_score(x), pm.bytes_measured(),
            memory_compact_bytes=pm.bytes_compact(), stored_photons=pm.n_photons, k=k,
            seconds_tree=pm.seconds_build)
        if n_ph == DEFAULT_PHOTONS or (n_ph == cfg["pm_photons"][-1] and "pm_default" not in images):
            images["pm_default"] = (n_ph, x)
        del pm, stats, cs

    # Cycles bake over samples; and the same bake denoised, as The Lightmapper
    # add-on does for Cycles bakes: the peer a baking artist would use.
    covered = {n: maps0[n][..., 3] > 0.0 for n in names}
    for spp in cfg["cycles_bake_spp"]:
        with quiet():
            maps, t = methods.cycles_bake(objs, res, spp, 11)
        x = stack_maps(maps, names)
        add("bake", "cycles_bake", "samples", spp, t, bake_score(x))
        images.setdefault("cycles_bake", {})[spp] = (t, x)
        if OIDN:
            dmaps, t_dn = methods.oidn_cycles_bake(maps, covered)
            add("bake", "cycles_bake_oidn", "samples", spp, t + t_dn, bake_score(stack_maps(dmaps, names)),
                seconds_denoise=t_dn)

    # Cycles baked finer and averaged into texels: slower per sample, but it reaches
    # the texel means that its bake at the texel resolution misses across shadow edges.
    ss = cfg["cycles_bake_ss"]
    for spp in cfg["cycles_bake_ss_spp"]:
        with quiet():
            maps, t = methods.cycles_bake_ss(objs, res, ss, spp, 11)
        add("bake", "cycles_bake_ss", "samples", spp, t, bake_score(stack_maps(maps, names)),
            supersampling=ss)
        if OIDN:
            dmaps, t_dn = methods.oidn_cycles_bake(maps, covered)
            add("bake", "cycles_bake_ss_oidn", "samples", spp, t + t_dn, bake_score(stack_maps(dmaps, names)),
                supersampling=ss, seconds_denoise=t_dn)

    # Renders: ours (constant, bilinear) over photons, Cycles over samples.
    for n_ph in cfg["render_photons"]:
        for mode, (img, t) in methods.ours_render(n_ph, RENDER_SPP, 7).items():
            meth = "ours_render_constant" if mode == lightmap.MODE_CONSTANT else "ours_render_bilinear"
            add("render", meth, "photons", n_ph, t, render_score(img), samples=RENDER_SPP)
            images.setdefault("ours_render", {})[(n_ph, meth)] = (t, img)
    # The gather's error floor is its camera samples, not its photons (a photon pass
    # of 300k leaves 7 % at 16 spp and 2.4 % at 256): photons and samples rise together.
    for n_ph, spp, rays in cfg["render_gather"]:
        if OIDN:
            (img, t), (dimg, t_d) = methods.ours_render_gather(n_ph, spp, 7, gather_rays=rays, denoise=True)
            # RT filter with albedo and normal of the first hits (session.denoise_render)
            add("render", "ours_render_gather_oidn", "photons", n_ph, t_d, render_score(dimg),
                samples=spp, gather_rays=rays, seconds_denoise=t_d - t, aux="albedo+normal")
        else:
            img, t = methods.ours_render_gather(n_ph, spp, 7, gather_rays=rays)
        add("render", "ours_render_gather", "photons", n_ph, t, render_score(img), samples=spp,
            gather_rays=rays)
        images.setdefault("ours_render", {})[(n_ph, "ours_render_gather")] = (t, img)
    for spp in cfg["cycles_render_spp"]:
        with quiet():
            img, t = methods.cycles_render(spp, 11)
        add("render", "cycles_render", "samples", spp, t, render_score(img))
        images.setdefault("cycles_render", {})[spp] = (t, img)
    if LUXCORE:
        luxcore_renders(cfg, render_score, add)

    if name == references.FINE_SCENE:
        images["fine"] = fine_study(cfg, ref, add)
    return points, info, images


def luxcore_renders(cfg, render_score, add):
    """LuxCore's path tracer, plain and with PhotonGI, in a worker process per render.

    seconds is the worker's LuxCore time (scene build + PhotonGI cache + rendering),
    like Cycles' render call; the process start and pyluxcore's import are kept
    apart in seconds_wall."""
    spec, arrays = luxcore_peer.export_scene(bpy.context.evaluated_depsgraph_get())
    luxcore_peer.render_spec(spec, arrays, "path", spp=1, seed=0)   # warm-up: file cache, libraries
    runs = [("luxcore_path", spp, None) for spp in cfg["luxcore_path_spp"]]
    runs += [("luxcore_photongi", spp, {"photon.maxcount": int(n)}) for n, spp in cfg["luxcore_photongi"]]
    for meth, spp, pgi in runs:
        img, st = luxcore_peer.render_spec(spec, arrays, meth.split("_")[1], spp=spp, seed=11, photongi=pgi)
        extra = {"cache_photons_max": pgi["photon.maxcount"]} if pgi else {}
        add("render", meth, "samples", spp, st["seconds"], render_score(img), samples=st["spp"],
            seconds_wall=st["seconds_wall"], seconds_cache=st["seconds_cache"],
            seconds_luxcore_render=st["seconds_render"], **extra)


def fine_study(cfg, ref, add):
    """Texels too coarse for a shadow edge: the window floor's lightmap at several
    resolutions, looked up (constant and bilinear) at the texel centres of a fine
    Cycles reference bake."""
    floor = bpy.data.objects[references.FINE_OBJECT]
    fres = cfg["ref"]["fine_res"]
    _, _, inside = methods.texel_points(floor, fres)
    score = Scorer(ref["fine_A"], ref["fine_B"], inside)
    shown = {"reference": 0.5 * (ref["fine_A"] + ref["fine_B"]), "inside": inside}
    for r in cfg["fine_res"]:
        _, t, nbytes, _, job = methods.ours_bake([floor], cfg["fine_photons"], 5, r)
        for mode, label in ((lightmap.MODE_CONSTANT, "constant"), (lightmap.MODE_BILINEAR, "bilinear")):
            x = methods.resample(job, references.FINE_OBJECT, fres, mode)
            add("fine", f"ours_floor_{label}", "resolution", r, t, score(x), nbytes,
                photons=cfg["fine_photons"])
            shown[(r, label)] = x
    return shown


# --------------------------------------------------------------------------------------
# Headlines
# --------------------------------------------------------------------------------------

def loglog_interp(xs, ys, y_target):
    """x where the piecewise log-log curve (xs increasing effort, ys falling) reaches y_target.

    Beyond the measured range the last two points' slope extrapolates; returns (x, extrapolated)."""
    lx, ly = np.log(np.asarray(xs, float)), np.log(np.maximum(np.asarray(ys, float), 1e-12))
    lt = math.log(max(y_target, 1e-12))
    for i in range(len(lx) - 1):
        if (ly[i] - lt) * (ly[i + 1] - lt) <= 0 and ly[i] != ly[i + 1]:
            f = (lt - ly[i]) / (ly[i + 1] - ly[i])
            return math.exp(lx[i] + f * (lx[i + 1] - lx[i])), False
    i = len(lx) - 2 if lt < ly[-1] else 0
    slope = (ly[i + 1] - ly[i]) / (lx[i + 1] - lx[i])
    if slope >= 0:
        return math.inf, True
    return math.exp(lx[i] + (lt - ly[i]) / slope), True


def fit_floor(photons, errs):
    """Fits rel_rmse^2 = a / N + b (variance + discretisation floor) by least squares.

    Returns slope of the first two points, the floor sqrt(b) and N where a/N = b."""
    N, e2 = np.asarray(photons, float), np.asarray(errs, float) ** 2
    A = np.stack([1.0 / N, np.ones_like(N)], axis=1)
    # Relative weights: every point matters equally in log space.
    w = 1.0 / np.maximum(e2, 1e-30)
    (a, b), *_ = np.linalg.lstsq(A * w[:, None], e2 * w, rcond=None)
    a, b = max(a, 0.0), max(b, 0.0)
    k = min(3, len(N))
    slope = float(np.polyfit(np.log(N[:k]), np.log(np.sqrt(e2[:k])), 1)[0])
    return slope, math.sqrt(b), (a / b if b > 0 else math.inf)


EXTRAPOLATE_AT_MOST = 4.0

# Render curves compared with Cycles' render: ours (gather, bilinear) and the LuxCore peer.
RENDER_PEERS = ("ours_render_gather", "ours_render_bilinear", "luxcore_path", "luxcore_photongi")


def render_ratio(p, cyc):
    """Cycles' render time to reach point p's error (log-log interpolated over its spp
    sweep) over p's time: above 1, p is faster at that accuracy."""
    t_cyc, extra = loglog_interp([q["seconds"] for q in cyc], [q["rel_rmse"] for q in cyc], p["rel_rmse"])
    return dict(knob_name=p["knob_name"], knob=p["knob"], samples=p.get("samples"), seconds=p["seconds"],
                rel_rmse=p["rel_rmse"], mean_error=p["mean_error"], cycles_seconds_at_equal_error=t_cyc,
                extrapolated=extra, ratio=t_cyc / p["seconds"])


def headlines(points):
    out = {}
    for scene in sorted({p["scene"] for p in points}):
        P = [p for p in points if p["scene"] == scene]

        def curve(method):
            c = sorted((p for p in P if p["method"] == method), key=lambda p: p["knob"])
            return c

        ours = curve("ours_bake")
        cyc = curve("cycles_bake")
        pm = curve("photon_map")
        h = {}
        # lookup: the thesis's bake; gather: the add-on's default (final gather)
        # each of ours against the Cycles curve of its kind: plain, or both denoised
        lookup_n, gather_n = DEFAULT_PHOTONS, DEFAULT_BAKE_PHOTONS
        for key, c, peer, n_default in (
                ("speedup_vs_cycles_bake", ours, cyc, lookup_n),
                ("speedup_vs_cycles_bake_gather", curve("ours_bake_gather"), cyc, gather_n),
                ("speedup_vs_cycles_bake_cache", curve("ours_bake_cache"), cyc, gather_n),
                ("speedup_oidn_vs_cycles_bake_oidn", curve("ours_bake_oidn"), curve("cycles_bake_oidn"),
                 lookup_n),
                ("speedup_gather_oidn_vs_cycles_bake_oidn", curve("ours_bake_gather_oidn"),
                 curve("cycles_bake_oidn"), gather_n)):
            if not (c and peer):
                continue
            d = min(c, key=lambda p: abs(math.log(p["knob"] / n_default)))
            # Cycles: whichever of its two bakes (at the texel resolution, or finer and
            # averaged) gets there first; extrapolated no further than EXTRAPOLATE_AT_MOST
            # times its longest run (beyond that, its curve's last slope says little)
            peers = [(peer[0]["method"], peer)]
            ss_peer = curve(peer[0]["method"].replace("cycles_bake", "cycles_bake_ss"))
            if ss_peer:
                peers.append((ss_peer[0]["method"], ss_peer))
            found = []
            for name, pc in peers:
                t, ex = loglog_interp([p["seconds"] for p in pc], [p["rel_rmse"] for p in pc], d["rel_rmse"])
                if ex and t > EXTRAPOLATE_AT_MOST * max(p["seconds"] for p in pc):
                    t = math.inf
                found.append((t, ex, name))
            t_cyc, extra, peer_name = min(found)
            h[key] = dict(
                ours_photons=d["knob"], ours_seconds=d["seconds"], ours_rel_rmse=d["rel_rmse"],
                ours_worst_object_error=d.get("worst_object_error"),
                cycles_seconds_at_equal_error=t_cyc, extrapolated=extra, ratio=t_cyc / d["seconds"],
                cycles_method=peer_name)
        if ours and pm:
            d = min(ours, key=lambda p: abs(math.log(p["knob"] / DEFAULT_PHOTONS)))
            # Memory grows with photon count, error falls: the same curve as time. Not
            # extrapolated: the photon map's curve flattens, so a line through its last
            # points can give absurd sizes; unreached errors are reported as such.
            errs = [p["rel_rmse"] for p in pm]
            mem_m, ex1 = loglog_interp([p["memory_bytes"] for p in pm], errs, d["rel_rmse"])
            mem_c, _ = loglog_interp([p["memory_compact_bytes"] for p in pm], errs, d["rel_rmse"])
            if ex1:
                mem_m = mem_c = math.inf
            h["memory_vs_photon_map"] = dict(
                ours_rel_rmse=d["rel_rmse"], ours_bytes=d["memory_bytes"],
                ours_compact_bytes=d["memory_compact_bytes"],
                photon_map_bytes_measured=mem_m, photon_map_bytes_20B=mem_c, extrapolated=ex1,
                ratio_measured=mem_m / d["memory_bytes"], ratio_20B_vs_12B=mem_c / d["memory_compact_bytes"],
                photon_map_best_rel_rmse=min(errs),
                photon_map_best_bytes_measured=pm[int(np.argmin(errs))]["memory_bytes"],
                photon_map_best_bytes_20B=pm[int(np.argmin(errs))]["memory_compact_bytes"])
        cyc_r = curve("cycles_render")
        rr = {m: [render_ratio(p, cyc_r) for p in curve(m)] for m in RENDER_PEERS} if cyc_r else {}
        rr = {m: v for m, v in rr.items() if v}
        if rr:
            h["render_speedup_vs_cycles"] = rr
        if len(ours) >= 3:
            slope, floor, n_cross = fit_floor([p["knob"] for p in ours], [p["rel_rmse"] for p in ours])
            h["error_vs_photons"] = dict(slope_low_photons=slope, floor_rel_rmse=floor,
                                         floor_reached_at_photons=n_cross)
        out[scene] = h
    return out


def _spp_note(r):
    return "" if r["knob_name"] == "samples" else f" {r['samples']} spp"


def print_headlines(h, log):
    log("\n=== Headline ratios ===")
    for scene, v in h.items():
        for key, what, peer in (("speedup_vs_cycles_bake", "lookup", "Cycles bake"),
                                ("speedup_vs_cycles_bake_gather", "gather", "Cycles bake"),
                                ("speedup_vs_cycles_bake_cache", "gather, irradiance cache: the default", "Cycles bake"),
                                ("speedup_oidn_vs_cycles_bake_oidn", "lookup + OIDN", "Cycles bake + OIDN"),
                                ("speedup_gather_oidn_vs_cycles_bake_oidn", "gather + OIDN",
                                 "Cycles bake + OIDN")):
            s = v.get(key)
            if s:
                log(f"[{scene}] (a) our bake ({what}) {s['ours_photons']:,} photons: {s['ours_seconds']:.2f} s at "
                    f"relRMSE {s['ours_rel_rmse']:.4f}"
                    + (f" (worst object mean {s['ours_worst_object_error']:+.2%})"
                       if s.get("ours_worst_object_error") is not None else "")
                    + f"; {peer} ({s.get('cycles_method', 'cycles_bake')}) needs "
                    + (f"{s['cycles_seconds_at_equal_error']:.1f} s" if math.isfinite(s['cycles_seconds_at_equal_error'])
                       else f"more than {EXTRAPOLATE_AT_MOST:g}x its longest run")
                    + f"{' (extrapolated)' if s['extrapolated'] else ''} -> {s['ratio']:.1f}x (goal >= 20x)")
        m = v.get("memory_vs_photon_map")
        if m and not math.isfinite(m["photon_map_bytes_measured"]):
            log(f"[{scene}] (b) memory at relRMSE {m['ours_rel_rmse']:.4f}: lightmaps {m['ours_bytes'] / 1e6:.2f} MB "
                f"({m['ours_compact_bytes'] / 1e6:.3f} MB at 12 B/texel); the photon map never got there: best "
                f"relRMSE {m['photon_map_best_rel_rmse']:.4f} with {m['photon_map_best_bytes_measured'] / 1e6:.1f} MB "
                f"measured ({m['photon_map_best_bytes_measured'] / m['ours_bytes']:.0f}x), "
                f"{m['photon_map_best_bytes_20B'] / 1e6:.1f} MB at 20 B/photon "
                f"({m['photon_map_best_bytes_20B'] / m['ours_compact_bytes']:.0f}x vs 12 B/texel)")
        elif m:
            log(f"[{scene}] (b) memory at relRMSE {m['ours_rel_rmse']:.4f}: lightmaps {m['ours_bytes'] / 1e6:.2f} MB "
                f"({m['ours_compact_bytes'] / 1e6:.3f} MB at 12 B/texel); photon map "
                f"{m['photon_map_bytes_measured'] / 1e6:.1f} MB measured ({m['ratio_measured']:.1f}x), "
                f"{m['photon_map_bytes_20B'] / 1e6:.1f} MB at 20 B/photon ({m['ratio_20B_vs_12B']:.1f}x vs 12 B/texel)"
                "")
        for m, pts in v.get("render_speedup_vs_cycles", {}).items():
            log(f"[{scene}] (d) render {m}: Cycles' time at equal relRMSE / its time: " + "; ".join(
                f"{r['knob']:,} {r['knob_name']}{_spp_note(r)}"
                f" {r['rel_rmse']:.4f} in {r['seconds']:.1f} s -> {r['ratio']:.2f}x"
                f"{' (extrap.)' if r['extrapolated'] else ''}" for r in pts))
        e = v.get("error_vs_photons")
        if e:
            log(f"[{scene}] (c) error vs photons: log-log slope {e['slope_low_photons']:.2f} at low counts; "
                f"floor relRMSE {e['floor_rel_rmse']:.4f}, reached near {e['floor_reached_at_photons']:,.0f} photons")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny knobs, cornell only")
    ap.add_argument("--scenes", default=None, help="comma-separated subset of " + ",".join(scenes.SCENES))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "out"))
    ap.add_argument("--charts", default=None, help="chart folder (default: OUT/charts; the full run "
                                                   "also copies them to benchmarks/charts)")
    ap.add_argument("--no-charts", action="store_true")
    ap.add_argument("--csg", action="store_true", help="also run bench_csg (exact CSG against the "
                                                       "Boolean mesh; about 25 min full, 6 min --quick)")
    args = ap.parse_args(argv)
    cfg = dict(QUICK if args.quick else FULL)
    if args.scenes:
        cfg["scenes"] = [s.strip() for s in args.scenes.split(",") if s.strip()]
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def log(msg):
        print(msg, flush=True)

    if not registration.is_registered():
        photon_lightmaps.register()
    if not LUXCORE:
        log("pyluxcore not importable: the luxcore_* renders are skipped (pip install -r benchmarks/requirements.txt)")
    t0 = time.perf_counter()
    points, infos, images = [], [], {}
    for name in cfg["scenes"]:
        p, info, imgs = run_scene(name, cfg, log)
        points += p
        infos.append(info)
        images[name] = imgs
    h = headlines(points)
    result = dict(quick=bool(args.quick), config={k: v for k, v in cfg.items() if k != "ref"},
                  reference_settings=cfg["ref"], default_photons=DEFAULT_PHOTONS,
                  default_bake_photons=DEFAULT_BAKE_PHOTONS,
                  default_resolution=DEFAULT_RES, render_spp=RENDER_SPP, photon_map_k="clip(0.2 sqrt(N), 50, 200)",
                  blender=bpy.app.version_string, scenes=infos, points=points, headlines=h,
                  seconds_total=None)
    print_headlines(h, log)
    if not args.no_charts:
        from benchmarks import charts
        chart_dir = pathlib.Path(args.charts) if args.charts else out / "charts"
        files = charts.make_all(result, images, chart_dir)
        if not args.quick and not args.charts:
            files += charts.make_all(result, images, ROOT / "benchmarks" / "charts")
        log("charts: " + ", ".join(sorted({pathlib.Path(f).name for f in files})))
    result["seconds_total"] = time.perf_counter() - t0
    with open(out / "results.json", "w") as f:
        json.dump(result, f, indent=1, default=float)
    log(f"wrote {out / 'results.json'} ({len(points)} points) in {result['seconds_total']:.0f} s")
    if args.csg:
        from benchmarks import bench_csg
        bench_csg.main((["--quick"] if args.quick else []) + ["--out", str(out)]
                       + (["--no-charts"] if args.no_charts else []))
    return result


if __name__ == "__main__":
    main()
