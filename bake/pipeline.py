"""The lightmap bake: prepare (main thread) -> compute (any thread) -> commit (main thread).

prepare_bake chooses the objects, makes their Lightmap UV layers and exports
the scene; compute_bake runs engine/session.py (photon pass, direct gather) and
turns lightmaps into RGBA arrays; commit_bake writes images, files and hooks.
A failed or cancelled compute or commit is undone by rollback_bake.
"""
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ..engine.lightmaps import lightmap
from ..engine import light_reuse, session
from ..engine import spectral
from ..engine.lightmaps import texel_areas
from ..engine.shading import spectrum
from ..engine.core.scene import SceneError
from ..export import csg as csg_export
from ..export import uv_layers
from ..export.ol_routing import OLRouter
from . import boolean_meshes, csg_atlas, hooks, images, spectral_exr
from .images import BakedMap


# The bake's passes: COMBINED (direct + indirect), DIRECT (light samples only: no
# photons), INDIRECT (the photons' and gathers' light only), AO (ambient occlusion,
# engine/transport/ambient_occlusion.py: no photons; written as the image's value),
# SHADOWMASK (up to four lights' visibility, one per channel, engine/transport/shadowmask.py).
BAKE_PASSES = ("COMBINED", "DIRECT", "INDIRECT", "AO", "SHADOWMASK")
# Directional bakes: one dominant direction per texel (as Unity's and Bakery's MonoSH), or
# first-order spherical harmonics per band (as Godot's and Bakery's SH).
DIRECTIONAL_MODES = ("DOMINANT", "SH")

# The last bake's photon pass (Keep Bake Light): the next bake of the unchanged scene
# reuses it. Let go on file load (operators/__init__.py) and when the scene changes.
BAKE_LIGHT = light_reuse.BakeLight()


@dataclass
class BakeSettings(session.Settings):
    """Scene settings (session.Settings, read from Scene.photon_lightmaps) plus the bake's options."""
    resolution: int = 0          # R x R texels per object; 0: each object's setting or the texel density
    indirect_only: bool = False  # leave the gathered direct light out
    # what the maps hold (BAKE_PASSES): all light, direct or indirect light alone, or AO
    bake_pass: str = "COMBINED"
    ao_distance: float = 1.0     # AO: rays that meet nothing within this many metres are unoccluded
    pass_rays: int = 16          # AO and shadowmask: rays (light samples) per point, 16 points a texel
    shadowmask_lights: str = ""  # SHADOWMASK: the lights (names, comma-separated) of channels R, G, B, A
    texel_validity: bool = False  # fill texels inside geometry from their neighbours (texel_validity.py)
    stitch_seams: bool = False    # texels meeting across UV seams agree where they meet (seam_stitch.py)
    # also which way each texel's light comes from (directional_lightmap.py): "" none,
    # DIRECTIONAL_MODES "DOMINANT" (one direction, of the light's luminance) or "SH" (L1 per band)
    directional: str = ""
    overwrite: bool = False
    save_dir: str = ""
    pack: bool = False
    hook_materials: bool = False
    bake_error_images: bool = False  # also an image of each texel's estimated relative error
    spectral_exr: bool = False       # spectral bakes: also "<object>_spectral.exr", every band (save_dir only)
    light_cache: str = ""            # a folder of saved photon passes (engine/light_reuse.py): reused, and added to


def bscene_props(bscene):
    """Scene.photon_lightmaps, or None where the add-on's properties are not registered."""
    return getattr(bscene, "photon_lightmaps", None)


@dataclass
class BakeResult:
    maps: dict = field(default_factory=dict)      # object name -> BakedMap
    images: dict = field(default_factory=dict)    # object name -> bpy image name
    paths: dict = field(default_factory=dict)     # object name -> saved file (None: unsaved/packed)
    skipped: dict = field(default_factory=dict)   # object name -> why it was not baked
    hooked: list = field(default_factory=list)    # materials given a lightmap hook
    warnings: list = field(default_factory=list)
    stats: object = None                          # PhotonStats of the photon pass
    irradiance_cache: dict = None                 # the cache's counts (records, rounds, rays), if used
    cluster: dict = None                          # on a cluster: its address, workers and tasks per phase
    bake_pass: str = "COMBINED"                   # what the maps hold (BAKE_PASSES)
    mask_lights: list = None                      # SHADOWMASK: the lights of channels R, G, B, A
    pass_rays: int = 0                            # AO and SHADOWMASK: rays per point used (0: other passes)
    # texel validity: object name -> {"invalid": texels filled from neighbours, "texels": measured}
    validity: dict = None
    # with stitch_seams: {"edges", "samples", "jump_before", "jump_after" (mean relative jump of the
    # two sides' bilinear reads along the seams), their 95th percentiles, "texels_changed", and for a
    # directional bake "direction_jump_before", "direction_jump_after" (its direction images')}
    seams: dict = None
    # the photon pass: {"reused": "memory" | "disk" | None, "why_not", "key", "kept_bytes", "saved"}
    light_reuse: dict = None
    seconds: dict = field(default_factory=dict)   # export, photon_pass, bake, total
    lightmap_bytes: int = 0
    uv_layers: dict = field(default_factory=dict)  # mesh name -> uv_layers.ensure_lightmap_uv status
    # CSG solid name -> {"leaves": baked leaf names, "skipped": {leaf: why}, "split_texels",
    # "boundary_texels", "atlas": (w, h)}
    csg: dict = field(default_factory=dict)
    environment: dict = None    # the world's map (compiled info["environment"]), None: constant
    gathered: bool = False      # indirect light by final gather (engine/transport/bake_gather.py), not photon lookup
    # object name -> {"rel_error_mean", "rel_error_p95", "rel_error_max", "rays_mean"}: the gathered
    # texels' estimated relative standard error (engine/session.texel_error) and rays they got
    error: dict = field(default_factory=dict)
    # object name -> BakedMap of that estimate per texel (RGB = relative error, A = coverage),
    # with bake_error_images; images "<object>_LightmapError", files "<object>_error.exr"
    error_maps: dict = field(default_factory=dict)
    error_images: dict = field(default_factory=dict)   # object name -> bpy image name
    error_paths: dict = field(default_factory=dict)    # object name -> saved file
    # with texel validity: object name -> BakedMap (R = share of rays meeting back faces,
    # G = 1 - R on valid texels, 0 on invalid ones, A = coverage); images
    # "<object>_LightmapValidity", files "<object>_validity.exr"
    validity_maps: dict = field(default_factory=dict)
    validity_images: dict = field(default_factory=dict)
    validity_paths: dict = field(default_factory=dict)
    # directional bakes: object name -> BakedMap (RGB = k s, the distant light's share times its
    # direction, world space; A = coverage); images "<object>_LightmapDirection", files "<object>_direction.exr"
    direction_maps: dict = field(default_factory=dict)
    direction_images: dict = field(default_factory=dict)
    direction_paths: dict = field(default_factory=dict)
    # L1 SH bakes, per axis "x", "y", "z": object name -> BakedMap (RGB = that axis's L1
    # coefficient per colour, world space, as E/pi; A = coverage); images
    # "<object>_LightmapL1x" ..., files "<object>_l1x.exr" ...
    l1_maps: dict = field(default_factory=lambda: {a: {} for a in "xyz"})
    l1_images: dict = field(default_factory=lambda: {a: {} for a in "xyz"})
    l1_paths: dict = field(default_factory=lambda: {a: {} for a in "xyz"})
    directional: dict = None       # the mode, the moments' memory and the images' (bytes)
    # with spectral_exr: object name -> (height, width, bands) E/pi per band, and its file
    spectral_maps: dict = field(default_factory=dict)
    spectral_paths: dict = field(default_factory=dict)


