"""Canonical analytic primitives in their local space (thesis 4.1, 5.2).

Every kernel works in the primitive's local space. The caller maps rays with an
affine transform, so ray directions are *not* normalised: every ``t`` returned
here is in units of the given direction and is therefore valid in every space.

Kinds (shared by the whole core, see docs/architecture.md):

====  ==========  ===========================================================
id    name        local definition
====  ==========  ===========================================================
0     TRIANGLE    mesh triangle (engine/geometry/triangle.py, not handled here)
1     SPHERE      unit sphere at the origin
2     BOX         [-1, 1]^3
3     CYLINDER    radius 1, z in [-1, 1], closed by two caps
4     CONE        apex (0, 0, 1), base radius 1 at z = -1, closed by the base
5     TORUS       major radius 1 around z, minor radius params[0] (0 < r < 1)
6     PARABOLOID  z = x^2 + y^2, 0 <= z <= 1, closed by the cap z = 1
7     DISK        unit disk in z = 0, normal +z (open surface)
8     QUAD        [-1, 1]^2 in z = 0, normal +z (open surface)
9     FRUSTUM     truncated cone around z: base radius 1 at z = -1, top radius
                  t = params[0] (0 <= t <= 1) at z = 1, closed by the base and
                  (t > 0) the top cap; t = 1 is the cylinder, t = 0 the cone
====  ==========  ===========================================================

Intersections (``prim_hits``) return *all* crossings of the infinite line,
sorted ascending. Solids always return an even count (0, 2 or, for the torus,
4): entry/exit pairs, which CSG interval classification relies on. Tangent
and grazing contacts (a double root, a ray through an edge or lying in a face
plane) count as *no* hit: the boundary itself is treated as outside, exactly
like ``prim_inside`` (strict inequalities). Open surfaces return 0 or 1 hit.

Faces (charts) and their (u, v) in [0, 1]^2. Every chart is oriented so that
dP/du x dP/dv points outward (the side of the returned normal); seen from
outside, u runs "right" and v "up", so textures are never mirrored.

* SPHERE, face 0: octahedral map (Cigolle et al. 2014) of the unit normal.
* BOX: face 0 +x (u<-y, v<-z), 1 -x (u<-z, v<-y), 2 +y (u<-z, v<-x),
  3 -y (u<-x, v<-z), 4 +z (u<-x, v<-y), 5 -z (u<-y, v<-x); each coordinate
  is mapped from [-1, 1] to [0, 1] as (c + 1) / 2.
* CYLINDER: face 0 side (phi / 2pi, (z + 1) / 2), face 1 cap z = +1,
  face 2 cap z = -1.
* CONE: face 0 side (graph z = 1 - 2 rho over the disk), face 1 base z = -1.
* TORUS, face 0: (phi / 2pi, theta / 2pi); phi around z from +x, theta
  around the tube from the outer equator towards +z.
* PARABOLOID: face 0 side (graph z = rho^2 over the disk), face 1 cap z = 1.
* DISK, face 0; QUAD, face 0: ((x + 1) / 2, (y + 1) / 2).
* FRUSTUM: face 0 side (phi / 2pi, (z + 1) / 2) as the cylinder's, face 1
  base z = -1, face 2 top cap z = +1 of radius t (the concentric map of
  (x / t, y / t)); with t = 0 the top cap has zero area (prim_point maps it
  to the apex) and prim_surface never returns it.

Disk-like charts use the concentric map: (u, v) = inverse_concentric(x, y).
On the faces that look down the disk (cylinder cap z = -1, cone base,
paraboloid side, frustum base, whose outward normals have a -z component) x
and y are swapped, (u, v) = inverse_concentric(y, x), because the concentric
map preserves orientation and the swap is what makes dP/du x dP/dv outward
there.
"""
import math

import numpy as np
from numba import njit, prange

from ..core.affine import inverse
from ..core.sampling import concentric_disk
from ..core.scene import SceneError, as_affine

TRIANGLE = 0
SPHERE = 1
BOX = 2
CYLINDER = 3
CONE = 4
TORUS = 5
PARABOLOID = 6
DISK = 7
QUAD = 8
FRUSTUM = 9

KIND_IDS = {"sphere": SPHERE, "box": BOX, "cylinder": CYLINDER, "cone": CONE,
            "torus": TORUS, "paraboloid": PARABOLOID, "disk": DISK, "quad": QUAD,
            "frustum": FRUSTUM}

# Faces (lightmap charts) per kind, indexed by kind id; its length is the
# number of kind ids (engine/geometry/csg.py numbers the CSG shape kind after them).
N_FACES = np.array([1, 1, 6, 3, 2, 1, 2, 1, 1, 3], dtype=np.int64)

_INF = math.inf
_TWO_PI = 2.0 * math.pi
_QUARTER_PI = 0.25 * math.pi
_SQRT5 = math.sqrt(5.0)


@njit(cache=True)
def prim_nfaces(kind):
    if kind < 0 or kind >= N_FACES.shape[0]:
        return 0
    return N_FACES[kind]


