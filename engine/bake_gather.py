"""Final gather for bakes: a texel's indirect light from gather rays over the photon lightmaps.

The thesis's bake is the photon lightmap itself: direct light gathered per
texel (texel_gather.py), indirect light = the texel's own photons, so every
texel shows its photons' noise. Here the indirect part moves one bounce away,
as final_gather.py does for renders: from points spread over the texel's
surface (by world area, as the direct part's), cosine rays sample the
hemisphere and read kd(q)·E(q) where they land (the photon pass recorded
total irradiance, record_direct). The texel's value is then

    E = E_direct (light samples) + E_gather (photon lightmaps one bounce away)
        + E_caustic (the texel's caustic photons: light focused by sharp
          mirrors and glass, which gather rays cannot find)

A texel gets `points` points, each `rays` gather rays per lit side, so its
indirect noise falls as 1/sqrt(points·rays). Sides: an open mesh, disk or quad
is lit from both sides (photons of both meet in its texel), a closed solid from
outside only unless a light lies inside it (texel_gather.lit_sides). Point
streams are keyed like the direct part's, xored with STREAM_XOR, so the direct
part of a bake is bit-identical with and without the gather, and results do
not depend on the thread count.
"""
import time

import numpy as np
from numba import njit, prange

from . import bsdf as BS
from . import csg as CSG
from . import lightmap as LM
from . import orientation_lightmap as OL
from . import texel_gather as TG
from .csg_bake import csg_texel_items, csg_texel_point
from .final_gather import gather_irradiance
from .raycast import STACK_WORDS
from .sampling import next_float, stream_state

STREAM_XOR = np.uint64(0x5BD1E9955BD1E995)
SCRATCH_ROWS = 7      # kd ks kt ind tp f rad of gather_irradiance


@njit(cache=True)
def point_indirect(g, ms, bt, ts, ls, lm, ol, env, isd, mode, n_rays, stack, px, py, pz, nx, ny, nz,
                   side, state, sc, pc, out):
    """Gathered indirect irradiance at a bake point into out (added): along n
    (side >= 0) and against it (side <= 0)."""
    for sgn in (1.0, -1.0):
        if side * sgn < 0.0:
            continue
        fx, fy, fz = sgn * nx, sgn * ny, sgn * nz
        state = gather_irradiance(g, ms, bt, ts, ls, lm, ol, env, isd, stack, px, py, pz, fx, fy, fz,
                                  fx, fy, fz, n_rays, mode, state, sc[0], sc[1], sc[2], pc, sc[3],
                                  sc[4], sc[5], sc[6], out)
    return state


@njit(cache=True)
def _add_caustic(lmc, lid, face, s, t, tmp, out):
    LM.lookup(lmc, lid, face, s, t, LM.MODE_CONSTANT, tmp)
    for b in range(out.shape[0]):
        out[b] += tmp[b]


@njit(cache=True, parallel=True)
def _indirect_mesh(g, ms, bt, ts, ls, lm, lmc, caustics, ol, env, isd, mode, item_inst, item_lid, item_side,
                   item_key, item_local, pstart, ptri, parea, pnv, pb, n_points, n_rays, out):
    K = out.shape[0]
    nb = out.shape[1]
    k = TG._grid_side(n_points)
    for it in prange(K):
        stack = np.empty(STACK_WORDS, np.int32)
        sc = np.empty((SCRATCH_ROWS, nb))
        pc = np.empty(BS.P_SIZE)
        e = np.zeros(nb)
        p0 = pstart[it]
        p1 = pstart[it + 1]
        total = 0.0
        for p in range(p0, p1):
            total += parea[p]
        if total > 0.0:
            xf = g.inst_xf[item_inst[it]]
            state = stream_state(item_key[it] ^ STREAM_XOR, item_local[it])
            for s in range(n_points):
                state, j1 = next_float(state)
                state, j2 = next_float(state)
                u1, u2 = TG._jitter(s, k, j1, j2)
                ok, px, py, pz, nx, ny, nz, t, b1, b2 = TG.mesh_texel_point(
                    g, xf, ptri, parea, pnv, pb, p0, p1, total, u1, u2)
                if not ok:
                    continue
                state = point_indirect(g, ms, bt, ts, ls, lm, ol, env, isd, mode, n_rays, stack, px, py, pz,
                                       nx, ny, nz, item_side[it], state, sc, pc, e)
                if caustics:
                    uv = g.tri_uv[t]
                    b0 = 1.0 - b1 - b2
                    _add_caustic(lmc, item_lid[it], 0, b0 * uv[0, 0] + b1 * uv[1, 0] + b2 * uv[2, 0],
                                 b0 * uv[0, 1] + b1 * uv[1, 1] + b2 * uv[2, 1], sc[3], e)
        for b in range(nb):
            out[it, b] = e[b] / n_points


