"""Compiles a plain `Scene` into the arrays the kernels read.

Geometry and both BVH levels (geometry/assembly.py), materials, lights with their
exact flux, per-instance photon lightmaps with exact texel areas, and the
camera. The result is what the photon pass and the renderer share.
"""
import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .geometry.csg import check_not_emissive
from .shading.environment import describe as describe_environment
from .core import memory_budget
from .lightmaps import lightmap
from .lightmaps import texel_areas
from .lightmaps import orientation_lightmap
from .geometry import primitives
from .lightmaps import split_texels
from .lightmaps.area_estimation import estimate_areas
from .shading.bsdf import compile_bsdf
from .geometry.trace_layout import DCSG as DCSG_KIND
from .geometry.assembly import compile_geometry, prototype_surfaces
from .geometry.validation import check_mesh_arrays, nondegenerate
from .shading.lights import compile_lights, environment_map
from .shading.materials import compile_materials
from .shading.texture import compile_textures, texture_bytes
from .transport.renderer import compile_camera
from .core.scene import CSGNode, OrientationLightmap, SceneError, TriangleMesh


@dataclass
class CompiledScene:
    name: str
    n_bands: int
    geometry: object
    materials: object
    lights: object
    lightmaps: object
    camera: object
    environment: object          # environment.EnvMap (np.asarray: the mean radiance per band)
    info: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    rays: dict = field(default_factory=dict)     # rays the last run of a kernel traced, by kernel
    # instance_lightmaps[i] lists lightmap ids of instance i, in surface-slot order.
    instance_lightmaps: list = field(default_factory=list)
    # orientation lightmaps: routing of instances to OLs and their lightmap ids
    orientation: object = None
    # finer lightmaps for caustic photons (same lightmap ids as `lightmaps`), or None
    caustics: object = None
    caustics_traced: bool = False   # the last photon pass stored its caustics there
    lightmaps_hold_direct: bool = False   # ... and recorded first hits (final gather, bakes of OLs)
    gather_light_set: object = None       # lights.LightSet a final gather samples at its hits (None: none)
    spectral: object = None               # spectrum.Bands of a spectral scene (engine/spectral.py), else None
    # photons carry Stokes vectors along specular paths (the scene's Polarization, or a
    # light with a polarizer): photon_tracer compiles its polarized kind
    polarization: bool = False
    bsdf: object = None             # bsdf.BsdfTables: albedo tables, layer and Fresnel per material
    # material textures (engine/shading/texture.py TextureSet; empty when the scene has none)
    textures: object = None
    # a render's irradiance-cache records over the traced light: (key, Records, info),
    # made by the first render that asks (session.render_records), dropped by a photon pass
    render_records: object = None

    def lightmap_bytes(self):
        lm = self.lightmaps
        return int(sum(a.nbytes for a in (lm.area, lm.coverage, lm.open, lm.flux, lm.flux_sq, lm.hits,
                                          lm.irradiance, lm.state, lm.split, lm.split_first,
                                          lm.split_cell)))

    def reset_lightmaps(self):
        """Clears recorded photons (areas stay) so a new photon pass starts from zero."""
        for lm in (self.lightmaps, self.caustics):
            if lm is None:
                continue
            for a in (lm.flux, lm.flux_sq, lm.hits, lm.irradiance, lm.state):
                a[...] = 0


def checked_camera(camera, n_bands):
    """compile_camera, once the image it renders fits the memory budget."""
    cam = compile_camera(camera)
    memory_budget.check(f"render resolution {cam.width}x{cam.height}",
                        cam.width * cam.height * (PIXEL_BYTES + PIXEL_BAND_BYTES * n_bands),
                        "lower the resolution (Output Properties > Format)")
    return cam


