"""Random numbers and warps shared by the photon tracer and the renderer.

The generator is counter based (a 64-bit hash of seed, stream and counter),
so any photon or pixel sample can be regenerated independently of thread
scheduling: this is what makes a parallel photon pass bit-reproducible.
"""
import math

import numpy as np
from numba import njit

_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_INV_2_53 = 1.0 / 9007199254740992.0


@njit(cache=True, inline="always")
def mix64(x):
    """splitmix64 finaliser: a bijective, well-distributed 64-bit hash."""
    x = (x ^ (x >> np.uint64(30))) * _M1
    x = (x ^ (x >> np.uint64(27))) * _M2
    return x ^ (x >> np.uint64(31))


@njit(cache=True)
def stream_state(seed, stream):
    """Initial state for an independent stream (e.g. one photon or one pixel)."""
    return mix64(np.uint64(seed) * _GOLDEN + mix64(np.uint64(stream) + _GOLDEN))


@njit(cache=True, inline="always")
def next_float(state):
    """Returns (new_state, u) with u uniform in [0, 1)."""
    state = state + _GOLDEN
    return state, float(mix64(state) >> np.uint64(11)) * _INV_2_53


@njit(cache=True, inline="always")
def orthonormal_basis(nx, ny, nz):
    """Tangent frame (Duff et al. 2017): returns t and b with (t, b, n) right-handed."""
    sign = 1.0 if nz >= 0.0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx,
            b, sign + ny * ny * a, -ny)


@njit(cache=True, inline="always")
def to_world(lx, ly, lz, nx, ny, nz):
    tx, ty, tz, bx, by, bz = orthonormal_basis(nx, ny, nz)
    return (lx * tx + ly * bx + lz * nx,
            lx * ty + ly * by + lz * ny,
            lx * tz + ly * bz + lz * nz)


@njit(cache=True, inline="always")
def concentric_disk(u1, u2):
    """Shirley–Chiu square -> unit disk map (area-preserving up to a constant)."""
    a = 2.0 * u1 - 1.0
    b = 2.0 * u2 - 1.0
    if a == 0.0 and b == 0.0:
        return 0.0, 0.0
    if abs(a) > abs(b):
        r = a
        phi = (math.pi / 4.0) * (b / a)
    else:
        r = b
        phi = (math.pi / 2.0) - (math.pi / 4.0) * (a / b)
    return r * math.cos(phi), r * math.sin(phi)


@njit(cache=True, inline="always")
def cosine_hemisphere(u1, u2):
    """Cosine-weighted direction about +z (pdf cos/pi)."""
    x, y = concentric_disk(u1, u2)
    z = math.sqrt(max(0.0, 1.0 - x * x - y * y))
    return x, y, z


@njit(cache=True, inline="always")
def uniform_sphere(u1, u2):
    z = 1.0 - 2.0 * u1
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    return r * math.cos(phi), r * math.sin(phi), z


@njit(cache=True, inline="always")
def uniform_cone(u1, u2, cos_max):
    """Uniform direction in the cone of half-angle acos(cos_max) about +z."""
    z = 1.0 - u1 * (1.0 - cos_max)
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * u2
    return r * math.cos(phi), r * math.sin(phi), z


@njit(cache=True)
def first_above(a, x, lo, hi):
    """Smallest i in [lo, hi] with a[i] > x, or hi when there is none (a ascending)."""
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True)
def sample_discrete(cdf, u):
    """Index i with cdf[i-1] <= u*cdf[-1] < cdf[i] (cdf is inclusive, ascending)."""
    return first_above(cdf, u * cdf[cdf.shape[0] - 1], 0, cdf.shape[0] - 1)
