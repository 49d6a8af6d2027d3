"""Direct light per texel for baking (thesis 3.5.2 / 8.2 applied to lightmaps).

A bake stores E = E_direct + E_indirect per texel. Photons carry only the
indirect part (trace_photons(record_direct=False)); the direct part is
gathered here by sampling the lights with shadow rays (direct_irradiance below),
which removes the photon noise of the brightest component.

Per texel the gathered value is the direct irradiance *averaged over the
surface that maps into the texel*, i.e. what flux / area of infinitely many
first-hit photons would give, so both parts mean the same thing:

* mesh atlas: points uniform by world area over the texel's pieces (UV
  triangles clipped to the texel, lightmap.triangle_texel_pieces): a piece in
  proportion to its world area, a fan triangle of it in proportion to area,
  then a uniform point in that triangle (UV -> world is affine per triangle);
* primitive: (u, v) uniform in the texel's chart cell, weighted by the world
  area element J = |M dp/du x M dp/dv| and normalised by the sum of weights
  (ratio estimator: exact for constant E, no quadrature mismatch).

Samples of a texel are jittered on a k x k grid (k = floor(sqrt(n)); the rest
are plain uniform) and use the counter-based RNG keyed by (seed, instance,
surface slot, texel within its lightmap): results are deterministic and do not
depend on which other lightmaps a scene allocates.

Sides: photons reaching a surface from either side add into one texel, so the
direct term sums both sides (n and -n) on open surfaces (mesh triangles, disks,
quads). A closed solid's inside is lit only by a light inside it: its inner
side is gathered only when some light may lie inside (see `_needs_inner_side`).

Convention (`add_direct`): the direct irradiance is added to the photon
lightmap as flux E_direct * area of each measured texel, then the lightmap is
finalize()d again, so `irradiance` = direct + indirect with the usual dilation
into empty texels (bilinear lookups and image borders behave as before).
`hits` and `flux_sq` keep describing the photons only.
"""
import math
import time
from collections import namedtuple

import numpy as np
from numba import njit

from ..core.affine import apply_linear, apply_point, cross
from ..core.jit import CORE, INLINE
from ..lightmaps import lightmap
from ..lightmaps import texel_areas
from ..geometry import primitives
from ..shading.lights import (
    AREA, EMISSIVE, ENVIRONMENT, POINT, SPOT, light_sample_count, pick_light, sample_environment_diffuse,
    sample_light_radiance)
from .path_vertex import ray_epsilon
from ..geometry.assembly import prototype_surfaces
from ..geometry.raycast import STACK_WORDS, occluded
from ..core.sampling import next_float, stream_state
from ..core import parallel

DEFAULT_SAMPLES = 16
NO_XOR = np.uint64(0)      # texel_stream of the direct light: the lightmap's key itself


# --------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------

@njit(cache=True)
def direct_irradiance(g, ls, stack, p, n, state, out):
    """Adds the direct irradiance at p (normal n facing the viewer) into out[bands]
    (direct_irradiance_stratum with no stratum, one side)."""
    return direct_irradiance_stratum(g, ls, stack, p, n, state, out, (-1, 0), np.empty(out.shape[0]), 1)


@njit(**CORE)
def direct_irradiance_at(g, ls, stack, p, n, state, out, rad):
    """direct_irradiance without allocating (rad[bands]: scratch), compiled once
    as a function of its own: what a gather ray's landing point calls."""
    return direct_irradiance_stratum(g, ls, stack, p, n, state, out, (-1, 0), rad, 1)


# A texel whose direct-light samples disagree (a shadow's edge or a spot's rim
# crosses it, where a few dozen samples leave the most error) is sampled again,
# REFINE_FACTOR times as many, and only that second batch counts: the choice to
# refine then does not bias what is kept. Disagree: the samples' values have a
# coefficient of variation above REFINE_SPREAD.
REFINE_FACTOR = 4
REFINE_SPREAD = 0.25


@njit(cache=True, inline="always")
def _spread(mean, mean_sq):
    return mean > 0.0 and mean_sq - mean * mean > (REFINE_SPREAD * mean) ** 2


@njit(cache=True, inline="always")
def texel_shift(state, k):
    """(state, the texel's random shift of its light strata: see light_stratum)."""
    state, us = next_float(state)
    return state, min(int(us * k * k), k * k - 1)


# Sample s of a texel takes light stratum (37 s + shift) mod k², the shift drawn
# once per texel: every sample keeps its own light stratum (the texel's samples
# cover the light evenly), the strata are not tied to the position strata of the
# same k x k grid, and the random shift makes each sample's light stratum
# uniform, so the pairing stays unbiased (a fixed one would not be).
_STRATUM_SHUFFLE = 37