def allocate_lightmaps(scene, geom, texel_density, max_resolution=1024, csg=None, csg_split=True,
                       info=None, ol_maps=None, dcsg=None):
    """One lightmap per (recording instance, surface slot), sized by texel density.

    csg: the geometry's CSG layout; the lightmaps of CSG leaf primitives then
    count only the surface left on the solid, and texels cut into disjoint
    regions get sub-texels (csg_split=False: plain primitive lightmaps).
    Split statistics go into `info`. ol_maps (orientation_lightmap.plan):
    each OL gets one R×R lightmap after the instances' ones, its bin areas
    estimated stochastically; returns ol_maps with those lightmap ids."""
    surfaces = prototype_surfaces(geom)
    layouts, fills, per_instance = [], [], []
    for i, inst in enumerate(scene.instances):
        ids = []
        if geom.inst_lm_base[i] >= 0:
            M = geom.inst_xf[i][:, :3]
            forced = int(inst.lightmap_resolution)
            if not 0 <= forced <= MAX_RESOLUTION:
                raise SceneError(f"instance '{inst.name}': lightmap resolution must be 0 (from the "
                                 f"texel density) to {MAX_RESOLUTION}, got {forced}")
            for kind, data in surfaces[int(geom.inst_proto[i])]:
                if kind == "mesh":
                    area3d = texel_areas.triangle_world_areas(geom.tri_p[data], M)
                    res = forced or lightmap.resolution_for(area3d.sum(), texel_density, max_res=max_resolution)
                    layouts.append((res, res, 1))
                    fills.append(("mesh", data, area3d))
                else:
                    pk = int(geom.prim_kind[data])
                    M3 = M @ geom.prim_xf[data][:, :3]
                    nf = int(primitives.N_FACES[pk])
                    face_area = texel_areas.primitive_texel_areas(pk, geom.prim_params[data], M3, 2).sum() / nf
                    res = forced or lightmap.resolution_for(face_area, texel_density, max_res=max_resolution)
                    layouts.append((nf * res, res, nf))
                    fills.append(("prim", data, M3))
                ids.append(len(layouts) - 1)
        per_instance.append(ids)
    _check_lightmap_memory(scene, layouts, per_instance, texel_density)
    plan, n_sub, t_plan = split_texels.plan_csg_lightmaps(csg if csg_split else None, fills, layouts)
    ols = list(scene.orientation_lightmaps)
    ol_lids = []
    for ol in ols:
        layouts.append((int(ol.resolution), int(ol.resolution), 1))
        ol_lids.append(len(layouts) - 1)
    extra_lid = None
    if n_sub:
        layouts.append((n_sub, 1, 1))           # the sub-texel rows
        extra_lid = len(layouts) - 1
    lm = lightmap.allocate(layouts, scene.n_bands)
    for lid, (kind, data, extra) in enumerate(fills):
        if kind == "mesh":
            lightmap.set_triangle_areas(lm, lid, geom.tri_uv[data], extra)
        else:
            lightmap.set_primitive_areas(lm, lid, int(geom.prim_kind[data]), geom.prim_params[data], extra)
    if plan:
        lm, st = split_texels.apply_csg_lightmaps(lm, plan, fills, csg["flat"], extra_lid)
        st["csg_setup_seconds"] = t_plan + st.pop("csg_apply_seconds")
        if info is not None:
            info.update(st)
    if ols:
        ol_maps = orientation_lightmap.with_lightmap_ids(ol_maps, ol_lids)
        rows = _orientation_areas(ols, ol_maps, geom, lm, dcsg)
        if info is not None:
            info["orientation_lightmaps"] = rows
    return lm, per_instance, ol_maps


# Per-object lightmap sides above this are refused (a 16k² lightmap is 16 GiB).
MAX_RESOLUTION = 16384
# Bytes per texel while rendering: the Lightmaps arrays (area, coverage, flux,
# flux², hits, irradiance, state, split) and finalize()'s copy of irradiance
# and state; plus TEXEL_BAND_BYTES per band (flux, irradiance, its copy).
TEXEL_BYTES = 46
TEXEL_BAND_BYTES = 24


# Bytes per area-estimation sample (bin, value, point and normal, the draw).
AREA_SAMPLE_BYTES = 96
# Bytes per pixel of a render: the band image, and Blender's RGBA float copy.
PIXEL_BAND_BYTES = 8
PIXEL_BYTES = 32


def _check_lightmap_memory(scene, layouts, per_instance, density):
    """Refuses lightmaps the machine cannot hold, naming the largest object and
    the texel density that would fit, before anything is allocated."""
    texels = np.array([w * h for w, h, _ in layouts], np.float64)
    ols = sum(int(ol.resolution) ** 2 for ol in scene.orientation_lightmaps)
    per_texel = TEXEL_BYTES + TEXEL_BAND_BYTES * int(scene.n_bands)
    need = (texels.sum() + ols) * per_texel
    per_obj = [texels[ids].sum() for ids in per_instance]
    big = int(np.argmax(per_obj)) if per_obj else 0

    def fix(budget):
        scale = math.sqrt(budget / need)
        what = (f"the largest is '{scene.instances[big].name}' with {per_obj[big]:,.0f} texels; "
                if per_obj else "")
        return (f"{what}lower the texel density to about {density * scale:.3g} texels/m"
                + (" and the per-object lightmap resolutions"
                   if any(int(i.lightmap_resolution) for i in scene.instances) else ""))

    memory_budget.check(f"lightmaps ({texels.sum() + ols:,.0f} texels at {density:g} texels/m)",
                        need, fix)


