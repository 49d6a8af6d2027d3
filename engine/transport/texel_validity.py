"""Texel validity: texels that lie inside geometry, found by the back faces they see.

A texel under a box standing on the floor, or behind a wall that cuts through
it, holds a surface nothing can see; whatever light or occlusion it reads
there (light leaking in through the box's inside, a box's inner darkness)
bleeds into its visible neighbours through texture filtering. As Unity's
Texel Validity does, rays from points spread over the texel (as the direct
gather's, texel_gather.py) tell: a ray from a point inside a closed object
meets that object's back faces. A texel whose share of rays meeting back
faces is above INVALID_SHARE is invalid; the bake then fills it from its
valid neighbours, as it fills texels outside the charts (`dilate_over`).
Rays leave the side the surface's normal faces; each texel follows its own
random stream (xored with VALIDITY_XOR), so results do not depend on threads
or machines (parallel.run(remote=True)).
"""
import math

import numpy as np
from numba import njit

from ..core import parallel
from ..core.jit import CORE
from ..core.sampling import cosine_hemisphere, next_float, to_world
from ..geometry.raycast import STACK_WORDS, intersect_closest
from ..lightmaps import lightmap
from . import texel_gather
from .path_vertex import ray_epsilon

VALIDITY_XOR = np.uint64(0x9B05688C2B3E6C1F)
INVALID_SHARE = 0.5
DEFAULT_POINTS = 8
DEFAULT_RAYS = 8


@njit(**CORE)
def _point_back(g, stack, p, n, rays, state):
    """Rays of `rays` (stratified cosine about n) from p whose first hit is a back face."""
    px, py, pz = p
    nx, ny, nz = n
    eps = ray_epsilon(px, py, pz)
    ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
    k = texel_gather.grid_side(rays)
    back = 0
    for r in range(rays):
        state, j1 = next_float(state)
        state, j2 = next_float(state)
        u1, u2 = texel_gather.jitter(r, k, j1, j2)
        lx, ly, lz = cosine_hemisphere(u1, u2)
        wx, wy, wz = to_world(lx, ly, lz, nx, ny, nz)
        hit, _, _, _, _, _, _, hx, hy, hz = intersect_closest(g, stack, ox, oy, oz, wx, wy, wz, 0.0, math.inf)
        if hit and wx * hx + wy * hy + wz * hz > 0.0:
            back += 1
    return state, back


@njit(cache=True, nogil=True)
def _back_mesh(g, tx, flip, params, out, start, stop):
    """Back-face share of mesh texels start..stop (params: points, rays) into out[item]."""
    _back_mesh_core(g, tx, flip, params, out, start, stop, np.empty(STACK_WORDS, np.int32))


@njit(**CORE)
def _back_mesh_core(g, tx, flip, params, out, start, stop, stack):
    n_points, rays = params
    k = texel_gather.grid_side(n_points)
    for it in range(start, stop):
        out[it] = 0.0
        pieces = texel_gather.mesh_texel_pieces(g, tx, it)
        if not (pieces[2] > 0.0):
            continue
        state = texel_gather.texel_stream(tx, it, VALIDITY_XOR)
        back = 0
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, px, py, pz, nx, ny, nz, _, _, _ = texel_gather.mesh_texel_sample(g, tx, pieces, u1, u2)
            if not ok:
                continue
            sg = flip[it]
            state, b = _point_back(g, stack, (px, py, pz), (sg * nx, sg * ny, sg * nz), rays, state)
            back += b
        out[it] = back / (n_points * rays)


@njit(cache=True, nogil=True)
def _back_prim(g, tx, params, out, start, stop):
    """Back-face share of primitive texels start..stop, weighted by the chart's area element."""
    _back_prim_core(g, tx, params, out, start, stop, np.empty(STACK_WORDS, np.int32))


@njit(**CORE)
def _back_prim_core(g, tx, params, out, start, stop, stack):
    n_points, rays = params
    k = texel_gather.grid_side(n_points)
    for it in range(start, stop):
        state = texel_gather.texel_stream(tx, it, VALIDITY_XOR)
        acc = 0.0
        wsum = 0.0
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, jac, px, py, pz, nx, ny, nz, _, _ = texel_gather.prim_texel_sample(tx, it, u1, u2)
            if not ok:
                continue
            state, b = _point_back(g, stack, (px, py, pz), (nx, ny, nz), rays, state)
            acc += jac * b
            wsum += jac
        out[it] = acc / (wsum * rays) if wsum > 0.0 else 0.0


def backface_share(cs, lightmap_ids, points=DEFAULT_POINTS, rays=DEFAULT_RAYS, seed=0):
    """Share of rays meeting back faces, per measured texel of the given instance
    lightmaps -> (texel ids, share float64[K])."""
    points, rays = int(points), int(rays)
    if points < 1 or rays < 1:
        raise ValueError(f"validity points and rays must be >= 1, got {points}, {rays}")
    owners = texel_gather.lightmap_owners(cs)
    mesh, prim = texel_gather.collect_texels(cs, owners, sorted({int(lid) for lid in lightmap_ids}), seed)
    parts = []
    tx = mesh.packed()
    if tx is not None:
        # the surface's front: the sampler's edge normal times det's sign (ambient_occlusion.py)
        det = np.linalg.det(cs.geometry.inst_xf[tx.inst][:, :, :3])
        flip = np.where(det >= 0.0, 1.0, -1.0)
        out = np.zeros(tx.texel.size)
        parallel.run(_back_mesh, out.size, cs.geometry, tx, flip, (points, rays), out, remote=True)
        parts.append((tx.texel, out))
    tx = prim.packed()
    if tx is not None:
        out = np.zeros(tx.texel.size)
        parallel.run(_back_prim, out.size, cs.geometry, tx, (points, rays), out, remote=True)
        parts.append((tx.texel, out))
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0)
    ids = np.concatenate([p[0] for p in parts])
    share = np.concatenate([p[1] for p in parts])
    order = np.argsort(ids, kind="stable")
    return ids[order], share[order]


def dilate_over(lm, rows):
    """Makes texel rows empty (no surface) and fills them, with the texels outside the
    charts, from their valid neighbours (lightmap.finalize's dilation)."""
    rows = np.asarray(rows, np.int64)
    if rows.size:
        lm.area[rows] = 0.0
        lm.open[rows] = 1.0             # a bake writes irradiance x open: the filled value whole
        lightmap.finalize(lm)
