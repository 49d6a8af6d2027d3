"""Exact texel areas (thesis 3.5.2): the A_j of B_j = m_j Φ / A_j, computed once per surface.

* Mesh atlases: each UV triangle is clipped against every texel square it
  overlaps (Sutherland–Hodgman, one rasteriser for areas and pieces) and its
  world area is shared out in proportion to the clipped UV area. A triangle
  without UV area owns no texel (and records no photon, lightmap.record_slot).
* Analytic primitives: Gauss–Legendre quadrature of |M dp/du × M dp/dv| over
  every texel cell, with the cells split along the creases of the (u, v) maps
  (octahedral sphere map, concentric disk map) so the integrand is smooth on
  every piece. Primitives under rotation × uniform scale reuse one cached
  quadrature of their local areas.
"""
import functools
import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from ..core.affine import apply_linear, cross
from ..geometry.primitives import prim_nfaces, prim_point

# A UV triangle whose doubled area in [0,1]² is below this has no texels: it
# neither owns area nor records photons (a photon there would land in some
# neighbouring chart's texel). Far below any real triangle of a 4096² atlas.
MIN_UV_AREA2 = 1e-15
MAX_PIECE_VERTICES = 7   # a triangle clipped by the four sides of a square


def cofactor(M):
    """cof(M) = det(M) M^-T, so (M a) × (M b) = cof(M) (a × b); defined for singular M too."""
    M = np.asarray(M, np.float64)[:3, :3]
    c0, c1, c2 = M[:, 0], M[:, 1], M[:, 2]
    return np.ascontiguousarray(np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=1))


def triangle_world_areas(tri_p, M=None):
    """World areas of triangles (T, 3, 3) under the linear part M of an affine map."""
    p = np.asarray(tri_p, np.float64)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    if M is not None:
        n = n @ cofactor(M).T
    return 0.5 * np.linalg.norm(n, axis=1)


# --------------------------------------------------------------------------------------
# Exact texel areas of UV triangles
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def _clip_axis(px, py, n, qx, qy, axis, bound, keep_below):
    """One Sutherland–Hodgman step against x<=bound / x>=bound (axis 0) or y (axis 1)."""
    m = 0
    if n == 0:
        return 0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        ax, ay, bx, by = px[i], py[i], px[j], py[j]
        ca = ax if axis == 0 else ay
        cb = bx if axis == 0 else by
        ina = (ca <= bound) if keep_below else (ca >= bound)
        inb = (cb <= bound) if keep_below else (cb >= bound)
        if ina:
            qx[m] = ax
            qy[m] = ay
            m += 1
        if ina != inb:
            t = (bound - ca) / (cb - ca)
            if axis == 0:
                qx[m] = bound
                qy[m] = ay + t * (by - ay)
            else:
                qx[m] = ax + t * (bx - ax)
                qy[m] = bound
            m += 1
    return m


@njit(cache=True, inline="always")
def _clip_unit_square(x0, y0, x1, y1, x2, y2, px, py, qx, qy):
    """Clips the triangle (texel units, relative to the texel corner) to [0,1]²:
    the polygon is left in px, py (at most 7 vertices); returns its vertex count."""
    px[0], py[0], px[1], py[1], px[2], py[2] = x0, y0, x1, y1, x2, y2
    n = _clip_axis(px, py, 3, qx, qy, 0, 0.0, False)
    n = _clip_axis(qx, qy, n, px, py, 0, 1.0, True)
    n = _clip_axis(px, py, n, qx, qy, 1, 0.0, False)
    return _clip_axis(qx, qy, n, px, py, 1, 1.0, True)


@njit(cache=True, inline="always")
def _polygon_area(px, py, n):
    """Area of the convex polygon px, py[:n] (0 for fewer than 3 vertices)."""
    if n < 3:
        return 0.0
    s = 0.0
    for i in range(n):
        j = i + 1 if i + 1 < n else 0
        s += px[i] * py[j] - px[j] * py[i]
    return abs(0.5 * s)


