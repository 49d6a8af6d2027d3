"""Lightmap UVs for meshes that have none: an xatlas unwrap, cached.

Photon lightmaps need a UV layout in which charts never share texels, also
under bilinear reconstruction and dilation (engine/lightmap.py). xatlas packs
charts with ``padding`` texels around each of them (plus one texel for
bilinear filtering), so two charts are at least 2·padding + 1 atlas texels
apart. UVs are normalised *uniformly* by the larger atlas side, which keeps
texels square and the atlas grid aligned with a lightmap of that many texels
per side.

Unwrapping takes seconds to minutes for large meshes, so every result is
stored on disk (keyed by a hash of the vertices, triangles and options) and in
a small in-memory LRU: a mesh is never unwrapped twice.
"""
import hashlib
import math
import os
import pathlib
import tempfile
from collections import OrderedDict, namedtuple

import numpy as np

# Bump when the stored result's meaning changes, so stale cache files are ignored.
_CACHE_VERSION = "uv-atlas-1"
_LRU_SIZE = 16
# Charts must stay this many lightmap texels apart at the requested resolution:
# a bilinear lookup reads texels up to 1.5 texels from its chart, and one ring of
# dilation reaches one texel further.
MIN_GAP_TEXELS = 3.0
# Used when neither a resolution nor a texel density is given (xatlas' own
# default packs a unit sphere into ~1300² texels). Low on purpose: the chart
# gaps are fixed in UV space, so a layout made for 64 texels stays leak-free
# on every lightmap of at least ~50 texels per side, at some cost in UV space.
DEFAULT_RESOLUTION = 64
_MAX_ATTEMPTS = 4

AtlasResult = namedtuple("AtlasResult", [
    "uv",              # float64[T, 3, 2] per-triangle-corner UVs in [0,1]², original order
    "chart",           # int32[T] chart id per triangle (-1: xatlas ignored a degenerate face)
    "width",           # atlas size in xatlas texels
    "height",
    "resolution",      # max(width, height): lightmap side on which the xatlas grid lies exactly
    "min_resolution",  # smallest lightmap side keeping charts MIN_GAP_TEXELS apart
])

_lru = OrderedDict()


def cache_dir():
    """Folder of the disk cache: $PHOTON_LIGHTMAPS_CACHE/uv or ~/.cache/photon_lightmaps/uv."""
    root = os.environ.get("PHOTON_LIGHTMAPS_CACHE")
    base = pathlib.Path(root) if root else pathlib.Path.home() / ".cache" / "photon_lightmaps"
    return base / "uv"


def clear_memory_cache():
    _lru.clear()


def _check_inputs(vertices, triangles):
    v = np.ascontiguousarray(vertices, dtype=np.float64)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {v.shape}")
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f"triangles must have shape (T, 3), got {t.shape}")
    if t.size and not np.issubdtype(t.dtype, np.integer):
        raise ValueError("triangles must be integer vertex indices")
    t = np.ascontiguousarray(t, dtype=np.int64)
    if not np.all(np.isfinite(v)):
        raise ValueError("vertices contain NaN or infinity")
    if t.size and (t.min() < 0 or t.max() >= v.shape[0]):
        raise ValueError(f"triangle indices out of range [0, {v.shape[0]})")
    return v, t


def _key(v, t, resolution, texels_per_unit, padding):
    import xatlas
    h = hashlib.sha256()
    opts = f"{_CACHE_VERSION}|xatlas {getattr(xatlas, '__version__', '?')}|" \
           f"{v.shape}|{t.shape}|{resolution}|{texels_per_unit}|{padding}"
    h.update(opts.encode())
    h.update(v.tobytes())
    h.update(t.tobytes())
    return h.hexdigest()


def _valid(res, n_tri):
    uv, chart = res.uv, res.chart
    return (uv.shape == (n_tri, 3, 2) and chart.shape == (n_tri,) and np.all(np.isfinite(uv))
            and (uv.size == 0 or (uv.min() >= 0.0 and uv.max() <= 1.0)))


def _load(path, n_tri):
    try:
        with np.load(path) as z:
            res = AtlasResult(z["uv"].astype(np.float64), z["chart"].astype(np.int32),
                              int(z["width"]), int(z["height"]), int(z["resolution"]),
                              int(z["min_resolution"]))
    except Exception:   # missing, truncated or foreign file: unwrap again
        return None
    return res if _valid(res, n_tri) else None


def _store(path, res):
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Write then rename, so a concurrent reader never sees half a file.
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, uv=res.uv, chart=res.chart, width=res.width, height=res.height,
                     resolution=res.resolution, min_resolution=res.min_resolution)
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only cache only costs time


def _copy(res):
    return res._replace(uv=res.uv.copy(), chart=res.chart.copy())


def _run_xatlas(v, t, resolution, texels_per_unit, padding):
    import xatlas
    atlas = xatlas.Atlas()
    atlas.add_mesh(v.astype(np.float32), t.astype(np.uint32))
    po = xatlas.PackOptions()
    po.padding = int(padding)
    po.bilinear = True
    if texels_per_unit:
        po.texels_per_unit = float(texels_per_unit)
    elif resolution:
        po.resolution = int(resolution)
    atlas.generate(chart_options=xatlas.ChartOptions(), pack_options=po)
    vmap, idx, uv = atlas[0]
    _, vchart = atlas.get_mesh_vertex_assignment(0)
    return (vmap.astype(np.int64), idx.astype(np.int64), uv.astype(np.float64),
            vchart.astype(np.int64), int(atlas.width), int(atlas.height),
            float(atlas.texels_per_unit))


