"""Photon lightmaps (thesis 3.5.2): texel buckets that count photon flux.

Every surface that records photons owns a regular texel grid. A texel j stores
the flux deposited by the photons that hit it; its radiosity is
B_j = m_j Φ / A_j (thesis eq. 3.7), with the texel's *exact* world-space area
A_j from texel_areas.py.

Layout (``Lightmaps``): one flat texel array for the whole scene; lightmap l
covers ``offset[l] : offset[l] + width[l] * height[l]``, row-major (index =
offset + y * width + x). A primitive with F faces has F square tiles of R × R
side by side (width = F·R); texel (x, y) of a tile covers the chart square
[x/R, (x+1)/R] × [y/R, (y+1)/R] of that face. A mesh atlas is one tile.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..core.sampling import first_above
from .texel_areas import has_uv_area, primitive_texel_areas, triangle_texel_areas

MODE_CONSTANT = 0
MODE_BILINEAR = 1

# Texel state after finalize(): bilinear lookups skip EMPTY texels.
STATE_EMPTY = 0
STATE_MEASURED = 1
STATE_DILATED = 2

# A texel whose area is below this fraction of its lightmap's mean texel area
# holds a sliver of surface: flux / area would be pure noise (one photon there
# reads as a thousand elsewhere, or as ~1e296 on a 1e-300 m² rounding
# remnant), so it is treated as empty and filled by dilation instead.
EMPTY_AREA_FRACTION = 1e-3
DILATION_PASSES = 4

Lightmaps = namedtuple("Lightmaps", [
    "offset",      # int64[L]   first texel of lightmap l
    "width",       # int32[L]   texels per row (tiles * R for primitives)
    "height",      # int32[L]
    "tiles",       # int32[L]   face tiles side by side (1 for a mesh atlas)
    "area",        # float64[N] exact world area of each texel (m²)
    "coverage",    # float64[N] covered fraction of the texel's UV square (alpha for baking)
    "open",        # float64[N] fraction of the texel's area outside every closed solid (open_area.py)
    "flux",        # float64[N, B] accumulated photon power (W)
    "flux_sq",     # float64[N] sum of squared band-mean photon powers (variance estimate)
    "hits",        # int64[N]
    "irradiance",  # float64[N, B] E = flux / (area·open) after finalize(), dilated into empty texels
    "state",       # int8[N]    STATE_EMPTY / STATE_MEASURED / STATE_DILATED
    # CSG texel splitting (thesis 5.2.2, engine/geometry/csg.py): a texel cut into several
    # disjoint visible regions keeps region 0 and gets sub-texel rows for the rest
    "split",       # int32[N]   -1, or row k of the tables below
    "split_first", # int64[K]   texel row of region 1 (regions 1.. are consecutive)
    "split_cell",  # int8[K, 64] region of each cell of the texel's 8x8 sampling grid
])

LightmapStats = namedtuple("LightmapStats", [
    "mean_irradiance",   # float64[L, B] Σflux / Σarea over texels with area
    "hits_per_texel",    # float64[L] mean photon hits per texel with area
    "rel_error",         # float64[N] sqrt(flux_sq) / flux (inf where no flux)
    "median_rel_error",  # float64[L] over texels that received hits (inf if none)
    "memory_bytes",      # int, all texel arrays together
])


# --------------------------------------------------------------------------------------
# Allocation and layout helpers (Python)
# --------------------------------------------------------------------------------------

def allocate(layouts, n_bands):
    """Lightmaps for a list of (width, height, tiles); all texels start empty."""
    n_bands = int(n_bands)
    if n_bands < 1:
        raise ValueError(f"n_bands must be >= 1, got {n_bands}")
    L = len(layouts)
    width = np.zeros(L, np.int32)
    height = np.zeros(L, np.int32)
    tiles = np.zeros(L, np.int32)
    offset = np.zeros(L, np.int64)
    n = 0
    for l, lay in enumerate(layouts):
        w, h, f = (int(x) for x in lay)
        if w < 1 or h < 1 or f < 1 or w % f != 0:
            raise ValueError(f"lightmap {l}: invalid layout (width={w}, height={h}, tiles={f}); "
                             "width must be a positive multiple of tiles")
        width[l], height[l], tiles[l], offset[l] = w, h, f, n
        n += w * h
    return Lightmaps(offset, width, height, tiles,
                     np.zeros(n), np.zeros(n), np.ones(n), np.zeros((n, n_bands)), np.zeros(n),
                     np.zeros(n, np.int64), np.zeros((n, n_bands)), np.zeros(n, np.int8),
                     np.full(n, -1, np.int32), np.zeros(0, np.int64), np.zeros((0, 64), np.int8))


def n_texels(lm):
    return lm.area.shape[0]


def texel_slice(lm, lm_id):
    o = int(lm.offset[lm_id])
    return slice(o, o + int(lm.width[lm_id]) * int(lm.height[lm_id]))


def resolution_for(area_world, texel_density, min_res=2, max_res=1024):
    """Texels per side so that a texel is about 1/density metres wide.

    For primitives pass the area of one face (one tile), for meshes the whole
    surface area of the atlas.
    """
    a = float(area_world)
    d = float(texel_density)
    if not (math.isfinite(a) and a > 0.0 and math.isfinite(d) and d > 0.0):
        return int(min_res)
    r = int(math.ceil(math.sqrt(a) * d - 1e-9))
    return int(min(max(r, int(min_res)), int(max_res)))


def set_areas(lm, lm_id, area, coverage=None):
    """Writes a lightmap's texel areas (row-major, lightmap layout) and coverage."""
    sl = texel_slice(lm, lm_id)
    n = sl.stop - sl.start
    area = np.asarray(area, np.float64).reshape(-1)
    if area.size != n:
        raise ValueError(f"lightmap {lm_id}: expected {n} texel areas, got {area.size}")
    if not np.all(np.isfinite(area)) or np.any(area < 0):
        raise ValueError(f"lightmap {lm_id}: texel areas must be finite and >= 0")
    lm.area[sl] = area
    if coverage is None:
        lm.coverage[sl] = 1.0
    else:
        lm.coverage[sl] = np.clip(np.asarray(coverage, np.float64).reshape(-1), 0.0, 1.0)


