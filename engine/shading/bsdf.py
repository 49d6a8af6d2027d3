"""Principled BSDF lobes: GGX microfacets with visible-normal sampling (Blender's Principled v2).

A hit's closure has four lobes, all sharing one roughness (alpha = roughness²,
as Blender maps it):

* diffuse: Lambertian kd, under the dielectric specular layer, which takes its
  directional albedo first (kd (1 - E_layer(cos_o)), Cycles' albedo scaling);
* layer: the dielectric specular layer (Principled 'Specular IOR Level'):
  GGX reflection with the exact dielectric Fresnel of the level-adjusted IOR,
  white, weight w_layer;
* metal: GGX reflection of colour ks, Schlick Fresnel with F0 = ks (Principled
  metal with a white F82 tint), a constant ks (the Glossy BSDF), or a
  conductor's exact Fresnel at its complex index per band (conductor.py), with
  Kulla–Conty style energy compensation (Cycles' multiscatter GGX: weight
  1 + F_avg (1 - E)/E, so a white metal furnace reflects all it receives);
* glass: rough dielectric (Walter et al. 2007) reflection and refraction,
  tinted kt, Fresnel-weighted.

Everything works in a local frame: z along the shading normal turned to the
outgoing side (wo.z > 0). Below DELTA_ALPHA the glossy lobes are perfect
mirrors/refractions (a delta, never hit by light sampling), as Cycles treats
alpha_x alpha_y <= 1e-7.

`p` packs a hit's scalars: see the P_* indices. The renderer samples only the
glossy part (its diffuse light comes from the lightmaps); the photon tracer
samples all four lobes.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..core.jit import CORE
from ..core.sampling import cosine_hemisphere, orthonormal_basis
from . import conductor
from . import polarization

DELTA_ALPHA = 3.2e-4

# closure scalars (one small float64 array per hit, filled by closure_scalars)
(P_ALPHA, P_ETA, P_LAYER_F0, P_LAYER_ETA, P_LAYER_W, P_SCHLICK, P_E_LAYER, P_E_METAL, P_METAL,
 P_SIZE) = range(10)
# P_SCHLICK's values: the metal lobe's Fresnel
METAL_CONSTANT, METAL_SCHLICK, METAL_CONDUCTOR = 0.0, 1.0, 2.0
# a conductor's (n, k, F_avg) per band follow the scalars: p[P_SIZE + 3 b + i]
P_COND = P_SIZE


@njit(cache=True)
def closure_size(nb):
    """Length of a closure array for nb bands."""
    return P_SIZE + 3 * nb


# selected lobe
ABSORB, DIFFUSE, GLOSSY = 0, 1, 2

BsdfTables = namedtuple("BsdfTables", "e_metal e_layer layer_f0 layer_eta layer_weight metal_fresnel metallic "
                                      "conductor")

# albedo tables: cos_o, alpha and F0 on sqrt-spaced grids (resolution at grazing
# angles, low roughness and the small F0 of common dielectrics, where the albedo
# is far from linear in F0: any F0 > 0 reflects everything at grazing angles)
N_MU, N_ALPHA, N_F0 = 16, 16, 24


# --------------------------------------------------------------------------------------
# Setup (numpy)
# --------------------------------------------------------------------------------------

def layer_f0_eta(ior, level):
    """Blender's Specular IOR Level: F0 from the IOR scaled by 2 level, and the IOR that has it."""
    ior = max(float(ior), 1e-3)
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2 * 2.0 * max(float(level), 0.0)
    f0 = min(f0, 0.999)
    if f0 <= 0.0:
        return 0.0, 1.0
    s = math.sqrt(f0)
    eta = (1.0 + s) / (1.0 - s)
    return f0, eta


