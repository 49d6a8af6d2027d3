"""Dispersion (thesis Appendix A.1): a dielectric's index of refraction per wavelength.

Glass catalogues give each glass as three Sellmeier terms,

    n(λ)² = 1 + Σ_i B_i λ² / (λ² - C_i)        (λ in µm, C_i in µm²),

which hold to a few 1e-6 over the visible range. A material that only knows
its index at the d line and its Abbe number V_d = (n_d - 1) / (n_F - n_C), as
Blender users and glass tables often quote them, gets Cauchy's two-term fit
n(λ) = A + B / λ² through n_d with that V_d.

In the passes (spectral mode only) a path carries every band until it meets a
dispersive surface; there it keeps one band, picked in proportion to what the
path carries in each (so the pick's weight leaves its total unchanged), and one
wavelength within that band, and from there on refracts at that wavelength
(the hero wavelength of A.1.2, with the others dropped rather than carried).
A path's wavelength state is two numbers (`WAVE_*`): the band it keeps (-1:
all of them) and its wavelength in nm.

The presets are catalogue data (Schott for N-BK7, N-SF11 and SF6; Malitson 1965
for fused silica; Peter 1923 for diamond), with the catalogue's own n_d and V_d
beside them, which the tests hold the Sellmeier terms to.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..core.jit import CORE, INLINE
from ..core.sampling import next_float

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


# ------------------------------------------------------------------ in the kernels

# A material's dispersion as the kernels read it: a row of DISPERSION_SIZE floats,
# [kind, then Sellmeier B1 B2 B3 C1 C2 C3, or Cauchy A B].
NONE, SELLMEIER, CAUCHY = 0, 1, 2
DISPERSION_SIZE = 7
# a path's wavelength state: the band it keeps (-1: every band) and its wavelength, nm
WAVE_BAND, WAVE_NM = 0, 1


def dispersion_row(glass="", abbe=0.0, ior=1.5, spectral=True, what="material"):
    """(row, n_d) of a material: its kernel row (NONE unless `spectral`) and the
    index RGB traces; `glass` a PRESETS name, else `abbe` > 0 spreads `ior` as n_d."""
    row = np.zeros(DISPERSION_SIZE)
    glass = str(glass or "")
    if glass:
        if glass not in PRESETS:
            raise ValueError(f"{what}: unknown glass '{glass}' (one of {', '.join(PRESETS)})")
        g = PRESETS[glass]
        row[0] = SELLMEIER
        row[1:4], row[4:7] = g.B, g.C
        n_d = float(sellmeier_index(g, LINE_D))
    elif abbe:
        try:
            A, B = cauchy_from_abbe(float(ior), float(abbe))
        except ValueError as e:
            raise ValueError(f"{what}: {e}; give it an IOR above 1 and an Abbe number above 0, "
                             "or turn its dispersion off") from None
        row[0], row[1], row[2] = CAUCHY, A, B
        n_d = float(ior)
    else:
        return row, float(ior)
    if not spectral:
        row[:] = 0.0
    return row, n_d


@njit(cache=True)
def index_at(row, nm):
    """n at wavelength nm of a dispersion row."""
    l2 = (nm * 1e-3) ** 2
    if row[0] == SELLMEIER:
        n2 = 1.0
        for i in range(3):
            n2 += row[1 + i] * l2 / (l2 - row[4 + i])
        return math.sqrt(max(n2, 1e-6))
    return row[1] + row[2] / l2


@njit(**INLINE)
def splits_bands(disp, m, wave):
    """True where material m (rows `disp`) disperses and the path still carries every band."""
    return m >= 0 and disp[m, 0] != NONE and wave[WAVE_BAND] < 0.0


@njit(**INLINE)
def path_ior(disp, m, ior, wave):
    """Material m's index for a path: at its wavelength where m disperses and
    the path has kept one band, else `ior` (n_d)."""
    if disp[m, 0] == NONE or wave[WAVE_BAND] < 0.0:
        return ior
    return index_at(disp[m], wave[WAVE_NM])


@njit(**CORE)
def keep_one_band(bands, tp, wave, state):
    """The path (throughput tp per band) keeps one band k, picked with
    probability tp[k] / sum(tp), and one wavelength uniform in it: tp becomes
    sum(tp) in band k and 0 elsewhere (tp[k] over its probability), so the
    expected throughput is unchanged in every band and the total exactly.
    bands = (n, lo nm, width nm) -> state."""
    nb = tp.shape[0]
    total = 0.0
    for b in range(nb):
        total += tp[b]
    state, u = next_float(state)
    state, v = next_float(state)
    if not total > 0.0:
        return state
    k = -1
    c = 0.0
    for b in range(nb):
        if tp[b] > 0.0:
            k = b               # rounding past the end keeps the last band that carries light
            c += tp[b]
            if u * total < c:
                break
    for b in range(nb):
        tp[b] = total if b == k else 0.0
    wave[WAVE_BAND] = k
    wave[WAVE_NM] = bands[1] + (k + v) * bands[2]
    return state