@njit(cache=True, parallel=True)
def _indirect_prim(g, ms, bt, ts, ls, lm, lmc, caustics, ol, env, isd, mode, item_lm, item_lid, item_face,
                   item_x, item_y, item_key, item_local, lm_kind, lm_params, lm_xf, lm_ncof, lm_res,
                   lm_sides, n_points, n_rays, out):
    K = out.shape[0]
    nb = out.shape[1]
    k = TG._grid_side(n_points)
    for it in prange(K):
        stack = np.empty(STACK_WORDS, np.int32)
        sc = np.empty((SCRATCH_ROWS, nb))
        pc = np.empty(BS.P_SIZE)
        e = np.zeros(nb)
        ew = np.zeros(nb)
        l = item_lm[it]
        side = 0 if lm_sides[l] == 2 else 1
        state = stream_state(item_key[it] ^ STREAM_XOR, item_local[it])
        wsum = 0.0
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = TG._jitter(s, k, j1, j2)
            ok, jac, px, py, pz, nx, ny, nz, cs_, ct = TG.prim_texel_point(
                lm_kind[l], lm_params[l], lm_xf[l], lm_ncof[l], item_face[it], item_x[it], item_y[it],
                1.0 / lm_res[l], u1, u2)
            if not ok:
                continue
            for b in range(nb):
                e[b] = 0.0
            state = point_indirect(g, ms, bt, ts, ls, lm, ol, env, isd, mode, n_rays, stack, px, py, pz,
                                   nx, ny, nz, side, state, sc, pc, e)
            if caustics:
                _add_caustic(lmc, item_lid[it], item_face[it], cs_, ct, sc[3], e)
            for b in range(nb):
                ew[b] += jac * e[b]
            wsum += jac
        for b in range(nb):
            out[it, b] = ew[b] / wsum if wsum > 0.0 else 0.0


@njit(cache=True, parallel=True)
def _indirect_csg(g, ms, bt, ts, ls, lm, lmc, caustics, ol, env, isd, mode, buf, item_lm, item_lid, item_face,
                  item_x, item_y, item_row, item_key, item_local, lm_kind, lm_params, lm_leaf, lm_root,
                  lm_pxf, lm_pinv, lm_wxf, lm_ncof, lm_res, lm_flip, lm_eps, n_points, n_rays, acc, wsum):
    """acc[row] += J·E_indirect, wsum[row] += J, like csg_bake._gather_csg (outside only)."""
    cb = CSG.csg_base(buf)
    K = item_lm.shape[0]
    nb = acc.shape[1]
    k = TG._grid_side(n_points)
    for it in prange(K):
        stack = np.empty(STACK_WORDS, np.int32)
        bits = np.empty(3 * CSG.MAX_WORK + 8, np.int32)
        sc = np.empty((SCRATCH_ROWS, nb))
        pc = np.empty(BS.P_SIZE)
        e = np.zeros(nb)
        l = item_lm[it]
        sgn = -1.0 if lm_flip[l] else 1.0
        state = stream_state(item_key[it] ^ STREAM_XOR, item_local[it])
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = TG._jitter(s, k, j1, j2)
            ok, row, jac, px, py, pz, nx, ny, nz, cs_, ct = csg_texel_point(
                buf, cb, bits, lm.split, lm.split_first, lm.split_cell, lm_kind[l], lm_params[l],
                lm_leaf[l], lm_root[l], lm_pxf[l], lm_pinv[l], lm_wxf[l], lm_ncof[l], lm_eps[l], sgn,
                item_face[it], item_x[it], item_y[it], item_row[it], 1.0 / lm_res[l], u1, u2)
            if not ok:
                continue
            for b in range(nb):
                e[b] = 0.0
            state = point_indirect(g, ms, bt, ts, ls, lm, ol, env, isd, mode, n_rays, stack, px, py, pz,
                                   nx, ny, nz, 1, state, sc, pc, e)
            if caustics:
                _add_caustic(lmc, item_lid[it], item_face[it], cs_, ct, sc[3], e)
            for b in range(nb):
                acc[row, b] += jac * e[b]
            wsum[row] += jac


