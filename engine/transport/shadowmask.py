"""Shadowmasks: per texel, how much of each of up to four lights reaches it unoccluded.

Game engines that light a scene with dynamic lights but bake their shadows
(Unity's and Godot's shadowmask, Unreal's stationary lights) read one light's
visibility per channel. A texel's visibility of a light is the share of light
samples, from points spread over the texel's surface (as the direct-light
gather's, texel_gather.py), whose shadow ray reaches the light unoccluded: 1 in
full light, 0 in umbra, between in a penumbra. The light's falloff, colour and
the receiver's cosine stay out (the engine applies them); a sample that cannot
light the point at all (outside a spot's cone, behind an area light, below a
surface that a solid closes) counts as occluded. Samples are stratified over
the light (k x k cells of its two random numbers), and each texel follows its
own random stream (xored with MASK_XOR): results do not depend on threads or
machines (parallel.run(remote=True)).
"""
import math

import numpy as np
from numba import njit

from ..core import parallel
from ..core.jit import CORE
from ..core.sampling import next_float
from ..geometry.raycast import STACK_WORDS, occluded
from ..shading.lights import sample_light
from . import texel_gather
from .path_vertex import ray_epsilon

MASK_XOR = np.uint64(0x510E527FADE682D1)
MAX_LIGHTS = 4
DEFAULT_POINTS = 16
DEFAULT_SAMPLES = 16


@njit(**CORE)
def _point_visibility(g, ls, stack, p, n, li, samples, state):
    """Light samples of light li (of `samples`, stratified) that reach p unoccluded."""
    px, py, pz = p
    nx, ny, nz = n
    eps = ray_epsilon(px, py, pz)
    k = texel_gather.grid_side(samples)
    seen = 0
    for r in range(samples):
        state, j1 = next_float(state)
        state, j2 = next_float(state)
        state, u3 = next_float(state)
        u1, u2 = texel_gather.jitter(r, k, j1, j2)
        wx, wy, wz, dist, scale, ok = sample_light(ls, g, li, px, py, pz, u1, u2, u3)
        if not ok or not (scale > 0.0):
            continue
        sg = 1.0 if wx * nx + wy * ny + wz * nz >= 0.0 else -1.0
        tmax = dist * (1.0 - 1e-6) - eps if dist < math.inf else math.inf
        if tmax > 0.0 and not occluded(g, stack, px + sg * eps * nx, py + sg * eps * ny, pz + sg * eps * nz,
                                       wx, wy, wz, 0.0, tmax):
            seen += 1
    return state, seen


@njit(cache=True, nogil=True)
def _mask_mesh(g, ls, tx, lights, params, out, start, stop):
    """Visibility of lights[j] at mesh texels start..stop into out[item, j] (params: points, samples)."""
    _mask_mesh_core(g, ls, tx, lights, params, out, start, stop, np.empty(STACK_WORDS, np.int32))


@njit(**CORE)
def _mask_mesh_core(g, ls, tx, lights, params, out, start, stop, stack):
    n_points, samples = params
    k = texel_gather.grid_side(n_points)
    for it in range(start, stop):
        for j in range(lights.shape[0]):
            out[it, j] = 0.0
        pieces = texel_gather.mesh_texel_pieces(g, tx, it)
        if not (pieces[2] > 0.0):
            continue
        state = texel_gather.texel_stream(tx, it, MASK_XOR)
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, px, py, pz, nx, ny, nz, _, _, _ = texel_gather.mesh_texel_sample(g, tx, pieces, u1, u2)
            if not ok:
                continue
            for j in range(lights.shape[0]):
                state, seen = _point_visibility(g, ls, stack, (px, py, pz), (nx, ny, nz), lights[j], samples,
                                                state)
                out[it, j] += seen
        for j in range(lights.shape[0]):
            out[it, j] /= n_points * samples


@njit(cache=True, nogil=True)
def _mask_prim(g, ls, tx, lights, params, out, start, stop):
    """Visibility at primitive texels start..stop, weighted by the chart's area element."""
    _mask_prim_core(g, ls, tx, lights, params, out, start, stop, np.empty(STACK_WORDS, np.int32))