@njit(cache=True, inline="always")
def has_uv_area(uv):
    """A UV triangle (3, 2) that covers texels (see MIN_UV_AREA2)."""
    return abs((uv[1, 0] - uv[0, 0]) * (uv[2, 1] - uv[0, 1])
               - (uv[2, 0] - uv[0, 0]) * (uv[1, 1] - uv[0, 1])) > MIN_UV_AREA2


@njit(cache=True, inline="always")
def _uv_triangle(uv, area3d, k, W, H):
    """Triangle k in texel units and its box of texels -> (cells, x0..y2, bx0, by0, bx1, by1);
    cells = 0 when it covers none: no world area, no UV area (has_uv_area), not finite."""
    x0, y0 = uv[k, 0, 0] * W, uv[k, 0, 1] * H
    x1, y1 = uv[k, 1, 0] * W, uv[k, 1, 1] * H
    x2, y2 = uv[k, 2, 0] * W, uv[k, 2, 1] * H
    a3 = area3d[k]
    if not (a3 > 0.0 and math.isfinite(a3) and math.isfinite(x0 + y0 + x1 + y1 + x2 + y2)
            and has_uv_area(uv[k])):
        return 0, x0, y0, x1, y1, x2, y2, 0, 0, -1, -1
    bx0 = max(int(math.floor(min(x0, x1, x2))), 0)
    by0 = max(int(math.floor(min(y0, y1, y2))), 0)
    bx1 = min(int(math.floor(max(x0, x1, x2))), W - 1)
    by1 = min(int(math.floor(max(y0, y1, y2))), H - 1)
    cells = (bx1 - bx0 + 1) * (by1 - by0 + 1) if bx1 >= bx0 and by1 >= by0 else 0
    return cells, x0, y0, x1, y1, x2, y2, bx0, by0, bx1, by1


@njit(cache=True)
def _piece_buffers(cap, with_bary):
    """Per-triangle scratch: texel, clipped UV area, polygon size, polygon barycentrics."""
    return (np.empty(cap, np.int64), np.empty(cap), np.empty(cap, np.int64),
            np.empty((cap if with_bary else 0, MAX_PIECE_VERTICES, 2)))


@njit(cache=True)
def _clip_into_texels(x0, y0, x1, y1, x2, y2, bx0, by0, bx1, by1, W, buf_i, buf_a, buf_nv, buf_b,
                      px, py, qx, qy):
    """Clips a triangle (texel units) to every texel of its box, the one rasteriser
    of the texel areas and pieces: texel ids, clipped UV areas and, when buf_b
    has room, the clipped polygons as barycentrics -> (pieces, their total area)."""
    det = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    with_bary = buf_b.shape[0] > 0
    m = 0
    total = 0.0
    for ty in range(by0, by1 + 1):
        for tx in range(bx0, bx1 + 1):
            n = _clip_unit_square(x0 - tx, y0 - ty, x1 - tx, y1 - ty, x2 - tx, y2 - ty, px, py, qx, qy)
            c = _polygon_area(px, py, n)
            if c > 0.0:
                buf_i[m] = ty * W + tx
                buf_a[m] = c
                buf_nv[m] = min(n, MAX_PIECE_VERTICES)
                if with_bary:
                    for i in range(buf_nv[m]):
                        rx = px[i] + tx - x0
                        ry = py[i] + ty - y0
                        buf_b[m, i, 0] = (rx * (y2 - y0) - (x2 - x0) * ry) / det
                        buf_b[m, i, 1] = ((x1 - x0) * ry - rx * (y1 - y0)) / det
                total += c
                m += 1
    return m, total


