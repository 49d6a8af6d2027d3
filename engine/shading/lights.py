"""Emitters: exact emitted flux, photon emission and direct-light sampling.

Units follow Cycles so that a Blender scene means the same here:
* point/spot of power P [W]: intensity I = P / (4 pi) W/sr (a spot only masks it);
  with a radius r it is a uniform sphere of radiance I / (pi r^2).
  Blender's "soft falloff" (on by default) makes Cycles light a receiver at
  distance d like I cos / (d^2 + r^2) instead of the sphere's I cos / d^2
  (measured against Cycles 5.0 to < 1% per pixel); a Light with the extra
  attribute `soft_falloff = True` gets that in direct lighting. Photons still
  leave the physical sphere, which differs only within a few radii of it.
* area light of power P: one-sided Lambertian, radiance L = P / (pi A).
* sun of strength S: irradiance S [W/m^2] on a surface facing it.
* emissive surfaces: radiance L = emission colour x strength; open surfaces
  (triangles, disks, quads) emit from both sides as in Cycles, solids outward.
* environment: a constant radiance L, or an equirectangular map of L (engine/shading/environment.py),
  importance-sampled for direct light and photon emission.
Every light reports its exact emitted flux, so the photon pass can be audited.
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from . import environment
from . import photon_aim
from ..geometry import primitives
from ..core.affine import apply_linear, apply_point, apply_transposed
from ..core.jit import CORE, INLINE
from ..core.sampling import (
    concentric_disk, cosine_hemisphere, first_above, next_float, orthonormal_basis,
    sample_discrete, to_world, uniform_cone, uniform_sphere)
from ..core.scene import AREA_SHAPES, SceneError, as_affine, as_bands

POINT, SPOT, SUN, AREA, EMISSIVE, ENVIRONMENT = 0, 1, 2, 3, 4, 5
RECT, ELLIPSE = 0, 1

LightSet = namedtuple("LightSet", [
    "kind", "pos", "axis_u", "axis_v", "normal", "shape", "radius", "soft", "cos_half", "smooth",
    "radiance", "flux", "area", "two_sided", "inst", "shape_id",
    "cell_start", "cell_count", "cell_face", "cell_u0", "cell_v0", "cell_du", "cell_dv",
    "cell_cdf", "power_cdf", "center", "bound_radius", "total_power",
    "aim_center", "aim_radius", "aim_fraction",     # importance emission (photon_aim.py)
    "pol"]          # per light: a polarizer's world axis and 1, or zeros (polarization.start_stokes)
    # the world (environment.EnvMap) field by field: parallel kernels take no nested tuples
    + ["env_" + f for f in environment.FIELDS])

EMISSIVE_GRID = 16  # (u,v) cells per primitive face used to sample emissive primitives


def spot_flux_factor(cos_half, smooth):
    """Integral of the spot mask over the sphere: 2 pi [(1 - cos_half) - smooth/2].

    The mask is smoothstep((cos - cos_half) / smooth); its integral over the
    blend ring is smooth/2 because smoothstep averages 1/2 over [0, 1].
    """
    return 2.0 * math.pi * ((1.0 - cos_half) - 0.5 * smooth)


def _transform_dir(xf, v):
    return xf[:, :3] @ v


def _polarizer(light, xf, name):
    """(world axis, 1) of the light's linear polarizer, or zeros without one."""
    angle = getattr(light, "polarizer", None)
    if angle is None:
        return np.zeros(4)
    if not math.isfinite(float(angle)):
        raise SceneError(f"{name}: the polarizer's angle must be finite, got {angle}")
    axis = _transform_dir(xf, np.array([math.cos(float(angle)), math.sin(float(angle)), 0.0]))
    ln = float(np.linalg.norm(axis))
    if not ln > 0.0:
        raise SceneError(f"{name}: its transform has no x-y plane for the polarizer")
    return np.append(axis / ln, 1.0)


