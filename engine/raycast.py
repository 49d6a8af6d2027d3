"""Two-level ray traversal over a compiled `Geometry`: closest hit and occlusion.

The world ray walks the TLAS; at an instance it is mapped into prototype
space with the instance's inverse transform (direction not normalised, so
t is shared by both spaces) and walks that prototype's BLAS; a primitive
maps it once more into its local space.

Both levels run on the 4-wide records of engine/bvh.py `pack_bvh`. A step
tests the four child boxes of a record, intersects hit leaf children at
once, descends into the nearest hit interior child and pushes the others
with their entry distances; popped entries beyond the closest hit so far are
skipped. The packer bounds the pushes per level, so two levels fit a
128-word int32 stack (`STACK_WORDS`, `new_stack()`), which the caller
allocates once per thread and reuses for every ray.

Robustness: boxes are float32 rounded outward and the slab test widens its
exit distance by a few ulps (Ize 2013), and triangles use the watertight
test, so rays through shared edges and vertices of closed meshes always hit.

Performance notes: the whole traversal is inlined into each entry point
(`inline="always"`), because a call that passes the Geometry namedtuple
moves ~300 machine words; entry points are compiled without the NRT
(`_nrt=False`), so no reference counts are touched per ray (atomic updates
of shared counters would also serialise threads).
"""
import math

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic

from .geometry import STACK_WORDS, new_stack  # noqa: F401  (re-exported for callers)
from .primitives import prim_hits, prim_surface
from .triangle import pick, triangle_normal, woop_setup, woop_test

# Slab exits are scaled by this to absorb the rounding of (b - o) * (1/d).
_ROBUST = 1.0 + 1e-15
# Stored entry distances are lowered by this relative amount so the float32
# copy never exceeds the true value (culling stays conservative).
_LOWER = 2.0 ** -22
_BIG = 1e300
_CHUNK = 256

_INLINE = dict(cache=True, error_model="numpy", inline="always")
_ENTRY = dict(cache=True, error_model="numpy", _nrt=False)


@njit(**_INLINE)
def _inv(d):
    # zero components give a huge finite reciprocal instead of inf, so that
    # (plane - o) * inv is never 0 * inf = NaN
    r = 1.0 / d
    if abs(r) < _BIG:
        return r
    return math.copysign(_BIG, r)


@njit(**_INLINE)
def _xform_ray(m, i, ox, oy, oz, dx, dy, dz):
    """Ray through affine m[i] (3x4): point and vector."""
    return (m[i, 0, 0] * ox + m[i, 0, 1] * oy + m[i, 0, 2] * oz + m[i, 0, 3],
            m[i, 1, 0] * ox + m[i, 1, 1] * oy + m[i, 1, 2] * oz + m[i, 1, 3],
            m[i, 2, 0] * ox + m[i, 2, 1] * oy + m[i, 2, 2] * oz + m[i, 2, 3],
            m[i, 0, 0] * dx + m[i, 0, 1] * dy + m[i, 0, 2] * dz,
            m[i, 1, 0] * dx + m[i, 1, 1] * dy + m[i, 1, 2] * dz,
            m[i, 2, 0] * dx + m[i, 2, 1] * dy + m[i, 2, 2] * dz)


@njit(**_INLINE)
def _normal_through(m, i, nx, ny, nz):
    """Normal through the inverse-transpose, given the inverse m[i]: m^T n."""
    return (m[i, 0, 0] * nx + m[i, 1, 0] * ny + m[i, 2, 0] * nz,
            m[i, 0, 1] * nx + m[i, 1, 1] * ny + m[i, 2, 1] * nz,
            m[i, 0, 2] * nx + m[i, 1, 2] * ny + m[i, 2, 2] * nz)


_V4F = ir.VectorType(ir.FloatType(), 4)
_V4D = ir.VectorType(ir.DoubleType(), 4)


