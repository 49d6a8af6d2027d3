"""xatlas lightmap unwrap: layout validity, input order, chart separation, caching."""
import subprocess
import time

import numpy as np
import pytest

from photon_lightmaps.engine.lightmaps import texel_areas
from photon_lightmaps.engine.lightmaps import uv_atlas
from photon_lightmaps.engine.core.scene import SceneError


def _torus_mesh(n=32, m=14, major=1.0, minor=0.35):
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    phi = 2 * np.pi * i / n
    th = 2 * np.pi * j / m
    r = major + minor * np.cos(th)
    v = np.stack([r * np.cos(phi), r * np.sin(phi), minor * np.sin(th)], axis=-1).reshape(-1, 3)
    a = (i * m + j).reshape(-1)
    b = (((i + 1) % n) * m + j).reshape(-1)
    c = (((i + 1) % n) * m + (j + 1) % m).reshape(-1)
    d = (i * m + (j + 1) % m).reshape(-1)
    tri = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    # Interleave the two halves so face order is not the grid order xatlas would pick.
    return v, tri[np.random.default_rng(0).permutation(tri.shape[0])]


def _uv_area(uv):
    a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]
    return 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1]))


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path))
    uv_atlas.clear_memory_cache()
    yield tmp_path
    uv_atlas.clear_memory_cache()


@pytest.fixture(scope="module")
def torus():
    return _torus_mesh()


def test_unwrap_layout_and_order(cache, torus):
    v, tri = torus
    res = uv_atlas.unwrap_atlas(v, tri, resolution=64)
    uv = res.uv
    assert uv.shape == (tri.shape[0], 3, 2) and uv.dtype == np.float64
    assert uv.min() >= 0.0 and uv.max() <= 1.0
    assert np.all(res.chart >= 0)
    a3 = 0.5 * np.linalg.norm(np.cross(v[tri[:, 1]] - v[tri[:, 0]], v[tri[:, 2]] - v[tri[:, 0]]), axis=1)
    ua = _uv_area(uv)
    assert np.all(ua > 0)
    assert ua.sum() <= 1.0
    # xatlas charts are near-isometric: UV/world area ratio is similar for every
    # triangle. A face-order mix-up would pair UVs with the wrong world triangle.
    ratio = ua / a3
    assert ratio.max() / ratio.min() < 4.0
    # Same for every corner: UV edge lengths follow world edge lengths.
    for c0, c1 in ((0, 1), (1, 2), (2, 0)):
        le = np.linalg.norm(v[tri[:, c1]] - v[tri[:, c0]], axis=1)
        lu = np.linalg.norm(uv[:, c1] - uv[:, c0], axis=1)
        q = lu / le
        assert q.max() / q.min() < 4.0


def test_charts_never_share_or_touch_texels(cache, torus):
    v, tri = torus
    R = 64
    res = uv_atlas.unwrap_atlas(v, tri, resolution=R)
    charts = np.unique(res.chart)
    assert charts.size >= 2
    masks = []
    for c in charts:
        sel = res.chart == c
        _, cov = texel_areas.triangle_texel_areas(res.uv[sel], np.ones(sel.sum()), R, R)
        masks.append((cov > 0).reshape(R, R))
    # A bilinear lookup reads up to 1.5 texels from its chart and dilation reaches
    # one further: texels of different charts must be at least 3 texels apart.
    for i, mi in enumerate(masks):
        grown = np.zeros_like(mi)
        for dy in range(-2, 3):
            for dx in range(-2, 3):
                grown |= np.roll(np.roll(np.pad(mi, 2), dy, 0), dx, 1)[2:-2, 2:-2]
        for j, mj in enumerate(masks):
            if i != j:
                assert not np.any(grown & mj), (i, j)


def test_small_resolution_repacks(cache, torus):
    v, tri = torus
    res = uv_atlas.unwrap_atlas(v, tri, resolution=24)
    assert res.min_resolution <= 24 * 1.01
    assert res.uv.min() >= 0.0 and res.uv.max() <= 1.0


