"""Error against time next to Cycles on a preset tree (L-systems, thesis ch. 7 and 8.5).

Usage (from the repository root):
    .venv/bin/python -m benchmarks.bench_lsystem_cycles            # ~10 minutes on 2 cores
    .venv/bin/python -m benchmarks.bench_lsystem_cycles --quick    # ~2 minutes
Options: --out DIR (JSON, default benchmarks/out)  --charts DIR (default benchmarks/charts)

Scene: the ternary tree preset (ABOP fig. 2.8a) at 5 derivation steps (485 segments,
cylinders and frustums) on a grey ground plane under a sun, a dim blue world, 96 x 96
pixels. This engine renders the grammar through its scene graph (analytic segments,
indirect light on the tree from its orientation lightmap, on the ground from its
lightmap); Cycles renders the Geometry Nodes preview realized at the same depth (the
preview's cylinders raised to 48 sides, so the silhouettes agree to 0.3 %).

Both are F12 renders (bpy.ops.render.render), timed wall-clock with a warm numba
cache, at rising effort: Cycles over samples, this engine over (photons, camera
samples). The error is the relative RMSE against a converged Cycles render with the
reference's own noise (estimated from two half-sample renders) taken out, so it
measures each method's error, not the reference's. This engine's curve flattens
at its bias (the orientation lightmap averages indirect light by normal over the
whole tree); Cycles converges to the reference by construction. Writes
DIR/lsystem_cycles.json and CHARTS/lsystem_tree_error_vs_time.png.
"""
import argparse
import json
import math
import os
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from photon_lightmaps import demo_blend, registration  # noqa: E402
from photon_lightmaps.bake import lsystem_plan, lsystem_preview  # noqa: E402
from photon_lightmaps.bake import render as render_engine  # noqa: E402
from photon_lightmaps.engine.geometry.dcsg import DCSG  # noqa: E402
from photon_lightmaps.engine.lsystem.presets import load_preset  # noqa: E402

from benchmarks.methods import MAX_BOUNCES, render_still, setup_cycles  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
PRESET, STEPS = "ternary_tree", 5
W = H = 96
SUN_ROTATION = (math.radians(50.0), 0.0, math.radians(30.0))
FULL = dict(ref_spp=1024, cycles=(4, 16, 64, 256),
            ours=((25_000, 1), (100_000, 4), (400_000, 16), (1_600_000, 32)))
QUICK = dict(ref_spp=128, cycles=(4, 16), ours=((25_000, 1), (100_000, 4)))
ENGINE = "PHOTON_LIGHTMAPS"


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def build_scene():
    """The tree on its ground, a sun, a dim sky colour, a camera framing the tree."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    registration.ensure_registered()
    scene = bpy.context.scene
    lo, hi = DCSG(load_preset(PRESET), STEPS).bounds()
    s = 2.0 * max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
    demo_blend.mesh_object("ground", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                           demo_blend.principled("ground", (0.5, 0.5, 0.5)), uvs=demo_blend.quad_uvs())
    lsystem_plan.SEGMENTS = 48               # the preview's 12-sided cylinders lose 1.1 % of the silhouette
    ob = lsystem_preview.new_lsystem_object("tree", preset=PRESET)
    props = ob.photon_lightmaps.lsystem
    props.use_render_iterations, props.render_iterations = True, STEPS
    props.preview_iterations = STEPS
    ob.data.materials.append(demo_blend.principled("bark", (0.55, 0.4, 0.25)))
    ob.material_slots[0].link, ob.material_slots[0].material = "OBJECT", bpy.data.materials["bark"]
    lsystem_preview.update_preview(ob)
    demo_blend.add_light(scene, "SUN", "sun", power=3.0, rotation=SUN_ROTATION)
    demo_blend.set_world(scene, color=(0.05, 0.07, 0.1))
    # frame the tree's box from the front, slightly above
    c = 0.5 * (lo + hi)
    size = float(max(hi[0] - lo[0], hi[2] - lo[2]))
    dist = 1.25 * size / (2.0 * math.tan(math.radians(39.6) / 2.0))
    tilt = math.radians(8.0)
    demo_blend.add_camera(scene, (c[0], c[1] - dist * math.cos(tilt), c[2] + dist * math.sin(tilt)),
                          (math.radians(90.0) - tilt, 0.0, 0.0))
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = W, H, 100
    scene.view_settings.view_transform = "Standard"
    return scene


def render(scene, engine):
    """F12 render -> ((H, W, 3) linear, rows top-down; wall seconds)."""
    scene.render.engine = engine
    img, seconds = render_still(scene)
    return img.astype(np.float64), seconds


def cycles(scene, spp, seed):
    setup_cycles(scene, spp, seed)
    return render(scene, "CYCLES")


def ours(scene, photons, samples, seed=0):
    s = scene.photon_lightmaps
    s.photons, s.samples, s.seed, s.max_bounces = int(photons), int(samples), int(seed), MAX_BOUNCES
    return render(scene, ENGINE)


def error(img, ref, var_ref):
    """Relative RMSE with the reference's noise removed (its variance per pixel)."""
    mse = float(np.mean((img - ref) ** 2))
    return math.sqrt(max(mse - var_ref, 0.0)) / float(ref.mean()), math.sqrt(mse) / float(ref.mean())