@intrinsic
def _slab4(typingctx, pf, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo, tmin, tmax):
    """Slab test of the four child boxes of the record at word b, as one
    4-wide vector computation (numba would emit it as 24 scalar min/max).

    Returns (mask, near0..near3): bit k of mask is set if the ray enters
    child k within [tmin, tmax]. nxo, nyo, nzo are the word offsets of the
    near planes (chosen by the direction signs); the far planes of an axis
    sit at the other offset of its pair (x: 0/4, y: 8/12, z: 16/20).
    Box bounds are float32 and widened exactly to float64; the exit is
    scaled by _ROBUST so rounding never loses a hit (Ize 2013).
    """
    f64 = types.float64
    sig = types.Tuple((types.int64, f64, f64, f64, f64))(
        pf, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo, tmin, tmax)

    def codegen(context, builder, signature, args):
        pf_, b_, ox_, oy_, oz_, ix_, iy_, iz_, nxo_, nyo_, nzo_, tmin_, tmax_ = args
        data = context.make_array(signature.args[0])(context, builder, pf_).data
        i32 = ir.IntType(32)
        i64 = ir.IntType(64)

        def splat(x):
            v = builder.insert_element(ir.Constant(_V4D, ir.Undefined), x, ir.Constant(i32, 0))
            return builder.shuffle_vector(v, v, ir.Constant(ir.VectorType(i32, 4), [0, 0, 0, 0]))

        def plane(off, o, inv):
            ptr = builder.gep(data, [builder.add(b_, off)], inbounds=True)
            v = builder.load(builder.bitcast(ptr, _V4F.as_pointer()), align=16)
            return builder.fmul(builder.fsub(builder.fpext(v, _V4D), splat(o)), splat(inv))

        # same NaN behaviour as numba's scalar max/min: keep the first operand
        def vmax(a, c):
            return builder.select(builder.fcmp_ordered(">", c, a), c, a)

        def vmin(a, c):
            return builder.select(builder.fcmp_ordered("<", c, a), c, a)

        near = vmax(vmax(plane(nxo_, ox_, ix_), plane(nyo_, oy_, iy_)),
                    vmax(plane(nzo_, oz_, iz_), splat(tmin_)))
        far = vmin(vmin(plane(builder.sub(ir.Constant(i64, 4), nxo_), ox_, ix_),
                        plane(builder.sub(ir.Constant(i64, 20), nyo_), oy_, iy_)),
                   plane(builder.sub(ir.Constant(i64, 36), nzo_), oz_, iz_))
        far = vmin(builder.fmul(far, splat(ir.Constant(ir.DoubleType(), _ROBUST))), splat(tmax_))
        hit = builder.fcmp_ordered("<=", near, far)
        mask = builder.zext(builder.bitcast(hit, ir.IntType(4)), i64)
        out = [mask] + [builder.extract_element(near, ir.Constant(i32, k)) for k in range(4)]
        return context.make_tuple(builder, signature.return_type, out)

    return sig, codegen


@njit(**_INLINE)
def _lowest(m, n0, n1, n2, n3):
    """Index and entry distance of the lowest set bit of a 4-bit mask."""
    if m & 1:
        return 0, n0
    if m & 2:
        return 1, n1
    if m & 4:
        return 2, n2
    return 3, n3


@njit(**_INLINE)
def _push(stack, fstack, sp, node, near):
    stack[sp] = node
    fstack[sp + 1] = np.float32(near - abs(near) * _LOWER)
    return sp + 2


@njit(**_INLINE)
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