def set_triangle_areas(lm, lm_id, uv, area3d):
    """Fills a mesh atlas lightmap from its UV triangles and world triangle areas."""
    w, h = int(lm.width[lm_id]), int(lm.height[lm_id])
    area, cov = triangle_texel_areas(uv, area3d, w, h)
    set_areas(lm, lm_id, area, cov)


def set_primitive_areas(lm, lm_id, kind, params, M, order=None):
    """Fills a primitive's lightmap (F tiles of R×R) from its world linear map M."""
    f, w, h = int(lm.tiles[lm_id]), int(lm.width[lm_id]), int(lm.height[lm_id])
    r = w // f
    if h != r:
        raise ValueError(f"lightmap {lm_id}: primitive tiles must be square, got {r}x{h}")
    a = primitive_texel_areas(kind, params, M, r, order)
    if a.size != f * r * r:
        raise ValueError(f"lightmap {lm_id}: layout has {f} tiles, primitive kind {kind} "
                         f"has {a.size // (r * r)} faces")
    set_areas(lm, lm_id, faces_to_rows(a, f, r), None)


def faces_to_rows(face_major, n_faces, r):
    """(F, R, R) face-major areas -> lightmap row layout (tiles side by side)."""
    a = np.asarray(face_major, np.float64).reshape(n_faces, r, r)
    return np.ascontiguousarray(a.transpose(1, 0, 2)).reshape(-1)


# --------------------------------------------------------------------------------------
# Photon recording
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _tile_of(lm, lm_id, face):
    """(width, height, tile side, face clamped to the tiles) of lightmap lm_id."""
    w = np.int64(lm.width[lm_id])
    nt = np.int64(lm.tiles[lm_id])
    f = min(max(np.int64(face), 0), nt - 1)
    return w, np.int64(lm.height[lm_id]), w // nt, f


@njit(cache=True, inline="always")
def texel_index(lm, lm_id, face, s, t):
    """Texel hit at chart coordinate (s, t) in [0,1]² of tile `face` (clamped)."""
    w, h, r, f = _tile_of(lm, lm_id, face)
    if not (s > 0.0):   # also catches NaN
        s = 0.0
    if not (t > 0.0):
        t = 0.0
    x = np.int64(min(s, 1.0) * r)
    y = np.int64(min(t, 1.0) * h)
    if x >= r:
        x = r - 1
    if y >= h:
        y = h - 1
    return lm.offset[lm_id] + y * w + f * r + x


