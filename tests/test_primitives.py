"""Analytic primitives: intersections, charts, derivatives, areas (engine/geometry/primitives.py)."""
import math

import numpy as np
import pytest
from numba import njit

from photon_lightmaps.engine.geometry import primitives
from photon_lightmaps.engine.geometry.primitives import (
    BOX, CONE, CYLINDER, DISK, FRUSTUM, KIND_IDS, N_FACES, PARABOLOID, QUAD, SPHERE, TORUS,
    check_primitive, hits_batch, inverse_concentric, prim_area, prim_hits, prim_inside,
    prim_local_bounds, prim_nfaces, prim_point, prim_surface)
from photon_lightmaps.engine.core.sampling import concentric_disk
from photon_lightmaps.engine.core.scene import PRIMITIVE_KINDS, Primitive, SceneError

TORUS_R = 0.4
FRUSTUM_T = 0.4
SOLIDS = [SPHERE, BOX, CYLINDER, CONE, TORUS, PARABOLOID, FRUSTUM]
OPEN = [DISK, QUAD]
ALL = SOLIDS + OPEN


def params_of(kind, t=None):
    """The tests' parameters of a kind; `t` overrides the frustum's top radius."""
    p = np.zeros(4)
    if kind == TORUS:
        p[0] = TORUS_R
    elif kind == FRUSTUM:
        p[0] = FRUSTUM_T if t is None else t
    return p


# --------------------------------------------------------- test-side kernels

@njit(cache=True)
def _march(kind, params, origins, dirs, tmin, tmax, nsteps, counts, cross):
    """Brute-force reference: sign changes of prim_inside on a fine t grid."""
    for i in range(origins.shape[0]):
        h = (tmax[i] - tmin[i]) / nsteps
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = dirs[i, 0], dirs[i, 1], dirs[i, 2]
        t = tmin[i]
        prev = primitives.prim_inside(kind, params, ox + t * dx, oy + t * dy, oz + t * dz)
        c = 0
        for k in range(1, nsteps + 1):
            t = tmin[i] + k * h
            cur = primitives.prim_inside(kind, params, ox + t * dx, oy + t * dy, oz + t * dz)
            if cur != prev:
                if c < cross.shape[1]:
                    cross[i, c] = t - 0.5 * h
                c += 1
            prev = cur
        counts[i] = c


@njit(cache=True)
def _surface_batch(kind, params, pts):
    m = pts.shape[0]
    face = np.empty(m, dtype=np.int64)
    out = np.empty((m, 5))
    for i in range(m):
        f, u, v, nx, ny, nz = primitives.prim_surface(kind, params, pts[i, 0], pts[i, 1], pts[i, 2])
        face[i] = f
        out[i, 0] = u
        out[i, 1] = v
        out[i, 2] = nx
        out[i, 3] = ny
        out[i, 4] = nz
    return face, out


@njit(cache=True)
def _point_batch(kind, params, face, us, vs):
    m = us.shape[0]
    out = np.empty((m, 9))
    for i in range(m):
        r = primitives.prim_point(kind, params, face, us[i], vs[i])
        for j in range(9):
            out[i, j] = r[j]
    return out


@njit(cache=True)
def _inside_batch(kind, params, pts):
    m = pts.shape[0]
    out = np.empty(m, dtype=np.bool_)
    for i in range(m):
        out[i] = primitives.prim_inside(kind, params, pts[i, 0], pts[i, 1], pts[i, 2])
    return out


def residual(kind, p, params=None):
    """Independent implicit description of each surface (zero on it)."""
    r = (params_of(kind) if params is None else params)[0]
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    rho = np.hypot(x, y)
    if kind == SPHERE:
        return np.abs(np.sqrt(x * x + y * y + z * z) - 1.0)
    if kind == BOX:
        return np.abs(np.max(np.abs(p), axis=1) - 1.0)
    if kind == CYLINDER:
        return np.abs(np.maximum(rho - 1.0, np.abs(z) - 1.0))
    if kind == CONE:
        return np.abs(np.maximum(-(z + 1.0), (2.0 * rho - (1.0 - z)) / math.sqrt(5.0)))
    if kind == TORUS:
        return np.abs(np.hypot(rho - 1.0, z) - r)
    if kind == PARABOLOID:
        return np.abs(np.maximum((rho * rho - z) / np.sqrt(1 + 4 * rho * rho), z - 1.0))
    if kind == DISK:
        return np.abs(z) + np.maximum(rho - 1.0, 0.0)
    if kind == QUAD:
        return np.abs(z) + np.maximum(np.maximum(np.abs(x), np.abs(y)) - 1.0, 0.0)
    if kind == FRUSTUM:
        # r is the top radius; the side's distance is its slant-normalised residual
        side = (rho - (1.0 + (r - 1.0) * (z + 1.0) / 2.0)) / math.hypot(1.0, (1.0 - r) / 2.0)
        return np.abs(np.maximum(side, np.abs(z) - 1.0))
    raise ValueError(kind)