@dataclass
class BakeJob:
    """A bake split in three, so an operator can run the photon pass off the UI thread."""
    scene: object                 # engine Scene (plain data)
    export_map: object
    targets: dict                 # object name -> engine instance id
    settings: BakeSettings
    direct: bool                  # gather direct light (False: --indirect-only)
    result: BakeResult
    t_start: float
    cs: object = None
    # CSG solid name -> {leaf object name: None (bake it) or why it is skipped}
    csg: dict = field(default_factory=dict)
    recording: list = field(default_factory=list)   # per instance: the export's own lightmap flag
    primitives: set = field(default_factory=set)   # stand-alone tagged primitives among targets
    # mesh name -> its Lightmap layer state before prepare_bake (rollback_bake puts it back)
    uv_undo: dict = field(default_factory=dict)
    # Boolean of plain meshes -> its operands' names (baked as Blender's result, boolean_meshes.py)
    booleans: dict = field(default_factory=dict)


def _original(ob):
    return getattr(ob, "original", None) or ob


def _is_excluded(ob):
    props = getattr(ob, "photon_lightmaps", None)
    return bool(props is not None and props.exclude)


def evaluated_depsgraph(context_or_depsgraph):
    import bpy
    if isinstance(context_or_depsgraph, bpy.types.Depsgraph):
        return context_or_depsgraph
    return context_or_depsgraph.evaluated_depsgraph_get()


def _world_area(ob):
    """Surface area of a mesh object in world units (as the lightmap allocator measures it)."""
    v, tv, _, _ = uv_layers.mesh_triangles(ob.data)
    if tv.shape[0] == 0:
        return 0.0
    M = np.array(ob.matrix_world, np.float64)[:3, :3]
    return float(texel_areas.triangle_world_areas(v[tv], M).sum())


def layout_resolution(ob, texel_density, resolution=None):
    """Lightmap texels per side the engine will give mesh object `ob` (what its UV layout is for)."""
    if resolution:
        return int(resolution)
    props = getattr(ob, "photon_lightmaps", None)
    if props is not None and int(props.lightmap_resolution) > 0:
        return int(props.lightmap_resolution)
    return lightmap.resolution_for(_world_area(ob), texel_density)


def _covering_ol(router, ob):
    """Name of the (non-backup) OL empty that takes this object's hits, else None."""
    key = router.route(ob) if router else None
    if key is None:
        return None
    empty = router.colls[key][1]
    return None if empty.photon_lightmaps.ol_backup else empty.name


def _wanted(depsgraph, objects, skipped):
    """The objects a bake bakes, in order; each other one goes into skipped with why."""
    wanted = []
    seen = set()
    operands = {o.name: solid for o, solid in csg_export.find_operands(depsgraph).items()}
    ol_router = OLRouter(depsgraph.scene, lambda level, msg: None)
    for ob in objects:
        ob = _original(ob)
        if ob.name in seen:
            continue
        seen.add(ob.name)
        if ob.type != "MESH":
            skipped[ob.name] = f"a {ob.type.lower()}, not a mesh"
        elif _is_excluded(ob):
            skipped[ob.name] = "excluded from lightmaps (Object > Photon Lightmaps)"
        elif ob.name in operands:
            skipped[ob.name] = (f"a Boolean operand of '{operands[ob.name]}': it is baked into "
                                "that solid's lightmap")
        elif _covering_ol(ol_router, ob) is not None:
            # no Lightmap UV layer either: its light lives in the OL, indexed by normal
            skipped[ob.name] = (f"covered by orientation lightmap '{_covering_ol(ol_router, ob)}': "
                                "use Bake Orientation Lightmaps")
        else:
            wanted.append(ob)
    return wanted


def unwrap_seconds(triangles):
    """About how long xatlas takes on `triangles`: the bake's up-front estimate.
    Fitted on this project's 2-core test machine to UV spheres of 4k to 100k
    triangles (1.0 s at 16k, 8.3 s at 65k, 9.4 s at 102k; it grows faster than
    linearly, and varies with the mesh)."""
    return 1.2 * (max(int(triangles), 0) / 16_000) ** 1.3


def unwrap_plan(context_or_depsgraph, objects, resolution=None):
    """The xatlas unwraps prepare_bake would run -> [(object name, vertices,
    triangles, lightmap side)]; reads the meshes, changes nothing. Run them with
    run_unwraps (any thread) first, and prepare_bake finds them cached."""
    depsgraph = evaluated_depsgraph(context_or_depsgraph)
    density = session.Settings.read(bscene_props(depsgraph.scene)).texel_density
    plan = []
    for ob in _wanted(depsgraph, objects, {}):
        if boolean_meshes.mesh_operands(ob) is not None:
            continue                  # its operands are laid out together (boolean_meshes.py)
        side = layout_resolution(ob, density, resolution)
        if not uv_layers.needs_unwrap(ob, side):
            continue
        v, tri, _, _ = uv_layers.mesh_triangles(ob.data)
        if tri.shape[0] and np.isfinite(v).all():
            plan.append((ob.name, v, tri, side))
    return plan


