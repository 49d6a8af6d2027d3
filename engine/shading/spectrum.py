"""Spectral bands (thesis Appendix A.1): colour as wavelengths instead of RGB.

The tracer is band-generic: every colour is an array of shape (..., n_bands).
In spectral mode the bands are wavelength intervals, N_BANDS of them, equally
wide over 380-780 nm. 16 bands of 25 nm: a prism's rainbow needs a band
narrower than the eye can tell hues apart in (about 20-30 nm in the middle of
the spectrum), and every band adds a colour channel to each texel and path
(16 bands: 5.3x the memory and arithmetic of RGB). Outside 380-780 nm the
CIE 1931 observer sees less than 0.05 % of its peak, so light there does not
reach the image; it still carries energy (fluorescence turns UV into visible
light).

* To RGB: a band spectrum S goes to CIE XYZ through the colour matching
  functions averaged over each band (`Bands.cmf`, from the CIE 1931 2-degree
  observer at 1 nm, engine/shading/data/, written by
  scripts/make_spectral_data.py from colour-science's data), and on to
  Blender's scene-linear Rec.709 by the matrix of its primaries and the
  bands' own D65 white, so the white light spectrum gives RGB (1, 1, 1) exactly.
* From RGB: a reflectance is a smooth spectrum, the sigmoid of a quadratic in
  wavelength (Jakob & Hanika 2019), whose three coefficients are fitted to the
  colour by damped Gauss-Newton against the bands' own matrix, so a colour
  comes back through the bands as it went in (to 1e-6), and 0 < R(λ) < 1 by
  construction. An emitted colour is its brightest channel times a reflectance
  times the white light (D65): lights and glowing surfaces keep their RGB too.

A scene in spectral mode and the same scene in RGB then agree where their
colours are grey (every band alike) and, elsewhere, to the extent that
products of spectra differ from products of their RGB colours.
"""
import functools
import pathlib
from dataclasses import dataclass

import numpy as np
from numba import njit

LO_NM, HI_NM = 380.0, 780.0
N_BANDS = 16
DATA = pathlib.Path(__file__).resolve().parent / "data" / "cie_1931_2deg.npz"

# Rec.709 / sRGB primaries (ITU-R BT.709), chromaticities x, y
REC709_PRIMARIES = ((0.640, 0.330), (0.300, 0.600), (0.150, 0.060))


@functools.lru_cache(maxsize=1)
def cie_tables():
    """(wavelength nm (K,), x̄ȳz̄ (K, 3), D65 (K,)) at 1 nm over 360-830 nm."""
    with np.load(DATA) as z:
        return z["wavelength"].copy(), z["xyz"].copy(), z["d65"].copy()


@dataclass(frozen=True)
class Bands:
    """n equal wavelength bands over [lo, hi] nm."""
    n: int = N_BANDS
    lo: float = LO_NM
    hi: float = HI_NM

    def __post_init__(self):
        if int(self.n) < 3 or not (0.0 < self.lo < self.hi):
            raise ValueError(f"spectral bands: need at least 3 bands over a positive range, got {self}")

    @property
    def edges(self):
        return np.linspace(self.lo, self.hi, int(self.n) + 1)

    @property
    def centres(self):
        e = self.edges
        return 0.5 * (e[:-1] + e[1:])

    @property
    def width(self):
        return (self.hi - self.lo) / int(self.n)

    def band_mean(self, wavelength, values):
        """Mean of tabulated `values` (K, ...) at `wavelength` (K,) over each band
        (linear interpolation, integrated at 0.1 nm) -> (n, ...)."""
        values = np.asarray(values, np.float64)
        fine = np.linspace(self.lo, self.hi, 10 * int(round(self.hi - self.lo)) + 1)
        cols = values.reshape(len(wavelength), -1)
        f = np.stack([np.interp(fine, wavelength, c) for c in cols.T], axis=1)
        e = self.edges
        out = np.empty((int(self.n), cols.shape[1]))
        for b in range(int(self.n)):
            m = (fine >= e[b]) & (fine <= e[b + 1])
            out[b] = np.trapz(f[m], fine[m], axis=0) / (e[b + 1] - e[b])
        return out.reshape((int(self.n),) + values.shape[1:])

    @functools.cached_property
    def cmf(self):
        """(n, 3): x̄ȳz̄ integrated over each band, so XYZ = Σ_b S_b cmf_b."""
        wl, xyz, _ = cie_tables()
        return self.band_mean(wl, xyz) * self.width

    @functools.cached_property
    def white(self):
        """(n,): the white light, D65 scaled so that its luminance Y is 1."""
        wl, _, d65 = cie_tables()
        w = self.band_mean(wl, d65)
        return w / float(w @ self.cmf[:, 1])

    @functools.cached_property
    def xyz_to_rgb(self):
        """3 x 3: XYZ -> scene-linear Rec.709, with these bands' white at RGB (1, 1, 1)."""
        return np.linalg.inv(rgb_to_xyz_matrix(self.white @ self.cmf))

    @functools.cached_property
    def to_rgb_matrix(self):
        """(n, 3): a band spectrum's RGB is spectrum @ to_rgb_matrix."""
        return self.cmf @ self.xyz_to_rgb.T

    @functools.cached_property
    def reflectance_matrix(self):
        """(n, 3): the RGB of a reflectance under the white light is R @ this."""
        return self.white[:, None] * self.to_rgb_matrix


