"""Ray–CSG kernels: hit-list interval classification (thesis 4.1, Roth 1982) over
the blob that geometry/csg.py flattens and packs (its docstring gives the
layout and how coincident boundaries are resolved), the hit's leaf surface,
and brute-force point membership."""
import math

import numpy as np
from numba import njit

from ..core.affine import normal_through, unit, xform_ray
from ..core.jit import CORE, INLINE
from .csg import (
    B_LEAF_FLIP, B_LEAF_INV, B_LEAF_KIND, B_LEAF_NODE0, B_LEAF_PARAMS, B_LEAF_TRI0,
    B_LEAF_VSHAPE, B_MNODE_A, B_MNODE_BOX, B_MNODE_CNT, B_MTRI, B_NLEAF, B_NODE_BOX, B_NODE_L,
    B_NODE_OP, B_NODE_R, B_NODE_RFIRST, B_NVSHAPE, B_VS0, B_VSHAPE_LEAF,
    CSG_SCRATCH_WORDS, DIFF, H_CSG, H_F64, INTER, LEAF, LIST_WORDS, MAX_INTERVALS, MAX_LISTS,
    MAX_WORK, MESH, MESH_STACK, SC_LEN, SC_LISTS, SC_MSTACK, SC_OVER, SC_TIES, SC_WORK, TIE_REL,
    UNION)
from .primitives import prim_hits, prim_inside, prim_surface
from .triangle import intersect_triangle, triangle_normal

# --------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------



@njit(**INLINE)
def csg_base(buf):
    """Byte offset of the CSG blob in a trace buffer (views (i64, f32, i32, f64, features))."""
    i64 = buf[0]
    return i64[H_F64] + 8 * i64[H_CSG]


@njit(**INLINE)
def _slab1(o, d, lo, hi, t0, t1):
    if d == 0.0:
        if o < lo or o > hi:
            return math.inf, -math.inf
        return t0, t1
    a = (lo - o) / d
    b = (hi - o) / d
    if a > b:
        a, b = b, a
    return max(t0, a), min(t1, b)


@njit(**INLINE)
def _box_clip(f, b, ox, oy, oz, dx, dy, dz, t0, t1):
    """[t0, t1] clipped to the box f[b:b+6] (lo xyz, hi xyz); empty: t0 > t1."""
    t0, t1 = _slab1(ox, dx, f[b], f[b + 3], t0, t1)
    t0, t1 = _slab1(oy, dy, f[b + 1], f[b + 4], t0, t1)
    t0, t1 = _slab1(oz, dz, f[b + 2], f[b + 5], t0, t1)
    return t0, t1


@njit(**INLINE)
def _lt(s0, L, k):
    """float64 index of boundary k of list L (scratch viewed as float64)."""
    return (s0 + SC_LISTS + L * LIST_WORDS) // 2 + k


@njit(**INLINE)
def _lo(s0, L, k):
    return s0 + SC_LISTS + L * LIST_WORDS + 4 * MAX_INTERVALS + k


@njit(**INLINE)
def _ls(s0, L, k):
    return s0 + SC_LISTS + L * LIST_WORDS + 6 * MAX_INTERVALS + k


@njit(**INLINE)
def _emit(sf, sc, s0, L, n, t, owner, sub):
    sf[_lt(s0, L, n)] = t
    sc[_lo(s0, L, n)] = owner
    sc[_ls(s0, L, n)] = sub
    return n + 1