@njit(cache=True)
def _triangle_texel_areas(uv, area3d, width, height):
    W = width
    H = height
    area = np.zeros(W * H)
    cov = np.zeros(W * H)
    px, py, qx, qy = np.empty(16), np.empty(16), np.empty(16), np.empty(16)
    buf_i, buf_a, buf_nv, buf_b = _piece_buffers(64, False)
    for k in range(uv.shape[0]):
        cells, x0, y0, x1, y1, x2, y2, bx0, by0, bx1, by1 = _uv_triangle(uv, area3d, k, W, H)
        if cells == 0:
            continue  # no texels: it records no photons either (record_slot)
        if cells > buf_i.shape[0]:
            buf_i, buf_a, buf_nv, buf_b = _piece_buffers(max(cells, 2 * buf_i.shape[0]), False)
        m, total = _clip_into_texels(x0, y0, x1, y1, x2, y2, bx0, by0, bx1, by1, W,
                                     buf_i, buf_a, buf_nv, buf_b, px, py, qx, qy)
        if m > 0 and total > 0.0:
            # Dividing by the sum of the clipped pieces (not the analytic UV area)
            # makes the triangle deposit exactly its world area, also for parts
            # that stick out of [0,1]².
            a3 = area3d[k]
            for i in range(m):
                area[buf_i[i]] += a3 * (buf_a[i] / total)
                cov[buf_i[i]] += buf_a[i]
    for i in range(W * H):
        cov[i] = min(cov[i], 1.0)
    return area, cov


def _atlas_inputs(uv, area3d, width, height):
    """Checked kernel inputs: uv (T,3,2) and area3d (T,) float64, a W×H atlas."""
    uv = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 3, 2)
    area3d = np.ascontiguousarray(area3d, dtype=np.float64).reshape(-1)
    if area3d.shape[0] != uv.shape[0]:
        raise ValueError(f"{uv.shape[0]} UV triangles but {area3d.shape[0]} areas")
    width, height = int(width), int(height)
    if width < 1 or height < 1:
        raise ValueError(f"invalid atlas size {width}x{height}")
    return uv, area3d, width, height


def triangle_texel_areas(uv, area3d, width, height):
    """Exact world area and UV coverage of every texel of a W×H atlas.

    uv (T,3,2) in [0,1]² and area3d (T,) world areas of the same triangles.
    Returns (area (H*W,), coverage (H*W,)), row-major (index y*W + x).
    Each triangle's area3d is shared among the texels it overlaps in proportion
    to the exactly clipped UV area, so sum(area) == sum(area3d) over triangles
    with UV area. Triangles without UV area (has_uv_area) or world area add
    nothing, and record no photons (record_slot).
    """
    return _triangle_texel_areas(*_atlas_inputs(uv, area3d, width, height))



TexelPieces = namedtuple("TexelPieces", [
    "start",  # int64[W*H+1] pieces of texel j: start[j] : start[j+1]
    "tri",    # int64[P]     triangle (row of the uv array given)
    "area",   # float64[P]   world area of the piece (sums to the texel's area)
    "nv",     # int64[P]     polygon vertex count (3..7)
    "bary",   # float64[P, 7, 2] polygon vertices as barycentrics (b1, b2) of the triangle
])