def inside_ref(kind, p, params=None):
    r = (params_of(kind) if params is None else params)[0]
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    rho = np.hypot(x, y)
    if kind == SPHERE:
        return x * x + y * y + z * z < 1
    if kind == BOX:
        return np.all(np.abs(p) < 1, axis=1)
    if kind == CYLINDER:
        return (rho < 1) & (np.abs(z) < 1)
    if kind == CONE:
        return (z > -1) & (rho < (1 - z) / 2)
    if kind == TORUS:
        return np.hypot(rho - 1, z) < r
    if kind == PARABOLOID:
        return (rho * rho < z) & (z < 1)
    if kind == FRUSTUM:
        return (np.abs(z) < 1) & (rho < 1 + (r - 1) * (z + 1) / 2)
    return np.zeros(len(p), dtype=bool)


def make_rays(kind, n, rng, inside_frac=0.2, params=None):
    """Origins on a radius-3 sphere aimed at random points of the bounds, some
    origins inside the bounds (hits at negative t), random direction scales."""
    b = np.array(prim_local_bounds(kind, params_of(kind) if params is None else params))
    lo, hi = b[:3], b[3:]
    target = lo + (hi - lo) * rng.random((n, 3))
    o = rng.normal(size=(n, 3))
    o *= 3.0 / np.linalg.norm(o, axis=1)[:, None]
    d = target - o
    k = int(n * inside_frac)
    o[:k] = lo + (hi - lo) * rng.random((k, 3))
    d[:k] = rng.normal(size=(k, 3))
    d *= 10.0 ** rng.uniform(-2, 2, size=(n, 1))
    return o, d


def ball_range(o, d, radius=2.5):
    """t interval of each line inside the ball |p| < radius (covers every bound)."""
    a = np.sum(d * d, axis=1)
    h = np.sum(o * d, axis=1)
    c = np.sum(o * o, axis=1) - radius * radius
    s = np.sqrt(h * h - a * c)
    return (-h - s) / a, (-h + s) / a


def hits_of(kind, o, d, params=None):
    n, t = hits_batch(kind, params_of(kind) if params is None else params, o, d)
    return n, t


# ---------------------------------------------------------------- constants

def test_kind_ids_and_faces():
    assert set(KIND_IDS) == set(PRIMITIVE_KINDS)
    assert [KIND_IDS[k] for k in PRIMITIVE_KINDS] == list(range(1, 10))
    ids = (primitives.TRIANGLE, SPHERE, BOX, CYLINDER, CONE, TORUS, PARABOLOID, DISK, QUAD, FRUSTUM)
    assert ids == tuple(range(10))
    assert list(N_FACES) == [1, 1, 6, 3, 2, 1, 2, 1, 1, 3]
    from photon_lightmaps.engine.geometry.csg import CSG
    assert CSG == len(N_FACES) == 10          # the CSG shape kind follows every primitive id
    for k in range(10):
        assert prim_nfaces(k) == N_FACES[k]
    assert prim_nfaces(42) == 0


def test_inverse_concentric_round_trip():
    rng = np.random.default_rng(1)
    uv = rng.random((4000, 2))
    # include the map's seams: axes, both diagonals, centre, corners
    s = rng.random(200)
    uv = np.vstack([uv, np.c_[s, s], np.c_[s, 1 - s], np.c_[s, np.full(200, 0.5)],
                    np.c_[np.full(200, 0.5), s], [[0.5, 0.5], [0, 0], [1, 1], [0, 1], [1, 0]]])
    for u, v in uv:
        x, y = concentric_disk(u, v)
        u2, v2 = inverse_concentric(x, y)
        assert abs(u2 - u) < 1e-12 and abs(v2 - v) < 1e-12, (u, v, u2, v2)
    # and the other way round, from disk points
    r = np.sqrt(rng.random(2000))
    a = rng.uniform(0, 2 * np.pi, 2000)
    for x, y in zip(r * np.cos(a), r * np.sin(a)):
        x2, y2 = concentric_disk(*inverse_concentric(x, y))
        assert abs(x2 - x) < 1e-12 and abs(y2 - y) < 1e-12


def test_inside_matches_reference():
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1.6, 1.6, size=(20000, 3))
    for kind in ALL:
        got = _inside_batch(kind, params_of(kind), pts)
        assert np.array_equal(got, inside_ref(kind, pts)), kind


# ------------------------------------------------------------ intersections

