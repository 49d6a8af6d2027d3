"""The fast lightmap layout (engine/lightmaps/fast_layout.py): charts that never overlap,
stay MIN_GAP_TEXELS apart, share one texel scale, and fit the lightmap they are
made for; folds are cut, and meshes of too many pieces are refused by count."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.lightmaps import fast_layout
from photon_lightmaps.engine.geometry.validation import nondegenerate


def _sphere(n_theta, n_phi):
    m = demo_scenes.uv_sphere_mesh(0.3, n_theta, n_phi)
    v, t = np.asarray(m.vertices, np.float64), np.asarray(m.triangles, np.int64)
    return v, t[nondegenerate(v[t])]


def _grid(n_u, n_v, f):
    """A (n_u × n_v)-quad sheet with vertices f(u, v) for u, v in [0, 1]."""
    u, w = np.meshgrid(np.linspace(0, 1, n_u + 1), np.linspace(0, 1, n_v + 1), indexing="ij")
    v = f(u.reshape(-1), w.reshape(-1))
    idx = np.arange((n_u + 1) * (n_v + 1)).reshape(n_u + 1, n_v + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    t = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return v, t


def _helicoid(turns=2.5, n_u=100, n_v=5):
    """A ramp that winds around itself: seen along z, each turn covers the last."""
    def f(u, w):
        th = 2 * math.pi * turns * u
        r = 1.0 + w
        return np.stack([r * np.cos(th), r * np.sin(th), 0.15 * th], axis=1)
    return _grid(n_u, n_v, f)


def _signed_area(uv):
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _overlapping_pairs(uv, chart, shrink=1e-6):
    """Pairs of triangles of one chart whose UV interiors intersect (separating
    axis test on every pair, brute force: an independent check of the layout)."""
    c = uv.mean(axis=1, keepdims=True)
    tri = c + (uv - c) * (1 - shrink)        # shared edges and vertices do not count
    n = tri.shape[0]
    i, j = np.triu_indices(n, 1)
    same = chart[i] == chart[j]
    i, j = i[same], j[same]
    A, B = tri[i], tri[j]
    separated = np.zeros(i.size, bool)
    for P in (A, B):
        for k in range(3):
            e = P[:, (k + 1) % 3] - P[:, k]
            axis = np.stack([-e[:, 1], e[:, 0]], 1)
            pa = np.einsum("nkd,nd->nk", A, axis)
            pb = np.einsum("nkd,nd->nk", B, axis)
            separated |= (pa.max(1) < pb.min(1)) | (pb.max(1) < pa.min(1))
    return int((~separated).sum())


def _chart_gaps_ok(uv, chart, R, gap):
    """Every two charts' texel rectangles are at least `gap` texels apart."""
    ids = np.unique(chart)
    lo = np.array([uv[chart == c].reshape(-1, 2).min(0) for c in ids]) * R
    hi = np.array([uv[chart == c].reshape(-1, 2).max(0) for c in ids]) * R
    i, j = np.triu_indices(ids.size, 1)
    apart = ((lo[j] - hi[i] >= gap - 1e-6) | (lo[i] - hi[j] >= gap - 1e-6)).any(axis=1)
    return bool(apart.all())


def test_dense_sphere_gets_six_charts_one_texel_scale_and_the_gaps():
    v, t = _sphere(256, 512)                      # 261,120 triangles: xatlas crashes on it
    L = fast_layout.layout(v, t, 256)
    assert L.resolution == 256 and L.charts == 6
    assert L.uv.shape == (t.shape[0], 3, 2) and L.uv.min() >= 0 and L.uv.max() <= 1
    assert _chart_gaps_ok(L.uv, L.chart, L.resolution, fast_layout.MIN_GAP_TEXELS)
    # One orientation for every chart (the front side's winding) ...
    s = _signed_area(L.uv)
    assert (s > 0).all() or (s < 0).all()
    # ... and one texel scale: UV area / surface area is k² times the cosine
    # between the normal and the chart's axis, which is 1/√3 .. 1.
    p = v[t]
    a3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    ratio = np.abs(s) / a3
    assert ratio.max() / ratio.min() < math.sqrt(3) * 1.02
    assert 0.45 < L.fill < 0.75
    assert L.fill == pytest.approx(np.abs(s).sum(), rel=1e-12)