def compile_lights(scene, geom, materials, bounds):
    """LightSet for the scene's lights, emissive shapes and environment.

    `bounds` = (lo, hi) world bounds of the geometry, used to aim sun and
    environment photons at the scene.
    """
    nb = scene.n_bands
    lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(hi < lo):
        lo, hi = np.zeros(3), np.zeros(3)
    center = 0.5 * (lo + hi)
    bound_radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-3) * 1.001

    rows = []  # dicts, turned into arrays below
    cells = {"face": [], "u0": [], "v0": [], "du": [], "dv": [], "cdf": []}

    def row(**kw):
        r = dict(kind=0, pos=np.zeros(3), axis_u=np.zeros(3), axis_v=np.zeros(3),
                 normal=np.array([0.0, 0.0, -1.0]), shape=RECT, radius=0.0, soft=False, cos_half=-1.0,
                 smooth=0.0, radiance=np.zeros(nb), flux=np.zeros(nb), area=0.0, two_sided=False,
                 inst=-1, shape_id=-1, cell_start=0, cell_count=0, pol=np.zeros(4))
        r.update(kw)
        rows.append(r)

    for light in scene.lights:
        name = f"light '{light.name}'"
        if light.kind not in ("point", "spot", "sun", "area"):
            raise SceneError(f"{name}: unknown kind '{light.kind}'")
        color = as_bands(light.color, nb, f"{name} colour")
        if not math.isfinite(light.power) or light.power < 0 or np.any(color < 0):
            raise SceneError(f"{name}: power must be finite and non-negative (got {light.power})")
        xf = as_affine(light.transform, name)
        strength = color * float(light.power)
        if not np.any(strength > 0):
            continue  # a dark light emits nothing; it is not an error
        pol = _polarizer(light, xf, name)
        if pol[3] > 0.0:
            strength = 0.5 * strength          # what passes the polarizer
        pos = xf[:, 3].copy()
        down = _transform_dir(xf, np.array([0.0, 0.0, -1.0]))
        down /= np.linalg.norm(down)
        if light.kind in ("point", "spot"):
            intensity = strength / (4.0 * math.pi)
            radius = max(float(light.radius), 0.0)
            soft = bool(getattr(light, "soft_falloff", False)) and radius > 0.0
            if light.kind == "point":
                row(kind=POINT, pos=pos, radius=radius, soft=soft, radiance=intensity,
                    flux=intensity * 4.0 * math.pi, pol=pol)
            else:
                cos_half = math.cos(min(max(float(light.spot_size), 1e-6), math.pi) / 2.0)
                smooth = (1.0 - cos_half) * min(max(float(light.spot_blend), 0.0), 1.0)
                row(kind=SPOT, pos=pos, normal=down, radius=radius, soft=soft, cos_half=cos_half, smooth=smooth,
                    radiance=intensity, flux=intensity * spot_flux_factor(cos_half, smooth), pol=pol)
        elif light.kind == "sun":
            half = 0.5 * max(float(light.angle), 0.0)
            row(kind=SUN, normal=down, cos_half=math.cos(half), radiance=strength,
                flux=strength * math.pi * bound_radius ** 2, pol=pol)
        else:
            if light.shape not in AREA_SHAPES:
                raise SceneError(f"{name}: unknown area shape '{light.shape}'")
            sx = float(light.size)
            sy = sx if light.shape in ("square", "disk") else float(light.size_y)
            au = _transform_dir(xf, np.array([0.5 * sx, 0.0, 0.0]))
            av = _transform_dir(xf, np.array([0.0, 0.5 * sy, 0.0]))
            ellipse = light.shape in ("disk", "ellipse")
            area = float(np.linalg.norm(np.cross(au, av))) * (math.pi if ellipse else 4.0)
            if not area > 0:
                raise SceneError(f"{name}: area light has zero size")
            normal = -np.cross(au, av)
            normal /= np.linalg.norm(normal)
            radiance = strength / (math.pi * area)
            row(kind=AREA, pos=pos, axis_u=au, axis_v=av, normal=normal,
                shape=ELLIPSE if ellipse else RECT, radiance=radiance, flux=strength, area=area, pol=pol)

    _emissive_rows(scene, geom, materials, row, cells)

    ev = environment.compile_environment(scene.environment, nb)
    if ev.constant and np.any(ev.pixels[0, 0] > 0):
        env = ev.pixels[0, 0].copy()
        # Radiance L from every direction crosses a sphere of radius R with flux L pi 4 pi R^2.
        row(kind=ENVIRONMENT, pos=center.copy(), radius=bound_radius, radiance=env,
            flux=env * math.pi * 4.0 * math.pi * bound_radius ** 2)
    elif not ev.constant and ev.total > 0.0:
        # Each direction's radiance L(w) crosses the bounding disk of radius R facing it:
        # flux pi R^2 int L dw, exact for the piecewise-constant map. `radiance` is the
        # solid-angle mean, what callers of sample_light (one radiance per light) get.
        row(kind=ENVIRONMENT, pos=center.copy(), radius=bound_radius, radiance=ev.power / (4.0 * math.pi),
            flux=ev.power * math.pi * bound_radius ** 2)

    n = len(rows)
    arr = lambda key, dtype: np.array([r[key] for r in rows], dtype=dtype) if n else None
    f64 = lambda key, shape: arr(key, np.float64) if n else np.zeros(shape)
    i32 = lambda key: arr(key, np.int32) if n else np.zeros(0, np.int32)
    flux = f64("flux", (0, nb)).reshape(n, nb)
    power = flux.mean(axis=1) if n else np.zeros(0)
    cdf = np.cumsum(power)
    c = {k: np.asarray(v, dtype=np.float64 if k != "face" else np.int32) for k, v in cells.items()}
    return LightSet(
        kind=i32("kind"), pos=f64("pos", (0, 3)).reshape(n, 3),
        axis_u=f64("axis_u", (0, 3)).reshape(n, 3), axis_v=f64("axis_v", (0, 3)).reshape(n, 3),
        normal=f64("normal", (0, 3)).reshape(n, 3), shape=i32("shape"),
        radius=f64("radius", 0), soft=arr("soft", np.bool_) if n else np.zeros(0, np.bool_),
        cos_half=f64("cos_half", 0), smooth=f64("smooth", 0),
        radiance=f64("radiance", (0, nb)).reshape(n, nb), flux=flux, area=f64("area", 0),
        two_sided=arr("two_sided", np.bool_) if n else np.zeros(0, np.bool_),
        inst=i32("inst"), shape_id=i32("shape_id"), cell_start=i32("cell_start"),
        cell_count=i32("cell_count"), cell_face=c["face"], cell_u0=c["u0"], cell_v0=c["v0"],
        cell_du=c["du"], cell_dv=c["dv"], cell_cdf=c["cdf"],
        power_cdf=cdf.astype(np.float64), center=center, bound_radius=float(bound_radius),
        total_power=float(cdf[-1]) if n else 0.0,
        # aimed at the scene itself: only lights outside it aim (a bake narrows it)
        aim_center=center.copy(), aim_radius=float(bound_radius), aim_fraction=photon_aim.AIMED,
        pol=f64("pol", (0, 4)).reshape(n, 4),
        **{"env_" + f: v for f, v in zip(environment.FIELDS, ev)})