def rgb_to_xyz_matrix(white_xyz, primaries=REC709_PRIMARIES):
    """3 x 3 RGB -> XYZ of an RGB space with these primaries whose (1, 1, 1) is white_xyz."""
    P = np.array([[x / y, 1.0, (1.0 - x - y) / y] for x, y in primaries]).T     # columns: the primaries' XYZ
    return P * np.linalg.solve(P, np.asarray(white_xyz, np.float64))[None, :]


def to_rgb(spectrum, bands):
    """Band spectra (..., n) -> scene-linear Rec.709 (..., 3)."""
    return np.asarray(spectrum, np.float64) @ bands.to_rgb_matrix


def as_rgb(values, bands=None):
    """Band values (..., n) as Rec.709 (..., 3): through `bands` when they are
    spectral, as they are when RGB, and as a grey of their mean otherwise."""
    if bands is not None:
        return to_rgb(values, bands)
    if values.shape[-1] == 3:
        return values
    return np.repeat(values.mean(axis=-1, keepdims=True), 3, axis=-1)


# ----------------------------------------------------------------- RGB -> spectrum

def _sigmoid(x):
    return 0.5 + x / (2.0 * np.sqrt(1.0 + x * x))


def reflectance_coefficients(rgb, bands, iterations=60):
    """Jakob & Hanika's three coefficients of the reflectance of each colour in
    `rgb` (..., 3), fitted to its RGB under the white light -> (..., 3).
    Components are held inside [1e-4, 1 - 1e-4]: a sigmoid never reaches 0 or 1.
    The fit starts from the grey of the colour's luminance; colours it leaves
    more than 1e-6 off (saturated purples, which need a dip in the middle of the
    spectrum, not a bump) start again from a dip and from a bump."""
    rgb = np.clip(np.asarray(rgb, np.float64), 1e-4, 1.0 - 1e-4)
    shape = rgb.shape
    target = rgb.reshape(-1, 3)
    grey = target @ np.array([0.2126, 0.7152, 0.0722])
    c0 = np.zeros_like(target)
    c0[:, 2] = (2.0 * grey - 1.0) / np.sqrt(1.0 - (2.0 * grey - 1.0) ** 2)
    c, res = _fit(target, c0, bands, iterations)
    for curve in (40.0, -40.0):
        bad = res > 1e-6
        if not bad.any():
            break
        start = c0[bad].copy()
        start[:, 0], start[:, 1] = curve, -curve        # vertex at the middle of the range
        c2, r2 = _fit(target[bad], start, bands, iterations)
        keep = r2 < res[bad]
        idx = np.flatnonzero(bad)[keep]
        c[idx], res[idx] = c2[keep], r2[keep]
    return c.reshape(shape)


def _fit(target, c, bands, iterations):
    """Damped Gauss-Newton from coefficients c (m, 3) -> (c, largest channel error)."""
    c = c.copy()
    t = (bands.centres - bands.lo) / (bands.hi - bands.lo)        # wavelength scaled to [0, 1]
    basis = np.stack([t * t, t, np.ones_like(t)], axis=1)           # (n, 3)
    A = bands.reflectance_matrix                                   # (n, 3)
    lam = np.full(len(target), 1e-3)
    for _ in range(iterations):
        x = c @ basis.T                                             # (m, n)
        r = _sigmoid(x) @ A - target                                # (m, 3)
        ds = 0.5 / (1.0 + x * x) ** 1.5                             # sigmoid'
        J = np.einsum("mb,bk,bj->mkj", ds, A, basis)                # d rgb_k / d c_j
        JtJ = np.einsum("mkj,mki->mji", J, J)
        g = np.einsum("mkj,mk->mj", J, r)
        step = -np.linalg.solve(JtJ + lam[:, None, None] * np.eye(3), g[..., None])[..., 0]
        cn = c + step
        rn = _sigmoid(cn @ basis.T) @ A - target
        better = (rn * rn).sum(1) < (r * r).sum(1)
        c[better] = cn[better]
        lam = np.clip(np.where(better, lam * 0.3, lam * 10.0), 1e-10, 1e10)
        if np.all(np.abs(np.where(better[:, None], rn, r)) < 1e-9):
            break
    return c, np.abs(_sigmoid(c @ basis.T) @ A - target).max(axis=1)


