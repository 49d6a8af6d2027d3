"""Materials as the kernels read them: per-band lobe weights (diffuse, specular,
transmission) plus Lambertian emission, and the inputs textures drive per hit.

surface_inputs gives a hit's weights, roughness and IOR; shading_normal its
normal-mapped normal. The lobes themselves, and how particle tracing (thesis
3.4.3) picks one of them per hit, are in bsdf.py.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..core.jit import CORE, INLINE
from ..core.scene import SceneError, as_bands
from . import dispersion
from . import fluorescence
from . import spectrum
from .texture import lod_for, sample4, sample_mean4

# diffuse/specular/transmission (n, bands): the lobe weights of an untextured material.
# tex (n, 5) int32: texture id per TEXTURE_INPUTS slot (-1: none); base (n, bands),
# metallic, transmission_weight: the Principled inputs the weights are recomputed
# from per hit when a texture drives one of them; specular_level: Principled
# 'Specular IOR Level' (the dielectric layer over diffuse; 0 none).
# dispersion (n, dispersion.DISPERSION_SIZE): each material's index per wavelength
# (all NONE in RGB); bands: (n, lo nm, width nm) of a spectral scene's bands (n 0: RGB).
# fluorescent (n,) bool, fluor (n, bands, bands) and fluor_albedo (n, bands): a
# fluorescent material's re-radiation matrix M[o, i] and its column sums (fluorescence.py).
# rgb_table (k, k, k, bands): a spectral scene's spectra of an RGB grid (spectrum.rgb_table),
# through which a base-colour texture's RGB becomes a spectrum per hit; (1, 1, 1, bands) unused.
MaterialSet = namedtuple("MaterialSet", "diffuse specular transmission roughness ior emission "
                                        "tex base metallic transmission_weight specular_level "
                                        "dispersion bands fluorescent fluor fluor_albedo rgb_table")

# Material.textures keys, in the column order of MaterialSet.tex
TEXTURE_INPUTS = ("base_color", "roughness", "metallic", "transmission", "normal")
TEX_BASE, TEX_ROUGHNESS, TEX_METALLIC, TEX_TRANSMISSION, TEX_NORMAL = range(5)



def compile_materials(scene):
    """Band arrays for every material; a default grey diffuse when the scene has none."""
    mats = scene.materials or []
    n, b = max(len(mats), 1), scene.n_bands
    out = MaterialSet(np.full((n, b), 0.8), np.zeros((n, b)), np.zeros((n, b)),
                      np.zeros(n), np.full(n, 1.5), np.zeros((n, b)),
                      np.full((n, len(TEXTURE_INPUTS)), -1, np.int32), np.full((n, b), 0.8),
                      np.zeros(n), np.zeros(n), np.zeros(n),
                      np.zeros((n, dispersion.DISPERSION_SIZE)), _bands(getattr(scene, "spectral", None)),
                      np.zeros(n, np.bool_), np.zeros((n, b, b)), np.zeros((n, b)), _rgb_table(scene, mats, b))
    n_tex = len(getattr(scene, "textures", None) or [])
    for i, m in enumerate(mats):
        _texture_inputs(out, i, m, b, n_tex)
        kd = as_bands(m.diffuse, b, f"material '{m.name}' diffuse")
        ks = as_bands(m.specular, b, f"material '{m.name}' specular")
        kt = as_bands(m.transmission, b, f"material '{m.name}' transmission")
        le = as_bands(m.emission, b, f"material '{m.name}' emission")
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
        try:
            out.dispersion[i], out.ior[i] = dispersion.dispersion_row(
                getattr(m, "glass", ""), float(getattr(m, "abbe", 0.0) or 0.0), float(m.ior),
                spectral=out.bands[0] > 0, what=f"material '{m.name}'")
        except ValueError as e:
            raise SceneError(str(e)) from None
        _fluorescence(out, i, m, getattr(scene, "spectral", None))
    return out


def _fluorescence(out, i, m, bands):
    """Row i's re-radiation (spectral scenes; RGB has no wavelengths to shift between)."""
    fl = getattr(m, "fluorescence", None)
    if fl is None or bands is None:
        return
    if not isinstance(fl, fluorescence.Fluorescence):
        raise SceneError(f"material '{m.name}': fluorescence must be a Fluorescence, got {fl!r}")
    try:
        M, kd = fluorescence.compile_fluorescence(fl, out.diffuse[i], bands, f"material '{m.name}'")
    except ValueError as e:
        raise SceneError(str(e)) from None
    out.fluorescent[i] = True
    out.fluor[i] = M
    out.fluor_albedo[i] = M.sum(axis=0)
    out.diffuse[i] = kd