def _albedo_tables(n_dir=32):
    """Directional albedos by quadrature over visible normals (exact in the limit):
    e_metal[mu, alpha] of single-scatter GGX with F = 1, and e_layer[mu, alpha, f0]
    of GGX with the dielectric Fresnel of the IOR that has F0."""
    mus = (np.arange(N_MU) / (N_MU - 1)) ** 2 * 0.999 + 0.001
    alphas = (np.arange(N_ALPHA) / (N_ALPHA - 1)) ** 2
    f0s = (np.arange(N_F0) / (N_F0 - 1)) ** 2 * 0.999
    u1, u2 = np.meshgrid((np.arange(n_dir) + 0.5) / n_dir, (np.arange(n_dir) + 0.5) / n_dir)
    u1, u2 = u1.ravel(), u2.ravel()
    e_metal = np.empty((N_MU, N_ALPHA))
    e_layer = np.empty((N_MU, N_ALPHA, N_F0))
    s0 = np.sqrt(f0s)
    etas = (1.0 + s0) / np.maximum(1.0 - s0, 1e-6)
    for i, mu in enumerate(mus):
        wo = np.array([math.sqrt(1.0 - mu * mu), 0.0, mu])
        for j, a in enumerate(alphas):
            if a <= DELTA_ALPHA:
                e_metal[i, j] = 1.0
                e_layer[i, j] = _fresnel_np(np.full(N_F0, mu), etas)
                continue
            h = _vndf_np(wo, a, u1, u2)
            cos_oh = np.clip(h @ wo, 0.0, 1.0)
            wi_z = 2.0 * cos_oh * h[:, 2] - wo[2]
            ok = wi_z > 0.0
            wi_x = 2.0 * cos_oh * h[:, 0] - wo[0]
            wi_y = 2.0 * cos_oh * h[:, 1] - wo[1]
            g1o = 1.0 / (1.0 + _lambda_np(wo[2], math.hypot(wo[0], wo[1]), a))
            g2 = 1.0 / (1.0 + _lambda_np(wo[2], math.hypot(wo[0], wo[1]), a)
                        + _lambda_np(wi_z, np.hypot(wi_x, wi_y), a))
            w = np.where(ok, g2 / g1o, 0.0)
            e_metal[i, j] = w.mean()
            e_layer[i, j] = (w[None, :] * _fresnel_np(cos_oh[None, :], etas[:, None])).mean(axis=1)
    return e_metal, e_layer


def _lambda_np(cos_t, sin_t, a):
    tan2 = np.where(cos_t > 0, (sin_t / np.maximum(cos_t, 1e-12)) ** 2, np.inf)
    return 0.5 * (-1.0 + np.sqrt(1.0 + a * a * tan2))


def _vndf_np(wo, a, u1, u2):
    v = np.array([a * wo[0], a * wo[1], wo[2]])
    v /= np.linalg.norm(v)
    phi = 2.0 * np.pi * u1
    z = (1.0 - u2) * (1.0 + v[2]) - v[2]
    s = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    hx, hy, hz = s * np.cos(phi) + v[0], s * np.sin(phi) + v[1], z + v[2]
    h = np.stack([a * hx, a * hy, np.maximum(hz, 0.0)], axis=1)
    return h / np.linalg.norm(h, axis=1, keepdims=True)


def _fresnel_np(c, eta):
    s2 = (1.0 - c * c) / (eta * eta)
    ct = np.sqrt(np.clip(1.0 - s2, 0.0, 1.0))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return np.where(s2 >= 1.0, 1.0, 0.5 * (rs * rs + rp * rp))


_TABLES = None


def compile_bsdf(materials, n_bands=3, bands=None):
    """Albedo tables and each material's layer and Fresnel parameters (scene.Material list;
    bands: spectrum.Bands in spectral mode). A bad conductor raises ValueError."""
    global _TABLES
    if _TABLES is None:
        _TABLES = _albedo_tables()
    n = max(len(materials), 1)
    f0 = np.zeros(n)
    eta = np.ones(n)
    weight = np.zeros(n)
    mode = np.zeros(n)
    metallic = np.zeros(n)
    cond = np.zeros((n, n_bands, 3))
    for i, m in enumerate(materials):
        level = float(getattr(m, "specular_level", 0.0))
        if not math.isfinite(level):
            level = 0.0
        f0[i], eta[i] = layer_f0_eta(m.ior, level)
        metal = min(max(float(getattr(m, "metallic", 0.0)), 0.0), 1.0)
        trans = min(max(float(getattr(m, "transmission_weight", 0.0)), 0.0), 1.0)
        # legacy materials (no Principled weights) put the layer over all of their diffuse
        weight[i] = (1.0 - metal) * (1.0 - trans)
        mode[i] = METAL_SCHLICK if getattr(m, "metal_fresnel", False) else METAL_CONSTANT
        metallic[i] = metal
        if getattr(m, "conductor", ""):
            try:
                nk = conductor.band_index(m.conductor, n_bands, bands)
            except ValueError as e:
                raise ValueError(f"material '{m.name}': {e}") from None
            mode[i] = METAL_CONDUCTOR
            cond[i, :, :2] = nk
            cond[i, :, 2] = [conductor.mean_reflectance(a, b) for a, b in nk]
    return BsdfTables(_TABLES[0], _TABLES[1], f0, eta, weight, mode, metallic, cond)