# ---------------------------------------------------------------- helpers

@njit(cache=True, inline="always")
def _sgn(x):
    # sign with sgn(0) = +1, so the octahedral fold is a bijection on its seams
    return 1.0 if x >= 0.0 else -1.0


@njit(cache=True, inline="always")
def _sorted_roots(a, h, c, disc):
    """Roots of a t^2 + 2 h t + c (a != 0, disc = h^2 - a c > 0), ascending.

    q = -(h + sign(h) sqrt(disc)) never cancels, and the two roots are q/a and
    c/q (Vieta), so neither root loses digits when the other is tiny.
    """
    q = -(h + math.copysign(math.sqrt(disc), h))
    r0 = q / a
    r1 = c / q
    if r0 > r1:
        return r1, r0
    return r0, r1


@njit(cache=True, inline="always")
def _slab(o, d, lo, hi):
    """Parameter interval of the line o + t d inside lo < x < hi (strict)."""
    if d != 0.0:
        t0 = (lo - o) / d
        t1 = (hi - o) / d
        if t0 > t1:
            return t1, t0
        return t0, t1
    if lo < o < hi:
        return -_INF, _INF
    return _INF, -_INF


@njit(cache=True, inline="always")
def _pair(lo, hi):
    # A convex solid is crossed on one interval; an empty or degenerate
    # (tangent) interval is no hit, an unbounded one cannot come from a
    # bounded solid and is treated as a numerical miss.
    if lo < hi and lo > -_INF and hi < _INF:
        return 2, lo, hi, _INF, _INF
    return 0, _INF, _INF, _INF, _INF


@njit(cache=True)
def inverse_concentric(x, y):
    """Exact inverse of engine.core.sampling.concentric_disk: disk point -> (u, v)."""
    rho = math.sqrt(x * x + y * y)
    if rho == 0.0:
        return 0.5, 0.5
    # concentric_disk writes (x, y) = r (cos phi, sin phi) with a signed radius
    # r, so the wedges x<0 / y<0 use the antipodal angle.
    if abs(x) > abs(y):
        if x > 0.0:
            a = rho
            phi = math.atan2(y, x)
        else:
            a = -rho
            phi = math.atan2(-y, -x)
        b = a * phi / _QUARTER_PI
    else:
        if y > 0.0:
            b = rho
            phi = math.atan2(y, x)
        else:
            b = -rho
            phi = math.atan2(-y, -x)
        a = b * (0.5 * math.pi - phi) / _QUARTER_PI
    return 0.5 * (a + 1.0), 0.5 * (b + 1.0)


@njit(cache=True)
def _concentric_d(u, v):
    """concentric_disk(u, v) and its partials: (x, y, x_u, x_v, y_u, y_v)."""
    x, y = concentric_disk(u, v)
    a = 2.0 * u - 1.0
    b = 2.0 * v - 1.0
    k = _QUARTER_PI
    if a == 0.0 and b == 0.0:
        # not differentiable at the centre; the one-sided limit keeps the
        # Jacobian determinant (pi) right for area integration
        xa, xb, ya, yb = 1.0, 0.0, 0.0, k
    elif abs(a) > abs(b):
        phi = k * (b / a)
        c = math.cos(phi)
        s = math.sin(phi)
        xa = c + phi * s
        xb = -k * s
        ya = s - phi * c
        yb = k * c
    else:
        w = k * (a / b)
        psi = 0.5 * math.pi - w
        c = math.cos(psi)
        s = math.sin(psi)
        xa = k * s
        xb = c - w * s
        ya = -k * c
        yb = s + w * c
    # d/du = 2 d/da, d/dv = 2 d/db
    return x, y, 2.0 * xa, 2.0 * xb, 2.0 * ya, 2.0 * yb


@njit(cache=True, inline="always")
def _clamp01(x):
    return min(max(x, 0.0), 1.0)


# ------------------------------------------------------------- intersection

@njit(cache=True)
def _sphere_hits(ox, oy, oz, dx, dy, dz):
    a = dx * dx + dy * dy + dz * dz
    h = ox * dx + oy * dy + oz * dz
    # disc = h^2 - a c computed as a (1 - |l|^2), l the foot of the
    # perpendicular from the centre: no cancellation for far origins
    f = h / a
    lx = ox - f * dx
    ly = oy - f * dy
    lz = oz - f * dz
    disc = a * (1.0 - (lx * lx + ly * ly + lz * lz))
    if not disc > 0.0:
        return 0, _INF, _INF, _INF, _INF
    c = ox * ox + oy * oy + oz * oz - 1.0
    r0, r1 = _sorted_roots(a, h, c, disc)
    return _pair(r0, r1)


@njit(cache=True)
def _box_hits(ox, oy, oz, dx, dy, dz):
    x0, x1 = _slab(ox, dx, -1.0, 1.0)
    y0, y1 = _slab(oy, dy, -1.0, 1.0)
    z0, z1 = _slab(oz, dz, -1.0, 1.0)
    return _pair(max(x0, y0, z0), min(x1, y1, z1))


