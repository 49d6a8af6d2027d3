"""Fluorescence (thesis Appendix A.3): bispectral re-radiation.

A fluorescent surface absorbs light at λ_i with its excitation spectrum a(λ_i)
and re-emits part of it at longer wavelengths λ_o > λ_i (the Stokes shift),
spread by its emission spectrum e(λ_o), Lambertian like its diffuse light. The
quantum yield q counts photons out per photon absorbed; a photon's energy goes
as 1/λ, so the power re-emitted at λ_o per unit absorbed at λ_i is

    q e(λ_o) λ_i / λ_o      for λ_o > λ_i (e normalised over all wavelengths).

Over the bands this is a re-radiation matrix M[o, i]: the power band o gains
per unit irradiance in band i, the double integral averaged over band i's
wavelengths (light taken as flat within a band). It is zero for o < i. The
fluorophore absorbs first, so the surface's diffuse reflectance in band i is at
most 1 - ā_i (ā_i: a's mean over band i); then reflected plus re-emitted never
exceeds what arrives, in each input band:

    kd_i + Σ_o M[o, i] <= (1 - ā_i) + q ā_i <= 1.

The diffuse lobe of a fluorescent material is the matrix diag(kd) + M: photons
change bands through it (power moves from band i to o), and the camera pass and
gathers apply it to the irradiance per band they read. Spectral mode only: RGB
has no wavelengths to shift between.

Spectra are Gaussians: a(λ) = peak exp(-(λ - μ_a)² / 2σ_a²), e(λ) the normal
density N(μ_e, σ_e). The presets are Gaussian fits of published spectra (peak
and width, to a few nm): a stilbene-type optical brightener (absorbs in the
near UV, glows blue; Shu et al. 2013), fluorescein in basic solution (quantum
yield 0.93, Sjöback et al. 1995), and a fluorescent yellow pigment, which is the
test model of the reference notes (excitation 450/20 nm, emission 520/25 nm).
"""
import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..core.jit import INLINE


@dataclass(frozen=True)
class Fluorescence:
    """A fluorophore: excitation peak (nm), its width σ (nm) and peak absorption (0-1);
    emission peak and width (nm); quantum yield (photons out per photon absorbed, 0-1)."""
    name: str = "fluorescent"
    excitation_nm: float = 450.0
    excitation_width: float = 20.0
    emission_nm: float = 520.0
    emission_width: float = 25.0
    peak: float = 0.8
    quantum_yield: float = 0.9

    def check(self, what="material"):
        vals = (self.excitation_nm, self.excitation_width, self.emission_nm, self.emission_width, self.peak,
                self.quantum_yield)
        if not (all(math.isfinite(float(v)) for v in vals) and self.excitation_width > 0.0
                and self.emission_width > 0.0 and self.excitation_nm > 0.0 and self.emission_nm > 0.0):
            raise ValueError(f"{what}: fluorescence needs positive finite peaks and widths, got {self}")
        if not (0.0 <= self.peak <= 1.0 and 0.0 <= self.quantum_yield <= 1.0):
            raise ValueError(f"{what}: fluorescence absorption and quantum yield must lie in [0, 1], "
                             f"got {self.peak} and {self.quantum_yield}")

    def absorption(self, nm):
        """a(λ), the fraction of light at nm the fluorophore absorbs."""
        x = (np.asarray(nm, np.float64) - self.excitation_nm) / self.excitation_width
        return self.peak * np.exp(-0.5 * x * x)

    def emission(self, nm):
        """e(λ) per nm (a normal density: it integrates to 1 over all wavelengths)."""
        x = (np.asarray(nm, np.float64) - self.emission_nm) / self.emission_width
        return np.exp(-0.5 * x * x) / (self.emission_width * math.sqrt(2.0 * math.pi))


PRESETS = {f.name: f for f in (
    Fluorescence("optical brightener", 365.0, 25.0, 440.0, 25.0, 0.9, 0.8),
    Fluorescence("fluorescein", 490.0, 15.0, 517.0, 17.0, 0.9, 0.93),
    Fluorescence("fluorescent yellow", 450.0, 20.0, 520.0, 25.0, 0.8, 0.9),
)}


def band_absorption(fl, bands, per_band=64):
    """ā per band: a's mean over each band of spectrum.Bands `bands`."""
    w = (bands.hi - bands.lo) / bands.n
    nm = bands.lo + (np.arange(bands.n)[:, None] + (np.arange(per_band) + 0.5) / per_band) * w
    return fl.absorption(nm).mean(axis=1)


def reradiation_matrix(fl, bands, step_nm=0.25):
    """M[o, i] (bands.n x bands.n) of Fluorescence fl over spectrum.Bands `bands`: the power
    re-emitted into band o per unit irradiance in band i (light flat within band i)."""
    n = int(bands.n)
    w = (bands.hi - bands.lo) / n
    per_band = max(int(math.ceil(w / step_nm)), 2)
    h = w / per_band
    nm = bands.lo + (np.arange(n * per_band) + 0.5) * h          # midpoints, per_band to a band
    band = np.arange(n * per_band) // per_band
    a = fl.absorption(nm)
    e = fl.emission(nm)
    li, lo = nm[None, :], nm[:, None]
    # kernel[o, i]: power density at lo per unit power at li; the point lo = li counts half
    shifted = np.where(lo > li, 1.0, np.where(lo == li, 0.5, 0.0))
    kernel = fl.quantum_yield * a[None, :] * e[:, None] * (li / lo) * shifted
    out = np.zeros((n, n))
    np.add.at(out, (band[:, None], band[None, :]), kernel * h * (h / w))
    return out


def compile_fluorescence(fl, kd, bands, what="material"):
    """(M, kd') of a material with Fluorescence fl and diffuse reflectance kd (per band):
    the re-radiation matrix and the reflectance left beside the fluorophore's absorption."""
    fl.check(what)
    kd = np.minimum(np.asarray(kd, np.float64), 1.0 - band_absorption(fl, bands))
    return reradiation_matrix(fl, bands), kd


# ------------------------------------------------------------------ in the kernels
# ms: materials.MaterialSet; ms.fluorescent[m] flags a fluorescent material, ms.fluor[m]
# is its M[o, i] and ms.fluor_albedo[m, i] = sum over o of M[o, i].

@njit(**INLINE)
def diffuse_probability(ms, m, kd, ds, lobes):
    """The lobe probabilities with the diffuse one raised to cover fluorescence: the largest
    kd_b + what band b re-emits, within what the other lobes leave."""
    pd, ps, pm, pg = lobes
    if m < 0 or not ms.fluorescent[m]:
        return lobes
    p = pd
    for b in range(kd.shape[0]):
        p = max(p, (kd[b] + ms.fluor_albedo[m, b]) * ds)
    return min(p, max(1.0 - ps - pm - pg, 0.0)), ps, pm, pg


@njit(**INLINE)
def reflected(ms, m, kd, e, b):
    """Band b of what the diffuse lobe of fluorescent material m sends back from irradiance
    e (per band): kd[b] e[b] plus what fluorescence moves into band b from e. Callers
    test ms.fluorescent[m] once, outside their band loops (plain materials: kd[b] e[b])."""
    r = kd[b] * e[b]
    for i in range(e.shape[0]):
        r += ms.fluor[m, b, i] * e[i]
    return r