# --------------------------------------------------------------------------------------
# Microfacet pieces
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def ggx_d(hz, a):
    """GGX normal distribution D(h) for the local half vector's z = cos theta_h."""
    if hz <= 0.0:
        return 0.0
    a2 = a * a
    t = hz * hz * (a2 - 1.0) + 1.0
    return a2 / (math.pi * t * t)


@njit(cache=True, inline="always")
def ggx_lambda(wx, wy, wz, a):
    z2 = wz * wz
    if not z2 > 0.0:            # also a grazing cosine whose square underflows
        return math.inf
    tan2 = (wx * wx + wy * wy) / z2
    return 0.5 * (-1.0 + math.sqrt(1.0 + a * a * tan2))


@njit(cache=True, inline="always")
def ggx_g1(wx, wy, wz, a):
    return 1.0 / (1.0 + ggx_lambda(wx, wy, wz, a))


@njit(cache=True, inline="always")
def ggx_g2(ox, oy, oz, ix, iy, iz, a):
    """Height-correlated masking-shadowing (Heitz 2014)."""
    return 1.0 / (1.0 + ggx_lambda(ox, oy, oz, a) + ggx_lambda(ix, iy, iz, a))


@njit(cache=True)
def sample_vndf(ox, oy, oz, a, u1, u2):
    """Visible normal of GGX for wo (oz > 0), by spherical caps (Dupuy & Benyoub 2023)."""
    vx, vy, vz = a * ox, a * oy, oz
    ln = math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx / ln, vy / ln, vz / ln
    phi = 2.0 * math.pi * u1
    z = (1.0 - u2) * (1.0 + vz) - vz
    s = math.sqrt(min(max(1.0 - z * z, 0.0), 1.0))
    hx, hy, hz = a * (s * math.cos(phi) + vx), a * (s * math.sin(phi) + vy), max(z + vz, 0.0)
    ln = math.sqrt(hx * hx + hy * hy + hz * hz)
    if ln == 0.0:
        return 0.0, 0.0, 1.0
    return hx / ln, hy / ln, hz / ln


@njit(cache=True, inline="always")
def vndf_pdf(ox, oy, oz, hx, hy, hz, a):
    """Density of sample_vndf's h: G1(wo) max(0, wo.h) D(h) / wo.z."""
    c = ox * hx + oy * hy + oz * hz
    if c <= 0.0 or oz <= 0.0:
        return 0.0
    return ggx_g1(ox, oy, oz, a) * c * ggx_d(hz, a) / oz


@njit(cache=True)
def fresnel_dielectric(cos_i, eta):
    """Unpolarised Fresnel reflectance and cos_t; cos_i > 0 on the incident side, eta = n_t / n_i."""
    sin2_t = (1.0 - cos_i * cos_i) / (eta * eta)
    if sin2_t >= 1.0:
        return 1.0, 0.0
    cos_t = math.sqrt(1.0 - sin2_t)
    rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
    return 0.5 * (rs * rs + rp * rp), cos_t


@njit(cache=True, inline="always")
def _schlick(f0, c):
    m = 1.0 - c
    m2 = m * m
    return f0 + (1.0 - f0) * m2 * m2 * m


