"""Conductors: metals at their measured complex index n + ik (thesis Appendix A.3).

A metal's reflectance follows from its complex index through Fresnel's
equations (polarization.fresnel): a colour and how it changes toward grazing
angles, and, for polarized light, the phase between the s and p components.
Blender's Principled metal has no index (Schlick's colour); a conductor
preset, or Blender's Metallic BSDF with its Physical Conductor Fresnel, gives
the metal lobe one: its Fresnel is then the conductor's, weighted by the
metallic share, and the base colour no longer colours it.

Presets (`PRESETS`): silver, aluminium, gold and copper, measured (Palik, as
scripts/make_conductor_data.py takes them). In spectral mode each band has the
mean index over its wavelengths. In RGB each channel has the index at the
channel's wavelength (`RGB_NM`); the colour then differs a little from the
measured spectrum's (see `rgb_index`).

An index given per RGB channel (the Metallic BSDF's IOR and Extinction) is
taken at `RGB_NM` and interpolated between them in spectral mode.
"""
import functools
import pathlib

import numpy as np
from numba import njit

from . import polarization

DATA = pathlib.Path(__file__).resolve().parent / "data" / "conductors.npz"
PRESETS = ("Ag", "Al", "Au", "Cu")
NAMES = {"Ag": "Silver", "Al": "Aluminium", "Au": "Gold", "Cu": "Copper"}
# the wavelengths an RGB index stands for
RGB_NM = (650.0, 550.0, 460.0)


@functools.lru_cache(maxsize=None)
def measured(name):
    """(wavelength nm, n, k) arrays of preset `name`."""
    if name not in PRESETS:
        raise ValueError(f"unknown conductor '{name}' (presets: {', '.join(PRESETS)})")
    with np.load(DATA) as z:
        t = z[name]
    return t[:, 0].copy(), t[:, 1].copy(), t[:, 2].copy()


def normal_reflectance(n, k):
    """Fresnel reflectance at normal incidence of index n + ik."""
    n, k = np.asarray(n, np.float64), np.asarray(k, np.float64)
    return ((n - 1.0) ** 2 + k * k) / ((n + 1.0) ** 2 + k * k)


@functools.lru_cache(maxsize=None)
def rgb_index(name):
    """(3, 2): (n, k) per RGB channel of preset `name`: the measured index at `RGB_NM`.
    (Matching each channel's reflectance of the measured spectrum instead fails for
    gold, whose red lies outside Rec.709: it asks for a reflectance of 1.)"""
    wl, n, k = measured(name)
    return np.stack([np.interp(RGB_NM, wl, n), np.interp(RGB_NM, wl, k)], axis=1)


def band_index(conductor, n_bands, bands=None):
    """(n_bands, 2): (n, k) per band of `conductor`, a preset name or an (n, k) pair whose
    parts are a scalar or per RGB channel; bands: spectrum.Bands in spectral mode."""
    if isinstance(conductor, str):
        if bands is not None:
            wl, n, k = measured(conductor)
            return bands.band_mean(wl, np.stack([n, k], axis=1))
        nk = rgb_index(conductor)
    else:
        try:
            n, k = conductor
            n = np.broadcast_to(np.asarray(n, np.float64).reshape(-1), (3,))
            k = np.broadcast_to(np.asarray(k, np.float64).reshape(-1), (3,))
        except (TypeError, ValueError):
            raise ValueError(f"a conductor is a preset ({', '.join(PRESETS)}) or an (n, k) pair, "
                             f"got {conductor!r}") from None
        if not (np.all(np.isfinite(n)) and np.all(np.isfinite(k)) and np.all(n > 0.0) and np.all(k >= 0.0)):
            raise ValueError(f"a conductor's index needs n > 0 and k >= 0, got n={n.tolist()}, k={k.tolist()}")
        nk = np.stack([n, k], axis=1)
        if bands is not None:
            order = np.argsort(RGB_NM)
            wl = np.asarray(RGB_NM)[order]
            return bands.band_mean(wl, nk[order])
    if n_bands == 3:
        return nk.copy()
    return np.repeat(nk.mean(axis=0, keepdims=True), n_bands, axis=0)     # grey scenes


def mean_reflectance(n, k, steps=256):
    """2 ∫ F(μ) μ dμ over the hemisphere: the unpolarized reflectance averaged over
    cosine-weighted incidence (a multiscatter lobe's F_avg)."""
    mu = (np.arange(steps) + 0.5) / steps
    f_s, f_p, _, _ = polarization.fresnel_retardance(mu, n, k)
    return float(2.0 * np.mean(0.5 * (f_s + f_p) * mu))


@njit(cache=True)
def reflectance(cos_i, n, k):
    """Unpolarized Fresnel reflectance of index n + ik at incidence cos_i."""
    f_s, f_p, _, _ = polarization.fresnel(cos_i, n, k)
    return 0.5 * (f_s + f_p)