# Inlined into the per-hit loops: a call would copy the Geometry and Lightmaps
# tuples for a few array reads.
@njit(cache=True, inline="always")
def lightmap_slot(g, lm, inst, shape, face, u, v):
    """(lightmap id, face, s, t) where hit (inst, shape, face, u, v) lands; id -1 if none."""
    base = g.inst_lm_base[inst]
    slot = g.shape_surface[shape]
    if base < 0 or slot < 0:
        return -1, 0, 0.0, 0.0
    if g.shape_kind[shape] == 0:
        # Triangle: interpolate the atlas UVs with the barycentrics.
        uv = g.tri_uv[g.shape_index[shape]]
        w0 = 1.0 - u - v
        s = w0 * uv[0, 0] + u * uv[1, 0] + v * uv[2, 0]
        t = w0 * uv[0, 1] + u * uv[1, 1] + v * uv[2, 1]
        return base + slot, 0, s, t
    return base + slot, face, u, v


@njit(cache=True, inline="always")
def record_slot(g, lm, inst, shape, face, u, v):
    """lightmap_slot for recording a photon: -1 on a triangle without UV area,
    which owns no texel area, so a photon counted anywhere would be misplaced."""
    lid, f, s, t = lightmap_slot(g, lm, inst, shape, face, u, v)
    if lid >= 0 and g.shape_kind[shape] == 0 and not has_uv_area(g.tri_uv[g.shape_index[shape]]):
        return -1, f, s, t
    return lid, f, s, t


SPLIT_SUB = 8   # sampling grid of a split texel per side: 64 cells, one uint64 mask (split_texels.py)


@njit(cache=True, inline="always")
def record_index(lm, lm_id, face, s, t):
    """Row that a hit at (s, t) of tile `face` records into: its texel, or for
    a split texel the sub-texel of the sampling cell under the hit."""
    i = texel_index(lm, lm_id, face, s, t)
    k = lm.split[i]
    if k < 0:
        return i
    r = np.int64(lm.width[lm_id]) // np.int64(lm.tiles[lm_id])
    fx = min(max(s, 0.0), 1.0) * r
    fy = min(max(t, 0.0), 1.0) * r
    cx = min(max(np.int64((fx - min(math.floor(fx), r - 1)) * SPLIT_SUB), 0), SPLIT_SUB - 1)
    cy = min(max(np.int64((fy - min(math.floor(fy), r - 1)) * SPLIT_SUB), 0), SPLIT_SUB - 1)
    c = np.int64(lm.split_cell[k, cy * SPLIT_SUB + cx])
    if c <= 0:
        return i
    return lm.split_first[k] + c - 1


@njit(cache=True)
def accumulate_kernel(lm, texel_ids, powers):
    """Serial, in record order: same input order -> bit-identical sums. Ids < 0 are skipped."""
    flux = lm.flux
    flux_sq = lm.flux_sq
    hits = lm.hits
    for k in range(texel_ids.shape[0]):
        i = texel_ids[k]
        if i >= 0:
            _add_record(flux, flux_sq, hits, i, powers[k])


def accumulate_records(lm, fine, rec_texel, rec_power, n_rows, n_main):
    """Adds a photon chunk's records (rec_texel[:n_rows], ids < 0 empty) in record
    order: ids below n_main to lm, the others, less n_main, to `fine` (the
    caustic lightmaps; pass lm when there are none). The same sums as
    `accumulate` on each map's records in order, without the masked copies the
    serial step between chunks would make. Returns the records added."""
    return _accumulate_records(lm.flux, lm.flux_sq, lm.hits, fine.flux, fine.flux_sq, fine.hits,
                               rec_texel, rec_power, n_rows, n_main)


# The arrays, not the tuples: a read of a tuple's field in the loop would cost a
# reference count each time.
@njit(cache=True, nogil=True)
def _accumulate_records(flux, flux_sq, hits, f_flux, f_flux_sq, f_hits, rec_texel, rec_power, n_rows, n_main):
    n = 0
    for r in range(n_rows):
        for j in range(rec_texel.shape[1]):
            i = rec_texel[r, j]
            if i < 0:
                continue
            if i < n_main:
                _add_record(flux, flux_sq, hits, i, rec_power[r, j])
            else:
                _add_record(f_flux, f_flux_sq, f_hits, i - n_main, rec_power[r, j])
            n += 1
    return n


@njit(cache=True, inline="always")
def _add_record(flux, flux_sq, hits, i, power):
    nb = flux.shape[1]
    m = 0.0
    for b in range(nb):
        flux[i, b] += power[b]
        m += power[b]
    m *= 1.0 / nb
    flux_sq[i] += m * m
    hits[i] += 1


