"""World light: a constant radiance or an equirectangular map, importance-sampled.

Direction <-> map follows Blender's equirectangular convention (Cycles'
`direction_to_equirectangular`, checked against a Cycles render in
tests/test_world.py):

    u = -atan2(d.y, d.x) / (2 pi) + 0.5        v = atan2(d.z, hypot(d.x, d.y)) / pi + 0.5

so u = 0.5 looks along +x, u = 0.25 along +y, and row 0 is the bottom (v = 0, d.z = -1).

Lookups are *nearest* pixel: the map is then exactly piecewise constant, so the
integral of L (the world's power, the photons' exact flux) is a finite sum, and
the sampling pdf is proportional to the very function the kernels return
(bilinear filtering would light directions of pixels with zero pdf: a bias).
At the default 1024 x 512 a pixel spans 0.35 degrees, below what a diffuse or
glossy lobe resolves.

Sampling: pixel (j, i) is chosen with probability lum(j, i) * dOmega(j) / T,
T = sum lum dOmega (lum = mean over bands), then a direction uniformly *in
solid angle* inside it (uniform in phi and in sin(elevation)), so the pdf is
constant per pixel: pdf(omega) = lum(j, i) / T. In the uv measure this is
pdf_uv = pdf * 2 pi^2 sin(theta), the usual Jacobian (theta the polar angle);
L / pdf = T for a grey map, so photon weights carry no sampling noise.

A constant world is a 1 x 1 map flagged `constant`: it keeps uniform-sphere
sampling, so results are bit-for-bit those of the constant world before maps.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from ..core.sampling import first_above, uniform_sphere
from ..core.scene import SceneError, as_bands

FIELDS = ["pixels", "constant", "lum", "row_cdf", "col_cdf", "sin_edges", "total", "power"]


class EnvMap(namedtuple("EnvMap", FIELDS)):
    """Compiled world light (a namedtuple the kernels take).

    pixels (H, W, B) radiance; constant (bool: 1 x 1, uniform sampling); lum (H, W)
    mean over bands; row_cdf (H + 1,) and col_cdf (H, W + 1) the normalised
    marginal / conditional CDFs of lum * dOmega; sin_edges (H + 1,) sin(elevation)
    of the row edges; total = sum lum dOmega (pdf normaliser, = mean of power);
    power (B,) = integral of L over the sphere, exact for the piecewise-constant map.

    np.asarray(env) is the solid-angle mean radiance per band: hosts that still
    treat the world as one radiance (e.g. a renderer's miss branch before it calls
    radiance()) see the averaged world, and a constant world exactly as before."""
    __slots__ = ()

    def __array__(self, dtype=None, copy=None):
        mean = self.pixels[0, 0] if self.constant else self.power / (4.0 * math.pi)
        return np.array(mean, dtype=dtype if dtype is not None else np.float64)

    @property
    def resolution(self):
        return self.pixels.shape[1], self.pixels.shape[0]

    def nbytes(self):
        return int(sum(getattr(self, f).nbytes for f in ("pixels", "lum", "row_cdf", "col_cdf", "sin_edges",
                                                        "power")))


def _pixel_pixels(env, n_bands):
    """(H, W, n_bands) float64 from an EnvironmentMap's pixels (1 or n_bands channels)."""
    a = np.asarray(env.pixels, dtype=np.float64)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise SceneError(f"environment map '{env.name}': expected (H, W, bands) pixels, got {a.shape}")
    if a.shape[2] == 1 and n_bands != 1:
        a = np.repeat(a, n_bands, axis=2)
    if a.shape[2] != n_bands:
        raise SceneError(f"environment map '{env.name}': expected {n_bands} bands, got {a.shape[2]}")
    if not np.all(np.isfinite(a)):
        raise SceneError(f"environment map '{env.name}': non-finite radiance")
    if np.any(a < 0):
        raise SceneError(f"environment map '{env.name}': radiance must be non-negative")
    return np.ascontiguousarray(a)


def compile_environment(env, n_bands):
    """EnvMap from Scene.environment: a constant (scalar or band array) or an EnvironmentMap."""
    if hasattr(env, "pixels"):
        px = _pixel_pixels(env, n_bands)
        h, w, _ = px.shape
        constant = False
    else:
        c = as_bands(env, n_bands, "environment")
        if np.any(c < 0):
            raise SceneError("environment radiance must be non-negative")
        px = c.reshape(1, 1, n_bands).copy()
        h, w = 1, 1
        constant = True
    lum = px.mean(axis=2)
    sin_edges = -np.cos(np.arange(h + 1) * (math.pi / h))      # sin(elevation) at v = j / h
    sin_edges[0], sin_edges[h] = -1.0, 1.0
    d_omega = (2.0 * math.pi / w) * np.diff(sin_edges)          # solid angle of a pixel of row j
    weight = lum * d_omega[:, None]
    row_sum = weight.sum(axis=1)
    total = float(row_sum.sum())
    power = (px * d_omega[:, None, None]).sum(axis=(0, 1))
    if constant:
        power = px[0, 0] * (4.0 * math.pi)
        total = float(power.mean())
    row_cdf = np.zeros(h + 1)
    col_cdf = np.zeros((h, w + 1))
    if total > 0.0:
        row_cdf[1:] = np.cumsum(row_sum) / total
        row_cdf[h] = 1.0
        for j in range(h):
            if row_sum[j] > 0.0:
                col_cdf[j, 1:] = np.cumsum(weight[j]) / row_sum[j]
                col_cdf[j, w] = 1.0
    return EnvMap(px, bool(constant), np.ascontiguousarray(lum), row_cdf, col_cdf, sin_edges,
                  float(total), np.ascontiguousarray(power, dtype=np.float64))