@njit(cache=True)
def _cylinder_hits(ox, oy, oz, dx, dy, dz):
    a = dx * dx + dy * dy
    if a > 0.0:
        h = ox * dx + oy * dy
        f = h / a
        lx = ox - f * dx
        ly = oy - f * dy
        disc = a * (1.0 - (lx * lx + ly * ly))
        if not disc > 0.0:
            return 0, _INF, _INF, _INF, _INF
        r0, r1 = _sorted_roots(a, h, ox * ox + oy * oy - 1.0, disc)
    elif ox * ox + oy * oy < 1.0:
        r0, r1 = -_INF, _INF
    else:
        return 0, _INF, _INF, _INF, _INF
    # side crossings clipped by the caps' slab = intersection of two intervals
    z0, z1 = _slab(oz, dz, -1.0, 1.0)
    return _pair(max(r0, z0), min(r1, z1))


@njit(cache=True)
def _cone_hits(ox, oy, oz, dx, dy, dz):
    # The frustum with top radius 0: its formulas are the cone's scaled by 1/4,
    # exact in binary, so the hits are bit for bit the cone's own.
    return _frustum_hits(0.0, ox, oy, oz, dx, dy, dz)


@njit(cache=True)
def _frustum_hits(tr, ox, oy, oz, dx, dy, dz):
    # Solid: rho < k := r(z) = (1 - s) - s z with slope s = (1 - tr) / 2 in
    # [0, 1/2], and -1 < z < 1. As for the cone (these are its formulas scaled
    # by 1/4 when tr = 0, bit for bit), rho - k is convex along the line, so
    # the nappe k > 0 holds one interval; squaring gives g = rho^2 - k^2 =
    # a t^2 + 2 h t + c, whose roots may lie on the mirrored nappe (k < 0,
    # above the virtual apex z = 1 / s - 1 >= 1), hence the nappe checks.
    # s = 0 is the cylinder: a >= 0 and no mirrored nappe.
    s = 0.5 * (1.0 - tr)
    k0 = (1.0 - s) - s * oz
    sz = s * dz                    # k = k0 - sz t along the line
    a = dx * dx + dy * dy - sz * sz
    h = ox * dx + oy * dy + k0 * sz
    c = ox * ox + oy * oy - k0 * k0
    if a > 0.0:
        disc = h * h - a * c
        if not disc > 0.0:
            return 0, _INF, _INF, _INF, _INF
        r0, r1 = _sorted_roots(a, h, c, disc)
        # g < 0 between the roots, a segment inside one nappe
        if not k0 - sz * (0.5 * (r0 + r1)) > 0.0:
            return 0, _INF, _INF, _INF, _INF
        lo, hi = r0, r1
    elif a < 0.0:
        # steeper than the side (so s > 0, dz != 0): g < 0 outside the roots,
        # one half-line per nappe; the real one (k -> +inf) is towards -z
        disc = h * h - a * c
        if not disc > 0.0:
            return 0, _INF, _INF, _INF, _INF
        r0, r1 = _sorted_roots(a, h, c, disc)
        if dz > 0.0:
            lo, hi = -_INF, r0
        else:
            lo, hi = r1, _INF
    elif h != 0.0:
        # parallel to a generator: g is linear, one crossing
        r = -c / (2.0 * h)
        if not k0 - sz * r > 0.0:
            return 0, _INF, _INF, _INF, _INF
        if h > 0.0:
            lo, hi = -_INF, r
        else:
            lo, hi = r, _INF
    elif s == 0.0 and c < 0.0:
        # cylinder, line along the axis inside it (with s > 0, a = h = 0
        # forces c >= 0: a line on the side, grazing)
        lo, hi = -_INF, _INF
    else:
        return 0, _INF, _INF, _INF, _INF
    z0, z1 = _slab(oz, dz, -1.0, 1.0)
    return _pair(max(lo, z0), min(hi, z1))


@njit(cache=True)
def _paraboloid_hits(ox, oy, oz, dx, dy, dz):
    # Solid: g = rho^2 - z <= 0 (convex along any line) and z <= 1.
    a = dx * dx + dy * dy
    h = ox * dx + oy * dy - 0.5 * dz
    c = ox * ox + oy * oy - oz
    if a > 0.0:
        disc = h * h - a * c
        if not disc > 0.0:
            return 0, _INF, _INF, _INF, _INF
        lo, hi = _sorted_roots(a, h, c, disc)
    elif dz > 0.0:
        lo, hi = c / dz, _INF
    elif dz < 0.0:
        lo, hi = -_INF, c / dz
    else:
        return 0, _INF, _INF, _INF, _INF
    z0, z1 = _slab(oz, dz, -_INF, 1.0)
    return _pair(max(lo, z0), min(hi, z1))


