"""Baking an exact CSG solid into one atlas (thesis 5.2 applied to bakes; no bpy).

A CSG solid's light lives in the lightmaps of its leaves (engine/geometry/csg.py): a
primitive leaf with F faces owns F tiles of R×R, restricted to the part of its
surface left on the solid, with sub-texel rows where a CSG boundary cuts a
texel into several visible regions. A bake wants one image per solid, so:

* `pack_atlas` places every leaf's F·R × R block on shelves of one atlas
  (texels stay square; a 1-texel gutter around each block repeats its border
  texels, so bilinear filtering at a block edge never reads a neighbour);
* `leaf_rgba` turns a leaf lightmap into pixels: RGB = E/pi, A = the visible
  fraction of the texel. A split texel shows its dominant region (largest
  visible area); a texel with no visible area has A = 0 and its dilated E;
* `direct_csg_texels` gathers the direct light of leaf texels the way
  texel_gather does for plain primitives, but only over the part of each texel
  that is on the solid (the same boundary test as csg.py's visibility
  kernel), with the solid's outward normal (flipped on subtracted leaves), and
  per region of a split texel;
* `chart_uv_error` tells whether a display mesh's UVs are the engine's chart
  layout (tile f covers U in [f/F, (f+1)/F]) of the leaf, so a bake may
  remap them into the leaf's block.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..core.affine import apply_linear, apply_point, apply_transposed, cross
from ..geometry import csg
from ..geometry import csg_trace
from ..lightmaps import lightmap
from ..shading import spectrum
from ..lightmaps import texel_areas
from ..geometry import primitives
from ..geometry.assembly import prototype_surfaces
from ..geometry.raycast import STACK_WORDS
from ..core.sampling import next_float
from ..core.jit import INLINE
from .texel_gather import (
    NO_XOR, add_normal, direct_irradiance_stratum, grid_side, jitter, light_stratum, moment_width, texel_shift,
    texel_stream)
from ..core import parallel

GUTTER = 1   # texels around each leaf block


# --------------------------------------------------------------------------------------
# Atlas layout
# --------------------------------------------------------------------------------------

def pack_atlas(sizes, gutter=GUTTER):
    """Shelf packing of (width, height) blocks -> (W, H, [(x, y) of each block's first texel]).

    Blocks go tallest first onto shelves of a strip about as wide as the
    square root of the total area, so the atlas stays roughly square.
    """
    sizes = [(int(w), int(h)) for w, h in sizes]
    if not sizes:
        return 1, 1, []
    g2 = 2 * int(gutter)
    total = sum((w + g2) * (h + g2) for w, h in sizes)
    strip = max(max(w + g2 for w, _ in sizes), int(math.ceil(math.sqrt(total))))
    order = sorted(range(len(sizes)), key=lambda i: (-sizes[i][1], -sizes[i][0], i))
    origins = [None] * len(sizes)
    x = y = shelf_h = width = 0
    for i in order:
        w, h = sizes[i][0] + g2, sizes[i][1] + g2
        if x + w > strip:
            y += shelf_h
            x = shelf_h = 0
        origins[i] = (x + gutter, y + gutter)
        x += w
        shelf_h = max(shelf_h, h)
        width = max(width, x)
    return width, y + shelf_h, origins


def blit(atlas, block, origin, gutter=GUTTER):
    """Writes `block` (h, w, 4) at `origin`; the gutter repeats the block's border RGB (A = 0)."""
    x0, y0 = origin
    h, w = block.shape[:2]
    if gutter:
        padded = np.pad(block, ((gutter, gutter), (gutter, gutter), (0, 0)), mode="edge")
        padded[:gutter, :, 3] = padded[-gutter:, :, 3] = 0.0
        padded[:, :gutter, 3] = padded[:, -gutter:, 3] = 0.0
        atlas[y0 - gutter:y0 + h + gutter, x0 - gutter:x0 + w + gutter] = padded
    else:
        atlas[y0:y0 + h, x0:x0 + w] = block


# --------------------------------------------------------------------------------------
# Leaf lightmap -> pixels
# --------------------------------------------------------------------------------------

def split_regions(lm, texel):
    """Rows of the regions of split texel `texel`: region 0 is the texel itself."""
    k = int(lm.split[texel])
    if k < 0:
        return np.array([texel], np.int64)
    n_extra = int(lm.split_cell[k].max())      # labels 0..n_comp-1 all occur
    return np.concatenate([[texel], int(lm.split_first[k]) + np.arange(n_extra)]).astype(np.int64)


def leaf_rgba(lm, lm_id, full_area, bands=None):
    """A leaf lightmap as float32 (h, w, 4): RGB = E/pi, A = visible fraction of the texel.
    bands: the spectrum.Bands of a spectral scene, whose band values go to Rec.709.

    full_area: the texels' areas before CSG (lightmap row layout), for A. A split
    texel shows its dominant region (largest visible area), unless that region
    holds no measurement (a sliver): then the texel's own, dilated, value.
    """
    sl = lightmap.texel_slice(lm, lm_id)
    w, h = int(lm.width[lm_id]), int(lm.height[lm_id])
    rows = np.arange(sl.start, sl.stop, dtype=np.int64)
    visible = lm.area[sl].copy()
    src = rows.copy()
    for j in np.flatnonzero(lm.split[sl] >= 0):
        reg = split_regions(lm, int(rows[j]))
        ra = lm.area[reg]
        visible[j] = ra.sum()
        best = reg[int(np.argmax(ra))]
        if lm.state[best] == lightmap.STATE_MEASURED:
            src[j] = best
    e = lm.irradiance[src]
    rgba = np.zeros((h * w, 4), np.float32)
    rgba[:, :3] = spectrum.as_rgb(e, bands) / math.pi
    full = np.asarray(full_area, np.float64).reshape(-1)
    cov = np.where(full > 0.0, visible / np.where(full > 0.0, full, 1.0), 0.0)
    rgba[:, 3] = np.clip(cov, 0.0, 1.0)
    return rgba.reshape(h, w, 4)


def full_primitive_areas(cs, inst, row, R):
    """World texel areas of primitive row `row` of instance `inst` as if no CSG cut it (row layout)."""
    g = cs.geometry
    kind = int(g.prim_kind[row])
    M3 = g.inst_xf[inst][:, :3] @ g.prim_xf[row][:, :3]
    a = texel_areas.primitive_texel_areas(kind, g.prim_params[row], M3, int(R))
    return lightmap.faces_to_rows(a, int(primitives.N_FACES[kind]), int(R))


# --------------------------------------------------------------------------------------
# Which lightmaps belong to which leaf
# --------------------------------------------------------------------------------------

@njit(cache=True)
def _leaf_of_shape(buf, vshape):
    leaf, _sub = csg_trace.csg_vshape_leaf(buf, csg_trace.csg_base(buf), vshape)
    return leaf


@njit(cache=True)
def _root_eps(buf, root):
    """The membership probe's step off the surface (as csg.leaf_visibility takes it)."""
    i64, _f32, _i32, f64 = buf[:4]
    cb = csg_trace.csg_base(buf)
    h = cb >> 3
    b = h + i64[h + csg.B_NODE_BOX] + 6 * root
    m = 0.0
    for j in range(3):
        m = max(m, abs(f64[b + j]), abs(f64[b + 3 + j]), f64[b + 3 + j] - f64[b + j])
    return 1e-7 * max(m, 1e-30)


def _trace(g):
    return (g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features)


def solid_leaves(cs, inst):
    """Leaf lightmaps of CSG instance `inst`: list of dicts (slot, name, lightmap, kind,
    prim row, leaf id, root) in surface-slot order; kind "prim" or "mesh"."""
    g = cs.geometry
    proto = int(g.inst_proto[inst])
    names = cs.info["surfaces"][proto]
    slots = prototype_surfaces(g)[proto]
    roots = np.flatnonzero((g.shape_kind == csg.CSG) & (g.shape_proto == proto))
    if roots.size != 1:
        raise ValueError(f"instance {inst} holds {roots.size} CSG solids, expected one")
    root = int(g.shape_index[roots[0]])
    buf = _trace(g)
    out = []
    for slot, lid in enumerate(cs.instance_lightmaps[inst]):
        kind, data = slots[slot]
        d = dict(slot=slot, name=names[slot][1], lightmap=int(lid), kind=kind, row=None,
                 leaf=None, root=root)
        if kind == "prim":
            d["row"] = int(data)
            s = np.flatnonzero((g.shape_kind == g.prim_kind[data]) & (g.shape_index == data)
                               & (g.shape_proto == proto))
            d["leaf"] = int(_leaf_of_shape(buf, np.int64(s.max())))
        out.append(d)
    return out


# --------------------------------------------------------------------------------------
# Direct light over the visible part of each texel
# --------------------------------------------------------------------------------------

@njit(cache=True)
def csg_texel_point(buf, cb, bits, split, split_first, split_cell, kind, params, leaf, root, pxf, pinv,
                    wxf, cof, eps, sgn, face, x, y, row0, inv_r, u1, u2):
    """The point of a CSG leaf texel for unit-square sample (u1, u2), if it lies on
    the solid's boundary as part of this leaf (csg._visibility_kernel's test).

    -> (ok, row, J, px, py, pz, nx, ny, nz, s, t): the texel's row (the region's
    sub-texel row in a split texel), the world area element, world point, the
    solid's outward unit normal (sgn flips it on subtracted leaves) and the
    chart coordinates."""
    S = lightmap.SPLIT_SUB
    s = (x + u1) * inv_r
    t = (y + u2) * inv_r
    r = primitives.prim_point(kind, params, face, s, t)
    cx, cy, cz = cross(r[3], r[4], r[5], r[6], r[7], r[8])
    qx, qy, qz = apply_point(pxf, r[0], r[1], r[2])
    nx, ny, nz = apply_transposed(pinv, cx, cy, cz)
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not ln > 0.0:
        return False, row0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, s, t   # crease or apex
    d = eps / ln
    a = csg_trace.point_inside(buf, cb, root, qx + d * nx, qy + d * ny, qz + d * nz, bits)
    b = csg_trace.point_inside(buf, cb, root, qx - d * nx, qy - d * ny, qz - d * nz, bits)
    if a == b or b == csg_trace.point_inside(buf, cb, root, qx - d * nx, qy - d * ny, qz - d * nz,
                                  bits, leaf, False):
        return False, row0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, s, t
    row = row0
    ks = split[row0]
    if ks >= 0:
        c = split_cell[ks, min(int(u2 * S), S - 1) * S + min(int(u1 * S), S - 1)]
        if c > 0:
            row = split_first[ks] + c - 1
    wx, wy, wz = apply_linear(cof, cx, cy, cz)
    jac = math.sqrt(wx * wx + wy * wy + wz * wz)
    if not jac > 0.0:
        return False, row, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, s, t
    px, py, pz = apply_point(wxf, r[0], r[1], r[2])
    f = sgn / jac
    return True, row, jac, px, py, pz, wx * f, wy * f, wz * f, s, t


CsgTexels = namedtuple("CsgTexels", [
    "buf",                    # the CSG trace views (csg_trace), with the solids' trees
    "split", "split_first", "split_cell",   # the lightmaps' split texels (lightmap.py)
    "lm", "lid",              # the item's lightmap within this set (per-lightmap columns), its id
    "face", "x", "y", "row",  # chart tile, cell, and the texel's row
    "key", "local",           # stream key and the texel within its lightmap
    # per lightmap of the set: the leaf primitive's kind and parameters, its leaf and
    # root in the tree, primitive and world transforms, normal cofactor, cells per
    # tile side, whether the leaf is subtracted, the solid's point-test offset
    "kind", "params", "leaf", "root", "pxf", "pinv", "wxf", "ncof", "res", "flip", "eps",
])


@njit(**INLINE)
def csg_texel_sample(tx, it, cb, bits, u1, u2):
    """csg_texel_point of item it of CsgTexels tx for unit-square sample (u1, u2);
    cb: csg_trace.csg_base(tx.buf), bits: the point test's scratch."""
    l = tx.lm[it]
    return csg_texel_point(tx.buf, cb, bits, tx.split, tx.split_first, tx.split_cell, tx.kind[l], tx.params[l],
                           tx.leaf[l], tx.root[l], tx.pxf[l], tx.pinv[l], tx.wxf[l], tx.ncof[l], tx.eps[l],
                           -1.0 if tx.flip[l] else 1.0, tx.face[it], tx.x[it], tx.y[it], tx.row[it],
                           1.0 / tx.res[l], u1, u2)


@njit(cache=True, nogil=True)
def _gather_csg(g, ls, tx, n_samples, nb, acc, wsum, start, stop):
    """acc[row] += J·E_direct and wsum[row] += J over the samples of each item's
    texel that lie on the solid's boundary as part of the item's leaf (rows of
    a split texel by the region label of the sample's cell). acc: (rows, nb), or a
    directional bake's rows (texel_gather.moment_width(nb))."""
    cb = csg_trace.csg_base(tx.buf)
    k = grid_side(n_samples)
    for it in range(start, stop):
        stack = np.empty(STACK_WORDS, np.int32)
        bits = np.empty(3 * csg.MAX_WORK + 8, np.int32)
        e = np.zeros(acc.shape[1])
        rad = np.empty(nb)
        state = texel_stream(tx, it, NO_XOR)
        state, shift = texel_shift(state, k)
        for s in range(n_samples):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = jitter(s, k, j1, j2)
            ok, row, jac, px, py, pz, nx, ny, nz, _, _ = csg_texel_sample(tx, it, cb, bits, u1, u2)
            if not ok:
                continue
            for bb in range(e.shape[0]):
                e[bb] = 0.0
            add_normal(e, nb, nx, ny, nz)
            state = direct_irradiance_stratum(g, ls, stack, (px, py, pz), (nx, ny, nz), state, e,
                                              (light_stratum(s, k, shift), k), rad, 1)
            for bb in range(e.shape[0]):
                acc[row, bb] += jac * e[bb]
            wsum[row] += jac


def csg_texel_items(cs, leaves, seed=0):
    """The texels of CSG leaves as the leaf-texel kernels take them -> CsgTexels, or
    None when no leaf has a texel on the solid. Items carry the owning lightmap
    (`lid`) and texel row of each; per-lightmap columns are indexed by `lm`."""
    from .texel_gather import affine_compose, lightmap_key
    lm = cs.lightmaps
    g = cs.geometry
    buf = _trace(g)
    items = dict(lm=[], lid=[], face=[], x=[], y=[], row=[], key=[], local=[])
    pl = dict(kind=[], params=[], leaf=[], root=[], pxf=[], pinv=[], wxf=[], ncof=[], res=[],
              flip=[], eps=[])
    cb_flip = _leaf_flips(buf)
    for inst, d in leaves:
        lid, row = d["lightmap"], d["row"]
        w, f = int(lm.width[lid]), int(lm.tiles[lid])
        r = w // f
        sl = lightmap.texel_slice(lm, lid)
        local = np.flatnonzero((lm.area[sl] > 0.0) | (lm.split[sl] >= 0)).astype(np.int64)
        if local.size == 0:
            continue
        y, x = np.divmod(local, w)
        items["lm"].append(np.full(local.size, len(pl["kind"]), np.int64))
        items["lid"].append(np.full(local.size, lid, np.int64))
        items["face"].append(x // r)
        items["x"].append(x % r)
        items["y"].append(y)
        items["row"].append(sl.start + local)
        items["key"].append(np.full(local.size, lightmap_key(seed, inst, d["slot"]), np.uint64))
        items["local"].append(local)
        pxf = np.ascontiguousarray(g.prim_xf[row])
        wxf = affine_compose(g.inst_xf[inst], pxf)
        det = float(np.linalg.det(wxf[:, :3]))
        pl["kind"].append(int(g.prim_kind[row]))
        pl["params"].append(np.asarray(g.prim_params[row][:4], np.float64))
        pl["leaf"].append(d["leaf"])
        pl["root"].append(d["root"])
        pl["pxf"].append(pxf)
        pl["pinv"].append(np.ascontiguousarray(g.prim_inv[row]))
        pl["wxf"].append(wxf)
        pl["ncof"].append(texel_areas.cofactor(wxf) * (1.0 if det >= 0.0 else -1.0))
        pl["res"].append(r)
        pl["flip"].append(int(cb_flip[d["leaf"]]))
        pl["eps"].append(float(_root_eps(buf, np.int64(d["root"]))))
    if not items["lm"]:
        return None
    cat = {k: np.ascontiguousarray(np.concatenate(v).astype(np.uint64 if k == "key" else np.int64))
           for k, v in items.items()}
    return CsgTexels(buf, lm.split, lm.split_first, lm.split_cell, kind=np.asarray(pl["kind"], np.int32),
                     params=np.stack(pl["params"]), leaf=np.asarray(pl["leaf"], np.int64),
                     root=np.asarray(pl["root"], np.int64), pxf=np.stack(pl["pxf"]), pinv=np.stack(pl["pinv"]),
                     wxf=np.stack(pl["wxf"]), ncof=np.stack(pl["ncof"]), res=np.asarray(pl["res"], np.int64),
                     flip=np.asarray(pl["flip"], np.int64), eps=np.asarray(pl["eps"], np.float64), **cat)


def direct_csg_texels(cs, leaves, samples_per_texel, seed=0, moments=False):
    """Direct irradiance of CSG leaf texels, averaged over their visible part.

    leaves: (instance, solid_leaves() entry) pairs of primitive leaves. Returns
    (texel rows int64[K], E float64[K, B]) for texel_gather.add_direct; rows
    include sub-texel rows of split texels. Sample streams are keyed like
    texel_gather's (seed, instance, slot, texel), so results are deterministic.
    Lights inside the solid are not gathered (the solid's inside is closed).
    moments: E's rows are a directional bake's (texel_gather.moment_width wide).
    """
    lm = cs.lightmaps
    nb = cs.n_bands
    width = moment_width(nb) if moments else nb
    tx = csg_texel_items(cs, leaves, seed)
    if tx is None:
        return np.zeros(0, np.int64), np.zeros((0, width))
    acc = np.zeros((lm.area.shape[0], width))
    wsum = np.zeros(lm.area.shape[0])
    parallel.run(_gather_csg, tx.lm.shape[0], cs.geometry, cs.lights, tx, int(samples_per_texel), nb, acc, wsum,
                 remote=True)
    ids = np.flatnonzero(wsum > 0.0).astype(np.int64)
    return ids, acc[ids] / wsum[ids][:, None]


@njit(cache=True)
def _leaf_flips_kernel(buf, out):
    i64, _f32, i32, _f64 = buf[:4]
    cb = csg_trace.csg_base(buf)
    h = cb >> 3
    c32 = cb >> 2
    for k in range(out.shape[0]):
        out[k] = i32[c32 + i64[h + csg.B_LEAF_FLIP] + k]


def _leaf_flips(buf):
    """leaf_flip of every leaf, read from the trace buffer's CSG blob."""
    n = _n_leaves(buf)
    out = np.zeros(n, np.int64)
    _leaf_flips_kernel(buf, out)
    return out


@njit(cache=True)
def _n_leaves(buf):
    i64 = buf[0]
    return i64[(csg_trace.csg_base(buf) >> 3) + csg.B_NLEAF]


# --------------------------------------------------------------------------------------
# Display-mesh UVs against the engine's charts
# --------------------------------------------------------------------------------------

@njit(cache=True, parallel=True)
def _chart_points(kind, params, face, u, v, out):
    for i in prange(face.shape[0]):
        r = primitives.prim_point(kind, params, face[i], u[i], v[i])
        out[i, 0] = r[0]
        out[i, 1] = r[1]
        out[i, 2] = r[2]


def chart_uv_error(kind, params, co, loop_vertex, loop_uv, poly_start, poly_total):
    """Largest distance (local units) between a display mesh's vertices and the
    engine's chart point of their `Lightmap` UV, inf when a UV leaves [0,1]².

    The face of a polygon is the tile holding its UV centroid, so corners on a
    tile edge (U = f/F) read the polygon's own chart.
    """
    kid = int(primitives.KIND_IDS[kind]) if isinstance(kind, str) else int(kind)
    F = int(primitives.N_FACES[kid])
    uv = np.asarray(loop_uv, np.float64).reshape(-1, 2)
    if uv.size == 0:
        return math.inf
    if not np.all(np.isfinite(uv)) or uv.min() < -1e-6 or uv.max() > 1.0 + 1e-6:
        return math.inf
    poly_start = np.asarray(poly_start, np.int64)
    poly_total = np.asarray(poly_total, np.int64)
    poly_of = np.repeat(np.arange(poly_start.size), poly_total)
    loops = np.concatenate([np.arange(s, s + t) for s, t in zip(poly_start, poly_total)]) \
        if poly_start.size else np.zeros(0, np.int64)
    cu = np.bincount(poly_of, uv[loops, 0], minlength=poly_start.size) / np.maximum(poly_total, 1)
    face = np.clip(np.floor(cu * F), 0, F - 1).astype(np.int64)[poly_of]
    p4 = np.zeros(4)
    pv = np.asarray(params, np.float64).reshape(-1)[:4]
    p4[:pv.size] = pv
    pts = np.zeros((loops.size, 3))
    _chart_points(np.int32(kid), p4, face, np.clip(uv[loops, 0] * F - face, 0.0, 1.0),
                  np.clip(uv[loops, 1], 0.0, 1.0), pts)
    dev = np.linalg.norm(pts - np.asarray(co, np.float64)[np.asarray(loop_vertex)[loops]], axis=1)
    return float(dev.max()) if dev.size else math.inf