def _rgb_table(scene, mats, nb):
    """The RGB grid's spectra where a spectral scene has a base-colour texture."""
    bands = getattr(scene, "spectral", None)
    if bands is None or not any("base_color" in (getattr(m, "textures", None) or {}) for m in mats):
        return np.zeros((1, 1, 1, nb))
    return spectrum.rgb_table(bands)


def _bands(bands):
    """(n, lo, width) of spectrum.Bands, or zeros for an RGB scene."""
    if bands is None:
        return np.zeros(3)
    return np.array([float(bands.n), float(bands.lo), (float(bands.hi) - float(bands.lo)) / float(bands.n)])


def _texture_inputs(out, i, m, b, n_tex):
    """Row i of the textured part of the MaterialSet (constants clamped to [0, 1])."""
    what = f"material '{m.name}'"
    base = as_bands(getattr(m, "base_color", 0.8), b, f"{what} base colour")
    scalars = [getattr(m, k, 0.0) for k in ("metallic", "transmission_weight", "specular_level")]
    if not all(math.isfinite(float(x)) for x in scalars):
        raise SceneError(f"{what}: non-finite metallic/transmission/specular level {scalars}")
    out.base[i] = np.clip(base, 0.0, 1.0)
    out.metallic[i] = min(max(float(scalars[0]), 0.0), 1.0)
    out.transmission_weight[i] = min(max(float(scalars[1]), 0.0), 1.0)
    out.specular_level[i] = max(float(scalars[2]), 0.0)
    for key, tid in dict(getattr(m, "textures", None) or {}).items():
        if key not in TEXTURE_INPUTS:
            raise SceneError(f"{what}: unknown texture input '{key}' (one of {', '.join(TEXTURE_INPUTS)})")
        if not (isinstance(tid, (int, np.integer)) and 0 <= tid < n_tex):
            raise SceneError(f"{what}: texture {tid!r} for {key} is not one of the scene's {n_tex} textures")
        out.tex[i, TEXTURE_INPUTS.index(key)] = int(tid)


# ------------------------------------------------------------------ textured inputs

@njit(cache=True)
def hit_tex_uv(g, inst, shape, u, v, footprint):
    """(ok, s, t, footprint_uv) of a hit on its material UV map.

    Only mesh triangles carry texture UVs (u, v: the barycentrics raycast
    returns); primitives, CSG and L-system shapes, and triangles whose UVs have
    no area, return ok=False (their textures are read at their mean).
    `footprint` is the ray's footprint width at the hit in world metres (a ray
    cone's width, 0 for the finest level); it is scaled into UV units by the
    triangle's UV-to-world size ratio, with the instance's scale folded in."""
    if shape < 0 or g.shape_kind[shape] != 0:
        return False, 0.0, 0.0, 0.0
    r = g.shape_index[shape]
    uv = g.tri_tex_uv
    du1 = uv[r, 1, 0] - uv[r, 0, 0]
    dv1 = uv[r, 1, 1] - uv[r, 0, 1]
    du2 = uv[r, 2, 0] - uv[r, 0, 0]
    dv2 = uv[r, 2, 1] - uv[r, 0, 1]
    a_uv = abs(du1 * dv2 - du2 * dv1)
    if not a_uv > 0.0:
        return False, 0.0, 0.0, 0.0
    w0 = 1.0 - u - v
    s = w0 * uv[r, 0, 0] + u * uv[r, 1, 0] + v * uv[r, 2, 0]
    t = w0 * uv[r, 0, 1] + u * uv[r, 1, 1] + v * uv[r, 2, 1]
    f_uv = 0.0
    if footprint > 0.0:
        e1x, e1y, e1z, e2x, e2y, e2z = _world_edges(g, inst, r)
        cx = e1y * e2z - e1z * e2y
        cy = e1z * e2x - e1x * e2z
        cz = e1x * e2y - e1y * e2x
        a_w = math.sqrt(cx * cx + cy * cy + cz * cz)
        if a_w > 0.0:
            f_uv = footprint * math.sqrt(a_uv / a_w)
    return True, s, t, f_uv