def chart(result, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    for method, style in (("cycles", dict(color="tab:blue", marker="o", label="Cycles (path tracing)")),
                          ("ours", dict(color="tab:red", marker="s",
                                        label="Photon Lightmaps (DCSG + orientation lightmap)"))):
        pts = [p for p in result["points"] if p["method"] == method]
        ax.loglog([p["seconds"] for p in pts], [max(p["rel_rmse"], 1e-4) for p in pts], **style)
        for p in pts:
            lab = f"{p['spp']} spp" if method == "cycles" else f"{p['photons'] / 1e3:g}k, {p['samples']} spp"
            ax.annotate(lab, (p["seconds"], max(p["rel_rmse"], 1e-4)), fontsize=7,
                        textcoords="offset points", xytext=(3, 3))
    ax.axhline(result["reference_noise"], color="0.6", ls=":", lw=1, label="reference noise (removed)")
    ax.set_xlabel("wall-clock seconds, F12 render (2 cores)")
    ax.set_ylabel("relative RMSE vs converged Cycles")
    ax.set_title(f"{PRESET} at {STEPS} steps ({result['segments']} segments), {W}x{H}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=72)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(HERE / "out"))
    ap.add_argument("--charts", default=str(HERE / "charts"))
    args = ap.parse_args()
    cfg = QUICK if args.quick else FULL
    t_all = time.perf_counter()
    scene = build_scene()
    log("warming up (numba cache, first export) ...")
    ours(scene, 10_000, 1)
    log(f"reference: Cycles {cfg['ref_spp']} spp in two halves ...")
    half_a, ta = cycles(scene, cfg["ref_spp"] // 2, seed=101)
    half_b, tb = cycles(scene, cfg["ref_spp"] // 2, seed=202)
    ref = 0.5 * (half_a + half_b)
    var_ref = float(np.mean((half_a - half_b) ** 2)) / 4.0     # variance of the mean of two halves
    points = []
    for spp in cfg["cycles"]:
        img, sec = cycles(scene, spp, seed=7)
        e, raw = error(img, ref, var_ref)
        points.append(dict(method="cycles", spp=spp, seconds=round(sec, 3), rel_rmse=round(e, 5),
                           rel_rmse_raw=round(raw, 5), mean_ratio=round(float(img.mean() / ref.mean()), 5)))
        log(f"cycles {spp:5d} spp: {sec:6.2f} s  rel RMSE {e:.4f}")
    for photons, samples in cfg["ours"]:
        img, sec = ours(scene, photons, samples)
        e, raw = error(img, ref, var_ref)
        run = render_engine.LAST_RUN
        points.append(dict(method="ours", photons=photons, samples=samples, seconds=round(sec, 3),
                           engine_seconds={k: round(v, 3) for k, v in run.seconds.items()},
                           rel_rmse=round(e, 5), rel_rmse_raw=round(raw, 5),
                           mean_ratio=round(float(img.mean() / ref.mean()), 5)))
        log(f"ours {photons:9,d} photons {samples:3d} spp: {sec:6.2f} s  rel RMSE {e:.4f}")
    graph = DCSG(load_preset(PRESET), STEPS)
    result = dict(preset=PRESET, steps=STEPS, segments=int(graph.implicit_primitives), width=W, height=H,
                  reference_spp=cfg["ref_spp"], reference_seconds=round(ta + tb, 2),
                  reference_noise=round(math.sqrt(var_ref) / float(ref.mean()), 5), points=points,
                  seconds=round(time.perf_counter() - t_all, 1), quick=bool(args.quick))
    # the headline: the time each method needs for this engine's best error
    best = min((p for p in points if p["method"] == "ours"), key=lambda p: p["rel_rmse"])
    cyc = [p for p in points if p["method"] == "cycles"]
    reach = next((p for p in cyc if p["rel_rmse"] <= best["rel_rmse"]), None)
    result["headline"] = dict(ours_best_rel_rmse=best["rel_rmse"], ours_seconds=best["seconds"],
                              cycles_seconds_at_that_error=reach["seconds"] if reach else None,
                              cycles_spp_at_that_error=reach["spp"] if reach else None)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "lsystem_cycles.json").write_text(json.dumps(result, indent=1))
    chart(result, pathlib.Path(args.charts) / "lsystem_tree_error_vs_time.png")
    print(json.dumps(result["headline"]))
    log(f"wrote {out / 'lsystem_cycles.json'} and the chart ({result['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
