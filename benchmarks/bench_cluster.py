"""Photon passes on a loopback Dask cluster against one process: efficiency, per-task
overhead and the bytes moved (engine/cluster.py), measured in the same run.

The Cornell room (demo_scenes.cornell_box, 16 texels per metre), a photon pass of
PHOTONS photons in blocks of BLOCK, traced

* in this process on 2 threads (the local run),
* in this process on 1 thread (what one block costs one core),
* on a local cluster of 2 worker processes with 1 thread each (the same 2 cores),

each after a warm-up, best of three. Both multi-block runs give the same lightmaps,
bit for bit (checked here too). Efficiency is the local run's time over the
cluster's; the per-task overhead is what the cluster takes beyond its blocks'
single-thread time, per block task and worker. Bytes moved are the pickled scene
(broadcast once per pass to each worker) and the block tallies (dense flux,
flux_sq and hits: one per block and one per inner tree node, each crossing the
network at most once).

A bake's gathers the same way: the room at BAKE_DENSITY texels per metre,
baked with the default gather (direct light, irradiance-cache records and
interpolation, per-texel fallbacks, at BAKE_RAYS rays per point). Its
bake_texels is timed here on 2 threads, here on 1 thread, and with its kernel
calls as tasks on the 2 workers (Cluster.kernels); the photon pass before it
runs here and is not timed.

    .venv/bin/python -m benchmarks.bench_cluster          # about five minutes on 2 cores
"""
import json
import os
import pathlib
import pickle
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import numba  # noqa: E402
import numpy as np  # noqa: E402

import photon_lightmaps.engine  # noqa: E402,F401  (sets the numba cache before numba loads)
from photon_lightmaps.engine import demo_scenes, session  # noqa: E402
from photon_lightmaps.engine.cluster import Cluster  # noqa: E402
from photon_lightmaps.engine.transport import photon_tracer  # noqa: E402

PHOTONS = 8_000_000
BLOCK = 1_000_000
OUT = ROOT / "benchmarks" / "charts" / "cluster.json"


def run(cluster=None, photons=PHOTONS, block=BLOCK, repeats=3):
    best = None
    for _ in range(repeats):
        cs = session.compile(demo_scenes.cornell_box(n_bands=3))
        t0 = time.perf_counter()
        stats = photon_tracer.trace_photons(cs, photons, seed=1, record_direct=True, block=block, cluster=cluster)
        dt = time.perf_counter() - t0
        if best is None or dt < best[0]:
            best = (dt, cs, stats)
    return best


BAKE_PHOTONS = 300_000
BAKE_RAYS = 16
BAKE_DENSITY = 64.0     # texels per metre: 16 x the room's texels, a bake that takes seconds


def bake(cluster=None, repeats=3):
    """Best of `repeats`: seconds of a gathered bake's bake_texels, the compiled scene."""
    import contextlib
    settings = session.Settings(photons=BAKE_PHOTONS, bake_photons=BAKE_PHOTONS, seed=1,
                                bake_gather_rays=BAKE_RAYS)
    best = None
    for _ in range(repeats):
        room = demo_scenes.cornell_box(n_bands=3)
        room.texel_density = BAKE_DENSITY
        cs, _ = session.compile_and_trace_bake(room, settings)
        ids = sorted(int(lid) for lids in cs.instance_lightmaps for lid in lids)
        t0 = time.perf_counter()
        with cluster.kernels() if cluster is not None else contextlib.nullcontext():
            session.bake_texels(cs, ids, [], settings)
        dt = time.perf_counter() - t0
        if best is None or dt < best[0]:
            best = (dt, cs)
    return best


def bake_report(c):
    threads = numba.get_num_threads()
    bake(repeats=1)
    t_local, cs_local = bake()
    numba.set_num_threads(1)
    t_one, _ = bake()
    numba.set_num_threads(threads)
    bake(c, repeats=1)
    before = c.tasks
    t_cluster, cs_cluster = bake(c)
    tasks = (c.tasks - before) // 3
    identical = bool(np.array_equal(cs_local.lightmaps.irradiance, cs_cluster.lightmaps.irradiance))
    scene_bytes = len(pickle.dumps(cs_local))
    report = dict(photons=BAKE_PHOTONS, gather_rays=BAKE_RAYS, texels=int(cs_local.bake_error[0].size),
                  irradiance_cache=cs_local.info.get("irradiance_cache"),
                  local_seconds=t_local, one_thread_seconds=t_one, cluster_seconds=t_cluster,
                  efficiency=t_local / t_cluster, tasks=tasks,
                  overhead_per_task_seconds=(t_cluster * 2 - t_one) / tasks, identical=identical,
                  scene_bytes=scene_bytes)
    print(f"bake gathers: local ({threads} threads) {t_local:.2f} s, one thread {t_one:.2f} s, cluster "
          f"(2 workers x 1 thread) {t_cluster:.2f} s in {tasks} tasks: efficiency {report['efficiency']:.2f}, "
          f"overhead {report['overhead_per_task_seconds'] * 1e3:.0f} ms per task; identical: {identical}")
    return report


def main():
    threads = numba.get_num_threads()
    run(photons=20_000, block=5_000, repeats=1)                  # kernels loaded
    t_local, cs_local, _ = run()
    numba.set_num_threads(1)
    t_one, _, _ = run(photons=BLOCK, block=BLOCK)
    numba.set_num_threads(threads)
    with Cluster.local(workers=2) as c:
        run(cluster=c, photons=20_000, block=5_000, repeats=1)  # the workers' kernels loaded
        t_cluster, cs_cluster, _ = run(cluster=c)
        bake_part = bake_report(c)
    identical = bool(np.array_equal(cs_local.lightmaps.flux, cs_cluster.lightmaps.flux))
    blocks = -(-PHOTONS // BLOCK)
    scene_bytes = len(pickle.dumps(cs_local))
    lm = cs_local.lightmaps                 # a block's tally: dense flux, flux_sq and hits
    tally_bytes = int(lm.flux.nbytes + lm.flux_sq.nbytes + lm.hits.nbytes)
    overhead = (t_cluster * 2 - blocks * t_one) / blocks
    report = dict(photons=PHOTONS, block=BLOCK, blocks=blocks, scene="cornell_box",
                  local_seconds=t_local, local_threads=threads, one_block_one_thread_seconds=t_one,
                  cluster_seconds=t_cluster, cluster_workers=2, efficiency=t_local / t_cluster,
                  overhead_per_task_seconds=overhead, identical=identical,
                  scene_bytes=scene_bytes, tally_bytes=tally_bytes,
                  bytes_moved=2 * scene_bytes + (2 * blocks - 1) * tally_bytes,
                  lightmap_texels=int(cs_local.lightmaps.flux.shape[0]), bake=bake_part)
    print(f"local ({threads} threads) {t_local:.2f} s, cluster (2 workers x 1 thread) {t_cluster:.2f} s: "
          f"efficiency {report['efficiency']:.2f}; one block on one thread {t_one:.2f} s, "
          f"overhead {overhead * 1e3:.0f} ms per task; scene {scene_bytes / 2**20:.1f} MiB, "
          f"tally {tally_bytes / 2**20:.2f} MiB, moved {report['bytes_moved'] / 2**20:.1f} MiB; "
          f"identical: {identical}")
    OUT.write_text(json.dumps(report, indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