@njit(cache=True)
def _world_edges(g, inst, r):
    """The triangle's edges p1 - p0 and p2 - p0 through the instance's linear part."""
    p = g.tri_p
    ax = p[r, 1, 0] - p[r, 0, 0]
    ay = p[r, 1, 1] - p[r, 0, 1]
    az = p[r, 1, 2] - p[r, 0, 2]
    bx = p[r, 2, 0] - p[r, 0, 0]
    by = p[r, 2, 1] - p[r, 0, 1]
    bz = p[r, 2, 2] - p[r, 0, 2]
    if inst < 0:
        return ax, ay, az, bx, by, bz
    M = g.inst_xf[inst]
    return (M[0, 0] * ax + M[0, 1] * ay + M[0, 2] * az,
            M[1, 0] * ax + M[1, 1] * ay + M[1, 2] * az,
            M[2, 0] * ax + M[2, 1] * ay + M[2, 2] * az,
            M[0, 0] * bx + M[0, 1] * by + M[0, 2] * bz,
            M[1, 0] * bx + M[1, 1] * by + M[1, 2] * bz,
            M[2, 0] * bx + M[2, 1] * by + M[2, 2] * bz)


@njit(cache=True)
def _lookup(ts, tid, ok, s, t, f_uv):
    if ok:
        return sample4(ts, tid, s, t, lod_for(ts, tid, f_uv))
    return sample_mean4(ts, tid)


@njit(cache=True)
def _unit01(x):
    return min(max(x, 0.0), 1.0)


# Per-hit functions are INLINE façades: an untextured material (most hits) is
# answered from a few arrays of the material set inside the caller, and only a
# textured one calls a body that takes the scene tuples (a call that passes a
# tuple of dozens of arrays copies it: lights.py measures what that costs).

@njit(**INLINE)
def surface_inputs(ms, ts, g, inst, m, shape, face, u, v, footprint, kd, ks, kt):
    """Lobe weights of material m at a hit into kd, ks, kt (n_bands each);
    returns (roughness, ior, specular_level).

    Without textures these are the constant weights, exactly as compiled. A
    texture on base colour, metallic or transmission recomputes all three as
    Blender's Principled BSDF mixes them: diffuse = B(1-M)(1-T), specular = B M
    (the metal's F0 colour), transmission = B(1-M)T. (inst, shape, face, u, v)
    are the hit as raycast.intersect_closest returns it; `footprint` the ray's
    width at the hit in world metres (see hit_tex_uv)."""
    tex = ms.tex
    if tex[m, 0] < 0 and tex[m, 1] < 0 and tex[m, 2] < 0 and tex[m, 3] < 0:
        for b in range(kd.shape[0]):
            kd[b] = ms.diffuse[m, b]
            ks[b] = ms.specular[m, b]
            kt[b] = ms.transmission[m, b]
        return ms.roughness[m], ms.ior[m], ms.specular_level[m]
    return _textured_inputs(ms, ts, g, inst, m, shape, face, u, v, footprint, kd, ks, kt)


@njit(**CORE)
def _textured_inputs(ms, ts, g, inst, m, shape, face, u, v, footprint, kd, ks, kt):
    """surface_inputs of a material with a texture on one of its lobe inputs."""
    nb = kd.shape[0]
    tex = ms.tex
    rough = ms.roughness[m]
    ok, s, t, f_uv = hit_tex_uv(g, inst, shape, u, v, footprint)
    if tex[m, TEX_ROUGHNESS] >= 0:
        rough = _unit01(_lookup(ts, tex[m, TEX_ROUGHNESS], ok, s, t, f_uv)[0])
    if tex[m, TEX_BASE] < 0 and tex[m, TEX_METALLIC] < 0 and tex[m, TEX_TRANSMISSION] < 0:
        for b in range(nb):
            kd[b] = ms.diffuse[m, b]
            ks[b] = ms.specular[m, b]
            kt[b] = ms.transmission[m, b]
        return rough, ms.ior[m], ms.specular_level[m]
    M = ms.metallic[m]
    T = ms.transmission_weight[m]
    if tex[m, TEX_METALLIC] >= 0:
        M = _unit01(_lookup(ts, tex[m, TEX_METALLIC], ok, s, t, f_uv)[0])
    if tex[m, TEX_TRANSMISSION] >= 0:
        T = _unit01(_lookup(ts, tex[m, TEX_TRANSMISSION], ok, s, t, f_uv)[0])
    cr, cg, cb = 0.0, 0.0, 0.0
    if tex[m, TEX_BASE] >= 0:
        cr, cg, cb, _ = _lookup(ts, tex[m, TEX_BASE], ok, s, t, f_uv)
        cr, cg, cb = _unit01(cr), _unit01(cg), _unit01(cb)
    # a spectral scene turns the texture's colour into a spectrum (a grey stays flat)
    table = ms.bands[0] > 0.0 and tex[m, TEX_BASE] >= 0 and not (cr == cg and cg == cb)
    for b in range(nb):
        if tex[m, TEX_BASE] < 0:
            B = ms.base[m, b]
        elif table:
            B = spectrum.table_band(ms.rgb_table, cr, cg, cb, b)
        elif nb == 3:
            B = cr if b == 0 else cg if b == 1 else cb
        else:                     # grey scenes: the mean of RGB, as the exporter's ctx.bands
            B = cr if ms.bands[0] > 0.0 else (cr + cg + cb) / 3.0
        B = _unit01(B)
        kd[b] = B * (1.0 - M) * (1.0 - T)
        ks[b] = B * M
        kt[b] = B * (1.0 - M) * T
    return rough, ms.ior[m], ms.specular_level[m]


