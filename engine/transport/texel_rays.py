"""Ray queries per texel: the bake passes that ask only where rays go, not what light they bring.

Ambient occlusion (ambient_occlusion.py), shadowmasks (shadowmask.py) and texel
validity (texel_validity.py) each spread points over a texel's surface, as the
direct-light gather does (texel_gather.py), and at each point ask one question
of rays from the side the surface faces:

- OCCLUSION: the share of stratified cosine rays that meet nothing within a distance;
- VISIBILITY: per light, the share of stratified light samples whose shadow
  ray reaches the light (a sample that cannot light the point counts as
  occluded);
- BACKFACES: the share of stratified cosine rays whose first hit is a back face.

A texel's answer is the mean over its points (primitive charts: weighted by the
chart's area element); a point that falls outside the texel's surface counts
as 0. On exact CSG solids (csg_bake.py) only the points on the solid's boundary
count, weighted the same way, and a texel the boundary splits gets an answer per
region, as its light does. One kernel per surface kind answers all three, so a scene compiles it
once whichever pass it bakes. Each texel follows its own random stream, keyed
by the pass (`xor`): results do not depend on threads or machines
(parallel.run(remote=True)).
"""
import math

import numpy as np
from numba import njit

from ..core import parallel
from ..core.jit import CORE
from ..core.sampling import cosine_hemisphere, next_float, to_world
from ..geometry import csg, csg_trace
from ..geometry.raycast import STACK_WORDS, intersect_closest, occluded
from ..shading.lights import sample_light
from . import texel_gather
from .csg_bake import csg_texel_items, csg_texel_sample
from .path_vertex import ray_epsilon

OCCLUSION, VISIBILITY, BACKFACES = 0, 1, 2


@njit(**CORE)
def _cosine_ray(nx, ny, nz, r, k, state):
    state, j1 = next_float(state)
    state, j2 = next_float(state)
    u1, u2 = texel_gather.jitter(r, k, j1, j2)
    lx, ly, lz = cosine_hemisphere(u1, u2)
    wx, wy, wz = to_world(lx, ly, lz, nx, ny, nz)
    return state, wx, wy, wz


@njit(**CORE)
def _point_query(g, ls, stack, query, p, n, state, acc):
    """query = (kind, rays, distance, lights, points): this point's answers added into acc."""
    kind, rays, distance, lights, _ = query
    px, py, pz = p
    nx, ny, nz = n
    eps = ray_epsilon(px, py, pz)
    ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
    k = texel_gather.grid_side(rays)
    if kind == VISIBILITY:
        for j in range(lights.shape[0]):
            seen = 0
            for r in range(rays):
                state, j1 = next_float(state)
                state, j2 = next_float(state)
                state, u3 = next_float(state)
                u1, u2 = texel_gather.jitter(r, k, j1, j2)
                wx, wy, wz, dist, scale, ok = sample_light(ls, g, lights[j], px, py, pz, u1, u2, u3)
                if not ok or not (scale > 0.0):
                    continue
                sg = 1.0 if wx * nx + wy * ny + wz * nz >= 0.0 else -1.0
                tmax = dist * (1.0 - 1e-6) - eps if dist < math.inf else math.inf
                if tmax > 0.0 and not occluded(g, stack, px + sg * eps * nx, py + sg * eps * ny,
                                               pz + sg * eps * nz, wx, wy, wz, 0.0, tmax):
                    seen += 1
            acc[j] += seen / rays
        return state
    count = 0
    for r in range(rays):
        state, wx, wy, wz = _cosine_ray(nx, ny, nz, r, k, state)
        if kind == OCCLUSION:
            if not occluded(g, stack, ox, oy, oz, wx, wy, wz, 0.0, distance):
                count += 1
        else:
            hit, _, _, _, _, _, _, hx, hy, hz = intersect_closest(g, stack, ox, oy, oz, wx, wy, wz, 0.0, math.inf)
            if hit and wx * hx + wy * hy + wz * hz > 0.0:
                count += 1
    acc[0] += count / rays
    return state


@njit(cache=True, nogil=True)
def _mesh(g, ls, tx, flip, query, xor, out, start, stop):
    """Mesh texels start..stop: the block's scratch, then the core."""
    _mesh_core(g, ls, tx, flip, query, xor, out, start, stop, np.empty(STACK_WORDS, np.int32),
               np.empty(out.shape[1]))


@njit(**CORE)
def _mesh_core(g, ls, tx, flip, query, xor, out, start, stop, stack, acc):
    n_points = query[4]
    k = texel_gather.grid_side(n_points)
    for it in range(start, stop):
        for c in range(acc.shape[0]):
            acc[c] = 0.0
        pieces = texel_gather.mesh_texel_pieces(g, tx, it)
        if pieces[2] > 0.0:
            state = texel_gather.texel_stream(tx, it, xor)
            for s in range(n_points):
                state, j1 = next_float(state)
                state, j2 = next_float(state)
                u1, u2 = texel_gather.jitter(s, k, j1, j2)
                ok, px, py, pz, nx, ny, nz, _, _, _ = texel_gather.mesh_texel_sample(g, tx, pieces, u1, u2)
                if ok:
                    sg = flip[it]
                    state = _point_query(g, ls, stack, query, (px, py, pz), (sg * nx, sg * ny, sg * nz), state, acc)
        for c in range(acc.shape[0]):
            out[it, c] = acc[c] / n_points