@njit(cache=True, inline="always")
def light_stratum(s, k, shift):
    """Light stratum of sample s of a texel's k x k grid (-1 past k², none)."""
    if s >= k * k:
        return -1
    return (s * _STRATUM_SHUFFLE + shift) % (k * k)


@njit(**INLINE)
def direct_irradiance_stratum(g, ls, stack, p, n, state, out, strata, rad, sides):
    """Adds the direct irradiance at p into out[bands]: of the side facing n
    (sides 1), or of both sides summed (sides 2: an open surface, whose photons
    from either side meet in one texel); rad[bands]: scratch. Inlined into the
    per-texel kernels, so no sample pays for a call that passes the scene's tuples.

    With few lights every light gets one sample; with many, four are drawn in
    proportion to power (unbiased either way). A light's sample does not depend
    on the receiver's normal, so one sample serves both sides: it lights the side
    it falls on, with |cos|, for one shadow ray. An environment map is sampled by
    MIS of the map and the receiver's cosine (lights.sample_environment_diffuse),
    so it takes a sample per side. The radiance comes per band; every light
    other than a map gives exactly the numbers of sample_light. With stratum >= 0
    (light_stratum of the sample), the light's two random numbers are jittered
    in that cell of a k x k grid (strata = (stratum, k)), so a texel's samples
    cover an area light, a sphere, a sun's disc or a map's CDF evenly: its soft
    shadows and a window's bright patch are hit a near-fixed number of times,
    not a binomial one.
    """
    px, py, pz = p
    nx, ny, nz = n
    stratum, k = strata
    n_lights = ls.kind.shape[0]
    if n_lights == 0:
        return state
    eps = ray_epsilon(px, py, pz)
    n_samples = light_sample_count(n_lights)
    for j in range(n_samples):
        state, li, w_sel = pick_light(ls, j, n_samples, state)
        if ls.kind[li] == ENVIRONMENT and not ls.env_constant:
            for side in range(sides):
                sg = 1.0 - 2.0 * side
                state, u1 = next_float(state)
                state, u2 = next_float(state)
                if stratum >= 0:
                    u1, u2 = jitter(stratum, k, u1, u2)
                wx, wy, wz, scale, ok = sample_environment_diffuse(ls, li, sg * nx, sg * ny, sg * nz,
                                                                   u1, u2, rad)
                if ok:
                    _add_unshadowed(g, stack, px, py, pz, sg * nx, sg * ny, sg * nz, eps, wx, wy, wz,
                                    math.inf, scale * w_sel, rad, out, sg)
            continue
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        state, u3 = next_float(state)
        if stratum >= 0:
            u1, u2 = jitter(stratum, k, u1, u2)
        wx, wy, wz, dist, scale, ok = sample_light_radiance(ls, g, li, px, py, pz, u1, u2, u3, rad)
        if not ok:
            continue
        sg = 1.0
        if sides == 2 and wx * nx + wy * ny + wz * nz < 0.0:
            sg = -1.0
        _add_unshadowed(g, stack, px, py, pz, sg * nx, sg * ny, sg * nz, eps, wx, wy, wz, dist,
                        scale * w_sel, rad, out, sg)
    return state


@njit(**INLINE)
def _add_unshadowed(g, stack, px, py, pz, nx, ny, nz, eps, wx, wy, wz, dist, scale, rad, out, sg):
    """out += rad · cos · scale when direction w reaches distance dist from p
    (offset along n, the lit side) unoccluded and above that side. An `out`
    longer than rad (a directional bake's row) also gets the light's moments
    (add_moment); light on the back (sg -1) of an open surface, which its texel
    sums with the front's, as if from the mirrored direction in front."""
    cos_r = wx * nx + wy * ny + wz * nz
    if cos_r <= 0.0:
        return
    tmax = dist * (1.0 - 1e-6) - eps if dist < math.inf else math.inf
    if tmax <= 0.0 or occluded(g, stack, px + eps * nx, py + eps * ny, pz + eps * nz, wx, wy, wz, 0.0, tmax):
        return
    c = cos_r * scale
    nb = rad.shape[0]
    for b in range(nb):
        out[b] += rad[b] * c
    if out.shape[0] > nb:
        if sg < 0.0:
            wx, wy, wz = wx - 2.0 * cos_r * nx, wy - 2.0 * cos_r * ny, wz - 2.0 * cos_r * nz
        add_moment(out, nb, rad, c, wx, wy, wz)


@njit(cache=True, inline="always")
def grid_side(n):
    k = int(math.sqrt(n))
    while (k + 1) * (k + 1) <= n:
        k += 1
    while k * k > n:
        k -= 1
    return k


