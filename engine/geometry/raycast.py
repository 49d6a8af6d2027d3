"""Two-level ray traversal over a compiled `Geometry`: closest hit and occlusion.

The world ray walks the TLAS; at an instance it is mapped into prototype
space with the instance's inverse transform (direction not normalised, so
t is shared by both spaces) and walks that prototype's BLAS; a primitive
maps it once more into its local space.

Both levels run on the 4-wide records of engine/geometry/bvh.py `pack_bvh`. A step
tests the four child boxes of a record as one vector, intersects hit leaf
children at once, descends into the nearest hit interior child and pushes
the others with their entry distances; popped entries beyond the closest
hit so far are skipped. Triangles sit in 4-lane packets and are tested four
at a time. The packer bounds the pushes per level, so two levels fit a
128-word int32 stack (`STACK_WORDS`, `new_stack()`), which the caller
allocates once per thread and reuses for every ray.

Robustness: boxes are float32 rounded outward and the slab test widens its
exit distance by a few ulps (Ize 2013); triangles use the watertight test
(engine/geometry/triangle.py), so rays through shared edges and vertices of closed
meshes always hit.

Calling convention: the kernels read only the trace buffer
(engine/geometry/trace_layout.py), as the tuple `buf` of its four typed views (g.trace_i64,
g.trace_f32, g.trace_i32, g.trace_f64) and its features marker (see the gates
below and engine/core/features.py), so a call passes a few dozen machine
words instead of the ~300 of the Geometry namedtuple, which measurably cost
~100 ns per call. The public entry points (`intersect_closest`, `occluded`,
`closest_hit`, `hit_surface`) are inlined wrappers that forward these views
to the compiled cores; the cores are compiled without the NRT (`_nrt=False`),
so no reference counts are touched per ray (atomic updates of counters
shared by all threads would also serialise them).
"""
import math

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic, overload

from . import trace_layout
from ..core.affine import normal_through, unit, xform_ray
from ..core.jit import CORE, INLINE, typed
from .trace_layout import STACK_WORDS, TRI_LEAF, new_stack  # noqa: F401  (re-exported)
from ..core import features
from .csg import CSG_SCRATCH_WORDS
from .csg_trace import csg_closest_core, csg_surface_core, csg_vs0
from .dcsg_blob import DCSG_REF
from .dcsg_trace import dcsg_closest_core, dcsg_hit_surface, dcsg_vs0
from .primitives import prim_hits, prim_surface
from .triangle import pick, triangle_normal, woop_setup, woop_test
from .wide_bvh import (  # noqa: F401
    V4D, ctz, descend, drop_far, load4, mask4, nearest_lane, pop_node, ray_slabs, slab4,
    splat)

_CHUNK = 256



# ------------------------------------------------------------- vector kernels