@njit(**INLINE)
def _prim_leaf(buf, cb, sf, sc, s0, L, k, ox, oy, oz, dx, dy, dz, tlo, thi):
    """Intervals of primitive leaf k into list L; returns the boundary count."""
    i64, _f32, i32, f64 = buf[:4]
    h = cb >> 3
    c32 = cb >> 2
    kind = i32[c32 + i64[h + B_LEAF_KIND] + k]
    m = h + i64[h + B_LEAF_INV] + 12 * k
    lox, loy, loz, ldx, ldy, ldz = xform_ray(f64, m, ox, oy, oz, dx, dy, dz)
    pp = h + i64[h + B_LEAF_PARAMS] + 4 * k
    n, t0, t1, t2, t3 = prim_hits(kind, (f64[pp], f64[pp + 1], f64[pp + 2], f64[pp + 3]),
                                  lox, loy, loz, ldx, ldy, ldz)
    c = 0
    # intervals entirely outside the ray range cannot change a boundary inside it
    if n >= 2 and t1 >= tlo and t0 <= thi:
        c = _emit(sf, sc, s0, L, c, t0, k, -1)
        c = _emit(sf, sc, s0, L, c, t1, k, -1)
    if n >= 4 and t3 >= tlo and t2 <= thi:
        c = _emit(sf, sc, s0, L, c, t2, k, -1)
        c = _emit(sf, sc, s0, L, c, t3, k, -1)
    return c


@njit(**INLINE)
def _mesh_leaf(buf, cb, sf, sc, s0, L, k, ox, oy, oz, dx, dy, dz, tol):
    """Intervals of closed-mesh leaf k into list L from all crossings of the
    line (mesh BVH walk), by winding number of the oriented crossings."""
    i64, _f32, i32, f64 = buf[:4]
    h = cb >> 3
    c32 = cb >> 2
    node0 = i32[c32 + i64[h + B_LEAF_NODE0] + k]
    nb = h + i64[h + B_MNODE_BOX]
    na = c32 + i64[h + B_MNODE_A]
    nc = c32 + i64[h + B_MNODE_CNT]
    tri = h + i64[h + B_MTRI]
    cap = 2 * MAX_INTERVALS
    n = 0
    over = 0
    sp = 0
    node = node0
    while True:
        t0, t1 = _box_clip(f64, nb + 6 * node, ox, oy, oz, dx, dy, dz, -math.inf, math.inf)
        if t0 <= t1:
            cnt = i32[nc + node]
            if cnt == 0:
                if sp < MESH_STACK:
                    sc[s0 + SC_MSTACK + sp] = i32[na + node]
                    sp += 1
                else:
                    over += 1
                node = node + 1
                continue
            a = i32[na + node]
            for j in range(a, a + cnt):
                q = tri + 9 * j
                hit, t, b1, b2 = intersect_triangle(f64[q], f64[q + 1], f64[q + 2], f64[q + 3],
                                                    f64[q + 4], f64[q + 5], f64[q + 6],
                                                    f64[q + 7], f64[q + 8], ox, oy, oz,
                                                    dx, dy, dz, -math.inf, math.inf)
                if hit:
                    if n >= cap:
                        over += 1
                        continue
                    nx, ny, nz = triangle_normal(f64[q], f64[q + 1], f64[q + 2], f64[q + 3],
                                                 f64[q + 4], f64[q + 5], f64[q + 6],
                                                 f64[q + 7], f64[q + 8])
                    dn = nx * dx + ny * dy + nz * dz
                    # -1 / +1 along / against the stored winding (sgn below
                    # turns that into leaving / entering the mesh's solid)
                    s = -1 if dn > 0.0 else (1 if dn < 0.0 else 0)
                    if s != 0:
                        # insertion sort by t
                        i = n
                        while i > 0 and sf[_lt(s0, L, i - 1)] > t:
                            sf[_lt(s0, L, i)] = sf[_lt(s0, L, i - 1)]
                            sc[_lo(s0, L, i)] = sc[_lo(s0, L, i - 1)]
                            sc[_ls(s0, L, i)] = sc[_ls(s0, L, i - 1)]
                            i -= 1
                        sf[_lt(s0, L, i)] = t
                        sc[_lo(s0, L, i)] = s
                        sc[_ls(s0, L, i)] = j
                        n += 1
        if sp == 0:
            break
        sp -= 1
        node = sc[s0 + SC_MSTACK + sp]
    if over:
        sc[s0 + SC_OVER] += 1
    # mesh leaves keep their orientation (+1 outward, -1 inward) in params[0]
    sgn = 1 if f64[h + i64[h + B_LEAF_PARAMS] + 4 * k] >= 0.0 else -1
    # Winding number over the crossings. Crossings within tol of each other
    # (a ray through a shared edge hits both triangles) are one event whose
    # signs add up: a crossing counts once, a grazing touch (+1 -1) not at all.
    w = 0
    base = 0
    out = 0
    i = 0
    while i < n:
        t = sf[_lt(s0, L, i)]
        s = 0
        j = i
        last = i
        while j < n and sf[_lt(s0, L, j)] - t <= tol:
            s += sc[_lo(s0, L, j)]
            last = j
            j += 1
        if s > 1:
            s = 1
        elif s < -1:
            s = -1
        s *= sgn
        tr = sc[_ls(s0, L, last)]
        nw = w + s
        if (w > base) != (nw > base):
            out = _emit(sf, sc, s0, L, out, t, k, tr)
        w = nw
        i = j
    if out % 2 == 1:
        # an unclosed interval can only come from a numerically inconsistent
        # crossing sequence: drop it and report
        out -= 1
        sc[s0 + SC_OVER] += 1
    return out


