"""Stochastic surface-area estimation per normal direction (thesis 6.3).

An orientation lightmap needs, for each normal bin, the area of the covered
geometry whose normal falls in it. Summing exact areas would mean visiting
every primitive, which is what OLs exist to avoid; instead s sample points
are spread over the m parts of the group by systematic sampling, so s may be
much smaller than m (6.3.2). A part is one shape (triangle, primitive or CSG
leaf) of one instance; instanced parts are sampled through their prototype
and the instance transform.

The thesis spreads samples evenly over the parts. That starves big parts
among many small ones (a sphereflake's root sphere is a fifth of its area but
one part in 7381), so here parts are drawn in proportion to a cheap size
proxy instead: the part's local area (exact for triangles, the closed form
for primitives) times the instance's mean area scale |det M|^(2/3). Each
sample is a uniform (u, v) point of its part's chart; its value is
A_uv · |∂p/∂u × ∂p/∂v| (the analytic area element: the derivatives come with
the chart, primitives.prim_point; a triangle's is its area) divided by s
times the part's probability. Under similarity transforms the proxy is the
part's true area, so the choice of part adds no variance: only the area
element inside a chart varies (for triangles nothing does). The value goes to the bin of the sample's world normal: every
bin's area and the total are unbiased estimates. A CSG leaf counts only
where it lies on its solid's boundary.

The same samples also measure how much of the group's surface the group
itself shades (`openness`): strongly self-shadowed groups (cavities, Menger
sponge) are where one irradiance per normal averages most.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..core.affine import apply_point, apply_transposed, cross
from ..geometry import csg
from ..geometry import csg_trace
from ..geometry.primitives import octa_encode, prim_area, prim_nfaces, prim_point
from ..geometry.raycast import STACK_WORDS, intersect_closest
from ..core.sampling import cosine_hemisphere, first_above, next_float, stream_state, to_world
from ..core import parallel

AreaEstimate = namedtuple("AreaEstimate", [
    "area",            # float64[R*R] estimated area per bin (m², row-major like a lightmap)
    "rel_error",       # float64[R*R] estimated relative standard error per bin (inf: no sample)
    "total",           # estimated total area
    "total_rel_error",
    "samples",         # s
    "parts",           # m
    "openness",        # fraction of hemisphere rays from the surface not blocked by the group
    "seconds",
])

OPENNESS_SAMPLES = 4096   # surface points probed for self-shadowing
OPENNESS_RAYS = 4         # cosine-distributed rays per point


@njit(cache=True, inline="always")
def _det3(m):
    return (m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
            - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
            + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))


@njit(cache=True)
def _csg_side(buf, cb, roots, leaf, px, py, pz, bits):
    """+1 / -1: p on leaf `leaf` bounds a solid of `roots` with the leaf's
    outward normal / flipped (a subtracted operand); 0: p is not on a boundary."""
    for r in roots:
        a = csg_trace.point_inside(buf, cb, r, px, py, pz, bits, leaf, True)
        b = csg_trace.point_inside(buf, cb, r, px, py, pz, bits, leaf, False)
        if a != b:
            return 1 if a else -1
    return 0


@njit(cache=True, nogil=True)
def _sample_kernel(g, pick, solids, job, out, start, stop):
    """Samples start..stop-1: each picks an instance, a part of it and a point on
    that part, and writes its normal's bin, its area value and the point.
    pick = (instances, their cumulative size, per prototype its first part,
    parts, parts' cumulative area); solids = (per prototype its first CSG root,
    roots, first CSG virtual shape); job = (bins per side, samples, seed);
    out = (bin, value, point and normal) per sample."""
    insts, inst_cum, part_start, parts, part_acc = pick
    csg_roots_start, csg_roots, vs0 = solids
    res, n_s, seed = job
    out_bin, out_val, out_pn = out
    total = inst_cum[inst_cum.shape[0] - 1]
    buf = (g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features)
    has_csg = csg_roots.shape[0] > 0
    cb = csg_trace.csg_base(buf) if has_csg else 0
    state0 = stream_state(seed, np.uint64(0xA5EA))
    state0, off = next_float(state0)
    for k in range(start, stop):
        bits = np.empty(3 * csg.MAX_WORK + 8, np.int32)
        state = stream_state(seed, k)
        x = (k + off) / n_s * total
        # instance: inst_cum[a] <= x < inst_cum[a+1] (cumulative size proxies)
        lo = first_above(inst_cum, x, 0, inst_cum.shape[0] - 1) - 1
        inst = insts[lo]
        proto = g.inst_proto[inst]
        w_inst = inst_cum[lo + 1] - inst_cum[lo]
        p0 = part_start[proto]
        p1 = part_start[proto + 1]
        a_proto = part_acc[p1 - 1]
        # part: the first whose cumulative local area exceeds the position inside the instance
        if not (w_inst > 0.0 and a_proto > 0.0):
            out_bin[k] = -1
            out_val[k] = 0.0
            continue
        y = min(max((x - inst_cum[lo]) / w_inst, 0.0), 1.0) * a_proto
        a, b = p0, p1 - 1
        while a < b:
            mid = (a + b) // 2
            if part_acc[mid] > y:
                b = mid
            else:
                a = mid + 1
        a_part = part_acc[a] - (part_acc[a - 1] if a > p0 else 0.0)
        shape = parts[a]
        # 1 / (s * P(part)): P = (w_inst / total) * (a_part / a_proto)
        scale = total * a_proto / (n_s * w_inst * a_part) if a_part > 0.0 else 0.0
        xf = g.inst_xf[inst]
        inv = g.inst_inv[inst]
        det_i = abs(_det3(xf))
        kind = g.shape_kind[shape]
        idx = g.shape_index[shape]
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        state, u3 = next_float(state)
        if kind == 0:
            p = g.tri_p[idx]
            ax, ay, az = p[1, 0] - p[0, 0], p[1, 1] - p[0, 1], p[1, 2] - p[0, 2]
            bx, by, bz = p[2, 0] - p[0, 0], p[2, 1] - p[0, 1], p[2, 2] - p[0, 2]
            cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
            if u2 + u3 > 1.0:
                u2, u3 = 1.0 - u2, 1.0 - u3
            lx = p[0, 0] + u2 * ax + u3 * bx
            ly = p[0, 1] + u2 * ay + u3 * by
            lz = p[0, 2] + u2 * az + u3 * bz
            area_local = 0.5
            det_p = 1.0
        else:
            nf = prim_nfaces(kind)
            face = min(np.int64(u1 * nf), nf - 1)
            params = g.prim_params[idx]
            r = prim_point(kind, (params[0], params[1], params[2], params[3]), face, u2, u3)
            pm = g.prim_xf[idx]
            # dp/du x dp/dv (outward), carried to prototype space like the normal
            cx, cy, cz = cross(r[3], r[4], r[5], r[6], r[7], r[8])
            cx, cy, cz = apply_transposed(g.prim_inv[idx], cx, cy, cz)
            det_p = abs(_det3(pm))
            lx, ly, lz = apply_point(pm, r[0], r[1], r[2])
            area_local = float(nf)
        side = 1
        if has_csg and shape >= vs0:
            leaf, _sub = csg_trace.csg_vshape_leaf(buf, cb, shape)
            roots = csg_roots[csg_roots_start[proto]:csg_roots_start[proto + 1]]
            side = _csg_side(buf, cb, roots, leaf, lx, ly, lz, bits)
        nx, ny, nz = apply_transposed(inv, cx, cy, cz)
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        # |M^-T c| |det M| = |cof(M) c|: the world area element
        val = area_local * ln * det_i * det_p * scale
        if side == 0 or not (ln > 0.0) or not math.isfinite(val):
            out_bin[k] = -1
            out_val[k] = 0.0
            continue
        nx, ny, nz = side * nx / ln, side * ny / ln, side * nz / ln
        s, t = octa_encode(nx, ny, nz)
        bx_ = min(np.int64(s * res), res - 1)
        by_ = min(np.int64(t * res), res - 1)
        out_bin[k] = by_ * res + bx_
        out_val[k] = val
        wx, wy, wz = apply_point(xf, lx, ly, lz)
        out_pn[k, 0], out_pn[k, 1], out_pn[k, 2] = wx, wy, wz
        out_pn[k, 3], out_pn[k, 4], out_pn[k, 5] = nx, ny, nz


@njit(cache=True, nogil=True)
def _openness_kernel(g, pn, member, n_rays, tmax, seed, out, start, stop):
    """Fraction of cosine rays from each point that leave without hitting the group."""
    for k in range(start, stop):
        stack = np.empty(STACK_WORDS, np.int32)
        state = stream_state(seed, k)
        px, py, pz = pn[k, 0], pn[k, 1], pn[k, 2]
        nx, ny, nz = pn[k, 3], pn[k, 4], pn[k, 5]
        eps = 1e-6 * (1.0 + max(abs(px), abs(py), abs(pz)))
        free = 0
        for _ in range(n_rays):
            state, u1 = next_float(state)
            state, u2 = next_float(state)
            lx, ly, lz = cosine_hemisphere(u1, u2)
            dx, dy, dz = to_world(lx, ly, lz, nx, ny, nz)
            hit, t, inst, shape, face, u, v, hx, hy, hz = intersect_closest(
                g, stack, px + eps * nx, py + eps * ny, pz + eps * nz, dx, dy, dz, 0.0, tmax)
            if not hit or not member[inst]:
                free += 1
        out[k] = free / n_rays


@njit(cache=True)
def _local_areas(g, parts):
    """Size proxy of each part in prototype space: a triangle's area, a primitive's
    closed-form area times its transform's mean area scale."""
    out = np.empty(parts.shape[0])
    for j in range(parts.shape[0]):
        sh = parts[j]
        idx = g.shape_index[sh]
        if g.shape_kind[sh] == 0:
            p = g.tri_p[idx]
            ax, ay, az = p[1, 0] - p[0, 0], p[1, 1] - p[0, 1], p[1, 2] - p[0, 2]
            bx, by, bz = p[2, 0] - p[0, 0], p[2, 1] - p[0, 1], p[2, 2] - p[0, 2]
            cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
            out[j] = 0.5 * math.sqrt(cx * cx + cy * cy + cz * cz)
        else:
            pr = g.prim_params[idx]
            out[j] = prim_area(g.shape_kind[sh], (pr[0], pr[1], pr[2], pr[3])) * \
                abs(_det3(g.prim_xf[idx])) ** (2.0 / 3.0)
    return out