@njit(**CORE)
def _mask_prim_core(g, ls, tx, lights, params, out, start, stop, stack):
    n_points, samples = params
    k = texel_gather.grid_side(n_points)
    for it in range(start, stop):
        for j in range(lights.shape[0]):
            out[it, j] = 0.0
        state = texel_gather.texel_stream(tx, it, MASK_XOR)
        wsum = 0.0
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, jac, px, py, pz, nx, ny, nz, _, _ = texel_gather.prim_texel_sample(tx, it, u1, u2)
            if not ok:
                continue
            for j in range(lights.shape[0]):
                state, seen = _point_visibility(g, ls, stack, (px, py, pz), (nx, ny, nz), lights[j], samples,
                                                state)
                out[it, j] += jac * seen
            wsum += jac
        for j in range(lights.shape[0]):
            out[it, j] = out[it, j] / (wsum * samples) if wsum > 0.0 else 0.0


def light_rows(scene, names):
    """The compiled light rows (cs.lights) of the scene's lights named `names`, in that
    order: compile_lights keeps the scene's lights first, in order, less the dark ones."""
    from ..core.errors import SceneError
    rows, row = {}, 0
    for light in scene.lights:
        lit = float(light.power) > 0.0 and np.any(np.asarray(light.color, np.float64) > 0.0)
        if lit:
            rows[light.name] = row
            row += 1
    if not 1 <= len(names) <= MAX_LIGHTS:
        raise SceneError(f"shadowmask: give 1 to {MAX_LIGHTS} lights, got {len(names)}")
    out = []
    for name in names:
        if name not in rows:
            known = ", ".join(sorted(rows)) or "none"
            raise SceneError(f"shadowmask light '{name}': not a light that emits in this scene (lights: {known})")
        out.append(rows[name])
    return np.asarray(out, np.int64)


def texel_visibility(cs, lightmap_ids, lights, points=DEFAULT_POINTS, samples=DEFAULT_SAMPLES, seed=0):
    """Visibility of the compiled lights `lights` (rows of cs.lights) over the measured
    texels of the given instance lightmaps -> (texel ids, V float64[K, len(lights)])."""
    lights = np.asarray(lights, np.int64)
    points, samples = int(points), int(samples)
    if points < 1 or samples < 1:
        raise ValueError(f"shadowmask points and samples must be >= 1, got {points}, {samples}")
    owners = texel_gather.lightmap_owners(cs)
    mesh, prim = texel_gather.collect_texels(cs, owners, sorted({int(lid) for lid in lightmap_ids}), seed)
    parts = []
    for tx, kernel in ((mesh.packed(), _mask_mesh), (prim.packed(), _mask_prim)):
        if tx is None:
            continue
        out = np.zeros((tx.texel.size, lights.size))
        parallel.run(kernel, tx.texel.size, cs.geometry, cs.lights, tx, lights, (points, samples), out, remote=True)
        parts.append((tx.texel, out))
    if not parts:
        return np.zeros(0, np.int64), np.zeros((0, lights.size))
    ids = np.concatenate([p[0] for p in parts])
    V = np.concatenate([p[1] for p in parts])
    order = np.argsort(ids, kind="stable")
    return ids[order], V[order]


def mask_channels(cs, ids, V):
    """The visibilities V (K, L <= 4) of texels `ids` as every lightmap row's four channels,
    each dilated into empty texels as light is (finalize), in the whole-texel means a bake
    writes (open_area.baked) -> float64 (rows, 4); channels past L are 0. cs.lightmaps is
    used for the dilation: afterwards it holds the last round's values."""
    from .bake_gather import set_gathered
    from .open_area import baked
    lm = cs.lightmaps
    nb = lm.flux.shape[1]
    rows = np.arange(lm.area.shape[0])
    out = np.zeros((rows.size, MAX_LIGHTS))
    for first in range(0, V.shape[1], nb):
        part = V[:, first:first + nb]
        E = np.zeros((ids.size, nb))
        E[:, :part.shape[1]] = math.pi * part
        lm.flux[:] = 0.0
        set_gathered(lm, (ids, E), (np.zeros(0, np.int64), np.zeros((0, nb))))
        out[:, first:first + part.shape[1]] = baked(lm, rows)[:, :part.shape[1]] / math.pi
    return out
