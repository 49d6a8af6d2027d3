"""Ambient occlusion per texel: a bake pass for game engines that mix it with their own light.

A texel's AO is the share of cosine-weighted rays from its surface, on the
side its normal faces, that leave without meeting geometry within `distance`
(Cycles' AO bake, with the world's AO distance). It is also the irradiance
that a sky of radiance 1 seen through that occlusion would give, over π: so
the pass is stored as that irradiance, E = π·AO, and the bake's usual E/π
writes AO into the image, dilation and texel areas as for light.

Points are spread over the texel's surface as the direct-light gather's are
(texel_gather.py), `points` of them, each with `rays` rays stratified over
the hemisphere, from the texel's own random stream (xored with AO_XOR): the
result does not depend on threads or machines (parallel.run(remote=True)).
Every surface occludes, whatever its material, as in Cycles.
"""
import math

import numpy as np
from numba import njit

from ..core import parallel
from ..core.jit import CORE
from ..core.sampling import cosine_hemisphere, next_float, to_world
from ..geometry.raycast import STACK_WORDS, occluded
from . import texel_gather
from .path_vertex import ray_epsilon

AO_XOR = np.uint64(0x3C6EF372FE94F82B)
DEFAULT_POINTS = 16
DEFAULT_RAYS = 16


@njit(**CORE)
def _point_ao(g, stack, p, n, distance, rays, state):
    """Unoccluded rays of `rays` (a k x k stratified cosine hemisphere about n) from p."""
    px, py, pz = p
    nx, ny, nz = n
    eps = ray_epsilon(px, py, pz)
    ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
    k = texel_gather.grid_side(rays)
    free = 0
    for r in range(rays):
        state, j1 = next_float(state)
        state, j2 = next_float(state)
        u1, u2 = texel_gather.jitter(r, k, j1, j2)
        lx, ly, lz = cosine_hemisphere(u1, u2)
        wx, wy, wz = to_world(lx, ly, lz, nx, ny, nz)
        if not occluded(g, stack, ox, oy, oz, wx, wy, wz, 0.0, distance):
            free += 1
    return state, free


@njit(cache=True, nogil=True)
def _ao_mesh(g, tx, flip, params, out, start, stop):
    """AO of mesh texels start..stop (params: points, rays, distance) into out[item]."""
    _ao_mesh_core(g, tx, flip, params, out, start, stop, np.empty(STACK_WORDS, np.int32))


@njit(**CORE)
def _ao_mesh_core(g, tx, flip, params, out, start, stop, stack):
    n_points, rays, distance = params
    k = texel_gather.grid_side(n_points)
    for it in range(start, stop):
        out[it] = 0.0
        pieces = texel_gather.mesh_texel_pieces(g, tx, it)
        if not (pieces[2] > 0.0):
            continue
        state = texel_gather.texel_stream(tx, it, AO_XOR)
        free = 0
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, px, py, pz, nx, ny, nz, _, _, _ = texel_gather.mesh_texel_sample(g, tx, pieces, u1, u2)
            if not ok:
                continue        # a point inside geometry (a closed part of the texel) sees nothing
            sg = flip[it]
            state, f = _point_ao(g, stack, (px, py, pz), (sg * nx, sg * ny, sg * nz), distance, rays, state)
            free += f
        out[it] = free / (n_points * rays)


@njit(cache=True, nogil=True)
def _ao_prim(g, tx, params, out, start, stop):
    """AO of primitive texels start..stop, weighted by the chart's area element."""
    _ao_prim_core(g, tx, params, out, start, stop, np.empty(STACK_WORDS, np.int32))


@njit(**CORE)
def _ao_prim_core(g, tx, params, out, start, stop, stack):
    n_points, rays, distance = params
    k = texel_gather.grid_side(n_points)
    for it in range(start, stop):
        state = texel_gather.texel_stream(tx, it, AO_XOR)
        acc = 0.0
        wsum = 0.0
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, jac, px, py, pz, nx, ny, nz, _, _ = texel_gather.prim_texel_sample(tx, it, u1, u2)
            if not ok:
                continue
            state, f = _point_ao(g, stack, (px, py, pz), (nx, ny, nz), distance, rays, state)
            acc += jac * f
            wsum += jac
        out[it] = acc / (wsum * rays) if wsum > 0.0 else 0.0


def texel_ao(cs, lightmap_ids, distance, points=DEFAULT_POINTS, rays=DEFAULT_RAYS, seed=0):
    """AO of the measured texels of the given instance lightmaps -> (texel ids, AO float64[K])."""
    points, rays, distance = int(points), int(rays), float(distance)
    if points < 1 or rays < 1:
        raise ValueError(f"AO points and rays must be >= 1, got {points}, {rays}")
    if not distance > 0.0:
        raise ValueError(f"AO distance must be positive, got {distance}")
    owners = texel_gather.lightmap_owners(cs)
    ids = sorted({int(lid) for lid in lightmap_ids})
    mesh, prim = texel_gather.collect_texels(cs, owners, ids, seed)
    parts = []
    tx = mesh.packed()
    if tx is not None:
        # the texel sampler's normal is the world edges' cross product, which a
        # mirroring transform turns to the back: the surface's front is det's sign
        det = np.linalg.det(cs.geometry.inst_xf[tx.inst][:, :, :3])
        flip = np.where(det >= 0.0, 1.0, -1.0)
        out = np.zeros(tx.texel.size)
        parallel.run(_ao_mesh, out.size, cs.geometry, tx, flip, (points, rays, distance), out, remote=True)
        parts.append((tx.texel, out))
    tx = prim.packed()
    if tx is not None:
        out = np.zeros(tx.texel.size)
        parallel.run(_ao_prim, out.size, cs.geometry, tx, (points, rays, distance), out, remote=True)
        parts.append((tx.texel, out))
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0)
    ids = np.concatenate([p[0] for p in parts])
    ao = np.concatenate([p[1] for p in parts])
    order = np.argsort(ids, kind="stable")
    return ids[order], ao[order]


def bake_ao(cs, lightmap_ids, distance, points=DEFAULT_POINTS, rays=DEFAULT_RAYS, seed=0):
    """The AO pass into cs.lightmaps: E = π·AO on every measured texel (the photon
    flux replaced), then finalize (dilation) -> (texel ids, AO)."""
    from .bake_gather import set_gathered
    ids, ao = texel_ao(cs, lightmap_ids, distance, points, rays, seed)
    nb = cs.lightmaps.flux.shape[1]
    cs.lightmaps.flux[:] = 0.0
    set_gathered(cs.lightmaps, (ids, np.repeat(math.pi * ao[:, None], nb, axis=1)),
                 (np.zeros(0, np.int64), np.zeros((0, nb))))
    return ids, ao