@njit(cache=True)
def _table2(t, mu, a):
    """Bilinear lookup of t[mu, alpha] on the sqrt-spaced grids."""
    x = math.sqrt(max(min((mu - 0.001) / 0.999, 1.0), 0.0)) * (t.shape[0] - 1)
    y = math.sqrt(max(min(a, 1.0), 0.0)) * (t.shape[1] - 1)
    i = min(int(x), t.shape[0] - 2)
    j = min(int(y), t.shape[1] - 2)
    fx, fy = x - i, y - j
    return ((1 - fx) * ((1 - fy) * t[i, j] + fy * t[i, j + 1])
            + fx * ((1 - fy) * t[i + 1, j] + fy * t[i + 1, j + 1]))


@njit(cache=True)
def _table3(t, mu, a, f0):
    z = math.sqrt(max(min(f0 / 0.999, 1.0), 0.0)) * (t.shape[2] - 1)
    k = min(int(z), t.shape[2] - 2)
    fz = z - k
    x = math.sqrt(max(min((mu - 0.001) / 0.999, 1.0), 0.0)) * (t.shape[0] - 1)
    y = math.sqrt(max(min(a, 1.0), 0.0)) * (t.shape[1] - 1)
    i = min(int(x), t.shape[0] - 2)
    j = min(int(y), t.shape[1] - 2)
    fx, fy = x - i, y - j
    acc = 0.0
    for di in range(2):
        wx = fx if di else 1.0 - fx
        for dj in range(2):
            wy = fy if dj else 1.0 - fy
            acc += wx * wy * ((1.0 - fz) * t[i + di, j + dj, k] + fz * t[i + di, j + dj, k + 1])
    return acc


# --------------------------------------------------------------------------------------
# Closure
# --------------------------------------------------------------------------------------

