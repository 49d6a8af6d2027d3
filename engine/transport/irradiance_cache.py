"""Irradiance caching for the bake's final gather (Ward, Rubinstein & Clear 1988).

The per-texel gather (bake_gather) sends its rays from points spread over every
texel. Indirect light changes slowly over most surfaces, so most of those rays
measure what the texel's neighbours measure too. Here the gather runs at a
sparse set of *records* instead, and every texel point interpolates the records
around it, as Ward's irradiance cache and Unreal's Lightmass do:

* A record is a world point, the side it gathers on (its normal), its
  irradiance from about `rays` gather rays (the per-texel gather's own,
  final_gather.gather_irradiance, one per cell of a stratified hemisphere), the
  standard error of that, its radius R: the harmonic mean distance of those
  rays to what surrounds it, clamped to [MIN_RADIUS_TEXELS, MAX_RADIUS_TEXELS]
  texels (near a wall, in a corner or where an object rests on the floor, R is
  small; on open surfaces it is large), and its irradiance gradients (Ward &
  Heckbert 1992), for a move across the surface and a tilt of the normal,
  from the same rays.
* A point x with normal n reads the records with
      eps_i = |x - x_i| / R_i + sqrt(1 - n·n_i) < ACCURACY
  and not in front of it, weighted w_i = 1/eps_i - 1/ACCURACY (which falls to 0
  at the edge of a record's reach, so the result is continuous), each record's
  irradiance carried to x by its gradients: E_i + (x - x_i)·gt_i +
  (n_i x n)·gr_i. Records are world points: texels on both sides of a UV seam,
  or of two objects that meet, read the same records, so no seam is made.
  The gradients matter where light changes across a record's reach: under the
  benchmark's baffle they take the bake's error against Cycles from 0.136 to
  0.075 (the per-texel gather: 0.104) at the same records.
* Placement is adaptive: the first records sit at every RECORD_STRIDE-th texel
  of each lightmap; then, for up to REFINE_ROUNDS rounds, every texel with a
  point no record reaches gets a record at that point. Where R is small (contact,
  corners, gradients of geometry) that places them densely.
* A texel some point of which no record reaches after the last round falls back
  to the per-texel gather, so nothing is left out; so do the texels that
  records past MAX_RECORDS_PER_ITEM would have served.

Direct light stays per texel (texel_gather), and caustics are read per point
from their own lightmap. Mesh texels only: primitives and CSG solids keep the
per-texel gather.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from . import texel_gather
from ..core import parallel
from . import final_gather
from .bake_gather import GatherPass, add_mesh_caustic, mirror_moments
from .path_vertex import new_path_scratch
from ..core.jit import CORE
from ..lightmaps.lightmap import MODE_BILINEAR as LM_MODE_BILINEAR
from ..core.sampling import next_float, orthonormal_basis, stream_state

RECORD_STRIDE = 3         # first records: every 3rd texel along each lightmap axis
ACCURACY = 0.35           # Ward's a: the reach of a record, in eps units
MIN_RADIUS_TEXELS = 2.0
MAX_RADIUS_TEXELS = 12.0
REFINE_ROUNDS = 3
# Records, each as many rays as a texel's own gather, at most this many per texel:
# where walls are thin and everything is near something (the window room's 0.1 m
# walls: 1.9 records per texel without it) the rest gather per texel.
MAX_RECORDS_PER_ITEM = 0.6
# |n_i x n| at the edge of a record's reach in normal (1 - cos = ACCURACY²)
MAX_TILT = math.sqrt(1.0 - (1.0 - ACCURACY ** 2) ** 2)
CLAMP_PASSES = 8          # neighbour clamping, repeated until it changes nothing (at most)
STREAM_RECORD = np.uint64(0x9E6C63D0676A9A99)


# --------------------------------------------------------------------------------------
# Records: gather and radius
# --------------------------------------------------------------------------------------

def strata(n_rays):
    """(rings, sectors) of a record's stratified hemisphere, about n_rays cells:
    Ward & Heckbert's split, sectors ~ pi x rings, and an even number of sectors
    (neighbouring pairs estimate the error)."""
    m = max(1, int(round(math.sqrt(max(int(n_rays), 1) / math.pi))))
    return m, max(2, (max(int(n_rays), 1) // m) // 2 * 2)


@njit(cache=True, nogil=True)
def _records(scene, mode, sites, strata, rec, start, stop):
    """Records start..stop-1: the block's scratch, then the core. sites = (pos,
    nrm, key, size) of each record; strata = (rings, sectors); rec = (E, se,
    radius, gt, gr), the records' columns to fill (E wider than the bands: a
    directional bake's, its moments after them)."""
    nb = rec[3].shape[1]
    n = strata[0] * strata[1]
    _records_core(scene, mode, sites, strata, rec, start, stop, new_path_scratch(nb),
                  (np.empty(rec[0].shape[1]), np.empty((n, nb)), np.empty(n)))


