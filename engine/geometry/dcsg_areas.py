"""Surface area per normal bin of an L-system's counted structure (thesis 6.3):
exact node areas, and stochastic area samples drawn down the graph for the
orientation lightmaps that own its subtrees."""
import math

import numpy as np
from numba import njit, prange

from ..core.affine import apply_transposed, cross, normal_through
from .primitives import octa_encode, prim_nfaces, prim_point
from ..core.sampling import next_float, stream_state
from .dcsg import ORGAN
from .dcsg_blob import B_ORG_CDF
from .dcsg_trace import alternative, child_hash, organ_tables, blob_tables, dcsg_base


# ---------------------------------------------------------------- area estimation (6.3)

def node_areas(graph):
    """Per node of the graph (its arrays' order): an area proxy of its subtree,
    the proposal by which area samples descend (expected over alternatives). Any
    positive proposal keeps the estimate unbiased; a good one keeps it quiet."""
    from .primitives import prim_area
    a = graph.arrays()
    ids = {id(n): i for i, n in enumerate(graph.nodes)}
    out = np.zeros(len(graph.nodes))
    done = np.zeros(len(graph.nodes), bool)

    def area(n):
        i = ids[id(n)]
        if done[i]:
            return out[i]
        if n.prim is not None:
            kind, params, xf, _ = n.prim
            local = graph.organs.area[int(params[0])] if kind == ORGAN else prim_area(kind, params)
            v = local * abs(np.linalg.det(xf[:, :3])) ** (2.0 / 3.0)
        else:
            v, prev = 0.0, 0.0
            for cum, children in n.alts:
                v += (cum - prev) * sum(area(c) for c, _, _ in children)
                prev = cum
        out[i], done[i] = v, True
        return v

    for n in reversed(graph.nodes):      # children were made before their parents
        area(n)
    del a
    return out