def _check_against_march(kind, o, d, nsteps=20000, params=None):
    """Every hit on the surface, entry/exit pairs, and agreement with the
    brute-force sign changes of prim_inside. Returns (n, skipped rays)."""
    params = params_of(kind) if params is None else params
    n, t = hits_of(kind, o, d, params)
    assert np.all(n % 2 == 0)
    tmin, tmax = ball_range(o, d)
    counts = np.zeros(len(o), dtype=np.int64)
    cross = np.full((len(o), 8), np.inf)
    _march(kind, params, o, d, tmin, tmax, nsteps, counts, cross)
    dl = np.linalg.norm(d, axis=1)
    step = (tmax - tmin) / nsteps          # in units of t
    skipped = 0
    for i in range(len(o)):
        ts = t[i, :n[i]]
        assert np.all(np.diff(ts) > 0) and np.all(np.isinf(t[i, n[i]:]))
        cosv = np.ones(1)
        if n[i]:
            pts = o[i] + ts[:, None] * d[i]
            assert np.all(residual(kind, pts, params) < 1e-9), (i, ts, residual(kind, pts, params))
            face, s = _surface_batch(kind, params, pts)
            cosv = s[:, 2:] @ d[i] / dl[i]
            # entry/exit pairs: normals face the ray at entries, away at exits
            if np.all(np.abs(cosv) > 1e-3):
                assert np.all(cosv[0::2] < 0) and np.all(cosv[1::2] > 0), (i, cosv)
        ref = cross[i, :counts[i]]
        gap = min(np.min(np.diff(ts), initial=np.inf), np.min(np.diff(ref), initial=np.inf))
        # near-tangent rays and chords shorter than the grid are ambiguous
        if np.any(np.abs(cosv) < 0.02) or gap < 20 * step[i] or counts[i] > 8:
            skipped += 1
            continue
        assert counts[i] == n[i], (i, ref, ts)
        assert np.all(np.abs(ref - ts) <= 0.5 * step[i] * 1.001 + 1e-12), (i, ref, ts)
    return n, skipped


@pytest.mark.parametrize("kind", SOLIDS)
def test_solid_hits_against_brute_force(kind):
    rng = np.random.default_rng(10 + kind)
    o, d = make_rays(kind, 1500, rng)
    n, skipped = _check_against_march(kind, o, d)
    assert skipped < 0.05 * len(o), skipped
    assert np.sum(n > 0) > 0.5 * len(o)
    if kind == TORUS:
        assert np.sum(n == 4) > 50
        assert np.sum(n == 2) > 50


@pytest.mark.parametrize("kind", SOLIDS)
def test_special_directions_against_brute_force(kind):
    """Axis-parallel rays and rays parallel to a cone generator exercise the
    degenerate (linear) branches of the quadrics."""
    g = np.linspace(-1.3, 1.3, 12)
    # the last four are exactly parallel to cone generators (4(dx^2+dy^2) == dz^2)
    dirs = np.array([[1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1], [0.5, 0, -1], [0, -0.5, 1],
                     [0.3, 0.4, -1], [-0.3, 0.4, 1]])
    assert np.all(4 * np.sum(dirs[4:, :2] ** 2, axis=1) == dirs[4:, 2] ** 2)
    os, ds = [], []
    for dv in dirs:
        # origins on a plane through the primitive, pushed back along the ray
        a = np.cross(dv, [0.3, 0.5, 0.7])
        a /= np.linalg.norm(a)
        b = np.cross(dv, a)
        b /= np.linalg.norm(b)
        for x in g:
            for y in g:
                os.append(x * a + y * b - 2.0 * dv)
                ds.append(dv)
    o = np.array(os)
    d = np.array(ds)
    n, skipped = _check_against_march(kind, o, d)
    assert skipped < 0.05 * len(o), skipped
    assert np.sum(n > 0) > 0.2 * len(o)


@pytest.mark.parametrize("kind", OPEN)
def test_open_surface_hits_against_plane(kind):
    rng = np.random.default_rng(20 + kind)
    o, d = make_rays(kind, 3000, rng)
    # also rays that miss the surface but hit its plane
    o2, d2 = make_rays(kind, 1000, rng)
    d2[:, :2] *= 3.0
    o = np.vstack([o, o2])
    d = np.vstack([d, d2])
    n, t = hits_of(kind, o, d)
    tp = -o[:, 2] / d[:, 2]
    p = o + tp[:, None] * d
    if kind == DISK:
        ok = np.hypot(p[:, 0], p[:, 1]) <= 1
    else:
        ok = np.max(np.abs(p[:, :2]), axis=1) <= 1
    assert np.array_equal(n, ok.astype(np.int32))
    assert np.allclose(t[ok, 0], tp[ok], rtol=1e-14, atol=0)
    assert np.all(np.isinf(t[:, 1:]))
    assert np.all(np.isinf(t[~ok, 0]))
    assert 0.2 * len(o) < ok.sum() < 0.95 * len(o)


