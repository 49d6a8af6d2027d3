"""Lights seen along glossy rays, and the densities multiple importance sampling weighs.

Camera paths reach a light two ways: a shadow ray from direct-light sampling
(lights.sample_light) or a glossy/transmitted ray that happens to hit it. Both
estimate the same radiance, so each is weighted by the power heuristic over
the two densities (Veach 1997), which keeps small bright lights on rough
metal as clean as large dim ones. As in Cycles, analytic lights are invisible
to camera rays and transparent (they add emission, they never block), and
only lights with a size can be hit: a point of radius 0 or a sun of angle 0
is a delta the glossy lobes only see through light sampling.

Emissive surfaces are geometry: a glossy ray that hits one adds its emission
unweighted, and their light samples skip the glossy lobes (unbiased, no MIS).
"""
import math

from numba import njit

from ..core.jit import CORE
from . import environment
from . import polarization
from .lights import AREA, ELLIPSE, EMISSIVE, ENVIRONMENT, POINT, SPOT, SUN, environment_of, spot_mask


@njit(cache=True, inline="always")
def power_heuristic(a, b):
    a2 = a * a
    return a2 / (a2 + b * b) if a2 > 0.0 else 0.0


@njit(cache=True)
def selection_factor(ls, li):
    """How often direct-light sampling tries light li per shading point
    (renderer.direct_light: every light once, or 4 by power when there are more than 8)."""
    n = ls.kind.shape[0]
    if n <= 8:
        return 1.0
    total = ls.power_cdf[n - 1]
    p = (ls.power_cdf[li] - (ls.power_cdf[li - 1] if li > 0 else 0.0)) / total
    return 4.0 * p


@njit(cache=True)
def sphere_cone(ls, li, px, py, pz):
    """cos of the half angle under which point/spot light li's sphere is seen from p,
    or -1 where light sampling treats it as a delta (radius 0, too far, or p inside)."""
    r = ls.radius[li]
    if r <= 0.0:
        return -1.0
    dx, dy, dz = ls.pos[li, 0] - px, ls.pos[li, 1] - py, ls.pos[li, 2] - pz
    d2 = dx * dx + dy * dy + dz * dz
    if d2 <= r * r:
        return -1.0
    sin2 = r * r / d2
    if sin2 < 1e-12:
        return -1.0
    return math.sqrt(max(0.0, 1.0 - sin2))


@njit(cache=True)
def light_pdf(ls, li, px, py, pz, wx, wy, wz, dist):
    """Solid-angle density with which sample_light picks direction w from p towards
    light li at distance dist; inf for deltas, 0 for lights the glossy lobes skip."""
    k = ls.kind[li]
    if k == AREA:
        cos_l = -(wx * ls.normal[li, 0] + wy * ls.normal[li, 1] + wz * ls.normal[li, 2])
        if cos_l <= 0.0:
            return 0.0
        return dist * dist / (cos_l * ls.area[li])
    if k == POINT or k == SPOT:
        c = sphere_cone(ls, li, px, py, pz)
        if c < 0.0:
            return math.inf
        return 1.0 / (2.0 * math.pi * (1.0 - c))
    if k == SUN:
        if ls.cos_half[li] >= 1.0:
            return math.inf
        return 1.0 / (2.0 * math.pi * (1.0 - ls.cos_half[li]))
    if k == ENVIRONMENT:
        if ls.env_constant:
            return 1.0 / (4.0 * math.pi)
        return environment.pdf(environment_of(ls), wx, wy, wz)
    return 0.0


@njit(cache=True)
def _area_hit(ls, li, ox, oy, oz, dx, dy, dz, tmax):
    nx, ny, nz = ls.normal[li, 0], ls.normal[li, 1], ls.normal[li, 2]
    dn = dx * nx + dy * ny + dz * nz
    if dn >= 0.0:                       # one-sided: only the front emits
        return -1.0
    t = ((ls.pos[li, 0] - ox) * nx + (ls.pos[li, 1] - oy) * ny + (ls.pos[li, 2] - oz) * nz) / dn
    if not 0.0 < t < tmax:
        return -1.0
    qx = ox + t * dx - ls.pos[li, 0]
    qy = oy + t * dy - ls.pos[li, 1]
    qz = oz + t * dz - ls.pos[li, 2]
    ux, uy, uz = ls.axis_u[li, 0], ls.axis_u[li, 1], ls.axis_u[li, 2]
    vx, vy, vz = ls.axis_v[li, 0], ls.axis_v[li, 1], ls.axis_v[li, 2]
    a = (qx * ux + qy * uy + qz * uz) / (ux * ux + uy * uy + uz * uz)
    b = (qx * vx + qy * vy + qz * vz) / (vx * vx + vy * vy + vz * vz)
    if ls.shape[li] == ELLIPSE:
        inside = a * a + b * b <= 1.0
    else:
        inside = abs(a) <= 1.0 and abs(b) <= 1.0
    return t if inside else -1.0


