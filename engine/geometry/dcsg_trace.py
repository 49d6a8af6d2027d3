"""Rays through the DCSG blob (engine/geometry/dcsg_blob.py): lazy expansion of the
cyclic scene graph per ray, with the expansion cache's BVHs, the closest hit, its
surface and OL stub address; and stand-alone tracing of one graph (tests, the CLI)."""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..core import features
from ..core.affine import cross, normal_through, unit, xform_ray
from ..core.jit import CORE, INLINE, as_float32, as_float64, as_uint64, typed
from .primitives import prim_hits, prim_surface
from ..core.sampling import mix64
from ..core.scene import SceneError
from .trace_layout import H_F64
from .wide_bvh import ctz, descend, drop_far, pop_node, ray_slabs, slab4
from .dcsg import ORGAN
from .dcsg_blob import (
    B_ALT_C0, B_ALT_CUM, B_ALT_NC, B_CACHE_REC, B_CACHE_ROOT, B_CHAIN_J, B_CH_BOX, B_CH_INV,
    B_CH_J, B_CH_NODE, B_CH_ROT, B_GRAPH_HASH, B_GRAPH_ROOT, B_GRAPH_STUB, B_ITEM_C0,
    B_ITEM_INV, B_ITEM_NC, B_ITEM_PRIM, B_ITEM_STUB, B_NODE_ALT0, B_NODE_BOX, B_NODE_CACHE,
    B_NODE_NALT, B_NODE_PRIM, B_NODE_STUB, B_ORG_NT, B_ORG_T0, B_ORG_TRI, B_PRIM_INV,
    B_PRIM_KIND, B_PRIM_PARAMS, B_STUB_ADDR, B_VS0, CACHE_STACK, H_DCSG, MAX_DEPTH,
    SCRATCH_WORDS, STACK_ENTRIES, ENTRY_F64, ENTRY_U64, pack_blob)


# ---------------------------------------------------------------- ray kernels
# uint64 arithmetic with uint64 constants only: numba turns uint64 op int64 into float64.

_GOLD = np.uint64(0x9E3779B97F4A7C15)
_DRAW = np.uint64(0xD1B54A32D192ED03)
_S11, _S32 = np.uint64(11), np.uint64(32)
_LO32 = np.uint64(0xFFFFFFFF)


@njit(**INLINE)
def _splitmix64(x):
    """grammar.splitmix64, the L-system format's generator, in uint64 arithmetic."""
    return mix64(x + _GOLD)


@njit(**INLINE)
def child_hash(h, j):
    return _splitmix64(h ^ (np.uint64(j + 1) * _GOLD))


@njit(**INLINE)
def _draw(h):
    return float(_splitmix64(h ^ _DRAW) >> _S11) * (2.0 ** -53)


@njit(**INLINE)
def _u64(i32, k):
    """The uint64 stored as int32 words k (low), k + 1 (high)."""
    return (np.uint64(np.uint32(i32[k])) & _LO32) | (np.uint64(np.uint32(i32[k + 1])) << _S32)


@njit(**INLINE)
def dcsg_base(buf):
    """Word offsets of the DCSG blob: (int64/float64 index, int32 index)."""
    i64 = buf[0]
    w = (i64[H_F64] >> 3) + i64[H_DCSG]
    return w, 2 * w


@njit(**INLINE)
def dcsg_vs0(buf):
    """First virtual shape of a DCSG primitive (NO_VSHAPE when the scene has none)."""
    i64 = buf[0]
    return i64[dcsg_base(buf)[0] + B_VS0]


@njit(**INLINE)
def alternative(i32, f64, o_alt0, o_nalt, o_cum, node, h):
    """The alternative a node of hash h takes: lsystem's choice, draw(h) against the
    running probabilities (the last one on rounding)."""
    k = i32[o_alt0 + node]
    nalt = i32[o_nalt + node]
    if nalt > 1:
        u = _draw(h)
        last = k + nalt - 1
        while k < last and not f64[o_cum + k] > u:
            k += 1
    return k


