"""Surface scattering: diffuse, glossy/specular reflection, dielectric transmission.

A material is a per-band mix of three lobes (diffuse, specular, transmission)
plus Lambertian emission. Particle tracing (thesis 3.4.3, after Pattanaik &
Mudur) picks *one* interaction per hit by probability, so a photon travels
unsplit; the renderer uses the same lobes for its specular paths.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from .sampling import cosine_hemisphere, to_world
from .scene import SceneError, _bands

MaterialSet = namedtuple("MaterialSet", "diffuse specular transmission roughness ior emission")

# Interaction chosen for a photon.
ABSORB, DIFFUSE, SPECULAR, TRANSMIT = 0, 1, 2, 3


def compile_materials(scene):
    """Band arrays for every material; a default grey diffuse when the scene has none."""
    mats = scene.materials or []
    n, b = max(len(mats), 1), scene.n_bands
    out = MaterialSet(np.full((n, b), 0.8), np.zeros((n, b)), np.zeros((n, b)),
                      np.zeros(n), np.full(n, 1.5), np.zeros((n, b)))
    for i, m in enumerate(mats):
        kd = _bands(m.diffuse, b, f"material '{m.name}' diffuse")
        ks = _bands(m.specular, b, f"material '{m.name}' specular")
        kt = _bands(m.transmission, b, f"material '{m.name}' transmission")
        le = _bands(m.emission, b, f"material '{m.name}' emission")
        for what, k in (("diffuse", kd), ("specular", ks), ("transmission", kt), ("emission", le)):
            if np.any(k < 0):
                raise SceneError(f"material '{m.name}': negative {what} {k}")
        total = kd + ks + kt
        if np.any(total > 1.0 + 1e-9):
            raise SceneError(f"material '{m.name}': diffuse+specular+transmission = {total.max():.3f} > 1 "
                             "would create energy")
        if not (math.isfinite(m.roughness) and math.isfinite(m.ior) and m.ior > 0):
            raise SceneError(f"material '{m.name}': invalid roughness/ior ({m.roughness}, {m.ior})")
        out.diffuse[i], out.specular[i], out.transmission[i], out.emission[i] = kd, ks, kt, le
        out.roughness[i] = min(max(float(m.roughness), 0.0), 1.0)
        out.ior[i] = float(m.ior)
    return out


@njit(cache=True)
def lobe_probabilities(ms, m):
    """Selection probabilities (p_diffuse, p_specular, p_transmit); the rest is absorption.

    Each lobe is chosen with the probability of its largest band, so a survivor's
    weight k/p never exceeds 1 in any band: photons keep (at most) their power,
    and absorbed energy per band is never negative. That needs the lobes'
    largest bands to sum to at most 1; where they do not (diffuse [.9, .1] with
    specular [.1, .9]: each band's own sum is fine) the probabilities are scaled
    down, a band's weight can exceed 1, and the pass stays unbiased.
    """
    pd = 0.0
    ps = 0.0
    pt = 0.0
    for b in range(ms.diffuse.shape[1]):
        pd = max(pd, ms.diffuse[m, b])
        ps = max(ps, ms.specular[m, b])
        pt = max(pt, ms.transmission[m, b])
    s = pd + ps + pt
    if s > 1.0:
        pd /= s
        ps /= s
        pt /= s
    return pd, ps, pt


@njit(cache=True, inline="always")
def reflect(dx, dy, dz, nx, ny, nz):
    c = 2.0 * (dx * nx + dy * ny + dz * nz)
    return dx - c * nx, dy - c * ny, dz - c * nz


@njit(cache=True)
def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance; cos_i > 0 on the incident side, eta = n_t / n_i."""
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0, 0.0
    cos_t = math.sqrt(1.0 - sin2_t)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp), cos_t


@njit(cache=True)
def glossy_perturb(rx, ry, rz, roughness, u1, u2):
    """Phong-like lobe around direction r; roughness 0 returns r (perfect specular).

    The exponent 2/r² - 2 matches the width of a microfacet lobe of roughness r
    (Walter et al. 2007 alpha = r²) closely enough for a glossy look.
    """
    if roughness <= 1e-4:
        return rx, ry, rz
    a = roughness * roughness
    e = max(2.0 / (a * a) - 2.0, 0.0)
    cos_t = u1 ** (1.0 / (e + 1.0))
    sin_t = math.sqrt(max(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * math.pi * u2
    return to_world(sin_t * math.cos(phi), sin_t * math.sin(phi), cos_t, rx, ry, rz)


@njit(cache=True)
def scatter(ms, m, lobe, dx, dy, dz, nx, ny, nz, u1, u2, u3):
    """New direction for the chosen lobe, d the (unit) incoming direction, n the normal.

    Returns (ok, ox, oy, oz): ok is False when a glossy sample fell below the
    surface (the photon is then absorbed, which keeps the estimator unbiased
    for the energy the lobe actually reflects).
    """
    cos_dn = dx * nx + dy * ny + dz * nz
    # The outward normal tells entering from leaving a dielectric.
    eta = ms.ior[m] if cos_dn < 0.0 else 1.0 / ms.ior[m]
    # Face the normal towards the incoming side (open surfaces are two-sided).
    if cos_dn > 0.0:
        nx, ny, nz, cos_dn = -nx, -ny, -nz, -cos_dn
    if lobe == DIFFUSE:
        lx, ly, lz = cosine_hemisphere(u1, u2)
        ox, oy, oz = to_world(lx, ly, lz, nx, ny, nz)
        return True, ox, oy, oz
    if lobe == SPECULAR:
        rx, ry, rz = reflect(dx, dy, dz, nx, ny, nz)
        ox, oy, oz = glossy_perturb(rx, ry, rz, ms.roughness[m], u1, u2)
        return (ox * nx + oy * ny + oz * nz) > 0.0, ox, oy, oz
    return refract_or_reflect(dx, dy, dz, nx, ny, nz, cos_dn, eta, ms.roughness[m], u1, u2, u3)


@njit(cache=True)
def refract_or_reflect(dx, dy, dz, nx, ny, nz, cos_dn, eta_rel, roughness, u1, u2, u3):
    """Fresnel-weighted choice between reflection and refraction (n faces the incident side)."""
    cos_i = -cos_dn
    f, cos_t = fresnel_dielectric(cos_i, eta_rel)
    if u3 < f:
        rx, ry, rz = reflect(dx, dy, dz, nx, ny, nz)
        ox, oy, oz = glossy_perturb(rx, ry, rz, roughness, u1, u2)
        return (ox * nx + oy * ny + oz * nz) > 0.0, ox, oy, oz
    inv = 1.0 / eta_rel
    k = inv * cos_i - cos_t
    tx, ty, tz = inv * dx + k * nx, inv * dy + k * ny, inv * dz + k * nz
    ln = math.sqrt(tx * tx + ty * ty + tz * tz)
    tx, ty, tz = tx / ln, ty / ln, tz / ln
    ox, oy, oz = glossy_perturb(tx, ty, tz, roughness, u1, u2)
    return (ox * nx + oy * ny + oz * nz) < 0.0, ox, oy, oz