@pytest.mark.parametrize("kind", ALL)
def test_direction_scaling_divides_t(kind):
    rng = np.random.default_rng(30 + kind)
    o, d = make_rays(kind, 2000, rng)
    n1, t1 = hits_of(kind, o, d)
    n3, t3 = hits_of(kind, o, 3.0 * d)
    assert np.array_equal(n1, n3)
    m = np.isfinite(t1)
    assert np.array_equal(m, np.isfinite(t3))
    assert m.sum() > 1000
    assert np.allclose(t3[m] * 3.0, t1[m], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", SOLIDS)
def test_hits_from_far_away(kind):
    """Far origins: re-centring keeps the hit points on the surface."""
    rng = np.random.default_rng(40 + kind)
    o, d = make_rays(kind, 500, rng, inside_frac=0.0)
    far = 10.0 ** rng.uniform(2, 5, size=(len(o), 1))
    target = o + d
    o = target + (o - target) * far
    d = (target - o) * rng.uniform(0.1, 10, size=(len(o), 1))
    n, t = hits_of(kind, o, d)
    assert np.sum(n > 0) > 0.3 * len(o)
    for i in np.nonzero(n)[0]:
        pts = o[i] + t[i, :n[i], None] * d[i]
        assert np.all(residual(kind, pts) < 1e-9 * far[i, 0]), (i, residual(kind, pts))


def test_tangent_and_grazing_rays_give_no_hits():
    z4 = np.zeros(4)
    cases = [
        (SPHERE, (-3.0, 1.0, 0.0), (1.0, 0.0, 0.0)),       # tangent
        (BOX, (-3.0, 1.0, 1.0), (2.0, 0.0, 0.0)),          # along an edge
        (BOX, (-3.0, 1.0, 0.2), (1.0, 0.0, 0.0)),          # in a face plane
        (BOX, (-3.0, -3.0, 0.0), (1.0, 1.0, 0.0)),         # chord between two opposite edges
        (CYLINDER, (-3.0, 1.0, 0.3), (1.0, 0.0, 0.0)),     # tangent to the side
        (CYLINDER, (-3.0, 0.2, 1.0), (1.0, 0.0, 0.0)),     # in the cap plane
        (CONE, (-3.0, 0.0, 1.0), (1.0, 0.0, 0.0)),         # touches the apex
        (PARABOLOID, (-3.0, 0.0, 0.0), (1.0, 0.0, 0.0)),   # touches the vertex
        (PARABOLOID, (-3.0, 0.2, 1.0), (1.0, 0.0, 0.0)),   # in the cap plane
    ]
    for kind, o, d in cases:
        n = prim_hits(kind, z4, *o, *d)[0]
        if kind == BOX and o[1] == -3.0:
            assert n == 2      # a diagonal through the box is a proper hit
        else:
            assert n == 0, (kind, o, d, prim_hits(kind, z4, *o, *d))
    # torus: a line tangent to the top of the tube touches it at two points
    pr = params_of(TORUS)
    n = prim_hits(TORUS, pr, -3.0, 0.0, TORUS_R, 1.0, 0.0, 0.0)[0]
    assert n % 2 == 0


# -------------------------------------------------------------------- torus

def test_torus_hole_and_four_hits():
    pr = params_of(TORUS)
    r = TORUS_R
    # through the hole, along and slightly tilted from the axis
    for ox, oy, dx, dy in [(0.0, 0.0, 0.0, 0.0), (0.3, -0.2, 0.01, 0.02), (-0.5, 0.0, 0.05, 0.0)]:
        assert prim_hits(TORUS, pr, ox, oy, 3.0, dx, dy, -1.0)[0] == 0
        assert not prim_inside(TORUS, pr, ox, oy, 0.0)
    # along the x axis: x = -1-r, -1+r, 1-r, 1+r, exactly
    n, *t = prim_hits(TORUS, pr, -3.0, 0.0, 0.0, 2.0, 0.0, 0.0)
    assert n == 4
    assert np.allclose(t, np.array([3 - 1 - r, 3 - 1 + r, 3 + 1 - r, 3 + 1 + r]) / 2.0,
                       rtol=0, atol=1e-14)
    # at height z: crossings at |x| = 1 +- sqrt(r^2 - z^2)
    z = 0.25
    w = math.sqrt(r * r - z * z)
    n, *t = prim_hits(TORUS, pr, 0.0, -5.0, z, 0.0, 0.5, 0.0)
    assert n == 4
    assert np.allclose(t, (5.0 + np.array([-1 - w, -1 + w, 1 - w, 1 + w])) / 0.5, atol=1e-13)
    # entry/exit alternation: inside between t0,t1 and t2,t3, outside elsewhere
    mids = [t[0] - 1, 0.5 * (t[0] + t[1]), 0.5 * (t[1] + t[2]), 0.5 * (t[2] + t[3]), t[3] + 1]
    assert [prim_inside(TORUS, pr, 0.0, -5.0 + 0.5 * m, z) for m in mids] == \
        [False, True, False, True, False]


def test_torus_roots_match_numpy_roots():
    rng = np.random.default_rng(50)
    pr = params_of(TORUS)
    r = TORUS_R
    o, d = make_rays(TORUS, 600, rng)
    n, t = hits_of(TORUS, o, d)
    checked = 0
    for i in range(len(o)):
        a = d[i] @ d[i]
        b = 2 * o[i] @ d[i]
        c = o[i] @ o[i] + 1 - r * r
        axy = d[i, :2] @ d[i, :2]
        bxy = 2 * o[i, :2] @ d[i, :2]
        cxy = o[i, :2] @ o[i, :2]
        coef = [a * a, 2 * a * b, b * b + 2 * a * c - 4 * axy, 2 * b * c - 4 * bxy, c * c - 4 * cxy]
        roots = np.roots(coef)
        scale = math.sqrt(a)      # roots in distance units: t * |d|
        gaps = np.abs(roots[:, None] - roots[None, :]) * scale
        gaps[np.diag_indices(4)] = np.inf
        if gaps.min() < 1e-2:
            continue   # near-tangent: numpy.roots itself is ill-conditioned there
        real = np.sort(roots[np.abs(roots.imag) * scale < 1e-7].real)
        assert len(real) == n[i], (i, roots, t[i])
        assert np.allclose(real * scale, t[i, :n[i]] * scale, rtol=0, atol=1e-8), (roots, t[i])
        checked += 1
    assert checked > 500


def test_hits_batch_matches_scalar():
    rng = np.random.default_rng(60)
    for kind in ALL:
        o, d = make_rays(kind, 50, rng)
        n, t = hits_of(kind, o, d)
        for i in range(len(o)):
            ref = prim_hits(kind, params_of(kind), *o[i], *d[i])
            assert ref[0] == n[i] and np.array_equal(np.array(ref[1:]), t[i])


# ---------------------------------------------------------- charts, normals

def faces_uv(rng, m, lo=0.0, hi=1.0):
    return rng.uniform(lo, hi, m), rng.uniform(lo, hi, m)


@pytest.mark.parametrize("kind", ALL)
def test_chart_round_trip(kind):
    rng = np.random.default_rng(70 + kind)
    params = params_of(kind)
    for face in range(N_FACES[kind]):
        us, vs = faces_uv(rng, 3000, 1e-6, 1 - 1e-6)
        pts = _point_batch(kind, params, face, us, vs)
        assert np.all(residual(kind, pts[:, :3]) < 1e-13)
        f, s = _surface_batch(kind, params, np.ascontiguousarray(pts[:, :3]))
        assert np.all(f == face), (face, np.unique(f))
        assert np.allclose(s[:, 0], us, rtol=0, atol=1e-10)
        assert np.allclose(s[:, 1], vs, rtol=0, atol=1e-10)


@pytest.mark.parametrize("kind", ALL)
def test_normals_unit_outward_and_match_derivatives(kind):
    rng = np.random.default_rng(80 + kind)
    params = params_of(kind)
    eps = 1e-5
    for face in range(N_FACES[kind]):
        us, vs = faces_uv(rng, 3000, 0.05, 0.95)
        pts = _point_batch(kind, params, face, us, vs)
        p = np.ascontiguousarray(pts[:, :3])
        f, s = _surface_batch(kind, params, p)
        nrm = s[:, 2:]
        assert np.allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-14)
        cr = np.cross(pts[:, 3:6], pts[:, 6:9])
        ln = np.linalg.norm(cr, axis=1)
        keep = ln > 1e-9 * np.max(ln)
        if kind == CONE and face == 0:
            keep &= np.hypot(p[:, 0], p[:, 1]) > 0.05      # apex has no normal
        cosang = np.sum(cr[keep] * nrm[keep], axis=1) / ln[keep]
        assert np.all(cosang > 1 - 1e-9), (face, cosang.min())
        if kind in SOLIDS:
            assert not _inside_batch(kind, params, p[keep] + eps * nrm[keep]).any()
            assert _inside_batch(kind, params, p[keep] - eps * nrm[keep]).all()