@njit(**CORE)
def _records_core(scene, mode, sites, strata, rec, start, stop, w, cells):
    pos, nrm, key, size = sites
    n_theta, n_phi = strata
    E, se, radius, gt, gr = rec
    e, cell_e, cell_t = cells
    nb = gt.shape[1]
    n = n_theta * n_phi
    wc = 1.0 / n
    for r in range(start, stop):
        state = stream_state(key[r] ^ STREAM_RECORD, r)
        p = (pos[r, 0], pos[r, 1], pos[r, 2])
        nx, ny, nz = nrm[r, 0], nrm[r, 1], nrm[r, 2]
        for b in range(e.shape[0]):
            e[b] = 0.0
        final_gather.gather_irradiance(scene, w, p, (nx, ny, nz), (nx, ny, nz), n, mode, state, e,
                                       (n_theta, cell_e, cell_t))
        inv = 0.0
        for c in range(n):
            if cell_t[c] > 0.0 and cell_t[c] < math.inf:
                inv += 1.0 / cell_t[c]
        for b in range(e.shape[0]):
            E[r, b] = e[b]
        # standard error of the mean from neighbouring pairs of cells: a pair's
        # difference holds both cells' variance (and a little of the light's change)
        d2 = 0.0
        for c in range(0, n, 2):
            m = 0.0
            for b in range(nb):
                m += cell_e[c, b] - cell_e[c + 1, b]
            d2 += (m / nb) ** 2
        se[r] = math.sqrt(d2) * wc
        # Ward's radius: the harmonic mean distance to the surroundings (a miss is far)
        rr = n / inv if inv > 0.0 else math.inf
        radius[r] = min(max(rr, MIN_RADIUS_TEXELS * size[r]), MAX_RADIUS_TEXELS * size[r])
        tx, ty, tz, bx, by, bz = orthonormal_basis(nx, ny, nz)   # the frame the rays were cut in
        _gradients(cell_e, cell_t, n_theta, n_phi, tx, ty, tz, bx, by, bz, E, radius[r], r, gt, gr)