@njit(**INLINE)
def shading_normal(ms, ts, g, inst, m, shape, face, u, v, footprint, nx, ny, nz):
    """The normal-mapped world-space shading normal of a hit (unit), or n itself.

    (nx, ny, nz): the hit's world geometric normal as raycast returns it (not
    flipped towards the ray). The texture holds the tangent-space normal
    Blender's Normal bake writes (0.5 n + 0.5, +X +Y +Z), applied in the frame
    Cycles uses: tangent T along dP/du projected into the surface, bitangent
    sign * (n x T), sign from dP/dv (MikkTSpace's frame for a flat triangle).
    Only mesh triangles with texture UVs are mapped; primitives, CSG and
    L-system shapes return n."""
    if m < 0 or ms.tex[m, TEX_NORMAL] < 0:
        return nx, ny, nz
    return _mapped_normal(ms, ts, g, inst, m, shape, u, v, footprint, nx, ny, nz)


@njit(cache=True)
def _mapped_normal(ms, ts, g, inst, m, shape, u, v, footprint, nx, ny, nz):
    """shading_normal of a material with a normal map."""
    tid = ms.tex[m, TEX_NORMAL]
    ok, s, t, f_uv = hit_tex_uv(g, inst, shape, u, v, footprint)
    if not ok:
        return nx, ny, nz
    r = g.shape_index[shape]
    uv = g.tri_tex_uv
    du1 = uv[r, 1, 0] - uv[r, 0, 0]
    dv1 = uv[r, 1, 1] - uv[r, 0, 1]
    du2 = uv[r, 2, 0] - uv[r, 0, 0]
    dv2 = uv[r, 2, 1] - uv[r, 0, 1]
    det = du1 * dv2 - du2 * dv1
    e1x, e1y, e1z, e2x, e2y, e2z = _world_edges(g, inst, r)
    # dP/du and dP/dv (world): the edges solved against their UV deltas
    tx = (dv2 * e1x - dv1 * e2x) / det
    ty = (dv2 * e1y - dv1 * e2y) / det
    tz = (dv2 * e1z - dv1 * e2z) / det
    bx = (du1 * e2x - du2 * e1x) / det
    by = (du1 * e2y - du2 * e1y) / det
    bz = (du1 * e2z - du2 * e1z) / det
    d = tx * nx + ty * ny + tz * nz
    tx -= d * nx
    ty -= d * ny
    tz -= d * nz
    ln = math.sqrt(tx * tx + ty * ty + tz * tz)
    if not ln > 0.0:
        return nx, ny, nz
    tx /= ln
    ty /= ln
    tz /= ln
    cx = ny * tz - nz * ty
    cy = nz * tx - nx * tz
    cz = nx * ty - ny * tx
    sign = 1.0 if cx * bx + cy * by + cz * bz >= 0.0 else -1.0
    cr, cg, cb, _ = _lookup(ts, tid, ok, s, t, f_uv)
    a = 2.0 * cr - 1.0
    b = 2.0 * cg - 1.0
    c = 2.0 * cb - 1.0
    ox = a * tx + b * sign * cx + c * nx
    oy = a * ty + b * sign * cy + c * ny
    oz = a * tz + b * sign * cz + c * nz
    ln = math.sqrt(ox * ox + oy * oy + oz * oz)
    if not ln > 0.0:
        return nx, ny, nz
    return ox / ln, oy / ln, oz / ln