@njit(cache=True, inline="always")
def jitter(s, k, j1, j2):
    """Sample s of a texel: jittered k x k grid, then plain uniform beyond k²."""
    if s < k * k:
        return (s % k + j1) / k, (s // k + j2) / k
    return j1, j2


@njit(**CORE)
def texel_point_on_triangles(tri_p, xf, ptri, parea, pnv, pb, p0, p1, total, u1, u2):
    # Piece by world area; u1 is rescaled inside the chosen interval so the
    # jitter keeps stratifying what follows.
    target = u1 * total
    p = p0
    acc = 0.0
    while p < p1 - 1 and acc + parea[p] <= target:
        acc += parea[p]
        p += 1
    u1 = min(max((target - acc) / parea[p], 0.0), 1.0) if parea[p] > 0.0 else 0.5
    # Fan triangle (0, i, i+1) of the clipped polygon by area (affine: bary ∝ world).
    nv = pnv[p]
    ax, ay = pb[p, 0, 0], pb[p, 0, 1]
    poly = 0.0
    for i in range(1, nv - 1):
        poly += abs((pb[p, i, 0] - ax) * (pb[p, i + 1, 1] - ay)
                    - (pb[p, i + 1, 0] - ax) * (pb[p, i, 1] - ay))
    fi = 1
    if poly > 0.0:
        target = u1 * poly
        acc = 0.0
        while fi < nv - 2:
            a = abs((pb[p, fi, 0] - ax) * (pb[p, fi + 1, 1] - ay)
                    - (pb[p, fi + 1, 0] - ax) * (pb[p, fi, 1] - ay))
            if acc + a > target:
                break
            acc += a
            fi += 1
        a = abs((pb[p, fi, 0] - ax) * (pb[p, fi + 1, 1] - ay)
                - (pb[p, fi + 1, 0] - ax) * (pb[p, fi, 1] - ay))
        u1 = min(max((target - acc) / a, 0.0), 1.0) if a > 0.0 else 0.5
    # Uniform point in the triangle (A, B, C) by the square-root warp.
    su = math.sqrt(u1)
    wa = 1.0 - su
    wb = su * (1.0 - u2)
    wc = su * u2
    b1 = wa * ax + wb * pb[p, fi, 0] + wc * pb[p, fi + 1, 0]
    b2 = wa * ay + wb * pb[p, fi, 1] + wc * pb[p, fi + 1, 1]
    b0 = 1.0 - b1 - b2
    t = ptri[p]
    v = tri_p[t]
    lx = b0 * v[0, 0] + b1 * v[1, 0] + b2 * v[2, 0]
    ly = b0 * v[0, 1] + b1 * v[1, 1] + b2 * v[2, 1]
    lz = b0 * v[0, 2] + b1 * v[1, 2] + b2 * v[2, 2]
    px, py, pz = apply_point(xf, lx, ly, lz)
    e1x, e1y, e1z = v[1, 0] - v[0, 0], v[1, 1] - v[0, 1], v[1, 2] - v[0, 2]
    e2x, e2y, e2z = v[2, 0] - v[0, 0], v[2, 1] - v[0, 1], v[2, 2] - v[0, 2]
    w1x, w1y, w1z = apply_linear(xf, e1x, e1y, e1z)
    w2x, w2y, w2z = apply_linear(xf, e2x, e2y, e2z)
    nx = w1y * w2z - w1z * w2y
    ny = w1z * w2x - w1x * w2z
    nz = w1x * w2y - w1y * w2x
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if not (ln > 0.0):
        return False, px, py, pz, 0.0, 0.0, 0.0, t, b1, b2
    return True, px, py, pz, nx / ln, ny / ln, nz / ln, t, b1, b2


@njit(cache=True)
def prim_texel_point(kind, params, xf, cof, face, x, y, inv_r, u1, u2):
    """The point of primitive texel (x, y) of chart tile `face` for unit-square
    sample (u1, u2) -> (ok, J, px, py, pz, nx, ny, nz, s, t): world point, unit
    outward normal cof(M)(pu x pv) (cof sign-corrected for mirroring), the world
    area element J and the chart coordinates; ok False at a crease or apex."""
    s = (x + u1) * inv_r
    t = (y + u2) * inv_r
    r = primitives.prim_point(kind, params, face, s, t)
    cx, cy, cz = cross(r[3], r[4], r[5], r[6], r[7], r[8])
    nx, ny, nz = apply_linear(cof, cx, cy, cz)
    jac = math.sqrt(nx * nx + ny * ny + nz * nz)
    px, py, pz = apply_point(xf, r[0], r[1], r[2])
    if not (jac > 0.0):
        return False, 0.0, px, py, pz, 0.0, 0.0, 0.0, s, t
    return True, jac, px, py, pz, nx / jac, ny / jac, nz / jac, s, t


# --------------------------------------------------------------------------------------
# Texel sets: the measured texels a bake's kernels walk, as records
# --------------------------------------------------------------------------------------

MeshTexels = namedtuple("MeshTexels", [
    "texel",                  # int64[K] the texel's row in the lightmaps
    "inst", "lid", "side",    # its instance, lightmap id, lit side (+1 / -1 along / against the winding normal, 0 both)
    "key", "local",           # uint64 stream key of its lightmap, and the texel within that lightmap
    "start",                  # int64[K + 1] its UV pieces: rows start[i]..start[i+1]-1 of the piece columns
    "tri", "area", "nv", "bary",   # per piece: triangle row, world area, corners, barycentric polygon
])

PrimTexels = namedtuple("PrimTexels", [
    "texel", "lm", "lid",     # the texel's row, its lightmap within this set (per-lightmap columns), its id
    "face", "x", "y",         # chart tile and cell within the tile
    "key", "local",           # stream key and the texel within its lightmap
    # per lightmap of the set: primitive kind and parameters, world transform,
    # normal cofactor (sign-corrected for mirroring), cells per tile side, lit sides
    "kind", "params", "xf", "ncof", "res", "sides",
])


@njit(**INLINE)
def mesh_texel_pieces(g, tx, it):
    """Mesh texel it of set tx -> (first piece, end, their world area, the instance's transform)."""
    p0 = tx.start[it]
    p1 = tx.start[it + 1]
    total = 0.0
    for p in range(p0, p1):
        total += tx.area[p]
    return p0, p1, total, g.inst_xf[tx.inst[it]]


@njit(**INLINE)
def mesh_texel_sample(g, tx, pieces, u1, u2):
    """The point of a mesh texel (its pieces: mesh_texel_pieces) for unit-square
    sample (u1, u2): uniform by world area over its UV pieces.

    -> (ok, px, py, pz, nx, ny, nz, triangle row, b1, b2): world point, unit
    geometric normal from the world edges (its sign is the triangle's winding),
    barycentrics; ok False on a zero-area triangle (it has no area share).
    The core it calls takes the triangle array only (lights.py says why)."""
    p0, p1, total, xf = pieces
    return texel_point_on_triangles(g.tri_p, xf, tx.tri, tx.area, tx.nv, tx.bary, p0, p1, total, u1, u2)


@njit(**INLINE)
def prim_texel_sample(tx, it, u1, u2):
    """prim_texel_point of primitive texel it of set tx for unit-square sample (u1, u2)."""
    l = tx.lm[it]
    return prim_texel_point(tx.kind[l], tx.params[l], tx.xf[l], tx.ncof[l], tx.face[it], tx.x[it], tx.y[it],
                            1.0 / tx.res[l], u1, u2)


@njit(**INLINE)
def texel_stream(tx, it, xor):
    """The random stream of texel it (its lightmap's key xored with a pass's, and the texel)."""
    return stream_state(tx.key[it] ^ xor, tx.local[it])


# A directional bake's row per texel: its nb bands, then each band's moment (the
# directions its light comes from weighted by that band's irradiance, 3 per band),
# then the surface normal (3), all averaged over the texel's samples. A plain
# bake's row is the bands alone; the kernels tell the two apart by the row's width.
@njit(cache=True, inline="always")
def moment_width(nb):
    """The width of a directional bake's row of nb bands."""
    return 4 * nb + 3


@njit(cache=True, inline="always")
def add_moment(out, nb, e, scale, wx, wy, wz):
    """Light e[band] · scale from direction w into the moments of row `out`."""
    for b in range(nb):
        v = e[b] * scale
        out[nb + 3 * b] += v * wx
        out[nb + 3 * b + 1] += v * wy
        out[nb + 3 * b + 2] += v * wz


@njit(cache=True, inline="always")
def add_normal(e, nb, nx, ny, nz):
    """The sample's normal into a directional bake's row (nothing into a plain one)."""
    if e.shape[0] > nb:
        e[4 * nb] += nx
        e[4 * nb + 1] += ny
        e[4 * nb + 2] += nz


@njit(cache=True, nogil=True)
def _gather_mesh(g, ls, tx, n_samples, nb, out, start, stop):
    """Direct light of mesh texels start..stop: the block's scratch, then the core.
    out: (texels, nb) irradiance per band, or a directional bake's rows
    (texels, moment_width(nb))."""
    _gather_mesh_core(g, ls, tx, n_samples, out, start, stop, np.empty(STACK_WORDS, np.int32),
                      np.empty(out.shape[1]), np.empty(nb))


# The per-sample loop compiles without NRT: with it, every read of a field of the
# scene tuples is an atomic incref and decref, which two threads contend for
# (half the kernel's time, measured with perf); scratch comes from the wrapper.
@njit(**CORE)
def _gather_mesh_core(g, ls, tx, n_samples, out, start, stop, stack, e, rad):
    nb = rad.shape[0]
    for it in range(start, stop):
        for b in range(out.shape[1]):
            out[it, b] = 0.0
        pieces = mesh_texel_pieces(g, tx, it)
        if not (pieces[2] > 0.0):
            continue
        state = texel_stream(tx, it, NO_XOR)
        n = n_samples
        for batch in range(2):
            k = grid_side(n)
            state, shift = texel_shift(state, k)
            for b in range(e.shape[0]):
                e[b] = 0.0
            s1 = 0.0
            s2 = 0.0
            for s in range(n):
                state, j1 = next_float(state)
                state, j2 = next_float(state)
                u1, u2 = jitter(s, k, j1, j2)
                ok, px, py, pz, nx, ny, nz, _, _, _ = mesh_texel_sample(g, tx, pieces, u1, u2)
                if not ok:
                    continue
                add_normal(e, nb, nx, ny, nz)
                before = 0.0
                for b in range(nb):
                    before += e[b]
                # both sides: photons from either side add into the one texel
                state = direct_irradiance_stratum(g, ls, stack, (px, py, pz), (nx, ny, nz), state, e,
                                                  (light_stratum(s, k, shift), k), rad, 2)
                v = -before
                for b in range(nb):
                    v += e[b]
                s1 += v
                s2 += v * v
            inv = 1.0 / n
            for b in range(e.shape[0]):
                out[it, b] = e[b] * inv
            mean = s1 * inv
            if batch == 1 or not _spread(mean, s2 * inv):
                break
            n = n_samples * REFINE_FACTOR


@njit(cache=True, nogil=True)
def _gather_prim(g, ls, tx, n_samples, nb, out, start, stop):
    """Direct light of primitive texels start..stop: the block's scratch, then the
    core (out as _gather_mesh's)."""
    m = out.shape[1]
    _gather_prim_core(g, ls, tx, n_samples, out, start, stop, np.empty(STACK_WORDS, np.int32),
                      np.empty((2, m)), np.empty(nb))


@njit(**CORE)
def _gather_prim_core(g, ls, tx, n_samples, out, start, stop, stack, scratch, rad):
    """_gather_prim without NRT (see _gather_mesh_core)."""
    e, ew = scratch[0], scratch[1]
    k = grid_side(n_samples)
    for it in range(start, stop):
        for b in range(ew.shape[0]):
            ew[b] = 0.0
        sides = tx.sides[tx.lm[it]]
        state = texel_stream(tx, it, NO_XOR)
        state, shift = texel_shift(state, k)
        wsum = 0.0
        for s in range(n_samples):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = jitter(s, k, j1, j2)
            ok, jac, px, py, pz, nx, ny, nz, _, _ = prim_texel_sample(tx, it, u1, u2)
            if not ok:
                continue
            for b in range(e.shape[0]):
                e[b] = 0.0
            add_normal(e, rad.shape[0], nx, ny, nz)
            state = direct_irradiance_stratum(g, ls, stack, (px, py, pz), (nx, ny, nz), state, e,
                                              (light_stratum(s, k, shift), k), rad, sides)
            for b in range(e.shape[0]):
                ew[b] += jac * e[b]
            wsum += jac
        for b in range(ew.shape[0]):
            out[it, b] = ew[b] / wsum if wsum > 0.0 else 0.0


# --------------------------------------------------------------------------------------
# Python side: which texels, which surface
# --------------------------------------------------------------------------------------

def lightmap_owners(cs):
    """lightmap id -> (instance, slot, ('mesh', tri rows) | ('prim', prim row))."""
    g = cs.geometry
    surfaces = surfaces_of(cs)
    owners = {}
    for inst, ids in enumerate(cs.instance_lightmaps):
        surf = surfaces[int(g.inst_proto[inst])]
        for slot, lid in enumerate(ids):
            owners[int(lid)] = (inst, slot, surf[slot])
    return owners


def affine_compose(a, b):
    """a ∘ b for 3x4 affine maps."""
    out = np.empty((3, 4))
    out[:, :3] = a[:, :3] @ b[:, :3]
    out[:, 3] = a[:, :3] @ b[:, 3] + a[:, 3]
    return out


def _needs_inner_side(cs, kind, params, xf):
    """Whether a closed solid's inside can see a light: some light lies inside it.

    Point, spot and area lights are tested by their position; an emissive shape
    could be anywhere, so any emissive light counts (conservative: extra shadow
    rays, never missing light). Sun and environment never reach an inside.
    """
    ls = cs.lights
    lin = xf[:, :3]
    if abs(np.linalg.det(lin)) <= 0.0:
        return True
    inv = np.linalg.inv(lin)
    for li in range(ls.kind.shape[0]):
        k = int(ls.kind[li])
        if k == EMISSIVE:
            return True
        if k in (POINT, SPOT, AREA):
            q = inv @ (np.asarray(ls.pos[li], np.float64) - xf[:, 3])
            if primitives.prim_inside(kind, params, float(q[0]), float(q[1]), float(q[2])):
                return True
    return False


def lightmap_key(seed, inst, slot):
    # Keyed by instance and surface slot, not by texel offset: another allocation of
    # lightmaps (e.g. fewer recording objects) gives the same samples.
    return stream_state(np.uint64(int(seed) & 0xFFFFFFFFFFFFFFFF),
                        np.uint64((int(inst) << 20) + int(slot)))


class _MeshTexels:
    """Measured texels of mesh lightmaps with their UV pieces (CSR rows into the
    piece arrays), as _gather_mesh takes them; with each texel's lightmap id and
    the side(s) its surface is lit from (`side`: +1 / -1 along / against the
    winding normal, 0 both), which the final gather needs."""

    def __init__(self):
        self.cols = dict(texel=[], inst=[], lid=[], side=[], key=[], local=[], start=[], tri=[],
                         area=[], nv=[], bary=[])
        self.n_pieces = 0

    def add(self, inst, lid, side, key, off, local, rows, pcs):
        cnt = pcs.start[local + 1] - pcs.start[local]
        # Piece rows of the measured texels, in texel order (vectorised CSR gather).
        sel = np.arange(int(cnt.sum())) + np.repeat(pcs.start[local] - (np.cumsum(cnt) - cnt), cnt)
        c = self.cols
        c["texel"].append(off + local)
        c["inst"].append(np.full(local.size, inst, np.int64))
        c["lid"].append(np.full(local.size, lid, np.int64))
        c["side"].append(np.full(local.size, side, np.int64))
        c["key"].append(np.full(local.size, key, np.uint64))
        c["local"].append(local)
        c["start"].append(self.n_pieces + np.cumsum(cnt) - cnt)
        c["tri"].append(rows[pcs.tri[sel]])
        c["area"].append(pcs.area[sel])
        c["nv"].append(pcs.nv[sel])
        c["bary"].append(pcs.bary[sel])
        self.n_pieces += int(sel.size)

    def packed(self):
        """The columns as a MeshTexels record, 'start' with its closing entry; None when empty."""
        if not self.cols["texel"]:
            return None
        cat = {k: np.ascontiguousarray(np.concatenate(v)) for k, v in self.cols.items()}
        cat["start"] = np.append(cat["start"], self.n_pieces).astype(np.int64)
        for k in ("tri", "nv"):
            cat[k] = cat[k].astype(np.int64)
        return MeshTexels(**cat)

    def gather(self, cs, n, moments=False):
        """(texel ids, E) of the collected texels (a directional bake's rows,
        moment_width wide, with `moments`); None when there are none."""
        tx = self.packed()
        if tx is None:
            return None
        out = np.zeros((tx.texel.size, moment_width(cs.n_bands) if moments else cs.n_bands))
        parallel.run(_gather_mesh, out.shape[0], cs.geometry, cs.lights, tx, n, cs.n_bands, out, remote=True)
        return tx.texel, out


class _PrimTexels:
    """Measured texels of primitive lightmaps (chart face and cell of each) and
    the per-lightmap surface data, as _gather_prim takes them."""

    def __init__(self):
        self.cols = dict(texel=[], lm=[], lid=[], face=[], x=[], y=[], key=[], local=[])
        self.pl = dict(kind=[], params=[], xf=[], ncof=[], res=[], sides=[])

    def add(self, cs, lid, key, off, local, row, xf, w, f):
        g = cs.geometry
        pk = int(g.prim_kind[row])
        params = np.zeros(4)
        params[:] = g.prim_params[row][:4]
        wxf = affine_compose(xf, g.prim_xf[row])
        det = float(np.linalg.det(wxf[:, :3]))
        ncof = texel_areas.cofactor(wxf) * (1.0 if det >= 0.0 else -1.0)
        closed = pk not in (primitives.DISK, primitives.QUAD)
        sides = 2 if (not closed or _needs_inner_side(cs, pk, params, wxf)) else 1
        r = w // f
        y, x = np.divmod(local, w)
        c = self.cols
        c["texel"].append(off + local)
        c["lm"].append(np.full(local.size, len(self.pl["kind"]), np.int64))
        c["lid"].append(np.full(local.size, lid, np.int64))
        c["face"].append(x // r)
        c["x"].append(x % r)
        c["y"].append(y)
        c["key"].append(np.full(local.size, key, np.uint64))
        c["local"].append(local)
        for name, value in (("kind", pk), ("params", params), ("xf", wxf), ("ncof", ncof),
                            ("res", r), ("sides", sides)):
            self.pl[name].append(value)

    def packed(self):
        """The items and per-lightmap columns as a PrimTexels record; None when empty."""
        if not self.cols["texel"]:
            return None
        cat = {k: np.ascontiguousarray(np.concatenate(v)) for k, v in self.cols.items()}
        for k in ("face", "x", "y"):
            cat[k] = cat[k].astype(np.int64)
        pl = self.pl
        return PrimTexels(kind=np.asarray(pl["kind"], np.int64), params=np.stack(pl["params"]), xf=np.stack(pl["xf"]),
                          ncof=np.stack(pl["ncof"]), res=np.asarray(pl["res"], np.int64),
                          sides=np.asarray(pl["sides"], np.int64), **cat)

    def gather(self, cs, n, moments=False):
        """(texel ids, E) of the collected texels (a directional bake's rows,
        moment_width wide, with `moments`); None when there are none."""
        tx = self.packed()
        if tx is None:
            return None
        out = np.zeros((tx.texel.size, moment_width(cs.n_bands) if moments else cs.n_bands))
        parallel.run(_gather_prim, out.shape[0], cs.geometry, cs.lights, tx, n, cs.n_bands, out, remote=True)
        return tx.texel, out


def collect_texels(cs, owners, lightmap_ids, seed, with_sides=False):
    """The measured texels of the given lightmaps, split by surface type:
    -> (_MeshTexels, _PrimTexels). with_sides: find each mesh's lit sides
    (lit_sides; the final gather needs them, direct light does not)."""
    lm = cs.lightmaps
    thr = lightmap.empty_thresholds(lm)
    mesh, prim = _MeshTexels(), _PrimTexels()
    sides = {}
    for lid in lightmap_ids:
        if lid not in owners:
            raise ValueError(f"lightmap {lid} does not belong to any instance")
        inst, slot, (skind, data) = owners[lid]
        w, h, f = int(lm.width[lid]), int(lm.height[lid]), int(lm.tiles[lid])
        measured = lightmap.is_measured(lm, lid, thr[lid])
        local = np.flatnonzero(measured).astype(np.int64)
        if local.size == 0:
            continue
        key = lightmap_key(seed, inst, slot)
        off = int(lm.offset[lid])
        xf = cs.geometry.inst_xf[inst]
        if skind == "mesh":
            if inst not in sides:
                # mesh_texel_sample's normal is the world edges' cross product: det(M) times the hit normal
                det = np.linalg.det(xf[:, :3])
                sides[inst] = lit_sides(cs, inst) * (1 if det >= 0.0 else -1) if with_sides else 0
            mesh.add(inst, lid, sides[inst], key, off, local, np.asarray(data, np.int64),
                     texel_pieces(cs, lid, data, xf, w, h))
        else:
            prim.add(cs, lid, key, off, local, int(data), xf, w, f)
    return mesh, prim


def texel_pieces(cs, lid, rows, xf, w, h):
    """Lightmap lid's TexelPieces (its mesh triangles `rows` under world map xf,
    clipped to its W×H texels), made once per compiled scene: a bake's direct
    light, its gather and its irradiance cache all walk the same pieces, and on
    a dense mesh the clipping costs as much as a pass of direct light."""
    memo = cs.__dict__.setdefault("_texel_pieces", {})
    if lid not in memo:
        rows = np.asarray(rows, np.int64)
        g = cs.geometry
        area3d = texel_areas.triangle_world_areas(g.tri_p[rows], xf[:, :3])
        memo[lid] = texel_areas.triangle_texel_pieces(g.tri_uv[rows], area3d, w, h)
    return memo[lid]


def lit_sides(cs, inst):
    """Which side(s) of instance `inst`'s mesh light can reach: 0 for both (an open
    mesh), +1 / -1 for a closed one, along / against its hit normal (the world
    normal ray queries return: counter-clockwise front), 0 when a point, spot or
    area light lies inside it. Photons of
    either side meet in one texel; the final gather must not read the inside of a
    closed mesh, whose rays would see the outside's light through its own texels."""
    memo = cs.__dict__.setdefault("_lit_sides", {})
    if inst not in memo:
        memo[inst] = _lit_sides(cs, inst)
    return memo[inst]


def surfaces_of(cs):
    """geometry.assembly.prototype_surfaces of the compiled scene, made once: a Python loop
    over every shape, which the bake's texel collection would repeat per instance."""
    if "_surfaces" not in cs.__dict__:
        cs.__dict__["_surfaces"] = prototype_surfaces(cs.geometry)
    return cs.__dict__["_surfaces"]


def _lit_sides(cs, inst):
    from ..geometry.csg import SceneError, check_closed_mesh
    g = cs.geometry
    rows = [np.asarray(d, np.int64) for k, d in surfaces_of(cs)[int(g.inst_proto[inst])] if k == "mesh"]
    if not rows:
        return 0
    tri = g.tri_p[np.concatenate(rows)]
    try:
        orient = check_closed_mesh(tri.reshape(-1, 3), np.arange(3 * len(tri)).reshape(-1, 3), "mesh")
    except SceneError:
        return 0
    xf = g.inst_xf[inst]
    ls = cs.lights
    for li in range(ls.kind.shape[0]):
        if int(ls.kind[li]) in (POINT, SPOT, AREA):
            q = np.linalg.solve(xf[:, :3], np.asarray(ls.pos[li], np.float64) - xf[:, 3])
            if _inside_mesh(tri, q):
                return 0
    return int(orient)


def instance_sides(cs):
    """lit_sides of every instance, for the gather's inside test: meshes as lit_sides,
    closed primitives and CSG solids +1 (outward hit normals) unless a light lies
    inside, everything else (open or mixed shapes, L-systems) 0."""
    g = cs.geometry
    surfaces = surfaces_of(cs)
    out = np.zeros(g.inst_proto.shape[0], np.int64)
    for inst in range(out.shape[0]):
        surf = surfaces[int(g.inst_proto[inst])]
        kinds = {k for k, _ in surf}
        if kinds == {"mesh"}:
            out[inst] = lit_sides(cs, inst)
        elif kinds == {"prim"}:
            closed = True
            for _, row in surf:
                pk = int(g.prim_kind[row])
                params = np.asarray(g.prim_params[row][:4], np.float64)
                if pk in (primitives.DISK, primitives.QUAD) or _needs_inner_side(
                        cs, pk, params, affine_compose(g.inst_xf[inst], g.prim_xf[row])):
                    closed = False
            out[inst] = 1 if closed else 0
    return out


def _inside_mesh(tri, q):
    """Whether point q lies inside the closed triangle mesh `tri` (T, 3, 3): crossings
    of a ray in a generic direction (Möller–Trumbore, vectorised), counted mod 2."""
    d = np.array([1.0, 0.0123456789, 0.00987654321])
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    pv = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, pv)
    ok = np.abs(det) > 1e-300
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    tv = q - tri[:, 0]
    u = np.einsum("ij,ij->i", tv, pv) * inv
    qv = np.cross(tv, e1)
    v = (qv @ d) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    hit = ok & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > 0.0)
    return bool(np.count_nonzero(hit) % 2)


