"""Dispersion (thesis Appendix A.1): a dielectric's index of refraction per wavelength.

Glass catalogues give each glass as three Sellmeier terms,

    n(λ)² = 1 + Σ_i B_i λ² / (λ² - C_i)        (λ in µm, C_i in µm²),

which hold to a few 1e-6 over the visible range. A material that only knows
its index at the d line and its Abbe number V_d = (n_d - 1) / (n_F - n_C), as
Blender users and glass tables often quote them, gets Cauchy's two-term fit
n(λ) = A + B / λ² through n_d with that V_d.

The presets are catalogue data (Schott for N-BK7, N-SF11 and SF6; Malitson 1965
for fused silica; Peter 1923 for diamond), with the catalogue's own n_d and V_d
beside them, which the tests hold the Sellmeier terms to.
"""
import math
from collections import namedtuple

import numpy as np

# Fraunhofer lines, nm: F (hydrogen), d (helium), C (hydrogen)
LINE_F, LINE_D, LINE_C = 486.1327, 587.5618, 656.2725

Glass = namedtuple("Glass", ["name", "B", "C", "n_d", "abbe"])

PRESETS = {g.name: g for g in (
    Glass("N-BK7", (1.03961212, 0.231792344, 1.01046945), (0.00600069867, 0.0200179144, 103.560653),
          1.51680, 64.17),
    Glass("N-SF11", (1.73759695, 0.313747346, 1.89878101), (0.013188707, 0.0623068142, 155.23629),
          1.78472, 25.68),
    Glass("SF6", (1.72448482, 0.390104889, 1.04572858), (0.0134871947, 0.0569318095, 118.557185),
          1.80518, 25.43),
    Glass("fused silica", (0.6961663, 0.4079426, 0.8974794), (0.0684043 ** 2, 0.1162414 ** 2, 9.896161 ** 2),
          1.45846, 67.82),
    # two terms (Peter 1923); its n_d is catalogued to four decimals only
    Glass("diamond", (0.3306, 4.3356, 0.0), (0.1750 ** 2, 0.1060 ** 2, 1.0), 2.4175, 55.3),
)}


def sellmeier_index(glass, wavelength_nm):
    """n of a Glass (or (B, C)) at wavelength_nm (scalar or array)."""
    B, C = (glass.B, glass.C) if isinstance(glass, Glass) else glass
    l2 = (np.asarray(wavelength_nm, np.float64) * 1e-3) ** 2
    n2 = 1.0 + sum(b * l2 / (l2 - c) for b, c in zip(B, C))
    return np.sqrt(n2)


def cauchy_from_abbe(n_d, abbe):
    """(A, B) of n(λ) = A + B / λ² (λ in µm) through n_d at the d line with Abbe number `abbe`."""
    if not (n_d > 1.0 and abbe > 0.0 and math.isfinite(n_d) and math.isfinite(abbe)):
        raise ValueError(f"dispersion: need n_d > 1 and an Abbe number > 0, got n_d={n_d}, V_d={abbe}")
    k = (LINE_F * 1e-3) ** -2 - (LINE_C * 1e-3) ** -2
    B = (n_d - 1.0) / (abbe * k)
    return n_d - B / (LINE_D * 1e-3) ** 2, B


def cauchy_index(A, B, wavelength_nm):
    """n = A + B / λ² at wavelength_nm."""
    return A + B / (np.asarray(wavelength_nm, np.float64) * 1e-3) ** 2


def abbe_number(index_at):
    """V_d of a dispersion given as a function n(λ nm)."""
    return (index_at(LINE_D) - 1.0) / (index_at(LINE_F) - index_at(LINE_C))


def minimum_deviation(n, apex_deg=60.0):
    """Minimum deviation (degrees) of a prism of index n and apex angle apex_deg in air."""
    a = math.radians(apex_deg)
    return math.degrees(2.0 * math.asin(n * math.sin(0.5 * a)) - a)