@njit(cache=True)
def _cubic_critical(p, q):
    """Real roots of x^3 + p x + q (1 or 3; a single root is repeated)."""
    if p == 0.0 and q == 0.0:
        return 0.0, 0.0, 0.0
    p3 = p / 3.0
    q2 = 0.5 * q
    disc = q2 * q2 + p3 * p3 * p3
    if disc > 0.0:
        # one real root (Cardano); pick the cube root without cancellation
        w3 = -q2 - math.copysign(math.sqrt(disc), q2)
        w = math.copysign(abs(w3) ** (1.0 / 3.0), w3)
        x = w - p3 / w
        return x, x, x
    # three real roots (p < 0): trigonometric form
    m = math.sqrt(-p3)
    arg = -q2 / (m * m * m)
    arg = min(max(arg, -1.0), 1.0)
    ang = math.acos(arg) / 3.0
    x0 = 2.0 * m * math.cos(ang)
    x1 = 2.0 * m * math.cos(ang - _TWO_PI / 3.0)
    x2 = 2.0 * m * math.cos(ang + _TWO_PI / 3.0)
    return x0, x1, x2


@njit(cache=True, inline="always")
def _torus_f(x, c, axy, bxy, cxy):
    # f(x) = (|p|^2 + R^2 - r^2)^2 - 4 R^2 rho^2 along the normalised line
    s = x * x + c
    return s * s - 4.0 * ((axy * x + bxy) * x + cxy)


@njit(cache=True)
def _torus_root(xa, xb, fa, fb, c, axy, bxy, cxy):
    """Root of the quartic in [xa, xb] (f monotone there, signs differ).

    Newton safeguarded by bisection: Newton converges quadratically on a
    monotone piece, the bracket guarantees convergence when it overshoots.
    """
    if fa < 0.0:
        xn, xp = xa, xb
    else:
        xn, xp = xb, xa
    x = xa - fa * (xb - xa) / (fb - fa)   # regula falsi start
    for _ in range(100):
        s = x * x + c
        f = s * s - 4.0 * ((axy * x + bxy) * x + cxy)
        if f < 0.0:
            xn = x
        elif f > 0.0:
            xp = x
        else:
            return x
        df = 4.0 * x * s - 4.0 * (2.0 * axy * x + bxy)
        lo = min(xn, xp)
        hi = max(xn, xp)
        xnew = x - f / df if df != 0.0 else 0.5 * (lo + hi)
        if not (lo < xnew < hi):
            xnew = 0.5 * (lo + hi)
        if abs(xnew - x) <= 4e-16 * max(1.0, abs(x)) or hi - lo <= 4e-16 * max(1.0, abs(x)):
            return xnew
        x = xnew
    return x


@njit(cache=True)
def _torus_hits(r, ox, oy, oz, dx, dy, dz):
    inf = _INF
    ll = math.sqrt(dx * dx + dy * dy + dz * dz)
    ex = dx / ll
    ey = dy / ll
    ez = dz / ll
    # Re-centre on the point of the line closest to the torus centre and use a
    # unit direction: the quartic loses its cubic term, its coefficients stay
    # O(1) however far the ray starts, and every root is within |x| <= 1 + r.
    s0 = -(ox * ex + oy * ey + oz * ez)
    px = ox + s0 * ex
    py = oy + s0 * ey
    pz = oz + s0 * ez
    rb = 1.0 + r
    pp = px * px + py * py + pz * pz
    if pp >= rb * rb:
        return 0, inf, inf, inf, inf
    c = pp + 1.0 - r * r
    axy = ex * ex + ey * ey
    bxy = 2.0 * (px * ex + py * ey)
    cxy = px * px + py * py
    # Beyond the bounding sphere f > 0, so bracket [-xm, xm]. The roots of f'
    # (a depressed cubic) cut it into monotone pieces; each sign change of f
    # between consecutive nodes is exactly one root. f > 0 at both ends, so
    # the number of roots is always even; a tangent contact (f = 0 at a node)
    # counts as outside, i.e. no hit.
    xm = math.sqrt(rb * rb - pp) + 1e-9 * rb
    c0, c1, c2 = _cubic_critical(c - 2.0 * axy, -bxy)
    # sort the three critical points and keep them in the bracket
    if c0 > c1:
        c0, c1 = c1, c0
    if c1 > c2:
        c1, c2 = c2, c1
    if c0 > c1:
        c0, c1 = c1, c0
    c0 = min(max(c0, -xm), xm)
    c1 = min(max(c1, -xm), xm)
    c2 = min(max(c2, -xm), xm)
    n = 0
    h0 = inf
    h1 = inf
    h2 = inf
    h3 = inf
    xa = -xm
    fa = _torus_f(xa, c, axy, bxy, cxy)
    for xb in (c0, c1, c2, xm):
        fb = _torus_f(xb, c, axy, bxy, cxy)
        if (fa < 0.0) != (fb < 0.0):
            root = (s0 + _torus_root(xa, xb, fa, fb, c, axy, bxy, cxy)) / ll
            if n == 0:
                h0 = root
            elif n == 1:
                h1 = root
            elif n == 2:
                h2 = root
            else:
                h3 = root
            n += 1
        xa = xb
        fa = fb
    return n, h0, h1, h2, h3