@njit(**INLINE)
def _member(op, a, b):
    if op == UNION:
        return a or b
    if op == INTER:
        return a and b
    return a and not b


@njit(**INLINE)
def _combine(sf, sc, s0, op, A, nA, B, nB, T, tol):
    """Merges boundary lists A and B (nA, nB boundaries) under op into list T.
    Coincident boundaries (within tol) are one event; see the module docstring."""
    cap = 2 * MAX_INTERVALS
    i = 0
    j = 0
    ina = False
    inb = False
    res = False
    n = 0
    ties = 0
    while i < nA or j < nB:
        ta = sf[_lt(s0, A, i)] if i < nA else math.inf
        tb = sf[_lt(s0, B, j)] if j < nB else math.inf
        if i < nA and j < nB and abs(ta - tb) <= tol:
            ties += 1
            ina = not ina
            inb = not inb
            # the cut (B) owns a shared boundary of a difference, A otherwise
            if op == DIFF:
                t, own, sub = tb, sc[_lo(s0, B, j)], sc[_ls(s0, B, j)]
            else:
                t, own, sub = ta, sc[_lo(s0, A, i)], sc[_ls(s0, A, i)]
            i += 1
            j += 1
        elif ta < tb:
            ina = not ina
            t, own, sub = ta, sc[_lo(s0, A, i)], sc[_ls(s0, A, i)]
            i += 1
        else:
            inb = not inb
            t, own, sub = tb, sc[_lo(s0, B, j)], sc[_ls(s0, B, j)]
            j += 1
        new = _member(op, ina, inb)
        if new != res:
            if new and n >= cap - 1:
                # no room for another interval: drop the farthest, report it
                sc[s0 + SC_OVER] += 1
                break
            n = _emit(sf, sc, s0, T, n, t, own, sub)
            res = new
    sc[s0 + SC_TIES] += ties
    return n


@njit(**INLINE)
def _copy_list(sf, sc, s0, src, dst, n):
    for k in range(n):
        sf[_lt(s0, dst, k)] = sf[_lt(s0, src, k)]
        sc[_lo(s0, dst, k)] = sc[_lo(s0, src, k)]
        sc[_ls(s0, dst, k)] = sc[_ls(s0, src, k)]