@njit(cache=True, nogil=True)
def _prim(g, ls, tx, query, xor, out, start, stop):
    """Primitive texels start..stop: the block's scratch, then the core."""
    _prim_core(g, ls, tx, query, xor, out, start, stop, np.empty(STACK_WORDS, np.int32),
               np.empty((2, out.shape[1])))


@njit(**CORE)
def _prim_core(g, ls, tx, query, xor, out, start, stop, stack, scratch):
    n_points = query[4]
    k = texel_gather.grid_side(n_points)
    acc, point = scratch[0], scratch[1]
    for it in range(start, stop):
        for c in range(acc.shape[0]):
            acc[c] = 0.0
        state = texel_gather.texel_stream(tx, it, xor)
        wsum = 0.0
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, jac, px, py, pz, nx, ny, nz, _, _ = texel_gather.prim_texel_sample(tx, it, u1, u2)
            if not ok:
                continue
            for c in range(point.shape[0]):
                point[c] = 0.0
            state = _point_query(g, ls, stack, query, (px, py, pz), (nx, ny, nz), state, point)
            for c in range(acc.shape[0]):
                acc[c] += jac * point[c]
            wsum += jac
        for c in range(acc.shape[0]):
            out[it, c] = acc[c] / wsum if wsum > 0.0 else 0.0


@njit(cache=True, nogil=True)
def _csg(g, ls, tx, query, xor, acc, wsum, start, stop):
    """CSG leaf texels (csg_bake.CsgTexels) start..stop: acc[row] += J·answers and
    wsum[row] += J over the points on the solid's boundary (a split texel's by the
    region of the point's cell). An item's rows are its own: blocks never share one."""
    cb = csg_trace.csg_base(tx.buf)
    n_points = query[4]
    k = texel_gather.grid_side(n_points)
    stack = np.empty(STACK_WORDS, np.int32)
    bits = np.empty(3 * csg.MAX_WORK + 8, np.int32)
    point = np.empty(acc.shape[1])
    for it in range(start, stop):
        state = texel_gather.texel_stream(tx, it, xor)
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, row, jac, px, py, pz, nx, ny, nz, _, _ = csg_texel_sample(tx, it, cb, bits, u1, u2)
            if not ok:
                continue
            for c in range(point.shape[0]):
                point[c] = 0.0
            state = _point_query(g, ls, stack, query, (px, py, pz), (nx, ny, nz), state, point)
            for c in range(point.shape[0]):
                acc[row, c] += jac * point[c]
            wsum[row] += jac


def per_texel(cs, lightmap_ids, kind, *, points, rays, xor, seed=0, distance=math.inf, lights=None, csg_leaves=()):
    """The answers of query `kind` over the measured texels of the given instance lightmaps
    and CSG leaves ((instance, csg_bake.solid_leaves entry) pairs) -> (texel ids,
    float64[K, channels]): one channel, or one per light for VISIBILITY."""
    points, rays = int(points), int(rays)
    if points < 1 or rays < 1:
        raise ValueError(f"points and rays per texel must be >= 1, got {points}, {rays}")
    lights = np.zeros(0, np.int64) if lights is None else np.asarray(lights, np.int64)
    channels = lights.size if kind == VISIBILITY else 1
    query = (int(kind), rays, float(distance), lights, points)
    owners = texel_gather.lightmap_owners(cs)
    mesh, prim = texel_gather.collect_texels(cs, owners, sorted({int(lid) for lid in lightmap_ids}), seed)
    parts = []
    tx = mesh.packed()
    if tx is not None:
        # the sampler's normal is the world edges' cross product, which a mirroring
        # transform turns to the back: the surface's front is det's sign
        det = np.linalg.det(cs.geometry.inst_xf[tx.inst][:, :, :3])
        flip = np.where(det >= 0.0, 1.0, -1.0)
        out = np.zeros((tx.texel.size, channels))
        parallel.run(_mesh, out.shape[0], cs.geometry, cs.lights, tx, flip, query, np.uint64(xor), out,
                     remote=True)
        parts.append((tx.texel, out))
    tx = prim.packed()
    if tx is not None:
        out = np.zeros((tx.texel.size, channels))
        parallel.run(_prim, out.shape[0], cs.geometry, cs.lights, tx, query, np.uint64(xor), out, remote=True)
        parts.append((tx.texel, out))
    tx = csg_texel_items(cs, list(csg_leaves), seed) if csg_leaves else None
    if tx is not None:
        rows = cs.lightmaps.area.shape[0]
        acc, wsum = np.zeros((rows, channels)), np.zeros(rows)
        parallel.run(_csg, tx.lm.shape[0], cs.geometry, cs.lights, tx, query, np.uint64(xor), acc, wsum,
                     remote=True)
        ids = np.flatnonzero(wsum > 0.0).astype(np.int64)
        parts.append((ids, acc[ids] / wsum[ids][:, None]))
    return texel_gather.by_texel(parts, channels)