def test_cache_identical_and_fast(cache, torus):
    v, tri = torus
    t0 = time.perf_counter()
    uv1 = uv_atlas.unwrap(v, tri, resolution=48)
    t_first = time.perf_counter() - t0
    assert any(cache.joinpath("uv").glob("*.npz"))
    t0 = time.perf_counter()
    uv2 = uv_atlas.unwrap(v, tri, resolution=48)
    t_mem = time.perf_counter() - t0
    uv_atlas.clear_memory_cache()
    t0 = time.perf_counter()
    uv3 = uv_atlas.unwrap(v, tri, resolution=48)
    t_disk = time.perf_counter() - t0
    assert uv1.tobytes() == uv2.tobytes() == uv3.tobytes()
    assert t_mem < 0.2 * t_first and t_disk < 0.5 * t_first
    uv2[:] = -1.0                       # callers own their copy
    assert uv_atlas.unwrap(v, tri, resolution=48).tobytes() == uv1.tobytes()
    # Different input -> different cache entry.
    v2 = v * 2.0
    assert uv_atlas.unwrap_atlas(v2, tri, resolution=48).uv.shape == uv1.shape
    assert len(list(cache.joinpath("uv").glob("*.npz"))) == 2


def test_corrupt_cache_file_is_redone(cache, torus):
    v, tri = torus
    uv1 = uv_atlas.unwrap(v, tri, resolution=32)
    for f in cache.joinpath("uv").glob("*.npz"):
        f.write_bytes(b"garbage")
    uv_atlas.clear_memory_cache()
    assert uv_atlas.unwrap(v, tri, resolution=32).tobytes() == uv1.tobytes()


def test_degenerate_faces_keep_their_slot(cache):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0]], float)
    tri = np.array([[0, 1, 2], [1, 4, 5], [0, 2, 3], [2, 2, 3]])   # 2nd: collinear, 4th: repeated
    res = uv_atlas.unwrap_atlas(v, tri, resolution=16)
    ua = _uv_area(res.uv)
    assert ua[0] > 0 and ua[2] > 0 and ua[1] == 0 and ua[3] == 0
    assert list(res.chart[[1, 3]]) == [-1, -1]
    # the two real triangles form the unit square: equal UV areas
    assert abs(ua[0] - ua[2]) < 1e-6


def test_reordered_xatlas_output_is_mapped_back():
    # Simulate xatlas returning faces shuffled and with rotated corners.
    t = np.array([[0, 1, 2], [2, 3, 0], [1, 3, 2]])
    vmap = np.array([2, 3, 0, 0, 1, 2, 3, 2, 1])       # output vertex -> input vertex
    idx = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])  # faces (2,3,0), (0,1,2), (3,2,1)
    uv_px = np.arange(18, dtype=float).reshape(9, 2)
    vchart = np.array([5, 5, 5, 6, 6, 6, 7, 7, 7])
    out, chart = uv_atlas._to_original_order(t, vmap, idx, uv_px, vchart)
    np.testing.assert_array_equal(out[0], uv_px[[3, 4, 5]])
    np.testing.assert_array_equal(out[1], uv_px[[0, 1, 2]])
    np.testing.assert_array_equal(out[2], uv_px[[8, 6, 7]])
    np.testing.assert_array_equal(chart, [6, 5, 7])


def test_unwrap_feeds_exact_texel_areas(cache, torus):
    v, tri = torus
    res = uv_atlas.unwrap_atlas(v, tri, resolution=40)
    a3 = texel_areas.triangle_world_areas(v[tri])
    area, cov = texel_areas.triangle_texel_areas(res.uv, a3, res.resolution, res.resolution)
    assert abs(area.sum() - a3.sum()) <= 1e-12 * a3.sum()
    assert cov.max() <= 1.0 and (cov > 0).sum() > 0.2 * cov.size