def _inputs(cs):
    """The photon-lightmap state every gather kernel reads (after a record_direct photon pass)."""
    if not getattr(cs, "lightmaps_hold_direct", False) and np.any(cs.lightmaps.flux):
        raise ValueError("a bake's final gather needs a photon pass that recorded direct light")
    ol = cs.orientation if cs.orientation is not None else OL.empty_maps(cs.geometry.inst_proto.shape[0])
    caustics = bool(getattr(cs, "caustics_traced", False)) and cs.caustics is not None
    lmc = cs.caustics if caustics else cs.lightmaps
    return (cs.geometry, cs.materials, cs.bsdf, cs.textures, cs.lights, cs.lightmaps, lmc, caustics, ol,
            cs.environment, TG.instance_sides(cs))


def gathered_indirect(cs, lightmap_ids=(), csg_leaves=(), points=TG.DEFAULT_SAMPLES, rays=4,
                      mode=LM.MODE_BILINEAR, seed=0):
    """Indirect irradiance (gather + caustics) of the measured texels of the given
    instance lightmaps and CSG leaves -> (texel ids int64[K], E float64[K, n_bands]),
    the same texels as texel_gather.direct_texel_irradiance / csg_bake.direct_csg_texels
    return. `rays` gather rays per point and lit side. Nothing in `cs` changes."""
    points, rays = int(points), int(rays)
    if points < 1 or rays < 1:
        raise ValueError(f"points and rays must be >= 1, got {points}, {rays}")
    t0 = time.perf_counter()
    fixed = _inputs(cs) + (int(mode),)
    nb = cs.n_bands
    parts = []
    ids = sorted({int(l) for l in lightmap_ids})
    if ids:
        mesh, prim = TG._collect_texels(cs, TG._lightmap_owners(cs), ids, seed, with_sides=True)
        cat = mesh.packed()
        if cat is not None:
            out = np.zeros((cat["texel"].size, nb))
            _indirect_mesh(*fixed, cat["inst"], cat["lid"], cat["side"], cat["key"], cat["local"],
                           cat["start"], cat["tri"], cat["area"], cat["nv"], cat["bary"], points, rays, out)
            parts.append((cat["texel"], out))
        got = prim.packed()
        if got is not None:
            cat, per_lm = got
            out = np.zeros((cat["texel"].size, nb))
            _indirect_prim(*fixed, cat["lm"], cat["lid"], cat["face"], cat["x"], cat["y"], cat["key"],
                           cat["local"], *per_lm, points, rays, out)
            parts.append((cat["texel"], out))
    if csg_leaves:
        got = csg_texel_items(cs, list(csg_leaves), seed)
        if got is not None:
            buf, cat, per_lm = got
            n_rows = cs.lightmaps.area.shape[0]
            acc = np.zeros((n_rows, nb))
            wsum = np.zeros(n_rows)
            _indirect_csg(*fixed, buf, cat["lm"], cat["lid"], cat["face"], cat["x"], cat["y"], cat["row"],
                          cat["key"], cat["local"], *per_lm, points, rays, acc, wsum)
            rows = np.flatnonzero(wsum > 0.0).astype(np.int64)
            parts.append((rows, acc[rows] / wsum[rows][:, None]))
    got = TG._by_texel(parts, nb)
    cs.timings["bake_gather"] = time.perf_counter() - t0
    return got


def set_gathered(lm, direct, indirect):
    """Writes E = direct + indirect (two (texel ids, E) results over the same texels)
    as the bake's lightmap: flux = E·area, the photon flux of those texels replaced,
    then finalize() (dilation into empty texels as usual)."""
    ids_d, E_d = direct
    ids_i, E_i = indirect
    nb = lm.flux.shape[1]
    ids = np.union1d(np.asarray(ids_d, np.int64), np.asarray(ids_i, np.int64))
    E = np.zeros((ids.size, nb))
    E[np.searchsorted(ids, ids_d)] += np.asarray(E_d).reshape(-1, nb)
    E[np.searchsorted(ids, ids_i)] += np.asarray(E_i).reshape(-1, nb)
    if ids.size:
        lm.flux[ids] = E * lm.area[ids][:, None]
    LM.finalize(lm)
