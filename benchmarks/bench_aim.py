"""Importance emission against Cycles: a small object baked alone in a big sunlit scene.

A 1 m cube on a 60 x 60 m ground under a sun 40 degrees from the zenith; only
the cube is baked (32 x 32 texels per face chart). Most of the sun's photons
land on ground no texel asks for, which is where aiming the photons at the
baked object (engine/shading/photon_aim.py) should pay. Curves, over photons or spp:

* ours_gather / ours_lookup: the add-on's bakes, photons aimed at the cube;
* ours_gather_unaimed / ours_lookup_unaimed: the same with aiming off;
* cycles_bake: Cycles' Diffuse bake (Direct + Indirect, no colour) of the cube.

Scored like run_all: relRMSE against a two-half Cycles reference (2 x 2048 spp)
over the cube's fully covered texels, and Cycles' time at equal error / ours.

    .venv/bin/python -m benchmarks.bench_aim            # about 3 minutes on 2 cores
"""
import json
import math
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from photon_lightmaps import demo_blend, registration  # noqa: E402
from photon_lightmaps.engine.shading import photon_aim  # noqa: E402
from photon_lightmaps.export import uv_layers  # noqa: E402

from benchmarks import methods  # noqa: E402
from benchmarks.quiet import quiet  # noqa: E402
from benchmarks.run_all import Scorer, loglog_interp, stack_maps  # noqa: E402

RES = 32
PHOTONS = [10_000, 30_000, 100_000, 300_000, 1_000_000, 3_000_000]
CYCLES_SPP = [4, 16, 64, 256, 1024]
REF_SPP = 2048
OUT = ROOT / "benchmarks" / "charts" / "aim.json"


def build():
    scene = demo_blend._reset()
    grey = demo_blend.principled("grey", (0.6, 0.6, 0.6))
    v, f = demo_blend.box_mesh_data()
    ground = demo_blend.mesh_object("ground", v, f, grey.copy())
    ground.scale, ground.location = (30.0, 30.0, 0.05), (0.0, 0.0, -0.05)
    cube = demo_blend.mesh_object("cube", v, f, grey.copy())
    cube.scale, cube.location = (0.5, 0.5, 0.5), (0.0, 0.0, 0.5)
    demo_blend.add_light(scene, "SUN", "sun", power=3.0, rotation=(0.0, math.radians(40.0), 0.0))
    bpy.context.view_layer.update()
    uv_layers.ensure_lightmap_uv(cube, resolution=16)
    bpy.context.view_layer.update()
    return cube


def ours(cube, photons, indirect, aimed):
    before = photon_aim.aimed.__defaults__
    if not aimed:
        photon_aim.aimed.__defaults__ = (0.0,)     # every photon as the light emits it
    try:
        maps, seconds, _, stats, _ = methods.ours_bake([cube], photons, 7, RES, indirect=indirect)
    finally:
        photon_aim.aimed.__defaults__ = before
    return maps, seconds


def main():
    if not registration.is_registered():
        registration.register()
    cube = build()
    with quiet():
        ref_A, _ = methods.cycles_bake([cube], RES, REF_SPP, 1)
        ref_B, _ = methods.cycles_bake([cube], RES, REF_SPP, 2)
    names = ["cube"]
    maps0, *_ = methods.ours_bake([cube], 1000, 0, RES)
    geo = methods.texel_points(cube, RES)
    mask = (geo[2] & (maps0["cube"][..., 3] >= 0.999))[None]
    score = Scorer(stack_maps(ref_A, names), stack_maps(ref_B, names), mask)
    points = []
    for indirect in ("GATHER", "LOOKUP"):
        ours(cube, 1000, indirect, True)              # warm-up
        for aimed in (True, False):
            method = f"ours_{indirect.lower()}" + ("" if aimed else "_unaimed")
            for n in PHOTONS:
                maps, t = ours(cube, n, indirect, aimed)
                s = score(stack_maps(maps, names))
                points.append(dict(method=method, knob=n, seconds=t, **s))
                print(f"{method:22s} {n:>10,} photons {t:6.2f} s  relRMSE {s['rel_rmse']:.4f}  "
                      f"bias {s['mean_error']:+.4f}", flush=True)
    with quiet():
        methods.cycles_bake([cube], RES, 4, 0)             # warm-up
    for spp in CYCLES_SPP:
        with quiet():
            maps, t = methods.cycles_bake([cube], RES, spp, 3)
        s = score(stack_maps(maps, names))
        points.append(dict(method="cycles_bake", knob=spp, seconds=t, **s))
        print(f"{'cycles_bake':22s} {spp:>10,} spp     {t:6.2f} s  relRMSE {s['rel_rmse']:.4f}", flush=True)
    cyc = [p for p in points if p["method"] == "cycles_bake"]
    for p in points:
        if p["method"] != "cycles_bake":
            t, extra = loglog_interp([c["seconds"] for c in cyc], [c["rel_rmse"] for c in cyc], p["rel_rmse"])
            p.update(cycles_seconds_at_equal_error=t, extrapolated=extra, ratio=t / p["seconds"])
    print("\nCycles' time at equal relRMSE / ours:")
    for m in ("ours_gather", "ours_gather_unaimed", "ours_lookup", "ours_lookup_unaimed"):
        row = [p for p in points if p["method"] == m]
        print(f"  {m:22s} " + "  ".join(f"{p['knob']:,}: {p['ratio']:.1f}x{' (extrap.)' if p['extrapolated'] else ''}"
                                          for p in row))
    OUT.write_text(json.dumps(dict(resolution=RES, reference_spp=REF_SPP, noise_floor=score.noise_floor(),
                                   points=points), indent=2))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