@njit(cache=True, error_model="numpy")
def _gradients(cell_e, cell_t, n_theta, n_phi, tx, ty, tz, bx, by, bz, E, R, r, gt, gr):
    """Ward & Heckbert's (1992) irradiance gradients of record r from its cells.

    Translation: moving the record moves every boundary between cells by how far
    away the nearer of the two surfaces seen across it is; each boundary trades
    its length of projected solid angle between the two cells' radiances.
    Rotation: tilting the normal by a small angle about axis a changes E by
    a · sum of L tan(theta) v(phi) over the cells (v: the tangent at right angles
    to the cell's azimuth). Each is capped so that at the edge of the record's
    reach it moves E by at most E itself: a gradient measured over a nearby
    contact must not push an interpolated value below zero."""
    nb = gt.shape[1]
    n = n_theta * n_phi
    for b in range(nb):
        gx = gy = gz = 0.0
        rx = ry = rz = 0.0
        for k in range(n_phi):
            km = k - 1 if k > 0 else n_phi - 1
            ring = 0.0      # along u(k): boundaries between rings j-1 and j
            side = 0.0      # along v(k-): the boundary between sectors k-1 and k
            rot = 0.0
            for j in range(n_theta):
                c = j * n_phi + k
                L = cell_e[c, b] / math.pi
                if j > 0:
                    cm = c - n_phi
                    t = min(cell_t[c], cell_t[cm])
                    if t < math.inf:
                        s2 = j / n_theta
                        ring += math.sqrt(s2) * (1.0 - s2) * (L - cell_e[cm, b] / math.pi) / t
                cm = j * n_phi + km
                t = min(cell_t[c], cell_t[cm])
                if t < math.inf:
                    side += (math.sqrt((j + 1) / n_theta) - math.sqrt(j / n_theta)) * (L - cell_e[cm, b] / math.pi) / t
                s2 = (j + 0.5) / n_theta
                rot += L * math.sqrt(s2 / (1.0 - s2))
            ring *= 2.0 * math.pi / n_phi
            pc = 2.0 * math.pi * (k + 0.5) / n_phi       # the sector's middle
            pb = 2.0 * math.pi * k / n_phi               # its boundary with sector k-1
            cu, su = math.cos(pc), math.sin(pc)
            cv, sv = -math.sin(pb), math.cos(pb)
            gx += ring * (cu * tx + su * bx) + side * (cv * tx + sv * bx)
            gy += ring * (cu * ty + su * by) + side * (cv * ty + sv * by)
            gz += ring * (cu * tz + su * bz) + side * (cv * tz + sv * bz)
            cv, sv = -su, cu                              # v at the sector's middle
            rx += rot * (cv * tx + sv * bx)
            ry += rot * (cv * ty + sv * by)
            rz += rot * (cv * tz + sv * bz)
        rs = math.pi / n
        rx, ry, rz = rx * rs, ry * rs, rz * rs
        cap = E[r, b] / (ACCURACY * R) if R > 0.0 and R < math.inf else 0.0
        mag = math.sqrt(gx * gx + gy * gy + gz * gz)
        s = cap / mag if mag > cap else 1.0
        gt[r, b, 0], gt[r, b, 1], gt[r, b, 2] = gx * s, gy * s, gz * s
        cap = E[r, b] / MAX_TILT
        mag = math.sqrt(rx * rx + ry * ry + rz * rz)
        s = cap / mag if mag > cap else 1.0
        gr[r, b, 0], gr[r, b, 1], gr[r, b, 2] = rx * s, ry * s, rz * s


# --------------------------------------------------------------------------------------
# The lookup grid: each record listed in every cell its reach overlaps (hashed)
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _hash(ix, iy, iz, mask):
    h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)
    return h & mask


@njit(cache=True)
def _cell_range(pos, reach, cell, r):
    return (np.int64(math.floor((pos[r, 0] - reach[r]) / cell)), np.int64(math.floor((pos[r, 0] + reach[r]) / cell)),
            np.int64(math.floor((pos[r, 1] - reach[r]) / cell)), np.int64(math.floor((pos[r, 1] + reach[r]) / cell)),
            np.int64(math.floor((pos[r, 2] - reach[r]) / cell)), np.int64(math.floor((pos[r, 2] + reach[r]) / cell)))


@njit(cache=True)
def _build_grid(pos, reach, cell, mask):
    """CSR over hash slots: start[h]..start[h+1] in entries are the records whose
    reach overlaps a cell hashing to h (cells that collide share a slot)."""
    n_slots = mask + 1
    start = np.zeros(n_slots + 1, np.int64)
    for r in range(pos.shape[0]):
        x0, x1, y0, y1, z0, z1 = _cell_range(pos, reach, cell, r)
        for ix in range(x0, x1 + 1):
            for iy in range(y0, y1 + 1):
                for iz in range(z0, z1 + 1):
                    start[_hash(ix, iy, iz, mask) + 1] += 1
    for i in range(n_slots):
        start[i + 1] += start[i]
    entries = np.empty(start[n_slots], np.int64)
    fill = start[:n_slots].copy()
    for r in range(pos.shape[0]):
        x0, x1, y0, y1, z0, z1 = _cell_range(pos, reach, cell, r)
        for ix in range(x0, x1 + 1):
            for iy in range(y0, y1 + 1):
                for iz in range(z0, z1 + 1):
                    h = _hash(ix, iy, iz, mask)
                    entries[fill[h]] = r
                    fill[h] += 1
    return start, entries