def reflectance_spectrum(rgb, bands):
    """A reflectance colour (..., 3) in [0, 1] -> its band spectrum (..., n), each band in (0, 1)."""
    c = reflectance_coefficients(rgb, bands)
    t = (bands.centres - bands.lo) / (bands.hi - bands.lo)
    x = c[..., 0:1] * t * t + c[..., 1:2] * t + c[..., 2:3]
    return _sigmoid(x)


RGB_TABLE_SIDE = 17


@functools.lru_cache(maxsize=4)
def rgb_table(bands, side=RGB_TABLE_SIDE):
    """(side, side, side, n): the reflectance spectra of an even grid over the RGB cube
    (reflectance_spectrum at each grid colour), for colours only known per hit (textures).

    Interpolated trilinearly between grid colours, the spectra (not their
    coefficients) give back the colour exactly: a spectrum's RGB is linear in it,
    and trilinear interpolation reproduces a linear function. A mix of sigmoids
    stays within (0, 1), but is not the sigmoid fitted to that colour itself: a
    textured colour's spectrum differs a little from the same colour given as a
    constant (the same RGB under the white light, a little apart under others)."""
    g = np.linspace(0.0, 1.0, int(side))
    grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1)
    return np.ascontiguousarray(reflectance_spectrum(grid, bands))


@njit(cache=True)
def table_band(table, r, g, b, band):
    """Band `band` of the spectrum of colour (r, g, b) in [0, 1]: trilinear in the RGB
    grid's spectra `table` (rgb_table), which gives the colour back exactly."""
    k = table.shape[0] - 1
    fr, fg, fb = r * k, g * k, b * k
    i, j, l = min(int(fr), k - 1), min(int(fg), k - 1), min(int(fb), k - 1)
    wr, wg, wb = fr - i, fg - j, fb - l
    out = 0.0
    for di in range(2):
        for dj in range(2):
            for dl in range(2):
                w = (wr if di else 1.0 - wr) * (wg if dj else 1.0 - wg) * (wb if dl else 1.0 - wb)
                out += w * table[i + di, j + dj, l + dl, band]
    return out


@njit(cache=True)
def _table_spectra(table, rgb, out):
    for p in range(rgb.shape[0]):
        for band in range(out.shape[1]):
            out[p, band] = table_band(table, rgb[p, 0], rgb[p, 1], rgb[p, 2], band)


def table_spectrum(rgb, bands):
    """Reflectance spectra (..., n) of colours (..., 3) in [0, 1] through rgb_table (trilinear):
    the colour back exactly, for as many colours as an image has, without a fit each."""
    rgb = np.clip(np.asarray(rgb, np.float64), 0.0, 1.0)
    flat = np.ascontiguousarray(rgb.reshape(-1, 3))
    out = np.empty((flat.shape[0], int(bands.n)))
    _table_spectra(rgb_table(bands), flat, out)
    return out.reshape(rgb.shape[:-1] + (int(bands.n),))


def emission_spectrum(rgb, bands):
    """An emitted colour (..., 3), any brightness -> band spectrum (..., n):
    its brightest channel times a reflectance times the white light."""
    rgb = np.asarray(rgb, np.float64)
    # headroom, so the brightest channel is not clipped to the sigmoid's range
    peak = np.max(rgb, axis=-1, keepdims=True) * (1.0 + 2e-4)
    safe = np.where(peak > 0.0, peak, 1.0)
    return np.where(peak > 0.0, peak, 0.0) * reflectance_spectrum(rgb / safe, bands) * bands.white


def blackbody_spectrum(kelvin, bands):
    """Planck's radiance over the bands (band means), scaled to luminance Y = 1 -> (n,)."""
    h, c, k = 6.62607015e-34, 2.99792458e8, 1.380649e-23
    wl = np.linspace(bands.lo, bands.hi, 10 * int(round(bands.hi - bands.lo)) + 1)
    lm = wl * 1e-9
    with np.errstate(over="ignore"):
        planck = 2.0 * h * c * c / lm ** 5 / np.expm1(h * c / (lm * k * float(kelvin)))
    s = bands.band_mean(wl, planck)
    return s / float(s @ bands.cmf[:, 1])


def luminance(spectrum, bands):
    """CIE Y of band spectra (..., n)."""
    return np.asarray(spectrum, np.float64) @ bands.cmf[:, 1]


def line_spectrum(nm, fwhm, bands):
    """(n,): a Gaussian line at nm of full width fwhm (nm), averaged over each band, with the
    white light's total over the bands (a line light of a given power carries a white one's)."""
    sigma = float(fwhm) / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    w = (bands.hi - bands.lo) / bands.n
    lam = bands.lo + (np.arange(bands.n)[:, None] + (np.arange(64) + 0.5) / 64) * w
    g = np.exp(-0.5 * ((lam - float(nm)) / sigma) ** 2).mean(axis=1)
    # its share of the full line inside the bands: (what the bands hold) / (the line's whole integral)
    inside = float(g.sum() * w / (sigma * np.sqrt(2.0 * np.pi)))
    return g * (bands.white.sum() / max(float(g.sum()), 1e-300)) * min(inside, 1.0)