def _orientation_areas(ols, maps, geom, lm, dcsg=None):
    """Estimates each OL's own instances, then sums each subtree bottom-up, so
    a level's area covers exactly the instances whose hits it receives."""
    K = len(ols)
    own = []
    covered = [orientation_lightmap.covered_instances(maps, k) for k in range(K)]
    for k, ol in enumerate(ols):
        memory_budget.check(f"orientation lightmap '{ol.name}' ({int(ol.samples):,} area samples)",
                            AREA_SAMPLE_BYTES * int(ol.samples), "lower its area samples")
        mine = np.flatnonzero(maps.inst_ol == k)
        member = np.zeros(maps.inst_ol.shape[0], np.bool_)
        member[covered[k]] = True
        own.append(estimate_areas(geom, mine, int(ol.resolution), int(ol.samples), int(ol.seed),
                                  member=member))
    area = [e.area.copy() for e in own]
    var = [(e.area * np.where(np.isfinite(e.rel_error), e.rel_error, 0.0)) ** 2 for e in own]
    if dcsg is not None:
        for k, (a, v, n_samples, seconds) in _lsystem_areas(ols, maps, geom, dcsg).items():
            area[k] += a
            var[k] += v
            # an OL over L-systems only spent no samples on instances
            mesh_samples = own[k].samples if own[k].total > 0 else 0
            own[k] = own[k]._replace(total=own[k].total + float(a.sum()),
                                     samples=mesh_samples + n_samples,
                                     seconds=own[k].seconds + seconds)
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
        lightmap.set_areas(lm, int(maps.lid[k]), area[k])
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
        rows[-1]["warnings"] = orientation_lightmap.averaging_warnings(rows[-1], area[k])
    return rows


def _chain(maps, k):
    out = []
    while k >= 0:
        out.append(k)
        k = int(maps.parent[k])
    return out


def _csg_meshes(node):
    """TriangleMesh leaves of a CSG tree, left to right."""
    if isinstance(node, CSGNode):
        return _csg_meshes(node.left) + _csg_meshes(node.right)
    return [node] if isinstance(node, TriangleMesh) else []


def _csg_with_uvs(node, uvs):
    """The CSG tree with each mesh leaf given its UVs from `uvs` (id(mesh) -> uv)."""
    if isinstance(node, CSGNode):
        return replace(node, left=_csg_with_uvs(node.left, uvs), right=_csg_with_uvs(node.right, uvs))
    if isinstance(node, TriangleMesh) and id(node) in uvs:
        return replace(node, uvs=uvs[id(node)])
    return node