# Lights a final gather samples where its rays land rather than reading their light
# from the lightmaps: small sources, whose shadows and patches are sharper than a
# texel (a sun patch through a window read off 0.3 m floor texels is smeared by
# as much). Area lights, glowing surfaces and the world give soft light that the
# texels hold well, and sampling them at every gather hit only adds noise.
GATHER_SAMPLED = (POINT, SPOT, SUN)


def gather_sampled(ls):
    """bool per light of `ls`: the lights a final gather samples at its hits."""
    return np.isin(ls.kind, GATHER_SAMPLED)


def light_subset(ls, keep):
    """The LightSet of the lights where `keep` (bool per light) is set, picked by
    power among themselves; the same types as `ls`, so kernels compile once."""
    keep = np.asarray(keep, bool)
    per_light = {"kind", "pos", "axis_u", "axis_v", "normal", "shape", "radius", "soft", "cos_half", "smooth",
                 "radiance", "flux", "area", "two_sided", "inst", "shape_id", "cell_start", "cell_count", "pol"}
    sub = {f: (np.ascontiguousarray(getattr(ls, f)[keep]) if f in per_light else getattr(ls, f))
           for f in LightSet._fields}
    cdf = np.cumsum(sub["flux"].mean(axis=1)) if keep.any() else np.zeros(0)
    sub["power_cdf"] = cdf.astype(np.float64)
    sub["total_power"] = float(cdf[-1]) if cdf.size else 0.0
    return LightSet(**sub)


def environment_map(ls):
    """The world of a LightSet as an environment.EnvMap (Python side)."""
    return environment.EnvMap(*(getattr(ls, "env_" + f) for f in environment.FIELDS))


@njit(**INLINE)
def environment_of(ls):
    """The same inside kernels."""
    return environment.EnvMap(ls.env_pixels, ls.env_constant, ls.env_lum, ls.env_row_cdf, ls.env_col_cdf,
                    ls.env_sin_edges, ls.env_total, ls.env_power)


def _emissive_rows(scene, geom, materials, row, cells):
    """One light per (instance, emissive shape); primitives get an area table of (u,v) cells."""
    emissive = np.where(materials.emission.max(axis=1) > 0)[0]
    if emissive.size == 0:
        return
    from ..lightmaps.texel_areas import primitive_texel_areas  # exact cell areas by quadrature

    shape_emits = np.isin(geom.shape_material, emissive)
    proto_shapes = {}
    for s in np.where(shape_emits)[0]:
        proto_shapes.setdefault(int(geom.shape_proto[s]), []).append(int(s))
    for i, p in enumerate(geom.inst_proto):
        for s in proto_shapes.get(int(p), ()):
            m = int(geom.shape_material[s])
            le = materials.emission[m]
            lin = geom.inst_xf[i][:, :3]
            kind = int(geom.shape_kind[s])
            start = len(cells["cdf"])
            if kind == primitives.TRIANGLE:
                tri = geom.tri_p[geom.shape_index[s]]
                area = 0.5 * float(np.linalg.norm(np.cross(lin @ (tri[1] - tri[0]), lin @ (tri[2] - tri[0]))))
                if not area > 0:
                    continue
                cells["face"].append(0)
                for k, v in (("u0", 0.0), ("v0", 0.0), ("du", 1.0), ("dv", 1.0)):
                    cells[k].append(v)
                cells["cdf"].append(area)
                two_sided = True
            else:
                j = int(geom.shape_index[s])
                m3 = lin @ geom.prim_xf[j][:, :3]
                g = EMISSIVE_GRID
                areas = primitive_texel_areas(kind, geom.prim_params[j], m3, g)
                nf = areas.size // (g * g)
                area = float(areas.sum())
                if not area > 0:
                    continue
                acc = 0.0
                for f in range(nf):
                    for y in range(g):
                        for x in range(g):
                            acc += areas[f * g * g + y * g + x]
                            cells["face"].append(f)
                            cells["u0"].append(x / g)
                            cells["v0"].append(y / g)
                            cells["du"].append(1.0 / g)
                            cells["dv"].append(1.0 / g)
                            cells["cdf"].append(acc)
                two_sided = kind in (primitives.DISK, primitives.QUAD)
            sides = 2.0 if two_sided else 1.0
            row(kind=EMISSIVE, radiance=le.copy(), flux=le * math.pi * area * sides, area=area,
                two_sided=two_sided, inst=i, shape_id=int(s), cell_start=start,
                cell_count=len(cells["cdf"]) - start)


# --------------------------------------------------------------------------------------
# Kernels
# --------------------------------------------------------------------------------------

# Per-sample functions come in two parts: an INLINE façade that takes the
# LightSet and Geometry tuples and picks out the arrays, and a CORE (or INLINE)
# body that takes only those arrays. A call that passes a tuple of dozens of
# arrays copies it and increfs every array in it: measured 1.3-2.0 us per
# sample_light call that way, against 7 ns through a façade.