@njit(cache=True)
def _clamp_radii(pos, R, cell, mask, start, entries):
    """Neighbour clamping (Křivánek et al. 2006): R_i <= R_j + |x_i - x_j| for every
    record j within i's reach, so a record next to one that sees nearby geometry
    (a shadow edge, a contact) cannot reach across it with a larger radius.
    start/entries: each record hashed to the one cell holding its position
    (_build_grid with no reach), so a query visits each candidate once."""
    out = R.copy()
    for i in range(pos.shape[0]):
        reach = ACCURACY * R[i]
        x0 = np.int64(math.floor((pos[i, 0] - reach) / cell))
        x1 = np.int64(math.floor((pos[i, 0] + reach) / cell))
        y0 = np.int64(math.floor((pos[i, 1] - reach) / cell))
        y1 = np.int64(math.floor((pos[i, 1] + reach) / cell))
        z0 = np.int64(math.floor((pos[i, 2] - reach) / cell))
        z1 = np.int64(math.floor((pos[i, 2] + reach) / cell))
        for ix in range(x0, x1 + 1):
            for iy in range(y0, y1 + 1):
                for iz in range(z0, z1 + 1):
                    h = _hash(ix, iy, iz, mask)
                    for k in range(start[h], start[h + 1]):
                        j = entries[k]
                        d = math.sqrt((pos[i, 0] - pos[j, 0]) ** 2 + (pos[i, 1] - pos[j, 1]) ** 2
                                      + (pos[i, 2] - pos[j, 2]) ** 2)
                        if d < reach and R[j] + d < out[i]:
                            out[i] = R[j] + d
    return out


class Grid:
    """Records hashed by the cells their reach (ACCURACY·R) overlaps."""

    def __init__(self, pos, radius):
        reach = ACCURACY * radius
        self.cell = max(float(np.median(reach)) if reach.size else 1.0, 1e-9)
        # Cells each record touches, bounded: reach / cell is at most MAX/MIN radius.
        span = np.floor((pos + reach[:, None]) / self.cell) - np.floor((pos - reach[:, None]) / self.cell) + 1
        n = int(np.prod(span, axis=1).sum()) if reach.size else 1
        self.mask = (1 << max(int(math.ceil(math.log2(max(2 * n, 2)))), 1)) - 1
        self.start, self.entries = _build_grid(pos, reach, self.cell, self.mask)


# --------------------------------------------------------------------------------------
# Interpolation at the texels' points
# --------------------------------------------------------------------------------------

@njit(cache=True, nogil=True)
def _interpolate(scene, tx, job, rec, out, var, misses, start, stop):
    """Items job.order[start:stop] of mesh texels tx: the block's scratch, then the core.
    job: the bake's GatherPass (points and stream; order: the items to do); rec:
    the records (Records); misses = (miss, miss_pos, miss_nrm), the first point
    of each item that no record reaches. out: (items, job.bands), or a
    directional bake's wider rows (the records' E as wide)."""
    _interpolate_core(scene, tx, job, rec, out, var, misses, start, stop, np.empty((3, out.shape[1])),
                      np.empty(job.bands))