def _off_kinks(kind, face, us, vs, margin):
    """Mask of (u, v) away from the charts' derivative kinks."""
    a = 2 * us - 1
    b = 2 * vs - 1
    m = (np.abs(a) > margin) & (np.abs(b) > margin) & (np.abs(np.abs(a) - np.abs(b)) > margin)
    m &= np.abs(np.abs(a) + np.abs(b) - 1) > margin
    m &= (us > margin) & (us < 1 - margin) & (vs > margin) & (vs < 1 - margin)
    return m


@pytest.mark.parametrize("kind", ALL)
def test_derivatives_match_finite_differences(kind):
    rng = np.random.default_rng(90 + kind)
    params = params_of(kind)
    h = 1e-6
    for face in range(N_FACES[kind]):
        us, vs = faces_uv(rng, 2000)
        m = _off_kinks(kind, face, us, vs, 1e-3)
        us, vs = us[m], vs[m]
        p = _point_batch(kind, params, face, us, vs)
        du = (_point_batch(kind, params, face, us + h, vs)[:, :3]
              - _point_batch(kind, params, face, us - h, vs)[:, :3]) / (2 * h)
        dv = (_point_batch(kind, params, face, us, vs + h)[:, :3]
              - _point_batch(kind, params, face, us, vs - h)[:, :3]) / (2 * h)
        scale = 1.0 + np.max(np.abs(p[:, 3:]))
        assert np.max(np.abs(du - p[:, 3:6])) < 1e-6 * scale, face
        assert np.max(np.abs(dv - p[:, 6:9])) < 1e-6 * scale, face


