"""Material textures: the images `Scene.textures` holds, as mip pyramids the kernels sample.

Every texture becomes a pyramid of box-filtered levels (each texel the mean of
the 2x2 texels below it; an odd side keeps its last row or column alone), all
levels of all textures in one flat float32 array, texels of C floats (1: data,
read as grey; 3: RGB; 4: RGBA), so a kernel takes one namedtuple of a few
arrays and a scalar map costs a quarter of a colour one. Lookups follow Blender's image
conventions: texel (0, 0) is the bottom-left corner, texel centres sit at
((i + 0.5) / W, (j + 0.5) / H), UVs wrap (Repeat), and within a level the
interpolation is bilinear (Cycles' "Linear"); between levels it is linear in
log2 of the footprint (trilinear).

Textures with encoding "srgb" (8-bit sRGB images, see scene.Texture) keep
sRGB-encoded RGB in every level, interpolate it and decode the result, as
Cycles does; their coarser levels are box means of the decoded values,
re-encoded, so a minified texture keeps its true linear mean.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..core import memory_budget
from ..core.scene import SceneError

# tex_first[k]: first level (row of level_*) of texture k; tex_levels[k]: its count;
# tex_channels[k]: floats per texel, 1 (data), 3 (RGB) or 4 (RGBA);
# tex_srgb[k]: 1 when its RGB is sRGB-encoded (decoded after interpolation).
# level_offset[l]: first float of level l in `texels`; level_w/h: its size.
TextureSet = namedtuple("TextureSet", "texels tex_first tex_levels tex_channels tex_srgb "
                                      "level_offset level_w level_h")
ENCODINGS = ("linear", "srgb")

MAX_SIDE = 16384


def _texels(pixels, what):
    """(H, W, C) float32 with C in (1, 3, 4): grey + alpha becomes RGBA."""
    a = np.asarray(pixels, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 2, 3, 4) or a.shape[0] < 1 or a.shape[1] < 1:
        raise SceneError(f"{what}: pixels must have shape (H, W, C) with C in 1..4, got {a.shape}")
    if max(a.shape[:2]) > MAX_SIDE:
        raise SceneError(f"{what}: {a.shape[1]}x{a.shape[0]} exceeds {MAX_SIDE} texels per side")
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{what}: pixels contain NaN or infinity")
    if a.shape[2] == 2:
        a = np.concatenate([a[..., :1], a[..., :1], a[..., :1], a[..., 1:]], axis=2)
    return a


def _float(x):
    """x as a float array of its own precision (float32 at least)."""
    x = np.asarray(x)
    return x.astype(np.result_type(x.dtype, np.float32), copy=False)


def srgb_to_linear(x):
    """sRGB-encoded values (byte images) -> scene linear (the one decoder: export uses it too)."""
    x = _float(x)
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4).astype(x.dtype)


def linear_to_srgb(x):
    x = _float(x)
    return np.where(x <= 0.0031308, x * 12.92,
                    1.055 * np.maximum(x, 0.0031308) ** (1.0 / 2.4) - 0.055).astype(x.dtype)


def mip_levels(texels, srgb=False):
    """The pyramid of an (H, W, C) array, finest first, down to 1x1; `srgb`: the
    RGB of `texels` is sRGB-encoded, averaged decoded and re-encoded per level."""
    if srgb:
        a = np.array(texels, np.float32)
        a[..., :3] = srgb_to_linear(a[..., :3])
        levels = mip_levels(a)
        for lv in levels[1:]:
            lv[..., :3] = linear_to_srgb(lv[..., :3])
        return [np.asarray(texels, np.float32)] + levels[1:]
    levels = [np.asarray(texels, np.float32)]
    while levels[-1].shape[0] > 1 or levels[-1].shape[1] > 1:
        a = levels[-1]
        h, w = a.shape[:2]
        # pad an odd side by repeating its edge, so the lone texel is averaged with itself
        if h % 2 and h > 1:
            a = np.concatenate([a, a[-1:]], axis=0)
        if w % 2 and w > 1:
            a = np.concatenate([a, a[:, -1:]], axis=1)
        if a.shape[0] > 1:
            a = 0.5 * (a[0::2] + a[1::2])
        if a.shape[1] > 1:
            a = 0.5 * (a[:, 0::2] + a[:, 1::2])
        levels.append(a)
    return levels


def compile_textures(scene, n_bands=None):
    """The TextureSet of scene.textures (an empty one when there are none).

    Colour textures are RGB; 3 bands use them as they are and 1 band their
    mean (as the exporter's ctx.bands does); a spectral scene's bands take the
    spectrum of their colour (materials.py). Other band counts would need a
    spectral upsampling the scene does not describe, so they are refused."""
    n_bands = int(scene.n_bands if n_bands is None else n_bands)
    texs = list(getattr(scene, "textures", None) or [])
    if texs and n_bands not in (1, 3) and getattr(scene, "spectral", None) is None:
        raise SceneError(f"textures need 3 (RGB) or 1 (grey) colour bands, the scene has {n_bands}")
    need = sum(4 * np.prod(np.shape(t.pixels)[:2]) * (np.shape(t.pixels) + (1,))[2] * 4 / 3
               for t in texs)
    memory_budget.check(f"{len(texs)} material textures", need,
                        "lower the texture resolution (export/textures.py TEXEL_DENSITY, MAX_SIDE)")
    first, count, chans, srgb, offs, ws, hs, chunks = [], [], [], [], [], [], [], []
    n = 0
    for k, tex in enumerate(texs):
        what = f"texture '{getattr(tex, 'name', k)}'"
        px = _texels(tex.pixels, what)
        enc = getattr(tex, "encoding", "linear")
        if enc not in ENCODINGS:
            raise SceneError(f"{what}: encoding must be one of {ENCODINGS}, got {enc!r}")
        first.append(len(offs))
        chans.append(px.shape[2])
        srgb.append(int(enc == "srgb" and px.shape[2] >= 3))
        lv = mip_levels(px, srgb[-1] == 1)
        count.append(len(lv))
        for a in lv:
            offs.append(n)
            hs.append(a.shape[0])
            ws.append(a.shape[1])
            chunks.append(a.reshape(-1))
            n += a.size
    texels = np.concatenate(chunks) if chunks else np.zeros(4, np.float32)
    return TextureSet(np.ascontiguousarray(texels, np.float32),
                      np.array(first, np.int32).reshape(-1), np.array(count, np.int32).reshape(-1),
                      np.array(chans, np.int32).reshape(-1), np.array(srgb, np.int32).reshape(-1),
                      np.array(offs, np.int64).reshape(-1),
                      np.array(ws, np.int32).reshape(-1), np.array(hs, np.int32).reshape(-1))


def texture_bytes(ts):
    return int(sum(a.nbytes for a in ts))


@njit(cache=True)
def _bilinear(ts, lvl, nc, s, t):
    """Bilinear RGBA lookup of level `lvl` (nc floats per texel) at (s, t), wrapped;
    one channel reads as grey, three as opaque RGB."""
    W = ts.level_w[lvl]
    H = ts.level_h[lvl]
    base = ts.level_offset[lvl]
    s -= math.floor(s)           # wrap first: huge UVs would overflow the integer texel index
    t -= math.floor(t)
    x = s * W - 0.5
    y = t * H - 0.5
    fx = math.floor(x)
    fy = math.floor(y)
    ax = x - fx
    ay = y - fy
    i0 = int(fx) % W             # Python modulo: x = -0.5 wraps to the last column
    j0 = int(fy) % H
    i1 = (i0 + 1) % W
    j1 = (j0 + 1) % H
    w00 = (1.0 - ax) * (1.0 - ay)
    w10 = ax * (1.0 - ay)
    w01 = (1.0 - ax) * ay
    w11 = ax * ay
    p00 = base + nc * (j0 * W + i0)
    p10 = base + nc * (j0 * W + i1)
    p01 = base + nc * (j1 * W + i0)
    p11 = base + nc * (j1 * W + i1)
    x = ts.texels
    r = w00 * x[p00] + w10 * x[p10] + w01 * x[p01] + w11 * x[p11]
    if nc == 1:
        return r, r, r, 1.0
    g = w00 * x[p00 + 1] + w10 * x[p10 + 1] + w01 * x[p01 + 1] + w11 * x[p11 + 1]
    b = w00 * x[p00 + 2] + w10 * x[p10 + 2] + w01 * x[p01 + 2] + w11 * x[p11 + 2]
    if nc == 3:
        return r, g, b, 1.0
    a = w00 * x[p00 + 3] + w10 * x[p10 + 3] + w01 * x[p01 + 3] + w11 * x[p11 + 3]
    return r, g, b, a


@njit(cache=True)
def _decode(c):
    """sRGB -> linear for one channel (clamped below at 0, as bytes are)."""
    if c <= 0.04045:
        return max(c, 0.0) / 12.92
    return ((c + 0.055) / 1.055) ** 2.4


@njit(cache=True)
def lod_for(ts, tid, footprint_uv):
    """Mip level (fractional) for a footprint of `footprint_uv` UV units: log2 of
    the footprint in texels of the finest level, clamped to the pyramid."""
    l0 = ts.tex_first[tid]
    side = max(ts.level_w[l0], ts.level_h[l0])
    px = footprint_uv * side
    if not px > 1.0:             # also NaN: the finest level
        return 0.0
    return min(math.log2(px), float(ts.tex_levels[tid] - 1))


@njit(cache=True)
def sample4(ts, tid, s, t, lod):
    """(r, g, b, a) of texture `tid` at UV (s, t): bilinear within the two levels
    around `lod` (clamped to the pyramid), linear between them. Allocates nothing."""
    if not (math.isfinite(s) and math.isfinite(t)):
        s = 0.0
        t = 0.0
    top = ts.tex_levels[tid] - 1
    nc = ts.tex_channels[tid]
    if not lod > 0.0:
        lod = 0.0
    if lod >= top:
        r, g, b, a = _bilinear(ts, ts.tex_first[tid] + top, nc, s, t)
    else:
        l = int(math.floor(lod))
        f = lod - l
        r, g, b, a = _bilinear(ts, ts.tex_first[tid] + l, nc, s, t)
        if f > 0.0:
            r1, g1, b1, a1 = _bilinear(ts, ts.tex_first[tid] + l + 1, nc, s, t)
            r += f * (r1 - r)
            g += f * (g1 - g)
            b += f * (b1 - b)
            a += f * (a1 - a)
    if ts.tex_srgb[tid] != 0:
        r, g, b = _decode(r), _decode(g), _decode(b)
    return r, g, b, a


@njit(cache=True)
def sample(ts, tid, s, t, lod, out4):
    """sample4 into out4[0:4]."""
    out4[0], out4[1], out4[2], out4[3] = sample4(ts, tid, s, t, lod)


@njit(cache=True)
def sample_mean4(ts, tid):
    """The texture's mean (its 1x1 level): what a surface without texture UVs sees."""
    return sample4(ts, tid, 0.5, 0.5, 1e30)