def unwrap_meshes(scene, warnings, progress=None, layouts=None, texel_density=None,
                  max_resolution=1024, should_stop=None):
    """Gives lightmap UVs to the meshes that record photons but have none.

    Only prototypes with an instance that keeps its own lightmaps are laid out
    (objects under an orientation lightmap need no UVs). Meshes up to
    scene.unwrap_limit triangles, and larger ones whose unwrap is cached, get an
    xatlas unwrap, all in one batch through the contained worker
    (engine/lightmaps/uv_atlas.py). Larger ones get the fast box-projection layout
    (engine/lightmaps/fast_layout.py) in seconds instead of minutes, and so does a mesh on
    which xatlas fails (with a warning naming it). The fast layout is made for
    the smallest lightmap among the prototype's instances; where its charts and
    gaps need more texels, those instances get a larger forced resolution. Only
    a mesh too fragmented for any lightmap falls back to an automatic
    orientation lightmap. layouts (a list) gets one row per laid-out or skipped
    mesh: which layout it got and why. progress(done, total) follows the xatlas
    batch (from 0 before it starts); should_stop() -> True cancels it (raises
    core.errors.Cancelled). Returns a new Scene; the input is not modified."""
    from .lightmaps import uv_atlas  # late: xatlas is only needed for such meshes
    from .lightmaps import fast_layout
    density = float(scene.texel_density if texel_density is None else texel_density)
    n_mat = len(scene.materials)
    recording = np.zeros(len(scene.prototypes), np.bool_)
    for inst in scene.instances:
        p = inst.prototype
        if inst.lightmap and isinstance(p, (int, np.integer)) and 0 <= p < recording.size:
            recording[p] = True
    layouts = [] if layouts is None else layouts
    limit = int(getattr(scene, "unwrap_limit", 0) or 0)
    jobs, owners = [], []          # owners[j]: (prototype, mesh, kept triangles) of xatlas job j
    fast = []                      # (prototype, mesh, kept, vertices, triangles, why, xatlas error)
    for pi, proto in enumerate(scene.prototypes):
        if not recording[pi]:
            continue
        meshes = list(proto.meshes) + [m for root in proto.csg for m in _csg_meshes(root)]
        for mesh in meshes:
            if mesh.uvs is not None:
                continue
            v, tri, _ = check_mesh_arrays(mesh, f"mesh '{mesh.name}' in prototype '{proto.name}'", n_mat)
            keep = nondegenerate(v[tri])
            n = int(keep.sum())
            if limit and n > limit and not uv_atlas.is_cached(v, tri[keep]):
                fast.append((pi, mesh, keep, v, tri[keep],
                             f"{n:,} triangles without a 'Lightmap' UV layer is above the "
                             f"unwrap limit of {limit:,}", None))
                continue
            jobs.append((v, tri[keep]))
            owners.append((pi, mesh, keep))
    if not jobs and not fast:
        return scene
    if jobs and progress is not None:
        progress(0, len(jobs))
    results = uv_atlas.unwrap_many(jobs, progress=progress, should_stop=should_stop) if jobs else []
    uvs_by_proto, failed = {}, {}
    for (pi, mesh, keep), (v, t), res in zip(owners, jobs, results):
        if isinstance(res, Exception):
            n = getattr(res, "triangles", None)
            what = getattr(res, "reason", str(res)) + (f" unwrapping {n:,} triangles" if n else "")
            fast.append((pi, mesh, keep, v, t, what, res))
            continue
        layouts.append({"mesh": mesh.name, "triangles": int(keep.sum()), "layout": "xatlas",
                        "reason": "no 'Lightmap' UV layer"})
        uv = np.zeros((keep.shape[0], 3, 2))
        uv[keep] = res.uv
        uvs_by_proto.setdefault(pi, {})[id(mesh)] = uv
    instances = list(scene.instances)
    for pi, mesh, keep, v, t, why, err in fast:
        sizes = _lightmap_sizes(instances, pi, v, t, density, max_resolution)   # never empty
        try:
            lay = fast_layout.layout(v, t, min(sizes.values()), max_resolution=max(max_resolution, *sizes.values()))
        except fast_layout.LayoutError as e:
            failed.setdefault(pi, (mesh, why if err is not None else None, e))
            continue
        for i, r in sizes.items():
            if r < lay.resolution:       # the charts' gaps need this many texels
                instances[i] = replace(instances[i], lightmap_resolution=lay.resolution)
        layouts.append({"mesh": mesh.name, "triangles": int(keep.sum()), "layout": "fast layout",
                        "reason": why, "charts": int(lay.charts), "resolution": int(lay.resolution)})
        if err is not None:
            warnings.append(f"mesh '{mesh.name}': {why}; it got a fast box-projection layout "
                            "instead (add a UV layer named 'Lightmap' for a tighter one)")
        uv = np.zeros((keep.shape[0], 3, 2))
        uv[keep] = lay.uv
        uvs_by_proto.setdefault(pi, {})[id(mesh)] = uv
    prototypes = list(scene.prototypes)
    for pi, uvs in uvs_by_proto.items():
        if pi in failed:
            continue
        proto = prototypes[pi]
        prototypes[pi] = replace(
            proto, meshes=[replace(m, uvs=uvs[id(m)]) if id(m) in uvs else m for m in proto.meshes],
            csg=[_csg_with_uvs(root, uvs) for root in proto.csg])
    ols = list(scene.orientation_lightmaps)
    covered = {int(i) for ol in ols for i in ol.instances}
    for pi, (mesh, xatlas_why, err) in failed.items():
        mine = [i for i, inst in enumerate(instances) if inst.prototype == pi and inst.lightmap]
        for i in mine:
            instances[i] = replace(instances[i], lightmap=False)
        alone = [i for i in mine if i not in covered]
        if alone:
            ols.append(OrientationLightmap(name=f"{mesh.name} (automatic)", instances=alone))
        what = (xatlas_why + "; " if xatlas_why else "") + err.reason
        layouts.append({"mesh": mesh.name, "triangles": int(np.asarray(mesh.triangles).shape[0]),
                        "layout": "orientation lightmap", "reason": what})
        warnings.append(f"mesh '{mesh.name}': {what}; its objects are lit through an orientation "
                        "lightmap instead (per-object shading detail is averaged by normal; add a "
                        "UV layer named 'Lightmap' to keep it)")
    return replace(scene, prototypes=prototypes, instances=instances, orientation_lightmaps=ols)


