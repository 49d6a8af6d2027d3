"""Optional Intel Open Image Denoise pass (pyoidn) for renders and baked lightmaps.

Off by default (Settings.denoise): a denoiser trades noise for bias, and the
benchmarks score that trade (benchmarks/run_all.py, curves *_oidn).

* Renders: OIDN's "RT" filter, HDR, with the first hit's albedo and shading
  normal (renderer.render_aux) as auxiliary images when given.
* Lightmaps: the "RTLightmap" filter (trained on texel noise, no aux images).
  Texels outside every UV chart hold no surface: they are filled from the
  charts before filtering, so the network sees no black border to blur into
  the chart edges, and get their input values back afterwards. Face tiles of a
  primitive are filtered one by one, so light does not bleed across a tile seam
  onto an unrelated face.

pyoidn is imported on first use only: without it every other feature works,
and asking for denoising fails with one line saying what to install.
"""
import numpy as np

from ..core.scene import SceneError

PYOIDN_REQUIREMENT = "pyoidn==2.5.1"


class DenoiseUnavailable(SceneError):
    """Denoising was asked for but pyoidn cannot be imported (a user error, not a bug)."""


def _oidn():
    try:
        import pyoidn
    except Exception as exc:  # noqa: BLE001 - ImportError, or its native library failing to load
        raise DenoiseUnavailable(
            f"denoise: the pyoidn package is not available ({type(exc).__name__}: {exc}); "
            f"install it ({PYOIDN_REQUIREMENT}) or turn Denoise off") from None
    return pyoidn


def require():
    """Raises DenoiseUnavailable now, before a long photon pass, rather than after it."""
    _oidn()


def available():
    """True when pyoidn imports (the UI shows a note otherwise)."""
    try:
        _oidn()
    except DenoiseUnavailable:
        return False
    return True


def _rgb(a, name):
    a = np.asarray(a)
    if a.ndim != 3 or a.shape[2] != 3 or min(a.shape[:2]) == 0:
        raise ValueError(f"{name}: expected a (height, width, 3) image, got shape {a.shape}")
    # OIDN's HDR mode expects finite, non-negative values: one NaN would spread over the
    # network's receptive field.
    return np.ascontiguousarray(np.maximum(np.nan_to_num(a.astype(np.float32), nan=0.0, posinf=0.0), 0.0))


def denoise_image(color, albedo=None, normal=None):
    """A render (H, W, 3) linear radiance -> denoised float32 (H, W, 3) (RT filter, HDR).

    albedo in [0, 1] and normal in [-1, 1], same shape, improve edges and texture
    detail; both or either may be None."""
    pyoidn = _oidn()
    c = _rgb(color, "color")
    kw = {}
    if albedo is not None:
        kw["albedo"] = np.clip(_rgb(albedo, "albedo"), 0.0, 1.0)
    if normal is not None:
        n = np.asarray(normal, np.float32)
        if n.shape != c.shape:
            raise ValueError(f"normal: expected shape {c.shape}, got {n.shape}")
        kw["normal"] = np.ascontiguousarray(np.clip(np.nan_to_num(n), -1.0, 1.0))
    # The aux images come from noise-free primary rays (only anti-aliasing jitter,
    # the same as the colour's), so OIDN need not prefilter them.
    clean = bool(kw)
    return pyoidn.denoise(c, hdr=True, clean_aux=clean, quality="high", filter_type="RT", **kw)


def _fill_empty(img, known):
    """Pull-push fill: unknown texels take the known-weighted mean of the nearest
    coarser level that has data, so the filter sees a smooth continuation of the
    chart instead of a jump to black (that jump would darken the chart's rim)."""
    h, w = known.shape
    wt = known.astype(np.float32)
    levels = [(img * wt[..., None], wt)]
    while max(levels[-1][1].shape) > 1:
        c, k = levels[-1]
        hh, ww = k.shape
        ph, pw = hh + (hh & 1), ww + (ww & 1)
        cp = np.zeros((ph, pw, c.shape[2]), np.float32)
        kp = np.zeros((ph, pw), np.float32)
        cp[:hh, :ww], kp[:hh, :ww] = c, k
        c2 = cp.reshape(ph // 2, 2, pw // 2, 2, -1).sum(axis=(1, 3))
        k2 = kp.reshape(ph // 2, 2, pw // 2, 2).sum(axis=(1, 3))
        levels.append((c2, k2))
    c, k = levels[-1]
    value = c / np.maximum(k, 1e-30)[..., None]
    for c, k in reversed(levels[:-1]):
        hh, ww = k.shape
        up = np.repeat(np.repeat(value, 2, axis=0), 2, axis=1)[:hh, :ww]
        value = np.where(k[..., None] > 0, c / np.maximum(k, 1e-30)[..., None], up)
    return np.where(known[..., None], img, value).astype(np.float32)


def denoise_lightmap(lightmap_image, covered=None, tiles=1):
    """A baked lightmap (H, W, 3) -> denoised float32 (H, W, 3) (RTLightmap filter).

    covered: bool (H, W), the texels some UV triangle touches (coverage > 0);
    the others come back exactly as they went in. None: all texels are surface.
    tiles: face tiles side by side (width = tiles * R, engine/lightmaps/lightmap.py), each
    filtered on its own."""
    pyoidn = _oidn()
    src = np.asarray(lightmap_image, np.float32)
    img = _rgb(src, "lightmap_image")
    h, w = img.shape[:2]
    known = np.ones((h, w), bool) if covered is None else np.asarray(covered, bool)
    if known.shape != (h, w):
        raise ValueError(f"covered: expected shape {(h, w)}, got {known.shape}")
    tiles = max(int(tiles), 1)
    if w % tiles:
        raise ValueError(f"tiles: {tiles} does not divide the width {w}")
    r = w // tiles
    out = src.astype(np.float32, copy=True)
    for t in range(tiles):
        sl = np.s_[:, t * r:(t + 1) * r]
        k = known[sl]
        if not k.any():
            continue
        filled = _fill_empty(img[sl], k)
        den = pyoidn.denoise(np.ascontiguousarray(filled), filter_type="RTLightmap", quality="high")
        out[sl] = np.where(k[..., None], den, out[sl])
    return out
