"""A fast lightmap layout: box-projected charts packed on shelves, in seconds.

xatlas makes the tighter atlas, but it takes minutes on a dense mesh and
crashes on some (engine/lightmaps/uv_atlas.py). A render needs less: charts that never
fold over themselves and that stay MIN_GAP_TEXELS apart on the lightmap they
will get. This layout gives that in numpy, without a child process:

1. Triangles are grouped by the axis their normal leans on most (±x, ±y, ±z)
   and then into edge-connected charts. Every normal in a chart lies within
   54.7° of its axis, so the projection along the axis is one-to-one locally.
2. Each chart is projected along its axis and turned to its principal axes
   where that makes its rectangle smaller.
3. A chart whose projection still overlaps itself (a fold, a ramp that turns
   over itself) is found by rasterising sample points and is cut in two across
   its longest side, until none overlaps.
4. The charts' rectangles go on shelves in an R×R texel grid, MIN_GAP_TEXELS
   apart, at the largest texel scale that fits (a bisection). Where the gaps
   alone need more texels than R×R has, R doubles.

Texel areas come from the UV triangles (engine/lightmaps/texel_areas.py), so the
projection's stretch changes the texel density, never the measured light.
"""
import math
from collections import namedtuple

import numpy as np

from ..core.scene import SceneError
from .xatlas_worker import MIN_GAP_TEXELS

FastLayout = namedtuple("FastLayout", [
    "uv",          # float64[T, 3, 2] per-corner UVs in [0,1]², input order
    "chart",       # int64[T] chart id per triangle
    "resolution",  # lightmap texels per side the layout is made for (>= the one asked for)
    "charts",      # number of charts
    "fill",        # fraction of the R×R texels that lie under a chart's triangles
])

# Folds are looked for with at least this many samples over the whole mesh
# (and at least one per texel), so a low-resolution lightmap still finds them.
_MIN_OVERLAP_SAMPLES = 256 * 256
# Candidate sample points tested per numpy batch (memory, not speed).
_BATCH = 1 << 21
_MAX_SPLIT_ROUNDS = 24
# A chart is turned to its principal axes only when they differ this much:
# the principal axes of a square chart are arbitrary and turning it costs room.
_ANISOTROPY = 1.25
# Atlas fill assumed for a first texel scale (the overlap samples' spacing).
_FILL_GUESS = 0.5
# The least fraction of the asked-for texel scale a layout settles for before
# it takes a larger lightmap.
_MIN_SCALE = 0.5


class LayoutError(SceneError):
    """No fast layout fits: `reason` says why (too many separate pieces)."""

    def __init__(self, reason):
        self.reason = reason
        super().__init__(reason)


