"""Photon-pass throughput and its scaling with scene size.

1. Photons/s and rays/s of the photon pass on the Cornell-like scene, with 1
   and with all threads.
2. Time per photon from 10^3 to 10^6 analytic spheres, all instances of one
   prototype (stored once), laid out as a carpet that covers the same area at
   every count: each photon meets a similar surface, so the growth measures
   what the two-level BVH costs as the scene grows. Goal: <= 2x over 10^3..10^6.

Usage: .venv/bin/python benchmarks/bench_photons.py [--quick] [--json OUT]
"""
import argparse
import json
import math
import os
import pathlib
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2]))
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(pathlib.Path(__file__).resolve().parents[1] / ".numba_cache"))

import photon_lightmaps.engine  # noqa: E402,F401  (sets the numba cache before numba loads)
import numba  # noqa: E402
import numpy as np  # noqa: E402

from photon_lightmaps.engine import demo_scenes  # noqa: E402
from photon_lightmaps.engine.compile import compile_scene  # noqa: E402
from photon_lightmaps.engine.transport.photon_tracer import trace_photons  # noqa: E402
from photon_lightmaps.engine.core.scene import (  # noqa: E402
    Instance, Light, Material, Primitive, Prototype, Scene, compose, scale, translate)


def cornell(n_photons, threads):
    numba.set_num_threads(threads)
    cs = compile_scene(demo_scenes.cornell_box())
    trace_photons(cs, 20_000, seed=0)  # compile kernels outside the timing
    rows = []
    for _ in range(3):
        cs.reset_lightmaps()
        t0 = time.perf_counter()
        st = trace_photons(cs, n_photons, seed=1)
        rows.append((time.perf_counter() - t0, st))
    dt, st = min(rows, key=lambda r: r[0])
    return {"threads": threads, "photons": n_photons, "seconds": dt,
            "photons_per_s": n_photons / dt, "rays_per_s": st.rays / dt,
            "rays_per_photon": st.rays / n_photons}


def carpet_scene(n):
    """n spheres on a jittered grid over [-1,1]^2, radius shrinking so coverage stays ~50 %."""
    s = Scene(n_bands=3, name=f"carpet_{n}")
    grey = s.add_material(Material("grey", diffuse=0.5))
    k = int(math.ceil(math.sqrt(n)))
    pitch = 2.0 / k
    r = 0.4 * pitch
    rng = np.random.default_rng(0)
    s.prototypes.append(Prototype("sphere", primitives=[Primitive("sphere", material=grey)]))
    idx = np.arange(n)
    cx = -1 + (idx % k + 0.5) * pitch + rng.uniform(-0.05, 0.05, n) * pitch
    cy = -1 + (idx // k + 0.5) * pitch + rng.uniform(-0.05, 0.05, n) * pitch
    for x, y in zip(cx, cy):
        m = np.array([[r, 0, 0, x], [0, r, 0, y], [0, 0, r, r]])
        s.instances.append(Instance(0, m, lightmap=False))
    floor = demo_scenes.quad_mesh((-1.5, -1.5, 0), (1.5, -1.5, 0), (1.5, 1.5, 0), (-1.5, 1.5, 0),
                                  material=grey, name="floor")
    s.add_object(floor, name="floor", lightmap_resolution=64)
    s.lights.append(Light("area", power=100.0, size=2.0, transform=translate(0, 0, 2.0)))
    return s


def scaling(counts, n_photons):
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    out = []
    for n in counts:
        t0 = time.perf_counter()
        scene = carpet_scene(n)
        cs = compile_scene(scene)
        setup = time.perf_counter() - t0
        trace_photons(cs, 5_000, seed=0)
        best = None
        for _ in range(2):
            cs.reset_lightmaps()
            t1 = time.perf_counter()
            st = trace_photons(cs, n_photons, seed=1)
            dt = time.perf_counter() - t1
            best = dt if best is None else min(best, dt)
        out.append({"primitives": n, "setup_seconds": setup, "seconds": best,
                    "us_per_photon": 1e6 * best / n_photons, "rays_per_photon": st.rays / n_photons,
                    "us_per_ray": 1e6 * best / st.rays,
                    "geometry_bytes": int(sum(getattr(a, "nbytes", 0) for a in cs.geometry))})
        print(f"  {n:>8} spheres: {out[-1]['us_per_photon']:.3f} us/photon, "
              f"{out[-1]['us_per_ray']:.3f} us/ray, setup {setup:.1f} s", file=sys.stderr)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="smaller counts (CI smoke run)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    n_photons = 200_000 if args.quick else 1_000_000
    counts = [10 ** 3, 10 ** 4, 10 ** 5] if args.quick else [10 ** 3, 10 ** 4, 10 ** 5, 10 ** 6]
    all_threads = numba.config.NUMBA_NUM_THREADS
    res = {"machine_threads": all_threads,
           "cornell": [cornell(n_photons, 1), cornell(n_photons, all_threads)]}
    res["cornell_thread_scaling"] = res["cornell"][1]["photons_per_s"] / res["cornell"][0]["photons_per_s"]
    res["scaling"] = scaling(counts, n_photons // 2)
    first, last = res["scaling"][0], res["scaling"][-1]
    res["time_per_photon_growth"] = last["us_per_photon"] / first["us_per_photon"]
    res["time_per_ray_growth"] = last["us_per_ray"] / first["us_per_ray"]
    res["goal_time_per_photon_growth_le_2"] = res["time_per_photon_growth"] <= 2.0
    text = json.dumps(res, indent=2)
    print(text)
    if args.json:
        pathlib.Path(args.json).write_text(text)


if __name__ == "__main__":
    main()