@njit(cache=True)
def _planar_hits(square, ox, oy, oz, dx, dy, dz):
    """The crossing of the plane z = 0 inside the unit disk, or the square
    [-1, 1]^2 if `square` (closed: the rim counts); a line in the plane misses."""
    if dz == 0.0:
        return 0, _INF, _INF, _INF, _INF
    t = -oz / dz
    x = ox + t * dx
    y = oy + t * dy
    if square:
        on = abs(x) <= 1.0 and abs(y) <= 1.0
    else:
        on = x * x + y * y <= 1.0
    if on:
        return 1, t, _INF, _INF, _INF
    return 0, _INF, _INF, _INF, _INF


@njit(cache=True)
def prim_hits(kind, params, ox, oy, oz, dx, dy, dz):
    """All crossings of the line o + t d (any t), ascending: (n, t0, t1, t2, t3).

    Unused slots are +inf. Solids give an even n (entry/exit pairs); tangent
    or grazing contacts give no hit. d need not be normalised (t is in units
    of d) but must be non-zero.
    """
    if kind == BOX:
        return _box_hits(ox, oy, oz, dx, dy, dz)
    elif kind == TORUS:
        return _torus_hits(params[0], ox, oy, oz, dx, dy, dz)
    elif (kind == SPHERE or kind == CYLINDER or kind == CONE or kind == PARABOLOID
          or kind == FRUSTUM):
        # Solve from the point of the line closest to the local origin: the
        # quadratic's coefficients then stay O(1) for far origins instead of
        # cancelling in the discriminant; the shift is added back to t.
        s0 = -(ox * dx + oy * dy + oz * dz) / (dx * dx + dy * dy + dz * dz)
        qx = ox + s0 * dx
        qy = oy + s0 * dy
        qz = oz + s0 * dz
        if kind == SPHERE:
            n, t0, t1, t2, t3 = _sphere_hits(qx, qy, qz, dx, dy, dz)
        elif kind == CYLINDER:
            n, t0, t1, t2, t3 = _cylinder_hits(qx, qy, qz, dx, dy, dz)
        elif kind == CONE:
            n, t0, t1, t2, t3 = _cone_hits(qx, qy, qz, dx, dy, dz)
        elif kind == FRUSTUM:
            n, t0, t1, t2, t3 = _frustum_hits(params[0], qx, qy, qz, dx, dy, dz)
        else:
            n, t0, t1, t2, t3 = _paraboloid_hits(qx, qy, qz, dx, dy, dz)
        return n, t0 + s0, t1 + s0, t2 + s0, t3 + s0   # inf + s0 stays inf
    elif kind == DISK or kind == QUAD:
        return _planar_hits(kind == QUAD, ox, oy, oz, dx, dy, dz)
    return 0, _INF, _INF, _INF, _INF


@njit(cache=True, parallel=True)
def hits_batch(kind, params, origins, dirs):
    """prim_hits for N rays: (n (N,) int32, t (N, 4) float64)."""
    m = origins.shape[0]
    n_out = np.zeros(m, dtype=np.int32)
    t_out = np.empty((m, 4), dtype=np.float64)
    for i in prange(m):
        n, t0, t1, t2, t3 = prim_hits(kind, params, origins[i, 0], origins[i, 1], origins[i, 2],
                                      dirs[i, 0], dirs[i, 1], dirs[i, 2])
        n_out[i] = n
        t_out[i, 0] = t0
        t_out[i, 1] = t1
        t_out[i, 2] = t2
        t_out[i, 3] = t3
    return n_out, t_out


# ----------------------------------------------------------- surface charts

@njit(cache=True)
def octa_encode(nx, ny, nz):
    s = abs(nx) + abs(ny) + abs(nz)
    x = nx / s
    y = ny / s
    if nz < 0.0:
        # fold the lower half onto the corners of the square
        x, y = (1.0 - abs(y)) * _sgn(x), (1.0 - abs(x)) * _sgn(y)
    return _clamp01(0.5 * (x + 1.0)), _clamp01(0.5 * (y + 1.0))


@njit(cache=True)
def _disk_uv(x, y, swap):
    if swap:
        u, v = inverse_concentric(y, x)
    else:
        u, v = inverse_concentric(x, y)
    return _clamp01(u), _clamp01(v)


@njit(cache=True)
def _wrap01(a):
    u = a / _TWO_PI
    if u < 0.0:
        u += 1.0
    return _clamp01(u)