def layout(vertices, triangles, resolution, max_resolution=4096, gap=MIN_GAP_TEXELS, groups=None):
    """Lightmap UVs of a mesh for an R×R lightmap, R >= resolution -> FastLayout.

    vertices (V, 3), triangles (T, 3): the mesh (validated by the caller).
    groups (T,): triangles that must share a chart (a polygon's triangles,
    whose corners a UV layer stores once per loop); they get the axis of their
    summed normal and are never cut apart.
    Charts are at least `gap` texels apart on the returned resolution. It
    doubles from `resolution` (up to max_resolution) while the charts and their
    gaps do not fit, or while the gaps leave the charts under half the texel
    scale `resolution` stands for; a LayoutError says when nothing fits.
    """
    v = np.asarray(vertices, np.float64)
    t = np.asarray(triangles, np.int64).reshape(-1, 3)
    T = t.shape[0]
    R = max(int(resolution), 1)
    if T == 0:
        return FastLayout(np.zeros((0, 3, 2)), np.zeros(0, np.int64), R, 0, 0.0)
    p = v[t]                                            # (T, 3, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    centre = p.mean(axis=1)
    a, b = _edge_pairs(v, t)
    if groups is None:
        group = np.arange(T)
        lean = n
    else:
        group = np.unique(np.asarray(groups).reshape(T), return_inverse=True)[1].reshape(-1)
        n_groups = int(group.max()) + 1
        lean = np.stack([np.bincount(group, n[:, k], n_groups) for k in range(3)], 1)[group]
        cnt = np.bincount(group, minlength=n_groups)[group][:, None]
        centre = np.stack([np.bincount(group, centre[:, k], n_groups) for k in range(3)], 1)[group] / cnt
        # A group's triangles are joined even where they share no edge.
        order = np.argsort(group, kind="stable")
        same = group[order][1:] == group[order][:-1]
        a, b = np.concatenate([a, order[:-1][same]]), np.concatenate([b, order[1:][same]])
    axis = np.argmax(np.abs(lean), axis=1)
    label = 2 * axis + (lean[np.arange(T), axis] < 0)
    chart = _charts(label, a, b)
    area3d = 0.5 * np.linalg.norm(n, axis=1)
    spacing = _sample_spacing(area3d.sum(), R)
    for _ in range(_MAX_SPLIT_ROUNDS):
        local = _chart_coordinates(p, axis, label, chart)
        bad = _overlapping(local, chart, spacing)
        if not bad.size:
            break
        chart = _charts(_split(centre, chart, bad), a, b)
    else:
        # Still folded after many cuts (a pathological mesh): every group of
        # such a chart becomes a chart of its own (a triangle cannot overlap itself).
        local = _chart_coordinates(p, axis, label, chart)
        bad = _overlapping(local, chart, spacing)
        if bad.size:
            alone = np.isin(chart, bad)
            chart = np.where(alone, chart.max() + 1 + group, chart)
            chart = np.unique(chart, return_inverse=True)[1].reshape(-1)
            local = _chart_coordinates(p, axis, label, chart)
    size = _chart_sizes(local, chart)
    n_charts = size.shape[0]
    # The texel scale the caller's resolution stands for (texels per unit of
    # surface, as engine/lightmap.resolution_for sizes a mesh's lightmap).
    wanted = R / math.sqrt(max(area3d.sum(), 1e-300))
    placed = None
    while True:
        got = _pack(size, R, gap)
        if got is not None:
            placed = (R, got)
            # Gaps are whole texels: on a small lightmap they can take most of
            # it. Double R until the charts get half the scale asked for.
            if got[0] >= _MIN_SCALE * wanted:
                break
        if R * 2 > max_resolution:
            break
        R *= 2
    if placed is None:
        raise LayoutError(f"{n_charts:,} separate charts do not fit a "
                          f"{max_resolution}×{max_resolution} lightmap {gap:g} texels apart")
    R, (scale, offset) = placed
    uv = (local * scale + offset[chart][:, None, :]) / R
    uv = np.clip(uv, 0.0, 1.0)
    fill = float(_uv_area(uv).sum())
    return FastLayout(uv, chart, R, n_charts, fill)


def _uv_area(uv):
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def _sample_spacing(area, R):
    """World distance between overlap samples: about a texel at R, finer for small R."""
    per_texel = math.sqrt(max(area, 1e-300) / (_FILL_GUESS * R * R))
    floor_ = math.sqrt(max(area, 1e-300) / _MIN_OVERLAP_SAMPLES)
    return min(0.7 * per_texel, floor_)


def _edge_pairs(v, t):
    """Pairs of triangles (a, b) that share an edge, vertices welded by position."""
    _, vid = np.unique(v, axis=0, return_inverse=True)
    vid = vid.reshape(-1)[t]
    lo = np.minimum(vid, np.roll(vid, -1, axis=1)).reshape(-1)
    hi = np.maximum(vid, np.roll(vid, -1, axis=1)).reshape(-1)
    key = lo * (int(vid.max()) + 1) + hi
    tri = np.repeat(np.arange(t.shape[0]), 3)
    order = np.argsort(key, kind="stable")
    key, tri = key[order], tri[order]
    # Consecutive triangles on one edge are joined (on a non-manifold edge: a chain).
    same = (key[1:] == key[:-1]) & (lo[order][1:] != hi[order][1:])
    return tri[:-1][same], tri[1:][same]


def _charts(label, a, b):
    """Chart id per triangle: the connected parts of each label (0.. in first-seen order)."""
    keep = label[a] == label[b]
    a, b = a[keep], b[keep]
    parent = np.arange(label.shape[0])
    while a.size:
        ra, rb = parent[a], parent[b]
        cross = ra != rb
        if not cross.any():
            break
        a, b, ra, rb = a[cross], b[cross], ra[cross], rb[cross]
        # Hook each root onto a smaller one: parent[x] <= x keeps it a forest.
        np.minimum.at(parent, np.maximum(ra, rb), np.minimum(ra, rb))
        while True:
            up = parent[parent]
            if np.array_equal(up, parent):
                break
            parent = up
    return np.unique(parent, return_inverse=True)[1].reshape(-1)