def _lightmap_sizes(instances, pi, v, t, density, max_resolution):
    """{instance: lightmap side} of prototype pi's recording instances for the
    mesh (v, t), as allocate_lightmaps will size them."""
    p = v[t]
    sizes = {}
    for i, inst in enumerate(instances):
        if inst.prototype != pi or not inst.lightmap:
            continue
        forced = int(inst.lightmap_resolution)
        if forced:
            sizes[i] = forced
            continue
        area = texel_areas.triangle_world_areas(p, np.asarray(inst.transform, np.float64)[:3, :3]).sum()
        sizes[i] = lightmap.resolution_for(area, density, max_res=max_resolution)
    return sizes


def _plan_orientation(scene):
    """OL routing, and the scene with instances under a non-backup OL recording there only."""
    ol_maps = orientation_lightmap.plan(scene)
    if ol_maps.lid.size:
        scene = replace(scene, instances=[
            replace(inst, lightmap=False) if ol_maps.inst_ol[i] >= 0 and not ol_maps.inst_keep[i]
            else inst for i, inst in enumerate(scene.instances)])
    return scene, ol_maps


# --------------------------------------------------------------------------------------
# L-systems (thesis ch. 7): no per-primitive lightmaps, their photons go into OLs
# --------------------------------------------------------------------------------------

def _lsystem_orientation(scene):
    """An instance carrying an L-system that no OL covers gets one of its own (7.3):
    per-primitive lightmaps would unroll the graph."""
    covered = {int(i) for ol in scene.orientation_lightmaps for i in ol.instances}
    add = []
    for i, inst in enumerate(scene.instances):
        p = inst.prototype
        if i in covered or not isinstance(p, (int, np.integer)) or not 0 <= p < len(scene.prototypes):
            continue
        if scene.prototypes[p].lsystems:
            add.append(OrientationLightmap(name=f"{inst.name} (L-system)", instances=[i]))
    if not add:
        return scene
    return replace(scene, orientation_lightmaps=list(scene.orientation_lightmaps) + add)


def _lsystem_stubs(scene, geom, dcsg, ol_maps):
    """One OL per stub of every L-system instance (7.4), under its enclosing stub or
    the instance's OL, keyed by the stub's address; -> (scene, routing with inst_stub0)."""
    ols = list(scene.orientation_lightmaps)
    inst_stub0 = np.full(len(scene.instances), -1, np.int64)
    owners = []                 # per new OL: (instance, graph, StubRecord)
    for i, inst in enumerate(scene.instances):
        k = int(ol_maps.inst_ol[i]) if ol_maps.inst_ol.size else -1
        graphs = dcsg["proto_graphs"][int(geom.inst_proto[i])]
        if k < 0 or not any(dcsg["stubs"][gi] for gi in graphs):
            continue
        base = ols[k]
        inst_stub0[i] = len(ols) - dcsg["stub_first"][graphs[0]]
        for gi in graphs:
            first = len(ols)
            index = {r.address: first + j for j, r in enumerate(dcsg["stubs"][gi])}
            for r in dcsg["stubs"][gi]:
                ols.append(OrientationLightmap(
                    name=f"{inst.name} stub {r.address:016x}", instances=[],
                    parent=index.get(r.parent, k), resolution=base.resolution,
                    samples=base.samples, min_hits=base.min_hits, seed=base.seed))
                owners.append((i, gi, r))
    if not owners:
        return scene, ol_maps
    scene = replace(scene, orientation_lightmaps=ols)
    maps = orientation_lightmap.plan(scene)
    dcsg["stub_owners"] = {len(scene.orientation_lightmaps) - len(owners) + j: o
                           for j, o in enumerate(owners)}
    return scene, maps._replace(inst_stub0=inst_stub0)