def accumulate(lm, texel_ids, powers):
    """Adds photon records (texel id int64[K], power float64[K,B]) to the lightmaps."""
    ids = np.ascontiguousarray(texel_ids, dtype=np.int64).reshape(-1)
    pw = np.ascontiguousarray(powers, dtype=np.float64)
    nb = lm.flux.shape[1]
    if pw.ndim == 1:
        pw = pw.reshape(-1, nb) if nb > 1 else pw.reshape(-1, 1)
    if pw.shape != (ids.shape[0], nb):
        raise ValueError(f"powers must have shape ({ids.shape[0]}, {nb}), got {pw.shape}")
    if ids.size and ids.max() >= lm.area.shape[0]:
        raise ValueError(f"texel id {ids.max()} out of range ({lm.area.shape[0]} texels)")
    accumulate_kernel(lm, ids, pw)


def clear(lm):
    """Forgets all recorded photons (areas stay)."""
    lm.flux[:] = 0.0
    lm.flux_sq[:] = 0.0
    lm.hits[:] = 0
    lm.irradiance[:] = 0.0
    lm.state[:] = STATE_EMPTY


# --------------------------------------------------------------------------------------
# Reconstruction: E = flux / area, then dilation
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _owner(offset, i):
    """Lightmap containing texel i (offsets ascending, no end sentinel: hi = L is
    never read, and "none above" then means the last lightmap)."""
    return first_above(offset, i, 0, offset.shape[0]) - 1


# Parallel kernels take the texel arrays one by one: numba (0.68) silently drops
# writes made through a namedtuple field inside a prange loop.
@njit(cache=True, parallel=True)
def _irradiance(offset, area, open_, flux, threshold, irradiance, state):
    n = area.shape[0]
    nb = flux.shape[1]
    for i in prange(n):
        l = _owner(offset, i)
        # a texel buried whole (open 0) holds no surface: empty, filled by dilation
        ao = area[i] * open_[i]
        if ao > threshold[l] and ao > 0.0:
            for b in range(nb):
                irradiance[i, b] = flux[i, b] / ao
            state[i] = STATE_MEASURED
        else:
            for b in range(nb):
                irradiance[i, b] = 0.0
            state[i] = STATE_EMPTY