# The blob's tables (dcsg_blob.py): per node its alternatives, terminal primitive,
# stub flag and box; per alternative its children and cumulative probability;
# per child edge its node, index, inverse transform, rotation and box; per
# terminal primitive its kind, parameters and inverse transform.
BlobTables = namedtuple("BlobTables", "alt0 nalt prim stub ac0 anc chn chj pk box cum cinv crot cbox pp pinv")

# The expansion cache's tables: per node its cache (-1: none); per cache its root
# record; the 4-wide records; per item its terminal, chain of child indices,
# innermost stub along the chain and inverse transform.
CacheTables = namedtuple("CacheTables", "node root rec item_prim item_c0 item_nc chain item_inv item_stub")


@njit(**INLINE)
def blob_tables(i64, w, iw):
    """Start of each blob table in its view: int32 ones, then float64 ones."""
    return BlobTables(iw + i64[w + B_NODE_ALT0], iw + i64[w + B_NODE_NALT], iw + i64[w + B_NODE_PRIM],
                      iw + i64[w + B_NODE_STUB], iw + i64[w + B_ALT_C0], iw + i64[w + B_ALT_NC],
                      iw + i64[w + B_CH_NODE], iw + i64[w + B_CH_J], iw + i64[w + B_PRIM_KIND],
                      w + i64[w + B_NODE_BOX], w + i64[w + B_ALT_CUM], w + i64[w + B_CH_INV],
                      w + i64[w + B_CH_ROT], w + i64[w + B_CH_BOX], w + i64[w + B_PRIM_PARAMS],
                      w + i64[w + B_PRIM_INV])


@njit(**INLINE)
def _cache_tables(i64, w, iw):
    """Start of each expansion-cache table in its view (the records: int32 / float32)."""
    return CacheTables(iw + i64[w + B_NODE_CACHE], iw + i64[w + B_CACHE_ROOT], iw + i64[w + B_CACHE_REC],
                       iw + i64[w + B_ITEM_PRIM], iw + i64[w + B_ITEM_C0], iw + i64[w + B_ITEM_NC],
                       iw + i64[w + B_CHAIN_J], w + i64[w + B_ITEM_INV], iw + i64[w + B_ITEM_STUB])


@njit(**INLINE)
def _inverse_dir(d):
    """1/d, with 1e300 of the same sign for d = 0: the slab test needs no branch then
    (a ray parallel to a slab outside it gets a huge finite entry: a false positive
    that tbest culls, never a false negative)."""
    if d != 0.0:
        return 1.0 / d
    return -1e300 if math.copysign(1.0, d) < 0.0 else 1e300


@njit(**INLINE)
def _slabs(f64, b, ox, oy, oz, ix, iy, iz, tmin, tmax):
    """Entry distance into the box at f64[b:b+6] of the ray with inverse direction
    (ix, iy, iz) within (tmin, tmax), or inf. The exit is widened by 1e-12 relative
    (the rounding of (b - o) / d)."""
    a0 = (f64[b] - ox) * ix
    a1 = (f64[b + 3] - ox) * ix
    b0 = (f64[b + 1] - oy) * iy
    b1 = (f64[b + 4] - oy) * iy
    c0 = (f64[b + 2] - oz) * iz
    c1 = (f64[b + 5] - oz) * iz
    t0 = max(tmin, min(a0, a1), min(b0, b1), min(c0, c1))
    t1 = min(tmax, max(a0, a1), max(b0, b1), max(c0, c1))
    t1 = t1 * (1.0 + 1e-12) if t1 > 0.0 else t1 * (1.0 - 1e-12)
    return t0 if t0 <= t1 else math.inf