def _gauss_triangles(cells=8, order=8):
    """Quadrature over [0,1]^2: cells split into 4 triangles by both diagonals.

    Cell edges land on u, v = 0.5 and the diagonals land on u = v, u = 1 - v
    and |2u-1| + |2v-1| = 1 (cells even), where the concentric and octahedral
    maps kink, so the integrand is smooth on every triangle.
    """
    x, w = np.polynomial.legendre.leggauss(order)
    x = 0.5 * (x + 1)
    w = 0.5 * w
    s, t = [a.ravel() for a in np.meshgrid(x, x, indexing="ij")]
    ws = np.outer(w, w).ravel()
    us, vs, wts = [], [], []
    h = 1.0 / cells
    for i in range(cells):
        for j in range(cells):
            c = np.array([(i + 0.5) * h, (j + 0.5) * h])
            corners = np.array([[i, j], [i + 1, j], [i + 1, j + 1], [i, j + 1]]) * h
            for k in range(4):
                b_, c_ = corners[k], corners[(k + 1) % 4]
                # Duffy map of the unit square onto the triangle (c, b_, c_)
                pt = c + s[:, None] * (b_ - c) + (s * t)[:, None] * (c_ - b_)
                jac = abs((b_ - c)[0] * (c_ - b_)[1] - (b_ - c)[1] * (c_ - b_)[0])
                us.append(pt[:, 0])
                vs.append(pt[:, 1])
                wts.append(ws * s * jac)
    return np.concatenate(us), np.concatenate(vs), np.concatenate(wts)


@pytest.mark.parametrize("kind", ALL)
def test_area_from_derivatives(kind):
    params = params_of(kind)
    us, vs, wts = _gauss_triangles()
    total = 0.0
    for face in range(N_FACES[kind]):
        p = _point_batch(kind, params, face, us, vs)
        total += np.sum(wts * np.linalg.norm(np.cross(p[:, 3:6], p[:, 6:9]), axis=1))
    area = prim_area(kind, params)
    assert abs(total - area) < 1e-9 * area, (total, area)


def test_area_closed_forms():
    r = TORUS_R
    pr = params_of(TORUS)
    z4 = np.zeros(4)
    assert prim_area(SPHERE, z4) == pytest.approx(4 * np.pi)
    assert prim_area(BOX, z4) == pytest.approx(24.0)
    assert prim_area(CYLINDER, z4) == pytest.approx(2 * np.pi * 2 + 2 * np.pi)
    assert prim_area(CONE, z4) == pytest.approx(np.pi + np.pi * np.sqrt(5))
    assert prim_area(TORUS, pr) == pytest.approx(4 * np.pi ** 2 * r)
    assert prim_area(PARABOLOID, z4) == pytest.approx(np.pi / 6 * (5 ** 1.5 - 1) + np.pi)
    assert prim_area(DISK, z4) == pytest.approx(np.pi)
    assert prim_area(QUAD, z4) == pytest.approx(4.0)
    t = FRUSTUM_T
    assert prim_area(FRUSTUM, params_of(FRUSTUM)) == pytest.approx(
        np.pi * (1 + t) * np.sqrt(4 + (1 - t) ** 2) + np.pi + np.pi * t * t)


@pytest.mark.parametrize("kind", ALL)
def test_bounds_tight(kind):
    rng = np.random.default_rng(100 + kind)
    params = params_of(kind)
    b = np.array(prim_local_bounds(kind, params))
    g = np.linspace(0, 1, 101)
    gu, gv = [a.ravel() for a in np.meshgrid(g, g)]
    us = np.r_[rng.random(20000), gu]
    vs = np.r_[rng.random(20000), gv]
    pts = np.vstack([_point_batch(kind, params, f, us, vs)[:, :3] for f in range(N_FACES[kind])])
    assert np.all(pts >= b[:3] - 1e-12) and np.all(pts <= b[3:] + 1e-12)
    assert np.all(pts.min(axis=0) < b[:3] + 0.02) and np.all(pts.max(axis=0) > b[3:] - 0.02)


