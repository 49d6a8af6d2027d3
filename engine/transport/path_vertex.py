"""A path vertex: what a photon, a camera ray and a gather ray each do at a hit.

All three read the closure of the surface they met, turned to face the way
they came (`surface_closure`), and leave the surface on the side they go to
(`leave_surface`); the scratch arrays a path needs for this, one thread at a
time, travel as one `PathScratch`, made once per block of work by the
kernel's wrapper (the kernels' cores run without the NRT and allocate nothing).
"""
from collections import namedtuple

import numpy as np
from numba import njit

from ..core.jit import INLINE
from ..geometry.raycast import STACK_WORDS
from ..shading import bsdf
from ..shading import dispersion
from ..shading import fluorescence
from ..shading import materials
from ..shading import polarization

PathScratch = namedtuple("PathScratch", [
    "kd", "ks", "kt",   # the closure's diffuse, specular and transmission colours, per band
    "f",                # the weight of a sampled glossy lobe, per band
    "rad",              # radiance of a light or world sample, per band
    "tp",               # the path's throughput, per band
    "e", "lg",          # direct light: diffuse irradiance and glossy radiance, per band
    "ind",              # a lookup's irradiance, per band
    "ray",              # one gather ray's irradiance, per band (directional bakes)
    "closure",          # bsdf.closure_scalars of the hit (bsdf.closure_size)
    "stack",            # the ray traversal's stack (geometry/raycast.py)
    "count",            # count[0]: rays traced
    "bands",            # the ten band arrays above as the rows of one array (a 2-D argument where one is due)
    "wave",             # the path's wavelength state (dispersion.WAVE_*): the band it keeps (-1: all), nm
    "pol",              # Stokes vectors (photons) or rows (camera paths) per band, and a frame (polarization.py)
])


@njit(cache=True)
def path_scratch(nb, stack, count):
    """Scratch for a path of nb bands that traverses with `stack` and counts its rays in count[0]
    (two paths of one thread, a camera path and its gathers, share both)."""
    r = np.empty((10, nb))
    return PathScratch(r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], np.empty(bsdf.closure_size(nb)),
                       stack, count, r,
                       np.full(2, -1.0), np.zeros(polarization.pol_size(nb)))


@njit(cache=True)
def new_path_scratch(nb):
    """path_scratch with a stack and counter of its own."""
    return path_scratch(nb, np.empty(STACK_WORDS, np.int32), np.zeros(1, np.int64))


@njit(cache=True)
def ray_epsilon(px, py, pz):
    """Offset that moves a ray origin off its surface, relative to the coordinates' size."""
    return 1e-7 * (1.0 + max(abs(px), abs(py), abs(pz)))


@njit(**INLINE)
def leave_surface(p, n, d):
    """The origin of a ray from hit point p in direction d: p moved off the surface
    (normal n) to the side d points to."""
    px, py, pz = p
    nx, ny, nz = n
    eps = ray_epsilon(px, py, pz)
    side = eps if (d[0] * nx + d[1] * ny + d[2] * nz) > 0.0 else -eps
    return px + side * nx, py + side * ny, pz + side * nz


@njit(**INLINE)
def surface_closure(ms, ts, bt, g, w, m, surf, n, d, foot):
    """The closure of material m at a hit, met along d (materials, textures, bsdf
    tables and geometry: the KernelScene's parts it reads).

    surf = (instance, shape, face, u, v) and n, the outward face normal, as the
    ray query returns them; foot: the ray's width there (texture filtering; 0:
    the finest level). Fills w.kd, w.ks, w.kt and w.closure, and returns
    (f, s, cos_dn, cos_o, lobes): the face normal and the (normal-mapped)
    shading normal, both turned to the side d came from; d·n (< 0: entering);
    the cosine of the way back along -d with s; the lobe probabilities
    (pd, ps, pm, pg). A normal map tilted away from the ray gives way to the face.
    A dispersive material refracts at the path's wavelength once it keeps one
    band (dispersion.keep_one_band, which the caller runs first)."""
    inst, shape, face, u, v = surf
    nx, ny, nz = n
    dx, dy, dz = d
    rough, ior, _ = materials.surface_inputs(ms, ts, g, inst, m, shape, face, u, v, foot, w.kd, w.ks, w.kt)
    ior = dispersion.path_ior(ms.dispersion, m, ior, w.wave)
    snx, sny, snz = materials.shading_normal(ms, ts, g, inst, m, shape, face, u, v, foot, nx, ny, nz)
    cos_dn = dx * nx + dy * ny + dz * nz
    if cos_dn > 0.0:
        fx, fy, fz, sx, sy, sz = -nx, -ny, -nz, -snx, -sny, -snz
    else:
        fx, fy, fz, sx, sy, sz = nx, ny, nz, snx, sny, snz
    cos_o = -(dx * sx + dy * sy + dz * sz)
    if cos_o <= 1e-6:
        sx, sy, sz = fx, fy, fz
        cos_o = abs(cos_dn)
    bsdf.closure_scalars(bt, m, rough, ior, cos_dn < 0.0, cos_o, w.closure)
    lobes = fluorescence.diffuse_probability(ms, m, w.kd, bsdf.diffuse_scale(w.closure),
                                             bsdf.lobe_probabilities(w.closure, w.kd, w.ks, w.kt, cos_o))
    return (fx, fy, fz), (sx, sy, sz), cos_dn, cos_o, lobes


@njit(cache=True)
def smooth_mueller_terms(w, lobes, d_in, d_out, fn):
    """The Mueller terms of the smooth interaction in w's closure that turns d_in into d_out
    (face normal fn) into w.pol (bsdf.mueller_terms): a reflection when d_out leaves on
    fn's side. A photon's d_in is its own way in; a camera path's, its way to the surface."""
    _, ps, pm, pg = lobes
    c = abs(d_in[0] * fn[0] + d_in[1] * fn[1] + d_in[2] * fn[2])
    reflect = d_out[0] * fn[0] + d_out[1] * fn[1] + d_out[2] * fn[2] > 0.0
    bsdf.mueller_terms(w.closure, w.ks, w.kt, ps, pm, pg, c, reflect, w.pol, polarization.terms_at(w.tp.shape[0]))