@njit(cache=True, nogil=True)
def _triangle_texel_pieces(uv, area3d, width, height):
    # The same rasteriser as _triangle_texel_areas (_uv_triangle, _clip_into_texels,
    # the same shares), so the pieces of a texel add up to the area it gets there.
    W = width
    H = height
    cap = 256
    p_tri = np.empty(cap, np.int64)
    p_tex = np.empty(cap, np.int64)
    p_area = np.empty(cap)
    p_nv = np.empty(cap, np.int64)
    p_b = np.empty((cap, MAX_PIECE_VERTICES, 2))
    n_p = 0
    px, py, qx, qy = np.empty(16), np.empty(16), np.empty(16), np.empty(16)
    buf_i, buf_a, buf_nv, buf_b = _piece_buffers(64, True)
    for k in range(uv.shape[0]):
        cells, x0, y0, x1, y1, x2, y2, bx0, by0, bx1, by1 = _uv_triangle(uv, area3d, k, W, H)
        if cells == 0:
            continue
        if cells > buf_i.shape[0]:
            buf_i, buf_a, buf_nv, buf_b = _piece_buffers(max(cells, 2 * buf_i.shape[0]), True)
        m, total = _clip_into_texels(x0, y0, x1, y1, x2, y2, bx0, by0, bx1, by1, W,
                                     buf_i, buf_a, buf_nv, buf_b, px, py, qx, qy)
        if m == 0 or not total > 0.0:
            continue
        if n_p + m > cap:
            cap = max(2 * cap, n_p + m)
            t_tri = np.empty(cap, np.int64)
            t_tex = np.empty(cap, np.int64)
            t_area = np.empty(cap)
            t_nv = np.empty(cap, np.int64)
            t_b = np.empty((cap, MAX_PIECE_VERTICES, 2))
            t_tri[:n_p] = p_tri[:n_p]
            t_tex[:n_p] = p_tex[:n_p]
            t_area[:n_p] = p_area[:n_p]
            t_nv[:n_p] = p_nv[:n_p]
            t_b[:n_p] = p_b[:n_p]
            p_tri, p_tex, p_area, p_nv, p_b = t_tri, t_tex, t_area, t_nv, t_b
        a3 = area3d[k]
        for i in range(m):
            p_tri[n_p] = k
            p_tex[n_p] = buf_i[i]
            p_area[n_p] = a3 * (buf_a[i] / total)
            p_nv[n_p] = buf_nv[i]
            p_b[n_p] = buf_b[i]
            n_p += 1
    return p_tri[:n_p], p_tex[:n_p], p_area[:n_p], p_nv[:n_p], p_b[:n_p]


# Triangles per block of the clipping: a dense mesh's clipping is split over the
# threads (the kernel releases the GIL); a small one stays in one call.
PIECES_BLOCK = 16384


def _pieces_in_blocks(uv, area3d, width, height):
    """_triangle_texel_pieces over blocks of triangles on the pool, joined in
    triangle order: the same arrays one call gives."""
    from ..core import parallel
    if uv.shape[0] < 2 * PIECES_BLOCK:
        return _triangle_texel_pieces(uv, area3d, width, height)
    parts = {}

    def block(start, stop):
        parts[start] = _triangle_texel_pieces(uv[start:stop], area3d[start:stop], width, height)
    parallel.run(block, uv.shape[0], min_block=PIECES_BLOCK)
    starts = sorted(parts)
    tri = np.concatenate([parts[a][0] + a for a in starts])
    return (tri,) + tuple(np.concatenate([parts[a][k] for a in starts]) for k in range(1, 5))


def triangle_texel_pieces(uv, area3d, width, height):
    """The parts of the UV triangles inside each texel of a W×H atlas (for
    integrating over a texel's surface, e.g. direct light at bake time).

    Same inputs and rules as `triangle_texel_areas`: a piece is a triangle
    clipped to a texel square, with that triangle's world area shared in
    proportion to clipped UV area; a triangle without UV area has no pieces.
    Returns `TexelPieces`, grouped by texel (CSR),
    within a texel in triangle order; per texel the piece areas sum to the
    texel's area from `triangle_texel_areas`.
    """
    uv, area3d, width, height = _atlas_inputs(uv, area3d, width, height)
    tri, tex, area, nv, bary = _pieces_in_blocks(uv, area3d, width, height)
    order = np.argsort(tex, kind="stable")
    start = np.zeros(width * height + 1, np.int64)
    np.cumsum(np.bincount(tex, minlength=width * height), out=start[1:])
    return TexelPieces(start, tri[order], area[order], nv[order], bary[order])


# --------------------------------------------------------------------------------------
# Exact texel areas of analytic primitives (quadrature)
# --------------------------------------------------------------------------------------

