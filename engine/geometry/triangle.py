"""Watertight ray–triangle intersection (Woop, Benthin & Wald, JCGT 2013).

The ray is turned into a canonical frame in which it starts at the origin and
points along +z: translate by the origin, permute the axes so that the
dominant direction component becomes z, and shear x and y so the direction
becomes (0, 0, 1). The hit test then reduces to 2D edge functions of the
sheared vertices. Because every vertex is transformed independently of the
triangle it belongs to, a shared edge produces exactly negated edge
functions in its two triangles, so a ray can never pass between them (no
cracks at edges or vertices). Edge functions equal to zero count as inside.

The split into a per-ray setup (`woop_setup`) and a per-triangle test on
already permuted vertices (`woop_test`) lets the traversal do the setup once
per ray and space. Everything is float64 and must not be compiled with
fastmath: contraction into FMAs would break the exact negation above.
"""

from numba import njit


@njit(cache=True, error_model="numpy", inline="always")
def woop_setup(dx, dy, dz):
    """Per-ray constants: axis permutation (kx, ky, kz) and shear (sx, sy, sz).

    kz is the dominant axis of the direction; kx, ky are swapped when the
    dominant component is negative so the permutation keeps the winding.
    (Branches rather than tuple indexing: this runs once per ray and space.)
    """
    ax, ay, az = abs(dx), abs(dy), abs(dz)
    if ax >= ay and ax >= az:
        kx, ky, kz = 1, 2, 0
        ex, ey, ez = dy, dz, dx
    elif ay >= az:
        kx, ky, kz = 2, 0, 1
        ex, ey, ez = dz, dx, dy
    else:
        kx, ky, kz = 0, 1, 2
        ex, ey, ez = dx, dy, dz
    if ez < 0.0:
        kx, ky = ky, kx
        ex, ey = ey, ex
    sz = 1.0 / ez
    return kx, ky, kz, ex * sz, ey * sz, sz


@njit(cache=True, error_model="numpy", inline="always")
def pick(k, x, y, z):
    """Component k of (x, y, z) without indexing a tuple."""
    if k == 0:
        return x
    if k == 1:
        return y
    return z


@njit(cache=True, error_model="numpy", inline="always")
def woop_test(ax, ay, az, bx, by, bz, cx, cy, cz, sx, sy, sz, tmin, tmax):
    """Hit test on vertices already relative to the ray origin and permuted.

    (a?, b?, c?) are the three vertices minus the origin, with components
    taken in (kx, ky, kz) order. Returns (hit, t, b1, b2); t is strictly
    inside (tmin, tmax), and the hit point is (1-b1-b2)·v0 + b1·v1 + b2·v2.
    Written without early exits: the decision is one combined test, which
    costs fewer mispredicted branches than rejecting edge by edge.
    """
    # shear so the ray runs along +z through the origin
    px = ax - sx * az
    py = ay - sy * az
    qx = bx - sx * bz
    qy = by - sy * bz
    rx = cx - sx * cz
    ry = cy - sy * cz
    # scaled barycentrics: signed 2D areas seen from the ray
    u = rx * qy - ry * qx
    v = px * ry - py * rx
    w = qx * py - qy * px
    neg = (u < 0.0) | (v < 0.0) | (w < 0.0)
    pos = (u > 0.0) | (v > 0.0) | (w > 0.0)
    det = u + v + w
    inv = 1.0 / det                    # inf/nan when det == 0: the tests below fail
    t = (u * az + v * bz + w * cz) * sz * inv
    hit = (not (neg & pos)) & (t > tmin) & (t < tmax)
    return hit, t, v * inv, w * inv


@njit(cache=True, error_model="numpy")
def intersect_triangle(p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z,
                       ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Stand-alone watertight test of one triangle: (hit, t, b1, b2)."""
    kx, ky, kz, sx, sy, sz = woop_setup(dx, dy, dz)
    okx, oky, okz = pick(kx, ox, oy, oz), pick(ky, ox, oy, oz), pick(kz, ox, oy, oz)
    return woop_test(pick(kx, p0x, p0y, p0z) - okx, pick(ky, p0x, p0y, p0z) - oky,
                     pick(kz, p0x, p0y, p0z) - okz,
                     pick(kx, p1x, p1y, p1z) - okx, pick(ky, p1x, p1y, p1z) - oky,
                     pick(kz, p1x, p1y, p1z) - okz,
                     pick(kx, p2x, p2y, p2z) - okx, pick(ky, p2x, p2y, p2z) - oky,
                     pick(kz, p2x, p2y, p2z) - okz,
                     sx, sy, sz, tmin, tmax)


@njit(cache=True, error_model="numpy", inline="always")
def triangle_normal(p0x, p0y, p0z, p1x, p1y, p1z, p2x, p2y, p2z):
    """Unnormalised geometric normal (p1-p0) x (p2-p0): counter-clockwise is front."""
    ex, ey, ez = p1x - p0x, p1y - p0y, p1z - p0z
    fx, fy, fz = p2x - p0x, p2y - p0y, p2z - p0z
    return ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