@njit(**INLINE)
def _normalize(x, y, z):
    ln = math.sqrt(x * x + y * y + z * z)
    if ln == 0.0:
        return 0.0, 0.0, 1.0, 0.0
    return x / ln, y / ln, z / ln, ln


@njit(**INLINE)
def _area_point_of(shape, pos, axis_u, axis_v, li, u1, u2):
    """A uniform point on area light li (rectangle or ellipse), from two uniforms."""
    if shape[li] == ELLIPSE:
        a, b = concentric_disk(u1, u2)
    else:
        a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
    return (pos[li, 0] + a * axis_u[li, 0] + b * axis_v[li, 0],
            pos[li, 1] + a * axis_u[li, 1] + b * axis_v[li, 1],
            pos[li, 2] + a * axis_u[li, 2] + b * axis_v[li, 2])


@njit(**INLINE)
def _area_point(ls, li, u1, u2):
    return _area_point_of(ls.shape, ls.pos, ls.axis_u, ls.axis_v, li, u1, u2)


@njit(**CORE)
def _emissive_point_core(l_cell_start, l_cell_count, l_inst, l_shape_id, l_area, l_cell_cdf, l_cell_u0,
                         l_cell_v0, l_cell_du, l_cell_dv, l_cell_face, inst_xf, inst_inv, shape_kind,
                         shape_index, tri_p, prim_kind, prim_params, prim_xf, prim_inv, li, u1, u2, u3):
    """emissive_point on the arrays it reads (l_*: the LightSet's)."""
    start = l_cell_start[li]
    cnt = l_cell_count[li]
    inst = l_inst[li]
    s = l_shape_id[li]
    ixf = inst_xf[inst]
    iinv = inst_inv[inst]
    if shape_kind[s] == 0:
        t = tri_p[shape_index[s]]
        su = math.sqrt(u1)
        b1 = 1.0 - su
        b2 = u2 * su
        x = t[0, 0] + b1 * (t[1, 0] - t[0, 0]) + b2 * (t[2, 0] - t[0, 0])
        y = t[0, 1] + b1 * (t[1, 1] - t[0, 1]) + b2 * (t[2, 1] - t[0, 1])
        z = t[0, 2] + b1 * (t[1, 2] - t[0, 2]) + b2 * (t[2, 2] - t[0, 2])
        e1x, e1y, e1z = t[1, 0] - t[0, 0], t[1, 1] - t[0, 1], t[1, 2] - t[0, 2]
        e2x, e2y, e2z = t[2, 0] - t[0, 0], t[2, 1] - t[0, 1], t[2, 2] - t[0, 2]
        nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
        px, py, pz = apply_point(ixf, x, y, z)
        wx, wy, wz = apply_transposed(iinv, nx, ny, nz)
        wx, wy, wz, _ = _normalize(wx, wy, wz)
        # a triangle flattened to zero world area: pdf 0, callers drop the sample
        return px, py, pz, wx, wy, wz, 1.0, 1.0 / l_area[li] if l_area[li] > 0.0 else 0.0
    # Primitive: choose a cell by area, then (u,v) uniformly inside it.
    total = l_cell_cdf[start + cnt - 1]
    c = first_above(l_cell_cdf, u3 * total, start, start + cnt - 1)
    prev = l_cell_cdf[c - 1] if c > start else 0.0
    a_cell = l_cell_cdf[c] - prev
    u = l_cell_u0[c] + u1 * l_cell_du[c]
    v = l_cell_v0[c] + u2 * l_cell_dv[c]
    j = shape_index[s]
    kind = prim_kind[j]
    params = prim_params[j]
    (x, y, z, ax, ay, az, bx, by, bz) = primitives.prim_point(kind, params, l_cell_face[c], u, v)
    pxf = prim_xf[j]
    pinv = prim_inv[j]
    x, y, z = apply_point(pxf, x, y, z)
    px, py, pz = apply_point(ixf, x, y, z)
    ax, ay, az = apply_linear(pxf, ax, ay, az)
    ax, ay, az = apply_linear(ixf, ax, ay, az)
    bx, by, bz = apply_linear(pxf, bx, by, bz)
    bx, by, bz = apply_linear(ixf, bx, by, bz)
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    cx, cy, cz, jac = _normalize(cx, cy, cz)
    # Orient by the exact outward normal (parameterisations may be left-handed).
    lx, ly, lz = primitives.prim_point(kind, params, l_cell_face[c], u, v)[:3]
    f, uu, vv, nx, ny, nz = primitives.prim_surface(kind, params, lx, ly, lz)
    nx, ny, nz = apply_transposed(pinv, nx, ny, nz)
    nx, ny, nz = apply_transposed(iinv, nx, ny, nz)
    if cx * nx + cy * ny + cz * nz < 0.0:
        cx, cy, cz = -cx, -cy, -cz
    du_dv = l_cell_du[c] * l_cell_dv[c]
    weight = jac * du_dv / a_cell if a_cell > 0.0 else 0.0
    pdf_area = (a_cell / total) / (du_dv * jac) if jac > 0.0 else 0.0
    return px, py, pz, cx, cy, cz, weight, pdf_area


