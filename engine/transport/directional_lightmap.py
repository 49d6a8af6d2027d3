"""Directional lightmaps: which way a texel's light comes from, so that a normal-mapped
surface shows its bumps under baked light.

Per texel the bake knows its irradiance E (the plain lightmap) and, from the direct
gather's light samples, the first moment of the direct light: the sum of each
sample's irradiance times its direction (band-averaged). Light reaching the texel
otherwise (the photons' and gather rays' light) enters as a uniform hemisphere
around the texel's normal n, whose moment is 2/3 E n. Their sum, over E, is the
irradiance-weighted mean direction v of all the light (|v| = 1 for one distant
light, 2/3 for a uniform sky).

The texel's light is modelled as a share k of one distant light from direction s
plus (1 - k) uniform hemisphere: v = k s + (1 - k) 2/3 n, solved for k and s per
texel (exact for a sun alone, for a sky alone, and for a mixture of the two). The
image stores u = k s (world space). For a shading normal n' the irradiance is then

    E(n') = E · [k · max(0, n'·s) / (n·s) + (1 - k) · (1 + n'·n) / 2]

which is E itself where n' = n: a flat surface reads exactly the plain lightmap.
bake/hooks.py builds these nodes for EEVEE (n: Geometry > True Normal).
"""
import numpy as np

from ..lightmaps import lightmap
from .texel_gather import MOMENTS

AMBIENT_MOMENT = 2.0 / 3.0        # |v| of a uniform hemisphere: ∫ cos² dω / ∫ cos dω
# n·s below this is taken as this: a light grazing the surface (its E share tiny)
# would otherwise make a bump facing it arbitrarily bright
MIN_COS = 0.05


def dominant(v, n):
    """Share k and direction s of the distant light in v = k s + (1 - k) (2/3) n
    (v, n: (K, 3), n unit) -> u = k s (K, 3), k clipped to [0, 1]."""
    c = AMBIENT_MOMENT * n
    a = v - c
    ac = np.einsum("ij,ij->i", a, c)
    aa = np.einsum("ij,ij->i", a, a)
    # |a + k c| = k: (1 - |c|²) k² - 2 (a·c) k - |a|² = 0, the positive root
    q = 1.0 - AMBIENT_MOMENT ** 2
    k = (ac + np.sqrt(np.maximum(ac * ac + q * aa, 0.0))) / q
    k = np.clip(k, 0.0, 1.0)
    w = v - (1.0 - k)[:, None] * c
    length = np.linalg.norm(w, axis=1)
    s = np.divide(w, length[:, None], out=np.zeros_like(w), where=length[:, None] > 1e-12)
    return k[:, None] * s


def direction_channels(cs, E_lum):
    """Every lightmap row's u = k s (RGB) and coverage (A), dilated into the texels
    around the charts as the irradiance is -> float64 (rows, 4). E_lum: each row's
    band-averaged irradiance as the bake wrote it. Rows without moments (not baked
    now, or no direct light gathered) hold 0: all light as ambient."""
    lm = cs.lightmaps
    moments = getattr(cs, "bake_moments", None)
    u = np.zeros((lm.area.shape[0], 3))
    if moments is not None and moments[0].size:
        ids, mom, E_direct = moments
        n = mom[:, 3:MOMENTS]
        length = np.linalg.norm(n, axis=1, keepdims=True)
        n = np.divide(n, length, out=np.zeros_like(n), where=length > 0.0)
        E = E_lum[ids]
        ambient = np.maximum(E - E_direct.mean(axis=1), 0.0)
        v = np.divide(mom[:, 0:3] + AMBIENT_MOMENT * ambient[:, None] * n, E[:, None],
                      out=np.zeros((ids.size, 3)), where=E[:, None] > 0.0)
        u[ids] = dominant(v, n)
    # dilation: the rows' u as a 3-band "irradiance" through the lightmap's own fill
    carrier = lm._replace(flux=u * (lm.area * lm.open)[:, None], irradiance=np.zeros_like(u),
                          state=lm.state.copy())
    lightmap.finalize(carrier)
    out = np.zeros((u.shape[0], 4))
    out[:, :3] = carrier.irradiance
    out[:, 3] = lm.coverage
    return out
