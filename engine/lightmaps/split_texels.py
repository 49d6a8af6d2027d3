"""Split texels (thesis 5.2): which part of each texel of a CSG leaf lies on the solid.

A CSG boundary can cut a primitive leaf's texel. Each texel is sampled on an
SPLIT_SUB × SPLIT_SUB grid of cells (one uint64 mask): a cell counts where
its surface point lies on the solid's boundary as part of this leaf
(csg_trace.point_inside, with the leaf itself forced). The visible area is the
quadrature of the covered cells; a texel whose visible cells fall apart into
several 8-connected regions gets one sub-texel per region, so light never
leaks across a wall that the solid puts inside one texel. The photon pass
records into the region under the hit (lightmap.record_index).
"""
import math
import time
from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..core.affine import apply_linear, apply_point, apply_transposed, cross
from ..geometry.csg import CSG_SCRATCH_WORDS, MAX_WORK, SC_TIES
from ..geometry.csg_trace import csg_base, evaluate_ray, point_inside
from .lightmap import SPLIT_SUB
from .texel_areas import cofactor
from ..geometry.primitives import N_FACES, prim_point, prim_surface

FULL_MASK = np.uint64(0xFFFFFFFFFFFFFFFF)


@njit(cache=True, parallel=True)
def _visibility_kernel(buf, tree, prim, grid, out, ties):
    """tree = (root, leaf) of the solid, prim = (kind, parameters, transform,
    inverse) of leaf L, grid = (faces, texels per side R, eps, span).
    out[f*R*R + y*R + x]: bit j*SUB+i set if the centre of sampling cell
    (i, j) of texel (x, y) of face f lies on the solid's boundary as part of
    leaf L = `leaf`. ties[same index]: coincident-boundary events (the ray
    kernel's tie rule, module docstring) on the ray segments (-span, span)
    through the texel's cell centres along L's normal: a ray landing on the
    cell head-on, so coplanar operand faces show up here (thesis 4.1.2); the
    short segment lets the node boxes cull every operand away from the cell.

    That is: the solid's membership differs just outside and just inside L
    (p ± eps·n), and just inside it depends on L (removing L changes it).
    The first test covers every operator, covered and subtracted parts alike;
    the second gives a face that coincides with another operand's face to the
    operand the ray kernel gives it (a ray through the face sees the same)."""
    root, leaf = tree
    kind, params, xf, inv = prim
    n_faces, R, eps, span = grid
    cb = csg_base(buf)
    S = SPLIT_SUB
    h = 1.0 / (R * S)
    for cell in prange(n_faces * R * R):
        bits = np.empty(3 * MAX_WORK + 8, np.int32)
        sc = np.zeros(CSG_SCRATCH_WORDS + 2, np.int32)
        f = cell // (R * R)
        rem = cell - f * R * R
        y = rem // R
        x = rem - y * R
        m = np.uint64(0)
        for j in range(S):
            v = (y * S + j + 0.5) * h
            for i in range(S):
                u = (x * S + i + 0.5) * h
                r = prim_point(kind, params, f, u, v)
                px, py, pz = r[0], r[1], r[2]
                # dP/du x dP/dv is outward on every chart
                lx, ly, lz = cross(r[3], r[4], r[5], r[6], r[7], r[8])
                qx, qy, qz = apply_point(xf, px, py, pz)
                nx, ny, nz = apply_transposed(inv, lx, ly, lz)
                ln = math.sqrt(nx * nx + ny * ny + nz * nz)
                if not ln > 0.0:
                    # singular chart point (apex, pole of a map): use its surface normal
                    fc, uu, vv, ax, ay, az = prim_surface(kind, params, px, py, pz)
                    nx, ny, nz = apply_transposed(inv, ax, ay, az)
                    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
                    if not ln > 0.0:
                        continue
                e = eps / ln
                evaluate_ray(buf, cb, sc, 0, root, qx, qy, qz, nx / ln, ny / ln, nz / ln, -span, span)
                a = point_inside(buf, cb, root, qx + e * nx, qy + e * ny, qz + e * nz, bits)
                b = point_inside(buf, cb, root, qx - e * nx, qy - e * ny, qz - e * nz, bits)
                if a != b and b != point_inside(buf, cb, root, qx - e * nx, qy - e * ny, qz - e * nz,
                                           bits, leaf, False):
                    m |= np.uint64(1) << np.uint64(j * S + i)
        out[cell] = m
        ties[cell] = sc[SC_TIES]