def run_unwraps(plan, progress=None, should_stop=None):
    """Any thread: the plan's xatlas unwraps into the unwrap cache (a mesh xatlas
    fails on is remembered too). progress(done, total); should_stop() -> True
    kills the worker and raises Cancelled."""
    from ..engine.lightmaps import uv_atlas
    uv_atlas.unwrap_many([dict(vertices=v, triangles=t, resolution=side) for _, v, t, side in plan],
                   progress=progress, should_stop=should_stop)


def directional_mode(value):
    """A directional option as given (None: unset; False or "": none; True: "DOMINANT";
    or a DIRECTIONAL_MODES name, any case) -> None, "" or a mode; SceneError otherwise."""
    if value is None:
        return None
    if isinstance(value, bool):
        return "DOMINANT" if value else ""
    mode = str(value).strip().upper()
    if mode in ("", "NONE"):
        return ""
    if mode not in DIRECTIONAL_MODES:
        raise SceneError(f"directional: must be one of {', '.join(m.lower() for m in DIRECTIONAL_MODES)}, "
                         f"got '{value}'")
    return mode


def prepare_bake(context_or_depsgraph, objects, *, photons=None, seed=None, resolution=None,
                 indirect_only=False, denoise=None, indirect=None, bake_gather_rays=None,
                 bake_target_error=None, bake_time=None, error_images=None, irradiance_cache=None,
                 gather_lights=None, spectral_exr=None, bake_pass=None, ao_distance=None,
                 shadowmask_lights=None, texel_validity=None, pass_rays=None, keep_light=None, light_cache=None,
                 lay_out=(), stitch_seams=None, direct_samples=None, directional=None):
    """Main thread: Lightmap UV layers for the objects, then the scene export.

    lay_out: other objects given the Lightmap UV layers a bake of them would make,
    but not baked: a process that rebakes some objects of a .blend it does not
    save (the CLI's --objects) exports the scene its full bake exported, so that
    the photon pass saved by that bake serves it.

    On failure the UV layers are as they were; after it, rollback_bake(job) puts them
    back (a failed or cancelled compute or commit)."""
    t0 = time.perf_counter()
    result = BakeResult()
    depsgraph = evaluated_depsgraph(context_or_depsgraph)
    bscene = depsgraph.scene
    props = bscene_props(bscene)
    density = session.Settings.read(props).texel_density
    if resolution is not None and int(resolution) < 1:
        raise SceneError(f"resolution: must be a positive number of texels, got {resolution}")
    bake_pass = _bake_pass(bake_pass, indirect_only)
    if ao_distance is not None and not float(ao_distance) > 0.0:
        raise SceneError(f"AO distance: must be a positive number of metres, got {ao_distance}")
    if pass_rays is not None and not 1 <= int(pass_rays) <= 65536:
        raise SceneError(f"pass rays: must be 1 to 65536 rays per point, got {pass_rays}")
    if direct_samples is not None and not 1 <= int(direct_samples) <= 1 << 20:
        raise SceneError(f"direct samples: must be 1 to {1 << 20} light samples per texel, got {direct_samples}")
    directional = directional_mode(directional)
    wanted = _wanted(depsgraph, objects, result.skipped)
    extra = [ob for ob in _wanted(depsgraph, lay_out, {}) if ob.name not in {w.name for w in wanted}]
    booleans = {}                   # Booleans of plain meshes: baked as Blender's result
    for ob in wanted + extra:
        _check_finite(ob)
        operands = boolean_meshes.mesh_operands(ob)
        if operands is not None:
            booleans[ob.name] = operands
    uv_undo = _uv_snapshot({o.data.name: o.data for o in
                            wanted + extra + [o for ops in booleans.values() for o in ops]}.values())
    try:
        job = _prepare_export(context_or_depsgraph, depsgraph, wanted, result, density, resolution, booleans,
                              extra)
    except BaseException:
        _uv_restore(uv_undo)
        raise
    job.uv_undo = uv_undo
    job.settings = BakeSettings.read(props, photons=photons, seed=seed, resolution=resolution,
                                     indirect_only=indirect_only, denoise=denoise, indirect=indirect,
                                     bake_gather_rays=bake_gather_rays, bake_target_error=bake_target_error,
                                     bake_time=bake_time, bake_error_images=error_images,
                                     bake_irradiance_cache=irradiance_cache, bake_gather_lights=gather_lights,
                                     spectral_exr=spectral_exr, bake_pass=bake_pass, ao_distance=ao_distance,
                                     shadowmask_lights=shadowmask_lights, texel_validity=texel_validity,
                                     pass_rays=pass_rays, bake_keep_light=keep_light, light_cache=light_cache,
                                     stitch_seams=stitch_seams, bake_direct_samples=direct_samples,
                                     directional=directional)
    if bake_pass == "SHADOWMASK":
        try:
            job.mask_lights = _mask_lights(job.scene, job.settings.shadowmask_lights)
        except BaseException:
            _uv_restore(uv_undo)
            raise
    if bake_pass in ("DIRECT", "AO", "SHADOWMASK"):
        # light samples (or AO rays) per texel alone: no photons to trace or gather
        job.settings.indirect, job.settings.indirect_only = "LOOKUP", False
    if bake_pass in ("AO", "SHADOWMASK"):
        job.settings.spectral = False       # geometry alone: no colour, so nothing for bands to carry
    if job.settings.spectral_exr and not job.settings.spectral:
        _uv_restore(uv_undo)
        raise SceneError("spectral EXR files need a spectral bake: turn Spectral on (CLI: --spectral)")
    if job.settings.spectral:
        try:
            job.scene = spectral.spectral_scene(job.scene)
        except BaseException:
            _uv_restore(uv_undo)
            raise
    if bake_pass in ("DIRECT", "AO", "SHADOWMASK"):
        job.settings.photons = 0
    elif photons is None:
        # the scene's count for this kind of bake: Bake Photons when it gathers
        job.settings.photons = job.settings.bake_photon_count
    if job.settings.bake_gathers:
        for inst, rec in zip(job.scene.instances, job.recording):
            inst.lightmap = inst.lightmap or rec
    if job.settings.denoise:
        # Missing pyoidn is told now, not after the photon pass.
        try:
            from ..engine.transport import denoise as DN
            DN.require()
        except BaseException:
            _uv_restore(uv_undo)
            raise
    job.direct, job.t_start = bake_pass != "INDIRECT", t0
    result.seconds["export"] = time.perf_counter() - t0
    return job