def test_small_lightmaps_grow_until_the_gaps_leave_room():
    """A 17-texel lightmap (the sphere at 16 texels/m) holds the six charts and
    their 3-texel gaps only at a sliver of the scale asked for: the layout
    doubles the side until the charts get at least half of it."""
    v, t = _sphere(32, 64)
    L = fast_layout.layout(v, t, 17)
    assert L.resolution == 34
    p = v[t]
    a3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    scale = math.sqrt(np.abs(_signed_area(L.uv)).sum() / a3) * L.resolution   # texels per metre
    assert scale >= 0.5 * 17 / math.sqrt(a3) * (1 / math.sqrt(3))
    assert _chart_gaps_ok(L.uv, L.chart, L.resolution, fast_layout.MIN_GAP_TEXELS)


def test_a_ramp_that_winds_over_itself_is_cut_until_no_chart_overlaps():
    v, t = _helicoid()
    # All normals lean on +z, so the box projection alone gives one chart, and
    # its turns lie on top of each other.
    p = v[t]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert (np.argmax(np.abs(n), axis=1) == 2).all()
    assert _overlapping_pairs(p[..., :2], np.zeros(t.shape[0], int)) > 0
    L = fast_layout.layout(v, t, 64)
    assert L.charts >= 3                          # 2.5 turns need at least 3 pieces
    assert _overlapping_pairs(L.uv, L.chart) == 0
    assert _chart_gaps_ok(L.uv, L.chart, L.resolution, fast_layout.MIN_GAP_TEXELS)


def test_plane_and_cube_keep_one_chart_per_side():
    v, t = _grid(20, 20, lambda u, w: np.stack([u * 2, w, 0.3 * u], 1))   # a tilted sheet
    L = fast_layout.layout(v, t, 32)
    assert L.charts == 1 and _overlapping_pairs(L.uv, L.chart) == 0
    m = demo_scenes.quad_mesh((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0))
    L = fast_layout.layout(m.vertices, m.triangles, 8)
    assert L.charts == 1 and L.uv.min() >= 0 and L.uv.max() <= 1


def test_doubled_faces_end_as_separate_charts():
    """The same face twice (a modelling slip): no cut can separate them; each
    such triangle ends as a chart of its own and the layout still finishes."""
    v, t = _grid(3, 3, lambda u, w: np.stack([u, w, 0 * u], 1))
    t2 = np.concatenate([t, t])
    L = fast_layout.layout(v, t2, 64)
    assert _overlapping_pairs(L.uv, L.chart) == 0
    assert L.charts == t2.shape[0]


def test_too_many_pieces_are_refused_with_their_count():
    """5,000 separate triangles (a grass-like mesh) need 3-texel gaps each: at
    most 64 texels per side they cannot fit."""
    rng = np.random.default_rng(1)
    base = rng.uniform(0, 10, (5000, 1, 3))
    v = (base + rng.uniform(0, 0.05, (5000, 3, 3))).reshape(-1, 3)
    t = np.arange(15000).reshape(-1, 3)
    with pytest.raises(fast_layout.LayoutError, match=r"5,000 separate charts .* 64×64"):
        fast_layout.layout(v, t, 16, max_resolution=64)
    L = fast_layout.layout(v, t, 16, max_resolution=1024)
    assert L.resolution >= 256 and L.charts == 5000


def test_a_polygons_triangles_share_a_chart():
    """A UV layer holds one UV per polygon corner, so both triangles of a quad
    must land in one chart, even where the quad is bent across two axes."""
    def bumpy(u, w):
        return np.stack([u, w, 0.9 * np.sin(6 * u) * np.cos(5 * w)], 1)
    v, t = _grid(24, 24, bumpy)
    quads = t.shape[0] // 2
    group = np.concatenate([np.arange(quads), np.arange(quads)])
    L = fast_layout.layout(v, t, 64, groups=group)
    assert (L.chart[:quads] == L.chart[quads:]).all()
    assert L.charts > 1 and _overlapping_pairs(L.uv, L.chart) == 0
    # Corners a quad's two triangles share get one UV (their chart's projection).
    a, c = t[:quads], t[quads:]
    assert np.allclose(L.uv[:quads, 0], L.uv[quads:, 0]) and np.allclose(L.uv[:quads, 2], L.uv[quads:, 1])
    assert (a[:, 0] == c[:, 0]).all() and (a[:, 2] == c[:, 1]).all()
