"""Photon passes on a Dask cluster (engine/cluster.py): a loopback cluster of worker
processes gives the lightmaps of the local run bit for bit, survives a worker killed
mid-pass, refuses workers of another engine version by name, and cancels cleanly."""
import os
import signal
import threading

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes, session
from photon_lightmaps.engine.cluster import Cluster, ClusterError
from photon_lightmaps.engine.core.errors import Cancelled
from photon_lightmaps.engine.transport import photon_tracer

PHOTONS, BLOCK = 50_000, 8192           # 7 blocks: a tree that is not a power of two


def scene():
    return demo_scenes.cornell_box(n_bands=3, width=16, height=16)


def traced(cluster=None, block=BLOCK, caustics=True, progress=None):
    cs = session.compile(scene())
    stats = photon_tracer.trace_photons(cs, PHOTONS, seed=5, record_direct=True, caustics=caustics, gather=True,
                                        block=block, cluster=cluster, progress=progress)
    return cs, stats


def assert_identical(a, b):
    (ca, sa), (cb, sb) = a, b
    for lm_a, lm_b in ((ca.lightmaps, cb.lightmaps), (ca.caustics, cb.caustics)):
        for name in ("flux", "flux_sq", "hits", "irradiance"):
            assert np.array_equal(getattr(lm_a, name), getattr(lm_b, name)), name
    for name in ("emitted", "absorbed", "escaped", "truncated"):
        assert np.array_equal(getattr(sa, name), getattr(sb, name)), name
    assert (sa.rays, sa.records, sa.photons) == (sb.rays, sb.records, sb.photons)


@pytest.fixture(scope="module")
def cluster():
    with Cluster.local(workers=2) as c:
        yield c


@pytest.fixture(scope="module")
def local():
    return traced()


def test_blocks_tree_is_fixed():
    """The tree over block indices: left subtrees are powers of two, whatever the count."""
    assert [photon_tracer.tree_split(0, n) for n in (2, 3, 4, 5, 7, 8, 9)] == [1, 2, 2, 4, 4, 4, 8]
    order = photon_tracer.reduce_blocks(lambda k: str(k), 7, add=lambda a, b: f"({a}+{b})")
    assert order == "(((0+1)+(2+3))+((4+5)+6))"


def test_one_block_adds_in_photon_order_as_before(local):
    """A pass within one block is the straight photon-order sum; split into blocks its
    lightmaps differ only by rounding (and the energy ledger balances either way)."""
    one = traced(block=PHOTONS)
    cs1, s1 = one
    cs7, s7 = local
    assert s1.audit_error() < 1e-12 and s7.audit_error() < 1e-12
    np.testing.assert_allclose(cs7.lightmaps.flux, cs1.lightmaps.flux, rtol=1e-9, atol=1e-15)
    assert np.array_equal(cs7.lightmaps.hits, cs1.lightmaps.hits)


def test_local_cluster_is_bit_identical(cluster, local):
    """Two worker processes, seven blocks: the same lightmaps (main and caustic), ledger,
    ray and record counts as the local run, bit for bit; one block alone too."""
    assert cluster.workers == 2
    assert_identical(traced(cluster), local)
    assert_identical(traced(cluster, block=PHOTONS), traced(block=PHOTONS))


def test_a_worker_killed_mid_pass_changes_nothing(local):
    """A worker process dies after the first block is in: its tasks run elsewhere (or on
    the restarted worker) and the result is the same, bit for bit."""
    with Cluster.local(workers=2) as c:
        pids = c.client.run(os.getpid)
        victim = pids[sorted(pids)[0]]
        killed = threading.Event()

        def progress(done, total):
            if not killed.is_set():
                killed.set()
                os.kill(victim, signal.SIGKILL)         # a crash, not a shutdown
            return True
        result = traced(c, progress=progress)
    assert killed.is_set()
    assert_identical(result, local)


def test_cancel_stops_the_cluster_and_writes_nothing(cluster):
    calls = []

    def progress(done, total):
        calls.append(done)
        return False
    cs = session.compile(scene())
    with pytest.raises(Cancelled):
        photon_tracer.trace_photons(cs, PHOTONS, seed=5, block=BLOCK, cluster=cluster, progress=progress)
    assert len(calls) == 1
    assert not cs.lightmaps.flux.any() and not cs.lightmaps.hits.any()
    # the cluster is free again: a pass after it runs
    cs2, stats = traced(cluster, block=PHOTONS)
    assert stats.photons == PHOTONS


