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


# Per-point maps through a (3, 4) or (3, 3) array; plain njit functions, which
# LLVM inlines at their call sites without the compile cost of inline="always".

@njit(cache=True)
def apply_point(m, x, y, z):
    """m [R|t] applied to the point (x, y, z)."""
    return (m[0, 0] * x + m[0, 1] * y + m[0, 2] * z + m[0, 3],
            m[1, 0] * x + m[1, 1] * y + m[1, 2] * z + m[1, 3],
            m[2, 0] * x + m[2, 1] * y + m[2, 2] * z + m[2, 3])


@njit(cache=True)
def apply_linear(m, x, y, z):
    """R (the 3x3 part of m) applied to the vector (x, y, z)."""
    return (m[0, 0] * x + m[0, 1] * y + m[0, 2] * z,
            m[1, 0] * x + m[1, 1] * y + m[1, 2] * z,
            m[2, 0] * x + m[2, 1] * y + m[2, 2] * z)


@njit(cache=True)
def apply_transposed(m, x, y, z):
    """R^T applied to (x, y, z): a normal through the inverse-transpose, given the inverse."""
    return (m[0, 0] * x + m[1, 0] * y + m[2, 0] * z,
            m[0, 1] * x + m[1, 1] * y + m[2, 1] * z,
            m[0, 2] * x + m[1, 2] * y + m[2, 2] * z)


@njit(cache=True)
def cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