# Creases of the primitive (u, v) maps, as lines a·u + b·v = c: the octahedral
# sphere map folds along u = ½, v = ½ and |u-½| + |v-½| = ½; the concentric disk
# map along the diagonals u = v and u + v = 1. Quadrature pieces never cross them.
_CREASES = np.array([
    [1.0, 0.0, 0.5], [0.0, 1.0, 0.5],
    [1.0, -1.0, 0.0], [1.0, 1.0, 1.0],
    [1.0, 1.0, 0.5], [1.0, 1.0, 1.5],
    [1.0, -1.0, 0.5], [1.0, -1.0, -0.5],
])

# Small tiles are subdivided so that a quadrature piece spans at most 1/_MIN_CELLS
# of the chart: a 2×2 sphere map would otherwise integrate a whole octant per rule.
_MIN_CELLS = 32
# Rule order for the pieces within _NEAR_CENTRE cells of the chart centre (see _quad_split).
_CENTRE_ORDER = 16
_NEAR_CENTRE = 4.0


@functools.lru_cache(maxsize=16)
def _gauss_legendre01(order):
    """Gauss–Legendre nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(int(order))
    return np.ascontiguousarray(0.5 * (x + 1.0)), np.ascontiguousarray(0.5 * w)


@njit(cache=True, inline="always")
def _area_element(kind, params, face, u, v, cof):
    r = prim_point(kind, params, face, u, v)
    nx, ny, nz = cross(r[3], r[4], r[5], r[6], r[7], r[8])
    wx, wy, wz = apply_linear(cof, nx, ny, nz)
    return math.sqrt(wx * wx + wy * wy + wz * wz)


@njit(cache=True)
def _quad_rect(kind, params, face, cof, u0, v0, du, dv, gx, gw):
    """Tensor Gauss–Legendre rule on the rectangle [u0, u0+du] × [v0, v0+dv]."""
    s = 0.0
    for i in range(gx.shape[0]):
        for j in range(gx.shape[0]):
            s += gw[i] * gw[j] * _area_element(kind, params, face, u0 + gx[i] * du,
                                               v0 + gx[j] * dv, cof)
    return s * du * dv


@njit(cache=True)
def _quad_triangle(kind, params, face, cof, ax, ay, bx, by, cx, cy, gx, gw):
    # Collapsed (Duffy) square -> triangle map: p = A + ξ(B-A) + ξη(C-B), dA = 2|T| ξ.
    j2 = abs((bx - ax) * (cy - ay) - (cx - ax) * (by - ay))
    if j2 == 0.0:
        return 0.0
    s = 0.0
    for i in range(gx.shape[0]):
        xi = gx[i]
        for j in range(gx.shape[0]):
            et = gx[j]
            u = ax + xi * (bx - ax) + xi * et * (cx - bx)
            v = ay + xi * (by - ay) + xi * et * (cy - by)
            s += gw[i] * gw[j] * xi * _area_element(kind, params, face, u, v, cof)
    return s * j2


@njit(cache=True)
def _quad_split(kind, params, face, cof, u0, v0, du, dv, gx, gw, gx_c, gw_c, creases):
    """Integral over a cell that a crease crosses: split it into convex pieces
    between the creases, fan-triangulate each and integrate the triangles."""
    maxp = 64
    maxv = 16
    polx = np.empty((maxp, maxv))
    poly = np.empty((maxp, maxv))
    pn = np.zeros(maxp, np.int64)
    polx[0, 0], poly[0, 0] = u0, v0
    polx[0, 1], poly[0, 1] = u0 + du, v0
    polx[0, 2], poly[0, 2] = u0 + du, v0 + dv
    polx[0, 3], poly[0, 3] = u0, v0 + dv
    pn[0] = 4
    npoly = 1
    tol = 1e-12 * (du + dv)
    d = np.empty(maxv)
    ax_ = np.empty(maxv)
    ay_ = np.empty(maxv)
    for c in range(creases.shape[0]):
        a, b, k = creases[c, 0], creases[c, 1], creases[c, 2]
        cur = npoly
        for p in range(cur):
            n = pn[p]
            lo = 0
            hi = 0
            for i in range(n):
                d[i] = a * polx[p, i] + b * poly[p, i] - k
                if d[i] < -tol:
                    lo += 1
                elif d[i] > tol:
                    hi += 1
            if lo == 0 or hi == 0 or npoly >= maxp:
                continue
            # Keep the d <= 0 side in p, append the d >= 0 side as a new polygon.
            q = npoly
            npoly += 1
            na = 0
            nb = 0
            for i in range(n):
                j = i + 1 if i + 1 < n else 0
                xi_, yi_, di = polx[p, i], poly[p, i], d[i]
                dj = d[j]
                if di <= tol:
                    ax_[na] = xi_
                    ay_[na] = yi_
                    na += 1
                if di >= -tol:
                    polx[q, nb] = xi_
                    poly[q, nb] = yi_
                    nb += 1
                if (di < -tol and dj > tol) or (di > tol and dj < -tol):
                    t = di / (di - dj)
                    ix = xi_ + t * (polx[p, j] - xi_)
                    iy = yi_ + t * (poly[p, j] - yi_)
                    ax_[na] = ix
                    ay_[na] = iy
                    na += 1
                    polx[q, nb] = ix
                    poly[q, nb] = iy
                    nb += 1
            for i in range(na):
                polx[p, i] = ax_[i]
                poly[p, i] = ay_[i]
            pn[p] = na
            pn[q] = nb
    s = 0.0
    for p in range(npoly):
        n = pn[p]
        # Fan from the vertex nearest the chart centre: the concentric map (and the
        # cone apex) make the integrand depend on the direction from the centre,
        # which the collapsed vertex of the Duffy rule turns into a smooth
        # function of the angle. It does not flatten as cells shrink, so pieces
        # at the centre get the high-order rule.
        c0 = 0
        best = 1e300
        for i in range(n):
            dc = abs(polx[p, i] - 0.5) + abs(poly[p, i] - 0.5)
            if dc < best:
                best = dc
                c0 = i
        centre = best <= tol
        for k in range(1, n - 1):
            i = (c0 + k) % n
            j = (c0 + k + 1) % n
            if centre:
                s += _quad_triangle(kind, params, face, cof, polx[p, c0], poly[p, c0],
                                    polx[p, i], poly[p, i], polx[p, j], poly[p, j], gx_c, gw_c)
            else:
                s += _quad_triangle(kind, params, face, cof, polx[p, c0], poly[p, c0],
                                    polx[p, i], poly[p, i], polx[p, j], poly[p, j], gx, gw)
    return s


@njit(cache=True)
def _crosses_crease(u0, v0, du, dv, creases):
    tol = 1e-12 * (du + dv)
    for c in range(creases.shape[0]):
        a, b, k = creases[c, 0], creases[c, 1], creases[c, 2]
        lo = False
        hi = False
        for corner in range(4):
            u = u0 + (du if corner == 1 or corner == 2 else 0.0)
            v = v0 + (dv if corner >= 2 else 0.0)
            dd = a * u + b * v - k
            if dd < -tol:
                lo = True
            elif dd > tol:
                hi = True
        if lo and hi:
            return True
    return False


@njit(cache=True, parallel=True)
def _primitive_areas_kernel(kind, params, cof, n_faces, r, sub, gx, gw, gx_c, gw_c, creases):
    out = np.zeros(n_faces * r * r)
    h = 1.0 / (r * sub)
    for cell in prange(n_faces * r * r):
        face = cell // (r * r)
        rem = cell - face * r * r
        y = rem // r
        x = rem - y * r
        s = 0.0
        for sy in range(sub):
            v0 = (y * sub + sy) * h
            for sx in range(sub):
                u0 = (x * sub + sx) * h
                # Near the chart centre the integrand of the concentric maps varies
                # with the direction to the centre on the scale of the cell itself.
                near = max(abs(u0 + 0.5 * h - 0.5), abs(v0 + 0.5 * h - 0.5)) < _NEAR_CENTRE * h
                if _crosses_crease(u0, v0, h, h, creases):
                    if near:
                        s += _quad_split(kind, params, face, cof, u0, v0, h, h, gx_c, gw_c,
                                         gx_c, gw_c, creases)
                    else:
                        s += _quad_split(kind, params, face, cof, u0, v0, h, h, gx, gw,
                                         gx_c, gw_c, creases)
                elif near:
                    s += _quad_rect(kind, params, face, cof, u0, v0, h, h, gx_c, gw_c)
                else:
                    s += _quad_rect(kind, params, face, cof, u0, v0, h, h, gx, gw)
        out[cell] = s
    return out


def primitive_texel_areas(kind, params, M, R, order=None):
    """World area of every texel cell of an analytic primitive, by quadrature.

    kind: primitive kind id (engine.geometry.primitives); params: float64[4]; M: 3×3 (or
    3×4) linear part of the primitive -> world map; R: texels per tile side.
    Returns float64[F*R*R] in FACE-MAJOR order (index f*R*R + y*R + x, texel
    (x, y) of face f covering [x/R,(x+1)/R]×[y/R,(y+1)/R]); use
    ``faces_to_rows`` for the lightmap's tiles-side-by-side row layout (both
    coincide for one face). The area element is |M pu × M pv| = |cof(M)(pu × pv)|,
    integrated with an order×order Gauss–Legendre rule on every piece of the
    cell between map creases (order None: 4, or 3 from R = 512 on, where the
    cells are small enough). Coverage is 1 for all primitive texels.
    """
    kind = int(kind)
    R = int(R)
    if R < 1:
        raise ValueError(f"resolution must be >= 1, got {R}")
    n_faces = int(prim_nfaces(kind))
    if n_faces < 1:
        raise ValueError(f"unknown primitive kind {kind}")
    p = np.zeros(4)
    pv = np.asarray(params, np.float64).reshape(-1)[:4]
    p[:pv.size] = pv
    if order is None:
        order = 4 if R < 512 else 3
    M = np.asarray(M, np.float64)[:3, :3]
    s2 = _similarity_scale2(M)
    if s2 is not None:
        # rotation x uniform scale: every texel's area is its local one times s²,
        # so thousands of instanced spheres share one quadrature
        return _local_texel_areas(kind, tuple(p), R, int(order)) * s2
    return _texel_areas_quadrature(kind, p, M, R, int(order))


def _texel_areas_quadrature(kind, p, M, R, order):
    gx, gw = _gauss_legendre01(order)
    gx_c, gw_c = _gauss_legendre01(max(int(order), _CENTRE_ORDER))
    sub = max(1, -(-_MIN_CELLS // R))
    return _primitive_areas_kernel(kind, p, cofactor(M), prim_nfaces(kind), R, sub, gx, gw, gx_c,
                                   gw_c, _CREASES)


@functools.lru_cache(maxsize=256)
def _local_texel_areas_cached(kind, params, R, order):
    a = _texel_areas_quadrature(kind, np.asarray(params, np.float64), np.eye(3), R, order)
    a.flags.writeable = False
    return a


def _local_texel_areas(kind, params, R, order):
    return _local_texel_areas_cached(kind, params, R, order).copy()


def _similarity_scale2(M, rtol=1e-12):
    """s² if M = s·Q with Q orthogonal (MᵀM = s² I), else None."""
    G = M.T @ M
    s2 = float(np.trace(G)) / 3.0
    if s2 > 0.0 and np.abs(G - s2 * np.eye(3)).max() <= rtol * s2:
        return s2
    return None