def test_a_worker_of_another_version_is_refused_by_name(cluster):
    """A worker whose engine source differs (its hash) is named, before any work."""
    address = sorted(cluster.client.scheduler_info()["workers"])[1]

    def pretend_other_version():
        from photon_lightmaps.engine import cluster as module
        module.engine_version.cache_clear()
        module._real_version = getattr(module, "_real_version", module.engine_version)
        module.engine_version = lambda: "0" * 64

    def restore():
        from photon_lightmaps.engine import cluster as module
        module.engine_version = module._real_version
    cluster.client.run(pretend_other_version, workers=[address])
    try:
        with pytest.raises(ClusterError, match=f"worker {address} runs another version of the engine"):
            cluster.check_versions()
    finally:
        cluster.client.run(restore, workers=[address])
    cluster.check_versions()


def test_without_dask_a_cluster_is_refused_clearly(monkeypatch):
    import builtins
    real = builtins.__import__

    def no_dask(name, *a, **k):
        if name == "distributed" or name.startswith("distributed."):
            raise ImportError(name)
        return real(name, *a, **k)
    monkeypatch.setattr(builtins, "__import__", no_dask)
    with pytest.raises(ClusterError, match="needs Dask"):
        Cluster.local(2)


def test_a_worker_started_from_the_cli_serves_a_scheduler(local):
    """`python -m photon_lightmaps worker ADDRESS` joins a scheduler; a pass through
    Cluster.connect on it gives the local run's lightmaps, bit for bit."""
    import subprocess
    import sys
    import time
    from distributed import LocalCluster
    with LocalCluster(n_workers=0, processes=False, protocol="tcp://", host="127.0.0.1",
                      dashboard_address=":0") as sched:
        worker = subprocess.Popen([sys.executable, "-m", "photon_lightmaps", "worker", sched.scheduler_address,
                                   "--nthreads", "1"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            with Cluster.connect(sched.scheduler_address) as c:
                deadline = time.monotonic() + 120
                while c.workers < 1 and time.monotonic() < deadline:
                    time.sleep(0.2)
                assert c.workers == 1
                assert_identical(traced(c), local)
        finally:
            worker.terminate()
            out, _ = worker.communicate(timeout=60)
    assert "photon_lightmaps worker: engine" in out


def test_cli_render_on_workers_equals_the_local_render(tmp_path):
    """render --workers 2: the same image, bit for bit, as the render here."""
    import bpy  # noqa: F401  (bmesh, which demo_blend uses, needs bpy loaded first)
    from test_cli_commands import run
    from photon_lightmaps import demo_blend
    from photon_lightmaps.registration import ensure_registered
    ensure_registered()
    blend = tmp_path / "room.blend"
    demo_blend.build_cornell_blend(str(blend), width=24, height=16)
    images = {}
    for name, extra in (("here", ()), ("workers", ("--workers", "2"))):
        run("render", blend, "--out", tmp_path / f"{name}.exr", "--photons", "30000", "--seed", "2",
            "--samples", "1", "--json", tmp_path / f"{name}.json", *extra)
        img = bpy.data.images.load(str(tmp_path / f"{name}.exr"))
        images[name] = np.array(img.pixels[:], np.float32)
        bpy.data.images.remove(img)
    assert images["here"].any() and np.array_equal(images["here"], images["workers"])
    import json
    assert json.loads((tmp_path / "workers.json").read_text())["settings"].get("cluster") == "local:2"


def test_render_tiles_on_the_cluster_are_bit_identical(cluster, local):
    """The camera pass with its tiles on the workers (final gather on, two progressive
    passes): the same image as here, bit for bit."""
    from photon_lightmaps.engine.transport import renderer
    cs, _ = local
    here = renderer.render(cs, samples=3, seed=4, tile=8, gather=2, passes=[1, 2])
    there = renderer.render(cs, samples=3, seed=4, tile=8, gather=2, passes=[1, 2], cluster=cluster)
    assert here.any() and np.array_equal(here, there)
    assert cs.rays["render"] > 0


def baked(cluster=None, cache=True, should_stop=None, keep=None):
    """A gathered bake of the room: direct light, then the final gather (through the
    irradiance cache, or per texel) with an adaptive second pass."""
    import contextlib
    settings = session.Settings(photons=PHOTONS, bake_photons=PHOTONS, seed=3, bake_gather_rays=4,
                                bake_target_error=0.05, bake_irradiance_cache=cache)
    cs, _ = session.compile_and_trace_bake(scene(), settings)
    ids = sorted(int(lid) for lids in cs.instance_lightmaps for lid in lids)
    if keep is not None:
        keep.append(cs)
    with cluster.kernels(should_stop) if cluster is not None else contextlib.nullcontext():
        session.bake_texels(cs, ids, [], settings, should_stop=should_stop)
    return cs


@pytest.mark.parametrize("cache", [True, False], ids=["irradiance_cache", "per_texel"])
def test_bake_gathers_on_the_cluster_are_bit_identical(cluster, cache):
    """A bake's direct light, its irradiance-cache records and interpolation, and its
    per-texel gathers (both passes) as tasks: every lightmap array and the error
    estimate the same, bit for bit."""
    here = baked(cache=cache)
    before = cluster.tasks
    there = baked(cluster, cache=cache)
    assert cluster.tasks - before >= 3 * 2 * cluster.workers      # direct, gather, second pass at least
    for name in ("flux", "irradiance", "hits"):
        assert np.array_equal(getattr(here.lightmaps, name), getattr(there.lightmaps, name)), name
    assert here.lightmaps.irradiance.any()
    for a, b in zip(here.bake_error, there.bake_error):
        assert np.array_equal(a, b)
    assert here.info.get("irradiance_cache") == there.info.get("irradiance_cache")


def test_cancel_stops_a_bake_on_the_cluster_and_writes_nothing(cluster):
    """should_stop (Esc in Blender) asked as the gather's tasks finish: the tasks are
    cancelled, Cancelled is raised, the lightmaps are the photon pass's, and the
    cluster is free for the next bake."""
    asked, kept = [], []

    def stop():
        asked.append(1)
        return len(asked) >= 2
    with pytest.raises(Cancelled):
        baked(cluster, should_stop=stop, keep=kept)
    settings = session.Settings(photons=PHOTONS, bake_photons=PHOTONS, seed=3, bake_gather_rays=4,
                                bake_target_error=0.05)
    traced_only, _ = session.compile_and_trace_bake(scene(), settings)
    assert np.array_equal(kept[0].lightmaps.flux, traced_only.lightmaps.flux)
    assert len(asked) == 2
    assert np.array_equal(baked(cluster).lightmaps.irradiance, baked().lightmaps.irradiance)


def test_cli_bake_on_workers_equals_the_local_bake(tmp_path):
    """bake --workers 2 (photon pass, direct light and final gather through the
    irradiance cache on the workers; meshes, spheres and an exact-CSG bowl): every
    lightmap image the same, bit for bit, as the bake here."""
    import json
    import bpy  # noqa: F401  (bmesh, which demo_blend uses, needs bpy loaded first)
    from test_cli_commands import run
    from photon_lightmaps import demo_blend
    from photon_lightmaps.registration import ensure_registered
    ensure_registered()
    blend = tmp_path / "room.blend"
    demo_blend.build_cornell_blend(str(blend), width=24, height=16, spheres=True, csg=True)
    pixels, reports = {}, {}
    for name, extra in (("here", ()), ("workers", ("--workers", "2"))):
        run("bake", blend, "--out", tmp_path / name, "--photons", "30000", "--seed", "2", "--resolution", "16",
            "--bake-gather-rays", "4", "--json", tmp_path / f"{name}.json", *extra)
        reports[name] = json.loads((tmp_path / f"{name}.json").read_text())
        pixels[name] = {}
        for ob, row in reports[name]["objects"].items():
            img = bpy.data.images.load(row["path"])
            pixels[name][ob] = np.array(img.pixels[:], np.float32)
            bpy.data.images.remove(img)
    assert pixels["here"].keys() == pixels["workers"].keys()
    assert any(ob.startswith("csg") for ob in pixels["here"]), sorted(pixels["here"])
    for ob, here in pixels["here"].items():
        assert here.any() and np.array_equal(here, pixels["workers"][ob]), ob
    assert reports["workers"]["irradiance_cache"]["records"] == reports["here"]["irradiance_cache"]["records"] > 0
    # the gathers ran there: 2 tasks per worker for each large enough kernel call
    assert reports["here"]["cluster"] is None
    used = reports["workers"]["cluster"]
    assert used["address"] == "local:2" and used["workers"] == 2 and used["tasks"]["bake"] >= 8, used


def test_a_session_inside_blender_reads_workers_that_name_the_add_on_otherwise(tmp_path, local):
    """Inside Blender the add-on is the package bl_ext.<repository>.photon_lightmaps and a
    worker's is photon_lightmaps, and Dask pickles by those names. A session importing it
    as Blender does (photon_lightmaps itself blocked) on a local cluster: the photon pass
    and the bake's gathers give this process's arrays, bit for bit."""
    import pathlib
    import subprocess
    import sys
    root = pathlib.Path(__file__).resolve().parents[1]
    out = tmp_path / "named.npz"
    r = subprocess.run([sys.executable, str(root / "tests" / "blender_named_session.py"), str(root), str(out)],
                       capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    got = np.load(out)
    assert got["tasks"] > 0
    assert np.array_equal(got["flux"], local[0].lightmaps.flux)
    assert np.array_equal(got["baked"], baked().lightmaps.irradiance)
