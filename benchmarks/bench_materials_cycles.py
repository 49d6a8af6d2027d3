"""Error against time next to Cycles on textured, mixed-material scenes.

Usage (from the repository root):
    .venv/bin/python -m benchmarks.bench_materials_cycles            # ~10 minutes on 2 cores
    .venv/bin/python -m benchmarks.bench_materials_cycles --quick    # ~2 minutes
Options: --out DIR (JSON, default benchmarks/out)  --charts DIR (default benchmarks/charts)

Scenes (demo_blend.build_spheres_blend, 96 x 48): gold, plastic and glass spheres on an
image-checker floor before a procedural-Checker wall,
* "studio": lit by a 1 m area light and a dim grey world;
* "sky": lit by a Nishita Sky Texture (sun disc on) and nothing else, the world baked by
  Cycles into an equirectangular map (export/world.py).
F12 renders timed wall-clock with a warm numba cache, at rising effort, error = relative
RMSE against a converged Cycles render with the reference's own noise taken out
(bench_lsystem_cycles.error). Writes DIR/materials_cycles.json and
CHARTS/materials_<scene>_error_vs_time.png.
"""
import argparse
import json
import math
import pathlib
import time


import bpy  # noqa: E402
import numpy as np  # noqa: E402

from photon_lightmaps import demo_blend, registration  # noqa: E402

from benchmarks.bench_lsystem_cycles import cycles, error, log, ours  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
FULL = dict(ref_spp=1024, cycles=(4, 16, 64, 256),
            ours=((50_000, 1), (200_000, 4), (800_000, 16), (2_000_000, 32)))
QUICK = dict(ref_spp=128, cycles=(4, 16), ours=((50_000, 1), (200_000, 4)))


def build(kind):
    registration.ensure_registered()
    scene = demo_blend.build_spheres_blend(textures=True)
    if kind == "sky":
        bpy.data.objects.remove(bpy.data.objects["key_light"])
        tree = scene.world.node_tree
        sky = tree.nodes.new("ShaderNodeTexSky")
        sky.sun_elevation, sky.sun_rotation = math.radians(35.0), math.radians(200.0)
        bg = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBackground")
        bg.inputs["Strength"].default_value = 0.3
        tree.links.new(sky.outputs["Color"], bg.inputs["Color"])
    return scene


def chart(points, title, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    for method, style in (("cycles", dict(color="tab:blue", marker="o", label="Cycles (path tracing)")),
                          ("ours", dict(color="tab:red", marker="s", label="Photon Lightmaps"))):
        pts = [p for p in points if p["method"] == method]
        ax.loglog([p["seconds"] for p in pts], [max(p["rel_rmse"], 1e-4) for p in pts], **style)
    ax.set_xlabel("wall-clock seconds, F12 render (2 cores)")
    ax.set_ylabel("relative RMSE vs converged Cycles")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=72)
    plt.close(fig)


def run(kind, cfg, charts):
    scene = build(kind)
    scene.cycles.blur_glossy = 0.0        # Filter Glossy blurs the caustics the reference should have
    ours(scene, 10_000, 1)                # warm-up: numba cache, texture and world bakes
    half_a, ta = cycles(scene, cfg["ref_spp"] // 2, seed=101)
    half_b, tb = cycles(scene, cfg["ref_spp"] // 2, seed=202)
    ref = 0.5 * (half_a + half_b)
    var_ref = float(np.mean((half_a - half_b) ** 2)) / 4.0
    points = []
    for spp in cfg["cycles"]:
        img, sec = cycles(scene, spp, seed=7)
        e, raw = error(img, ref, var_ref)
        points.append(dict(method="cycles", spp=spp, seconds=round(sec, 3), rel_rmse=round(e, 5),
                           mean_ratio=round(float(img.mean() / ref.mean()), 5)))
        log(f"{kind} cycles {spp:5d} spp: {sec:6.2f} s  rel RMSE {e:.4f}")
    for photons, samples in cfg["ours"]:
        img, sec = ours(scene, photons, samples)
        e, raw = error(img, ref, var_ref)
        points.append(dict(method="ours", photons=photons, samples=samples, seconds=round(sec, 3),
                           rel_rmse=round(e, 5), mean_ratio=round(float(img.mean() / ref.mean()), 5)))
        log(f"{kind} ours {photons:9,d} photons {samples:3d} spp: {sec:6.2f} s  rel RMSE {e:.4f}")
    chart(points, f"{kind}: textured floor and wall, gold / plastic / glass, 96x48",
          pathlib.Path(charts) / f"materials_{kind}_error_vs_time.png")
    return dict(reference_spp=cfg["ref_spp"], reference_seconds=round(ta + tb, 2),
                reference_noise=round(math.sqrt(var_ref) / float(ref.mean()), 5), points=points)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(HERE / "out"))
    ap.add_argument("--charts", default=str(HERE / "charts"))
    args = ap.parse_args()
    cfg = QUICK if args.quick else FULL
    t0 = time.perf_counter()
    result = {kind: run(kind, cfg, args.charts) for kind in ("studio", "sky")}
    result["seconds"] = round(time.perf_counter() - t0, 1)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "materials_cycles.json").write_text(json.dumps(result, indent=1))
    log(f"wrote {out / 'materials_cycles.json'} ({result['seconds']:.0f} s)")


if __name__ == "__main__":
    main()