@njit(**INLINE)
def emissive_point(ls, g, li, u1, u2, u3):
    """Point on emissive shape li: (px,py,pz, nx,ny,nz, weight) with weight = A_cell-relative
    density correction (1 for triangles; J du dv / A_cell for primitive cells), and the
    area pdf of the sampled point (1/A for uniform)."""
    return _emissive_point_core(ls.cell_start, ls.cell_count, ls.inst, ls.shape_id, ls.area, ls.cell_cdf,
                                ls.cell_u0, ls.cell_v0, ls.cell_du, ls.cell_dv, ls.cell_face, g.inst_xf,
                                g.inst_inv, g.shape_kind, g.shape_index, g.tri_p, g.prim_kind, g.prim_params,
                                g.prim_xf, g.prim_inv, li, u1, u2, u3)


@njit(**INLINE)
def _spot_mask_of(normal, cos_half, smooth, li, dx, dy, dz):
    c = dx * normal[li, 0] + dy * normal[li, 1] + dz * normal[li, 2]
    if c <= cos_half[li]:
        return 0.0
    sm = smooth[li]
    if sm <= 0.0:
        return 1.0
    x = min((c - cos_half[li]) / sm, 1.0)
    return x * x * (3.0 - 2.0 * x)


@njit(**INLINE)
def spot_mask(ls, li, dx, dy, dz):
    """Cycles' spot falloff: smoothstep over the blend ring inside the cone (d unit, from light)."""
    return _spot_mask_of(ls.normal, ls.cos_half, ls.smooth, li, dx, dy, dz)


# Inlined into the photon loop, once per photon: a call would copy the LightSet
# and Geometry tuples.
@njit(**INLINE)
def emit_photon(ls, g, state):
    """Samples a photon: returns (state, light, ox,oy,oz, dx,dy,dz, weight).

    The photon's power is weight * ls.flux[light] * total_power / power(light) / N:
    lights are chosen in proportion to power, so photons carry similar power.
    weight is 0 when the sample is rejected (it then carries nothing); it is
    p_light / p_mixture for photons aimed at the aim sphere (photon_aim.py).
    """
    state, u0 = next_float(state)
    li = sample_discrete(ls.power_cdf, u0)
    state, u1 = next_float(state)
    state, u2 = next_float(state)
    state, u3 = next_float(state)
    state, u4 = next_float(state)
    state, u5 = next_float(state)
    k = ls.kind[li]
    weight = 1.0
    if k == POINT or k == SPOT:
        cx, cy, cz = ls.pos[li, 0], ls.pos[li, 1], ls.pos[li, 2]
        r = ls.radius[li]
        if k == SPOT:
            # Uniform in the cone, weighted by the falloff over its mean: the expected
            # power matches the exact spot flux and no photon is wasted on rejection.
            nx, ny, nz = ls.normal[li, 0], ls.normal[li, 1], ls.normal[li, 2]
            lx, ly, lz = uniform_cone(u1, u2, ls.cos_half[li])
            dx, dy, dz = to_world(lx, ly, lz, nx, ny, nz)
            state, dx, dy, dz, weight = photon_aim.aim_direction(ls, state, cx, cy, cz, dx, dy, dz, photon_aim.CONE,
                                                        nx, ny, nz, ls.cos_half[li])
            mean_mask = spot_flux_mean(ls, li)
            weight *= spot_mask(ls, li, dx, dy, dz) / mean_mask if mean_mask > 0.0 else 0.0
            if r > 0.0:
                nx, ny, nz = uniform_sphere(u3, u4)
                if nx * dx + ny * dy + nz * dz < 0.0:
                    nx, ny, nz = -nx, -ny, -nz
                return state, li, cx + r * nx, cy + r * ny, cz + r * nz, dx, dy, dz, weight
            return state, li, cx, cy, cz, dx, dy, dz, weight
        if r > 0.0:
            nx, ny, nz = uniform_sphere(u1, u2)
            lx, ly, lz = cosine_hemisphere(u3, u4)
            dx, dy, dz = to_world(lx, ly, lz, nx, ny, nz)
            ox, oy, oz = cx + r * nx, cy + r * ny, cz + r * nz
            state, dx, dy, dz, weight = photon_aim.aim_direction(ls, state, ox, oy, oz, dx, dy, dz, photon_aim.COSINE,
                                                        nx, ny, nz, 0.0)
            return state, li, ox, oy, oz, dx, dy, dz, weight
        dx, dy, dz = uniform_sphere(u1, u2)
        state, dx, dy, dz, weight = photon_aim.aim_direction(ls, state, cx, cy, cz, dx, dy, dz, photon_aim.UNIFORM,
                                                    0.0, 0.0, 1.0, 0.0)
        return state, li, cx, cy, cz, dx, dy, dz, weight
    if k == AREA:
        ox, oy, oz = _area_point(ls, li, u1, u2)
        nx, ny, nz = ls.normal[li, 0], ls.normal[li, 1], ls.normal[li, 2]
        lx, ly, lz = cosine_hemisphere(u3, u4)
        dx, dy, dz = to_world(lx, ly, lz, nx, ny, nz)
        state, dx, dy, dz, weight = photon_aim.aim_direction(ls, state, ox, oy, oz, dx, dy, dz, photon_aim.COSINE,
                                                    nx, ny, nz, 0.0)
        return state, li, ox, oy, oz, dx, dy, dz, weight
    if k == SUN:
        lx, ly, lz = uniform_cone(u3, u4, ls.cos_half[li])
        dx, dy, dz = to_world(lx, ly, lz, ls.normal[li, 0], ls.normal[li, 1], ls.normal[li, 2])
        # A disk of the scene's bounding radius facing the sun, just outside the scene.
        a, b = concentric_disk(u1, u2)
        R = ls.bound_radius
        ox, oy, oz = _disk_point(ls, R, dx, dy, dz, a, b, -2.0 * R)
        state, ox, oy, oz, weight = photon_aim.aim_disk(ls, state, dx, dy, dz, R, ox, oy, oz)
        return state, li, ox, oy, oz, dx, dy, dz, weight
    if k == ENVIRONMENT and not ls.env_constant:
        # Direction towards the world by the map's CDF, then a point on the disk of the
        # scene's bounding radius facing it, outside the scene (as for the sun). The
        # weight L/pdf * pi R^2 / flux is 1 in the mean band by construction of the pdf;
        # photon_tint gives the per-band colour of the direction.
        wx, wy, wz, pdf = environment.sample(environment_of(ls), u1, u2)
        a, b = concentric_disk(u3, u4)
        R = ls.radius[li]
        ox, oy, oz = _disk_point(ls, R, wx, wy, wz, a, b, 2.0 * R)
        state, ox, oy, oz, weight = photon_aim.aim_disk(ls, state, -wx, -wy, -wz, R, ox, oy, oz)
        if not pdf > 0.0:
            weight = 0.0
        return state, li, ox, oy, oz, -wx, -wy, -wz, weight
    if k == ENVIRONMENT:
        R = ls.radius[li]
        if ls.aim_fraction > 0.0 and ls.aim_radius < R:
            # Aimed: the same photons as below, parametrised as for a map (a uniform
            # direction, then a point on the disk facing it) so the disk can be aimed.
            wx, wy, wz = uniform_sphere(u1, u2)
            a, b = concentric_disk(u3, u4)
            ox, oy, oz = _disk_point(ls, R, wx, wy, wz, a, b, 2.0 * R)
            state, ox, oy, oz, weight = photon_aim.aim_disk(ls, state, -wx, -wy, -wz, R, ox, oy, oz)
            return state, li, ox, oy, oz, -wx, -wy, -wz, weight
        nx, ny, nz = uniform_sphere(u1, u2)
        lx, ly, lz = cosine_hemisphere(u3, u4)
        dx, dy, dz = to_world(lx, ly, lz, -nx, -ny, -nz)
        return (state, li, ls.center[0] + R * nx, ls.center[1] + R * ny, ls.center[2] + R * nz,
                dx, dy, dz, weight)
    # EMISSIVE
    px, py, pz, nx, ny, nz, w, pdf = emissive_point(ls, g, li, u1, u2, u5)
    if ls.two_sided[li]:
        state, us = next_float(state)
        if us < 0.5:
            nx, ny, nz = -nx, -ny, -nz
    lx, ly, lz = cosine_hemisphere(u3, u4)
    dx, dy, dz = to_world(lx, ly, lz, nx, ny, nz)
    state, dx, dy, dz, weight = photon_aim.aim_direction(ls, state, px, py, pz, dx, dy, dz, photon_aim.COSINE, nx, ny, nz, 0.0)
    return state, li, px, py, pz, dx, dy, dz, w * weight