@njit(**INLINE)
def _scratch(s0):
    """Offsets of the ray scratch: float64 entries, uint64 entries (float64 / uint64
    index), then int32 indices of the nodes, edges, depths, path, best path, the
    cache-BVH stack, its float64 entry t's (float64 index), and the result."""
    fb = s0 // 2
    hb = fb + ENTRY_F64 * STACK_ENTRIES
    nb = 2 * (hb + ENTRY_U64 * STACK_ENTRIES)
    eb = nb + STACK_ENTRIES
    db = eb + STACK_ENTRIES
    pb = db + STACK_ENTRIES
    bp = pb + MAX_DEPTH
    kb = bp + MAX_DEPTH
    k2 = kb + CACHE_STACK
    k2 += k2 % 2
    rb = k2 + 2 * CACHE_STACK
    return fb, hb, nb, eb, db, pb, bp, kb, k2 // 2, rb


@njit(**INLINE)
def _keep_path(stack, pb, bp, d):
    """The edge path to the current node (depth d) becomes the closest hit's."""
    for q in range(1, d + 1):
        stack[bp + q] = stack[pb + q]


@njit(**INLINE)
def organ_tables(i64, w, iw):
    """(first triangle, triangle count: int32 per organ; triangles: 9 float64 each)."""
    return iw + i64[w + B_ORG_T0], iw + i64[w + B_ORG_NT], w + i64[w + B_ORG_TRI]


@njit(**INLINE)
def _terminal_hit(i32, f64, o_pk, o_pp, o_org, p, m, ray, tmin, tbest):
    """Nearest crossing in (tmin, tbest) of terminal primitive row p, the ray
    (origin, direction) mapped into its frame by the 3x4 at f64[m:]: (t, local
    normal, not unit); t = inf if none. An organ is a triangle mesh (both sides;
    normal e1 x e2), any other kind an analytic primitive."""
    lx, ly, lz, ex, ey, ez = xform_ray(f64, m, ray[0], ray[1], ray[2], ray[3], ray[4], ray[5])
    pp = o_pp + 4 * p
    kind = i32[o_pk + p]
    if kind == ORGAN:
        o_t0, o_nt, o_tri = o_org
        g = np.int64(f64[pp])
        t = math.inf
        nx, ny, nz = 0.0, 0.0, 1.0
        t0 = i32[o_t0 + g]
        for k in range(t0, t0 + i32[o_nt + g]):
            q = o_tri + 9 * k
            ti, cx, cy, cz = _triangle(f64, q, lx, ly, lz, ex, ey, ez, tmin, min(t, tbest))
            if ti < t:
                t, nx, ny, nz = ti, cx, cy, cz
        return t, nx, ny, nz
    params = (f64[pp], f64[pp + 1], f64[pp + 2], f64[pp + 3])
    n, t0_, t1, t2, t3 = prim_hits(kind, params, lx, ly, lz, ex, ey, ez)
    for i in range(n):
        ti = (t0_, t1, t2, t3)[i]
        if ti > tmin and ti < tbest:
            _fc, _u, _v, nx, ny, nz = prim_surface(kind, params, lx + ti * ex, ly + ti * ey,
                                                   lz + ti * ez)
            return ti, nx, ny, nz
    return math.inf, 0.0, 0.0, 1.0