def _bake_pass(bake_pass, indirect_only):
    """The pass asked for (BAKE_PASSES; None: COMBINED, or INDIRECT with indirect_only)."""
    if bake_pass is None:
        return "INDIRECT" if indirect_only else "COMBINED"
    name = str(bake_pass).upper()
    if name not in BAKE_PASSES:
        raise SceneError(f"bake pass '{bake_pass}': use one of {', '.join(p.lower() for p in BAKE_PASSES)}")
    if indirect_only and name != "INDIRECT":
        raise SceneError(f"bake pass '{bake_pass}' with Indirect Only: choose one (the indirect pass "
                         "is Indirect Only)")
    return name


def _mask_lights(scene, names):
    """A shadowmask's lights: the names given (comma-separated), or every light of the
    scene when it has at most four -> (names, compiled light rows)."""
    from ..engine.transport import shadowmask
    chosen = [n.strip() for n in str(names or "").split(",") if n.strip()]
    if not chosen:
        chosen = [light.name for light in scene.lights]
        if len(chosen) > shadowmask.MAX_LIGHTS:
            raise SceneError(f"shadowmask: the scene has {len(chosen)} lights; choose up to "
                             f"{shadowmask.MAX_LIGHTS} (CLI --shadowmask-lights 'Sun,Lamp')")
    return chosen, shadowmask.light_rows(scene, chosen)


def _prepare_export(context_or_depsgraph, depsgraph, wanted, result, density, resolution, booleans, extra=()):
    """prepare_bake after choosing the objects: their Lightmap UV layers, then the export.
    booleans: {name: operands} of the wanted Booleans of plain meshes (boolean_meshes.py).
    extra: objects laid out too (prepare_bake's lay_out); one that cannot be is left as it is."""
    from ..engine.lightmaps.uv_atlas import UnwrapError
    from ..export import export_scene
    bscene = depsgraph.scene
    changed = False
    sides = {}
    for ob in list(wanted) + list(extra):
        if ob.name in booleans:
            try:
                sides[ob.name], status = boolean_meshes.prepare(ob, booleans[ob.name], density, resolution)
            except (UnwrapError, SceneError) as exc:
                if ob not in wanted:
                    continue
                wanted.remove(ob)
                result.skipped[ob.name] = getattr(exc, "reason", None) or str(exc)
                result.warnings.append(f"object '{ob.name}': {result.skipped[ob.name]}")
                continue
            result.uv_layers.update(status)
            changed = True
            continue
        changed |= boolean_meshes.release(ob.data)
        notes = []
        try:
            side = layout_resolution(ob, density, resolution)
            status = uv_layers.ensure_lightmap_uv(ob, resolution=side, notes=notes)
            result.warnings.extend(f"object '{ob.name}': {note}" for note in notes)
            need = uv_layers.required_resolution(ob)
            if need > side:                 # a fast layout whose gaps need more texels
                sides[ob.name] = need
        except UnwrapError as exc:
            # xatlas failed (or crashed in its worker) on this mesh alone: bake the others
            if ob not in wanted:
                continue
            wanted.remove(ob)
            result.skipped[ob.name] = (f"no Lightmap UV layer: {exc.reason}; add a UV layer named "
                                       f"'{uv_layers.LAYER_NAME}' (e.g. UV > Lightmap Pack) and bake again")
            result.warnings.append(f"object '{ob.name}': {result.skipped[ob.name]}")
            continue
        except (ValueError, RuntimeError) as exc:
            if ob not in wanted:
                continue
            # xatlas refusals (UnwrapError), Edit Mode, a linked mesh: the user's to fix, so
            # say which object (unless the message does already).
            if isinstance(exc, SceneError) and f"'{ob.name}'" in str(exc):
                raise
            raise SceneError(f"object '{ob.name}': cannot make its Lightmap UV layer: {exc}") from exc
        result.uv_layers[ob.data.name] = status
        changed |= status in (uv_layers.CREATED, uv_layers.UPDATED)
    if changed:
        # The export reads evaluated meshes: let them pick up the new layers.
        if context_or_depsgraph is depsgraph:
            depsgraph.update()
        else:
            context_or_depsgraph.view_layer.update()
            depsgraph = context_or_depsgraph.evaluated_depsgraph_get()

    warnings = result.warnings
    scene, emap = export_scene(depsgraph, report=lambda level, msg: None, mesh_results=set(booleans))
    warnings.extend(emap.warnings)
    targets = {}
    csg = {}
    primitives = set()
    for ob in wanted:
        ids = [i for i in emap.object_instances(ob.name) if emap.instances[i].lightmap]
        if not ids:
            result.skipped[ob.name] = "not in the rendered scene (hidden from render, or no faces)"
            continue
        i = ids[0]
        rec = emap.prototypes[emap.instances[i].prototype]
        if rec.uv_source == "csg":
            csg[ob.name] = csg_atlas.leaf_plan(scene.prototypes[emap.instances[i].prototype], ob.name,
                                          csg, warnings)
            targets[ob.name] = i
            continue
        if emap.csg_solids.get(ob.name) == "primitive":
            primitives.add(ob.name)
        if rec.uv_source != uv_layers.LAYER_NAME:
            result.skipped[ob.name] = (f"its UV layer '{uv_layers.LAYER_NAME}' leaves [0,1]², so the "
                                       "lightmap would not match it; fix or rename that layer")
            continue
        targets[ob.name] = i
    # Only baked objects record photons for a lookup bake: the others' lightmaps would
    # cost memory and time, and recording never changes where photons go. A gathering
    # bake gives them back (prepare_bake): its gather rays read their light.
    recording = [bool(inst.lightmap) for inst in scene.instances]
    for i, inst in enumerate(scene.instances):
        inst.lightmap = i in targets.values()
        if inst.lightmap and resolution:
            inst.lightmap_resolution = int(resolution)
    for name, side in sides.items():
        # A Boolean's layout is its operands' atlas, `side` texels wide; a fast
        # layout needs `side` texels for its gaps. Objects not baked record photons
        # for the gather in the layout they would be baked in.
        for i in [targets[name]] if name in targets else emap.object_instances(name):
            if side and not (resolution and name not in targets):
                scene.instances[i].lightmap_resolution = int(side)
    return BakeJob(scene, emap, targets, BakeSettings.read(bscene_props(bscene)), True, result, 0.0, csg=csg,
                   primitives=primitives, recording=recording,
                   booleans={n: [o.name for o in ops[1:]] for n, ops in booleans.items() if n in targets})