@njit(cache=True, parallel=True)
def _dilate_pass(offset, width, height, tiles, irr_prev, state_prev, irradiance, state):
    """Each empty texel takes the mean of its non-empty 8-neighbours inside the same tile."""
    n = state.shape[0]
    nb = irradiance.shape[1]
    changed = 0
    for i in prange(n):
        if state_prev[i] != STATE_EMPTY:
            continue
        l = _owner(offset, i)
        w = np.int64(width[l])
        h = np.int64(height[l])
        r = w // np.int64(tiles[l])
        local = i - offset[l]
        y = local // w
        x = local - y * w
        x_lo = (x // r) * r
        x_hi = x_lo + r - 1
        cnt = 0
        for b in range(nb):
            irradiance[i, b] = 0.0
        for dy in range(-1, 2):
            ny = y + dy
            if ny < 0 or ny >= h:
                continue
            for dx in range(-1, 2):
                nx = x + dx
                if (dx == 0 and dy == 0) or nx < x_lo or nx > x_hi:
                    continue
                j = offset[l] + ny * w + nx
                if state_prev[j] != STATE_EMPTY:
                    for b in range(nb):
                        irradiance[i, b] += irr_prev[j, b]
                    cnt += 1
        if cnt > 0:
            inv = 1.0 / cnt
            for b in range(nb):
                irradiance[i, b] *= inv
            state[i] = STATE_DILATED
            changed += 1
    return changed


def empty_thresholds(lm):
    """Per lightmap: texels with area <= this are empty after finalize() (slivers)."""
    L = lm.offset.shape[0]
    threshold = np.zeros(L)
    for l in range(L):
        sl = texel_slice(lm, l)
        n = sl.stop - sl.start
        if n:
            threshold[l] = EMPTY_AREA_FRACTION * float(lm.area[sl].sum()) / n
    return threshold


def is_measured(lm, lm_id, threshold=None):
    """bool per texel of lightmap lm_id: the texels finalize() computes (the rest are dilated)."""
    thr = empty_thresholds(lm)[lm_id] if threshold is None else threshold
    a = lm.area[texel_slice(lm, lm_id)]
    return (a > thr) & (a > 0.0)


def finalize(lm, passes=DILATION_PASSES):
    """Irradiance E = flux / (area·open) per texel, then `passes` rings of dilation:
    what a ray landing on the texel's open surface reads (open_area.py).

    Texels with (near-)zero area get E = 0 and are marked empty; dilation then
    fills empty texels next to valid ones (within the same tile only), so that
    bilinear reconstruction near chart borders reads plausible values. Can be
    called repeatedly (progressive rendering): it always recomputes from flux.
    """
    threshold = empty_thresholds(lm)
    if lm.area.shape[0] == 0:
        return
    _irradiance(lm.offset, lm.area, lm.open, lm.flux, threshold, lm.irradiance, lm.state)
    for _ in range(int(passes)):
        irr_prev = lm.irradiance.copy()
        state_prev = lm.state.copy()
        if _dilate_pass(lm.offset, lm.width, lm.height, lm.tiles, irr_prev, state_prev,
                        lm.irradiance, lm.state) == 0:
            break


# --------------------------------------------------------------------------------------
# Lookups (renderer)
# --------------------------------------------------------------------------------------

@njit(cache=True)
def lookup_constant(lm, lm_id, face, s, t, out):
    """E of the texel containing (s, t) of tile `face` -> out (B,)."""
    i = texel_index(lm, lm_id, face, s, t)
    for b in range(out.shape[0]):
        out[b] = lm.irradiance[i, b]


@njit(cache=True)
def lookup_bilinear(lm, lm_id, face, s, t, out):
    """Bilinear E between texel centres, clamped to the tile, skipping empty texels."""
    w, h, r, f = _tile_of(lm, lm_id, face)
    if not (s > 0.0):
        s = 0.0
    if not (t > 0.0):
        t = 0.0
    s = min(s, 1.0)
    t = min(t, 1.0)
    fx = s * r - 0.5
    fy = t * h - 0.5
    x0f = math.floor(fx)
    y0f = math.floor(fy)
    wx = fx - x0f
    wy = fy - y0f
    x0 = np.int64(x0f)
    y0 = np.int64(y0f)
    x1 = min(max(x0 + 1, 0), r - 1)
    y1 = min(max(y0 + 1, 0), h - 1)
    x0 = min(max(x0, 0), r - 1)
    y0 = min(max(y0, 0), h - 1)
    base = lm.offset[lm_id] + f * r
    for b in range(out.shape[0]):
        out[b] = 0.0
    wsum = 0.0
    for k in range(4):
        xx = x1 if (k & 1) else x0
        yy = y1 if (k & 2) else y0
        wk = (wx if (k & 1) else 1.0 - wx) * (wy if (k & 2) else 1.0 - wy)
        i = base + yy * w + xx
        if wk > 0.0 and lm.state[i] != STATE_EMPTY:
            for b in range(out.shape[0]):
                out[b] += wk * lm.irradiance[i, b]
            wsum += wk
    if wsum > 0.0:
        inv = 1.0 / wsum
        for b in range(out.shape[0]):
            out[b] *= inv
    else:
        lookup_constant(lm, lm_id, face, s, t, out)


@njit(cache=True)
def lookup(lm, lm_id, face, s, t, mode, out):
    i = texel_index(lm, lm_id, face, s, t)
    if lm.split[i] >= 0:
        # a split texel: its sub-texels do not blend across the cut
        j = record_index(lm, lm_id, face, s, t)
        for b in range(out.shape[0]):
            out[b] = lm.irradiance[j, b]
        return
    if mode == MODE_BILINEAR:
        lookup_bilinear(lm, lm_id, face, s, t, out)
    else:
        lookup_constant(lm, lm_id, face, s, t, out)


# --------------------------------------------------------------------------------------
# Statistics
# --------------------------------------------------------------------------------------

def memory_bytes(lm):
    return int(sum(a.nbytes for a in lm))


def texel_stats(lm):
    """Per-lightmap mean E and hits per texel, per-texel relative standard error.

    The relative error of a texel's flux estimate is sqrt(Σ p_k²) / Σ p_k over its
    photon records (band means): 1/sqrt(m) for m equal-power photons.
    """
    L = lm.offset.shape[0]
    nb = lm.flux.shape[1]
    fm = lm.flux.mean(axis=1)
    rel = np.full(lm.area.shape[0], np.inf)
    ok = fm > 0
    rel[ok] = np.sqrt(lm.flux_sq[ok]) / fm[ok]
    mean_e = np.zeros((L, nb))
    hpt = np.zeros(L)
    med = np.full(L, np.inf)
    for l in range(L):
        sl = texel_slice(lm, l)
        a = lm.area[sl]
        valid = a > 0
        atot = a[valid].sum()
        if atot > 0:
            mean_e[l] = lm.flux[sl][valid].sum(axis=0) / atot
        if valid.any():
            hpt[l] = lm.hits[sl][valid].sum() / valid.sum()
        hit = lm.hits[sl] > 0
        if hit.any():
            med[l] = float(np.median(rel[sl][hit]))
    return LightmapStats(mean_e, hpt, rel, med, memory_bytes(lm))