@njit(**INLINE)
def _disk_point(ls, R, ux, uy, uz, a, b, shift):
    """Point (a, b) of the unit disk on the disk of radius R about the scene's
    centre facing u, moved `shift` along u: where parallel photons start."""
    tx, ty, tz, bx, by, bz = orthonormal_basis(ux, uy, uz)
    return (ls.center[0] + R * (a * tx + b * bx) + shift * ux,
            ls.center[1] + R * (a * ty + b * by) + shift * uy,
            ls.center[2] + R * (a * tz + b * bz) + shift * uz)


@njit(cache=True)
def spot_flux_mean(ls, li):
    """Mean falloff over the cone (accept rate of spot photon rejection sampling)."""
    ch = ls.cos_half[li]
    return ((1.0 - ch) - 0.5 * ls.smooth[li]) / (1.0 - ch) if ch < 1.0 else 1.0


@njit(**CORE)
def _sample_analytic(kind, pos, axis_u, axis_v, normal, shape, radius, soft, cos_half, smooth, area,
                     li, px, py, pz, u1, u2, u3):
    """sample_light for every kind but EMISSIVE, on the arrays it reads. Kept
    apart from the emissive part, whose primitive code would make every call
    pay for its locals.

    Returns (wx, wy, wz, dist, contrib_scale, ok): the unit direction towards the
    light, the distance for the shadow ray (inf for sun/environment), and a
    scalar so that irradiance from this sample = radiance[li] * contrib_scale
    (already includes cos at the light and 1/pdf, but not cos at the receiver,
    which the caller multiplies in).
    """
    k = kind[li]
    if k == POINT or k == SPOT:
        cx, cy, cz = pos[li, 0], pos[li, 1], pos[li, 2]
        wx, wy, wz, d = _normalize(cx - px, cy - py, cz - pz)
        if not d * d > 0.0:    # also d > 0 whose square underflows (1/d² would raise)
            return 0.0, 0.0, 1.0, 0.0, 0.0, False
        mask = 1.0
        if k == SPOT:
            mask = _spot_mask_of(normal, cos_half, smooth, li, -wx, -wy, -wz)
            if mask <= 0.0:
                return wx, wy, wz, d, 0.0, False
        r = radius[li]
        if r <= 0.0:
            return wx, wy, wz, d, mask / (d * d), True
        # Soft falloff: the sphere's irradiance scaled by d^2 / (d^2 + r^2).
        falloff = d * d / (d * d + r * r) if soft[li] else 1.0
        if d <= r:
            return wx, wy, wz, d, falloff * mask / (d * d), True
        # Sphere light: uniform direction in the visible cone; radiance I/(pi r^2).
        sin2 = (r * r) / (d * d)
        if sin2 < 1e-12:
            # the cone is too narrow for 1 - cos_max (it rounds to 0, pdf = 1/0);
            # a fully visible uniform sphere gives exactly the point light's E
            return wx, wy, wz, d, falloff * mask / (d * d), True
        cos_max = math.sqrt(max(0.0, 1.0 - sin2))
        lx, ly, lz = uniform_cone(u1, u2, cos_max)
        sx, sy, sz = to_world(lx, ly, lz, wx, wy, wz)
        # Distance to the sphere along the sample direction.
        b = lz * d
        disc = r * r - (d * d - b * b)
        ts = b - math.sqrt(max(disc, 0.0))
        pdf = 1.0 / (2.0 * math.pi * (1.0 - cos_max))
        return sx, sy, sz, ts, falloff * mask / (math.pi * r * r) / pdf, True
    if k == AREA:
        qx, qy, qz = _area_point_of(shape, pos, axis_u, axis_v, li, u1, u2)
        wx, wy, wz, d = _normalize(qx - px, qy - py, qz - pz)
        cos_l = -(wx * normal[li, 0] + wy * normal[li, 1] + wz * normal[li, 2])
        if cos_l <= 0.0 or not d * d > 0.0:
            return wx, wy, wz, d, 0.0, False
        return wx, wy, wz, d, cos_l * area[li] / (d * d), True
    if k == SUN:
        lx, ly, lz = uniform_cone(u1, u2, cos_half[li])
        wx, wy, wz = to_world(lx, ly, lz, -normal[li, 0], -normal[li, 1], -normal[li, 2])
        return wx, wy, wz, math.inf, 1.0, True
    if k == ENVIRONMENT:
        # Uniform sphere; the caller's receiver cosine completes E = int L cos. With a map,
        # radiance[li] is its mean (the averaged world): sample_light_radiance samples the map.
        wx, wy, wz = uniform_sphere(u1, u2)
        return wx, wy, wz, math.inf, 4.0 * math.pi, True
    return 0.0, 0.0, 1.0, 0.0, 0.0, False


