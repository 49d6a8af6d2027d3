"""Rays per second of engine/geometry/raycast.py against Embree (embreex) on UV spheres.

    .venv/bin/python benchmarks/bench_rays.py [--rays N] [--reps R] [--sizes 100000,800000]

Both tracers get the same rays (generated in float32, which Embree needs,
and widened exactly to float64 for ours): origins uniform in a box around
the mesh, directions uniform on the sphere. Embree is driven through
embreex's `EmbreeScene.run`, a Cython loop that calls rtcIntersect1 once per
ray on the calling thread, so its query is single-threaded (its BVH build
uses TBB threads, which is not timed); the JSON reports its CPU/wall ratio as
evidence. Ours is timed with numba.set_num_threads(1) and (2). Every figure
is the best of `reps` runs (wall clock), which filters out interference from
other processes on a shared machine. Prints one JSON object.
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

from photon_lightmaps.engine.geometry import raycast  # noqa: E402
from photon_lightmaps.engine.geometry.assembly import compile_geometry  # noqa: E402
from photon_lightmaps.engine.core.scene import Scene, TriangleMesh  # noqa: E402


def uv_sphere(n_lon, n_lat):
    """Unit UV sphere with 2 * n_lon * (n_lat - 1) triangles (pole fans + quads)."""
    th = np.linspace(0.0, np.pi, n_lat + 1)[1:-1]
    ph = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    ring = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph),
                     np.cos(th)[:, None] * np.ones_like(ph)], axis=-1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1.0]], ring, [[0, 0, -1.0]]])
    south = len(v) - 1
    j = np.arange(n_lon)
    j1 = (j + 1) % n_lon
    tris = [np.stack([np.zeros(n_lon, int), 1 + j, 1 + j1], 1)]
    for i in range(n_lat - 2):
        a = 1 + i * n_lon
        b = a + n_lon
        tris.append(np.stack([a + j, b + j, b + j1], 1))
        tris.append(np.stack([a + j, b + j1, a + j1], 1))
    last = 1 + (n_lat - 2) * n_lon
    tris.append(np.stack([last + j, np.full(n_lon, south), last + j1], 1))
    return v, np.concatenate(tris)


SPHERES = {100_000: (250, 201), 800_000: (1000, 401)}


def rays(n, seed=1, half=1.5):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-half, half, (n, 3)).astype(np.float32)
    d = rng.normal(size=(n, 3))
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    return o, d


def best_of(fn, reps):
    fn()                                          # warm-up (compile / commit)
    wall, cpu = [], []
    for _ in range(reps):
        c = time.process_time()
        t = time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    k = int(np.argmin(wall))
    return wall[k], cpu[k]


def bench_mesh(n_tri, o32, d32, reps):
    n_lon, n_lat = SPHERES[n_tri]
    v, f = uv_sphere(n_lon, n_lat)
    assert len(f) == n_tri
    n = len(o32)
    out = {"triangles": int(n_tri), "rays": int(n)}

    sc = Scene()
    sc.add_object(TriangleMesh(v, f, uvs=np.zeros((len(f), 3, 2)), name="sphere"))
    t = time.perf_counter()
    g, info = compile_geometry(sc)
    out["ours_build_s"] = round(time.perf_counter() - t, 3)
    o64, d64 = o32.astype(np.float64), d32.astype(np.float64)

    res = {}
    for th in (1, 2):
        numba.set_num_threads(th)
        w, c = best_of(lambda: res.__setitem__(th, raycast.trace_closest_batch(g, o64, d64)), reps)
        out[f"ours_{th}t_mrays"] = round(n / w / 1e6, 3)
        out[f"ours_{th}t_cpu_over_wall"] = round(c / w, 2)
        w, _ = best_of(lambda: raycast.occluded_batch(g, o64, d64), reps)
        out[f"ours_{th}t_occluded_mrays"] = round(n / w / 1e6, 3)
    t_ours, _, shape_ours = res[1]
    assert np.array_equal(res[1][0], res[2][0]), "thread counts disagree"
    hit_ours = shape_ours >= 0

    try:
        from embreex import rtcore_scene as rtcs
        from embreex.mesh_construction import TriangleMesh as EmbreeMesh
    except ImportError:
        out["embree"] = "embreex not installed"
        return out
    es = rtcs.EmbreeScene()
    EmbreeMesh(es, np.ascontiguousarray(v[f], dtype=np.float32))
    t = time.perf_counter()
    es.run(o32[:1], d32[:1])                      # first run commits (builds) the scene
    out["embree_build_s"] = round(time.perf_counter() - t, 3)
    emb = {}
    w, c = best_of(lambda: emb.__setitem__("r", es.run(o32, d32, output=1)), reps)
    out["embree_mrays"] = round(n / w / 1e6, 3)
    out["embree_cpu_over_wall"] = round(c / w, 2)   # ~1.0: one thread
    w, _ = best_of(lambda: es.run(o32, d32, query="OCCLUDED"), reps)
    out["embree_occluded_mrays"] = round(n / w / 1e6, 3)
    hit_emb = emb["r"]["primID"] >= 0
    out["hits_embree"] = int(hit_emb.sum())
    out["hits_ours"] = int(hit_ours.sum())
    # Embree tests float32 triangles and is not watertight, so rays grazing
    # an edge may differ; anything beyond a handful would be a bug
    out["hit_disagreements"] = int(np.sum(hit_emb != hit_ours))
    # hit distances agree to Embree's float32 precision (the sphere has radius 1)
    both = hit_emb & hit_ours
    diff = np.abs(emb["r"]["tfar"][both].astype(np.float64) - t_ours[both])
    out["t_max_abs_diff"] = float(diff.max()) if both.any() else 0.0
    for th in (1, 2):
        out[f"ratio_ours_{th}t_over_embree"] = round(out[f"ours_{th}t_mrays"] / out["embree_mrays"], 3)
    out["scaling_2t_over_1t"] = round(out["ours_2t_mrays"] / out["ours_1t_mrays"], 3)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rays", type=int, default=1_000_000)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--sizes", default="100000,800000")
    a = ap.parse_args()
    o32, d32 = rays(a.rays)
    report = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
              "numba": numba.__version__, "threading_layer": None,
              "load_avg_start": os.getloadavg()[0], "results": []}
    for n_tri in (int(s) for s in a.sizes.split(",")):
        report["results"].append(bench_mesh(n_tri, o32, d32, a.reps))
        report["threading_layer"] = numba.threading_layer()
    report["load_avg_end"] = os.getloadavg()[0]
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
