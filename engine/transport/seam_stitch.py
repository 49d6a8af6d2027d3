"""Seam stitching: lightmap texels that meet across a UV seam agree where they meet.

A mesh edge where two charts meet (a UV seam within one object, or an edge two
objects share) is drawn twice in the lightmaps, once from each side. A real-time
engine samples each side bilinearly, mixing the chart's border texels with the
gutter texels dilation made; the two sides then read different values at the same
world point, and the edge shows as a line. The light itself agrees there (it is
evaluated at world positions), so what differs is only how the two images are
read along the edge.

Stitching (as in Sloan's and Iwanicki's seam solvers) samples every seam edge at
points along it, a few per texel, and solves in the least-squares sense for texel
values whose bilinear reads agree on both sides at every point, while each texel
stays near its baked value: a gutter texel (no surface under it) is nearly free, a
covered texel is held by its coverage. One sparse solve (conjugate gradients on
the normal equations) per colour channel, over the texels the seams touch.

`seam_jump` measures what is left: the mean relative difference between the two
sides' bilinear reads along every seam, which is what a renderer's linear texture
filter shows there.
"""
from collections import namedtuple

import numpy as np

# bilinear reads per texel of edge length (each side's; the longer decides)
SAMPLES_PER_TEXEL = 2
# how much a seam sample's disagreement weighs against one fully covered texel's change
SEAM_WEIGHT = 16.0
# the hold on a texel nothing covers (a gutter texel): small, so it follows the seam
GUTTER_HOLD = 1e-3
# endpoints closer than this share of the scene's size are the same point
WELD = 1e-6
# Only edges where the surface goes on smoothly are stitched: across a crease (a
# cube's edge, a floor meeting a wall) the light itself jumps, as the faces'
# orientations do. Faces meeting at up to this angle are smooth (a UV sphere of
# 16 segments bends by 22.5 degrees between faces).
SMOOTH_DEGREES = 30.0
# an edge drawn by more triangles than this is left alone (a fan of coincident faces)
MAX_FAN = 8

# Seam samples: bilinear reads of side A (image ia, 4 texels, weights) and of side B
Seams = namedtuple("Seams", ["edges", "ia", "ta", "wa", "ib", "tb", "wb"])


def _unit(v):
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def mesh_charts(cs, lightmap_ids):
    """Per mesh lightmap among `lightmap_ids`: (id, world triangles (n, 3, 3), its
    lightmap UVs in texels (n, 3, 2), the triangles' unit normals (n, 3)). Primitive
    and CSG lightmaps have none."""
    from .texel_gather import lightmap_owners
    g, lm = cs.geometry, cs.lightmaps
    owners = lightmap_owners(cs)
    out = []
    for lid in lightmap_ids:
        inst, _, (kind, rows) = owners[int(lid)]
        if kind != "mesh" or int(lm.tiles[lid]) != 1:
            continue
        rows = np.asarray(rows, np.int64)
        xf = np.asarray(g.inst_xf[inst], np.float64)
        p = np.asarray(g.tri_p[rows], np.float64) @ xf[:, :3].T + xf[:, 3]
        uv = np.asarray(g.tri_uv[rows], np.float64) * np.array([int(lm.width[lid]), int(lm.height[lid])])
        out.append((int(lid), p, uv, _unit(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]))))
    return out