@njit(cache=True, parallel=True)
def _area_samples(buf, node_area, start, start_hash, rot0, inst_inv, det_inst, exclude_stubs,
                  res, n_s, seed, out_bin, out_val):
    """s samples over the subtree of node `start` (hash start_hash, object rotation
    rot0 (3, 3)): the sample's world area element, divided by s and its probability,
    into the octahedral bin of its normal. exclude_stubs: a sample that enters a
    nested stub counts 0 there (that stub is an OL of its own)."""
    i64, f32, i32, f64 = buf[:4]
    w, iw = dcsg_base(buf)
    (o_alt0, o_nalt, o_prim, o_stub, o_ac0, o_anc, o_chn, o_chj, o_pk,
     _o_box, o_cum, _o_cinv, o_crot, _o_cbox, o_pp, o_pinv) = blob_tables(i64, w, iw)
    o_org_t0, o_org_nt, o_org_tri = organ_tables(i64, w, iw)
    o_org_cdf = w + i64[w + B_ORG_CDF]
    for k in prange(n_s):
        out_bin[k] = -1
        out_val[k] = 0.0
        state = stream_state(seed, k)
        node = start
        h = start_hash
        prob = 1.0
        # the object rotation of the current node, as scalars (no per-sample arrays)
        r00, r01, r02 = rot0[0, 0], rot0[0, 1], rot0[0, 2]
        r10, r11, r12 = rot0[1, 0], rot0[1, 1], rot0[1, 2]
        r20, r21, r22 = rot0[2, 0], rot0[2, 1], rot0[2, 2]
        alive = True
        while i32[o_prim + node] < 0:
            a = alternative(i32, f64, o_alt0, o_nalt, o_cum, node, h)
            c0 = i32[o_ac0 + a]
            nc = i32[o_anc + a]
            total = 0.0
            for c in range(c0, c0 + nc):
                total += node_area[i32[o_chn + c]]
            if nc == 0 or not total > 0.0:
                alive = False
                break
            state, u = next_float(state)
            x = u * total
            pick = c0 + nc - 1
            acc = 0.0
            for c in range(c0, c0 + nc):
                acc += node_area[i32[o_chn + c]]
                if x < acc:
                    pick = c
                    break
            child = i32[o_chn + pick]
            prob *= node_area[child] / total
            if exclude_stubs and i32[o_stub + child]:
                alive = False
                break
            r = o_crot + 9 * pick
            c00, c01, c02 = f64[r], f64[r + 1], f64[r + 2]
            c10, c11, c12 = f64[r + 3], f64[r + 4], f64[r + 5]
            c20, c21, c22 = f64[r + 6], f64[r + 7], f64[r + 8]
            r00, r01, r02 = (r00 * c00 + r01 * c10 + r02 * c20, r00 * c01 + r01 * c11 + r02 * c21,
                             r00 * c02 + r01 * c12 + r02 * c22)
            r10, r11, r12 = (r10 * c00 + r11 * c10 + r12 * c20, r10 * c01 + r11 * c11 + r12 * c21,
                             r10 * c02 + r11 * c12 + r12 * c22)
            r20, r21, r22 = (r20 * c00 + r21 * c10 + r22 * c20, r20 * c01 + r21 * c11 + r22 * c21,
                             r20 * c02 + r21 * c12 + r22 * c22)
            h = child_hash(h, i32[o_chj + pick])
            node = child
        if not alive or not prob > 0.0:
            continue
        p = i32[o_prim + node]
        kind = i32[o_pk + p]
        pp = o_pp + 4 * p
        params = (f64[pp], f64[pp + 1], f64[pp + 2], f64[pp + 3])
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        state, u3 = next_float(state)
        if kind == ORGAN:
            # a triangle by its share of the organ's area, then e1 x e2 (twice its area)
            g = np.int64(params[0])
            t0 = i32[o_org_t0 + g]
            nt = i32[o_org_nt + g]
            j = t0 + nt - 1
            for tk in range(t0, t0 + nt):
                if u1 < f64[o_org_cdf + tk]:
                    j = tk
                    break
            pk = f64[o_org_cdf + j] - (f64[o_org_cdf + j - 1] if j > t0 else 0.0)
            if not pk > 0.0:
                continue
            qq = o_org_tri + 9 * j
            cx, cy, cz = cross(f64[qq + 3] - f64[qq], f64[qq + 4] - f64[qq + 1], f64[qq + 5] - f64[qq + 2],
                               f64[qq + 6] - f64[qq], f64[qq + 7] - f64[qq + 1], f64[qq + 8] - f64[qq + 2])
            nf = 0.5 / pk
        else:
            nf = prim_nfaces(kind)
            face = min(np.int64(u1 * nf), nf - 1)
            q = prim_point(kind, params, face, u2, u3)
            cx, cy, cz = cross(q[3], q[4], q[5], q[6], q[7], q[8])
        # local -> node: cof(P) c = det(P) P^-T c, P^-1 being the stored inverse
        m = o_pinv + 12 * p
        det_inv = (f64[m] * (f64[m + 5] * f64[m + 10] - f64[m + 6] * f64[m + 9])
                   - f64[m + 1] * (f64[m + 4] * f64[m + 10] - f64[m + 6] * f64[m + 8])
                   + f64[m + 2] * (f64[m + 4] * f64[m + 9] - f64[m + 5] * f64[m + 8]))
        nx, ny, nz = normal_through(f64, m, cx, cy, cz)
        sc = 1.0 / abs(det_inv)
        ox = (r00 * nx + r01 * ny + r02 * nz) * sc
        oy = (r10 * nx + r11 * ny + r12 * nz) * sc
        oz = (r20 * nx + r21 * ny + r22 * nz) * sc
        wx, wy, wz = apply_transposed(inst_inv, ox, oy, oz)
        ln = math.sqrt(wx * wx + wy * wy + wz * wz) * det_inst
        if not ln > 0.0:
            continue
        s_, t_ = octa_encode(wx, wy, wz)
        bx = min(max(np.int64(s_ * res), 0), res - 1)
        by = min(max(np.int64(t_ * res), 0), res - 1)
        out_bin[k] = by * res + bx
        out_val[k] = nf * ln / (n_s * prob)


def estimate_graph_areas(views, graph, node_area, start, start_hash, rot0, inst_inv, res, samples,
                         seed=0, exclude_stubs=True):
    """(area per bin, variance per bin) of one subtree of a graph under an instance:
    `start` (global node id), its hash and object rotation; inst_inv the instance's
    3x4 inverse. Unbiased for any proposal; samples that enter nested stubs count 0."""
    s = int(samples)
    R = int(res)
    b = np.empty(s, np.int64)
    v = np.empty(s)
    inv = np.ascontiguousarray(inst_inv, np.float64)[:3]
    det_inst = 1.0 / abs(float(np.linalg.det(inv[:, :3])))
    _area_samples(views, np.ascontiguousarray(node_area, np.float64), int(start), np.uint64(start_hash),
                  np.ascontiguousarray(rot0, np.float64), inv, det_inst, bool(exclude_stubs), R, s,
                  np.uint64(seed), b, v)
    ok = b >= 0
    area = np.bincount(b[ok], weights=v[ok], minlength=R * R).astype(np.float64)
    sq = np.bincount(b[ok], weights=v[ok] ** 2, minlength=R * R).astype(np.float64)
    var = np.maximum(sq - area * area / s, 0.0) * s / max(s - 1, 1)
    return area, var