@njit(**INLINE)
def evaluate_ray(buf, cb, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Interval list of the CSG tree at node `root` along the ray, restricted
    to what can matter inside [tmin, tmax]. Left in list 0 of the scratch;
    returns (boundary count, tol). Subtrees whose box the ray misses there are
    empty; a difference or intersection with an empty first operand skips the
    other one."""
    i64, _f32, i32, f64 = buf[:4]
    sf = sc.view(np.float64)
    h = cb >> 3
    c32 = cb >> 2
    n_op = c32 + i64[h + B_NODE_OP]
    n_l = c32 + i64[h + B_NODE_L]
    n_r = c32 + i64[h + B_NODE_R]
    n_rf = c32 + i64[h + B_NODE_RFIRST]
    n_box = h + i64[h + B_NODE_BOX]
    l_kind = c32 + i64[h + B_LEAF_KIND]
    t0, t1 = _box_clip(f64, n_box + 6 * root, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if not (t0 <= t1):
        return 0, 0.0
    # ties are judged relative to the ray's reach through the solid's box
    tol = TIE_REL * max(abs(t0), abs(t1), t1 - t0)
    tlo = t0 - tol
    thi = t1 + tol
    len_ = s0 + SC_LEN
    wk = s0 + SC_WORK
    sc[wk] = root * 4
    wp = 1
    nl = 0
    while wp > 0:
        wp -= 1
        e = sc[wk + wp]
        nd = e >> 2
        st = e & 3
        op = i32[n_op + nd]
        if st == 0:
            b0, b1 = _box_clip(f64, n_box + 6 * nd, ox, oy, oz, dx, dy, dz, tlo, thi)
            if not (b0 <= b1):
                sc[len_ + nl] = 0
                nl += 1
            elif op == LEAF:
                k = i32[n_l + nd]
                if i32[l_kind + k] == MESH:
                    sc[len_ + nl] = _mesh_leaf(buf, cb, sf, sc, s0, nl, k, ox, oy, oz,
                                               dx, dy, dz, tol)
                else:
                    sc[len_ + nl] = _prim_leaf(buf, cb, sf, sc, s0, nl, k, ox, oy, oz,
                                               dx, dy, dz, tlo, thi)
                nl += 1
            else:
                first = i32[n_r + nd] if i32[n_rf + nd] else i32[n_l + nd]
                sc[wk + wp] = nd * 4 + 1
                sc[wk + wp + 1] = first * 4
                wp += 2
        elif st == 1:
            rf = i32[n_rf + nd]
            if sc[len_ + nl - 1] == 0 and (op == INTER or (op == DIFF and rf == 0)):
                continue                      # the result is that empty list
            second = i32[n_l + nd] if rf else i32[n_r + nd]
            sc[wk + wp] = nd * 4 + 2
            sc[wk + wp + 1] = second * 4
            wp += 2
        else:
            if i32[n_rf + nd]:
                A, B = nl - 1, nl - 2
            else:
                A, B = nl - 2, nl - 1
            n = _combine(sf, sc, s0, op, A, sc[len_ + A], B, sc[len_ + B], MAX_LISTS, tol)
            _copy_list(sf, sc, s0, MAX_LISTS, nl - 2, n)
            sc[len_ + nl - 2] = n
            nl -= 1
    return sc[len_], tol


@njit(**INLINE)
def leaf_surface(buf, cb, leaf, sub, ox, oy, oz, dx, dy, dz, t, entering):
    """(face, u, v, nx, ny, nz) of a boundary point of the solid owned by
    `leaf` (mesh leaves: triangle `sub`, face = sub, (u, v) barycentrics).
    Prototype-space unit normal, outward of the solid."""
    i64, _f32, i32, f64 = buf[:4]
    h = cb >> 3
    c32 = cb >> 2
    kind = i32[c32 + i64[h + B_LEAF_KIND] + leaf]
    flip = i32[c32 + i64[h + B_LEAF_FLIP] + leaf]
    if kind == MESH:
        q = h + i64[h + B_MTRI] + 9 * sub
        hit, tt, u, v = intersect_triangle(f64[q], f64[q + 1], f64[q + 2], f64[q + 3],
                                           f64[q + 4], f64[q + 5], f64[q + 6], f64[q + 7],
                                           f64[q + 8], ox, oy, oz, dx, dy, dz,
                                           -math.inf, math.inf)
        nx, ny, nz = triangle_normal(f64[q], f64[q + 1], f64[q + 2], f64[q + 3], f64[q + 4],
                                     f64[q + 5], f64[q + 6], f64[q + 7], f64[q + 8])
        face = sub
    else:
        m = h + i64[h + B_LEAF_INV] + 12 * leaf
        lox, loy, loz, ldx, ldy, ldz = xform_ray(f64, m, ox, oy, oz, dx, dy, dz)
        pp = h + i64[h + B_LEAF_PARAMS] + 4 * leaf
        face, u, v, lx, ly, lz = prim_surface(kind, (f64[pp], f64[pp + 1], f64[pp + 2],
                                                     f64[pp + 3]),
                                              lox + t * ldx, loy + t * ldy, loz + t * ldz)
        nx, ny, nz = normal_through(f64, m, lx, ly, lz)
    if flip:
        nx, ny, nz = -nx, -ny, -nz
    nx, ny, nz = unit(nx, ny, nz)
    return face, u, v, nx, ny, nz


@njit(**INLINE)
def csg_first_boundary(buf, cb, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Nearest boundary of the solid in (tmin, tmax): (t, leaf, sub, entering);
    leaf -1 if none. The cheap part of a hit: no surface chart."""
    n, tol = evaluate_ray(buf, cb, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax)
    sf = sc.view(np.float64)
    for k in range(n):
        t = sf[_lt(s0, 0, k)]
        if t > tmin:
            if t < tmax:
                return t, sc[_lo(s0, 0, k)], sc[_ls(s0, 0, k)], (k & 1) == 0
            break
    return math.inf, -1, -1, False


@njit(**INLINE)
def csg_vshape(buf, cb, leaf, sub):
    """Virtual shape id of a hit owned by (leaf, sub)."""
    i64, _f32, i32, _f64 = buf[:4]
    h = cb >> 3
    c32 = cb >> 2
    v = i32[c32 + i64[h + B_LEAF_VSHAPE] + leaf]
    if i32[c32 + i64[h + B_LEAF_KIND] + leaf] == MESH:
        v += sub - i32[c32 + i64[h + B_LEAF_TRI0] + leaf]
    return v


@njit(**INLINE)
def csg_vshape_leaf(buf, cb, vshape):
    """(leaf, sub) of a virtual shape id (inverse of csg_vshape)."""
    i64, _f32, i32, _f64 = buf[:4]
    h = cb >> 3
    c32 = cb >> 2
    j = vshape - i64[h + B_VS0]
    leaf = i32[c32 + i64[h + B_VSHAPE_LEAF] + j]
    sub = -1
    if i32[c32 + i64[h + B_LEAF_KIND] + leaf] == MESH:
        sub = i32[c32 + i64[h + B_LEAF_TRI0] + leaf] + j - (
            i32[c32 + i64[h + B_LEAF_VSHAPE] + leaf] - i64[h + B_VS0])
    return leaf, sub


@njit(**CORE)
def csg_first_hit_core(buf, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """csg_first_hit on a trace buffer with caller scratch sc[s0 : s0+CSG_SCRATCH_WORDS]."""
    cb = csg_base(buf)
    t, leaf, sub, entering = csg_first_boundary(buf, cb, sc, s0, root, ox, oy, oz, dx, dy, dz,
                                                tmin, tmax)
    if leaf < 0:
        return False, math.inf, -1, -1, 0.0, 0.0, 0.0, 0.0, 0.0, False
    face, u, v, nx, ny, nz = leaf_surface(buf, cb, leaf, sub, ox, oy, oz, dx, dy, dz, t, entering)
    return True, t, leaf, face, u, v, nx, ny, nz, entering


@njit(**INLINE)
def csg_vs0(buf):
    """First virtual shape id: shape ids from here on are CSG leaf hits."""
    i64 = buf[0]
    return i64[(csg_base(buf) >> 3) + B_VS0]


@njit(**CORE)
def csg_closest_core(buf, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """For the traversal: nearest boundary of solid `root` in (tmin, tmax) as
    (t, virtual shape id); (inf, -1) if none. A real call, so the BVH loops
    that reach it stay small."""
    cb = csg_base(buf)
    t, leaf, sub, entering = csg_first_boundary(buf, cb, sc, s0, root, ox, oy, oz, dx, dy, dz,
                                                tmin, tmax)
    if leaf < 0:
        return math.inf, -1
    return t, csg_vshape(buf, cb, leaf, sub)


@njit(**CORE)
def csg_surface_core(buf, vshape, ox, oy, oz, dx, dy, dz, t):
    """(face, u, v, nx, ny, nz) of a hit on virtual shape `vshape` at t of a
    prototype-space ray: the owning primitive's chart, or (0, b1, b2) of a
    mesh triangle, and the solid's outward normal (prototype space)."""
    cb = csg_base(buf)
    leaf, sub = csg_vshape_leaf(buf, cb, vshape)
    face, u, v, nx, ny, nz = leaf_surface(buf, cb, leaf, sub, ox, oy, oz, dx, dy, dz, t, True)
    if sub >= 0:
        face = 0
    return face, u, v, nx, ny, nz


@njit(cache=True, error_model="numpy")
def csg_first_hit(g, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """First boundary of CSG solid `root` (node id) in (tmin, tmax) along a
    prototype-space ray: (hit, t, leaf, face, u, v, nx, ny, nz, entering).

    `g`: anything with the trace views holding a CSG blob (Geometry, CSGTable.g).
    leaf: the leaf owning the boundary (its primitive/mesh gives material and
    lightmap); face/u/v: that primitive's chart, or for a mesh leaf the
    triangle index (CSG triangle array) and its barycentrics; n: unit outward
    normal of the solid (a subtracted operand's normal flipped); entering:
    the ray enters the solid there. Allocates its scratch (tests and tools;
    the traversal passes its own)."""
    sc = np.empty(CSG_SCRATCH_WORDS + 2, np.int32)
    sc[:4] = 0
    return csg_first_hit_core((g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features), sc, 0, root,
                              ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(cache=True, error_model="numpy")
def _all_intervals(buf, root, ox, oy, oz, dx, dy, dz, tmin, tmax, t_out, leaf_out):
    sc = np.zeros(CSG_SCRATCH_WORDS + 2, np.int32)
    cb = csg_base(buf)
    n, tol = evaluate_ray(buf, cb, sc, 0, root, ox, oy, oz, dx, dy, dz, tmin, tmax)
    sf = sc.view(np.float64)
    for k in range(n):
        t_out[k] = sf[_lt(0, 0, k)]
        leaf_out[k] = sc[_lo(0, 0, k)]
    return n, sc[SC_TIES], sc[SC_OVER]


def csg_all_intervals(table, root, o, d, tmin=-math.inf, tmax=math.inf):
    """All intervals of solid `root` along the ray (for tests): dict with
    'intervals' (K, 2), 'leaves' (K, 2) owning leaf of each boundary, 'ties'
    (coincident boundary events) and 'overflow' (truncated lists)."""
    t = np.empty(2 * MAX_INTERVALS)
    lf = np.empty(2 * MAX_INTERVALS, np.int32)
    n, ties, over = _all_intervals(table.trace, int(root), *map(float, o), *map(float, d),
                                   float(tmin), float(tmax), t, lf)
    return {"intervals": t[:n].reshape(-1, 2).copy(), "leaves": lf[:n].reshape(-1, 2).copy(),
            "ties": int(ties), "overflow": int(over)}


# --------------------------------------------------------------------------------------
# Brute-force point membership (tests, texel splitting)
# --------------------------------------------------------------------------------------

@njit(**INLINE)
def _mesh_winding(buf, cb, k, px, py, pz):
    """Signed crossings of a fixed skew ray from p with leaf k's triangles (brute force)."""
    i64, _f32, i32, f64 = buf[:4]
    h = cb >> 3
    c32 = cb >> 2
    t0 = i32[c32 + i64[h + B_LEAF_TRI0] + k]
    nt = _leaf_ntri(buf, cb, k)
    sgn = 1 if f64[h + i64[h + B_LEAF_PARAMS] + 4 * k] >= 0.0 else -1
    # a skew direction, so the ray is unlikely to run through edges
    dx, dy, dz = 0.5773502691896258, 0.5883484054145521, 0.5661798502000004
    w = 0
    for j in range(t0, t0 + nt):
        q = h + i64[h + B_MTRI] + 9 * j
        hit, t, b1, b2 = intersect_triangle(f64[q], f64[q + 1], f64[q + 2], f64[q + 3],
                                            f64[q + 4], f64[q + 5], f64[q + 6], f64[q + 7],
                                            f64[q + 8], px, py, pz, dx, dy, dz, 0.0, math.inf)
        if hit:
            nx, ny, nz = triangle_normal(f64[q], f64[q + 1], f64[q + 2], f64[q + 3],
                                         f64[q + 4], f64[q + 5], f64[q + 6], f64[q + 7],
                                         f64[q + 8])
            dn = nx * dx + ny * dy + nz * dz
            if dn > 0.0:
                w += 1
            elif dn < 0.0:
                w -= 1
    return w * sgn > 0


@njit(**INLINE)
def _leaf_ntri(buf, cb, k):
    """Triangles of mesh leaf k: its virtual shapes are one per triangle."""
    i64, _f32, i32, _f64 = buf[:4]
    h = cb >> 3
    c32 = cb >> 2
    v0 = i32[c32 + i64[h + B_LEAF_VSHAPE] + k]
    if k + 1 < i64[h + B_NLEAF]:
        return i32[c32 + i64[h + B_LEAF_VSHAPE] + k + 1] - v0
    return i64[h + B_VS0] + i64[h + B_NVSHAPE] - v0


@njit(cache=True, error_model="numpy")
def point_inside(buf, cb, root, px, py, pz, bits, force_leaf=-1, force_val=False):
    """Membership of p in solid `root` (strict for primitives: boundary is outside).
    `bits` is an int32 work array of at least 3*MAX_WORK + 8 entries. Leaf
    `force_leaf` (if >= 0) is taken as `force_val` instead of tested."""
    i64, _f32, i32, f64 = buf[:4]
    h = cb >> 3
    c32 = cb >> 2
    n_op = c32 + i64[h + B_NODE_OP]
    n_l = c32 + i64[h + B_NODE_L]
    n_r = c32 + i64[h + B_NODE_R]
    # explicit post-order walk with a value stack
    work = bits[:2 * MAX_WORK + 8]
    vals = bits[2 * MAX_WORK + 8:]
    work[0] = root * 4
    wp = 1
    nv = 0
    while wp > 0:
        wp -= 1
        e = work[wp]
        nd = e >> 2
        st = e & 3
        op = i32[n_op + nd]
        if st == 0 and op == LEAF:
            k = i32[n_l + nd]
            kind = i32[c32 + i64[h + B_LEAF_KIND] + k]
            if k == force_leaf:
                r = force_val
            elif kind == MESH:
                r = _mesh_winding(buf, cb, k, px, py, pz)
            else:
                m = h + i64[h + B_LEAF_INV] + 12 * k
                lx, ly, lz, a, b, c = xform_ray(f64, m, px, py, pz, 0.0, 0.0, 0.0)
                pp = h + i64[h + B_LEAF_PARAMS] + 4 * k
                r = prim_inside(kind, (f64[pp], f64[pp + 1], f64[pp + 2], f64[pp + 3]),
                                lx, ly, lz)
            vals[nv] = 1 if r else 0
            nv += 1
        elif st == 0:
            work[wp] = nd * 4 + 1
            work[wp + 1] = i32[n_r + nd] * 4
            work[wp + 2] = i32[n_l + nd] * 4
            wp += 3
        else:
            b = vals[nv - 1] != 0
            a = vals[nv - 2] != 0
            nv -= 1
            vals[nv - 1] = 1 if _member(op, a, b) else 0
    return vals[0] != 0


@njit(cache=True, error_model="numpy")
def csg_inside_batch(buf, root, pts, out):
    bits = np.empty(3 * MAX_WORK + 8, np.int32)
    cb = csg_base(buf)
    for i in range(pts.shape[0]):
        out[i] = point_inside(buf, cb, root, pts[i, 0], pts[i, 1], pts[i, 2], bits)