@intrinsic
def _woop4(typingctx, f64a, base, kx, ky, kz, sx, sy, sz, okx, oky, okz, tmin, tmax):
    """engine/geometry/triangle.py `woop_test` on the four lanes of the packet at
    element `base` of `f64a` (vertex v, axis k, lane q at base+12v+4k+q), as
    4-wide vector code with the same operations in the same order, so a lane
    gives the bit-identical t of the scalar test. Returns (mask, t0..t3):
    bit q set if lane q is hit in (tmin, tmax). NaN lanes never hit."""
    f64 = types.float64
    sig = types.Tuple((types.int64, f64, f64, f64, f64))(
        f64a, base, kx, ky, kz, sx, sy, sz, okx, oky, okz, tmin, tmax)

    def codegen(context, builder, signature, args):
        a_, base_, kx_, ky_, kz_, sx_, sy_, sz_, okx_, oky_, okz_, tmin_, tmax_ = args
        data = context.make_array(signature.args[0])(context, builder, a_).data
        i64 = ir.IntType(64)

        def row(vtx, axis, o):
            off = builder.add(base_, builder.add(ir.Constant(i64, 12 * vtx),
                                                 builder.shl(axis, ir.Constant(i64, 2))))
            return builder.fsub(load4(builder, data, off, V4D), splat(builder, o))

        def lt(a, c):
            return builder.fcmp_ordered("<", a, c)

        ax, ay, az = row(0, kx_, okx_), row(0, ky_, oky_), row(0, kz_, okz_)
        bx, by, bz = row(1, kx_, okx_), row(1, ky_, oky_), row(1, kz_, okz_)
        cx, cy, cz = row(2, kx_, okx_), row(2, ky_, oky_), row(2, kz_, okz_)
        vsx, vsy, vsz = (splat(builder, x) for x in (sx_, sy_, sz_))
        fsub, fmul = builder.fsub, builder.fmul
        px = fsub(ax, fmul(vsx, az))
        py = fsub(ay, fmul(vsy, az))
        qx = fsub(bx, fmul(vsx, bz))
        qy = fsub(by, fmul(vsy, bz))
        rx = fsub(cx, fmul(vsx, cz))
        ry = fsub(cy, fmul(vsy, cz))
        u = fsub(fmul(rx, qy), fmul(ry, qx))
        v = fsub(fmul(px, ry), fmul(py, rx))
        w = fsub(fmul(qx, py), fmul(qy, px))
        zero = ir.Constant(V4D, [0.0] * 4)
        neg = builder.or_(builder.or_(lt(u, zero), lt(v, zero)), lt(w, zero))
        pos = builder.or_(builder.or_(lt(zero, u), lt(zero, v)), lt(zero, w))
        inv = builder.fdiv(ir.Constant(V4D, [1.0] * 4), builder.fadd(builder.fadd(u, v), w))
        num = builder.fadd(builder.fadd(fmul(u, az), fmul(v, bz)), fmul(w, cz))
        t = fmul(fmul(num, vsz), inv)
        ok = builder.and_(builder.not_(builder.and_(neg, pos)),
                          builder.and_(lt(splat(builder, tmin_), t), lt(t, splat(builder, tmax_))))
        out = [mask4(builder, ok)] + [builder.extract_element(t, ir.Constant(ir.IntType(32), k))
                                       for k in range(4)]
        return context.make_tuple(builder, signature.return_type, out)

    return sig, codegen


# ------------------------------------------------------------- scalar helpers

@njit(**INLINE)
def _valid_ray(ox, oy, oz, dx, dy, dz):
    """Finite origin, finite non-zero direction. (A NaN ray would enter every
    box, since NaN slab distances read as "no limit".)"""
    s = ox + oy + oz + dx + dy + dz
    return (s - s == 0.0) and (dx != 0.0 or dy != 0.0 or dz != 0.0)


@njit(**INLINE)
def _lane_test(f64, base, q, kx, ky, kz, sx, sy, sz, okx, oky, okz, tmin, tmax):
    """Scalar watertight test of lane q of the packet at f64[base:]."""
    return woop_test(f64[base + 4 * kx + q] - okx, f64[base + 4 * ky + q] - oky,
                     f64[base + 4 * kz + q] - okz,
                     f64[base + 12 + 4 * kx + q] - okx, f64[base + 12 + 4 * ky + q] - oky,
                     f64[base + 12 + 4 * kz + q] - okz,
                     f64[base + 24 + 4 * kx + q] - okx, f64[base + 24 + 4 * ky + q] - oky,
                     f64[base + 24 + 4 * kz + q] - okz,
                     sx, sy, sz, tmin, tmax)


@njit(**INLINE)
def _layout(buf):
    """The trace views (see geometry.trace_views) and the element offsets of
    the records, int32 and float64 sections."""
    i64, f32, i32, f64 = buf[:4]
    return (i64, f32, i32, f64, i64[trace_layout.H_REC] >> 2, i64[trace_layout.H_I32] >> 2, i64[trace_layout.H_F64] >> 3)