def _to_original_order(t, vmap, idx, uv_px, vchart):
    """Per-corner UVs (texel units) and chart ids in the input triangle order."""
    T = t.shape[0]
    chart = np.full(T, -1, np.int64)
    out = np.zeros((T, 3, 2))
    orig = vmap[idx] if idx.size else np.zeros((0, 3), np.int64)
    if idx.shape[0] == T and np.array_equal(orig, t):
        # xatlas keeps faces in input order with the same corner order (the usual case).
        out[:] = uv_px[idx]
        chart[:] = vchart[idx[:, 0]]
    else:
        # Reordered or dropped faces: match by vertex triple, corner by corner.
        rows = {}
        for k in range(T):
            rows.setdefault(tuple(sorted(t[k])), []).append(k)
        for j in range(idx.shape[0]):
            cand = rows.get(tuple(sorted(orig[j])))
            if not cand:
                continue
            k = cand.pop(0)
            for c in range(3):
                pos = np.nonzero(orig[j] == t[k, c])[0]
                out[k, c] = uv_px[idx[j, pos[0] if pos.size else c]]
            chart[k] = vchart[idx[j, 0]]
    # xatlas marks ignored (degenerate) faces with chart 0xFFFFFFFF.
    chart[(chart < 0) | (chart >= 2 ** 31 - 1)] = -1
    return out, chart.astype(np.int32)


def _unwrap_uncached(v, t, resolution, texels_per_unit, padding):
    T = t.shape[0]
    if T == 0:
        return AtlasResult(np.zeros((0, 3, 2)), np.zeros(0, np.int32), 1, 1, 1, 1)
    gap = 2 * int(padding) + 1  # xatlas leaves 2·padding (+1 bilinear) texels between charts
    tpu = texels_per_unit
    for attempt in range(_MAX_ATTEMPTS):
        vmap, idx, uv, vchart, w, h, tpu_used = _run_xatlas(v, t, resolution, tpu, padding)
        side = max(w, h, 1)
        if not resolution or gap * resolution / side >= MIN_GAP_TEXELS or attempt == _MAX_ATTEMPTS - 1:
            break
        # The packed atlas came out too large for the requested lightmap: shrink
        # the texel density in proportion and pack again (rare: xatlas' own
        # estimate usually overshoots the requested size by < 1.6x).
        tpu = tpu_used * (gap * resolution / (MIN_GAP_TEXELS * side)) * 0.97
    uv_px = uv * np.array([w, h], np.float64)
    out, chart = _to_original_order(t, vmap, idx, uv_px, vchart)
    uvn = np.clip(out / side, 0.0, 1.0)
    min_res = int(math.ceil(MIN_GAP_TEXELS * side / gap))
    return AtlasResult(uvn, chart, int(w), int(h), int(side), min_res)


def unwrap_atlas(vertices, triangles, resolution=None, texels_per_unit=None, padding=2,
                 use_cache=True):
    """xatlas unwrap of a mesh -> AtlasResult (see the namedtuple fields).

    resolution: lightmap texels per side the atlas is meant for; charts are
    packed so that they stay at least MIN_GAP_TEXELS apart at that resolution
    (the atlas is repacked with a lower texel density if xatlas overshoots).
    texels_per_unit: fixes the texel density instead (object-space units);
    then use ``result.resolution`` as the lightmap size. Neither: DEFAULT_RESOLUTION.
    padding: xatlas padding in atlas texels (>= 2).
    """
    v, t = _check_inputs(vertices, triangles)
    padding = max(int(padding), 2)
    resolution = int(resolution) if resolution else None
    if resolution is not None and resolution < 1:
        raise ValueError(f"resolution must be >= 1, got {resolution}")
    tpu = float(texels_per_unit) if texels_per_unit else None
    if tpu is not None and not (math.isfinite(tpu) and tpu > 0):
        raise ValueError(f"texels_per_unit must be positive, got {texels_per_unit}")
    if resolution is None and tpu is None:
        resolution = DEFAULT_RESOLUTION
    key = _key(v, t, resolution, tpu, padding)
    if use_cache:
        hit = _lru.get(key)
        if hit is not None:
            _lru.move_to_end(key)
            return _copy(hit)
        path = cache_dir() / f"{key}.npz"
        res = _load(path, t.shape[0])
        if res is None:
            res = _unwrap_uncached(v, t, resolution, tpu, padding)
            _store(path, res)
        _lru[key] = res
        while len(_lru) > _LRU_SIZE:
            _lru.popitem(last=False)
        return _copy(res)
    return _unwrap_uncached(v, t, resolution, tpu, padding)


def unwrap(vertices, triangles, resolution=None, texels_per_unit=None, padding=2):
    """Per-triangle-corner lightmap UVs (T, 3, 2) in [0,1]², in the input triangle order.

    Faces xatlas ignores (zero area, repeated vertex) get UV (0, 0) at every
    corner; the lightmap gives such zero-UV-area triangles' world area to the
    texel under their UV centroid.
    """
    return unwrap_atlas(vertices, triangles, resolution, texels_per_unit, padding).uv
