"""Importance emission: photons aimed at the geometry that is baked.

A light far from the objects being baked (a sun over a large terrain, a lamp
outside a courtyard) sends most photons where they light nothing the bake
reads. Lightmass aims them at an importance volume; here the volume is the
*aim sphere* around the baked objects, and every light's emission becomes a
defensive mixture: a fraction AIMED of its photons goes toward the sphere,
the rest is emitted as before, and each photon's weight p_light / p_mixture
keeps the estimate unbiased. Every direction the light emits into keeps a
density of at least (1 - AIMED) p_light, so the weights stay below
1 / (1 - AIMED).

The aimed photons spread over nested spheres, r, 2r, 4r, ... out to the one
that holds the scene, each taking an equal share: a baked object is lit indirectly by what surrounds
it, and a lit ground at distance x sends a vertical face light that falls off
only as 1/x, so each doubling of distance matters about as much as the last.
On a 1 m box on a 60 m lit ground this takes the box's noise per texel from
1.95 to 0.56 (relative, 1 M photons), 12 times fewer photons for the same
noise; a single sphere three times the box's size reached only 0.73, its far
photons few and heavy.

A sphere that holds the whole scene aims nothing, and a light inside the
sphere emits as before, so the default (every object baked, lights in the
room) traces exactly the photons it always did.
"""
import math

import numpy as np
from numba import njit

from ..core.jit import CORE, INLINE
from ..core.sampling import concentric_disk, next_float, orthonormal_basis, to_world, uniform_cone

AIMED = 0.75        # fraction of photons aimed: weights stay below 1 / (1 - AIMED) = 4
LEVELS = 12         # nested aim spheres at most (radius doubling each)
# Aim only at targets this many times smaller than the scene: in a room, what lights
# one wall indirectly is the rest of the room, which aiming at the wall would starve.
MIN_RATIO = 4.0

# base distributions a light emits by (the density the aimed photons are weighed against)
UNIFORM, COSINE, CONE = 0, 1, 2


def sphere_around(geom, instances):
    """(centre, radius) of the sphere around the world bounds of `instances`
    (engine instance ids); None when there are none."""
    instances = np.asarray(sorted(set(int(i) for i in instances)), np.int64)
    if instances.size == 0:
        return None
    roots = geom.proto_root[geom.inst_proto[instances]]
    lo, hi = geom.blas_min[roots].astype(np.float64), geom.blas_max[roots].astype(np.float64)
    corners = np.stack([np.where(np.array([(c >> k) & 1 for k in range(3)], bool), hi, lo)
                        for c in range(8)], axis=1)                     # (n, 8, 3) prototype space
    xf = geom.inst_xf[instances].astype(np.float64)                     # (n, 3, 4)
    world = np.einsum("nij,nkj->nki", xf[:, :, :3], corners) + xf[:, None, :, 3]
    ok = np.all(np.isfinite(world), axis=(1, 2))
    if not np.any(ok):
        return None
    world = world[ok].reshape(-1, 3)
    wlo, whi = world.min(axis=0), world.max(axis=0)
    return 0.5 * (wlo + whi), max(0.5 * float(np.linalg.norm(whi - wlo)), 1e-3)


def aimed(ls, sphere, fraction=AIMED):
    """The LightSet `ls` aiming at `sphere` = (centre, radius). A sphere not
    MIN_RATIO times smaller than the scene's aims at the scene itself, which
    changes only lights outside it."""
    if sphere is None:
        return ls
    c, r = np.asarray(sphere[0], np.float64), float(sphere[1])
    if not (np.all(np.isfinite(c)) and math.isfinite(r) and r > 0.0):
        return ls
    if float(np.linalg.norm(c - ls.center)) + ls.bound_radius <= r or r * MIN_RATIO > ls.bound_radius:
        c, r = ls.center, ls.bound_radius
    return ls._replace(aim_center=c.copy(), aim_radius=r, aim_fraction=float(fraction))


@njit(**INLINE)
def _base_pdf(base, nx, ny, nz, cos_c, dx, dy, dz):
    """Density (per solid angle) of direction d under a light's own emission."""
    if base == UNIFORM:
        return 0.25 / math.pi
    c = dx * nx + dy * ny + dz * nz
    if base == COSINE:
        return max(c, 0.0) / math.pi
    return 1.0 / (2.0 * math.pi * (1.0 - cos_c)) if c >= cos_c else 0.0


@njit(**INLINE)
def _levels(aim, limit):
    """The nested spheres aimed at: radii r 2^k, the last one cut to `limit`
    (the one that holds the scene's bounding sphere, or less) -> (count, limit).
    A single sphere when the aim sphere is at the limit already."""
    _, aim_center, r, center, bound_radius = aim
    ex, ey, ez = aim_center[0] - center[0], aim_center[1] - center[1], aim_center[2] - center[2]
    limit = max(min(limit, math.sqrt(ex * ex + ey * ey + ez * ez) + bound_radius), r)
    n = 1
    while n < LEVELS and r * (1 << (n - 1)) < limit:
        n += 1
    return n, limit


@njit(**INLINE)
def _aim(ls):
    """What aiming reads of a light set: (fraction, aim centre, aim radius, scene
    centre, scene radius)."""
    return ls.aim_fraction, ls.aim_center, ls.aim_radius, ls.center, ls.bound_radius