@njit(**CORE)
def _interpolate_core(scene, tx, job, rec, out, var, misses, start, stop, bands, caustic):
    miss, miss_pos, miss_nrm = misses
    e, ep, tmp = bands[0], bands[1], bands[2]
    nb = job.bands
    n_points = job.points
    k = texel_gather.grid_side(n_points)
    for j in range(start, stop):
        it = job.order[j]
        for b in range(e.shape[0]):
            e[b] = 0.0
        miss[it] = 0
        v2 = 0.0
        pieces = texel_gather.mesh_texel_pieces(scene.geometry, tx, it)
        n_ok = 0
        if pieces[2] > 0.0:
            # the per-texel gather's points: the same stream, so the same places
            state = texel_gather.texel_stream(tx, it, job.stream)
            for s in range(n_points):
                state, j1 = next_float(state)
                state, j2 = next_float(state)
                u1, u2 = texel_gather.jitter(s, k, j1, j2)
                ok, px, py, pz, nx, ny, nz, t, b1, b2 = texel_gather.mesh_texel_sample(
                    scene.geometry, tx, pieces, u1, u2)
                if not ok:
                    continue
                n_ok += 1
                for b in range(ep.shape[0]):
                    ep[b] = 0.0
                texel_gather.add_normal(ep, nb, nx, ny, nz)
                for sgn in (1.0, -1.0):
                    if tx.side[it] * sgn < 0.0:
                        continue
                    fx, fy, fz = sgn * nx, sgn * ny, sgn * nz
                    wsum, vs = lookup(rec, (px, py, pz), (fx, fy, fz), tmp)
                    if wsum <= 0.0:
                        if miss[it] == 0:
                            miss[it] = 1
                            miss_pos[it, 0], miss_pos[it, 1], miss_pos[it, 2] = px, py, pz
                            miss_nrm[it, 0], miss_nrm[it, 1], miss_nrm[it, 2] = fx, fy, fz
                        continue
                    if sgn < 0.0:
                        # the back side's moments as if from the front (bake_gather.point_indirect)
                        mirror_moments(tmp, nb, (nx, ny, nz))
                    for b in range(ep.shape[0]):
                        ep[b] += tmp[b]
                    v2 += vs
                if scene.caustics:
                    add_mesh_caustic(scene, tx, it, t, b1, b2, (nx, ny, nz), caustic, ep)
                for b in range(e.shape[0]):
                    e[b] += ep[b]
        for b in range(e.shape[0]):
            out[it, b] = e[b] / n_ok if n_ok > 0 else 0.0
        # neighbouring points read the same records: their errors are not
        # independent, so the texel keeps the mean per-point variance
        var[it] = v2 / n_ok if n_ok > 0 else 0.0


@njit(**CORE)
def lookup(rec, p, n, out):
    """Ward's weighted mean of the records (Records) that reach p, each moved to p
    and tilted to normal n by its gradients -> (weight sum, variance of the mean
    from the records' errors); out[bands] the irradiance (0 weights: none). An
    out as wide as the records' E also gets their moments' weighted mean (no
    gradients)."""
    px, py, pz = p
    nx, ny, nz = n
    rec_pos, rec_nrm, rec_E, rec_se, rec_R, rec_gt, rec_gr = rec.pos, rec.nrm, rec.E, rec.se, rec.R, rec.gt, rec.gr
    cell = rec.cell
    nb = rec_gt.shape[1]
    for b in range(out.shape[0]):
        out[b] = 0.0
    h = _hash(np.int64(math.floor(px / cell)), np.int64(math.floor(py / cell)),
              np.int64(math.floor(pz / cell)), rec.mask)
    wsum = 0.0
    w2v = 0.0
    for j in range(rec.start[h], rec.start[h + 1]):
        r = rec.entries[j]
        w = _weight(px, py, pz, nx, ny, nz, rec_pos, rec_nrm, rec_R, r)
        if not w > 0.0:
            continue
        wsum += w
        w2v += w * w * rec_se[r] * rec_se[r]
        dx, dy, dz = px - rec_pos[r, 0], py - rec_pos[r, 1], pz - rec_pos[r, 2]
        # n_i x n: the axis (times the sine) that tilts the record's normal onto x's
        ax = rec_nrm[r, 1] * nz - rec_nrm[r, 2] * ny
        ay = rec_nrm[r, 2] * nx - rec_nrm[r, 0] * nz
        az = rec_nrm[r, 0] * ny - rec_nrm[r, 1] * nx
        for b in range(nb):
            v = (rec_E[r, b] + dx * rec_gt[r, b, 0] + dy * rec_gt[r, b, 1] + dz * rec_gt[r, b, 2]
                 + ax * rec_gr[r, b, 0] + ay * rec_gr[r, b, 1] + az * rec_gr[r, b, 2])
            out[b] += w * max(v, 0.0)
        for b in range(nb, out.shape[0]):
            out[b] += w * rec_E[r, b]
    if wsum > 0.0:
        for b in range(out.shape[0]):
            out[b] /= wsum
        return wsum, w2v / (wsum * wsum)
    return 0.0, 0.0


