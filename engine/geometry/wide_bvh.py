"""The walk over 4-wide BVH records (engine/geometry/bvh.py `pack_bvh`): one vector slab
test of a record's four child boxes, then the ordered descent (nearest hit
interior child next, the others pushed with their entry distances, popped
entries beyond the closest hit skipped). The two-level traversal
(engine/geometry/raycast.py) and the expansion cache of the scene graphs
(engine/geometry/dcsg_trace.py) walk their records with it.

Robustness: boxes are float32 rounded outward and the slab test widens its
exit distance by a few ulps (Ize 2013). Records must start on a 16-byte
boundary (the vector loads are aligned).
"""
import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from ..core.jit import INLINE

# Slab exits are scaled by this to absorb the rounding of (b - o) * (1/d).
_ROBUST = 1.0 + 1e-15
# Stored entry distances are lowered by this relative amount so the float32
# copy never exceeds the true value (culling stays conservative).
_LOWER = 2.0 ** -22

_V4F = ir.VectorType(ir.FloatType(), 4)
V4D = ir.VectorType(ir.DoubleType(), 4)


def splat(builder, x):
    i32 = ir.IntType(32)
    v = builder.insert_element(ir.Constant(V4D, ir.Undefined), x, ir.Constant(i32, 0))
    return builder.shuffle_vector(v, v, ir.Constant(ir.VectorType(i32, 4), [0, 0, 0, 0]))


def load4(builder, data, index, vec):
    ptr = builder.gep(data, [index], inbounds=True)
    return builder.load(builder.bitcast(ptr, vec.as_pointer()), align=16)


def mask4(builder, cond):
    return builder.zext(builder.bitcast(cond, ir.IntType(4)), ir.IntType(64))


@intrinsic
def slab4(typingctx, rec, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo, tmin, tmax):
    """Slab test of the four child boxes of the record at word b of `rec`
    (float32), as one 4-wide vector computation.

    Returns (mask, leaves, near0..near3): bit k of mask is set if the ray
    enters child k within [tmin, tmax]; bit k of leaves if child k is a leaf
    (count word > 0), so the traversal can sort children without branching
    on each of them. nxo, nyo, nzo are the word offsets of the
    near planes (chosen by the direction signs); the far plane of an axis is
    the other offset of its pair (x: 0/4, y: 8/12, z: 16/20). The float32
    bounds widen exactly to float64 and the exit is scaled by _ROBUST.
    """
    f64 = types.float64
    sig = types.Tuple((types.int64, types.int64, f64, f64, f64, f64))(
        rec, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo, tmin, tmax)

    def codegen(context, builder, signature, args):
        rec_, b_, ox_, oy_, oz_, ix_, iy_, iz_, nxo_, nyo_, nzo_, tmin_, tmax_ = args
        data = context.make_array(signature.args[0])(context, builder, rec_).data
        i64 = ir.IntType(64)

        def plane(off, o, inv):
            v = builder.fpext(load4(builder, data, builder.add(b_, off), _V4F), V4D)
            return builder.fmul(builder.fsub(v, splat(builder, o)), splat(builder, inv))

        # max/min that keep the accumulator `a` when c is NaN (one vmaxpd /
        # vminpd). 0 * inf = NaN means the ray runs in that plane, which must
        # not limit the slab (inside, boundary included): accumulating from
        # tmin / +inf makes every NaN drop out.
        def vmax(a, c):
            return builder.select(builder.fcmp_ordered(">", c, a), c, a)

        def vmin(a, c):
            return builder.select(builder.fcmp_ordered("<", c, a), c, a)

        near = vmax(vmax(vmax(splat(builder, tmin_), plane(nxo_, ox_, ix_)),
                         plane(nyo_, oy_, iy_)), plane(nzo_, oz_, iz_))
        far = vmin(vmin(vmin(ir.Constant(V4D, [math.inf] * 4),
                             plane(builder.sub(ir.Constant(i64, 4), nxo_), ox_, ix_)),
                        plane(builder.sub(ir.Constant(i64, 20), nyo_), oy_, iy_)),
                   plane(builder.sub(ir.Constant(i64, 36), nzo_), oz_, iz_))
        far = builder.fmul(far, splat(builder, ir.Constant(ir.DoubleType(), _ROBUST)))
        far = vmin(far, splat(builder, tmax_))
        mask = mask4(builder, builder.fcmp_ordered("<=", near, far))
        v4i = ir.VectorType(ir.IntType(32), 4)
        counts = builder.bitcast(load4(builder, data, builder.add(b_, ir.Constant(i64, 28)), _V4F), v4i)
        leaves = mask4(builder, builder.icmp_signed(">", counts, ir.Constant(v4i, [0] * 4)))
        out = [mask, leaves] + [builder.extract_element(near, ir.Constant(ir.IntType(32), k))
                                for k in range(4)]
        return context.make_tuple(builder, signature.return_type, out)

    return sig, codegen


