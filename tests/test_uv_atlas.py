"""xatlas lightmap unwrap: layout validity, input order, chart separation, caching."""
import time

import numpy as np
import pytest

from photon_lightmaps.engine import lightmap as LM
from photon_lightmaps.engine import uv_atlas as UA


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
    UA.clear_memory_cache()
    yield tmp_path
    UA.clear_memory_cache()


@pytest.fixture(scope="module")
def torus():
    return _torus_mesh()


def test_unwrap_layout_and_order(cache, torus):
    v, tri = torus
    res = UA.unwrap_atlas(v, tri, resolution=64)
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
    res = UA.unwrap_atlas(v, tri, resolution=R)
    charts = np.unique(res.chart)
    assert charts.size >= 2
    masks = []
    for c in charts:
        sel = res.chart == c
        _, cov = LM.triangle_texel_areas(res.uv[sel], np.ones(sel.sum()), R, R)
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
    res = UA.unwrap_atlas(v, tri, resolution=24)
    assert res.min_resolution <= 24 * 1.01
    assert res.uv.min() >= 0.0 and res.uv.max() <= 1.0


def test_cache_identical_and_fast(cache, torus):
    v, tri = torus
    t0 = time.perf_counter()
    uv1 = UA.unwrap(v, tri, resolution=48)
    t_first = time.perf_counter() - t0
    assert any(cache.joinpath("uv").glob("*.npz"))
    t0 = time.perf_counter()
    uv2 = UA.unwrap(v, tri, resolution=48)
    t_mem = time.perf_counter() - t0
    UA.clear_memory_cache()
    t0 = time.perf_counter()
    uv3 = UA.unwrap(v, tri, resolution=48)
    t_disk = time.perf_counter() - t0
    assert uv1.tobytes() == uv2.tobytes() == uv3.tobytes()
    assert t_mem < 0.2 * t_first and t_disk < 0.5 * t_first
    uv2[:] = -1.0                       # callers own their copy
    assert UA.unwrap(v, tri, resolution=48).tobytes() == uv1.tobytes()
    # Different input -> different cache entry.
    v2 = v * 2.0
    assert UA.unwrap_atlas(v2, tri, resolution=48).uv.shape == uv1.shape
    assert len(list(cache.joinpath("uv").glob("*.npz"))) == 2


def test_corrupt_cache_file_is_redone(cache, torus):
    v, tri = torus
    uv1 = UA.unwrap(v, tri, resolution=32)
    for f in cache.joinpath("uv").glob("*.npz"):
        f.write_bytes(b"garbage")
    UA.clear_memory_cache()
    assert UA.unwrap(v, tri, resolution=32).tobytes() == uv1.tobytes()


def test_degenerate_faces_keep_their_slot(cache):
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [3, 0, 0]], float)
    tri = np.array([[0, 1, 2], [1, 4, 5], [0, 2, 3], [2, 2, 3]])   # 2nd: collinear, 4th: repeated
    res = UA.unwrap_atlas(v, tri, resolution=16)
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
    out, chart = UA._to_original_order(t, vmap, idx, uv_px, vchart)
    np.testing.assert_array_equal(out[0], uv_px[[3, 4, 5]])
    np.testing.assert_array_equal(out[1], uv_px[[0, 1, 2]])
    np.testing.assert_array_equal(out[2], uv_px[[8, 6, 7]])
    np.testing.assert_array_equal(chart, [6, 5, 7])


def test_unwrap_feeds_exact_texel_areas(cache, torus):
    v, tri = torus
    res = UA.unwrap_atlas(v, tri, resolution=40)
    a3 = LM.triangle_world_areas(v[tri])
    area, cov = LM.triangle_texel_areas(res.uv, a3, res.resolution, res.resolution)
    assert abs(area.sum() - a3.sum()) <= 1e-12 * a3.sum()
    assert cov.max() <= 1.0 and (cov > 0).sum() > 0.2 * cov.size


def test_bad_input(cache):
    with pytest.raises(ValueError):
        UA.unwrap(np.zeros((3, 2)), np.array([[0, 1, 2]]))
    with pytest.raises(ValueError):
        UA.unwrap(np.zeros((3, 3)), np.array([[0, 1, 3]]))
    with pytest.raises(ValueError):
        UA.unwrap(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
    assert UA.unwrap(np.zeros((3, 3)), np.zeros((0, 3), int)).shape == (0, 3, 2)
