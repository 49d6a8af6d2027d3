"""Directional lightmaps: which way a texel's light comes from, so that a normal-mapped
surface shows its bumps under baked light.

Per texel the bake knows its irradiance E (the plain lightmap) and, per band, the
first moment of its light: the sum of each light sample's and each gather ray's
irradiance times the direction it came from (texel_gather.add_moment). Light
whose direction the bake does not keep (caustic photons; the photons' own light
in a bake without the gather) enters as a uniform hemisphere around the
texel's normal n, whose moment is 2/3 E n. The band-averaged sum, over E, is
the irradiance-weighted mean direction v of all the light (|v| = 1 for one
distant light, 2/3 for a uniform sky).

The texel's light is modelled as a share k of one distant light from direction s
plus (1 - k) uniform hemisphere: v = k s + (1 - k) 2/3 n, solved for k and s per
texel (exact for a sun alone, for a sky alone, and for a mixture of the two). The
image stores u = k s (world space). For a shading normal n' the irradiance is then

    E(n') = E · [k · max(0, n'·s) / (n·s) + (1 - k) · (1 + n'·n) / 2]

which is E itself where n' = n: a flat surface reads exactly the plain lightmap.
bake/hooks.py builds these nodes for EEVEE (n: Geometry > True Normal).

That is one direction for all colours (as Unity's directional mode and Bakery's
MonoSH). The per-band option (bake --directional sh) solves the same model per
band and stores it as first-order spherical harmonics of irradiance per band,
E(n') = c0 + c1·n' (l1_coefficients), as Godot's and Bakery's L1 SH: light of
different colours from different sides keeps its colours on a bump, but L1 widens
a key light's lobe (a bump facing a sun is under-lit).
"""
import numpy as np

from ..lightmaps import lightmap

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


def _moments(cs, E):
    """Rows with moments: (ids, n (K, 3) unit normals, per-band first moments (K, nb, 3)
    with the light they do not cover added as ambient, E (K, nb)), or None. E:
    every lightmap row's irradiance per band as the bake wrote it."""
    moments = getattr(cs, "bake_moments", None)
    if moments is None or not moments[0].size:
        return None
    ids, mom, E_covered = moments
    nb = E_covered.shape[1]
    n = mom[:, 3 * nb:3 * nb + 3]
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0.0)
    E = E[ids]
    ambient = np.maximum(E - E_covered, 0.0)
    m = mom[:, :3 * nb].reshape(-1, nb, 3) + AMBIENT_MOMENT * ambient[:, :, None] * n[:, None, :]
    return ids, n, m, E


def _dilated(cs, values):
    """Every lightmap row's `values` (rows, C) dilated into the texels around the
    charts as the irradiance is (through the lightmap's own fill)."""
    lm = cs.lightmaps
    carrier = lm._replace(flux=values * (lm.area * lm.open)[:, None], irradiance=np.zeros_like(values),
                          state=lm.state.copy())
    lightmap.finalize(carrier)
    return carrier.irradiance


def direction_channels(cs, E):
    """Every lightmap row's u = k s (RGB) and coverage (A), dilated into the texels
    around the charts as the irradiance is -> float64 (rows, 4). E: each row's
    irradiance per band as the bake wrote it. Rows without moments (not baked
    now) hold 0: all light as ambient."""
    lm = cs.lightmaps
    u = np.zeros((lm.area.shape[0], 3))
    got = _moments(cs, E)
    if got is not None:
        ids, n, m, E_rows = got
        E_sum = E_rows.sum(axis=1)
        v = np.divide(m.sum(axis=1), E_sum[:, None], out=np.zeros((ids.size, 3)), where=E_sum[:, None] > 0.0)
        u[ids] = dominant(v, n)
    out = np.zeros((u.shape[0], 4))
    out[:, :3] = _dilated(cs, u)
    out[:, 3] = lm.coverage
    return out


def l1_coefficients(E, u, n):
    """Per band, the L1 irradiance of the model v = k s + (1 - k) 2/3 n: E(n') ≈ c0 +
    c1·n', from the distant light's radiance (its irradiance at normal incidence
    I = k E / max(n·s, MIN_COS)) and the ambient hemisphere's (A = (1 - k) E).
    The clamped cosine's expansion to first order is 1/4 + (n'·ω)/2, so

        c0 = (I + 2 A) / 4,   c1 = (I s + A n) / 2

    scaled so that c0 + c1·n = E: a flat surface reads exactly the lightmap.
    A sky alone comes out exact; a sun alone as L1 sees it (its lobe widened).
    E (K, nb), u = k s (K, nb, 3), n (K, 3) -> L1 = c1 (K, nb, 3); c0 = E - L1·n."""
    k = np.linalg.norm(u, axis=2)
    s = np.divide(u, k[..., None], out=np.zeros_like(u), where=k[..., None] > 1e-12)
    cos = np.einsum("kbj,kj->kb", s, n)
    I = k * E / np.maximum(cos, MIN_COS)
    A = (1.0 - k) * E
    c1 = 0.5 * (I[..., None] * s + A[..., None] * n[:, None, :])
    at_n = 0.25 * (I + 2.0 * A) + np.einsum("kbj,kj->kb", c1, n)
    scale = np.divide(E, at_n, out=np.zeros_like(E), where=at_n > 0.0)
    return scale[..., None] * c1


def l1_channels(cs, E):
    """A per-band (L1 SH) directional bake's coefficients: every lightmap row's L1
    (rows, nb, 3) per band and axis, dilated as the irradiance is. The L0
    coefficient is E - L1·n (n: the surface's normal), so the lightmap and L1 give
    E(n') = E + L1·(n' - n) for a shading normal n' (bake/hooks.py)."""
    lm = cs.lightmaps
    rows, nb = lm.area.shape[0], E.shape[1]
    L1 = np.zeros((rows, nb, 3))
    got = _moments(cs, E)
    if got is not None:
        ids, n, m, E_rows = got
        v = np.divide(m, E_rows[..., None], out=np.zeros_like(m), where=E_rows[..., None] > 0.0)
        K = ids.size
        u = dominant(v.reshape(K * nb, 3), np.repeat(n, nb, axis=0)).reshape(K, nb, 3)
        L1[ids] = l1_coefficients(E_rows, u, n)
    return _dilated(cs, L1.reshape(rows, 3 * nb)).reshape(rows, nb, 3)