@njit(**CORE)
def closure_scalars(bt, m, roughness, ior, entering, cos_o, p):
    """Fills p for material m at a hit: alpha, the glass eta (n_t/n_i from the side the
    light arrives on), the layer's F0, eta and weight, and the albedos at cos_o."""
    r = min(max(roughness, 0.0), 1.0)
    a = r * r
    p[P_ALPHA] = a
    p[P_ETA] = ior if entering else 1.0 / ior
    p[P_LAYER_F0] = bt.layer_f0[m]
    p[P_LAYER_ETA] = bt.layer_eta[m]
    p[P_LAYER_W] = bt.layer_weight[m] if bt.layer_f0[m] > 0.0 else 0.0
    p[P_SCHLICK] = bt.metal_fresnel[m]
    p[P_METAL] = bt.metallic[m]
    if p[P_SCHLICK] == METAL_CONDUCTOR:
        for b in range(min(bt.conductor.shape[1], (p.shape[0] - P_COND) // 3)):
            for i in range(3):
                p[P_COND + 3 * b + i] = bt.conductor[m, b, i]
    mu = min(max(cos_o, 0.0), 1.0)
    if p[P_LAYER_W] > 0.0:
        if a <= DELTA_ALPHA:
            p[P_E_LAYER] = fresnel_dielectric(max(mu, 1e-6), bt.layer_eta[m])[0]
        else:
            p[P_E_LAYER] = min(max(_table3(bt.e_layer, mu, a, bt.layer_f0[m]), 0.0), 1.0)
    else:
        p[P_E_LAYER] = 0.0
    p[P_E_METAL] = 1.0 if a <= DELTA_ALPHA else max(_table2(bt.e_metal, mu, a), 1e-3)


@njit(cache=True, inline="always")
def diffuse_scale(p):
    """What the layer leaves to the diffuse lobe at this cos_o (energy-conserving layering)."""
    return 1.0 - p[P_LAYER_W] * p[P_E_LAYER]


@njit(cache=True)
def _metal_fresnel(p, ks, b, c):
    """ks = B M (Principled): the metal's share M times Schlick of F0 = B, so a
    dielectric (M = 0) has no metal lobe even at grazing angles. A conductor: M times
    its Fresnel at its index in band b."""
    if p[P_SCHLICK] == METAL_CONDUCTOR:
        return p[P_METAL] * conductor.reflectance(c, p[P_COND + 3 * b], p[P_COND + 3 * b + 1])
    if p[P_SCHLICK] > 0.0:
        m = 1.0 - c
        m2 = m * m
        return ks[b] + (p[P_METAL] - ks[b]) * m2 * m2 * m
    return ks[b]


@njit(cache=True)
def _metal_compensation(p, ks, b):
    """1 + F_avg (1 - E) / E: the energy of multiply scattered light, re-added (Cycles)."""
    e = p[P_E_METAL]
    if p[P_SCHLICK] == METAL_CONDUCTOR:
        f_avg = p[P_METAL] * p[P_COND + 3 * b + 2]
    else:
        f_avg = ks[b] + (p[P_METAL] - ks[b]) / 21.0 if p[P_SCHLICK] > 0.0 else ks[b]
    return 1.0 + f_avg * (1.0 - e) / e


@njit(cache=True)
def lobe_probabilities(p, kd, ks, kt, cos_o):
    """Selection probabilities (diffuse, layer, metal, glass), from each lobe's largest
    band at cos_o; their sum is at most 1 (the rest is absorption for photons)."""
    pd = 0.0
    pm = 0.0
    pg = 0.0
    ds = diffuse_scale(p)
    for b in range(kd.shape[0]):
        pd = max(pd, kd[b] * ds)
        # with the multiscatter weight, so a metal's sample weight stays within 1
        pm = max(pm, _metal_fresnel(p, ks, b, min(max(cos_o, 0.0), 1.0)) * _metal_compensation(p, ks, b))
        pg = max(pg, kt[b])
    ps = p[P_LAYER_W] * p[P_E_LAYER]
    s = pd + ps + pm + pg
    if s > 1.0:
        pd /= s
        ps /= s
        pm /= s
        pg /= s
    return pd, ps, pm, pg


@njit(cache=True)
def eval_glossy(p, ks, kt, ps, pm, pg, ox, oy, oz, ix, iy, iz, out):
    """Glossy f cos_i per band into out (local frame, wo.z > 0) and the pdf of
    sample_glossy for wi: the selection-weighted mixture of the glossy lobes'
    visible-normal densities (probabilities relative to ps + pm + pg)."""
    nb = out.shape[0]
    for b in range(nb):
        out[b] = 0.0
    a = p[P_ALPHA]
    total = ps + pm + pg
    if a <= DELTA_ALPHA or total <= 0.0 or oz <= 0.0:
        return 0.0
    pdf = 0.0
    if iz > 0.0:
        hx, hy, hz = ox + ix, oy + iy, oz + iz
        ln = math.sqrt(hx * hx + hy * hy + hz * hz)
        if not ln > 0.0:
            return 0.0
        hx, hy, hz = hx / ln, hy / ln, hz / ln
        c = ox * hx + oy * hy + oz * hz
        if c > 0.0:
            d = ggx_d(hz, a)
            g2 = ggx_g2(ox, oy, oz, ix, iy, iz, a)
            base = d * g2 / (4.0 * oz)            # f cos_i without Fresnel
            p_refl = vndf_pdf(ox, oy, oz, hx, hy, hz, a) / (4.0 * c)
            if ps > 0.0:
                f = p[P_LAYER_W] * fresnel_dielectric(c, p[P_LAYER_ETA])[0] * base
                for b in range(nb):
                    out[b] += f
                pdf += ps / total * p_refl
            if pm > 0.0:
                for b in range(nb):
                    out[b] += _metal_fresnel(p, ks, b, c) * _metal_compensation(p, ks, b) * base
                pdf += pm / total * p_refl
            if pg > 0.0:
                fr = fresnel_dielectric(c, p[P_ETA])[0]
                for b in range(nb):
                    out[b] += kt[b] * fr * base
                pdf += pg / total * fr * p_refl
        return pdf
    if pg <= 0.0 or iz >= 0.0:
        return pdf
    # refraction: the generalised half vector h = -(eta wi + wo), turned up
    eta = p[P_ETA]
    hx, hy, hz = -(eta * ix + ox), -(eta * iy + oy), -(eta * iz + oz)
    ln = math.sqrt(hx * hx + hy * hy + hz * hz)
    if not ln > 0.0:
        return pdf
    hx, hy, hz = hx / ln, hy / ln, hz / ln
    if hz < 0.0:
        hx, hy, hz = -hx, -hy, -hz
    co = ox * hx + oy * hy + oz * hz
    ci = ix * hx + iy * hy + iz * hz
    if co <= 0.0 or ci >= 0.0:
        return pdf
    fr = fresnel_dielectric(co, eta)[0]
    denom = co + eta * ci
    if not denom * denom > 0.0:
        return pdf
    jac = eta * eta * abs(ci) / (denom * denom)
    d = ggx_d(hz, a)
    g2 = ggx_g2(ox, oy, oz, ix, iy, iz, a)
    # importance and radiance alike: the 1/eta^2 radiance scaling cancels on the
    # way in and out of a solid, and Cycles leaves it out as well
    f = (1.0 - fr) * d * g2 * co * jac / oz
    for b in range(nb):
        out[b] += kt[b] * f
    pdf += pg / total * (1.0 - fr) * vndf_pdf(ox, oy, oz, hx, hy, hz, a) * jac
    return pdf


@njit(cache=True)
def _refract(ox, oy, oz, hx, hy, hz, eta, co):
    """Refracts wo (pointing away) about h; eta = n_t / n_i. Returns (ok, wi)."""
    s2 = (1.0 - co * co) / (eta * eta)
    if s2 >= 1.0:
        return False, 0.0, 0.0, 0.0
    ct = math.sqrt(1.0 - s2)
    inv = 1.0 / eta
    k = inv * co - ct
    ix, iy, iz = -inv * ox + k * hx, -inv * oy + k * hy, -inv * oz + k * hz
    ln = math.sqrt(ix * ix + iy * iy + iz * iz)
    return True, ix / ln, iy / ln, iz / ln


@njit(cache=True)
def sample_glossy(p, ks, kt, ps, pm, pg, ox, oy, oz, u0, u1, u2, u3, weight):
    """Samples the glossy lobes (probabilities relative to ps + pm + pg).

    Returns (ok, ix, iy, iz, pdf, delta); weight[b] = f cos / pdf of the glossy
    part *given* that it was chosen (the caller divides by the part's probability).
    pdf is the mixture density eval_glossy gives (0 for a delta sample).
    """
    nb = weight.shape[0]
    total = ps + pm + pg
    if total <= 0.0:
        return False, 0.0, 0.0, 1.0, 0.0, False
    a = p[P_ALPHA]
    u0 *= total
    if a <= DELTA_ALPHA:
        # mirror directions: layer, metal and the glass's Fresnel reflection share one
        c = oz
        fr, _ = fresnel_dielectric(c, p[P_ETA]) if pg > 0.0 else (0.0, 0.0)
        p_refl = ps + pm + pg * fr
        if u0 < p_refl:
            lf = p[P_LAYER_W] * fresnel_dielectric(c, p[P_LAYER_ETA])[0] if ps > 0.0 else 0.0
            for b in range(nb):
                f = lf
                if pm > 0.0:
                    f += _metal_fresnel(p, ks, b, c)
                if pg > 0.0:
                    f += kt[b] * fr
                weight[b] = f * total / p_refl
            return True, -ox, -oy, oz, 0.0, True
        ok, ix, iy, iz = _refract(ox, oy, oz, 0.0, 0.0, 1.0, p[P_ETA], c)
        if not ok:
            return False, 0.0, 0.0, 1.0, 0.0, True
        for b in range(nb):
            weight[b] = kt[b] * (1.0 - fr) * total / (pg * (1.0 - fr))
        return True, ix, iy, iz, 0.0, True
    hx, hy, hz = sample_vndf(ox, oy, oz, a, u1, u2)
    co = ox * hx + oy * hy + oz * hz
    if co <= 0.0:
        return False, 0.0, 0.0, 1.0, 0.0, False
    if u0 >= ps + pm:
        # glass: Fresnel picks reflection or refraction about the same visible normal
        fr = fresnel_dielectric(co, p[P_ETA])[0]
        if u3 >= fr:
            ok, ix, iy, iz = _refract(ox, oy, oz, hx, hy, hz, p[P_ETA], co)
            if not ok or iz >= 0.0:
                return False, 0.0, 0.0, 1.0, 0.0, False
            pdf = eval_glossy(p, ks, kt, ps, pm, pg, ox, oy, oz, ix, iy, iz, weight)
            if pdf <= 0.0:
                return False, 0.0, 0.0, 1.0, 0.0, False
            for b in range(nb):
                weight[b] /= pdf
            return True, ix, iy, iz, pdf, False
    ix, iy, iz = 2.0 * co * hx - ox, 2.0 * co * hy - oy, 2.0 * co * hz - oz
    if iz <= 0.0:
        return False, 0.0, 0.0, 1.0, 0.0, False
    pdf = eval_glossy(p, ks, kt, ps, pm, pg, ox, oy, oz, ix, iy, iz, weight)
    if pdf <= 0.0:
        return False, 0.0, 0.0, 1.0, 0.0, False
    for b in range(nb):
        weight[b] /= pdf
    return True, ix, iy, iz, pdf, False


@njit(cache=True)
def mueller_terms(p, ks, kt, ps, pm, pg, c, reflect, out, at):
    """The Mueller terms (A, B, C, S) per band, in the s frame (polarization.py), of a smooth
    closure's mirror reflection (`reflect`) or refraction at incidence cos c, into out[at +
    4 b ...]: the sum of what its lobes reflect (the layer's and glass's dielectric Fresnel,
    the metal's conductor Fresnel, a Schlick metal's colour with a perfect conductor's
    phase and no s/p difference) or the glass transmits. A equals the weight
    sample_glossy gives that direction."""
    nb = kt.shape[0]
    if reflect:
        la, lb, lc, ls_ = 0.0, 0.0, 0.0, 0.0
        if ps > 0.0:
            la, lb, lc, ls_ = polarization.reflection_terms(*polarization.fresnel(c, p[P_LAYER_ETA], 0.0))
            w = p[P_LAYER_W]
            la, lb, lc, ls_ = w * la, w * lb, w * lc, w * ls_
        ga, gb, gc, gs = 0.0, 0.0, 0.0, 0.0
        if pg > 0.0:
            ga, gb, gc, gs = polarization.reflection_terms(*polarization.fresnel(c, p[P_ETA], 0.0))
        for b in range(nb):
            A, B, C, S = la + kt[b] * ga, lb + kt[b] * gb, lc + kt[b] * gc, ls_ + kt[b] * gs
            if pm > 0.0:
                if p[P_SCHLICK] == METAL_CONDUCTOR:
                    ma, mb, mc, ms = polarization.reflection_terms(
                        *polarization.fresnel(c, p[P_COND + 3 * b], p[P_COND + 3 * b + 1]))
                    M = p[P_METAL]
                    A, B, C, S = A + M * ma, B + M * mb, C + M * mc, S + M * ms
                else:
                    # no index: a perfect conductor's phase (r_p = -r_s), which mirrors the field
                    f = _metal_fresnel(p, ks, b, c)
                    A, C = A + f, C - f
            out[at + 4 * b], out[at + 4 * b + 1], out[at + 4 * b + 2], out[at + 4 * b + 3] = A, B, C, S
    else:
        ta, tb, tc, ts = polarization.transmission_terms(*polarization.fresnel(c, p[P_ETA], 0.0)[:2])
        for b in range(nb):
            out[at + 4 * b], out[at + 4 * b + 1] = kt[b] * ta, kt[b] * tb
            out[at + 4 * b + 2], out[at + 4 * b + 3] = kt[b] * tc, kt[b] * ts


@njit(cache=True, inline="always")
def to_local(x, y, z, nx, ny, nz):
    tx, ty, tz, bx, by, bz = orthonormal_basis(nx, ny, nz)
    return x * tx + y * ty + z * tz, x * bx + y * by + z * bz, x * nx + y * ny + z * nz


@njit(cache=True, inline="always")
def from_local(x, y, z, nx, ny, nz):
    tx, ty, tz, bx, by, bz = orthonormal_basis(nx, ny, nz)
    return (x * tx + y * bx + z * nx, x * ty + y * by + z * ny, x * tz + y * bz + z * nz)


@njit(cache=True)
def sample_diffuse(u1, u2):
    """Cosine direction in the local frame (f cos / pdf = kd (1 - E_layer))."""
    return cosine_hemisphere(u1, u2)