@njit(cache=True, inline="always", error_model="numpy")
def _weight(px, py, pz, nx, ny, nz, rec_pos, rec_nrm, rec_R, r):
    """Ward's weight 1/eps - 1/a of record r at x (0: it does not reach x)."""
    dx, dy, dz = px - rec_pos[r, 0], py - rec_pos[r, 1], pz - rec_pos[r, 2]
    cosn = nx * rec_nrm[r, 0] + ny * rec_nrm[r, 1] + nz * rec_nrm[r, 2]
    if cosn <= 0.0:
        return 0.0
    eps = math.sqrt(dx * dx + dy * dy + dz * dz) / rec_R[r] + math.sqrt(max(1.0 - cosn, 0.0))
    if eps >= ACCURACY:
        return 0.0
    # a record in front of x (above its surface) sees what x does not
    front = (dx * (nx + rec_nrm[r, 0]) + dy * (ny + rec_nrm[r, 1]) + dz * (nz + rec_nrm[r, 2])) * 0.5
    if front < -0.05 * rec_R[r]:
        return 0.0
    return 1.0 / max(eps, 1e-6) - 1.0 / ACCURACY


# --------------------------------------------------------------------------------------
# The bake's cached gather of mesh texels
# --------------------------------------------------------------------------------------

def _first_sites(cs, cat):
    """Items whose texel lies on the every-RECORD_STRIDE-th lattice of its lightmap."""
    lm = cs.lightmaps
    w = lm.width[cat.lid].astype(np.int64)
    x, y = cat.local % w, cat.local // w
    return np.flatnonzero((x % RECORD_STRIDE == 0) & (y % RECORD_STRIDE == 0))


def _dense_items(cat, owner, missed):
    """bool per item: its lightmap's first records (at every RECORD_STRIDE-th
    texel) serve fewer than 1 / MAX_RECORDS_PER_ITEM of its texels each, so records
    there would not be sparse. Its texels are gathered one by one instead, which
    costs no more and interpolates nothing: on a room of coarse texels (the
    window room's 6 x 6 texels per wall face, 0.6 m each) records reach less than
    a texel, and reading them smoothed the light at the window's jambs (objects
    1.8 % dark, against 0.9 % per texel). A lightmap with no first record is left
    to the rounds."""
    n = int(cat.lid.max()) + 1 if cat.lid.size else 0
    reached = np.ones(cat.lid.size, bool)
    reached[missed] = False
    served = np.bincount(cat.lid[reached], minlength=n)
    first = np.bincount(cat.lid[owner], minlength=n)
    return ((first > 0) & (first > MAX_RECORDS_PER_ITEM * served))[cat.lid]


def _texel_sizes(cs, cat):
    """World size of each item's texel: the square root of a whole texel's area.
    A texel on a chart's border covers only part of its square; its covered area
    over its coverage is what a whole one would hold. Radii are clamped in these
    units, and a sliver's own small area made records there reach almost nothing
    (and neighbour clamping spread that: thin walls ended with more records than
    texels)."""
    area = np.add.reduceat(cat.area, cat.start[:-1]) if cat.area.size else np.zeros(0)
    area[np.diff(cat.start) == 0] = 0.0
    cover = cs.lightmaps.coverage[cat.texel] if cat.texel.size else np.zeros(0)
    return np.sqrt(np.maximum(area, 0.0) / np.maximum(cover, 0.05))


def _site_points(cs, cat, items, stream):
    """(pos, nrm, key, size) records at the first point of each given item, one per
    lit side (both sides of an open surface)."""
    pos = np.zeros((items.size, 3))
    nrm = np.zeros((items.size, 3))
    ok = np.zeros(items.size, bool)
    _centres(cs.geometry, cat, items, pos, nrm, ok)
    return _sided(cat, items[ok], pos[ok], nrm[ok])


@njit(cache=True)
def _centres(g, tx, items, pos, nrm, ok):
    for j in range(items.shape[0]):
        it = items[j]
        pieces = texel_gather.mesh_texel_pieces(g, tx, it)
        if not pieces[2] > 0.0:
            continue
        good, px, py, pz, nx, ny, nz, _, _, _ = texel_gather.mesh_texel_sample(g, tx, pieces, 0.5, 0.5)
        if good:
            ok[j] = True
            pos[j, 0], pos[j, 1], pos[j, 2] = px, py, pz
            nrm[j, 0], nrm[j, 1], nrm[j, 2] = nx, ny, nz


