"""Compiles a plain `Scene` into the arrays the kernels read.

Geometry and both BVH levels (geometry.py), materials, lights with their
exact flux, per-instance photon lightmaps with exact texel areas, and the
camera. The result is what the photon pass and the renderer share.
"""
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from . import csg as CSG
from . import lightmap as LM
from . import orientation_lightmap as OL
from . import primitives as P
from .area_estimation import estimate_areas
from .geometry import compile_geometry
from .lights import compile_lights
from .materials import compile_materials
from .renderer import compile_camera
from .scene import SceneError, _bands


@dataclass
class CompiledScene:
    name: str
    n_bands: int
    geometry: object
    materials: object
    lights: object
    lightmaps: object
    camera: object
    environment: np.ndarray
    info: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    # instance_lightmaps[i] lists lightmap ids of instance i, in surface-slot order.
    instance_lightmaps: list = field(default_factory=list)
    # orientation lightmaps: routing of instances to OLs and their lightmap ids
    orientation: object = None

    def lightmap_bytes(self):
        lm = self.lightmaps
        return int(sum(a.nbytes for a in (lm.area, lm.coverage, lm.flux, lm.flux_sq, lm.hits,
                                          lm.irradiance, lm.state, lm.split, lm.split_first,
                                          lm.split_cell)))

    def reset_lightmaps(self):
        """Clears recorded photons (areas stay) so a new photon pass starts from zero."""
        for a in (self.lightmaps.flux, self.lightmaps.flux_sq, self.lightmaps.hits,
                  self.lightmaps.irradiance, self.lightmaps.state):
            a[...] = 0


def _prototype_surfaces(geom):
    """For each prototype: list over surface slots of ('mesh', triangle rows) or ('prim', row)."""
    out = []
    # shapes by prototype, including CSG leaves (which sit outside the BVH ranges)
    n_p = len(geom.proto_shape_start)
    by_proto = np.split(np.argsort(geom.shape_proto, kind="stable"),
                        np.cumsum(np.bincount(geom.shape_proto, minlength=n_p))[:-1])
    for p in range(n_p):
        slots = {}
        for s in by_proto[p]:
            slot = int(geom.shape_surface[s])
            if slot < 0:
                continue
            if geom.shape_kind[s] == P.TRIANGLE:
                slots.setdefault(slot, ("mesh", []))[1].append(int(geom.shape_index[s]))
            else:
                slots[slot] = ("prim", int(geom.shape_index[s]))
        out.append([(k, np.asarray(v) if k == "mesh" else v) for k, v in
                    (slots[i] for i in sorted(slots))])
    return out


def allocate_lightmaps(scene, geom, texel_density, max_resolution=1024, csg=None, csg_split=True,
                       info=None, ol_maps=None):
    """One lightmap per (recording instance, surface slot), sized by texel density.

    csg: the geometry's CSG layout; the lightmaps of CSG leaf primitives then
    count only the surface left on the solid, and texels cut into disjoint
    regions get sub-texels (csg_split=False: plain primitive lightmaps).
    Split statistics go into `info`. ol_maps (orientation_lightmap.plan):
    each OL gets one R×R lightmap after the instances' ones, its bin areas
    estimated stochastically; returns ol_maps with those lightmap ids."""
    surfaces = _prototype_surfaces(geom)
    layouts, fills, per_instance = [], [], []
    for i, inst in enumerate(scene.instances):
        ids = []
        if geom.inst_lm_base[i] >= 0:
            M = geom.inst_xf[i][:, :3]
            forced = int(inst.lightmap_resolution)
            for kind, data in surfaces[int(geom.inst_proto[i])]:
                if kind == "mesh":
                    area3d = LM.triangle_world_areas(geom.tri_p[data], M)
                    res = forced or LM.resolution_for(area3d.sum(), texel_density, max_res=max_resolution)
                    layouts.append((res, res, 1))
                    fills.append(("mesh", data, area3d))
                else:
                    pk = int(geom.prim_kind[data])
                    M3 = M @ geom.prim_xf[data][:, :3]
                    nf = int(P.N_FACES[pk])
                    face_area = LM.primitive_texel_areas(pk, geom.prim_params[data], M3, 2).sum() / nf
                    res = forced or LM.resolution_for(face_area, texel_density, max_res=max_resolution)
                    layouts.append((nf * res, res, nf))
                    fills.append(("prim", data, M3))
                ids.append(len(layouts) - 1)
        per_instance.append(ids)
    plan, n_sub, t_plan = CSG.plan_csg_lightmaps(csg if csg_split else None, fills, layouts)
    ols = list(scene.orientation_lightmaps)
    ol_lids = []
    for ol in ols:
        layouts.append((int(ol.resolution), int(ol.resolution), 1))
        ol_lids.append(len(layouts) - 1)
    extra_lid = None
    if n_sub:
        layouts.append((n_sub, 1, 1))           # the sub-texel rows
        extra_lid = len(layouts) - 1
    lm = LM.allocate(layouts, scene.n_bands)
    for lid, (kind, data, extra) in enumerate(fills):
        if kind == "mesh":
            LM.set_triangle_areas(lm, lid, geom.tri_uv[data], extra)
        else:
            LM.set_primitive_areas(lm, lid, int(geom.prim_kind[data]), geom.prim_params[data], extra)
    if plan:
        lm, st = CSG.apply_csg_lightmaps(lm, plan, fills, csg["flat"], extra_lid)
        st["csg_setup_seconds"] = t_plan + st.pop("csg_apply_seconds")
        if info is not None:
            info.update(st)
    if ols:
        ol_maps = OL.with_lightmap_ids(ol_maps, ol_lids)
        rows = _orientation_areas(ols, ol_maps, geom, lm)
        if info is not None:
            info["orientation_lightmaps"] = rows
    return lm, per_instance, ol_maps