@njit(**CORE)
def _sample_emissive(area, two_sided, l_cell_start, l_cell_count, l_inst, l_shape_id, l_cell_cdf, l_cell_u0,
                     l_cell_v0, l_cell_du, l_cell_dv, l_cell_face, inst_xf, inst_inv, shape_kind, shape_index,
                     tri_p, prim_kind, prim_params, prim_xf, prim_inv, li, px, py, pz, u1, u2, u3):
    """sample_light for an EMISSIVE light (a shape's surface), on the arrays it reads."""
    qx, qy, qz, nx, ny, nz, w, pdf_area = _emissive_point_core(
        l_cell_start, l_cell_count, l_inst, l_shape_id, area, l_cell_cdf, l_cell_u0, l_cell_v0, l_cell_du,
        l_cell_dv, l_cell_face, inst_xf, inst_inv, shape_kind, shape_index, tri_p, prim_kind, prim_params,
        prim_xf, prim_inv, li, u1, u2, u3)
    wx, wy, wz, d = _normalize(qx - px, qy - py, qz - pz)
    cos_l = -(wx * nx + wy * ny + wz * nz)
    if two_sided[li]:
        cos_l = abs(cos_l)
    if cos_l <= 0.0 or not d * d > 0.0 or not pdf_area > 0.0:
        return wx, wy, wz, d, 0.0, False
    return wx, wy, wz, d, cos_l / (d * d) / pdf_area, True


# Direct light at a point: with at most this many lights every light gets one
# sample, else LIGHT_DRAWS lights are drawn in proportion to power.
ALL_LIGHTS_UP_TO = 8
LIGHT_DRAWS = 4


@njit(**INLINE)
def light_sample_count(n_lights):
    """Light samples one direct-light estimate takes (see pick_light)."""
    return n_lights if n_lights <= ALL_LIGHTS_UP_TO else LIGHT_DRAWS


@njit(**INLINE)
def pick_light(ls, j, n_samples, state):
    """Light sample j of n_samples -> (state, light index, selection weight): every
    light once when there are few, else drawn in proportion to power, weighted
    1 / (n_samples p) so the sum stays unbiased. The renderer and the texel
    gather share it, so a pixel and a texel sample the same lights."""
    n_lights = ls.kind.shape[0]
    if n_lights <= ALL_LIGHTS_UP_TO:
        return state, j, 1.0
    state, us = next_float(state)
    li = sample_discrete(ls.power_cdf, us)
    p_li = (ls.power_cdf[li] - (ls.power_cdf[li - 1] if li > 0 else 0.0)) / ls.power_cdf[n_lights - 1]
    return state, li, 1.0 / (n_samples * p_li)