@njit(cache=True)
def prim_surface(kind, params, px, py, pz):
    """Chart of a local surface point: (face, u, v, nx, ny, nz), n outward unit."""
    if kind == SPHERE:
        ln = math.sqrt(px * px + py * py + pz * pz)
        nx = px / ln
        ny = py / ln
        nz = pz / ln
        u, v = octa_encode(nx, ny, nz)
        return 0, u, v, nx, ny, nz
    elif kind == BOX:
        ax = abs(px)
        ay = abs(py)
        az = abs(pz)
        cx = _clamp01(0.5 * (px + 1.0))
        cy = _clamp01(0.5 * (py + 1.0))
        cz = _clamp01(0.5 * (pz + 1.0))
        if ax >= ay and ax >= az:
            if px >= 0.0:
                return 0, cy, cz, 1.0, 0.0, 0.0
            return 1, cz, cy, -1.0, 0.0, 0.0
        elif ay >= az:
            if py >= 0.0:
                return 2, cz, cx, 0.0, 1.0, 0.0
            return 3, cx, cz, 0.0, -1.0, 0.0
        if pz >= 0.0:
            return 4, cx, cy, 0.0, 0.0, 1.0
        return 5, cy, cx, 0.0, 0.0, -1.0
    elif kind == CYLINDER:
        rho = math.sqrt(px * px + py * py)
        # the closer of the two surfaces decides (robust near the rims)
        if abs(abs(pz) - 1.0) < abs(rho - 1.0):
            if pz >= 0.0:
                u, v = _disk_uv(px, py, False)
                return 1, u, v, 0.0, 0.0, 1.0
            u, v = _disk_uv(px, py, True)
            return 2, u, v, 0.0, 0.0, -1.0
        if rho > 0.0:
            nx = px / rho
            ny = py / rho
        else:
            nx = 1.0
            ny = 0.0
        return 0, _wrap01(math.atan2(py, px)), _clamp01(0.5 * (pz + 1.0)), nx, ny, 0.0
    elif kind == CONE:
        rho = math.sqrt(px * px + py * py)
        if abs(pz + 1.0) < abs(2.0 * rho - (1.0 - pz)) / _SQRT5:
            u, v = _disk_uv(px, py, True)
            return 1, u, v, 0.0, 0.0, -1.0
        u, v = _disk_uv(px, py, False)
        if rho > 0.0:
            # gradient of 2 rho + z - 1
            return 0, u, v, 2.0 * px / (rho * _SQRT5), 2.0 * py / (rho * _SQRT5), 1.0 / _SQRT5
        return 0, u, v, 0.0, 0.0, 1.0   # apex: no tangent plane, use the axis
    elif kind == TORUS:
        rho = math.sqrt(px * px + py * py)
        if rho > 0.0:
            cph = px / rho
            sph = py / rho
        else:
            cph = 1.0
            sph = 0.0
        qx = rho - 1.0
        m = math.sqrt(qx * qx + pz * pz)
        if m > 0.0:
            cth = qx / m
            sth = pz / m
        else:
            cth = 1.0
            sth = 0.0
        return (0, _wrap01(math.atan2(py, px)), _wrap01(math.atan2(pz, qx)),
                cth * cph, cth * sph, sth)
    elif kind == PARABOLOID:
        r2 = px * px + py * py
        if abs(pz - 1.0) < abs(pz - r2) / math.sqrt(1.0 + 4.0 * r2):
            u, v = _disk_uv(px, py, False)
            return 1, u, v, 0.0, 0.0, 1.0
        u, v = _disk_uv(px, py, True)
        inv = 1.0 / math.sqrt(1.0 + 4.0 * r2)
        return 0, u, v, 2.0 * px * inv, 2.0 * py * inv, -inv
    elif kind == DISK:
        u, v = _disk_uv(px, py, False)
        return 0, u, v, 0.0, 0.0, 1.0
    elif kind == QUAD:
        return 0, _clamp01(0.5 * (px + 1.0)), _clamp01(0.5 * (py + 1.0)), 0.0, 0.0, 1.0
    elif kind == FRUSTUM:
        tr = params[0]
        s = 0.5 * (1.0 - tr)
        rho = math.sqrt(px * px + py * py)
        w = math.sqrt(1.0 + s * s)
        # the closest of the three surfaces decides (robust near the rims);
        # a zero-radius top cap (the cone's apex) is no surface
        d_side = abs(rho - ((1.0 - s) - s * pz)) / w
        d_base = abs(pz + 1.0)
        d_top = abs(pz - 1.0) if tr > 0.0 else _INF
        if d_base < d_side and d_base <= d_top:
            u, v = _disk_uv(px, py, True)
            return 1, u, v, 0.0, 0.0, -1.0
        if d_top < d_side:
            u, v = _disk_uv(px / tr, py / tr, False)
            return 2, u, v, 0.0, 0.0, 1.0
        u = _wrap01(math.atan2(py, px))
        v = _clamp01(0.5 * (pz + 1.0))
        if rho > 0.0:
            # gradient of rho + s z
            return 0, u, v, px / (rho * w), py / (rho * w), s / w
        return 0, u, v, 0.0, 0.0, 1.0   # apex (t = 0): no tangent plane, use the axis
    return -1, 0.0, 0.0, 0.0, 0.0, 1.0


