"""Rays per second inside each kernel, as a fraction of the raw ray rate on the same scene.

    .venv/bin/python benchmarks/bench_kernels.py [--triangles 100000] [--reps 3] [--threads 2]

The scene is the one bench_rays times (a UV sphere of about 100k triangles)
standing in the Cornell room of engine/demo_scenes, lit by its area light. The
raw rates are engine/geometry/raycast.py's batch queries on that scene, with rays like
the kernels' own: closest hits from random points in the room in random
directions, and shadow segments from random points to random points on the
light. Each kernel's rate is the rays it traces over its wall time:

* photons: the rays the photon pass counts itself (PhotonStats.rays);
* direct: one shadow ray per texel sample (one light sample serves both
  sides of a surface: it lights the side it falls on);
* gather: gather rays per point × points × lit sides, as the bake gather
  reports them (Gathered.rays), one closest hit each;
* render: the rays the render kernel counts itself (camera, shadow, gather and
  glossy rays; cs.rays["render"]), against the raw closest-hit rate.

The texels' UV pieces and lit sides, which a bake collects once before its
first kernel and keeps, are timed apart ("texels": "collect_seconds"), not in
either kernel. A kernel below 50 % of the raw rate spends its time on
something other than tracing. Every figure is the best of `reps` runs. Prints one JSON object.
"""
import argparse
import json
import os
import pathlib
import platform
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import photon_lightmaps.engine  # noqa: E402,F401  (sets the numba cache before numba loads)
import numba  # noqa: E402
import numpy as np  # noqa: E402
from dataclasses import replace  # noqa: E402

from photon_lightmaps.engine.transport import bake_gather  # noqa: E402
from photon_lightmaps.engine import demo_scenes, session  # noqa: E402
from photon_lightmaps.engine.geometry import raycast  # noqa: E402
from photon_lightmaps.engine.transport import texel_gather  # noqa: E402
from photon_lightmaps.engine.core.scene import translate  # noqa: E402


def scene(triangles):
    """The Cornell room with a UV sphere of about `triangles` triangles on its floor."""
    n_theta = max(int(round(np.sqrt(triangles / 2.5))), 8)
    n_phi = max(int(round(triangles / (2 * (n_theta - 1)))), 8)
    s = demo_scenes.cornell_box(width=64, height=64, with_primitives=False)
    s.add_object(demo_scenes.uv_sphere_mesh(0.45, n_theta, n_phi), translate(0.1, 0.1, 0.46), name="ball")
    s.prototypes[-1].meshes[0].name = "ball"
    return replace(s, unwrap_limit=1000)      # the ball gets the fast layout, the walls xatlas


# The compiled scene's memos of the texels a bake walks (collected once per bake,
# whichever of direct light and the gather comes first).
TEXEL_MEMOS = ("_lit_sides", "_surfaces", "_texel_pieces")


def best_of(fn, reps, cs=None):
    """Best wall time of fn() over reps runs (after a warm-up); with cs, the
    compiled scene's texel memos are cleared first, so every run pays what a
    bake's first walk of its texels pays."""
    fn()                                      # warm-up: compile or load the kernels
    best = None
    for _ in range(reps):
        if cs is not None:
            for memo in TEXEL_MEMOS:
                cs.__dict__.pop(memo, None)
        t = time.perf_counter()
        out = fn()
        wall = time.perf_counter() - t
        if best is None or wall < best[0]:
            best = (wall, out)
    return best


def raw_rates(cs, n, reps, seed=1):
    rng = np.random.default_rng(seed)
    o = np.column_stack([rng.uniform(-0.98, 0.98, n), rng.uniform(-0.98, 0.98, n), rng.uniform(0.02, 1.96, n)])
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    closest, _ = best_of(lambda: raycast.trace_closest_batch(cs.geometry, o, d), reps)
    # shadow segments to the 0.5 m square light under the ceiling (z = 1.98)
    q = np.column_stack([rng.uniform(-0.25, 0.25, n), rng.uniform(-0.25, 0.25, n), np.full(n, 1.98)])
    seg = q - o                               # unnormalised: t runs from 0 to 1 along the segment
    occl, _ = best_of(lambda: raycast.occluded_batch(cs.geometry, o, seg, 1.0 - 1e-6), reps)
    return n / closest, n / occl


