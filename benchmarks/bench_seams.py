"""Seams: how far the two sides' bilinear reads disagree along every seam (the jump
seam_stitch.seam_jump measures), for our bake plain and stitched and for Cycles'
Diffuse bake of the same objects on the same Lightmap UVs, with each one's time.

The scene of tests/test_seam_stitch.py: two 1 x 2 m floor halves meeting along an
edge, a smooth UV sphere and a lamp close above, white diffuse (0.8), at 32 x 32
texels per object. Cycles bakes Direct + Indirect without Color at 64, 256 and 1024
samples with its default 4-texel margin. Our seams are found once, on our compiled
scene, and every method's images are read along them. Times: wall seconds, 2 threads,
after a warm-up.

    .venv/bin/python -m benchmarks.bench_seams      # about a minute on 2 cores
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

from photon_lightmaps.bake import pipeline  # noqa: E402
from photon_lightmaps.engine.transport import seam_stitch  # noqa: E402
from photon_lightmaps.registration import ensure_registered  # noqa: E402
from blender_session import cycles_diffuse_bake  # noqa: E402
from test_seam_stitch import halves_and_ball  # noqa: E402

RES = 32
CYCLES_SAMPLES = (64, 256, 1024)
OUT = ROOT / "benchmarks" / "charts" / "seams.json"


def ours(objs, stitch):
    t0 = time.perf_counter()
    job = pipeline.prepare_bake(bpy.context, objs, seed=1, resolution=RES, stitch_seams=stitch)
    pipeline.compute_bake(job)
    pipeline.commit_bake(job, overwrite=True)
    return job, time.perf_counter() - t0


def main():
    ensure_registered()
    _, objs = halves_and_ball()
    white = bpy.data.materials.new("white")
    white.diffuse_color = (0.8, 0.8, 0.8, 1.0)
    white.use_nodes = True
    for ob in objs:
        ob.data.materials.append(white)
    ours(objs, False)                                   # warm-up: kernels loaded, UVs made
    plain, t_plain = ours(objs, False)
    stitched, t_stitched = ours(objs, True)
    cs = plain.cs
    by_id = {bm.lightmap_id: name for name, bm in plain.result.maps.items()}
    charts = seam_stitch.mesh_charts(cs, sorted(by_id))
    names = [by_id[lid] for lid, *_ in charts]
    seams = seam_stitch.find_seams(charts, {k: (RES, RES) for k in range(len(charts))})
    rows = []

    def row(method, seconds, maps):
        jump, p95 = seam_stitch.seam_jump(seams, [np.asarray(maps[n], np.float64) for n in names])
        rows.append({"method": method, "seconds": seconds, "seam_jump": jump, "seam_jump_p95": p95})
        print(f"{method:22s} {seconds:7.2f} s  seam jump {jump:.4f} (p95 {p95:.4f})")

    row("photon_lightmaps", t_plain, {n: bm.rgba for n, bm in plain.result.maps.items()})
    row("photon_lightmaps_stitched", t_stitched, {n: bm.rgba for n, bm in stitched.result.maps.items()})
    for spp in CYCLES_SAMPLES:
        t0 = time.perf_counter()
        maps = {ob.name: cycles_diffuse_bake(ob, RES, spp) for ob in objs}
        row(f"cycles_{spp}spp", time.perf_counter() - t0, maps)
    OUT.write_text(json.dumps({"resolution": RES, "edges": seams.edges, "samples": int(seams.ia.size),
                               "rows": rows}, indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