def _orientation_areas(ols, maps, geom, lm):
    """Estimates each OL's own instances, then sums each subtree bottom-up, so
    a level's area covers exactly the instances whose hits it receives."""
    K = len(ols)
    own = []
    covered = [OL.covered_instances(maps, k) for k in range(K)]
    for k, ol in enumerate(ols):
        mine = np.flatnonzero(maps.inst_ol == k)
        member = np.zeros(maps.inst_ol.shape[0], np.bool_)
        member[covered[k]] = True
        own.append(estimate_areas(geom, mine, int(ol.resolution), int(ol.samples), int(ol.seed),
                                  member=member))
    area = [e.area.copy() for e in own]
    var = [(e.area * np.where(np.isfinite(e.rel_error), e.rel_error, 0.0)) ** 2 for e in own]
    weight = [e.total * e.openness for e in own]
    total = [e.total for e in own]
    secs = [e.seconds for e in own]
    # children before parents: deeper levels first
    depth = [len(_chain(maps, k)) for k in range(K)]
    for k in sorted(range(K), key=lambda k: -depth[k]):
        p = int(maps.parent[k])
        if p >= 0:
            area[p] += area[k]
            var[p] += var[k]
            weight[p] += weight[k]
            total[p] += total[k]
    rows = []
    for k, ol in enumerate(ols):
        LM.set_areas(lm, int(maps.lid[k]), area[k])
        pos = area[k] > 0
        rel = np.full(area[k].shape, np.inf)
        rel[pos] = np.sqrt(var[k][pos]) / area[k][pos]
        tot = float(area[k].sum())
        rows.append(dict(
            name=ol.name, resolution=int(ol.resolution), bins=int(area[k].size),
            bins_with_area=int(pos.sum()), parent=int(maps.parent[k]), backup=bool(ol.backup),
            instances=int(covered[k].size), parts=int(own[k].parts),
            samples=int(own[k].samples), area=tot,
            area_rel_error=float(math.sqrt(var[k].sum()) / tot) if tot > 0 else math.inf,
            bin_rel_error=rel,
            openness=float(weight[k] / total[k]) if total[k] > 0 else 1.0,
            area_seconds=float(secs[k])))
        rows[-1]["warnings"] = OL.averaging_warnings(rows[-1], area[k])
    return rows


def _chain(maps, k):
    out = []
    while k >= 0:
        out.append(k)
        k = int(maps.parent[k])
    return out


def compile_scene(scene, texel_density=None, max_resolution=1024, csg_split=True):
    t0 = time.perf_counter()
    if int(scene.n_bands) < 1:
        raise SceneError(f"n_bands must be >= 1, got {scene.n_bands}")
    density = float(scene.texel_density if texel_density is None else texel_density)
    if not (math.isfinite(density) and density > 0):
        raise SceneError(f"texel density must be positive, got {density}")
    materials = compile_materials(scene)
    ol_maps = OL.plan(scene)
    if ol_maps.lid.size:
        # instances under a (non-backup) OL record there instead of on own lightmaps
        scene = replace(scene, instances=[
            replace(inst, lightmap=False) if ol_maps.inst_ol[i] >= 0 and not ol_maps.inst_keep[i]
            else inst for i, inst in enumerate(scene.instances)])
    geom, info = compile_geometry(scene)
    n_mat = materials.diffuse.shape[0]
    if geom.shape_material.size and (geom.shape_material.max() >= n_mat or geom.shape_material.min() < 0):
        bad = int(geom.shape_material.max())
        raise SceneError(f"a shape uses material {bad}, but the scene has {len(scene.materials)} materials")
    csg = info.pop("csg_layout", None)
    if csg is not None:
        CSG.check_not_emissive(csg, materials)
    t_geo = time.perf_counter()
    info = dict(info)
    lightmaps, per_instance, ol_maps = allocate_lightmaps(scene, geom, density, max_resolution,
                                                          csg, csg_split, info, ol_maps)
    t_lm = time.perf_counter()
    if geom.tlas_min.shape[0] > 0:
        bounds = (geom.tlas_min[0].astype(np.float64), geom.tlas_max[0].astype(np.float64))
    else:
        bounds = (np.zeros(3), np.zeros(3))
    lights = compile_lights(scene, geom, materials, bounds)
    camera = compile_camera(scene.camera)
    env = _bands(scene.environment, scene.n_bands, "environment")
    info.update(lightmaps=int(lightmaps.offset.shape[0]), texels=int(lightmaps.area.shape[0]),
                lights=int(lights.kind.shape[0]))
    cs = CompiledScene(scene.name, int(scene.n_bands), geom, materials, lights, lightmaps, camera,
                       env, info, instance_lightmaps=per_instance, orientation=ol_maps)
    cs.timings.update(geometry=t_geo - t0, lightmap_setup=t_lm - t_geo,
                      setup=time.perf_counter() - t0)
    return cs