def _chart_coordinates(p, axis, label, chart):
    """(T, 3, 2) corner coordinates in each chart's plane, rectangle corner at 0,
    the longer side along the first coordinate."""
    T = p.shape[0]
    n_charts = int(chart.max()) + 1
    # One projection axis per chart: the label of its first triangle (all agree
    # unless the chart came from the one-triangle fallback, which is fine too).
    first = np.full(n_charts, T, np.int64)
    np.minimum.at(first, chart, np.arange(T))
    c_axis = axis[first][chart]
    c_flip = (label[first] % 2 == 1)[chart]
    rows = np.arange(T)[:, None]
    u = p[rows, :, ((c_axis + 1) % 3)[:, None]][:, 0]   # (T, 3)
    w = p[rows, :, ((c_axis + 2) % 3)[:, None]][:, 0]
    u = np.where(c_flip[:, None], -u, u)                 # keep the UV winding of the front side
    q = np.stack([u, w], axis=-1)                        # (T, 3, 2)
    corner_chart = np.repeat(chart, 3)
    flat = q.reshape(-1, 2)
    cnt = np.bincount(corner_chart, minlength=n_charts).astype(np.float64)
    mean = np.stack([np.bincount(corner_chart, flat[:, k], n_charts) for k in (0, 1)], 1) / cnt[:, None]
    d = flat - mean[corner_chart]
    sxx = np.bincount(corner_chart, d[:, 0] * d[:, 0], n_charts)
    syy = np.bincount(corner_chart, d[:, 1] * d[:, 1], n_charts)
    sxy = np.bincount(corner_chart, d[:, 0] * d[:, 1], n_charts)
    theta = 0.5 * np.arctan2(2 * sxy, sxx - syy)
    spread = np.sqrt((sxx - syy) ** 2 + 4 * sxy ** 2)
    lam1, lam2 = 0.5 * (sxx + syy + spread), 0.5 * (sxx + syy - spread)
    turn = lam1 > _ANISOTROPY ** 2 * np.maximum(lam2, 0.0)

    def turned(angle):
        c, s = np.cos(angle)[corner_chart], np.sin(angle)[corner_chart]
        r = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], 1)
        lo, hi = _per_chart_min_max(r, corner_chart, n_charts)
        return r - lo[corner_chart], (hi - lo).prod(axis=1)

    r, box = turned(np.zeros(n_charts))
    r_pca, box_pca = turned(np.where(turn, theta, 0.0))
    r = np.where((box_pca < 0.999 * box)[corner_chart][:, None], r_pca, r)
    # Longer side first: the shelves are filled with wide, flat rectangles.
    _, hi = _per_chart_min_max(r, corner_chart, n_charts)
    tall = (hi[:, 1] > hi[:, 0])[corner_chart]
    r = np.where(tall[:, None], r[:, ::-1] * np.array([1.0, -1.0]) + np.stack(
        [np.zeros_like(r[:, 0]), hi[corner_chart][:, 0]], 1), r)
    return r.reshape(T, 3, 2)


def _per_chart_min_max(r, corner_chart, n_charts):
    lo = np.full((n_charts, 2), np.inf)
    hi = np.full((n_charts, 2), -np.inf)
    for k in (0, 1):
        np.minimum.at(lo[:, k], corner_chart, r[:, k])
        np.maximum.at(hi[:, k], corner_chart, r[:, k])
    return lo, hi


def _chart_sizes(local, chart):
    n_charts = int(chart.max()) + 1
    _, hi = _per_chart_min_max(local.reshape(-1, 2), np.repeat(chart, 3), n_charts)
    return np.maximum(hi, 0.0)


def _overlapping(local, chart, spacing):
    """Chart ids whose triangles cover one sample point twice (a fold in the projection)."""
    T = local.shape[0]
    q = local / spacing
    # Off-lattice by an irrational amount, so that no sample lies on a shared
    # edge or vertex of a regular mesh and counts for both triangles.
    shift = np.array([0.5 + 0.0123 * math.pi, 0.5 + 0.0071 * math.e])
    lo = np.ceil(q.min(axis=1) - shift).astype(np.int64)
    hi = np.floor(q.max(axis=1) - shift).astype(np.int64)
    nx = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    ny = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    count = nx * ny
    keys = []
    ends = np.cumsum(count)
    start = 0
    while start < T:
        stop = int(np.searchsorted(ends, (ends[start - 1] if start else 0) + _BATCH, "right"))
        stop = min(max(stop, start + 1), T)
        keys.append(_inside_samples(q, lo, nx, count, chart, shift, start, stop))
        start = stop
    keys = np.concatenate(keys) if keys else np.zeros(0, np.int64)
    if not keys.size:
        return np.zeros(0, np.int64)
    keys.sort()
    twice = keys[1:][keys[1:] == keys[:-1]]
    if not twice.size:
        return np.zeros(0, np.int64)
    return np.unique(twice >> 42)


