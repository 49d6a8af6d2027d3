"""Split bake passes against Cycles' matching bakes: error against time, same run.

The Cornell room (demo_blend.build_cornell_blend, mirror and glass balls too), its
floor, back and left walls and tall box at 64 x 64 texels, the same Lightmap UVs:

* AO within 0.5 m: ours (16 points x 4, 16 and 64 rays per texel) against
  Cycles' AO bake (the world's AO distance 0.5 m) at 64, 256 and 1024 samples;
* direct light alone: ours (the direct gather's 64, 256 and 1024 light samples a
  texel) against Cycles' Diffuse bake with Direct only, at 64, 256 and 1024 samples.

The reference is Cycles at 8192 samples. Error: relative RMSE over interior texels
(fully covered, 2 texels from a chart border; for AO, texels inside geometry,
where Cycles reads 0, and their neighbours left out: docs/baking.md). Times are
wall seconds of the bake call, after a warm-up (kernels loaded), 2 threads.

    .venv/bin/python -m benchmarks.bench_bake_passes      # about four minutes on 2 cores
"""
import json
import os
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402
import bpy  # noqa: E402

from photon_lightmaps import bake, demo_blend  # noqa: E402
from photon_lightmaps.registration import ensure_registered  # noqa: E402
from blender_session import cycles_diffuse_bake  # noqa: E402
from test_bake import erode  # noqa: E402

RES = 64
OBJECTS = ("floor", "back", "left", "tall_box")
CYCLES_SAMPLES = (64, 256, 1024)
REFERENCE_SAMPLES = 8192
DISTANCE = 0.5
OUT = ROOT / "benchmarks" / "charts" / "bake_passes.json"


def cycles(objs, samples, kind):
    t0 = time.perf_counter()
    if kind == "ao":
        maps = {ob.name: cycles_diffuse_bake(ob, RES, samples, bake_type="AO", pass_filter=()) for ob in objs}
    else:
        maps = {ob.name: cycles_diffuse_bake(ob, RES, samples, pass_filter=("DIRECT",)) for ob in objs}
    return maps, time.perf_counter() - t0


def ours(objs, kind, rays=16, direct_samples=None):
    t0 = time.perf_counter()
    res = bake.bake_objects(bpy.context, objs, resolution=RES, bake_pass=kind.upper(), ao_distance=DISTANCE,
                            seed=2, overwrite=True, pass_rays=rays, direct_samples=direct_samples)
    return {n: m.rgba for n, m in res.maps.items()}, time.perf_counter() - t0


def rmse(maps, ref, kind, cover):
    a_all, b_all = [], []
    for name in OBJECTS:
        m = cover[name]
        if kind == "ao":
            m = m & erode(ref[name][..., 0] > 0.0, 1)
        a_all.append(maps[name][..., :3][m])
        b_all.append(ref[name][..., :3][m])
    a, b = np.concatenate(a_all), np.concatenate(b_all)
    return float(np.sqrt(np.mean((a - b) ** 2)) / b.mean())


def main():
    ensure_registered()
    demo_blend.build_cornell_blend(spheres=True)
    scene = bpy.context.scene
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.light_settings.distance = DISTANCE
    objs = [bpy.data.objects[n] for n in OBJECTS]
    report = {"resolution": RES, "objects": OBJECTS, "reference_samples": REFERENCE_SAMPLES}
    for kind in ("ao", "direct"):
        ours(objs, kind)                                  # warm-up: kernels loaded
        mine, t_mine = ours(objs, kind)
        cover = {n: erode(mine[n][..., 3] >= 1.0 - 1e-6, 2) for n in OBJECTS}
        ref, t_ref = cycles(objs, REFERENCE_SAMPLES, kind)
        rows = [{"method": "photon_lightmaps", "seconds": t_mine, "rel_rmse": rmse(mine, ref, kind, cover)}]
        if kind == "ao":                # the AO pass's rays per point (16 points a texel): 64, 256 rays a texel
            for rays in (4, 16, 64):
                maps, t = ours(objs, kind, rays)
                rows.append({"method": f"photon_lightmaps_{rays}rays", "seconds": t,
                             "rel_rmse": rmse(maps, ref, kind, cover)})
        else:                           # Bake Direct Samples: light samples a texel (default 64)
            for samples in (256, 1024):
                maps, t = ours(objs, kind, direct_samples=samples)
                rows.append({"method": f"photon_lightmaps_{samples}samples", "seconds": t,
                             "rel_rmse": rmse(maps, ref, kind, cover)})
        for spp in CYCLES_SAMPLES:
            maps, t = cycles(objs, spp, kind)
            rows.append({"method": f"cycles_{spp}spp", "seconds": t, "rel_rmse": rmse(maps, ref, kind, cover)})
        report[kind] = {"rows": rows, "reference_seconds": t_ref}
        for r in rows:
            print(f"{kind:6s} {r['method']:18s} {r['seconds']:7.2f} s  rel RMSE {r['rel_rmse']:.4f}")
    OUT.write_text(json.dumps(report, indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