# aim_direction and aim_disk are façades over compiled bodies: emit_photon inlines
# them at eight places, and numba copies an inlined function's IR with all that
# was inlined into it, so inlined bodies made emit_photon cost 12 s to compile
# into every kernel that emits photons. A call per photon passes a few words.
@njit(**INLINE)
def aim_direction(ls, state, ox, oy, oz, dx, dy, dz, base, nx, ny, nz, cos_c):
    """_aim_direction with the light set's aim (see there)."""
    return _aim_direction(_aim(ls), state, (ox, oy, oz), (dx, dy, dz), base, (nx, ny, nz), cos_c)


@njit(**INLINE)
def aim_disk(ls, state, dx, dy, dz, R, ox, oy, oz):
    """_aim_disk with the light set's aim (see there)."""
    return _aim_disk(_aim(ls), state, (dx, dy, dz), R, (ox, oy, oz))


@njit(**CORE)
def _aim_direction(aim, state, o, d, base, n, cos_c):
    """Mixes direction d (already drawn from the light's own distribution `base`
    about n, of cone cos_c for CONE) with the cones from o that hold the nested
    aim spheres -> (state, dx, dy, dz, weight). A light inside the aim sphere
    keeps d and draws no random numbers. aim: photon_aim._aim of the light set."""
    f, aim_center, r, center, bound_radius = aim
    ox, oy, oz = o
    dx, dy, dz = d
    nx, ny, nz = n
    ax, ay, az = aim_center[0] - ox, aim_center[1] - oy, aim_center[2] - oz
    d2 = ax * ax + ay * ay + az * az
    if not (f > 0.0) or d2 <= r * r:
        return state, dx, dy, dz, 1.0
    dist = math.sqrt(d2)
    ax, ay, az = ax / dist, ay / dist, az / dist
    n_lv, limit = _levels(aim, dist * (1.0 - 1e-6))
    state, uc = next_float(state)
    state, u1 = next_float(state)
    state, u2 = next_float(state)
    if uc < f:
        rk = min(r * (1 << min(int(uc / f * n_lv), n_lv - 1)), limit)
        lx, ly, lz = uniform_cone(u1, u2, math.sqrt(max(0.0, 1.0 - rk * rk / d2)))
        dx, dy, dz = to_world(lx, ly, lz, ax, ay, az)
    c = dx * ax + dy * ay + dz * az
    p_aim = 0.0
    for k in range(n_lv):
        rk = min(r * (1 << k), limit)
        cos_max = math.sqrt(max(0.0, 1.0 - rk * rk / d2))
        # the cone's edge with a little slack, so a cone sample rounded outside still counts
        if c >= cos_max - 1e-12:
            p_aim += 1.0 / (2.0 * math.pi * (1.0 - cos_max))
    p = _base_pdf(base, nx, ny, nz, cos_c, dx, dy, dz)
    mix = f * p_aim / n_lv + (1.0 - f) * p
    return state, dx, dy, dz, (p / mix if mix > 0.0 else 0.0)


@njit(**CORE)
def _aim_disk(aim, state, d, R, o):
    """Parallel photons (sun, world) along d start on the disk of radius R about
    the scene's centre, facing d: origin o was drawn uniformly on it. Mixes it
    with the disks that cover the nested aim spheres -> (state, ox, oy, oz, weight)."""
    f, aim_center, r, center, bound_radius = aim
    dx, dy, dz = d
    ox, oy, oz = o
    if not (f > 0.0) or r >= R:
        return state, ox, oy, oz, 1.0
    cx, cy, cz = center[0], center[1], center[2]
    ex, ey, ez = aim_center[0] - cx, aim_center[1] - cy, aim_center[2] - cz
    # q: the aim sphere's centre moved along d into o's plane (the scene's centre + s d)
    s = (ox - cx) * dx + (oy - cy) * dy + (oz - cz) * dz
    t = ex * dx + ey * dy + ez * dz
    qx, qy, qz = cx + ex + (s - t) * dx, cy + ey + (s - t) * dy, cz + ez + (s - t) * dz
    n_lv, limit = _levels(aim, R)
    state, uc = next_float(state)
    state, u1 = next_float(state)
    state, u2 = next_float(state)
    if uc < f:
        rk = min(r * (1 << min(int(uc / f * n_lv), n_lv - 1)), limit)
        a, b = concentric_disk(u1, u2)
        tx, ty, tz, bx, by, bz = orthonormal_basis(dx, dy, dz)
        ox = qx + rk * (a * tx + b * bx)
        oy = qy + rk * (a * ty + b * by)
        oz = qz + rk * (a * tz + b * bz)
    px, py, pz = ox - cx - s * dx, oy - cy - s * dy, oz - cz - s * dz
    p_big = 1.0 / (math.pi * R * R) if px * px + py * py + pz * pz <= R * R * (1.0 + 1e-12) else 0.0
    e2 = (ox - qx) ** 2 + (oy - qy) ** 2 + (oz - qz) ** 2
    p_aim = 0.0
    for k in range(n_lv):
        rk = min(r * (1 << k), limit)
        if e2 <= rk * rk * (1.0 + 1e-12):
            p_aim += 1.0 / (math.pi * rk * rk)
    mix = f * p_aim / n_lv + (1.0 - f) * p_big
    return state, ox, oy, oz, (p_big / mix if mix > 0.0 else 0.0)