@njit(**_INLINE)
def _prim_first(g, j, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Nearest crossing of primitive row j in (tmin, tmax), prototype-space ray; inf if none."""
    lox, loy, loz, ldx, ldy, ldz = _xform_ray(g.prim_inv, j, ox, oy, oz, dx, dy, dz)
    pp = g.prim_params
    # parameters as a tuple: an array row would be a view object
    n, t0, t1, t2, t3 = prim_hits(g.prim_kind[j], (pp[j, 0], pp[j, 1], pp[j, 2], pp[j, 3]),
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


@njit(**_INLINE)
def _tri(tp, j, kx, ky, kz, sx, sy, sz, okx, oky, okz, tmin, tmax):
    return woop_test(tp[j, 0, kx] - okx, tp[j, 0, ky] - oky, tp[j, 0, kz] - okz,
                     tp[j, 1, kx] - okx, tp[j, 1, ky] - oky, tp[j, 1, kz] - okz,
                     tp[j, 2, kx] - okx, tp[j, 2, ky] - oky, tp[j, 2, kz] - okz,
                     sx, sy, sz, tmin, tmax)


@njit(**_INLINE)
def _blas_closest(g, stack, fstack, sp0, p, ox, oy, oz, dx, dy, dz, tmin, tbest,
                  shape, b1, b2):
    """Closest hit in prototype p for a prototype-space ray, improving on
    (tbest, shape, b1, b2); uses the stack above sp0."""
    ix = _inv(dx)
    iy = _inv(dy)
    iz = _inv(dz)
    kx, ky, kz, sx, sy, sz = woop_setup(dx, dy, dz)
    okx = pick(kx, ox, oy, oz)
    oky = pick(ky, ox, oy, oz)
    okz = pick(kz, ox, oy, oz)
    nxo = 4 if ix < 0.0 else 0
    nyo = 12 if iy < 0.0 else 8
    nzo = 20 if iz < 0.0 else 16
    pf = g.blas_pf
    pi = g.blas_pi
    tp = g.tri_p
    node = g.proto_slot[p]
    sp = sp0
    while True:
        b = node * 32
        m, n0, n1, n2, n3 = _slab4(pf, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo, tmin, tbest)
        best = -1
        bt = 0.0
        lo = sp
        while m != 0:
            k, near = _lowest(m, n0, n1, n2, n3)
            m &= m - 1
            if near > tbest:          # a leaf processed before got closer
                continue
            a = pi[b + 24 + k]
            c = pi[b + 28 + k]
            if c > 0:
                # blas_items is the identity: positions are shape ids
                for s in range(a, a + c):
                    j = g.shape_ref[s]
                    if j >= 0:
                        h, t, u, v = _tri(tp, j, kx, ky, kz, sx, sy, sz, okx, oky, okz,
                                          tmin, tbest)
                        if h:
                            tbest = t
                            shape = s
                            b1 = u
                            b2 = v
                    else:
                        t = _prim_first(g, -1 - j, ox, oy, oz, dx, dy, dz, tmin, tbest)
                        if t < tbest:
                            tbest = t
                            shape = s
                            b1 = 0.0
                            b2 = 0.0
            elif best < 0:
                best = a
                bt = near
            elif near < bt:
                sp = _push(stack, fstack, sp, best, bt)
                best = a
                bt = near
            else:
                sp = _push(stack, fstack, sp, a, near)
        if sp - lo > 2:
            _sort_top(stack, fstack, lo, sp)
        if best >= 0 and bt <= tbest:
            node = best
        else:
            node = -1
            while sp > sp0:
                sp -= 2
                if fstack[sp + 1] <= tbest:
                    node = stack[sp]
                    break
            if node < 0:
                break
    return tbest, shape, b1, b2


@njit(**_INLINE)
def _closest(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """(t, inst, shape, b1, b2) of the closest hit in (tmin, tmax); shape -1: none."""
    fstack = stack.view(np.float32)
    tbest = tmax
    inst = -1
    shape = -1
    b1 = 0.0
    b2 = 0.0
    ix = _inv(dx)
    iy = _inv(dy)
    iz = _inv(dz)
    nxo = 4 if ix < 0.0 else 0
    nyo = 12 if iy < 0.0 else 8
    nzo = 20 if iz < 0.0 else 16
    pf = g.tlas_pf
    pi = g.tlas_pi
    node = 0
    sp = 0
    while True:
        b = node * 32
        m, n0, n1, n2, n3 = _slab4(pf, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo, tmin, tbest)
        best = -1
        bt = 0.0
        lo = sp
        while m != 0:
            k, near = _lowest(m, n0, n1, n2, n3)
            m &= m - 1
            if near > tbest:
                continue
            a = pi[b + 24 + k]
            c = pi[b + 28 + k]
            if c > 0:
                for q in range(a, a + c):
                    i = g.tlas_items[q]
                    lox, loy, loz, ldx, ldy, ldz = _xform_ray(g.inst_inv, i, ox, oy, oz,
                                                              dx, dy, dz)
                    s0 = shape
                    tbest, shape, b1, b2 = _blas_closest(
                        g, stack, fstack, sp, g.inst_proto[i], lox, loy, loz,
                        ldx, ldy, ldz, tmin, tbest, shape, b1, b2)
                    if shape != s0:
                        inst = i
            elif best < 0:
                best = a
                bt = near
            elif near < bt:
                sp = _push(stack, fstack, sp, best, bt)
                best = a
                bt = near
            else:
                sp = _push(stack, fstack, sp, a, near)
        if sp - lo > 2:
            _sort_top(stack, fstack, lo, sp)
        if best >= 0 and bt <= tbest:
            node = best
        else:
            node = -1
            while sp > 0:
                sp -= 2
                if fstack[sp + 1] <= tbest:
                    node = stack[sp]
                    break
            if node < 0:
                break
    return tbest, inst, shape, b1, b2


@njit(**_INLINE)
def _blas_any(g, stack, sp0, p, ox, oy, oz, dx, dy, dz, tmin, tmax):
    ix = _inv(dx)
    iy = _inv(dy)
    iz = _inv(dz)
    kx, ky, kz, sx, sy, sz = woop_setup(dx, dy, dz)
    okx = pick(kx, ox, oy, oz)
    oky = pick(ky, ox, oy, oz)
    okz = pick(kz, ox, oy, oz)
    nxo = 4 if ix < 0.0 else 0
    nyo = 12 if iy < 0.0 else 8
    nzo = 20 if iz < 0.0 else 16
    pf = g.blas_pf
    pi = g.blas_pi
    tp = g.tri_p
    node = g.proto_slot[p]
    sp = sp0
    while True:
        b = node * 32
        m, n0, n1, n2, n3 = _slab4(pf, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo, tmin, tmax)
        best = -1
        while m != 0:
            k, near = _lowest(m, n0, n1, n2, n3)
            m &= m - 1
            a = pi[b + 24 + k]
            c = pi[b + 28 + k]
            if c > 0:
                for s in range(a, a + c):
                    j = g.shape_ref[s]
                    if j >= 0:
                        h, t, u, v = _tri(tp, j, kx, ky, kz, sx, sy, sz, okx, oky, okz,
                                          tmin, tmax)
                        if h:
                            return True
                    elif _prim_first(g, -1 - j, ox, oy, oz, dx, dy, dz, tmin, tmax) < tmax:
                        return True
            elif best < 0:
                best = a
            else:
                stack[sp] = a
                sp += 2
        if best >= 0:
            node = best
        elif sp > sp0:
            sp -= 2
            node = stack[sp]
        else:
            return False


@njit(**_INLINE)
def _occluded(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    ix = _inv(dx)
    iy = _inv(dy)
    iz = _inv(dz)
    nxo = 4 if ix < 0.0 else 0
    nyo = 12 if iy < 0.0 else 8
    nzo = 20 if iz < 0.0 else 16
    pf = g.tlas_pf
    pi = g.tlas_pi
    node = 0
    sp = 0
    while True:
        b = node * 32
        m, n0, n1, n2, n3 = _slab4(pf, b, ox, oy, oz, ix, iy, iz, nxo, nyo, nzo, tmin, tmax)
        best = -1
        while m != 0:
            k, near = _lowest(m, n0, n1, n2, n3)
            m &= m - 1
            a = pi[b + 24 + k]
            c = pi[b + 28 + k]
            if c > 0:
                for q in range(a, a + c):
                    i = g.tlas_items[q]
                    lox, loy, loz, ldx, ldy, ldz = _xform_ray(g.inst_inv, i, ox, oy, oz,
                                                              dx, dy, dz)
                    if _blas_any(g, stack, sp, g.inst_proto[i], lox, loy, loz,
                                 ldx, ldy, ldz, tmin, tmax):
                        return True
            elif best < 0:
                best = a
            else:
                stack[sp] = a
                sp += 2
        if best >= 0:
            node = best
        elif sp > 0:
            sp -= 2
            node = stack[sp]
        else:
            return False


@njit(**_INLINE)
def _surface(g, t, inst, shape, b1, b2, ox, oy, oz, dx, dy, dz):
    ux, uy, uz, vx, vy, vz = _xform_ray(g.inst_inv, inst, ox, oy, oz, dx, dy, dz)
    j = g.shape_index[shape]
    if g.shape_kind[shape] == 0:
        tp = g.tri_p
        px, py, pz = triangle_normal(tp[j, 0, 0], tp[j, 0, 1], tp[j, 0, 2],
                                     tp[j, 1, 0], tp[j, 1, 1], tp[j, 1, 2],
                                     tp[j, 2, 0], tp[j, 2, 1], tp[j, 2, 2])
        face = 0
        u = b1
        v = b2
    else:
        # the same local ray as in the traversal, so the point is the hit point
        lox, loy, loz, ldx, ldy, ldz = _xform_ray(g.prim_inv, j, ux, uy, uz, vx, vy, vz)
        pp = g.prim_params
        face, u, v, lnx, lny, lnz = prim_surface(
            g.prim_kind[j], (pp[j, 0], pp[j, 1], pp[j, 2], pp[j, 3]),
            lox + t * ldx, loy + t * ldy, loz + t * ldz)
        px, py, pz = _normal_through(g.prim_inv, j, lnx, lny, lnz)
    nx, ny, nz = _normal_through(g.inst_inv, inst, px, py, pz)
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if ln > 0.0:
        nx /= ln
        ny /= ln
        nz /= ln
    return face, u, v, nx, ny, nz


# ------------------------------------------------------------------ entry points

@njit(**_ENTRY)
def closest_hit(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit in (tmin, tmax): (t, inst, shape, b1, b2); inst = shape = -1 on a miss.

    b1, b2 are the triangle barycentrics (0 for primitives). `stack`: int32
    array of at least STACK_WORDS words, reused across calls of one thread.
    """
    return _closest(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(**_ENTRY)
def hit_surface(g, t, inst, shape, b1, b2, ox, oy, oz, dx, dy, dz):
    """Surface data of a hit from `closest_hit`: (face, u, v, nx, ny, nz), world unit normal."""
    return _surface(g, t, inst, shape, b1, b2, ox, oy, oz, dx, dy, dz)


@njit(**_ENTRY)
def intersect_closest(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Closest hit in (tmin, tmax): (hit, t, inst, shape, face, u, v, nx, ny, nz).

    (nx, ny, nz) is the world-space unit normal: the geometric normal of a
    triangle (counter-clockwise front) or the outward normal of a primitive,
    both carried through the inverse-transpose of the transforms. face/u/v
    are (0, b1, b2) for triangles and the primitive's chart otherwise.
    On a miss: (False, inf, -1, -1, -1, 0, 0, 0, 0, 0).
    """
    t, inst, shape, b1, b2 = _closest(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax)
    if shape < 0:
        return False, math.inf, -1, -1, -1, 0.0, 0.0, 0.0, 0.0, 0.0
    face, u, v, nx, ny, nz = _surface(g, t, inst, shape, b1, b2, ox, oy, oz, dx, dy, dz)
    return True, t, inst, shape, face, u, v, nx, ny, nz


@njit(**_ENTRY)
def occluded(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """True if anything lies on the ray strictly between tmin and tmax (any hit)."""
    return _occluded(g, stack, ox, oy, oz, dx, dy, dz, tmin, tmax)


@njit(cache=True, error_model="numpy", parallel=True, _nrt=False)
def _closest_batch(g, origins, dirs, tmax, stacks, t_out, inst_out, shape_out):
    n = origins.shape[0]
    n_chunks = (n + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        stack = stacks[c]
        for i in range(c * _CHUNK, min(n, (c + 1) * _CHUNK)):
            t, inst, shape, b1, b2 = _closest(g, stack, origins[i, 0], origins[i, 1],
                                              origins[i, 2], dirs[i, 0], dirs[i, 1],
                                              dirs[i, 2], 0.0, tmax)
            t_out[i] = t if shape >= 0 else math.inf
            inst_out[i] = inst
            shape_out[i] = shape


@njit(cache=True, error_model="numpy", parallel=True, _nrt=False)
def _occluded_batch(g, origins, dirs, tmax, stacks, out):
    n = origins.shape[0]
    n_chunks = (n + _CHUNK - 1) // _CHUNK
    for c in prange(n_chunks):
        stack = stacks[c]
        for i in range(c * _CHUNK, min(n, (c + 1) * _CHUNK)):
            out[i] = _occluded(g, stack, origins[i, 0], origins[i, 1], origins[i, 2],
                               dirs[i, 0], dirs[i, 1], dirs[i, 2], 0.0, tmax)


def _rays(origins, dirs):
    o = np.ascontiguousarray(origins, dtype=np.float64).reshape(-1, 3)
    d = np.ascontiguousarray(dirs, dtype=np.float64).reshape(-1, 3)
    if o.shape != d.shape:
        raise ValueError("origins and dirs must both have shape (N, 3)")
    return o, d


def trace_closest_batch(g, origins, dirs, tmax=math.inf):
    """Closest hits of N rays with t in (0, tmax): (t (N,) inf on a miss, inst (N,), shape (N,))."""
    o, d = _rays(origins, dirs)
    n = o.shape[0]
    t = np.empty(n)
    inst = np.empty(n, np.int32)
    shape = np.empty(n, np.int32)
    # one stack per chunk of rays: no allocation inside the kernel
    stacks = np.empty(((n + _CHUNK - 1) // _CHUNK, STACK_WORDS), np.int32)
    if n:
        _closest_batch(g, o, d, float(tmax), stacks, t, inst, shape)
    return t, inst, shape


def occluded_batch(g, origins, dirs, tmax=math.inf):
    """Occlusion of N rays over t in (0, tmax): bool (N,)."""
    o, d = _rays(origins, dirs)
    n = o.shape[0]
    out = np.zeros(n, np.bool_)
    stacks = np.empty(((n + _CHUNK - 1) // _CHUNK, STACK_WORDS), np.int32)
    if n:
        _occluded_batch(g, o, d, float(tmax), stacks, out)
    return out