def _lsystem_areas(ols, maps, geom, dcsg):
    """{OL: (area per bin, variance, samples, seconds)} of the L-system geometry each
    OL owns: a stub its subtree, an instance's OL the rest, nested stubs left to
    their own OLs."""
    from .geometry import dcsg_areas
    views = (geom.trace_i64, geom.trace_f32, geom.trace_i32, geom.trace_f64, geom.trace_features)
    out = {}

    def add(k, start, h, rot, i, graph):
        ol = ols[k]
        t = time.perf_counter()
        a, v = dcsg_areas.estimate_graph_areas(views, graph, dcsg["node_area"], start, h, rot,
                                      geom.inst_inv[i], int(ol.resolution), int(ol.samples),
                                      int(ol.seed) + 7919 * (start + 1))
        row = (a, v, int(ol.samples), time.perf_counter() - t)
        out[k] = row if k not in out else tuple(x + y for x, y in zip(out[k], row))

    for i in range(maps.inst_ol.shape[0]):
        k = int(maps.inst_ol[i])
        if k < 0:
            continue
        for gi in dcsg["proto_graphs"][int(geom.inst_proto[i])]:
            g = dcsg["graphs"][gi]
            add(k, dcsg["roots"][gi], g.root_hash, np.eye(3), i, g)
    for k, (i, gi, r) in dcsg.get("stub_owners", {}).items():
        add(k, r.node, r.address, r.rotation, i, dcsg["graphs"][gi])
    return out


def compile_warnings(info):
    """One line per thing the compile dropped or changed, naming the mesh (for reports)."""
    out = []
    for what, n in info.get("degenerate", {}).items():
        out.append(f"{what}: {n:,} zero-area triangles dropped (Blender: Mesh > Clean Up > Degenerate Dissolve)")
    for what, n in info.get("uv_clamped", {}).items():
        out.append(f"{what}: {n:,} triangles have lightmap UVs outside [0,1]², clamped to the atlas")
    return out


# A lobe this smooth (Blender roughness) or smoother keeps a photon's caustic focus.
CAUSTIC_ROUGHNESS = 0.1


def _caustic_lightmaps(scene, geom, density, max_resolution, csg, csg_split, dcsg, info):
    """The caustic lightmaps: the instances' lightmaps again at caustic_resolution x the
    texel density, allocated only when a material can focus light (a sharp mirror or
    glass). Their ids equal the regular ones, so a hit finds its texel in either."""
    k = float(getattr(scene, "caustic_resolution", 1.0))
    # at 1x they still keep caustics apart: the final gather reads them at the hit
    if not (math.isfinite(k) and k >= 1.0):
        return None
    sharp = [m.name for m in scene.materials
             if float(m.roughness) <= CAUSTIC_ROUGHNESS
             and (np.any(np.asarray(m.specular, float) > 0) or np.any(np.asarray(m.transmission, float) > 0))]
    if not sharp or not np.any(geom.inst_lm_base >= 0):
        return None
    # instance lightmaps only (OLs come after them, so the ids still agree)
    plain = replace(scene, orientation_lightmaps=[])
    asked = k
    while k >= 1.0:
        try:      # allocate_lightmaps checks the memory budget before it allocates
            lm, _, _ = allocate_lightmaps(plain, geom, density * k, int(max_resolution * k), csg, csg_split,
                                          {}, None, dcsg)
        except memory_budget.BudgetError:
            k *= 0.5          # caustics may be coarser; they never make a scene fail
            continue
        if k < asked:
            info.setdefault("warnings", []).append(
                f"caustic lightmaps at {k:g}x the texel density instead of {asked:g}x (memory)")
        info.update(caustic_texels=int(lm.area.shape[0]), caustic_resolution=k)
        return lm
    info.setdefault("warnings", []).append("caustic lightmaps are off: they do not fit in memory")
    return None