@njit(cache=True)
def prim_point(kind, params, face, u, v):
    """Inverse chart: (px, py, pz, dP/du (3), dP/dv (3)), analytic derivatives.

    dP/du x dP/dv points outward on every face.
    """
    if kind == SPHERE:
        a = 2.0 * u - 1.0
        b = 2.0 * v - 1.0
        sa = _sgn(a)
        sb = _sgn(b)
        wz = 1.0 - abs(a) - abs(b)
        if wz >= 0.0:
            wx = a
            wy = b
            ax_, ay_, az_ = 1.0, 0.0, -sa
            bx_, by_, bz_ = 0.0, 1.0, -sb
        else:
            wx = (1.0 - abs(b)) * sa
            wy = (1.0 - abs(a)) * sb
            ax_, ay_, az_ = 0.0, -sa * sb, -sa
            bx_, by_, bz_ = -sa * sb, 0.0, -sb
        lw = math.sqrt(wx * wx + wy * wy + wz * wz)
        px = wx / lw
        py = wy / lw
        pz = wz / lw
        # d(w/|w|) = (dw - P (P . dw)) / |w|; d/du = 2 d/da
        pa = px * ax_ + py * ay_ + pz * az_
        pb = px * bx_ + py * by_ + pz * bz_
        ka = 2.0 / lw
        return (px, py, pz,
                ka * (ax_ - px * pa), ka * (ay_ - py * pa), ka * (az_ - pz * pa),
                ka * (bx_ - px * pb), ka * (by_ - py * pb), ka * (bz_ - pz * pb))
    elif kind == BOX:
        su = 2.0 * u - 1.0
        sv = 2.0 * v - 1.0
        if face == 0:
            return 1.0, su, sv, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0
        elif face == 1:
            return -1.0, sv, su, 0.0, 0.0, 2.0, 0.0, 2.0, 0.0
        elif face == 2:
            return sv, 1.0, su, 0.0, 0.0, 2.0, 2.0, 0.0, 0.0
        elif face == 3:
            return su, -1.0, sv, 2.0, 0.0, 0.0, 0.0, 0.0, 2.0
        elif face == 4:
            return su, sv, 1.0, 2.0, 0.0, 0.0, 0.0, 2.0, 0.0
        return sv, su, -1.0, 0.0, 2.0, 0.0, 2.0, 0.0, 0.0
    elif kind == CYLINDER:
        if face == 0:
            phi = _TWO_PI * u
            c = math.cos(phi)
            s = math.sin(phi)
            return c, s, 2.0 * v - 1.0, -_TWO_PI * s, _TWO_PI * c, 0.0, 0.0, 0.0, 2.0
        x, y, xu, xv, yu, yv = _concentric_d(u, v)
        if face == 1:
            return x, y, 1.0, xu, yu, 0.0, xv, yv, 0.0
        return y, x, -1.0, yu, xu, 0.0, yv, xv, 0.0
    elif kind == CONE:
        x, y, xu, xv, yu, yv = _concentric_d(u, v)
        if face == 0:
            rho = math.sqrt(x * x + y * y)
            if rho > 0.0:
                zu = -2.0 * (x * xu + y * yu) / rho
                zv = -2.0 * (x * xv + y * yv) / rho
            else:
                zu = 0.0   # apex: the cone has no tangent plane there
                zv = 0.0
            return x, y, 1.0 - 2.0 * rho, xu, yu, zu, xv, yv, zv
        return y, x, -1.0, yu, xu, 0.0, yv, xv, 0.0
    elif kind == TORUS:
        r = params[0]
        phi = _TWO_PI * u
        th = _TWO_PI * v
        cph = math.cos(phi)
        sph = math.sin(phi)
        cth = math.cos(th)
        sth = math.sin(th)
        ring = 1.0 + r * cth
        return (ring * cph, ring * sph, r * sth,
                -_TWO_PI * ring * sph, _TWO_PI * ring * cph, 0.0,
                -_TWO_PI * r * sth * cph, -_TWO_PI * r * sth * sph, _TWO_PI * r * cth)
    elif kind == PARABOLOID:
        x, y, xu, xv, yu, yv = _concentric_d(u, v)
        if face == 0:
            return (y, x, x * x + y * y, yu, xu, 2.0 * (x * xu + y * yu),
                    yv, xv, 2.0 * (x * xv + y * yv))
        return x, y, 1.0, xu, yu, 0.0, xv, yv, 0.0
    elif kind == DISK:
        x, y, xu, xv, yu, yv = _concentric_d(u, v)
        return x, y, 0.0, xu, yu, 0.0, xv, yv, 0.0
    elif kind == QUAD:
        return 2.0 * u - 1.0, 2.0 * v - 1.0, 0.0, 2.0, 0.0, 0.0, 0.0, 2.0, 0.0
    elif kind == FRUSTUM:
        tr = params[0]
        if face == 0:
            # radius r = 1 - (1 - t) v along z = 2 v - 1
            phi = _TWO_PI * u
            c = math.cos(phi)
            s = math.sin(phi)
            w = 1.0 - tr
            r = 1.0 - w * v
            return (r * c, r * s, 2.0 * v - 1.0, -_TWO_PI * r * s, _TWO_PI * r * c, 0.0,
                    -w * c, -w * s, 2.0)
        x, y, xu, xv, yu, yv = _concentric_d(u, v)
        if face == 1:
            return y, x, -1.0, yu, xu, 0.0, yv, xv, 0.0
        return tr * x, tr * y, 1.0, tr * xu, tr * yu, 0.0, tr * xv, tr * yv, 0.0
    return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0


