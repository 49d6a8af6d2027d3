"""Affine 3x4 maps [R|t] (row-major, p -> R p + t): inverses at compile time,
rays and normals through the flat copies the kernels read."""
import math

import numpy as np
from numba import njit

from .jit import INLINE


def inverse(a):
    """Inverse of an invertible 3x4 affine map (checked by scene._affine)."""
    inv = np.empty((3, 4))
    r = np.linalg.inv(a[:, :3])
    inv[:, :3] = r
    inv[:, 3] = -r @ a[:, 3]
    return inv


@njit(**INLINE)
def xform_ray(f, m, ox, oy, oz, dx, dy, dz):
    """Ray through the 3x4 row-major affine at f[m:m+12]: point and vector."""
    return (f[m] * ox + f[m + 1] * oy + f[m + 2] * oz + f[m + 3],
            f[m + 4] * ox + f[m + 5] * oy + f[m + 6] * oz + f[m + 7],
            f[m + 8] * ox + f[m + 9] * oy + f[m + 10] * oz + f[m + 11],
            f[m] * dx + f[m + 1] * dy + f[m + 2] * dz,
            f[m + 4] * dx + f[m + 5] * dy + f[m + 6] * dz,
            f[m + 8] * dx + f[m + 9] * dy + f[m + 10] * dz)


@njit(**INLINE)
def normal_through(f, m, nx, ny, nz):
    """Normal through the inverse-transpose, given the inverse at f[m:m+12]."""
    return (f[m] * nx + f[m + 4] * ny + f[m + 8] * nz,
            f[m + 1] * nx + f[m + 5] * ny + f[m + 9] * nz,
            f[m + 2] * nx + f[m + 6] * ny + f[m + 10] * nz)


@njit(**INLINE)
def unit(nx, ny, nz):
    """The vector scaled to length 1 (a zero vector stays zero)."""
    ln = math.sqrt(nx * nx + ny * ny + nz * nz)
    if ln > 0.0:
        return nx / ln, ny / ln, nz / ln
    return nx, ny, nz