def primitive_charts(cs, lightmap_ids):
    """Per primitive lightmap among `lightmap_ids`: (id, world triangles, UVs in
    texels, normals), as mesh_charts gives a mesh's: each face chart cut into one
    cell per texel, its corners on the texels' corners, two triangles a cell. Where
    the surface meets itself (a cylinder's side around its seam, the sphere's
    octahedral fold, a torus both ways) two cells' edges then share their world
    endpoints, which find_seams pairs as it pairs a mesh's. A triangle's normal is
    the surface's at its cell's centre (a flat cell across the sphere's octahedral
    kink can lean far from it); triangles that a chart's corner collapses are left
    out."""
    from .texel_gather import affine_compose, lightmap_owners
    from ..geometry import primitives
    g, lm = cs.geometry, cs.lightmaps
    owners = lightmap_owners(cs)
    out = []
    for lid in lightmap_ids:
        inst, _, (kind, row) = owners[int(lid)]
        if kind != "prim":
            continue
        pk, params = np.int32(g.prim_kind[row]), np.asarray(g.prim_params[row][:4], np.float64)
        wxf = affine_compose(np.asarray(g.inst_xf[inst], np.float64), np.asarray(g.prim_xf[row], np.float64))
        faces, h = int(lm.tiles[lid]), int(lm.height[lid])
        r = int(lm.width[lid]) // faces
        cof = np.linalg.inv(wxf[:, :3]).T * np.sign(np.linalg.det(wxf[:, :3]))   # normals to world
        ps, uvs, ns = [], [], []
        for f in range(faces):
            corners = np.array([[primitives.prim_point(pk, params, np.int64(f), i / r, j / h)[:3]
                                 for i in range(r + 1)] for j in range(h + 1)])
            corners = corners @ wxf[:, :3].T + wxf[:, 3]
            texel = np.stack(np.meshgrid(f * r + np.arange(r + 1.0), np.arange(h + 1.0)), axis=-1)
            # the surface's normal at each cell's centre, for both its triangles
            d = np.array([[primitives.prim_point(pk, params, np.int64(f), (i + 0.5) / r, (j + 0.5) / h)[3:9]
                           for i in range(r)] for j in range(h)]).reshape(-1, 6)
            normal = np.cross(d[:, :3], d[:, 3:]) @ cof.T
            for tri in (((0, 0), (0, 1), (1, 1)), ((0, 0), (1, 1), (1, 0))):     # (dj, di) of its corners
                ps.append(np.stack([corners[dj:dj + h, di:di + r] for dj, di in tri], axis=2).reshape(-1, 3, 3))
                uvs.append(np.stack([texel[dj:dj + h, di:di + r] for dj, di in tri], axis=2).reshape(-1, 3, 2))
                ns.append(normal)
        p, uv = np.concatenate(ps), np.concatenate(uvs)
        flat = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        n = np.concatenate(ns)
        n = np.where(np.linalg.norm(n, axis=1, keepdims=True) > 0.0, n, flat)   # an apex: the cell's own
        area = np.linalg.norm(flat, axis=1)
        keep = area > 1e-12 * max(float(area.max()), 1e-300)
        out.append((int(lid), p[keep], uv[keep], _unit(n[keep])))
    return out


def find_seams(charts, shapes):
    """The seam edges of `charts` (mesh_charts, primitive_charts) and their sample
    points -> Seams.

    Two triangles drawing the same edge (its two world endpoints, welded) make a
    seam when they lie in different lightmaps or their UVs differ there, and their
    normals are at most SMOOTH_DEGREES apart. shapes: image index of each chart ->
    (height, width)."""
    if not charts:
        return _empty()
    P = np.concatenate([c[1] for c in charts])
    UV = np.concatenate([c[2] for c in charts])
    normal = np.concatenate([c[3] for c in charts])
    img = np.concatenate([np.full(len(c[1]), k, np.int64) for k, c in enumerate(charts)])
    a, b = np.tile([0, 1, 2], len(P)), np.tile([1, 2, 0], len(P))      # each triangle's edges a -> b
    tri = np.repeat(np.arange(len(P)), 3)
    pa, pb = P[tri, a], P[tri, b]
    size = max(float(np.ptp(P.reshape(-1, 3), axis=0).max()), 1e-12)
    qa, qb = np.round(pa / (WELD * size)).astype(np.int64), np.round(pb / (WELD * size)).astype(np.int64)
    swap = _less(qb, qa)                     # orient every edge from its smaller endpoint
    lo, hi = np.where(swap[:, None], qb, qa), np.where(swap[:, None], qa, qb)
    ua, ub = UV[tri, a], UV[tri, b]
    ua, ub = np.where(swap[:, None], ub, ua), np.where(swap[:, None], ua, ub)
    key = np.ascontiguousarray(np.concatenate([lo, hi], axis=1)).view([("", np.int64)] * 6).ravel()
    order = np.argsort(key, kind="stable")
    key = key[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, key.size])
    # every pair of the triangles drawing an edge (a wall standing on the edge two
    # floor halves share makes three; the halves still pair)
    pairs = [(order[starts[counts == c] + i], order[starts[counts == c] + j])
             for c in np.unique(counts) if 2 <= c <= MAX_FAN for i in range(c) for j in range(i + 1, c)]
    if not pairs:
        return _empty()
    first = np.concatenate([f for f, _ in pairs])
    second = np.concatenate([g for _, g in pairs])
    same = ((img[tri[first]] == img[tri[second]])
            & np.all(np.abs(ua[first] - ua[second]) < 1e-4, axis=1)
            & np.all(np.abs(ub[first] - ub[second]) < 1e-4, axis=1))
    smooth = np.einsum("ij,ij->i", normal[tri[first]], normal[tri[second]]) >= np.cos(np.radians(SMOOTH_DEGREES))
    first, second = first[~same & smooth], second[~same & smooth]
    if first.size == 0:
        return _empty()
    texels = np.maximum(np.linalg.norm(ub[first] - ua[first], axis=1), np.linalg.norm(ub[second] - ua[second], axis=1))
    n = np.maximum(np.ceil(texels * SAMPLES_PER_TEXEL).astype(np.int64), 2)
    edge = np.repeat(np.arange(first.size), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)
    hw = np.array([shapes[k] for k in range(len(charts))])
    side = []
    for e in (first, second):
        u = ua[e][edge] + t[:, None] * (ub[e][edge] - ua[e][edge])
        i = img[tri[e]][edge]
        side.append((i, *_bilinear(u, hw[i])))
    (ia, ta, wa), (ib, tb, wb) = side
    return Seams(int(first.size), ia, ta, wa, ib, tb, wb)