# ------------------------------------------------------------------ frustum

def _close_hits(n1, t1, n2, t2, d, tol=1e-12):
    """Same hit counts, and the hits' points within tol (distance) of each other."""
    assert np.array_equal(n1, n2)
    m = np.isfinite(t1)
    assert np.array_equal(m, np.isfinite(t2))
    dl = np.broadcast_to(np.linalg.norm(d, axis=1)[:, None], t1.shape)
    assert np.all(np.abs(t1[m] - t2[m]) * dl[m] <= tol * (1.0 + np.abs(t1[m]) * dl[m]))


@pytest.mark.parametrize("ref", [CYLINDER, CONE])
def test_frustum_reduces_to_cylinder_and_cone(ref):
    """t = 1 is the cylinder, t = 0 the cone: same hits on random and special rays."""
    rng = np.random.default_rng(110 + ref)
    pr = params_of(FRUSTUM, 1.0 if ref == CYLINDER else 0.0)
    o, d = make_rays(ref, 20000, rng)
    # axis-parallel and generator-parallel lines (the quadrics' degenerate branches)
    g = rng.uniform(-1.3, 1.3, size=(400, 3))
    dirs = np.array([[0, 0, 1], [0, 0, -1], [0.5, 0, -1], [0, -0.5, 1], [0.3, 0.4, -1], [1, 0, 0]])
    o = np.vstack([o] + [g - 2.0 * dv for dv in dirs])
    d = np.vstack([d] + [np.broadcast_to(dv, g.shape).astype(float) for dv in dirs])
    n1, t1 = hits_of(FRUSTUM, o, d, pr)
    n2, t2 = hits_of(ref, o, d)
    assert np.sum(n1 > 0) > 0.4 * len(o)
    _close_hits(n1, t1, n2, t2, d)
    # prim_inside agrees, and so do the charts' normals at the hits
    pts = rng.uniform(-1.2, 1.2, size=(20000, 3))
    assert np.array_equal(_inside_batch(FRUSTUM, pr, pts), _inside_batch(ref, params_of(ref), pts))
    hit = np.nonzero(n1)[0][:2000]
    p = o[hit] + t1[hit, :1] * d[hit]
    _, s1 = _surface_batch(FRUSTUM, pr, p)
    _, s2 = _surface_batch(ref, params_of(ref), p)
    assert np.allclose(s1[:, 2:], s2[:, 2:], atol=1e-12)


@pytest.mark.parametrize("t", [0.0, 0.05, 0.5, 0.95, 1.0])
def test_frustum_hits_against_brute_force_for_several_t(t):
    rng = np.random.default_rng(int(120 + 100 * t))
    pr = params_of(FRUSTUM, t)
    o, d = make_rays(FRUSTUM, 800, rng, params=pr)
    # lines parallel to the axis and (exactly, for t = 0.5 and 0) to the side's generators:
    # 4 (dx^2 + dy^2) (1 - t)^-2 == dz^2
    s = 0.5 * (1 - t)
    gen = np.array([[1, 0, 4], [0, -1, -4], [3, 4, 20], [-3, 4, -20]], float)
    gen[:, :2] *= 4 * s
    dirs = np.vstack([[[0, 0, 1], [0, 0, -1], [1, 0, 0]], gen])
    g = np.linspace(-1.3, 1.3, 10)
    os, ds = [], []
    for dv in dirs:
        a = np.cross(dv, [0.3, 0.5, 0.7])
        a /= np.linalg.norm(a)
        b = np.cross(dv, a)
        b /= np.linalg.norm(b)
        for x in g:
            for y in g:
                os.append(x * a + y * b - 2.0 * dv / np.linalg.norm(dv))
                ds.append(dv)
    o = np.vstack([o, os])
    d = np.vstack([d, ds])
    n, skipped = _check_against_march(FRUSTUM, o, d, params=pr)
    assert skipped < 0.05 * len(o), skipped
    assert np.sum(n > 0) > 0.3 * len(o)