@njit(**INLINE)
def sample_light(ls, g, li, px, py, pz, u1, u2, u3):
    """Direct light from light li at point p.

    Returns (wx, wy, wz, dist, contrib_scale, ok): the unit direction towards the
    light, the distance for the shadow ray (inf for sun/environment), and a
    scalar so that irradiance from this sample = radiance[li] * contrib_scale
    (already includes cos at the light and 1/pdf, but not cos at the receiver,
    which the caller multiplies in).
    """
    if ls.kind[li] == EMISSIVE:
        return _sample_emissive(ls.area, ls.two_sided, ls.cell_start, ls.cell_count, ls.inst, ls.shape_id,
                                ls.cell_cdf, ls.cell_u0, ls.cell_v0, ls.cell_du, ls.cell_dv, ls.cell_face,
                                g.inst_xf, g.inst_inv, g.shape_kind, g.shape_index, g.tri_p, g.prim_kind,
                                g.prim_params, g.prim_xf, g.prim_inv, li, px, py, pz, u1, u2, u3)
    return _sample_analytic(ls.kind, ls.pos, ls.axis_u, ls.axis_v, ls.normal, ls.shape, ls.radius, ls.soft,
                            ls.cos_half, ls.smooth, ls.area, li, px, py, pz, u1, u2, u3)


@njit(**INLINE)
def sample_light_radiance(ls, g, li, px, py, pz, u1, u2, u3, rad):
    """sample_light with the sample's radiance per band written into rad[bands].

    Returns (wx, wy, wz, dist, contrib_scale, ok) as sample_light, with irradiance from
    this sample = rad * contrib_scale (times the receiver cosine). rad is ls.radiance[li]
    for every light but an environment map, which is importance-sampled: rad = L(w),
    contrib_scale = 1 / pdf(w). A constant world keeps sample_light's uniform sampling."""
    if ls.kind[li] == ENVIRONMENT and not ls.env_constant:
        return _environment_sample(ls.env_pixels, ls.env_constant, ls.env_lum, ls.env_row_cdf, ls.env_col_cdf,
                                   ls.env_sin_edges, ls.env_total, ls.env_power, u1, u2, rad)
    wx, wy, wz, dist, scale, ok = sample_light(ls, g, li, px, py, pz, u1, u2, u3)
    for b in range(rad.shape[0]):
        rad[b] = ls.radiance[li, b]
    return wx, wy, wz, dist, scale, ok


@njit(**CORE)
def _environment_sample(pixels, constant, lum, row_cdf, col_cdf, sin_edges, total, power, u1, u2, rad):
    """sample_light_radiance of an environment map, on its arrays."""
    ev = environment.EnvMap(pixels, constant, lum, row_cdf, col_cdf, sin_edges, total, power)
    wx, wy, wz, pdf = environment.sample_radiance(ev, u1, u2, rad)
    if not pdf > 0.0:
        return wx, wy, wz, math.inf, 0.0, False
    return wx, wy, wz, math.inf, 1.0 / pdf, True


@njit(**INLINE)
def photon_tint(ls, li, dx, dy, dz, out):
    """Per-band factor for a photon of light li leaving along d: the environment map's
    colour in that direction relative to its flux colour (expectation 1 per band, see
    environment.photon_tint); 1 for every other light."""
    if ls.kind[li] == ENVIRONMENT:
        environment.photon_tint(environment_of(ls), dx, dy, dz, out)
        return
    for b in range(out.shape[0]):
        out[b] = 1.0


@njit(**INLINE)
def sample_environment_diffuse(ls, li, nx, ny, nz, u1, u2, rad):
    """Direct light of environment-map light li for a diffuse receiver of normal n:
    one-sample MIS (balance heuristic) of the map's importance sampling and cosine
    sampling around n. Returns (wx, wy, wz, contrib_scale, ok)
    with irradiance = rad * contrib_scale * cos (as sample_light_radiance); the cosine
    half keeps dim parts of the sky that face the receiver from being starved by a
    bright patch behind it."""
    return _environment_diffuse(ls.env_pixels, ls.env_constant, ls.env_lum, ls.env_row_cdf, ls.env_col_cdf,
                                ls.env_sin_edges, ls.env_total, ls.env_power, nx, ny, nz, u1, u2, rad)


@njit(**CORE)
def _environment_diffuse(pixels, constant, lum, row_cdf, col_cdf, sin_edges, total, power, nx, ny, nz, u1, u2,
                         rad):
    """sample_environment_diffuse on the map's arrays."""
    ev = environment.EnvMap(pixels, constant, lum, row_cdf, col_cdf, sin_edges, total, power)
    # u1 < 1/2 picks the map, the rest cosine sampling: the halves of a stratified
    # (u1, u2) square stay stratified for each strategy
    if u1 < 0.5:
        wx, wy, wz, p_env = environment.sample(ev, 2.0 * u1, u2)
    else:
        lx, ly, lz = cosine_hemisphere(2.0 * u1 - 1.0, u2)
        wx, wy, wz = to_world(lx, ly, lz, nx, ny, nz)
        p_env = environment.pdf(ev, wx, wy, wz)
    cos_r = wx * nx + wy * ny + wz * nz
    pdf = 0.5 * p_env + 0.5 * max(cos_r, 0.0) / math.pi
    if not pdf > 0.0 or cos_r <= 0.0:
        return wx, wy, wz, 0.0, False
    environment.radiance(ev, wx, wy, wz, rad)
    return wx, wy, wz, 1.0 / pdf, True