def _sided(cat, items, pos, nrm):
    side = cat.side[items]
    rows, normals = [], []
    for sgn in (1.0, -1.0):
        keep = side * sgn >= 0
        rows.append(np.flatnonzero(keep))
        normals.append(sgn * nrm[keep])
    order = np.concatenate(rows)
    return (np.ascontiguousarray(pos[order]), np.ascontiguousarray(np.concatenate(normals)),
            np.ascontiguousarray(cat.key[items][order]), items[order])


class Cache:
    """Records of one bake, grown round by round."""

    def __init__(self, nb, width=None):
        self.pos = np.zeros((0, 3))
        self.nrm = np.zeros((0, 3))
        self.E = np.zeros((0, width or nb))    # a directional bake's: the moments after the bands
        self.se = np.zeros(0)
        self.R = np.zeros(0)
        self.gt = np.zeros((0, nb, 3))      # translational gradient dE/dx
        self.gr = np.zeros((0, nb, 3))      # rotational gradient (E changes by gr · (n_i x n))
        self.rays = 0

    def add(self, scene, mode, pos, nrm, key, size, n_rays, first_id):
        n = pos.shape[0]
        if n == 0:
            return
        nb = self.gt.shape[1]
        E, se, R = np.zeros((n, self.E.shape[1])), np.zeros(n), np.zeros(n)
        gt, gr = np.zeros((n, nb, 3)), np.zeros((n, nb, 3))
        # the record's id in the key: records of later rounds at the same texel differ
        keyed = key ^ (np.arange(first_id, first_id + n, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15))
        n_theta, n_phi = strata(n_rays)
        parallel.run(_records, n, scene, int(mode), (pos, nrm, keyed, size), (n_theta, n_phi), (E, se, R, gt, gr),
                     remote=True)
        self.pos = np.concatenate([self.pos, pos])
        self.nrm = np.concatenate([self.nrm, nrm])
        self.E = np.concatenate([self.E, E])
        self.se = np.concatenate([self.se, se])
        self.R = np.concatenate([self.R, R])
        self.gt = np.concatenate([self.gt, gt])
        self.gr = np.concatenate([self.gr, gr])
        self.rays += n * n_theta * n_phi


def cached_mesh_gather(cs, scene, mode, cat, n_points, n_rays, stream, width=None):
    """The gather of the mesh items `cat` (bake_gather's MeshTexels) through
    the irradiance cache -> (E (K, B), var (K,), fallback items, info): the items in
    `fallback` were not reached by any record and must be gathered per texel.
    width: a directional bake's row width (texel_gather.moment_width): E's rows
    are then its rows, moments and all."""
    out, var, missed, info, _ = _build(cs, scene, mode, cat, n_points, n_rays, stream, width)
    return out, var, missed, info