def compile_scene(scene, texel_density=None, max_resolution=1024, csg_split=True, unwrap_progress=None,
                  should_stop=None):
    """Scene -> CompiledScene. unwrap_progress(done, total) and should_stop():
    the xatlas unwraps of meshes without lightmap UVs (unwrap_meshes)."""
    t0 = time.perf_counter()
    if int(scene.n_bands) < 1:
        raise SceneError(f"n_bands must be >= 1, got {scene.n_bands}")
    density = float(scene.texel_density if texel_density is None else texel_density)
    if not (math.isfinite(density) and density > 0):
        raise SceneError(f"texel density must be positive, got {density}")
    materials = compile_materials(scene)
    try:
        bsdf_tables = compile_bsdf(scene.materials, int(scene.n_bands), getattr(scene, "spectral", None))
    except ValueError as e:
        raise SceneError(str(e)) from None
    textures = compile_textures(scene)
    warnings = []
    # instances under a (non-backup) OL record there instead of on own lightmaps
    scene = _lsystem_orientation(scene)
    scene, ol_maps = _plan_orientation(scene)
    n_ols = len(scene.orientation_lightmaps)
    layouts = []
    scene = unwrap_meshes(scene, warnings, progress=unwrap_progress, layouts=layouts,
                          texel_density=density, max_resolution=max_resolution, should_stop=should_stop)
    if len(scene.orientation_lightmaps) != n_ols:    # unwrap fallbacks added OLs
        scene, ol_maps = _plan_orientation(scene)
    t_unwrap = time.perf_counter()
    geom, info = compile_geometry(scene)
    n_mat = materials.diffuse.shape[0]
    if geom.shape_material.size and (geom.shape_material.max() >= n_mat or geom.shape_material.min() < 0):
        bad = int(geom.shape_material.max())
        raise SceneError(f"a shape uses material {bad}, but the scene has {len(scene.materials)} materials")
    csg = info.pop("csg_layout", None)
    if csg is not None:
        check_not_emissive(csg, materials)
    dcsg = info.pop("dcsg_layout", None)
    if dcsg is not None:
        lit = np.isin(geom.shape_material[geom.shape_kind == DCSG_KIND],
                      np.flatnonzero(materials.emission.max(axis=1) > 0))
        if lit.any():
            raise SceneError("an L-system uses an emissive material; emission on L-systems is not "
                             "supported yet: light it with a lamp or an emissive mesh instead")
        scene, ol_maps = _lsystem_stubs(scene, geom, dcsg, ol_maps)
    t_geo = time.perf_counter()
    info = dict(info)
    info["warnings"] = warnings + compile_warnings(info)
    info["layouts"] = layouts
    lightmaps, per_instance, ol_maps = allocate_lightmaps(scene, geom, density, max_resolution,
                                                          csg, csg_split, info, ol_maps, dcsg)
    caustics = _caustic_lightmaps(scene, geom, density, max_resolution, csg, csg_split, dcsg, info)
    t_lm = time.perf_counter()
    if geom.tlas_min.shape[0] > 0:
        bounds = (geom.tlas_min[0].astype(np.float64), geom.tlas_max[0].astype(np.float64))
    else:
        bounds = (np.zeros(3), np.zeros(3))
    lights = compile_lights(scene, geom, materials, bounds)
    camera = checked_camera(scene.camera, scene.n_bands)
    env = environment_map(lights)    # environment.EnvMap: radiance(), sample(), pdf() on it
    env_info = describe_environment(env)
    if env_info is not None:
        env_info.update(name=str(getattr(scene.environment, "name", "world")),
                        bake_seconds=float(getattr(scene.environment, "bake_seconds", 0.0)))
        info["environment"] = env_info
    info.update(lightmaps=int(lightmaps.offset.shape[0]), texels=int(lightmaps.area.shape[0]),
                lights=int(lights.kind.shape[0]))
    info.update(textures=int(textures.tex_first.shape[0]), texture_bytes=texture_bytes(textures),
                texture_bake_seconds=float(sum(getattr(t, "bake_seconds", 0.0)
                                               for t in getattr(scene, "textures", None) or [])))
    cs = CompiledScene(scene.name, int(scene.n_bands), geom, materials, lights, lightmaps, camera,
                       env, info, instance_lightmaps=per_instance, orientation=ol_maps,
                       textures=textures, bsdf=bsdf_tables, caustics=caustics)
    cs.spectral = getattr(scene, "spectral", None)
    cs.polarization = bool(getattr(scene.camera, "polarized", False)) or bool(np.any(lights.pol[:, 3] > 0.0))
    cs.timings.update(unwrap=t_unwrap - t0, geometry=t_geo - t0, lightmap_setup=t_lm - t_geo,
                      setup=time.perf_counter() - t0)
    return cs