@njit(cache=True)
def _components(masks, labels, n_comp):
    """4-connected regions of the visible cells of each mask; labels[k, cell]
    is the region of every cell, invisible cells taking the region of the
    nearest visible cell (so a photon whose hit falls on an invisible sample
    cell near the cut still finds a sub-texel)."""
    S = SPLIT_SUB
    queue = np.empty(S * S, np.int64)
    dist = np.empty(S * S, np.int64)
    for k in range(masks.shape[0]):
        m = masks[k]
        for c in range(S * S):
            labels[k, c] = -1
        nc = 0
        for c0 in range(S * S):
            if (m >> np.uint64(c0)) & np.uint64(1) == 0 or labels[k, c0] >= 0:
                continue
            labels[k, c0] = nc
            qh = 0
            qt = 1
            queue[0] = c0
            while qh < qt:
                c = queue[qh]
                qh += 1
                cy = c // S
                cx = c - cy * S
                for dd in range(4):
                    nx_ = cx + (1 if dd == 0 else (-1 if dd == 1 else 0))
                    ny_ = cy + (1 if dd == 2 else (-1 if dd == 3 else 0))
                    if nx_ < 0 or nx_ >= S or ny_ < 0 or ny_ >= S:
                        continue
                    q = ny_ * S + nx_
                    if (m >> np.uint64(q)) & np.uint64(1) and labels[k, q] < 0:
                        labels[k, q] = nc
                        queue[qt] = q
                        qt += 1
            nc += 1
        n_comp[k] = nc
        # nearest-visible affiliation of the invisible cells (multi-source BFS)
        qh = 0
        qt = 0
        for c in range(S * S):
            if labels[k, c] >= 0:
                queue[qt] = c
                qt += 1
                dist[c] = 0
            else:
                dist[c] = -1
        while qh < qt:
            c = queue[qh]
            qh += 1
            cy = c // S
            cx = c - cy * S
            for dd in range(8):
                ox_ = (1, -1, 0, 0, 1, 1, -1, -1)[dd]
                oy_ = (0, 0, 1, -1, 1, -1, 1, -1)[dd]
                nx_ = cx + ox_
                ny_ = cy + oy_
                if nx_ < 0 or nx_ >= S or ny_ < 0 or ny_ >= S:
                    continue
                q = ny_ * S + nx_
                if dist[q] < 0:
                    dist[q] = dist[c] + 1
                    labels[k, q] = labels[k, c]
                    queue[qt] = q
                    qt += 1


@njit(cache=True, parallel=True)
def _cell_weights(kind, params, cof, R, texels, out):
    """World area element |cof (dP/du x dP/dv)| at each sampling-cell centre of
    the given face-major texels: the cells' share of their texel's exact area."""
    S = SPLIT_SUB
    h = 1.0 / (R * S)
    for q in prange(texels.shape[0]):
        cell = texels[q]
        f = cell // (R * R)
        rem = cell - f * R * R
        y = rem // R
        x = rem - y * R
        for j in range(S):
            for i in range(S):
                r = prim_point(kind, params, f, (x * S + i + 0.5) * h, (y * S + j + 0.5) * h)
                nx, ny, nz = cross(r[3], r[4], r[5], r[6], r[7], r[8])
                wx, wy, wz = apply_linear(cof, nx, ny, nz)
                out[q, j * S + i] = math.sqrt(wx * wx + wy * wy + wz * wz)


LeafSplit = namedtuple("LeafSplit", [
    "mask",       # uint64[F*R*R] face-major: visible sampling cells of every texel
    "mixed",      # int64[K] face-major texels with visible and removed cells
    "n_comp",     # int64[K] disjoint visible regions of each mixed texel
    "labels",     # int8[K, 64] region of each sampling cell (nearest for removed cells)
    "ties",       # int64[F*R*R] coincident-boundary events on the texel's sampling rays
])


def leaf_visibility(table_trace, root, flat, leaf, R):
    # table_trace: the trace views (i64, f32, i32, f64) and features marker
    """Sampling-grid visibility of primitive leaf `leaf` of solid `root` on an
    R×R-per-face lightmap (prototype space, so instances can share it)."""
    kind = int(flat.leaf_kind[leaf])
    nf = int(N_FACES[kind])
    box = flat.node_box[root]
    # the membership probe steps off the surface by a tiny fraction of the solid's size
    size = max(float(np.max(np.abs(box))), float(np.max(box[3:] - box[:3])), 1e-30)
    eps = 1e-7 * size
    mask = np.zeros(nf * R * R, np.uint64)
    ties = np.zeros(nf * R * R, np.int64)
    _visibility_kernel(table_trace, (int(root), int(leaf)),
                       (np.int32(kind), flat.leaf_params[leaf], flat.leaf_xf[leaf], flat.leaf_inv[leaf]),
                       (nf, int(R), eps, 1e-3 * size), mask, ties)
    mixed = np.nonzero((mask != 0) & (mask != FULL_MASK))[0].astype(np.int64)
    labels = np.empty((mixed.size, SPLIT_SUB * SPLIT_SUB), np.int8)
    n_comp = np.zeros(mixed.size, np.int64)
    _components(mask[mixed], labels, n_comp)
    return LeafSplit(mask, mixed, n_comp, labels, ties)