def _less(x, y):
    """Row-wise lexicographic x < y of integer (n, 3) arrays."""
    out = np.zeros(len(x), bool)
    decided = np.zeros(len(x), bool)
    for c in range(x.shape[1]):
        lt, gt = x[:, c] < y[:, c], x[:, c] > y[:, c]
        out |= lt & ~decided
        decided |= lt | gt
    return out


def _bilinear(u, hw):
    """Bilinear read at texel coordinates u (K, 2) of images (K, (h, w)) -> (texel
    (K, 4) flat indices within each image, weights (K, 4)), as a linear texture
    filter reads with clamped edges (texel centres at +0.5)."""
    x, y = u[:, 0] - 0.5, u[:, 1] - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    h, w = hw[:, 0], hw[:, 1]
    xs = [np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1)]
    ys = [np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1)]
    texel = np.stack([(ys[j] * w + xs[i]).astype(np.int64) for j in (0, 1) for i in (0, 1)], axis=1)
    weight = np.stack([(fx if i else 1 - fx) * (fy if j else 1 - fy) for j in (0, 1) for i in (0, 1)], axis=1)
    return texel, weight


def _empty():
    z = np.zeros((0, 4))
    return Seams(0, np.zeros(0, np.int64), z.astype(np.int64), z, np.zeros(0, np.int64), z.astype(np.int64), z)


def _reads(seams, images, channels):
    """Both sides' bilinear reads at every seam sample -> (K, C), (K, C)."""
    flat = [im.reshape(-1, im.shape[-1]) for im in images]
    out = []
    for i, t, w in ((seams.ia, seams.ta, seams.wa), (seams.ib, seams.tb, seams.wb)):
        v = np.zeros((i.size, len(channels)))
        for k in np.unique(i):
            sel = i == k
            v[sel] = np.einsum("kj,kjc->kc", w[sel], flat[k][t[sel]][..., channels])
        out.append(v)
    return out


def seam_jump(seams, images, channels=(0, 1, 2)):
    """The two sides' bilinear reads along every seam: mean |A - B| over the mean
    of A and B, over every sample and channel -> (mean relative jump, its 95th percentile)."""
    if seams.edges == 0:
        return 0.0, 0.0
    A, B = _reads(seams, images, list(channels))
    scale = max(float(np.mean(0.5 * (A + B))), 1e-12)
    rel = np.abs(A - B).mean(axis=1) / scale
    return float(rel.mean()), float(np.percentile(rel, 95))


def stitch(seams, images, holds, channels=(0, 1, 2)):
    """Texel values of `images` (float arrays (h, w, C), changed in place) whose
    bilinear reads agree across `seams`; holds: per image (h, w), how firmly each
    texel keeps its value (its coverage), GUTTER_HOLD at least -> texels changed."""
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import cg
    if seams.edges == 0:
        return 0
    sizes = np.array([im.shape[0] * im.shape[1] for im in images], np.int64)
    base = np.r_[0, np.cumsum(sizes)[:-1]]
    ga, gb = base[seams.ia][:, None] + seams.ta, base[seams.ib][:, None] + seams.tb
    used, local = np.unique(np.concatenate([ga.ravel(), gb.ravel()]), return_inverse=True)
    la, lb = local[:ga.size].reshape(ga.shape), local[ga.size:].reshape(gb.shape)
    k = np.arange(ga.shape[0])
    rows = np.concatenate([np.repeat(k, 4), np.repeat(k, 4)])
    A = coo_matrix((np.concatenate([seams.wa.ravel(), -seams.wb.ravel()]),
                    (rows, np.concatenate([la.ravel(), lb.ravel()]))), shape=(k.size, used.size)).tocsr()
    hold = np.maximum(np.concatenate([np.asarray(h, np.float64).ravel() for h in holds])[used], GUTTER_HOLD)
    M = (SEAM_WEIGHT * (A.T @ A) + diags(hold)).tocsr()
    img_of = np.searchsorted(base, used, side="right") - 1
    at = used - base[img_of]
    changed = 0
    for c in channels:
        x0 = np.empty(used.size)
        for i in np.unique(img_of):
            sel = img_of == i
            x0[sel] = images[i].reshape(-1, images[i].shape[-1])[at[sel], c]
        x, info = cg(M, hold * x0, x0=x0, rtol=1e-10, maxiter=2000)
        if info < 0:
            continue
        for i in np.unique(img_of):
            sel = img_of == i
            flat = images[i].reshape(-1, images[i].shape[-1])
            flat[at[sel], c] = x[sel]
        changed = max(changed, int(np.count_nonzero(np.abs(x - x0) > 1e-7 * max(np.abs(x0).max(), 1e-12))))
    return changed