def by_texel(parts, nb):
    """The (texel ids, E) parts joined and sorted by texel id."""
    parts = [p for p in parts if p is not None]
    if not parts:
        return np.zeros(0, np.int64), np.zeros((0, nb))
    ids = np.concatenate([p[0] for p in parts])
    E = np.concatenate([p[1] for p in parts])
    order = np.argsort(ids, kind="stable")
    return ids[order], E[order]


def direct_texel_irradiance(cs, lightmap_ids=None, samples_per_texel=DEFAULT_SAMPLES, seed=0, moments=False):
    """Direct irradiance averaged over each measured texel of the given lightmaps.

    Returns (texel_ids int64[K], E float64[K, n_bands]): the global texel indices
    (those finalize() computes: area above the sliver threshold) and their
    direct irradiance in W/m² (both sides summed on open surfaces). Nothing in
    `cs` changes; `add_direct` folds the result into the lightmaps.
    lightmap_ids None: all instance lightmaps of the scene. moments: E's rows
    are a directional bake's (moment_width wide).
    """
    n = int(samples_per_texel)
    if n < 1:
        raise ValueError(f"samples_per_texel must be >= 1, got {samples_per_texel}")
    t0 = time.perf_counter()
    owners = lightmap_owners(cs)
    if lightmap_ids is None:
        # every instance's own lightmaps (not OLs or CSG sub-texel rows)
        lightmap_ids = owners.keys()
    lightmap_ids = sorted({int(l) for l in lightmap_ids})
    mesh, prim = collect_texels(cs, owners, lightmap_ids, seed)
    ids, E = by_texel([mesh.gather(cs, n, moments), prim.gather(cs, n, moments)],
                      moment_width(cs.n_bands) if moments else cs.n_bands)
    cs.timings["direct_gather"] = time.perf_counter() - t0
    return ids, E


def add_direct(lm, texel_ids, E):
    """Adds gathered direct irradiance to a photon lightmap and re-finalizes it.

    flux[j] += E[j] * area[j] (the power first-hit photons would have left there
    on average), then finalize(): irradiance = direct + indirect, dilated into
    empty texels as usual. Call after the photon pass (which finalizes too).
    """
    ids = np.asarray(texel_ids, np.int64).reshape(-1)
    # explicit band count: reshape(0, -1) of an empty result is an error
    E = np.asarray(E, np.float64).reshape(ids.size, lm.flux.shape[1])
    if ids.size:
        lm.flux[ids] += E * lm.area[ids][:, None]
    lightmap.finalize(lm)


def bake_texels(cs, lightmap_ids=None, samples_per_texel=DEFAULT_SAMPLES, seed=0):
    """direct_texel_irradiance + add_direct on the given lightmaps; returns seconds taken."""
    t0 = time.perf_counter()
    ids, E = direct_texel_irradiance(cs, lightmap_ids, samples_per_texel, seed)
    add_direct(cs.lightmaps, ids, E)
    return time.perf_counter() - t0