def _check_finite(ob):
    """A NaN or infinite vertex would fail deep in the unwrap or the kernels: refuse it by name."""
    co = np.empty(len(ob.data.vertices) * 3, np.float32)
    ob.data.vertices.foreach_get("co", co)
    bad = ~np.isfinite(co.reshape(-1, 3)).all(axis=1)
    if bad.any():
        raise SceneError(f"object '{ob.name}': vertex {int(np.argmax(bad))} of mesh '{ob.data.name}' is NaN "
                         f"or infinite ({int(bad.sum())} such vertices); move it to a finite position or "
                         "delete it")


def _uv_props():
    return (uv_layers.HASH_PROP, uv_layers.DIGEST_PROP, uv_layers.MIN_RES_PROP, uv_layers.LAYOUT_PROP,
            boolean_meshes.BLOCK_PROP)


def _uv_snapshot(meshes):
    """What uv_layers.ensure_lightmap_uv may change on each mesh, to put back on failure."""
    snap = {}
    for me in meshes:
        layer = me.uv_layers.get(uv_layers.LAYER_NAME)
        snap[me.name] = dict(uv=None if layer is None else uv_layers.read_uvs(layer).copy(),
                             props={k: me[k] for k in _uv_props() if k in me},
                             active=me.uv_layers.active_index,
                             render=[l.name for l in me.uv_layers if l.active_render])
    return snap


def _uv_restore(snap):
    """Puts back what _uv_snapshot saw: a layer we added goes, a layer we rewrote gets its UVs back."""
    import bpy
    for name, s in snap.items():
        me = bpy.data.meshes.get(name)
        if me is None:
            continue
        layer = me.uv_layers.get(uv_layers.LAYER_NAME)
        if layer is not None and s["uv"] is None:
            me.uv_layers.remove(layer)
        elif layer is not None and not np.array_equal(uv_layers.read_uvs(layer), s["uv"]):
            layer.uv.foreach_set("vector", s["uv"].reshape(-1))
        for k in _uv_props():
            if k in s["props"]:
                me[k] = s["props"][k]
            elif k in me:
                del me[k]
        if len(me.uv_layers):
            me.uv_layers.active_index = s["active"]
            for l in me.uv_layers:
                if l.name in s["render"]:
                    l.active_render = True
        me.update()


def rollback_bake(job):
    """After a failed or cancelled bake: the Lightmap UV layers as they were before prepare_bake."""
    _uv_restore(job.uv_undo)
    job.uv_undo = {}


def _error_stats(cs, job, solids):
    """Per baked object: its gathered texels' estimated relative error and rays (BakeResult.error)."""
    ids, rel, rays = cs.bake_error
    lm = cs.lightmaps
    out = {}
    for name, i in job.targets.items():
        lids = [d["lightmap"] for d in solids[name]] if name in job.csg else [cs.instance_lightmaps[i][0]]
        rows = np.concatenate([np.arange(lightmap.texel_slice(lm, l).start, lightmap.texel_slice(lm, l).stop)
                               for l in lids]) if lids else np.zeros(0, np.int64)
        sel = np.isin(ids, rows)
        if not sel.any():
            continue
        r = rel[sel]
        out[name] = dict(rel_error_mean=float(r.mean()), rel_error_p95=float(np.percentile(r, 95)),
                         rel_error_max=float(r.max()), rays_mean=float(rays[sel].mean()))
    return out


def _fill_invalid(cs, job, ids, leaves=(), solids=None):
    """Texel validity over the baked lightmaps `ids` and CSG leaves `leaves` (their
    solids' leaf lists in `solids`): texels inside geometry filled from their
    neighbours -> ({object: {"invalid", "texels"}}, {object: validity BakedMap}, seconds)."""
    from ..engine.transport import texel_validity
    t0 = time.perf_counter()
    rows, share = texel_validity.backface_share(cs, ids, seed=int(job.settings.seed), csg_leaves=leaves)
    invalid = share > texel_validity.INVALID_SHARE
    lm = cs.lightmaps
    channels = np.zeros((lm.area.shape[0], 4))
    channels[rows, 0] = share
    channels[rows, 1] = np.where(invalid, 0.0, 1.0 - share)
    channels[:, 3] = lm.coverage
    counts, maps = {}, {}
    # a solid's validity colours go through its atlas, as its error image (the layouts store E/pi)
    carrier = lm._replace(irradiance=math.pi * channels[:, :3]) if leaves else None
    for name, i in job.targets.items():
        if name in job.csg:
            # a solid's counted texels are its leaves' texels (a split texel once, not per region)
            mine = np.concatenate([np.arange(s.start, s.stop) for s in
                                   (lightmap.texel_slice(lm, d["lightmap"]) for d in solids[name])] or [[]])
            inside = np.isin(rows, mine)
            bm = csg_atlas.atlas(cs, job, name, solids[name], lightmaps=carrier)
            if bm is not None:
                maps[name] = bm
        else:
            lm_id = cs.instance_lightmaps[i][0]
            sl = lightmap.texel_slice(lm, lm_id)
            inside = (rows >= sl.start) & (rows < sl.stop)
            maps[name] = BakedMap(name, images.texel_rgba(lm, lm_id, channels), lm_id)
        counts[name] = {"invalid": int(np.count_nonzero(inside & invalid)), "texels": int(np.count_nonzero(inside))}
    texel_validity.dilate_over(lm, rows[invalid])
    return counts, maps, time.perf_counter() - t0


def _error_maps(cs, job, solids):
    """Per baked object: the estimated relative error of each texel as an image (BakeResult.error_maps).

    The values go through the lightmap's own image layout (lightmap_rgba, the CSG atlas),
    so error pixel and lightmap pixel are the same texel; texels without an estimate are 0."""
    ids, rel, _ = cs.bake_error
    lm = cs.lightmaps
    values = np.zeros_like(lm.irradiance)
    values[ids] = (math.pi * rel)[:, None]     # the layouts store E/pi
    err = lm._replace(irradiance=values)
    out = {}
    for name, i in job.targets.items():
        if name in job.csg:
            bm = csg_atlas.atlas(cs, job, name, solids[name], lightmaps=err)
        else:
            lm_id = cs.instance_lightmaps[i][0]
            bm = BakedMap(name, images.lightmap_rgba(err, lm_id), lm_id)
        if bm is not None and name in job.result.maps:
            out[name] = bm
    return out