def visible_areas(split, kind, params, M, R, area_facemajor):
    """Texel areas restricted to the solid's surface (face-major), and the
    area of every region of each mixed texel: (area (F*R*R,), region_area list)."""
    area = np.where(split.mask == FULL_MASK, area_facemajor, 0.0)
    w = np.zeros((split.mixed.size, SPLIT_SUB * SPLIT_SUB))
    if split.mixed.size:
        _cell_weights(np.int32(kind), np.asarray(params, np.float64), cofactor(M), int(R),
                      split.mixed, w)
    bits = ((split.mask[split.mixed, None] >> np.arange(64, dtype=np.uint64)) & np.uint64(1)) == 1
    tot = w.sum(axis=1)
    tot[tot <= 0] = 1.0
    regions = []
    for q, cell in enumerate(split.mixed):
        share = area_facemajor[cell] / tot[q]
        ra = np.array([w[q][bits[q] & (split.labels[q] == c)].sum() * share
                       for c in range(int(split.n_comp[q]))])
        regions.append(ra)
        area[cell] = ra.sum()
    return area, regions


def plan_csg_lightmaps(csg_info, fills, layouts):
    """Finds the lightmaps that belong to CSG leaf primitives and their texel
    visibility. csg_info: engine/geometry/assembly.py info['csg'] (None: no CSG);
    fills/layouts: engine/compile.py's per-lightmap lists. Returns (plan,
    extra sub-texel rows needed, seconds); plan entries are (lightmap id, leaf,
    LeafSplit)."""
    if not csg_info:
        return [], 0, 0.0
    t0 = time.perf_counter()
    row_leaf = csg_info["prim_row_leaf"]
    flat = csg_info["flat"]
    cache = {}
    plan = []
    extra = 0
    for lid, (kind, data, _) in enumerate(fills):
        if kind != "prim" or int(data) not in row_leaf:
            continue
        leaf = row_leaf[int(data)]
        R = int(layouts[lid][1])
        key = (leaf, R)
        if key not in cache:
            cache[key] = leaf_visibility(csg_info["trace"], int(csg_info["leaf_root"][leaf]),
                                         flat, leaf, R)
        sp = cache[key]
        plan.append((lid, leaf, sp))
        extra += int(np.sum(np.maximum(sp.n_comp - 1, 0)))
    return plan, extra, time.perf_counter() - t0


def apply_csg_lightmaps(lm, plan, fills, flat, extra_lid):
    """Restricts the planned lightmaps' texel areas to the solid's surface and
    splits texels with several disjoint visible regions into sub-texels (rows
    of lightmap extra_lid). Returns (lm with split tables, stats dict)."""
    t0 = time.perf_counter()
    split_rows, firsts, labels = [], [], []
    n_mixed = n_removed = n_ties = n_tie_texels = 0
    next_row = int(lm.offset[extra_lid]) if extra_lid is not None else 0
    for lid, leaf, sp in plan:
        F = int(lm.tiles[lid])
        R = int(lm.height[lid])
        W = F * R
        o = int(lm.offset[lid])
        rows = lm.area[o:o + W * R]
        face_major = rows.reshape(R, F, R).transpose(1, 0, 2).reshape(-1).copy()
        kind = int(flat.leaf_kind[leaf])
        area, regions = visible_areas(sp, kind, flat.leaf_params[leaf], fills[lid][2], R,
                                      face_major)
        n_mixed += sp.mixed.size
        n_removed += int(np.sum(sp.mask == 0))
        n_ties += int(sp.ties.sum())
        n_tie_texels += int(np.count_nonzero(sp.ties))
        f, rem = np.divmod(sp.mixed, R * R)
        y, x = np.divmod(rem, R)
        texel_rows = o + y * W + f * R + x
        for q, ra in enumerate(regions):
            # region 0 stays in the texel itself, the others get sub-texel rows
            area[sp.mixed[q]] = ra[0] if ra.size else 0.0
            if ra.size > 1:
                split_rows.append(texel_rows[q])
                firsts.append(next_row)
                labels.append(sp.labels[q])
                lm.area[next_row:next_row + ra.size - 1] = ra[1:]
                lm.coverage[next_row:next_row + ra.size - 1] = 1.0
                next_row += ra.size - 1
        rows[:] = area.reshape(F, R, R).transpose(1, 0, 2).reshape(-1)
    K = len(split_rows)
    lm = lm._replace(split_first=np.array(firsts, np.int64).reshape(K),
                     split_cell=np.array(labels, np.int8).reshape(K, SPLIT_SUB * SPLIT_SUB))
    lm.split[np.array(split_rows, np.int64)] = np.arange(K, dtype=np.int32)
    stats = {"csg_boundary_texels": int(n_mixed), "csg_split_texels": K,
             "csg_sub_texels": int(next_row - (int(lm.offset[extra_lid]) if extra_lid is not None else 0)),
             "csg_removed_texels": int(n_removed),
             # coplanar operand faces: resolved by the tie rule, reported (thesis 4.1.2)
             "csg_ties": int(n_ties), "csg_tie_texels": int(n_tie_texels),
             "csg_split_bytes": int(lm.split.nbytes + lm.split_first.nbytes + lm.split_cell.nbytes),
             "csg_apply_seconds": time.perf_counter() - t0}
    return lm, stats