@njit(**INLINE)
def _prim_first(i32, f64, ib, fb, i64, j, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Nearest crossing of primitive row j in (tmin, tmax), prototype-space ray; inf if none."""
    m = fb + i64[trace_layout.H_PRIM_INV] + 12 * j
    lox, loy, loz, ldx, ldy, ldz = xform_ray(f64, m, ox, oy, oz, dx, dy, dz)
    pp = fb + i64[trace_layout.H_PRIM_PARAMS] + 4 * j
    n, t0, t1, t2, t3 = prim_hits(i32[ib + i64[trace_layout.H_PRIM_KIND] + j],
                                  (f64[pp], f64[pp + 1], f64[pp + 2], f64[pp + 3]),
                                  lox, loy, loz, ldx, ldy, ldz)
    if n > 0 and t0 > tmin and t0 < tmax:
        return t0
    if n > 1 and t1 > tmin and t1 < tmax:
        return t1
    if n > 2 and t2 > tmin and t2 < tmax:
        return t2
    if n > 3 and t3 > tmin and t3 < tmax:
        return t3
    return math.inf


# ---------------------------------------------------------------------- gates
# The CSG and L-system cores through gates: for a scene without such solids
# (its features marker says so, engine/core/features.py) a gate compiles to a miss,
# and the core is never compiled.

def _csg_closest(buf, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """csg_trace.csg_closest_core, or a miss for a scene without CSG solids."""


def _csg_surface(buf, vshape, ox, oy, oz, dx, dy, dz, t):
    """csg_trace.csg_surface_core (a scene without CSG solids never calls it)."""


def _is_csg_shape(buf, shape):
    """True if `shape` is a CSG leaf's virtual shape."""


def _dcsg_closest(buf, stack, s0, graph, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit):
    """dcsg_trace.dcsg_closest_core, or a miss for a scene without L-systems."""


def _dcsg_surface(buf, stack, s0):
    """dcsg_trace.dcsg_hit_surface (a scene without L-systems never calls it)."""


def _is_dcsg_shape(buf, shape):
    """True if `shape` is an L-system terminal's virtual shape."""


@overload(_csg_closest, jit_options=dict(error_model="numpy"))
def _csg_closest_gate(buf, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax):
    if features.has(buf.types[4], features.CSG):
        return lambda buf, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax: csg_closest_core(
            buf, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax)
    return lambda buf, sc, s0, root, ox, oy, oz, dx, dy, dz, tmin, tmax: (math.inf, np.int64(-1))


@overload(_csg_surface, jit_options=dict(error_model="numpy"))
def _csg_surface_gate(buf, vshape, ox, oy, oz, dx, dy, dz, t):
    if features.has(buf.types[4], features.CSG):
        return lambda buf, vshape, ox, oy, oz, dx, dy, dz, t: csg_surface_core(
            buf, vshape, ox, oy, oz, dx, dy, dz, t)
    return lambda buf, vshape, ox, oy, oz, dx, dy, dz, t: (np.int64(0), 0.0, 0.0, 0.0, 0.0, 1.0)


@overload(_is_csg_shape)
def _is_csg_shape_gate(buf, shape):
    if features.has(buf.types[4], features.CSG):
        return lambda buf, shape: shape >= csg_vs0(buf)
    return lambda buf, shape: False


@overload(_dcsg_closest, jit_options=dict(error_model="numpy"))
def _dcsg_closest_gate(buf, stack, s0, graph, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit):
    if features.has(buf.types[4], features.DCSG):
        return lambda buf, stack, s0, graph, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit: dcsg_closest_core(
            buf, stack, s0, graph, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit)
    return lambda buf, stack, s0, graph, ox, oy, oz, dx, dy, dz, tmin, tmax, any_hit: (math.inf, np.int64(-1))


@overload(_dcsg_surface)
def _dcsg_surface_gate(buf, stack, s0):
    if features.has(buf.types[4], features.DCSG):
        return lambda buf, stack, s0: dcsg_hit_surface(stack, s0)
    return lambda buf, stack, s0: (np.int64(-1), 0.0, 0.0, 1.0, np.int64(0))


@overload(_is_dcsg_shape)
def _is_dcsg_shape_gate(buf, shape):
    if features.has(buf.types[4], features.DCSG):
        return lambda buf, shape: shape >= dcsg_vs0(buf)
    return lambda buf, shape: False


# ------------------------------------------------------------------ traversal

@njit(**INLINE)
def _woop(ox, oy, oz, dx, dy, dz):
    """Per-ray (and per-space) constants of the triangle test."""
    kx, ky, kz, sx, sy, sz = woop_setup(dx, dy, dz)
    return (kx, ky, kz, sx, sy, sz,
            pick(kx, ox, oy, oz), pick(ky, ox, oy, oz), pick(kz, ox, oy, oz))


@njit(**INLINE)
def _blas_start(buf, p, dx, dy, dz):
    """What a traversal of prototype p needs: the buffer views, the triangle and
    shape-reference bases, its root record and the ray's slab setup."""
    i64, f32, i32, f64, rb, ib, fb = _layout(buf)
    ix, iy, iz, nxo, nyo, nzo = ray_slabs(dx, dy, dz)
    return (i64, f32, i32, f64, rb, ib, fb, fb + i64[trace_layout.H_TRI4], ib + i64[trace_layout.H_SHAPE_REF],
            i32[ib + i64[trace_layout.H_PROTO_SLOT] + p], ix, iy, iz, nxo, nyo, nzo)


@njit(**INLINE)
def _blas_closest(buf, stack, fstack, sp0, p, ox, oy, oz, dx, dy, dz, tmin, tbest,
                  code, b1, b2):
    """Closest hit in prototype p for a prototype-space ray, improving on
    (tbest, code, b1, b2); code is 4*packet+lane for triangles and -1-shape
    for other shapes (-1: none). Uses the stack above sp0."""
    (i64, f32, i32, f64, rb, ib, fb, tri4, sref, node,
     ix, iy, iz, nxo, nyo, nzo) = _blas_start(buf, p, dx, dy, dz)
    # the triangle test's setup waits for the first leaf: many rays never get there
    kx, ky, kz, sx, sy, sz, okx, oky, okz = 0, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    woop = False
    sp = sp0
    t_start = tbest
    while True:
        b = rb + node * 32
        m, lm, n0, n1, n2, n3 = slab4(f32, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo,
                                       tmin, tbest)
        ml = m & lm
        mi = m & ~lm
        if ml != 0:
            if not woop:
                kx, ky, kz, sx, sy, sz, okx, oky, okz = _woop(ox, oy, oz, dx, dy, dz)
                woop = True
            t_in = tbest
            while ml != 0:
                k = ctz(ml)
                ml &= ml - 1
                a = i32[b + 24 + k]
                c = i32[b + 28 + k]
                if c >= TRI_LEAF:
                    for pk in range(a, a + c - TRI_LEAF):
                        base = tri4 + 36 * pk
                        hm, t0, t1, t2, t3 = _woop4(f64, base, kx, ky, kz, sx, sy, sz,
                                                    okx, oky, okz, tmin, tbest)
                        if hm != 0:
                            q, tbest = nearest_lane(hm, t0, t1, t2, t3)
                            code = 4 * pk + q     # barycentrics once, on the way out
                else:
                    # a leaf mixing primitives and triangles: shapes a .. a+c-1
                    for s in range(a, a + c):
                        r = i32[sref + s]
                        if r >= 0:
                            base = tri4 + 36 * (r >> 2)
                            h, t, u, v = _lane_test(f64, base, r & 3, kx, ky, kz, sx, sy, sz,
                                                    okx, oky, okz, tmin, tbest)
                            if h:
                                tbest = t
                                code = r
                        elif r <= DCSG_REF:
                            # an L-system: the hit is reported on its terminal's virtual shape
                            t, vs = _dcsg_closest(buf, stack, trace_layout.TRAV_WORDS + CSG_SCRATCH_WORDS,
                                                      DCSG_REF - r, ox, oy, oz, dx, dy, dz, tmin,
                                                      tbest, typed(False))
                            if t < tbest:
                                tbest = t
                                code = -1 - vs
                        elif r <= trace_layout.CSG_REF:
                            # a CSG solid: the hit is reported on the owning
                            # leaf's virtual shape
                            t, vs = _csg_closest(buf, stack, trace_layout.TRAV_WORDS, trace_layout.CSG_REF - r,
                                                     ox, oy, oz, dx, dy, dz, tmin, tbest)
                            if t < tbest:
                                tbest = t
                                code = -1 - vs
                        else:
                            t = _prim_first(i32, f64, ib, fb, i64, -1 - r, ox, oy, oz,
                                            dx, dy, dz, tmin, tbest)
                            if t < tbest:
                                tbest = t
                                code = -1 - s
            if tbest < t_in:
                mi = drop_far(mi, n0, n1, n2, n3, tbest)
        node, sp = descend(stack, fstack, sp, i32, b, mi, n0, n1, n2, n3, tbest)
        if node < 0:
            node, sp = pop_node(stack, fstack, sp, sp0, tbest)
            if node < 0:
                break
    if tbest < t_start:
        # hit in this prototype: barycentrics from the scalar test of that
        # lane (the same arithmetic as the packet test, so the same t)
        if code >= 0:
            h, t, b1, b2 = _lane_test(f64, tri4 + 36 * (code >> 2), code & 3, kx, ky, kz,
                                      sx, sy, sz, okx, oky, okz, tmin, math.inf)
        else:
            b1 = 0.0
            b2 = 0.0
    return tbest, code, b1, b2


@njit(**CORE)
def _instance_closest(buf, stack, sp, i, ox, oy, oz, dx, dy, dz, tmin, tbest,
                      inst, code, b1, b2):
    """Instance i against the world ray. A real call (not inlined): it keeps
    one copy of the BLAS traversal in the binary for a few dozen words of
    arguments per instance visited."""
    i64, f32, i32, f64, rb, ib, fb = _layout(buf)
    p = i32[ib + i64[trace_layout.H_INST_PROTO] + i]
    if i32[ib + i64[trace_layout.H_INST_IDENT] + i] == 0:
        ox, oy, oz, dx, dy, dz = xform_ray(f64, fb + i64[trace_layout.H_INST_INV] + 12 * i,
                                        ox, oy, oz, dx, dy, dz)
    t0 = tbest
    tbest, code, b1, b2 = _blas_closest(buf, stack, stack.view(np.float32), sp, p,
                                        ox, oy, oz, dx, dy, dz, tmin, tbest, code, b1, b2)
    if tbest < t0:                       # hits only ever shorten tbest
        inst = i
    return tbest, inst, code, b1, b2


@njit(**CORE)
def _instance_any(buf, stack, sp, i, ox, oy, oz, dx, dy, dz, tmin, tmax):
    i64, f32, i32, f64, rb, ib, fb = _layout(buf)
    p = i32[ib + i64[trace_layout.H_INST_PROTO] + i]
    if i32[ib + i64[trace_layout.H_INST_IDENT] + i] == 0:
        ox, oy, oz, dx, dy, dz = xform_ray(f64, fb + i64[trace_layout.H_INST_INV] + 12 * i,
                                        ox, oy, oz, dx, dy, dz)
    return _blas_any(buf, stack, sp, p, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(**INLINE)
def _resolve(i64, i32, ib, tbest, inst, code, b1, b2):
    """Final (t, inst, shape, b1, b2) from a traversal's packet/shape code."""
    if inst < 0:
        return tbest, -1, -1, 0.0, 0.0
    if code >= 0:
        shape = i32[ib + i64[trace_layout.H_LANE_SHAPE] + code]
    else:
        shape = -1 - code
    return tbest, inst, shape, b1, b2


@njit(**CORE)
def closest_core(buf, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit in (tmin, tmax) on a trace buffer: (t, inst, shape, b1, b2);
    inst = shape = -1 on a miss. b1, b2: triangle barycentrics (0 otherwise)."""
    if not _valid_ray(ox, oy, oz, dx, dy, dz):
        return tmax, -1, -1, 0.0, 0.0
    i64, f32, i32, f64, rb, ib, fb = _layout(buf)
    fstack = stack.view(np.float32)
    items = ib + i64[trace_layout.H_TLAS_ITEMS]
    tbest = tmax
    inst = typed(-1)        # not literals: one signature per core (jit.typed)
    code = typed(-1)
    b1 = 0.0
    b2 = 0.0
    single = i64[trace_layout.H_SINGLE]
    if single >= 0:
        tbest, inst, code, b1, b2 = _instance_closest(buf, stack, typed(0), single, ox, oy, oz,
                                                      dx, dy, dz, tmin, tbest, inst, code,
                                                      b1, b2)
        return _resolve(i64, i32, ib, tbest, inst, code, b1, b2)
    node = 0
    ix, iy, iz, nxo, nyo, nzo = ray_slabs(dx, dy, dz)
    sp = typed(0)        # int64 at once: inference compiles a core per type it meets
    while True:
        b = rb + node * 32
        m, lm, n0, n1, n2, n3 = slab4(f32, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo,
                                       tmin, tbest)
        ml = m & lm
        mi = m & ~lm
        if ml != 0:
            t_in = tbest
            while ml != 0:
                k = ctz(ml)
                ml &= ml - 1
                a = i32[b + 24 + k]
                for q in range(a, a + i32[b + 28 + k]):
                    tbest, inst, code, b1, b2 = _instance_closest(
                        buf, stack, sp, np.int64(i32[items + q]), ox, oy, oz, dx, dy, dz,
                        tmin, tbest, inst, code, b1, b2)
            if tbest < t_in:
                mi = drop_far(mi, n0, n1, n2, n3, tbest)
        node, sp = descend(stack, fstack, sp, i32, b, mi, n0, n1, n2, n3, tbest)
        if node < 0:
            node, sp = pop_node(stack, fstack, sp, 0, tbest)
            if node < 0:
                break
    return _resolve(i64, i32, ib, tbest, inst, code, b1, b2)


@njit(**INLINE)
def _any_next(stack, sp, sp0, rec_i, b, mi):
    """Occlusion needs no order: descend into the first hit interior child,
    push the rest; pop when there is none. Returns (node, sp), -1: done."""
    if mi == 0:
        if sp > sp0:
            return stack[sp - 2], sp - 2
        return -1, sp
    k = ctz(mi)
    mi &= mi - 1
    node = rec_i[b + 24 + k]
    while mi != 0:
        k = ctz(mi)
        mi &= mi - 1
        stack[sp] = rec_i[b + 24 + k]
        sp += 2
    return node, sp


@njit(**INLINE)
def _blas_any(buf, stack, sp0, p, ox, oy, oz, dx, dy, dz, tmin, tmax):
    (i64, f32, i32, f64, rb, ib, fb, tri4, sref, node,
     ix, iy, iz, nxo, nyo, nzo) = _blas_start(buf, p, dx, dy, dz)
    kx, ky, kz, sx, sy, sz, okx, oky, okz = 0, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    woop = False
    sp = sp0
    while True:
        b = rb + node * 32
        m, lm, n0, n1, n2, n3 = slab4(f32, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo,
                                       tmin, tmax)
        ml = m & lm
        if ml != 0 and not woop:
            kx, ky, kz, sx, sy, sz, okx, oky, okz = _woop(ox, oy, oz, dx, dy, dz)
            woop = True
        while ml != 0:
            k = ctz(ml)
            ml &= ml - 1
            a = i32[b + 24 + k]
            c = i32[b + 28 + k]
            if c >= TRI_LEAF:
                for pk in range(a, a + c - TRI_LEAF):
                    hm, t0, t1, t2, t3 = _woop4(f64, tri4 + 36 * pk, kx, ky, kz, sx, sy, sz,
                                                okx, oky, okz, tmin, tmax)
                    if hm != 0:
                        return True
            else:
                for s in range(a, a + c):
                    r = i32[sref + s]
                    if r >= 0:
                        h, t, u, v = _lane_test(f64, tri4 + 36 * (r >> 2), r & 3, kx, ky, kz,
                                                sx, sy, sz, okx, oky, okz, tmin, tmax)
                        if h:
                            return True
                    elif r <= DCSG_REF:
                        if _dcsg_closest(buf, stack, trace_layout.TRAV_WORDS + CSG_SCRATCH_WORDS,
                                             DCSG_REF - r, ox, oy, oz, dx, dy, dz, tmin, tmax,
                                             typed(True))[0] < tmax:
                            return True
                    elif r <= trace_layout.CSG_REF:
                        if _csg_closest(buf, stack, trace_layout.TRAV_WORDS, trace_layout.CSG_REF - r, ox, oy, oz,
                                            dx, dy, dz, tmin, tmax)[0] < tmax:
                            return True
                    elif _prim_first(i32, f64, ib, fb, i64, -1 - r, ox, oy, oz,
                                     dx, dy, dz, tmin, tmax) < tmax:
                        return True
        node, sp = _any_next(stack, sp, sp0, i32, b, m & ~lm)
        if node < 0:
            return False


@njit(**CORE)
def occluded_core(buf, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """True if anything lies on the ray strictly between tmin and tmax."""
    if not _valid_ray(ox, oy, oz, dx, dy, dz):
        return False
    i64, f32, i32, f64, rb, ib, fb = _layout(buf)
    items = ib + i64[trace_layout.H_TLAS_ITEMS]
    single = i64[trace_layout.H_SINGLE]
    if single >= 0:
        return _instance_any(buf, stack, typed(0), single, ox, oy, oz, dx, dy, dz, tmin, tmax)
    ix, iy, iz, nxo, nyo, nzo = ray_slabs(dx, dy, dz)
    node = 0
    sp = typed(0)
    while True:
        b = rb + node * 32
        m, lm, n0, n1, n2, n3 = slab4(f32, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo,
                                       tmin, tmax)
        ml = m & lm
        while ml != 0:
            k = ctz(ml)
            ml &= ml - 1
            a = i32[b + 24 + k]
            for q in range(a, a + i32[b + 28 + k]):
                if _instance_any(buf, stack, sp, np.int64(i32[items + q]), ox, oy, oz, dx, dy, dz,
                                 tmin, tmax):
                    return True
        node, sp = _any_next(stack, sp, 0, i32, b, m & ~lm)
        if node < 0:
            return False


@njit(**CORE)
def surface_core(buf, t, inst, shape, b1, b2, ox, oy, oz, dx, dy, dz):
    """(face, u, v, nx, ny, nz) of a hit from `closest_core`, world unit normal."""
    i64, f32, i32, f64, rb, ib, fb = _layout(buf)
    m_inst = fb + i64[trace_layout.H_INST_INV] + 12 * inst
    is_csg = _is_csg_shape(buf, shape)
    r = 0 if is_csg else i32[ib + i64[trace_layout.H_SHAPE_REF] + shape]
    if is_csg:
        # CSG leaf hit: the owning primitive's chart, the solid's normal
        ux, uy, uz, vx, vy, vz = xform_ray(f64, m_inst, ox, oy, oz, dx, dy, dz)
        face, u, v, px, py, pz = _csg_surface(buf, shape, ux, uy, uz, vx, vy, vz, t)
    elif r >= 0:
        base = fb + i64[trace_layout.H_TRI4] + 36 * (r >> 2) + (r & 3)
        px, py, pz = triangle_normal(f64[base], f64[base + 4], f64[base + 8],
                                     f64[base + 12], f64[base + 16], f64[base + 20],
                                     f64[base + 24], f64[base + 28], f64[base + 32])
        face = 0
        u = b1
        v = b2
    else:
        j = -1 - r
        # the same local ray as in the traversal, so the point is the hit point
        ux, uy, uz, vx, vy, vz = xform_ray(f64, m_inst, ox, oy, oz, dx, dy, dz)
        m_prim = fb + i64[trace_layout.H_PRIM_INV] + 12 * j
        lox, loy, loz, ldx, ldy, ldz = xform_ray(f64, m_prim, ux, uy, uz, vx, vy, vz)
        pp = fb + i64[trace_layout.H_PRIM_PARAMS] + 4 * j
        face, u, v, lnx, lny, lnz = prim_surface(
            i32[ib + i64[trace_layout.H_PRIM_KIND] + j], (f64[pp], f64[pp + 1], f64[pp + 2], f64[pp + 3]),
            lox + t * ldx, loy + t * ldy, loz + t * ldz)
        px, py, pz = normal_through(f64, m_prim, lnx, lny, lnz)
    nx, ny, nz = normal_through(f64, m_inst, px, py, pz)
    nx, ny, nz = unit(nx, ny, nz)
    return face, u, v, nx, ny, nz


@njit(**CORE)
def intersect_core(buf, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    t, inst, shape, b1, b2 = closest_core(buf, stack, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if shape < 0:
        return False, math.inf, -1, -1, -1, 0.0, 0.0, 0.0, 0.0, 0.0
    if _is_dcsg_shape(buf, shape):
        # an L-system hit: the traversal left its normal and OL stub (face) in the stack
        face, px, py, pz, _address = _dcsg_surface(buf, stack, trace_layout.TRAV_WORDS + CSG_SCRATCH_WORDS)
        i64, f32, i32, f64, rb, ib, fb = _layout(buf)
        nx, ny, nz = normal_through(f64, fb + i64[trace_layout.H_INST_INV] + 12 * inst, px, py, pz)
        nx, ny, nz = unit(nx, ny, nz)
        return True, t, inst, shape, face, 0.0, 0.0, nx, ny, nz
    face, u, v, nx, ny, nz = surface_core(buf, t, inst, shape, b1, b2, ox, oy, oz, dx, dy, dz)
    return True, t, inst, shape, face, u, v, nx, ny, nz


# -------------------------------------------------------------- entry points
# Thin wrappers inlined into the caller: only the trace views cross the call.

@njit(**INLINE)
def _buf(g):
    return (g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features)


@njit(**INLINE)
def closest_hit(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit in (tmin, tmax): (t, inst, shape, b1, b2); inst = shape = -1 on a miss.

    b1, b2 are the triangle barycentrics (0 for primitives). `stack`: int32
    array of at least STACK_WORDS words, reused across calls of one thread.
    """
    return closest_core(_buf(g), stack, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(**INLINE)
def hit_surface(g, t, inst, shape, b1, b2, ox, oy, oz, dx, dy, dz):
    """Surface data of a hit from `closest_hit`: (face, u, v, nx, ny, nz), world unit normal."""
    return surface_core(_buf(g), t, inst, shape, b1, b2, ox, oy, oz, dx, dy, dz)


@njit(**INLINE)
def intersect_closest(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit in (tmin, tmax): (hit, t, inst, shape, face, u, v, nx, ny, nz).

    (nx, ny, nz) is the world-space unit normal: the geometric normal of a
    triangle (counter-clockwise front) or the outward normal of a primitive,
    both carried through the inverse-transpose of the transforms. face/u/v
    are (0, b1, b2) for triangles and the primitive's chart otherwise.
    On a miss: (False, inf, -1, -1, -1, 0, 0, 0, 0, 0).
    """
    return intersect_core(_buf(g), stack, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(**INLINE)
def occluded(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """True if anything lies on the ray strictly between tmin and tmax (any hit)."""
    return occluded_core(_buf(g), stack, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(cache=True, error_model="numpy", parallel=True, _nrt=False)
def _closest_batch(i64, f32, i32, f64, feat, origins, dirs, tmax, stacks, t_out, inst_out, shape_out):
    buf = (i64, f32, i32, f64, feat)
    n = origins.shape[0]
    n_chunks = (n + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        stack = stacks[c]
        for i in range(c * _CHUNK, min(n, (c + 1) * _CHUNK)):
            t, inst, shape, b1, b2 = closest_core(buf, stack, origins[i, 0], origins[i, 1],
                                                  origins[i, 2], dirs[i, 0], dirs[i, 1],
                                                  dirs[i, 2], 0.0, tmax)
            t_out[i] = t if shape >= 0 else math.inf
            inst_out[i] = inst
            shape_out[i] = shape


@njit(cache=True, error_model="numpy", parallel=True, _nrt=False)
def _occluded_batch(i64, f32, i32, f64, feat, origins, dirs, tmax, stacks, out):
    buf = (i64, f32, i32, f64, feat)
    n = origins.shape[0]
    n_chunks = (n + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        stack = stacks[c]
        for i in range(c * _CHUNK, min(n, (c + 1) * _CHUNK)):
            out[i] = occluded_core(buf, stack, origins[i, 0], origins[i, 1], origins[i, 2],
                                   dirs[i, 0], dirs[i, 1], dirs[i, 2], 0.0, tmax)


def _rays(origins, dirs):
    o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(dirs, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape:
        raise ValueError("origins and dirs must both have shape (N, 3)")
    return o, d


def trace_closest_batch(g, origins, dirs, tmax=math.inf):
    """Closest hits of N rays with t in (0, tmax): (t (N,) inf on a miss, inst (N,), shape (N,)).

    Runs in parallel on numba's threads (numba.set_num_threads)."""
    o, d = _rays(origins, dirs)
    n = o.shape[0]
    t = np.empty(n)
    inst = np.empty(n, np.int32)
    shape = np.empty(n, np.int32)
    # one stack per chunk of rays: nothing is allocated inside the kernel
    stacks = np.empty(((n + _CHUNK - 1) // _CHUNK, STACK_WORDS), np.int32)
    if n:
        _closest_batch(g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features, o, d, float(tmax),
                       stacks, t, inst, shape)
    return t, inst, shape


def occluded_batch(g, origins, dirs, tmax=math.inf):
    """Occlusion of N rays over t in (0, tmax): bool (N,)."""
    o, d = _rays(origins, dirs)
    n = o.shape[0]
    out = np.zeros(n, np.bool_)
    stacks = np.empty(((n + _CHUNK - 1) // _CHUNK, STACK_WORDS), np.int32)
    if n:
        _occluded_batch(g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features, o, d, float(tmax),
                        stacks, out)
    return out