def test_frustum_tangent_and_grazing_rays_give_no_hits():
    for t in (0.0, 0.4, 1.0):
        pr = params_of(FRUSTUM, t)
        r0 = 1 + (t - 1) / 2                                   # radius at z = 0
        cases = [((-3.0, r0, 0.0), (1.0, 0.0, 0.0)),          # tangent to the side
                 ((-3.0, 0.2 * t, 1.0), (1.0, 0.0, 0.0)),      # in the top cap's plane
                 ((-3.0, 0.2, -1.0), (1.0, 0.0, 0.0)),         # in the base's plane
                 ((-3.0, 1.0, -1.0), (1.0, 0.0, 0.0)),         # along the base rim's tangent
                 ((-3.0, 0.0, 1.0), (1.0, 0.0, 0.0))]          # through the top (apex if t = 0)
        for o, d in cases:
            assert prim_hits(FRUSTUM, pr, *o, *d)[0] == 0, (t, o, d, prim_hits(FRUSTUM, pr, *o, *d))
        # a chord just below the top is a proper hit (for t = 0 a tiny one near the apex)
        n, t0, t1, _, _ = prim_hits(FRUSTUM, pr, -3.0, 0.0, 1.0 - 1e-9, 1.0, 0.0, 0.0)
        assert n == 2 and t1 - t0 == pytest.approx(2 * (t + 0.5e-9 * (1 - t)), rel=1e-6)


@pytest.mark.parametrize("t", [0.0, 1e-3, 0.7, 1.0])
def test_frustum_charts_for_several_t(t):
    """Round trips and orientation at the extremes (the cone's apex, the cylinder)."""
    rng = np.random.default_rng(int(130 + 1000 * t))
    pr = params_of(FRUSTUM, t)
    for face in range(3):
        us, vs = faces_uv(rng, 3000, 1e-6, 1 - 1e-6)
        pts = _point_batch(FRUSTUM, pr, face, us, vs)
        if face == 2 and t == 0.0:
            # zero-area top cap: everything maps to the apex, never reported
            assert np.all(pts[:, :3] == [0.0, 0.0, 1.0]) and np.all(pts[:, 3:] == 0.0)
            continue
        assert np.all(residual(FRUSTUM, pts[:, :3], pr) < 1e-13)
        p = np.ascontiguousarray(pts[:, :3])
        f, s = _surface_batch(FRUSTUM, pr, p)
        keep = np.ones(len(us), bool) if (face or t > 0) else vs < 0.999   # apex: u undefined
        assert np.all(f[keep] == face), (face, np.unique(f[keep]))
        assert np.allclose(s[keep, 0], us[keep], rtol=0, atol=1e-10)
        assert np.allclose(s[keep, 1], vs[keep], rtol=0, atol=1e-10)
        cr = np.cross(pts[:, 3:6], pts[:, 6:9])
        ln = np.linalg.norm(cr, axis=1)
        keep &= ln > 1e-6 * ln.max()
        assert np.all(np.sum(cr[keep] * s[keep, 2:], axis=1) / ln[keep] > 1 - 1e-9)
        eps = 1e-6
        assert not _inside_batch(FRUSTUM, pr, p[keep] + eps * s[keep, 2:]).any()
        if face or t > 0:
            assert _inside_batch(FRUSTUM, pr, p[keep] - eps * s[keep, 2:]).all()
    if t == 0.0:
        # points around the apex go to the side (or the base), never to the empty cap
        q = np.c_[rng.normal(scale=1e-7, size=(500, 2)), 1 - np.abs(rng.normal(scale=1e-7, size=500))]
        f, _ = _surface_batch(FRUSTUM, pr, q)
        assert np.all(f == 0)


@pytest.mark.parametrize("t", [0.0, 0.1, 0.4, 0.9, 1.0])
def test_frustum_area_formula(t):
    pr = params_of(FRUSTUM, t)
    us, vs, wts = _gauss_triangles()
    total = 0.0
    for face in range(3):
        p = _point_batch(FRUSTUM, pr, face, us, vs)
        total += np.sum(wts * np.linalg.norm(np.cross(p[:, 3:6], p[:, 6:9]), axis=1))
    exact = np.pi * (1 + t) * np.sqrt(4 + (1 - t) ** 2) + np.pi + np.pi * t * t
    assert prim_area(FRUSTUM, pr) == pytest.approx(exact, rel=1e-15)
    assert abs(total - exact) < 1e-9 * exact, (total, exact)
    if t == 1.0:
        assert exact == pytest.approx(prim_area(CYLINDER, params_of(CYLINDER)), rel=1e-15)
    if t == 0.0:
        assert exact == pytest.approx(prim_area(CONE, params_of(CONE)), rel=1e-15)


def test_check_primitive_frustum():
    for t in (0.0, 0.4, 1.0):
        kid, p4, *_ = check_primitive(Primitive("frustum", params=(t,), name="twig"), "primitive 'twig'")
        assert kid == FRUSTUM and p4[0] == t
    for bad in ((-0.1,), (1.5,), (np.nan,), (np.inf,), ()):
        with pytest.raises(SceneError, match="primitive 'twig'"):
            check_primitive(Primitive("frustum", params=bad, name="twig"), "primitive 'twig'")