def compute_bake(job, progress=None, phase=None, should_stop=None):
    """Any thread: photon pass and per-object RGBA arrays. Raises Cancelled.

    progress(done, total) follows the photon pass (False: cancel); should_stop()
    -> True cancels the texel gathers (between their parts; on a cluster, between
    its tasks); phase(name,
    detail) is told as each other part starts: "scene", "kernels" (a first run
    compiling, with how many so far), "direct" and "gather" (texels),
    "images", "denoise"."""
    from ..engine.core import kernel_watch
    result = job.result
    t0 = time.perf_counter()
    if not job.targets:
        result.seconds["photon_pass"] = 0.0
        return job
    phase = phase or (lambda name, detail: None)
    started = []

    def on_compile(watch, name):
        started or started.append(time.perf_counter())
        phase("kernels", f"{watch.started} compiled so far, {time.perf_counter() - started[0]:.0f} s "
                         "(first run; cached afterwards)")

    phase("scene", f"{len(job.scene.instances):,} objects")
    keep = job.settings.bake_keep_light or job.settings.light_cache
    with kernel_watch.watching(on_compile):
        cs, stats = session.compile_and_trace_bake(
            job.scene, job.settings, progress=progress, aim_at=list(job.targets.values()),
            kept=(BAKE_LIGHT if job.settings.bake_keep_light else light_reuse.BakeLight()) if keep else None,
            cache_dir=job.settings.light_cache)
    if not job.settings.bake_keep_light:
        BAKE_LIGHT.clear()
    result.light_reuse = cs.info.get("light_reuse")
    result.stats = stats
    result.lightmap_bytes = cs.lightmap_bytes()
    result.environment = cs.info.get("environment")
    result.seconds["photon_pass"] = time.perf_counter() - t0
    solids = {name: csg_atlas.solid_leaves(cs, job, name) for name in job.csg}
    ids = [cs.instance_lightmaps[i][0] for n, i in job.targets.items() if n not in job.csg]
    leaves = [(job.targets[n], d) for n, ls in solids.items() for d in ls]
    result.gathered = job.settings.bake_gathers
    cs.info.pop("irradiance_cache", None)
    # --time / Bake Time counts the export too, which prepare_bake did
    deadline = (t0 + job.settings.bake_time - result.seconds.get("export", 0.0)
                if job.settings.bake_time > 0 else None)
    ao = job.settings.bake_pass in ("AO", "SHADOWMASK")      # occlusion: no light
    masks = None
    with kernel_watch.watching(on_compile):
        if job.settings.bake_pass == "SHADOWMASK":
            phase("shadowmask", ", ".join(job.mask_lights[0]))
            masks, seconds = session.bake_shadowmask(cs, ids, job.settings, job.mask_lights[1],
                                                     samples=job.settings.pass_rays, should_stop=should_stop,
                                                     csg_leaves=leaves)
            result.seconds.update(seconds)
            result.mask_lights = list(job.mask_lights[0])
        elif ao:
            phase("ao", f"{len(ids) + len(solids):,} objects")
            result.seconds.update(session.bake_ao(cs, ids, job.settings, job.settings.ao_distance,
                                                  rays=job.settings.pass_rays, should_stop=should_stop,
                                                  csg_leaves=leaves))
        else:
            result.seconds.update(session.bake_texels(
                cs, ids, leaves, job.settings, direct=job.direct, deadline=deadline, should_stop=should_stop,
                directional=bool(job.settings.directional),
                phase=lambda name, n: phase(name, f"{n:,} texels" if name != "kernels" else
                                            f"compiled in a second process, {n:.0f} s (first run)")))
    if job.settings.texel_validity and masks is None:
        phase("validity", f"{len(ids):,} objects")
        result.validity, result.validity_maps, result.seconds["validity"] = _fill_invalid(cs, job, ids, leaves,
                                                                                          solids)
    if getattr(cs, "bake_error", None) is not None:
        result.error = _error_stats(cs, job, solids)
    result.irradiance_cache = cs.info.get("irradiance_cache")
    result.cluster = cs.info.get("cluster")
    result.bake_pass = job.settings.bake_pass
    if job.settings.bake_pass in ("AO", "SHADOWMASK"):
        result.pass_rays = int(job.settings.pass_rays)
    if ao:
        pass                        # occlusion needs no light
    elif cs.lights.total_power <= 0.0:
        result.warnings.append("no photons were traced (no lights): lightmaps are black")
    elif stats.photons == 0 and job.settings.bake_pass != "DIRECT":
        result.warnings.append("no photons were traced (zero photons): lightmaps hold "
                               + ("direct light only" if job.direct else "no light"))
    t1 = time.perf_counter()
    phase("images", f"{len(job.targets):,} objects")
    for name, i in job.targets.items():
        if name in job.csg and masks is not None:
            bm = _solid_mask(cs, job, name, solids[name], masks)
            if bm is not None:
                result.maps[name] = bm
            continue
        if name in job.csg:
            bm = csg_atlas.atlas(cs, job, name, solids[name])
            if bm is not None:
                result.maps[name] = bm
            continue
        lm_id = cs.instance_lightmaps[i][0]
        if masks is not None:
            result.maps[name] = BakedMap(name, images.texel_rgba(cs.lightmaps, lm_id, masks), lm_id)
            continue
        result.maps[name] = BakedMap(name, images.lightmap_rgba(cs.lightmaps, lm_id, cs.spectral), lm_id)
        if job.settings.spectral_exr:
            result.spectral_maps[name] = images.lightmap_bands(cs.lightmaps, lm_id)
    if job.settings.spectral_exr and job.csg:
        result.warnings.append(f"spectral EXR files are not written for CSG solids ({', '.join(sorted(job.csg))}); "
                               "their RGB lightmaps are")
    if job.settings.bake_error_images and getattr(cs, "bake_error", None) is not None:
        result.error_maps = _error_maps(cs, job, solids)
    if job.settings.directional and not ao:
        t_dir = time.perf_counter()
        _direction_maps(cs, job, result, solids)
        result.seconds["direction"] = time.perf_counter() - t_dir
    result.seconds["extract"] = time.perf_counter() - t1
    if job.settings.denoise:
        phase("denoise", f"{len(result.maps):,} images")
        t2 = time.perf_counter()
        for bm in result.maps.values():
            _denoise_map(cs, bm)
        result.seconds["denoise"] = time.perf_counter() - t2
    if job.settings.stitch_seams:
        phase("seams", f"{len(result.maps):,} images")
        t3 = time.perf_counter()
        result.seams = _stitch_seams(cs, job, result)
        result.seconds["seams"] = time.perf_counter() - t3
    job.cs = cs
    return job


