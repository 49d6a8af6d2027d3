"""Photon lightmaps: exact texel areas, recording, reconstruction (thesis 3.5.2)."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine.lightmaps import texel_areas
from photon_lightmaps.engine.geometry import primitives

ALL_KINDS = (primitives.SPHERE, primitives.BOX, primitives.CYLINDER, primitives.CONE, primitives.TORUS, primitives.PARABOLOID, primitives.DISK, primitives.QUAD)
TORUS_PARAMS = np.array([0.35, 0.0, 0.0, 0.0])


def _params(kind):
    return TORUS_PARAMS if kind == primitives.TORUS else np.zeros(4)


def _rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def _uv_area(uv):
    a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]
    return 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1]))


# ------------------------------------------------------------------ triangle texel areas

def test_triangle_areas_sum_to_world_area():
    rng = np.random.default_rng(3)
    uv = rng.random((500, 3, 2))
    uv[:50] *= 0.02                     # many tiny triangles inside one texel
    area3d = rng.random(500) * 10.0
    for w, h in ((1, 1), (7, 5), (64, 64), (33, 90)):
        area, cov = texel_areas.triangle_texel_areas(uv, area3d, w, h)
        assert area.shape == (w * h,) and cov.shape == (w * h,)
        assert abs(area.sum() - area3d.sum()) <= 1e-12 * area3d.sum()
        assert np.all(area >= 0) and np.all((cov >= 0) & (cov <= 1))


def test_half_grid_triangles_exact():
    # Lower-left half of the unit square on a 2x2 grid: texel (0,0) full, (1,0) and
    # (0,1) half, (1,1) untouched.
    uv = np.array([[[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]])
    area, cov = texel_areas.triangle_texel_areas(uv, [2.0], 2, 2)
    np.testing.assert_array_equal(cov, [1.0, 0.5, 0.5, 0.0])
    np.testing.assert_array_equal(area, [1.0, 0.5, 0.5, 0.0])
    # The other diagonal half: cut through texels (0,0) and (1,1).
    uv = np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]])
    area, cov = texel_areas.triangle_texel_areas(uv, [4.0], 2, 2)
    np.testing.assert_array_equal(cov, [0.5, 1.0, 0.0, 0.5])
    np.testing.assert_array_equal(area, [1.0, 2.0, 0.0, 1.0])


def test_triangle_coverage_matches_supersampling():
    rng = np.random.default_rng(11)
    w, h, n = 9, 7, 48                  # n×n samples per texel
    xs = (np.arange(w * n) + 0.5) / (w * n)
    ys = (np.arange(h * n) + 0.5) / (h * n)
    gx, gy = np.meshgrid(xs, ys)
    for _ in range(12):
        tri = rng.random((1, 3, 2))
        ua = _uv_area(tri)[0]
        if ua < 1e-3:
            continue
        # area3d = UV area in texel units, so texel area == covered texel fraction.
        area, cov = texel_areas.triangle_texel_areas(tri, [ua * w * h], w, h)
        a, b, c = tri[0]
        d1 = (gx - b[0]) * (a[1] - b[1]) - (a[0] - b[0]) * (gy - b[1])
        d2 = (gx - c[0]) * (b[1] - c[1]) - (b[0] - c[0]) * (gy - c[1])
        d3 = (gx - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (gy - a[1])
        inside = ~(((d1 < 0) | (d2 < 0) | (d3 < 0)) & ((d1 > 0) | (d2 > 0) | (d3 > 0)))
        ref = inside.reshape(h, n, w, n).mean(axis=(1, 3)).reshape(-1)
        np.testing.assert_allclose(cov, ref, atol=0.04)
        np.testing.assert_allclose(area, cov, rtol=1e-9, atol=1e-12)
        assert np.abs(cov - ref).mean() < 0.005


def test_zero_uv_area_triangles_own_no_texels():
    """Without UV area a triangle has no texels: it adds no area (and records no
    photons, see record_slot), so no texel mixes in surface it cannot resolve."""
    uv = np.array([
        [[0.1, 0.1], [0.6, 0.6], [0.9, 0.9]],     # collinear UVs: zero UV area
        [[0.7, 0.2], [0.7, 0.2], [0.7, 0.2]],     # a single UV point
        [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],     # zero world area: adds nothing
        [[0.0, 0.0], [0.5, 0.0], [0.0, 0.5]],     # a real one
    ])
    area, cov = texel_areas.triangle_texel_areas(uv, [1.5, 0.25, 0.0, 2.0], 4, 4)
    assert area.sum() == pytest.approx(2.0, rel=1e-12)
    assert area[[0, 1, 4]].sum() == pytest.approx(2.0, rel=1e-12)   # texels under the real one
    pcs = texel_areas.triangle_texel_pieces(uv, [1.5, 0.25, 0.0, 2.0], 4, 4)
    assert set(pcs.tri.tolist()) == {3}


def test_triangle_world_areas_affine():
    rng = np.random.default_rng(5)
    p = rng.normal(size=(20, 3, 3))
    M = rng.normal(size=(3, 3))
    ref = 0.5 * np.linalg.norm(np.cross((p[:, 1] - p[:, 0]) @ M.T, (p[:, 2] - p[:, 0]) @ M.T), axis=1)
    np.testing.assert_allclose(texel_areas.triangle_world_areas(p, M), ref, rtol=1e-12)


# ------------------------------------------------------------------ primitive texel areas

@pytest.mark.parametrize("kind", ALL_KINDS)
def test_primitive_areas_uniform_scale(kind):
    rng = np.random.default_rng(kind)
    s = 1.7
    M = s * _rotation(rng)
    exact = primitives.prim_area(kind, _params(kind)) * s * s
    nf = int(primitives.prim_nfaces(kind))
    for R in (1, 2, 5, 16):
        a = texel_areas.primitive_texel_areas(kind, _params(kind), M, R)
        assert a.shape == (nf * R * R,)
        assert np.all(a > 0)
        assert abs(a.sum() - exact) <= 1e-9 * exact, (R, a.sum(), exact)


@pytest.mark.parametrize("kind", ALL_KINDS)
def test_primitive_areas_nonuniform_scale_per_texel(kind):
    M = np.array([[2.0, 0.3, 0.0], [0.0, 0.5, 0.2], [0.1, 0.0, 1.3]])
    R, k = 6, 8
    nf = int(primitives.prim_nfaces(kind))
    a = texel_areas.primitive_texel_areas(kind, _params(kind), M, R)
    fine = texel_areas.primitive_texel_areas(kind, _params(kind), M, R * k, order=8)
    ref = fine.reshape(nf, R, k, R, k).sum(axis=(2, 4)).reshape(-1)
    np.testing.assert_allclose(a, ref, rtol=1e-6)
    assert abs(a.sum() - fine.sum()) <= 1e-9 * fine.sum()


def test_box_face_layout_exact():
    # Box [-1,1]^3 scaled by (1,2,3): faces ±x have area 2·2·(2·3) = 24, ±y 12, ±z 8.
    a = texel_areas.primitive_texel_areas(primitives.BOX, np.zeros(4), np.diag([1.0, 2.0, 3.0]), 4)
    faces = a.reshape(6, 16).sum(axis=1)
    np.testing.assert_allclose(faces, [24, 24, 12, 12, 8, 8], rtol=1e-13)
    # Row layout of the lightmap puts the tiles side by side.
    rows = lightmap.faces_to_rows(a, 6, 4).reshape(4, 24)
    for f in range(6):
        np.testing.assert_array_equal(rows[:, 4 * f:4 * f + 4], a.reshape(6, 4, 4)[f])


def test_set_primitive_areas_matches_texel_index():
    lm = lightmap.allocate([(3, 3, 1), (3 * 4, 4, 3)], 1)
    M = np.diag([1.0, 2.0, 0.5])
    lightmap.set_primitive_areas(lm, 1, primitives.CYLINDER, np.zeros(4), M)
    a = texel_areas.primitive_texel_areas(primitives.CYLINDER, np.zeros(4), M, 4).reshape(3, 4, 4)
    for f in range(3):
        for y in range(4):
            for x in range(4):
                i = lightmap.texel_index(lm, 1, f, (x + 0.5) / 4, (y + 0.5) / 4)
                assert lm.area[i] == a[f, y, x]
    assert np.all(lm.coverage[lightmap.texel_slice(lm, 1)] == 1.0)
    assert np.all(lm.area[lightmap.texel_slice(lm, 0)] == 0.0)


# ------------------------------------------------------------------ recording

def _filled(layouts, n_bands=3, area=1.0):
    lm = lightmap.allocate(layouts, n_bands)
    lm.area[:] = area
    lm.coverage[:] = 1.0
    return lm


def test_texel_index_and_clamping():
    lm = lightmap.allocate([(5, 5, 1), (8, 4, 2)], 1)
    assert lightmap.texel_index(lm, 0, 0, 0.0, 0.0) == 0
    assert lightmap.texel_index(lm, 0, 0, 1.0, 1.0) == 24
    assert lightmap.texel_index(lm, 0, 0, 0.45, 0.61) == 3 * 5 + 2
    assert lightmap.texel_index(lm, 0, 0, -3.0, math.nan) == 0
    assert lightmap.texel_index(lm, 0, 7, 2.0, 0.0) == 4            # face clamped to the only tile
    # lightmap 1: two 4x4 tiles side by side, starting at texel 25
    assert lightmap.texel_index(lm, 1, 1, 0.0, 0.0) == 25 + 4
    assert lightmap.texel_index(lm, 1, 1, 0.99, 0.99) == 25 + 3 * 8 + 7
    assert lightmap.texel_index(lm, 1, 0, 1.0, 0.3) == 25 + 1 * 8 + 3   # s = 1 stays in tile 0


def test_accumulate_matches_reference_and_is_deterministic():
    rng = np.random.default_rng(7)
    lm1 = _filled([(16, 16, 1), (12, 4, 3)])
    lm2 = _filled([(16, 16, 1), (12, 4, 3)])
    n = lm1.area.shape[0]
    ids = rng.integers(-1, n, 200_000)
    pw = rng.random((200_000, 3))
    for part in np.array_split(np.arange(ids.size), 5):
        lightmap.accumulate(lm1, ids[part], pw[part])
        lightmap.accumulate(lm2, ids[part], pw[part])
    assert lm1.flux.tobytes() == lm2.flux.tobytes()
    assert lm1.flux_sq.tobytes() == lm2.flux_sq.tobytes()
    keep = ids >= 0
    ref = np.zeros((n, 3))
    np.add.at(ref, ids[keep], pw[keep])
    np.testing.assert_allclose(lm1.flux, ref, rtol=1e-12)
    np.testing.assert_array_equal(lm1.hits, np.bincount(ids[keep], minlength=n))
    ref_sq = np.zeros(n)
    np.add.at(ref_sq, ids[keep], pw[keep].mean(axis=1) ** 2)
    np.testing.assert_allclose(lm1.flux_sq, ref_sq, rtol=1e-12)
    with pytest.raises(ValueError):
        lightmap.accumulate(lm1, [n], np.ones((1, 3)))


def test_irradiance_is_flux_over_area_exactly():
    rng = np.random.default_rng(2)
    lm = lightmap.allocate([(8, 8, 1)], 3)
    lm.area[:] = rng.random(64) + 0.1
    lightmap.accumulate(lm, rng.integers(0, 64, 5000), rng.random((5000, 3)))
    lightmap.finalize(lm)
    np.testing.assert_array_equal(lm.irradiance, lm.flux / lm.area[:, None])
    assert np.all(lm.state == lightmap.STATE_MEASURED)


def test_zero_and_tiny_area_texels_never_nan():
    lm = lightmap.allocate([(4, 4, 1), (3, 3, 1)], 2)
    lm.area[:16] = 1.0
    lm.area[5] = 0.0          # photon recorded in a zero-area texel
    lm.area[6] = 1e-300       # sliver: below the empty threshold
    lightmap.accumulate(lm, np.arange(25), np.ones((25, 2)))
    lightmap.finalize(lm, passes=0)
    assert np.all(np.isfinite(lm.irradiance))
    assert np.all(lm.irradiance[[5, 6]] == 0.0) and np.all(lm.state[[5, 6]] == lightmap.STATE_EMPTY)
    assert np.all(lm.irradiance[16:] == 0.0)           # lightmap without any area
    lightmap.finalize(lm)
    assert np.all(np.isfinite(lm.irradiance))
    np.testing.assert_array_equal(lm.irradiance[[5, 6]], 1.0)   # dilated from neighbours
    assert np.all(lm.irradiance[16:] == 0.0) and np.all(lm.state[16:] == lightmap.STATE_EMPTY)


def test_dilation_fills_rings_and_stays_in_tile():
    # Lightmap 0: 2 tiles of 10x10; tile 0 has one measured texel, tile 1 none.
    lm = lightmap.allocate([(20, 10, 2), (6, 6, 1)], 1)
    t = 3 * 20 + 3            # texel (3, 3) of tile 0
    lm.area[t] = 2.0
    lm.flux[t] = 8.0
    o1 = int(lm.offset[1])
    lm.area[o1:] = 1.0        # lightmap 1 is fully measured with E = 7
    lm.flux[o1:] = 7.0
    lightmap.finalize(lm, passes=4)
    irr = lm.irradiance[:200, 0].reshape(10, 20)
    state = lm.state[:200].reshape(10, 20)
    # Chebyshev distance <= 4 from (3, 3) inside tile 0 gets E = 4, nothing else.
    yy, xx = np.mgrid[0:10, 0:20]
    ring = (np.maximum(abs(xx - 3), abs(yy - 3)) <= 4) & (xx < 10)
    np.testing.assert_array_equal(irr[ring], 4.0)
    assert np.all(irr[~ring] == 0.0) and np.all(state[~ring] == lightmap.STATE_EMPTY)
    assert np.all(state[:, 10:] == lightmap.STATE_EMPTY)      # never bled into tile 1
    assert state[3, 3] == lightmap.STATE_MEASURED and state[3, 4] == lightmap.STATE_DILATED
    np.testing.assert_array_equal(lm.irradiance[o1:, 0], 7.0)


def test_dilation_averages_neighbours():
    lm = lightmap.allocate([(3, 3, 1)], 1)
    lm.area[:] = 1.0
    lm.flux[:, 0] = np.arange(9.0)
    lm.area[4] = 0.0          # centre hole
    lightmap.finalize(lm)
    assert lm.irradiance[4, 0] == np.mean([0, 1, 2, 3, 5, 6, 7, 8])


# ------------------------------------------------------------------ lookups

def _grid_points(rng, n):
    pts = list(rng.random((n, 2)))
    for s in (0.0, 1.0, 0.5, 1e-9, 1 - 1e-9):
        for t in (0.0, 1.0, 0.37):
            pts.append((s, t))
    return pts


@pytest.mark.parametrize("passes", [0, 1])
def test_bilinear_constant_field_everywhere(passes):
    rng = np.random.default_rng(4)
    lm = lightmap.allocate([(3 * 7, 7, 3), (10, 6, 1)], 3)
    lm.area[:] = 0.5
    # Holes: a whole empty tile (2), empty blocks wider than the dilation reach,
    # scattered zero texels. Without dilation (passes=0) the lookups next to
    # them must skip the empty texels.
    lm.area[:7 * 21].reshape(7, 21)[:, 14:] = 0.0
    lm.area[:7 * 21].reshape(7, 21)[:, 11:14] = 0.0
    lm.area[7 * 21:].reshape(6, 10)[2:, 5:] = 0.0
    lm.area[rng.integers(0, lm.area.size, 10)] = 0.0
    c = np.array([0.25, 1.5, 3.0])
    lm.flux[:] = c * 0.5
    lightmap.finalize(lm, passes=passes)
    assert lm.state[6 * 21 + 13] == lightmap.STATE_EMPTY     # (13, 6): still empty after dilation
    out = np.zeros(3)
    for lid, faces in ((0, (0, 1)), (1, (0,))):
        for f in faces:
            for s, t in _grid_points(rng, 300):
                if lm.area[lightmap.texel_index(lm, lid, f, s, t)] == 0.0:
                    continue          # no surface there: hits cannot land in empty texels
                lightmap.lookup_bilinear(lm, lid, f, s, t, out)
                np.testing.assert_allclose(out, c, rtol=1e-14)
                lightmap.lookup(lm, lid, f, s, t, lightmap.MODE_BILINEAR, out)
                np.testing.assert_allclose(out, c, rtol=1e-14)
    # The empty tile reads zero, never the neighbouring tile's values.
    lightmap.lookup_bilinear(lm, 0, 2, 0.02, 0.5, out)
    assert np.all(out == 0.0)


def test_bilinear_reproduces_linear_ramp():
    rng = np.random.default_rng(8)
    R = 8
    lm = lightmap.allocate([(2 * R, R, 2)], 1)
    lm.area[:] = 1.0
    yy, xx = np.mgrid[0:R, 0:2 * R]
    xc = (xx % R + 0.5) / R
    yc = (yy + 0.5) / R
    face = xx // R
    lm.flux[:, 0] = (1.0 + 2.0 * xc - 3.0 * yc + 10.0 * face).reshape(-1)
    lightmap.finalize(lm)
    out = np.zeros(1)
    for _ in range(400):
        f = int(rng.integers(0, 2))
        s, t = 0.5 / R + rng.random(2) * (1 - 1.0 / R)
        lightmap.lookup_bilinear(lm, 0, f, s, t, out)
        assert abs(out[0] - (1 + 2 * s - 3 * t + 10 * f)) < 1e-12
    # At the border the lookup clamps to the edge texels (flat outside the centres).
    lightmap.lookup_bilinear(lm, 0, 1, 0.0, 0.0, out)
    assert abs(out[0] - (1 + 2 * 0.5 / R - 3 * 0.5 / R + 10)) < 1e-12


def test_constant_lookup_picks_containing_texel():
    rng = np.random.default_rng(9)
    lm = lightmap.allocate([(2, 2, 1), (12, 5, 3)], 1)
    lm.area[:] = 1.0
    lm.flux[:, 0] = np.arange(lm.area.size, dtype=float)
    lightmap.finalize(lm)
    out = np.zeros(1)
    for _ in range(300):
        f = int(rng.integers(0, 3))
        s, t = rng.random(2)
        lightmap.lookup(lm, 1, f, s, t, lightmap.MODE_CONSTANT, out)
        assert out[0] == 4 + int(t * 5) * 12 + f * 4 + int(s * 4)


# ------------------------------------------------------------------ statistics / helpers

def test_texel_stats():
    lm = lightmap.allocate([(2, 2, 1), (2, 1, 1)], 3)
    lm.area[:4] = 0.5
    n = 400
    lightmap.accumulate(lm, np.zeros(n, np.int64), np.full((n, 3), 0.01))
    lightmap.accumulate(lm, [1], [[1.0, 2.0, 3.0]])
    st = lightmap.texel_stats(lm)
    assert abs(st.rel_error[0] - 1.0 / math.sqrt(n)) < 1e-12
    assert abs(st.rel_error[1] - 1.0) < 1e-12
    assert np.isinf(st.rel_error[2])
    np.testing.assert_allclose(st.mean_irradiance[0], (n * 0.01 + np.array([1, 2, 3])) / 2.0)
    assert st.hits_per_texel[0] == (n + 1) / 4 and st.hits_per_texel[1] == 0
    assert np.isinf(st.median_rel_error[1])
    assert st.memory_bytes == sum(a.nbytes for a in lm) > 0


def test_resolution_for():
    assert lightmap.resolution_for(1.0, 16.0) == 16
    assert lightmap.resolution_for(4.0, 10.0) == 20
    assert lightmap.resolution_for(1e-6, 16.0) == 2
    assert lightmap.resolution_for(1e6, 16.0) == 1024
    assert lightmap.resolution_for(0.0, 16.0) == 2 and lightmap.resolution_for(math.nan, 1.0) == 2


def test_allocate_rejects_bad_layouts():
    with pytest.raises(ValueError):
        lightmap.allocate([(10, 4, 3)], 3)
    with pytest.raises(ValueError):
        lightmap.allocate([(0, 4, 1)], 3)
    lm = lightmap.allocate([(4, 2, 2), (3, 3, 1)], 2)
    assert list(lm.offset) == [0, 8] and lm.flux.shape == (17, 2)