def _part_tables(g):
    """Per prototype: the shapes that are surfaces (CSR), and its CSG roots (CSR)."""
    n_p = g.proto_root.shape[0]
    kind = g.shape_kind
    is_part = (kind != csg.CSG) & (g.shape_surface >= 0)
    sp = g.shape_proto
    order = np.argsort(sp, kind="stable")
    order = order[is_part[order]]
    counts = np.bincount(sp[order], minlength=n_p)
    part_start = np.zeros(n_p + 1, np.int64)
    part_start[1:] = np.cumsum(counts)
    roots_sel = np.flatnonzero(kind == csg.CSG)
    roots_sel = roots_sel[np.argsort(sp[roots_sel], kind="stable")]
    rc = np.bincount(sp[roots_sel], minlength=n_p)
    roots_start = np.zeros(n_p + 1, np.int64)
    roots_start[1:] = np.cumsum(rc)
    return (part_start, order.astype(np.int64), counts, roots_start,
            g.shape_index[roots_sel].astype(np.int64))


def estimate_areas(g, instances, resolution, samples, seed=0, member=None, tmax=None,
                   openness_samples=OPENNESS_SAMPLES):
    """Area per octahedral normal bin of the given instances' surfaces.

    instances: instance ids of the group; resolution R: bins per side;
    samples s: points spread over all parts. member (bool[I]) marks the
    instances that count as the group when measuring openness (default: the
    given ones); tmax bounds those rays (default: the group's box diagonal).
    """
    import time
    t0 = time.perf_counter()
    R = int(resolution)
    s = int(samples)
    insts = np.asarray(instances, np.int64).reshape(-1)
    part_start, parts, counts, roots_start, roots = _part_tables(g)
    m = int(counts[g.inst_proto[insts]].sum()) if insts.size else 0
    # cumulative local part areas, restarting at each prototype
    local = _local_areas(g, parts)
    acc = np.cumsum(local)
    first = part_start[:-1][counts > 0]
    base = np.zeros(parts.size)
    base[first] = np.concatenate([[0.0], acc[first[1:] - 1]]) if first.size else 0.0
    part_acc = acc - np.maximum.accumulate(base)
    proto_area = np.zeros(counts.size)
    has = counts > 0
    proto_area[has] = part_acc[part_start[1:][has] - 1]
    det = np.abs(np.linalg.det(g.inst_xf[insts][:, :, :3])) if insts.size else np.zeros(0)
    w = proto_area[g.inst_proto[insts]] * det ** (2.0 / 3.0) if insts.size else np.zeros(0)
    inst_cum = np.zeros(insts.size + 1)
    inst_cum[1:] = np.cumsum(w)
    if m == 0 or s < 1 or not inst_cum[-1] > 0:
        nbin = R * R
        return AreaEstimate(np.zeros(nbin), np.full(nbin, np.inf), 0.0, math.inf, s, m, 1.0,
                            time.perf_counter() - t0)
    vs0 = csg_trace.csg_vs0((g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features)) if roots.size else 0
    out_bin = np.empty(s, np.int64)
    out_val = np.empty(s)
    out_pn = np.zeros((s, 6))
    parallel.run(_sample_kernel, s, g, (insts, inst_cum, part_start, parts, np.ascontiguousarray(part_acc)),
                 (roots_start, roots, int(vs0)), (R, s, np.uint64(seed)), (out_bin, out_val, out_pn), min_block=256)
    ok = out_bin >= 0
    b = out_bin[ok]
    v = out_val[ok]
    # astype: with no sample in any bin numpy's bincount returns int64 even with weights
    area = np.bincount(b, weights=v, minlength=R * R).astype(np.float64)
    sq = np.bincount(b, weights=v * v, minlength=R * R).astype(np.float64)
    # X_k = value of sample k in this bin (0 elsewhere): Var(sum) ~ s/(s-1) Σ (X_k - mean)²
    var = np.maximum(sq - area * area / s, 0.0) * s / max(s - 1, 1)
    rel = np.full(R * R, np.inf)
    pos = area > 0
    rel[pos] = np.sqrt(var[pos]) / area[pos]
    total = float(area.sum())
    tvar = max(float((out_val ** 2).sum()) - total * total / s, 0.0) * s / max(s - 1, 1)
    total_rel = math.sqrt(tvar) / total if total > 0 else math.inf
    openness = 1.0
    if openness_samples and ok.any():
        if member is None:
            member = np.zeros(g.inst_proto.shape[0], np.bool_)
            member[insts] = True
        pick = np.flatnonzero(ok)
        if pick.size > openness_samples:
            pick = pick[np.linspace(0, pick.size - 1, int(openness_samples)).astype(np.int64)]
        pn = np.ascontiguousarray(out_pn[pick])
        if tmax is None:
            tmax = float(np.linalg.norm(pn[:, :3].max(axis=0) - pn[:, :3].min(axis=0))) or 1.0
        free = np.empty(pn.shape[0])
        parallel.run(_openness_kernel, pn.shape[0], g, pn, np.asarray(member, np.bool_), OPENNESS_RAYS,
                     float(tmax), np.uint64(seed + 1), free)
        # area-weighted: a big open face counts more than a small hidden one
        w = out_val[pick]
        openness = float((free * w).sum() / max(w.sum(), 1e-300))
    return AreaEstimate(area, rel, total, total_rel, s, m, openness, time.perf_counter() - t0)