def _inside_samples(q, lo, nx, count, chart, shift, start, stop):
    """Keys (chart << 42 | sample) of the samples strictly inside triangles start..stop."""
    c = count[start:stop]
    tri = np.repeat(np.arange(start, stop), c)
    if not tri.size:
        return np.zeros(0, np.int64)
    k = np.arange(tri.size) - np.repeat(np.cumsum(c) - c, c)
    ix = lo[tri, 0] + k % nx[tri]
    iy = lo[tri, 1] + k // nx[tri]
    px, py = ix + shift[0], iy + shift[1]
    a, b, cc = q[tri, 0], q[tri, 1], q[tri, 2]
    area = (b[:, 0] - a[:, 0]) * (cc[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (cc[:, 0] - a[:, 0])
    sgn = np.sign(area)

    def edge(p0, p1):
        return sgn * ((p1[:, 0] - p0[:, 0]) * (py - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (px - p0[:, 0]))

    tol = 1e-9 * np.abs(area)
    inside = (edge(a, b) > tol) & (edge(b, cc) > tol) & (edge(cc, a) > tol)
    # 21 bits per lattice coordinate within a chart: far more than any spacing gives.
    key = (chart[tri].astype(np.int64) << 42) | ((iy & 0x1FFFFF) << 21) | (ix & 0x1FFFFF)
    return key[inside]


def _split(centre, chart, bad):
    """Labels that cut each chart in `bad` in two across the middle of its longest
    side; centre (T, 3): where each triangle counts (its group's centre)."""
    n_charts = int(chart.max()) + 1
    lo = np.full((n_charts, 3), np.inf)
    hi = np.full((n_charts, 3), -np.inf)
    for k in range(3):
        np.minimum.at(lo[:, k], chart, centre[:, k])
        np.maximum.at(hi[:, k], chart, centre[:, k])
    longest = np.argmax(hi - lo, axis=1)
    mid = 0.5 * (lo + hi)[np.arange(n_charts), longest]
    side = centre[np.arange(chart.shape[0]), longest[chart]] > mid[chart]
    cut = np.isin(chart, bad) & side
    return 2 * chart + cut


def _pack(size, R, gap):
    """Shelf packing of chart rectangles (world units) into R×R texels, `gap`
    texels apart -> (texels per world unit, texel offset per chart) or None."""
    n = size.shape[0]
    if n * gap * gap > R * R:
        return None
    order = np.argsort(-size[:, 1], kind="stable")
    w, h = size[order, 0], size[order, 1]

    def place(k):
        W = np.ceil(w * k + gap)
        H = np.ceil(h * k + gap)
        if W.max() > R:
            return None
        cs = np.cumsum(W)
        x = np.empty(n)
        y = np.empty(n)
        s, top = 0, 0.0
        while s < n:
            base = cs[s - 1] if s else 0.0
            e = int(np.searchsorted(cs, base + R, "right"))
            x[s:e] = cs[s:e] - W[s:e] - base
            y[s:e] = top
            top += H[s]
            if top > R:
                return None
            s = e
        return x, y

    total = float((w * h).sum())
    k_hi = R / math.sqrt(total) if total > 0 else R / max(float(w.max()), 1e-300)
    k_hi = min(k_hi, (R - gap) / max(float(w.max()), 1e-300))
    k_lo = 0.0
    best = place(k_lo)
    if best is None:
        return None
    for _ in range(40):
        k = 0.5 * (k_lo + k_hi)
        got = place(k)
        if got is None:
            k_hi = k
        else:
            k_lo, best = k, got
        if k_hi - k_lo < 1e-4 * k_hi:
            break
    if k_lo == 0.0:
        # Only zero-size charts fit (every chart a point or a segment): any scale works.
        k_lo = 1.0 / max(float(w.max()), float(h.max()), 1e-300) if (w.max() or h.max()) else 1.0
        best = place(k_lo) or best
    x, y = best
    offset = np.empty((n, 2))
    offset[order, 0] = x + 0.5 * gap
    offset[order, 1] = y + 0.5 * gap
    return k_lo, offset