def _build(cs, scene, mode, cat, n_points, n_rays, stream, width=None):
    """Records placed for the items of `cat`, round by round -> (E, var, missed, info,
    (cache, grid)) with E and var interpolated at every item's points."""
    nb = cs.n_bands
    K = cat.texel.size
    size = _texel_sizes(cs, cat)
    cache = Cache(nb, width)
    pos, nrm, key, owner = _site_points(cs, cat, _first_sites(cs, cat), stream)
    cache.add(scene, mode, pos, nrm, key, size[owner], n_rays, 0)
    out, var = np.zeros((K, width or nb)), np.zeros(K)
    miss = np.zeros(K, np.int64)
    rounds = 0
    miss_pos, miss_nrm = np.zeros((K, 3)), np.zeros((K, 3))
    # Round 0 interpolates every item; each later round places a record at the
    # first unreached point of every item that had one and tries those items
    # again (a reached point stays reached as records are added). If records were
    # added, a last pass interpolates every item with all of them.
    grid = [None]
    clamped_for = [-1]       # the record count the radii were last clamped for

    def interpolate(items):
        if clamped_for[0] != cache.pos.shape[0]:        # records were added: clamp again
            if cache.R.size:
                cell = max(float(np.median(ACCURACY * cache.R)), 1e-9)
                mask = (1 << max(int(math.ceil(math.log2(max(2 * cache.R.size, 2)))), 1)) - 1
                start, entries = _build_grid(cache.pos, np.zeros(cache.R.size), cell, mask)
                for _ in range(CLAMP_PASSES):   # until every neighbour pair obeys it (a chain needs passes)
                    clamped = _clamp_radii(cache.pos, cache.R, cell, mask, start, entries)
                    done = np.array_equal(clamped, cache.R)
                    cache.R = clamped
                    if done:
                        break
            clamped_for[0] = cache.pos.shape[0]
            grid[0] = Grid(cache.pos, cache.R)
        gr = grid[0]
        job = GatherPass(int(mode), int(n_points), np.zeros(0, np.int64), items, stream, nb)
        parallel.run(_interpolate, items.size, scene, cat, job, records(cache, gr), out, var,
                     (miss, miss_pos, miss_nrm), remote=True)
        return items[miss[items] > 0]

    missed = interpolate(np.arange(K, dtype=np.int64))
    dense = _dense_items(cat, owner, missed)
    missed = missed[~dense[missed]]
    budget = cache.pos.shape[0] + int(MAX_RECORDS_PER_ITEM * np.count_nonzero(~dense)) - int(np.sum(~dense[owner]))
    while missed.size and rounds < REFINE_ROUNDS and cache.pos.shape[0] < budget:
        rounds += 1
        room = budget - cache.pos.shape[0]
        # past the budget, records would cost more rays than gathering those texels
        # each: a subset spread over them, and the rest fall back
        add = missed if missed.size <= room else missed[np.linspace(0, missed.size - 1, room).astype(np.int64)]
        cache.add(scene, mode, miss_pos[add], miss_nrm[add], cat.key[add], size[add], n_rays,
                  cache.pos.shape[0])
        missed = interpolate(missed)
    if rounds:
        missed = interpolate(np.arange(K, dtype=np.int64))
    missed = np.union1d(missed, np.flatnonzero(dense))
    info = dict(records=int(cache.pos.shape[0]), rounds=rounds, record_rays=int(cache.rays),
                fallback_items=int(missed.size), items=int(K), dense_items=int(np.count_nonzero(dense)))
    return out, var, missed, info, (cache, grid[0])


# --------------------------------------------------------------------------------------
# Renders: one cache over every mesh lightmap, read at the camera's diffuse hits
# --------------------------------------------------------------------------------------

Records = namedtuple("Records", ["pos", "nrm", "E", "se", "R", "gt", "gr", "cell", "mask", "start", "entries"])


def records(cache, grid):
    """The Records of a Cache and its Grid."""
    return Records(cache.pos, cache.nrm, cache.E, cache.se, cache.R, cache.gt, cache.gr, float(grid.cell),
                   int(grid.mask), grid.start, grid.entries)


def no_records(nb):
    """The renderer's argument when no cache is used (nothing is ever reached)."""
    return Records(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, nb)), np.zeros(0), np.zeros(0),
                   np.zeros((0, nb, 3)), np.zeros((0, nb, 3)), 1.0, 1, np.zeros(3, np.int64), np.zeros(0, np.int64))


RENDER_POINTS = 16        # texel points that test where records reach while placing them


def scene_records(cs, rays, seed=0):
    """The records of every mesh lightmap of a traced compiled scene (the photon
    pass recorded direct light, as the final gather needs) -> (Records, info).
    View-independent: a camera animation builds them once."""
    from . import bake_gather
    ids = sorted({int(l) for lids in cs.instance_lightmaps for l in lids})
    tex = bake_gather.Texels(cs, ids, (), RENDER_POINTS, LM_MODE_BILINEAR, seed)
    if tex.mesh is None:
        return no_records(cs.n_bands), dict(records=0)
    _, _, _, info, (cache, grid) = _build(cs, tex.scene, tex.mode, tex.mesh, RENDER_POINTS, int(rays),
                                          bake_gather.STREAM_XOR)
    return records(cache, grid), info