@njit(cache=True)
def _sphere_hit(ls, li, ox, oy, oz, dx, dy, dz, tmax):
    r = ls.radius[li]
    cx, cy, cz = ox - ls.pos[li, 0], oy - ls.pos[li, 1], oz - ls.pos[li, 2]
    b = cx * dx + cy * dy + cz * dz
    c = cx * cx + cy * cy + cz * cz - r * r
    disc = b * b - c
    if disc < 0.0 or c <= 0.0:
        return -1.0
    t = -b - math.sqrt(disc)
    return t if 0.0 < t < tmax else -1.0


@njit(**CORE)
def add_seen_lights(ls, ox, oy, oz, dx, dy, dz, tmax, pdf_bsdf, delta, tp, acc, pol, polarized):
    """Adds into acc the radiance tp * L of every sized light the ray o + t d
    (t < tmax; inf: the ray escaped) passes, weighted against light sampling.

    pdf_bsdf is the density the path's glossy sampling chose d with; delta marks a
    mirror/refraction sample, which light sampling cannot produce (weight 1).
    The environment is left to the caller, which knows the world's radiance.
    polarized: a camera path that traces polarization, its rows in pol: a light
    behind a polarizer sends polarized light, which each band's row measures.
    """
    nb = acc.shape[0]
    for li in range(ls.kind.shape[0]):
        k = ls.kind[li]
        if k == EMISSIVE or k == ENVIRONMENT:
            continue
        scale = 0.0
        pdf_l = 0.0
        if k == AREA:
            t = _area_hit(ls, li, ox, oy, oz, dx, dy, dz, tmax)
            if t < 0.0:
                continue
            pdf_l = light_pdf(ls, li, ox, oy, oz, dx, dy, dz, t)
            scale = 1.0
        elif k == POINT or k == SPOT:
            c = sphere_cone(ls, li, ox, oy, oz)
            if c < 0.0:
                continue
            t = _sphere_hit(ls, li, ox, oy, oz, dx, dy, dz, tmax)
            if t < 0.0:
                continue
            r = ls.radius[li]
            ex, ey, ez = ls.pos[li, 0] - ox, ls.pos[li, 1] - oy, ls.pos[li, 2] - oz
            d2 = ex * ex + ey * ey + ez * ez
            soft = d2 / (d2 + r * r) if ls.soft[li] else 1.0
            mask = spot_mask(ls, li, -dx, -dy, -dz) if k == SPOT else 1.0
            scale = soft * mask / (math.pi * r * r)
            pdf_l = 1.0 / (2.0 * math.pi * (1.0 - c))
        else:   # SUN: only rays that leave the scene see it
            if tmax < math.inf or ls.cos_half[li] >= 1.0:
                continue
            if -(dx * ls.normal[li, 0] + dy * ls.normal[li, 1] + dz * ls.normal[li, 2]) < ls.cos_half[li]:
                continue
            pdf_l = 1.0 / (2.0 * math.pi * (1.0 - ls.cos_half[li]))
            scale = pdf_l
        if scale <= 0.0:
            continue
        w = 1.0 if delta else power_heuristic(pdf_bsdf, selection_factor(ls, li) * pdf_l)
        if polarized and ls.pol[li, 3] > 0.0:
            axis = (ls.pol[li, 0], ls.pol[li, 1], ls.pol[li, 2])
            for b in range(nb):
                acc[b] += (tp[b] * ls.radiance[li, b] * scale * w
                           * polarization.arriving_light(pol, nb, b, axis, (-dx, -dy, -dz)))
            continue
        for b in range(nb):
            acc[b] += tp[b] * ls.radiance[li, b] * scale * w


@njit(**CORE)
def environment_light(ls):
    """Index of the environment's light row, -1 when the world is dark."""
    for li in range(ls.kind.shape[0]):
        if ls.kind[li] == ENVIRONMENT:
            return li
    return -1