@njit(**INLINE)
def _triangle(f64, q, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Moller-Trumbore against the triangle at f64[q:q+9] (v0, v1, v2): (t, e1 x e2),
    t = inf outside (tmin, tmax) or on a miss."""
    ax, ay, az = f64[q], f64[q + 1], f64[q + 2]
    e1x, e1y, e1z = f64[q + 3] - ax, f64[q + 4] - ay, f64[q + 5] - az
    e2x, e2y, e2z = f64[q + 6] - ax, f64[q + 7] - ay, f64[q + 8] - az
    px, py, pz = cross(dx, dy, dz, e2x, e2y, e2z)
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return math.inf, 0.0, 0.0, 1.0
    inv = 1.0 / det
    sx, sy, sz = ox - ax, oy - ay, oz - az
    u = (sx * px + sy * py + sz * pz) * inv
    if u < 0.0 or u > 1.0:
        return math.inf, 0.0, 0.0, 1.0
    qx, qy, qz = cross(sx, sy, sz, e1x, e1y, e1z)
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return math.inf, 0.0, 0.0, 1.0
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    if not (t > tmin and t < tmax):
        return math.inf, 0.0, 0.0, 1.0
    nx, ny, nz = cross(e1x, e1y, e1z, e2x, e2y, e2z)
    return t, nx, ny, nz


# What a traversal reads of the blob: its typed views, its word offsets, and the
# start of each table (blob_tables, _cache_tables, organ_tables).
DcsgView = namedtuple("DcsgView", "i64 f32 i32 f64 w iw blob cache org")

# The closest hit so far: distance, terminal primitive row, the address of its
# innermost stub and its own, the depth of its node, and its normal in that node's frame.
Best = namedtuple("Best", "t p stub addr depth nx ny nz")


@njit(**INLINE)
def _view(buf):
    i64, f32, i32, f64 = buf[:4]
    w, iw = dcsg_base(buf)
    return DcsgView(i64, f32, i32, f64, w, iw, blob_tables(i64, w, iw), _cache_tables(i64, w, iw),
                    organ_tables(i64, w, iw))


@njit(**CORE)
def dcsg_closest_core(buf, stack, s0, graph, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit):
    """Closest hit of a prototype-space ray with DCSG `graph`, expanded lazily:
    (t, virtual shape id); (tmax, -1) on a miss. On a hit the normal (prototype
    space) and the stub's index in the scene's stub table (-1: none) are left for
    `dcsg_hit_surface`. any_hit: stop at the first hit (occlusion).

    Like a BVH node, a node holds its children's boxes in its own frame, so a
    child is entered (its ray transformed, pushed) only when the ray meets its box;
    the nearest child is expanded first. Entries carry only the ray: the hit's
    normal is rotated to the object by the edge path, once per ray."""
    v = _view(buf)
    sb = _scratch(s0)
    fb, hb, nb, eb, db, pb = sb[:6]
    fs = as_float64(stack)
    us = as_uint64(stack)
    root = v.i32[v.iw + v.i64[v.w + B_GRAPH_ROOT] + graph]
    t_root = _slabs(v.f64, v.blob.box + 6 * root, ox, oy, oz, _inverse_dir(dx), _inverse_dir(dy),
                    _inverse_dir(dz), tmin, tmax)
    if t_root == math.inf:
        return tmax, -1
    fs[fb], fs[fb + 1], fs[fb + 2], fs[fb + 3], fs[fb + 4], fs[fb + 5] = ox, oy, oz, dx, dy, dz
    fs[fb + 6] = t_root
    us[hb] = _u64(v.i32, v.iw + v.i64[v.w + B_GRAPH_HASH] + 2 * graph)
    us[hb + 1] = np.uint64(0)
    stack[nb], stack[eb], stack[db] = root, -1, 0
    sp = 1
    best = Best(tmax, np.int64(-1), np.uint64(0), np.uint64(0), np.int64(0), 0.0, 0.0, 1.0)
    while sp > 0:
        sp -= 1
        f = fb + ENTRY_F64 * sp
        if fs[f + 6] >= best.t:
            continue
        node = stack[nb + sp]
        d = stack[db + sp]
        e = stack[eb + sp]
        stack[pb + d] = e                # ancestors' edges at 1..d-1 are still in place (DFS)
        h = us[hb + 2 * sp]
        stub = h if v.i32[v.blob.stub + node] else us[hb + 2 * sp + 1]
        # copied out: the children are pushed over this very entry. Entries hold the
        # parent's ray; it enters the child's frame only now, past the tbest cull.
        ray = (fs[f], fs[f + 1], fs[f + 2], fs[f + 3], fs[f + 4], fs[f + 5])
        if e >= 0:
            ray = xform_ray(v.f64, v.blob.cinv + 12 * e, ray[0], ray[1], ray[2], ray[3], ray[4], ray[5])
        entry = (node, h, stub, d)
        ci = v.i32[v.cache.node + node]
        p = v.i32[v.blob.prim + node]
        if ci >= 0:                      # an expanded subgraph: its BVH, in this node's frame
            best = _cached_subgraph(v, stack, sb, ci, entry, ray, tmin, best, any_hit)
        elif p >= 0:                     # a terminal root (terminal children are tested below)
            m = v.blob.pinv + 12 * p
            t, nx, ny, nz = _terminal_hit(v.i32, v.f64, v.blob.pk, v.blob.pp, v.org, p, m, ray, tmin, best.t)
            if t < best.t:
                best = _take(v, stack, sb, m, (t, p, stub, h, d), (nx, ny, nz))
        else:
            base = sp
            sp, best = _expand(v, stack, sb, entry, ray, tmin, best, sp, any_hit)
            if not (any_hit and best.p >= 0):
                _sort_level(stack, sb, base, sp)
        if any_hit and best.p >= 0:
            break
    return _finish(v, stack, sb, best, graph)


@njit(**INLINE)
def _take(v, stack, sb, m, hit, n):
    """The hit (t, p, stub, address, depth) with local normal n, in the frame of the
    3x4 at f64[m:], becomes the closest: its node's normal and edge path are kept."""
    t, p, stub, addr, d = hit
    _keep_path(stack, sb[5], sb[6], d)
    nx, ny, nz = normal_through(v.f64, m, n[0], n[1], n[2])
    return Best(t, np.int64(p), stub, addr, np.int64(d), nx, ny, nz)


@njit(**INLINE)
def _cached_subgraph(v, stack, sb, ci, entry, ray, tmin, best, any_hit):
    """The closest hit, so far, after the items of expansion-cache BVH ci (in the
    frame of the entry's node): each item a terminal with its transform and the
    chain of child indices that makes its address."""
    c = v.cache
    i32, f64 = v.i32, v.f64
    kb = sb[7]
    f32s = as_float32(stack)
    _, h, stub, d = entry
    rox, roy, roz, rdx, rdy, rdz = ray
    sx, sy, sz, nxo, nyo, nzo = ray_slabs(rdx, rdy, rdz)
    rec = i32[c.root + ci]
    ks = kb
    while True:
        b = c.rec + 32 * rec
        mk, lm, n0, n1, n2, n3 = slab4(v.f32, b, rox, roy, roz, sx, sy, sz, nxo, nyo, nzo, tmin, best.t)
        ml = mk & lm
        mi = mk & ~lm
        t_in = best.t
        while ml != 0:
            k = ctz(ml)
            ml &= ml - 1
            a_ = i32[b + 24 + k]
            for it in range(a_, a_ + i32[b + 28 + k]):
                p = i32[c.item_prim + it]
                m = c.item_inv + 12 * it
                ti, nx, ny, nz = _terminal_hit(i32, f64, v.blob.pk, v.blob.pp, v.org, p, m, ray, tmin, best.t)
                if ti < best.t:
                    hh = h               # the address: the chain of child indices
                    s_ = stub
                    at = i32[c.item_stub + it]   # and the innermost stub along it
                    c0_ = i32[c.item_c0 + it]
                    for q in range(c0_, c0_ + i32[c.item_nc + it]):
                        hh = child_hash(hh, i32[c.chain + q])
                        if q - c0_ + 1 == at:
                            s_ = hh
                    best = _take(v, stack, sb, m, (ti, p, s_, hh, d), (nx, ny, nz))
        if any_hit and best.p >= 0:
            return best
        if best.t < t_in:
            mi = drop_far(mi, n0, n1, n2, n3, best.t)
        rec, ks = descend(stack, f32s, ks, i32, b, mi, n0, n1, n2, n3, best.t)
        if rec < 0:
            rec, ks = pop_node(stack, f32s, ks, kb, best.t)
            if rec < 0:
                return best


@njit(**INLINE)
def _expand(v, stack, sb, entry, ray, tmin, best, sp, any_hit):
    """The entry's node takes its alternative: terminal children are tested at once,
    the others whose box the ray meets are pushed -> (stack pointer, closest hit)."""
    bt = v.blob
    i32, f64 = v.i32, v.f64
    fb, hb, nb, eb, db = sb[:5]
    fs = as_float64(stack)
    us = as_uint64(stack)
    node, h, stub, d = entry
    rox, roy, roz, rdx, rdy, rdz = ray
    ix, iy, iz = _inverse_dir(rdx), _inverse_dir(rdy), _inverse_dir(rdz)
    k = alternative(i32, f64, bt.alt0, bt.nalt, bt.cum, node, h)
    c0 = i32[bt.ac0 + k]
    for c in range(c0, c0 + i32[bt.anc + k]):
        te = _slabs(f64, bt.cbox + 6 * c, rox, roy, roz, ix, iy, iz, tmin, best.t)
        if te == math.inf:
            continue
        child = i32[bt.chn + c]
        p = i32[bt.prim + child]
        if p >= 0:                   # a terminal: test it now, with no push
            m = bt.cinv + 12 * c
            ti, nx, ny, nz = _terminal_hit(i32, f64, bt.pk, bt.pp, v.org, p, m, ray, tmin, best.t)
            if ti < best.t:
                best = _take(v, stack, sb, m, (ti, p, stub, child_hash(h, i32[bt.chj + c]), d), (nx, ny, nz))
            if any_hit and best.p >= 0:
                return sp, best
            continue
        g = fb + ENTRY_F64 * sp
        fs[g], fs[g + 1], fs[g + 2], fs[g + 3], fs[g + 4], fs[g + 5] = rox, roy, roz, rdx, rdy, rdz
        fs[g + 6] = te
        stack[nb + sp], stack[eb + sp], stack[db + sp] = child, c, d + 1
        us[hb + 2 * sp] = child_hash(h, i32[bt.chj + c])
        us[hb + 2 * sp + 1] = stub
        sp += 1
    return sp, best


@njit(**INLINE)
def _sort_level(stack, sb, base, sp):
    """Entries base..sp-1 (one node's children) sorted far first: the nearest child on top."""
    fb, hb, nb, eb = sb[:4]
    fs = as_float64(stack)
    us = as_uint64(stack)
    for i in range(base + 1, sp):
        j = i
        while j > base and fs[fb + ENTRY_F64 * (j - 1) + 6] < fs[fb + ENTRY_F64 * j + 6]:
            a_, b_ = fb + ENTRY_F64 * (j - 1), fb + ENTRY_F64 * j
            for q in range(ENTRY_F64):
                fs[a_ + q], fs[b_ + q] = fs[b_ + q], fs[a_ + q]
            for q in (nb, eb):
                stack[q + j - 1], stack[q + j] = stack[q + j], stack[q + j - 1]
            for q in range(2):
                us[hb + 2 * (j - 1) + q], us[hb + 2 * j + q] = us[hb + 2 * j + q], us[hb + 2 * (j - 1) + q]
            j -= 1


@njit(**INLINE)
def _finish(v, stack, sb, best, graph):
    """-> (t, virtual shape) of the closest hit, (its tmax, -1) for none; a hit's
    normal is rotated from its node to the object along the kept edge path, and
    with its address and stub index left in the result words."""
    if best.p < 0:
        return best.t, -1
    bp, rb = sb[6], sb[9]
    f64 = v.f64
    fs = as_float64(stack)
    us = as_uint64(stack)
    rf = rb // 2                       # result: normal (3 float64), stub (int32 at rb + 6), address
    bnx, bny, bnz = best.nx, best.ny, best.nz
    for q in range(best.depth, 0, -1):       # node -> object: R_c1 (R_c2 (... R_cd n))
        r = v.blob.crot + 9 * stack[bp + q]
        bnx, bny, bnz = (f64[r] * bnx + f64[r + 1] * bny + f64[r + 2] * bnz,
                         f64[r + 3] * bnx + f64[r + 4] * bny + f64[r + 5] * bnz,
                         f64[r + 6] * bnx + f64[r + 7] * bny + f64[r + 8] * bnz)
    fs[rf], fs[rf + 1], fs[rf + 2] = unit(bnx, bny, bnz)
    us[rf + 4] = best.addr
    stack[rb + 6] = _stub_index(v.i32, v.iw, v.i64[v.w + B_GRAPH_STUB], v.i64[v.w + B_STUB_ADDR], graph, best.stub)
    return best.t, v.i64[v.w + B_VS0] + best.p


@njit(**INLINE)
def _stub_index(i32, iw, o_rows, o_addr, graph, addr):
    """Index of stub address `addr` in the scene's stub table (the graph's rows of it
    are sorted), -1 if none."""
    if addr == np.uint64(0):
        return -1
    lo = i32[iw + o_rows + 2 * graph]
    hi = lo + i32[iw + o_rows + 2 * graph + 1] - 1
    while lo <= hi:
        mid = (lo + hi) // 2
        v = _u64(i32, iw + o_addr + 2 * mid)
        if v == addr:
            return mid
        if v < addr:
            lo = mid + 1
        else:
            hi = mid - 1
    return -1


@njit(**INLINE)
def dcsg_hit_surface(stack, s0):
    """(stub index, nx, ny, nz, address) of the last DCSG hit `dcsg_closest_core` returned."""
    fs = as_float64(stack)
    rb = _scratch(s0)[-1]
    rf = rb // 2
    return stack[rb + 6], fs[rf], fs[rf + 1], fs[rf + 2], as_uint64(stack)[rf + 4]


# ---------------------------------------------------------------- stand-alone tracing

def dcsg_table(graphs):
    """A minimal trace-style buffer holding only the DCSG blob, so the same kernels
    run on it as on a Geometry (tests, the CLI, benchmarks) -> (buf views, prim_graph, stubs)."""
    blob, prim_graph, stubs = pack_blob(graphs, vs0=0)
    hdr = np.zeros(32, np.int64)
    hdr[H_F64] = 32 * 8
    hdr[H_DCSG] = 0
    from .bvh import aligned_empty
    raw = aligned_empty(hdr.nbytes + blob.nbytes, np.uint8)      # the records' vector loads
    raw[:hdr.nbytes] = hdr.view(np.uint8)
    raw[hdr.nbytes:] = blob.view(np.uint8)
    views = (raw.view(np.int64), raw.view(np.float32), raw.view(np.int32), raw.view(np.float64),
             features.marker(features.DCSG))
    return views, prim_graph, stubs


@njit(cache=True)
def _closest_batch(buf, origins, dirs, tmax, t_out, p_out, s_out, h_out, n_out):
    stack = np.empty(SCRATCH_WORDS + 2, np.int32)
    for i in range(origins.shape[0]):
        # typed, not literal, arguments: the traversal's signature (jit.typed)
        t, vs = dcsg_closest_core(buf, stack, typed(0), typed(0), origins[i, 0], origins[i, 1],
                                  origins[i, 2], dirs[i, 0], dirs[i, 1], dirs[i, 2], 0.0, tmax[i],
                                  typed(False))
        t_out[i] = t
        p_out[i] = vs
        s, n_out[i, 0], n_out[i, 1], n_out[i, 2], h_out[i] = dcsg_hit_surface(stack, 0)
        s_out[i] = s if vs >= 0 else -1


def trace_closest(graph, origins, dirs, tmax=math.inf):
    """Closest hits of object-space rays with one graph: (t, terminal primitive row,
    address, stub index into `stub_addresses(graph)` (-1: none), unit normal (n, 3));
    t = tmax and row -1 on a miss."""
    views, _pg, stubs = dcsg_table([graph])
    o = np.ascontiguousarray(origins, np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(dirs, np.float64).reshape(-1, 3)
    if not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        raise SceneError("DCSG rays: non-finite origin or direction")
    n = o.shape[0]
    tm = np.broadcast_to(np.asarray(tmax, np.float64), (n,)).copy()
    t, p, s, nrm = np.empty(n), np.empty(n, np.int64), np.empty(n, np.int64), np.empty((n, 3))
    h = np.empty(n, np.uint64)
    _closest_batch(views, o, d, tm, t, p, s, h, nrm)
    return t, p, h, s, nrm