@njit(**INLINE)
def _inv(d):
    # d = +-0 gives +-inf; slab4 reads the 0 * inf of a ray lying in a
    # box plane as "no limit"
    return 1.0 / d


@njit(**INLINE)
def ray_slabs(dx, dy, dz):
    """Reciprocal direction and, per axis, the offset of the near slab plane in
    a 4-wide record (the far plane is the other one): one setup per ray."""
    ix = _inv(dx)
    iy = _inv(dy)
    iz = _inv(dz)
    return ix, iy, iz, (4 if ix < 0.0 else 0), (12 if iy < 0.0 else 8), (20 if iz < 0.0 else 16)


@intrinsic
def ctz(typingctx, x):
    """Index of the lowest set bit (x != 0)."""
    sig = types.int64(types.int64)

    def codegen(context, builder, signature, args):
        i64 = ir.IntType(64)
        fnty = ir.FunctionType(i64, [i64, ir.IntType(1)])
        fn = builder.module.declare_intrinsic("llvm.cttz", [i64], fnty)
        return builder.call(fn, [args[0], ir.Constant(ir.IntType(1), 1)])

    return sig, codegen


@njit(**INLINE)
def _pick4(k, a0, a1, a2, a3):
    # a select chain (no memory, no branches)
    return a0 if k == 0 else (a1 if k == 1 else (a2 if k == 2 else a3))


@njit(**INLINE)
def nearest_lane(m, t0, t1, t2, t3):
    """Lane and t of the smallest t among the set bits of m (m != 0)."""
    lane = -1
    t = math.inf
    if m & 1:
        lane = 0
        t = t0
    if m & 2 and (lane < 0 or t1 < t):
        lane = 1
        t = t1
    if m & 4 and (lane < 0 or t2 < t):
        lane = 2
        t = t2
    if m & 8 and (lane < 0 or t3 < t):
        lane = 3
        t = t3
    return lane, t


@njit(**INLINE)
def _push(stack, fstack, sp, node, near):
    stack[sp] = node
    fstack[sp + 1] = np.float32(near - abs(near) * _LOWER)
    return sp + 2


@njit(**INLINE)
def _sort_top(stack, fstack, lo, sp):
    """One bubble pass over the entries pushed by this step (at most three),
    leaving the nearest on top so it is popped first."""
    j = sp - 2
    while j > lo:
        if fstack[j + 1] > fstack[j - 1]:
            n = stack[j]
            f = fstack[j + 1]
            stack[j] = stack[j - 2]
            fstack[j + 1] = fstack[j - 1]
            stack[j - 2] = n
            fstack[j - 1] = f
        j -= 2


@njit(**INLINE)
def descend(stack, fstack, sp, rec_i, b, mi, n0, n1, n2, n3, tbest):
    """Next record among the hit interior children `mi` of the record at b:
    the nearest; the others are pushed, nearest on top. Returns (node, sp),
    node -1 if there is none (the caller pops)."""
    if mi == 0:
        return -1, sp
    k = ctz(mi)
    mi &= mi - 1
    node = rec_i[b + 24 + k]
    if mi == 0:                                   # the common case: one child
        return node, sp
    near = _pick4(k, n0, n1, n2, n3)
    lo = sp
    while mi != 0:
        k = ctz(mi)
        mi &= mi - 1
        other = rec_i[b + 24 + k]
        d = _pick4(k, n0, n1, n2, n3)
        if d < near:
            sp = _push(stack, fstack, sp, node, near)
            node = other
            near = d
        else:
            sp = _push(stack, fstack, sp, other, d)
    if sp - lo > 2:
        _sort_top(stack, fstack, lo, sp)
    return node, sp


@njit(**INLINE)
def pop_node(stack, fstack, sp, sp0, tbest):
    """Top entry not beyond tbest, or -1 when the stack (above sp0) runs out."""
    while sp > sp0:
        sp -= 2
        if fstack[sp + 1] <= tbest:
            return stack[sp], sp
    return -1, sp


@njit(**INLINE)
def drop_far(mi, n0, n1, n2, n3, tbest):
    """Clears children of mask mi whose entry lies beyond tbest."""
    if n0 > tbest:
        mi &= 14
    if n1 > tbest:
        mi &= 13
    if n2 > tbest:
        mi &= 11
    if n3 > tbest:
        mi &= 7
    return mi