def describe(ev):
    """The map's numbers for the report: resolution and bytes (None for a constant world)."""
    if ev.constant:
        return None
    w, h = ev.resolution
    return {"width": int(w), "height": int(h), "bytes": ev.nbytes()}


# --------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------

@njit(cache=True)
def direction_to_pixel(ev, dx, dy, dz):
    """(row j, column i) of the map pixel seen along d (need not be unit)."""
    h = ev.pixels.shape[0]
    w = ev.pixels.shape[1]
    u = -math.atan2(dy, dx) / (2.0 * math.pi) + 0.5
    v = math.atan2(dz, math.sqrt(dx * dx + dy * dy)) / math.pi + 0.5
    i = min(max(int(u * w), 0), w - 1)
    j = min(max(int(v * h), 0), h - 1)
    return j, i


@njit(cache=True)
def radiance(ev, dx, dy, dz, out):
    """Writes the world radiance seen along direction d into out[bands] (nearest pixel)."""
    if ev.constant:
        for b in range(out.shape[0]):
            out[b] = ev.pixels[0, 0, b]
        return
    j, i = direction_to_pixel(ev, dx, dy, dz)
    for b in range(out.shape[0]):
        out[b] = ev.pixels[j, i, b]


@njit(cache=True)
def pdf(ev, dx, dy, dz):
    """Solid-angle pdf of sample() for direction d (0 where the map is black)."""
    if ev.constant:
        return 1.0 / (4.0 * math.pi)
    if not ev.total > 0.0:
        return 0.0
    j, i = direction_to_pixel(ev, dx, dy, dz)
    return ev.lum[j, i] / ev.total


@njit(cache=True)
def _sample_pixel(ev, u1, u2):
    """(wx, wy, wz, pdf, j, i): importance sample of a non-constant map and its pixel."""
    h = ev.pixels.shape[0]
    w = ev.pixels.shape[1]
    if not ev.total > 0.0:
        return 0.0, 0.0, 1.0, 0.0, 0, 0
    # Row by the marginal, column by the row's conditional; the remainders of u1 and
    # u2 inside the chosen cells are uniform again and place the point in the pixel.
    j = first_above(ev.row_cdf, u1, 1, h) - 1
    c0 = ev.row_cdf[j]
    r1 = (u1 - c0) / (ev.row_cdf[j + 1] - c0)
    i = first_above(ev.col_cdf[j], u2, 1, w) - 1
    c1 = ev.col_cdf[j, i]
    r2 = (u2 - c1) / (ev.col_cdf[j, i + 1] - c1)
    r1 = min(max(r1, 0.0), 1.0)
    r2 = min(max(r2, 0.0), 1.0)
    s = ev.sin_edges[j] + r1 * (ev.sin_edges[j + 1] - ev.sin_edges[j])
    phi = (0.5 - (i + r2) / w) * (2.0 * math.pi)
    c = math.sqrt(max(0.0, 1.0 - s * s))
    return c * math.cos(phi), c * math.sin(phi), s, ev.lum[j, i] / ev.total, j, i


@njit(cache=True)
def sample(ev, u1, u2):
    """Direction towards the world, importance-sampled: (wx, wy, wz, pdf_solid_angle).

    Constant world: uniform over the sphere (pdf 1/(4 pi)), the same numbers as before maps."""
    if ev.constant:
        wx, wy, wz = uniform_sphere(u1, u2)
        return wx, wy, wz, 1.0 / (4.0 * math.pi)
    wx, wy, wz, p, j, i = _sample_pixel(ev, u1, u2)
    return wx, wy, wz, p


@njit(cache=True)
def sample_radiance(ev, u1, u2, out):
    """sample() that also writes the radiance of the sampled pixel into out[bands]
    (the pixel the sample lies in, so L / pdf never pairs one pixel's L with another's pdf)."""
    if ev.constant:
        wx, wy, wz = uniform_sphere(u1, u2)
        for b in range(out.shape[0]):
            out[b] = ev.pixels[0, 0, b]
        return wx, wy, wz, 1.0 / (4.0 * math.pi)
    wx, wy, wz, p, j, i = _sample_pixel(ev, u1, u2)
    for b in range(out.shape[0]):
        out[b] = ev.pixels[j, i, b]
    return wx, wy, wz, p


@njit(cache=True)
def photon_tint(ev, dx, dy, dz, out):
    """Per-band factor of an environment photon travelling along d (emitted with the
    flux's mean colour): (L_b / lum)(-d) / (power_b / mean power). Its expectation
    over emitted photons is 1 per band, so it colours photons by direction without
    changing the emitted flux. 1 for a constant world."""
    nb = out.shape[0]
    if ev.constant or not ev.total > 0.0:
        for b in range(nb):
            out[b] = 1.0
        return
    j, i = direction_to_pixel(ev, -dx, -dy, -dz)
    lum = ev.lum[j, i]
    for b in range(nb):
        pb = ev.power[b]
        out[b] = ev.pixels[j, i, b] / lum * ev.total / pb if lum > 0.0 and pb > 0.0 else 0.0