# ------------------------------------------------------ bounds, area, inside

@njit(cache=True)
def prim_local_bounds(kind, params):
    """Tight local AABB: (minx, miny, minz, maxx, maxy, maxz)."""
    if kind == TORUS:
        r = params[0]
        return -1.0 - r, -1.0 - r, -r, 1.0 + r, 1.0 + r, r
    elif kind == PARABOLOID:
        return -1.0, -1.0, 0.0, 1.0, 1.0, 1.0
    elif kind == DISK or kind == QUAD:
        return -1.0, -1.0, 0.0, 1.0, 1.0, 0.0
    return -1.0, -1.0, -1.0, 1.0, 1.0, 1.0


@njit(cache=True)
def prim_area(kind, params):
    """Exact total surface area in local space (all faces)."""
    if kind == SPHERE:
        return 4.0 * math.pi
    elif kind == BOX:
        return 24.0
    elif kind == CYLINDER:
        return 6.0 * math.pi                      # side 4 pi + two caps
    elif kind == CONE:
        return math.pi * (1.0 + _SQRT5)           # base + slant height sqrt(5)
    elif kind == TORUS:
        return 4.0 * math.pi * math.pi * params[0]
    elif kind == PARABOLOID:
        # lateral: integral of sqrt(1 + 4 rho^2) over the unit disk, plus cap
        return math.pi / 6.0 * (5.0 * _SQRT5 - 1.0) + math.pi
    elif kind == DISK:
        return math.pi
    elif kind == QUAD:
        return 4.0
    elif kind == FRUSTUM:
        # lateral pi (1 + t) * slant, slant sqrt(4 + (1 - t)^2), plus both caps
        tr = params[0]
        w = 1.0 - tr
        return math.pi * ((1.0 + tr) * math.sqrt(4.0 + w * w) + 1.0 + tr * tr)
    return 0.0


@njit(cache=True)
def prim_inside(kind, params, px, py, pz):
    """Strict point membership of the solid (the boundary is outside)."""
    if kind == SPHERE:
        return px * px + py * py + pz * pz < 1.0
    elif kind == BOX:
        return abs(px) < 1.0 and abs(py) < 1.0 and abs(pz) < 1.0
    elif kind == CYLINDER:
        return px * px + py * py < 1.0 and abs(pz) < 1.0
    elif kind == CONE:
        return pz > -1.0 and 2.0 * math.sqrt(px * px + py * py) < 1.0 - pz
    elif kind == TORUS:
        q = math.sqrt(px * px + py * py) - 1.0
        r = params[0]
        return q * q + pz * pz < r * r
    elif kind == PARABOLOID:
        return px * px + py * py < pz and pz < 1.0
    elif kind == FRUSTUM:
        s = 0.5 * (1.0 - params[0])
        return pz > -1.0 and pz < 1.0 and math.sqrt(px * px + py * py) < (1.0 - s) - s * pz
    return False


def check_primitive(prim, what, n_materials=0):
    """A scene.Primitive validated for the kernels -> (kind id, params (4,), xf, inverse, material);
    raises SceneError naming `what` (bad kind, parameters, material or transform)."""
    kind = prim.kind.lower() if isinstance(prim.kind, str) else prim.kind
    if kind not in KIND_IDS:
        raise SceneError(f"{what}: unknown primitive kind {prim.kind!r} "
                         f"(expected one of {', '.join(KIND_IDS)})")
    params = np.asarray(prim.params if prim.params is not None else (), dtype=np.float64).reshape(-1)
    if params.size > 4:
        raise SceneError(f"{what}: at most 4 parameters, got {params.size}")
    if not np.all(np.isfinite(params)):
        raise SceneError(f"{what}: parameters contain NaN or infinity")
    p4 = np.zeros(4)
    p4[:params.size] = params
    if kind == "torus" and not (params.size >= 1 and 0.0 < p4[0] < 1.0):
        raise SceneError(f"{what}: a torus needs params=(minor_radius,) with 0 < minor_radius < 1")
    if kind == "frustum" and not (params.size >= 1 and 0.0 <= p4[0] <= 1.0):
        raise SceneError(f"{what}: a frustum needs params=(top_radius,) with 0 <= top_radius <= 1")
    mat = int(prim.material)
    if n_materials and not (0 <= mat < n_materials):
        raise SceneError(f"{what}: material index {mat} out of range (scene has {n_materials} materials)")
    xf = as_affine(prim.transform, what)
    return KIND_IDS[kind], p4, xf, inverse(xf), mat