def _solid_mask(cs, job, name, leaves, masks):
    """A CSG solid's shadowmask in its atlas layout: lights 1 to 3 in RGB and the fourth
    in A, as a mesh's (its A holds no coverage); masks: every lightmap row's four."""
    lm = cs.lightmaps
    bm = csg_atlas.atlas(cs, job, name, leaves, lightmaps=lm._replace(irradiance=math.pi * masks[:, :3]))
    if bm is not None:
        fourth = np.repeat(math.pi * masks[:, 3:4], 3, axis=1)
        bm.rgba[..., 3] = csg_atlas.atlas(cs, job, name, leaves, lightmaps=lm._replace(irradiance=fourth)).rgba[..., 0]
    return bm


def _direction_maps(cs, job, result, solids):
    """A directional bake's images per baked object (engine/transport/directional_lightmap.py):
    its direction image (DOMINANT) or its three L1 images (SH) into `result`, in the
    layout of its lightmap (a CSG solid's: its atlas, `solids` its leaves)."""
    from ..engine.transport import directional_lightmap, open_area
    lm = cs.lightmaps
    E = open_area.baked(lm, np.arange(lm.area.shape[0]))
    sh = job.settings.directional == "SH"
    if sh:
        L1 = directional_lightmap.l1_channels(cs, E)
        layers = [(result.l1_maps[a], spectrum.as_rgb(L1[:, :, i], cs.spectral) / math.pi)
                  for i, a in enumerate("xyz")]
    else:
        layers = [(result.direction_maps, directional_lightmap.direction_channels(cs, E)[:, :3])]
    # per layer, its rows as a mesh image's (A = coverage) and as a solid's atlas takes
    # them (its lightmap's layout: E/pi, A its visible share)
    layers = [(maps, np.concatenate([rgb, lm.coverage[:, None]], axis=1), lm._replace(irradiance=math.pi * rgb))
              for maps, rgb in layers]
    moments = getattr(cs, "bake_moments", None)
    nbytes = 0
    for name, bm in result.maps.items():
        for maps, rgba, carrier in layers:
            if name in job.csg:
                out = csg_atlas.atlas(cs, job, name, solids[name], lightmaps=carrier)
            else:
                out = BakedMap(name, images.texel_rgba(lm, bm.lightmap_id, rgba), bm.lightmap_id)
            if out is not None:
                maps[name] = out
                nbytes += out.rgba.nbytes
    result.directional = {"mode": job.settings.directional.lower(), "image_bytes": int(nbytes),
                          "moment_bytes": int(sum(a.nbytes for a in moments)) if moments else 0}


def _stitch_seams(cs, job, result):
    """Seam stitching over the baked mesh and primitive lightmaps, all together (seams between
    objects too), and over their direction images if the bake is directional, which
    are read across the seams as the lightmaps are: engine/transport/seam_stitch.py
    -> BakeResult.seams."""
    from ..engine.transport import seam_stitch
    lm = cs.lightmaps
    by_id = {bm.lightmap_id: bm for name, bm in result.maps.items() if name not in job.csg and bm.tiles is None}
    charts = seam_stitch.mesh_charts(cs, sorted(by_id)) + seam_stitch.primitive_charts(cs, sorted(by_id))
    images = [by_id[lid].rgba for lid, *_ in charts]
    seams = seam_stitch.find_seams(charts, {k: im.shape[:2] for k, im in enumerate(images)})
    holds = [lm.coverage[lightmap.texel_slice(lm, lid)].reshape(im.shape[:2]) for (lid, *_), im in
             zip(charts, images)]
    channels = (0, 1, 2, 3) if job.settings.bake_pass == "SHADOWMASK" else (0, 1, 2)
    before = seam_stitch.seam_jump(seams, images, channels)
    changed = seam_stitch.stitch(seams, images, holds, channels)
    after = seam_stitch.seam_jump(seams, images, channels)
    report = {"edges": seams.edges, "samples": int(seams.ia.size), "jump_before": before[0],
              "jump_before_p95": before[1], "jump_after": after[0], "jump_after_p95": after[1],
              "texels_changed": changed}
    for key, maps in [("direction", result.direction_maps)] + [("l1" + a, result.l1_maps[a]) for a in "xyz"]:
        by_lid = {bm.lightmap_id: bm.rgba for bm in maps.values()}
        if by_lid and charts:
            images = [by_lid[lid] for lid, *_ in charts]
            report[key + "_jump_before"] = seam_stitch.seam_jump(seams, images)[0]
            seam_stitch.stitch(seams, images, holds)
            report[key + "_jump_after"] = seam_stitch.seam_jump(seams, images)[0]
    return report