def texel_items(cs, lightmap_ids):
    """(texel items, lit sides summed over them) of the bake kernels, as they collect them."""
    mesh, prim = texel_gather.collect_texels(cs, texel_gather.lightmap_owners(cs), sorted(lightmap_ids), 0, with_sides=True)
    items = sides = 0
    tx = mesh.packed()
    if tx is not None:
        items += tx.texel.size
        sides += int(np.where(tx.side == 0, 2, 1).sum())   # side 0: gathered on both sides
    tx = prim.packed()
    if tx is not None:
        items += tx.texel.size
        sides += int(np.where(tx.sides[tx.lm] == 2, 2, 1).sum())
    return items, sides


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=100_000)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--photons", type=int, default=1_000_000)
    ap.add_argument("--rays", type=int, default=2_000_000)
    args = ap.parse_args()
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    out = {"machine": platform.processor() or platform.machine(), "threads": numba.get_num_threads()}
    t = time.perf_counter()
    cs = session.compile(scene(args.triangles))
    out["triangles"] = int(cs.geometry.tri_p.shape[0])
    out["compile_s"] = round(time.perf_counter() - t, 2)
    closest, occl = raw_rates(cs, args.rays, args.reps)
    out["raw_closest_mrays"] = round(closest / 1e6, 3)
    out["raw_occluded_mrays"] = round(occl / 1e6, 3)

    st = session.Settings(photons=args.photons, seed=1)
    wall, stats = best_of(lambda: session.photon_pass(cs, st, record_direct=True, gather=True), args.reps)
    out["photons"] = {"seconds": round(wall, 3), "rays": int(stats.rays),
                      "mrays": round(stats.rays / wall / 1e6, 3),
                      "of_raw_closest": round(stats.rays / wall / closest, 3)}

    ids = sorted({int(l) for lids in cs.instance_lightmaps for l in lids})
    # The texels' UV pieces (triangles clipped to texels) and lit sides: made once
    # per bake, before its first kernel, and kept for the rest; timed apart.
    collect, (items, sides) = best_of(lambda: texel_items(cs, ids), args.reps, cs)
    n_direct = items * session.DIRECT_SAMPLES
    wall, _ = best_of(lambda: session.gather_direct(cs, ids, st), args.reps)
    out["direct"] = {"seconds": round(wall, 3), "rays": n_direct, "mrays": round(n_direct / wall / 1e6, 3),
                     "of_raw_occluded": round(n_direct / wall / occl, 3)}

    per_point = max(int(st.bake_rays_per_point), 1)
    wall, got = best_of(lambda: bake_gather.gathered_indirect(cs, ids, (), session.DIRECT_SAMPLES, per_point,
                                                     st.mode, seed=1), args.reps)
    assert (got.rays == per_point).all()          # one pass, no adaptive rays
    n_gather = per_point * session.DIRECT_SAMPLES * sides
    out["gather"] = {"seconds": round(wall, 3), "rays": n_gather, "mrays": round(n_gather / wall / 1e6, 3),
                     "of_raw_closest": round(n_gather / wall / closest, 3)}
    out["texels"] = {"items": items, "lit_sides": sides, "collect_seconds": round(collect, 3)}

    rs = session.Settings(photons=args.photons, seed=1, samples=4, gather_rays=8)
    session.photon_pass(cs, rs, record_direct=True, caustics=True, gather=True)
    wall, _ = best_of(lambda: session.render(cs, rs), args.reps)
    n_render = int(cs.rays["render"])
    n_px = int(cs.camera.width) * int(cs.camera.height) * rs.samples
    out["render"] = {"seconds": round(wall, 3), "camera_samples": n_px, "rays": n_render,
                     "mrays": round(n_render / wall / 1e6, 3),
                     "of_raw_closest": round(n_render / wall / closest, 3)}
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