def test_bad_input(cache):
    launches = uv_atlas.worker_launches
    with pytest.raises(uv_atlas.UnwrapError):
        uv_atlas.unwrap(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(uv_atlas.UnwrapError, match="out of range"):
        uv_atlas.unwrap(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    v = np.eye(3)
    v[1, 2] = np.nan
    with pytest.raises(SceneError, match="NaN or infinity") as e:
        uv_atlas.unwrap(v, np.array([[0, 1, 2]]))
    assert isinstance(e.value, uv_atlas.UnwrapError) and isinstance(e.value, ValueError)
    assert "vertex 1" in str(e.value) and e.value.triangles == 1
    assert uv_atlas.unwrap(np.zeros((3, 3)), np.zeros((0, 3), int)).shape == (0, 3, 2)
    # Caught before xatlas: no child process for any of them.
    assert uv_atlas.worker_launches == launches


def _uv_sphere(seg, ring):
    th = np.pi * np.arange(1, ring) / ring
    ph = 2 * np.pi * np.arange(seg) / seg
    ring_v = np.stack([np.sin(th)[:, None] * np.cos(ph), np.sin(th)[:, None] * np.sin(ph),
                       np.cos(th)[:, None] * np.ones(seg)], -1).reshape(-1, 3)
    v = np.concatenate([[[0, 0, 1]], ring_v, [[0, 0, -1]]])
    j = np.arange(seg)
    top = np.stack([np.zeros(seg, int), 1 + j, 1 + (j + 1) % seg], 1)
    i, j2 = np.meshgrid(np.arange(ring - 2), j, indexing="ij")
    a = 1 + i * seg + j2
    b = 1 + i * seg + (j2 + 1) % seg
    quads = np.concatenate([np.stack([a, a + seg, b + seg], -1), np.stack([a, b + seg, b], -1)], -1)
    n, last = len(v) - 1, 1 + (ring - 2) * seg
    bottom = np.stack([np.full(seg, n), last + (j + 1) % seg, last + j], 1)
    return v, np.concatenate([top, quads.reshape(-1, 3), bottom])


def test_xatlas_crash_is_contained_and_the_batch_goes_on(cache, torus):
    """xatlas 0.0.11 segfaults on this sphere: the job fails, this process lives on,
    and a new child unwraps the mesh after it."""
    sphere = _uv_sphere(512, 256)
    v, tri = torus
    calls = []
    launches = uv_atlas.worker_launches
    bad, good = uv_atlas.unwrap_many([(*sphere, 64), dict(vertices=v, triangles=tri, resolution=64)],
                                     progress=lambda done, total: calls.append((done, total)))
    assert uv_atlas.worker_launches == launches + 2       # restarted once, after the crash
    assert isinstance(bad, uv_atlas.UnwrapError) and isinstance(bad, SceneError)
    assert bad.reason == "xatlas crashed (SIGSEGV)" and bad.triangles == 261_120
    assert "unwrapping 261,120 triangles" in str(bad) and "'Lightmap'" in str(bad)
    assert isinstance(good, uv_atlas.AtlasResult) and np.all(good.chart >= 0)
    ref = uv_atlas.unwrap_atlas(v, tri, resolution=64, use_cache=False)
    assert good.uv.tobytes() == ref.uv.tobytes() and good.min_resolution == ref.min_resolution
    assert calls[-1] == (2, 2)
    # A crash is not stored on disk, but this process remembers it: asking again
    # (a bake's prepass, then the bake) fails the same way without a worker.
    assert len(list(cache.joinpath("uv").glob("*.npz"))) == 1       # the torus only
    launches = uv_atlas.worker_launches
    with pytest.raises(uv_atlas.UnwrapError, match=r"xatlas crashed \(SIGSEGV\)") as e:
        uv_atlas.unwrap(*sphere, resolution=64)
    assert uv_atlas.worker_launches == launches and e.value.triangles == 261_120
    uv_atlas.clear_memory_cache()
    with pytest.raises(uv_atlas.UnwrapError, match=r"xatlas crashed \(SIGSEGV\)"):
        uv_atlas.unwrap(*sphere, resolution=64)
    assert uv_atlas.worker_launches == launches + 1


def test_cache_hits_start_no_worker(cache, torus):
    v, tri = torus
    launches = uv_atlas.worker_launches
    uv = uv_atlas.unwrap(v, tri, resolution=40)
    assert uv_atlas.worker_launches == launches + 1
    assert uv_atlas.unwrap(v, tri, resolution=40).tobytes() == uv.tobytes()     # memory
    uv_atlas.clear_memory_cache()
    assert uv_atlas.unwrap(v, tri, resolution=40).tobytes() == uv.tobytes()     # disk
    assert uv_atlas.worker_launches == launches + 1
    # A batch sends only its misses, each distinct mesh once, to one child.
    out = uv_atlas.unwrap_many([(v, tri, 40), (v * 2, tri, 40), (v, tri, 40), (v * 2, tri, 40)])
    assert uv_atlas.worker_launches == launches + 2
    assert out[0].uv.tobytes() == out[2].uv.tobytes() == uv.tobytes()
    assert out[1].uv.tobytes() == out[3].uv.tobytes()
    out[1].uv[:] = 0                                  # each job owns its copy
    assert out[3].uv.max() > 0


def test_should_stop_kills_the_worker(cache, torus, monkeypatch):
    from photon_lightmaps.engine.core.errors import Cancelled
    procs = []

    class Recorded(subprocess.Popen):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            procs.append(self)

    monkeypatch.setattr(subprocess, "Popen", Recorded)
    v, tri = torus
    t0 = time.perf_counter()
    with pytest.raises(Cancelled):
        uv_atlas.unwrap_many([(v, tri, 32), (v * 2, tri, 32)], should_stop=lambda: True)
    assert time.perf_counter() - t0 < 5.0
    assert len(procs) == 1 and procs[0].returncode is not None   # killed and reaped
    assert not any(cache.joinpath("uv").glob("*.npz"))


def test_worker_that_cannot_start_raises(cache, torus, monkeypatch):
    monkeypatch.setattr(uv_atlas, "_WORKER", str(cache / "no_such_worker.py"))
    v, tri = torus
    with pytest.raises(uv_atlas.UnwrapError, match="could not start") as e:
        uv_atlas.unwrap(v, tri)
    assert "no_such_worker.py" in str(e.value)     # the child's stderr tail
    # Not remembered: once the worker can start, the mesh is unwrapped.
    monkeypatch.undo()
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(cache))
    assert uv_atlas.unwrap(v, tri).shape == (tri.shape[0], 3, 2)


_HANGING_WORKER = """
import os, runpy, sys, time
folder, start = sys.argv[1], sys.argv[2]
marker = os.path.join({mark!r}, "hung_once")
if start == "0" and ({always!r} or not os.path.exists(marker)):
    open(marker, "w").close()
    print({tag!r}, "start", 0, flush=True)
    time.sleep(600)
sys.argv = [{real!r}, folder, start]
runpy.run_path({real!r}, run_name="__main__")
"""


def _hanging_worker(monkeypatch, folder, always):
    """A worker whose job 0 hangs (once, or every time); the rest run for real."""
    path = folder / "hanging_worker.py"
    path.write_text(_HANGING_WORKER.format(mark=str(folder), always=always, tag=uv_atlas._W.TAG,
                                           real=uv_atlas._WORKER))
    monkeypatch.setattr(uv_atlas, "_WORKER", str(path))
    monkeypatch.setattr(uv_atlas, "_STALL_BASE_S", 2.0)
    monkeypatch.setattr(uv_atlas, "_STALL_S_PER_TRIANGLE", 0.0)


def test_a_hung_job_is_killed_and_tried_again(cache, torus, monkeypatch):
    v, tri = torus
    ref = uv_atlas.unwrap_atlas(v, tri, resolution=32, use_cache=False)
    _hanging_worker(monkeypatch, cache, always=False)
    launches = uv_atlas.worker_launches
    t0 = time.perf_counter()
    out = uv_atlas.unwrap_many([(v, tri, 32), (v * 2, tri, 32)])
    assert 2.0 < time.perf_counter() - t0 < 30.0
    assert uv_atlas.worker_launches == launches + 2           # the stuck one, then one for both
    assert out[0].uv.tobytes() == ref.uv.tobytes() and np.all(out[1].chart >= 0)


def test_a_job_that_hangs_twice_fails_and_the_batch_goes_on(cache, torus, monkeypatch):
    v, tri = torus
    _hanging_worker(monkeypatch, cache, always=True)
    launches = uv_atlas.worker_launches
    bad, good = uv_atlas.unwrap_many([(v, tri, 32), (v * 2, tri, 32)])
    assert uv_atlas.worker_launches == launches + 3
    assert isinstance(bad, uv_atlas.UnwrapError) and bad.reason == "xatlas did not finish within 2 s, twice"
    assert f"unwrapping {tri.shape[0]:,} triangles" in str(bad)
    assert isinstance(good, uv_atlas.AtlasResult) and np.all(good.chart >= 0)


def test_pack_islands_in_the_worker(cache, torus):
    v, tri = torus
    res = uv_atlas.unwrap_atlas(v, tri, resolution=32)
    uv, min_res = uv_atlas.pack_islands(v, tri, res.uv * 10.0, res.chart, 32)
    assert uv.shape == tri.shape + (2,) and uv.min() >= 0 and uv.max() <= 1
    assert np.all(_uv_area(uv) > 0) and min_res <= 32 * 1.01
    with pytest.raises(uv_atlas.UnwrapError):
        uv_atlas.pack_islands(v, tri, np.full((len(tri), 3, 2), np.nan), res.chart, 32)