def _denoise_map(cs, bm):
    """Denoises a BakedMap in place, one face tile / CSG leaf block at a time so that
    no light crosses into an unrelated part of the image."""
    if bm.tiles is None:
        bm.rgba = session.denoise_baked(bm.rgba, tiles=int(cs.lightmaps.tiles[bm.lightmap_id]))
        return
    for x, y, w, h in bm.tiles.values():    # a leaf block: its primitive's square face tiles
        bm.rgba[y:y + h, x:x + w] = session.denoise_baked(bm.rgba[y:y + h, x:x + w],
                                                          tiles=max(w // max(h, 1), 1))


def commit_bake(job, *, overwrite=False, save_dir=None, pack=False, hook_materials=False):
    """Main thread: writes the computed maps to images (and files, and material hooks)."""
    import bpy
    result = job.result
    t0 = time.perf_counter()
    if result.maps:
        # A folder that cannot take the files fails here, before any image is touched.
        images.check_output(save_dir, pack)
    for name, bm in result.maps.items():
        ob = bpy.data.objects[name]
        img = images.target_image(ob, bm.width, bm.height, overwrite, result.warnings)
        images.write_pixels(img, bm.rgba)
        result.images[name] = img.name
        result.paths[name] = images.store(img, name, save_dir=save_dir, pack=pack)
        if bm.tiles is not None:
            csg_atlas.place_leaf_uvs(name, bm, result.warnings)
        elif name in job.primitives:
            csg_atlas.place_leaf_uvs(name, BakedMap(name, bm.rgba, bm.lightmap_id, {name: None}),
                                     result.warnings)
    for maps, names, paths, kind, suffix in (
            (result.error_maps, result.error_images, result.error_paths, images.ERROR, images.ERROR_FILE_SUFFIX),
            (result.validity_maps, result.validity_images, result.validity_paths, images.VALIDITY,
             images.VALIDITY_FILE_SUFFIX),
            (result.direction_maps, result.direction_images, result.direction_paths, images.DIRECTION,
             images.DIRECTION_FILE_SUFFIX)) + tuple(
            (result.l1_maps[a], result.l1_images[a], result.l1_paths[a], images.L1[a], images.L1_FILE_SUFFIX[a])
            for a in "xyz"):
        for name, bm in maps.items():
            if name not in result.maps:
                continue                      # deleted during the bake (the operator dropped its map)
            img = images.target_image(bpy.data.objects[name], bm.width, bm.height, overwrite,
                                      result.warnings, kind=kind)
            images.write_pixels(img, bm.rgba)
            names[name] = img.name
            paths[name] = images.store(img, name + suffix, save_dir=save_dir, pack=pack)
    for name, values in result.spectral_maps.items():
        if not save_dir:
            result.warnings.append("spectral EXR files are written only to a folder (the CLI's --out)")
            break
        path = os.path.join(save_dir, images.file_name(name) + "_spectral.exr")
        spectral_exr.write(path, values, job.cs.spectral)
        result.spectral_paths[name] = path
    if result.maps and images.in_memory_only(save_dir, pack):
        result.warnings.append("the .blend is not saved yet: the lightmap images live only in memory "
                               "(save the .blend and bake again, or pack them)")
    if hook_materials and result.maps:
        baked = set(result.maps)
        for name, bm in result.maps.items():
            ob = bpy.data.objects[name]
            parts = sorted(bm.tiles) if bm.tiles else job.booleans.get(name, ())
            direction = result.direction_images.get(name)
            l1 = [result.l1_images[a].get(name) for a in "xyz"]
            result.hooked += hooks.add_lightmap_hook(ob, bpy.data.images[result.images[name]],
                                               baked_objects=baked, warnings=result.warnings,
                                               parts=parts, materials=csg_atlas.solid_materials(ob, parts),
                                               direction=bpy.data.images[direction] if direction else None,
                                               l1=[bpy.data.images[i] for i in l1] if all(l1) else None)
    result.seconds["bake"] = result.seconds.get("extract", 0.0) + time.perf_counter() - t0
    result.seconds["total"] = time.perf_counter() - job.t_start
    return result


def bake_objects(context_or_depsgraph, objects, *, photons=None, seed=None, resolution=None,
                 indirect_only=False, progress=None, overwrite=False, save_dir=None, pack=False,
                 hook_materials=False, denoise=None, indirect=None, bake_gather_rays=None,
                 bake_target_error=None, bake_time=None, error_images=None, irradiance_cache=None,
                 gather_lights=None, spectral_exr=None, bake_pass=None, ao_distance=None,
                 shadowmask_lights=None, texel_validity=None, pass_rays=None, keep_light=None,
                 light_cache=None, lay_out=(), stitch_seams=None, direct_samples=None, directional=None):
    """Bakes the lightmaps of mesh `objects` to images "<object>_Lightmap" -> BakeResult.

    One photon pass for all of them; per texel the direct light (unless
    `indirect_only`) and the indirect light, by final gather over the photon
    lightmaps or from the texel's own photons (`indirect` "GATHER" / "LOOKUP",
    `bake_gather_rays` per texel, more where a texel's error is above
    `bake_target_error` or in the time left of `bake_time` seconds; None: the
    scene's settings; `irradiance_cache` gathers mesh texels through the sparse
    irradiance cache (None: the scene's Bake Irradiance Cache); `gather_lights`
    samples point, spot and sun lights where gather rays land (None: the scene's
    Bake Gather Lights); `error_images` also writes each texel's estimated
    relative error as an image, BakeResult.error_maps; `spectral_exr`, with a
    spectral bake and `save_dir`, also writes every band to
    "<save_dir>/<object>_spectral.exr", bake/spectral_exr.py). `resolution` forces
    R x R texels per object; otherwise the object's own setting or the scene's
    texel density decides. `bake_pass` (BAKE_PASSES, None: COMBINED) bakes all
    light, direct or indirect light alone, or ambient occlusion within
    `ao_distance` metres (the image holds AO itself), or a shadowmask of up to
    four lights (`shadowmask_lights`, names comma-separated; the image's R, G,
    B, A hold each one's visibility), each from 16 points x `pass_rays` rays per
    texel (None: 16). Exact CSG solids are skipped by AO and shadowmasks.
    `texel_validity` fills texels that lie inside geometry (most of their rays
    meet back faces) from their neighbours, counts them in BakeResult.validity
    and shows them in BakeResult.validity_maps (mesh and primitive lightmaps;
    not shadowmasks).
    `keep_light` (None: the scene's Keep Bake Light) keeps the photon pass in
    memory, and a later bake of the unchanged scene reuses it (BAKE_LIGHT);
    `light_cache`, a folder, does the same across processes: a pass saved there
    for this scene is loaded, and one traced is saved. BakeResult.light_reuse
    says which, or why not. `lay_out`: see prepare_bake. `stitch_seams` makes
    texels that meet across UV seams and edges objects share agree where they
    meet (engine/transport/seam_stitch.py; mesh lightmaps), and reports the jump
    along the seams before and after in BakeResult.seams. `direct_samples`: light
    samples per texel for the direct light (None: the scene's Bake Direct
    Samples). `directional` also writes each object's direction image
    (BakeResult.direction_maps; engine/transport/directional_lightmap.py), which
    a material hook uses to light normal maps. `denoise` (None: the scene's setting) runs OIDN over
    each map (engine/transport/denoise.py). `progress(done, total)`
    may return False to cancel: Cancelled is raised before any image changes.
    See the module docstring for image naming, overwriting and saving.
    """
    job = prepare_bake(context_or_depsgraph, objects, photons=photons, seed=seed,
                       resolution=resolution, indirect_only=indirect_only, denoise=denoise,
                       indirect=indirect, bake_gather_rays=bake_gather_rays,
                       bake_target_error=bake_target_error, bake_time=bake_time,
                       error_images=error_images, irradiance_cache=irradiance_cache, gather_lights=gather_lights,
                       spectral_exr=spectral_exr, bake_pass=bake_pass, ao_distance=ao_distance,
                       shadowmask_lights=shadowmask_lights, texel_validity=texel_validity,
                       pass_rays=pass_rays, keep_light=keep_light, light_cache=light_cache, lay_out=lay_out,
                       stitch_seams=stitch_seams, direct_samples=direct_samples, directional=directional)
    try:
        compute_bake(job, progress)
    except BaseException:
        rollback_bake(job)
        raise
    return commit_bake(job, overwrite=overwrite, save_dir=save_dir, pack=pack,
                       hook_materials=hook_materials)

