"""Baking photon lightmaps to image textures (and Blender's own Bake button).

One photon pass lights the whole scene; each baked mesh object's lightmap is
then written to a float RGBA image:

* RGB = E / pi, the irradiance E of the texel divided by pi: the radiance a
  white Lambertian surface would reflect there. This is what Cycles' Diffuse
  bake gives with Direct + Indirect and without Color.
  E = E_direct + E_indirect (thesis 3.5.2 / 8.2): photons are recorded only
  after their first bounce (indirect), and the direct part is gathered per
  texel by sampling the lights with shadow rays, averaged over the texel's
  surface (engine/texel_gather.py), which takes the photon noise out of the
  brightest component. `indirect_only` skips the direct gather.
* A = the texel's UV coverage (0 where no UV triangle touches it). RGB next to
  the charts holds the lightmap's dilated values, so texture filtering at
  chart borders reads sensible colours.

Texel (x, y) of a lightmap is image pixel (x, y): both count rows bottom-up,
like UV v. Images are called "<object>_Lightmap" and use the mesh's
`Lightmap` UV layer (uv_layers.py makes one where missing).

Image policy. An image we made carries the custom property
``photon_lightmaps_object`` and is updated in place by the next bake. An
image of the same name that we did not make belongs to the user: with
``overwrite`` it is replaced (its users are remapped to the new image);
otherwise the bake writes a new image with a unique name (".001", ...) and
says so in `BakeResult.warnings`. Nothing is written until every lightmap
has been computed, so a cancelled or failed bake leaves all images as they
were; the Lightmap UV layers the export needs are made first and put back as
they were (rollback_bake) when the bake fails or is cancelled. The output
folder is checked before the first image is written. A user error (bad scene
data) is an engine SceneError naming the object, e.g. a NaN vertex.

Files. `save_dir` saves "<dir>/<object>.exr"; otherwise an image is saved to
"//lightmaps/<object>.exr" next to a saved .blend, or packed with `pack`.
OpenEXR, 32-bit float, ZIP, RGBA, alpha stored as is (images use the
"Channel Packed" alpha mode: coverage is data, not transparency).

Material hook (`hook_materials`): a node group "Photon Lightmap" is added to
each material of a baked object, with its own Material Output for EEVEE only,
so EEVEE and Material Preview show baked light while Cycles keeps rendering
the material as it was. Every node we add is named "Photon Lightmap ..." and
tagged; `remove_lightmap_hook` deletes exactly those nodes.

Exact primitives and CSG solids. A tagged Photon CSG primitive is baked from its
analytic charts: F faces give F tiles of R x R side by side, which is the layout
of its display mesh's generated `Lightmap` layer. A CSG solid (an object with
Boolean modifiers, exported as an exact CSG tree) gets ONE image,
"<base object>_Lightmap", in which the lightmap of every primitive leaf (F·R x R
texels) is a block of one atlas (engine/csg_bake.py: shelf packing, square
texels, a 1-texel gutter repeating each block's border, alpha 0). A texel's
alpha is the visible fraction of its surface (0 where the CSG operation removed
all of it; RGB then holds the dilated neighbours). The direct light of leaf
texels is gathered over their visible part only, with the solid's outward
normal (inverted on subtracted operands). After the image is written, each
leaf's `Lightmap` layer is moved into its block, (U, V) -> (x0 + sx U, y0 + sy V),
and the rect is kept in the mesh property `uv_layers.TILE_PROP`; Blender's
Boolean result carries the operands' UVs over, so the image shows on the
evaluated mesh in EEVEE, and the hook goes into the base's materials and those
the result takes from its operands. Re-baking first maps the layer back with
the stored rect, so it never shrinks twice (an unchanged rect writes nothing);
a stand-alone primitive whose layer was moved gets the chart layout back.
A layer is only moved while it still *is* the generated layout (every vertex on
the chart point of its UV, uv_layers.primitive_chart_uvs): an operand whose layer
the user made or edited, a plain mesh operand, a mesh shared with other objects
or an operand used twice is left out of the solid's image with a warning naming
it, and its UVs are never touched. Operands passed as bake targets are skipped
(they are part of their solid's image).

Split texels. Where a CSG boundary cuts a texel into several visible regions,
the engine keeps one sub-texel per region (engine/csg.py). An image texel holds
one value, so it shows the region with the largest visible area (if that
region holds no measurement, the texel's own dilated value). This is not enough
where the other regions matter: thin slivers or slots narrower than a texel,
and walls meeting at a cut, show the dominant side's light on both sides
(light bleeds across the cut, e.g. a lit rim next to a dark groove). Bake at a
higher resolution (Object > Photon Lightmaps > resolution, or the scene's texel
density) until the features span several texels.

`BakeMixin` gives the render engine Blender's bake API (see BakeMixin.bake).
`bake_main` is the `python -m photon_lightmaps bake` command.
"""
import hashlib
import math
import os
import re
import tempfile
import time
from dataclasses import dataclass, field

import numpy as np

from .engine import lightmap as LM  # first: the engine package picks numba's cache folder
from numba import njit, prange  # noqa: E402
from .engine.photon_tracer import Cancelled
from .engine.scene import SceneError
from .messages import describe, is_user_error

IMAGE_SUFFIX = "_Lightmap"
OWNER_PROP = "photon_lightmaps_object"
HOOK_PROP = "photon_lightmaps_hook"
HOOK_GROUP = "Photon Lightmap"
HOOK_PREFIX = "Photon Lightmap"
LIGHTMAP_DIR = "lightmaps"

# RenderEngine.bake pass_filter bits (BakeSettings.pass_filter enum values, read from bpy).
FILTER_EMIT = 2
FILTER_DIFFUSE = 4
FILTER_GLOSSY = 8
FILTER_TRANSMISSION = 16
FILTER_DIRECT = 64
FILTER_INDIRECT = 128
FILTER_COLOR = 256

_DEFAULTS = dict(photons=1_000_000, max_bounces=8, seed=0)
# Light-sampled points per texel for the direct part; one unstratified light
# sample per point, so this sets the direct term's noise (~1/sqrt(n)).
DIRECT_SAMPLES = 64


# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------

@dataclass
class BakedMap:
    """One object's lightmap as an image: rgba float32 (height, width, 4), rows bottom-up."""
    object_name: str
    rgba: np.ndarray
    lightmap_id: int
    # CSG solids: leaf object name -> (x, y, width, height) of its block in texels
    tiles: dict = None

    @property
    def width(self):
        return int(self.rgba.shape[1])

    @property
    def height(self):
        return int(self.rgba.shape[0])

    def mean(self):
        """Coverage-weighted mean RGB over the texels a UV triangle touches."""
        a = self.rgba[..., 3].astype(np.float64)
        if a.sum() <= 0:
            return [0.0, 0.0, 0.0]
        return [float((self.rgba[..., c] * a).sum() / a.sum()) for c in range(3)]


@dataclass
class BakeResult:
    maps: dict = field(default_factory=dict)      # object name -> BakedMap
    images: dict = field(default_factory=dict)    # object name -> bpy image name
    paths: dict = field(default_factory=dict)     # object name -> saved file (None: unsaved/packed)
    skipped: dict = field(default_factory=dict)   # object name -> why it was not baked
    hooked: list = field(default_factory=list)    # materials given a lightmap hook
    warnings: list = field(default_factory=list)
    stats: object = None                          # PhotonStats of the photon pass
    seconds: dict = field(default_factory=dict)   # export, photon_pass, bake, total
    lightmap_bytes: int = 0
    uv_layers: dict = field(default_factory=dict)  # mesh name -> uv_layers.ensure_lightmap_uv status
    # CSG solid name -> {"leaves": baked leaf names, "skipped": {leaf: why}, "split_texels",
    # "boundary_texels", "atlas": (w, h)}
    csg: dict = field(default_factory=dict)


# --------------------------------------------------------------------------------------
# Lightmap -> pixels
# --------------------------------------------------------------------------------------

@njit(cache=True, parallel=True)
def _sample_bilinear(lm, lm_id, s, t, out):
    for i in prange(s.shape[0]):
        LM.lookup_bilinear(lm, lm_id, 0, s[i], t[i], out[i])


def lightmap_rgba(lm, lm_id):
    """Lightmap `lm_id` as float32 (height, width, 4): RGB = E/pi, A = coverage."""
    sl = LM.texel_slice(lm, lm_id)
    w, h = int(lm.width[lm_id]), int(lm.height[lm_id])
    e = lm.irradiance[sl]
    rgba = np.zeros((h * w, 4), np.float32)
    nb = e.shape[1]
    rgba[:, :3] = (e if nb == 3 else np.repeat(e.mean(axis=1, keepdims=True), 3, axis=1)) / math.pi
    rgba[:, 3] = lm.coverage[sl]
    return rgba.reshape(h, w, 4)


# --------------------------------------------------------------------------------------
# Shared helpers
# --------------------------------------------------------------------------------------

def _settings(bscene):
    s = getattr(bscene, "photon_lightmaps", None)
    if s is None:
        return dict(_DEFAULTS)
    return dict(photons=int(s.photons), max_bounces=int(s.max_bounces), seed=int(s.seed))


def _original(ob):
    return getattr(ob, "original", None) or ob


def _is_excluded(ob):
    props = getattr(ob, "photon_lightmaps", None)
    return bool(props is not None and props.exclude)


def _depsgraph(context_or_depsgraph):
    import bpy
    if isinstance(context_or_depsgraph, bpy.types.Depsgraph):
        return context_or_depsgraph
    return context_or_depsgraph.evaluated_depsgraph_get()


def _world_area(ob):
    """Surface area of a mesh object in world units (as the lightmap allocator measures it)."""
    from .uv_layers import mesh_triangles
    v, tv, _, _ = mesh_triangles(ob.data)
    if tv.shape[0] == 0:
        return 0.0
    M = np.array(ob.matrix_world, np.float64)[:3, :3]
    return float(LM.triangle_world_areas(v[tv], M).sum())


def layout_resolution(ob, texel_density, resolution=None):
    """Lightmap texels per side the engine will give mesh object `ob` (what its UV layout is for)."""
    if resolution:
        return int(resolution)
    props = getattr(ob, "photon_lightmaps", None)
    if props is not None and int(props.lightmap_resolution) > 0:
        return int(props.lightmap_resolution)
    return LM.resolution_for(_world_area(ob), texel_density)


def _photon_pass(scene, settings, progress):
    """Compiled scene with its lightmaps holding the indirect light (photons after the first bounce)."""
    from .engine.compile import compile_scene
    from .engine.photon_tracer import trace_photons
    cs = compile_scene(scene)
    stats = trace_photons(cs, settings["photons"], seed=settings["seed"],
                          max_bounces=settings["max_bounces"], record_direct=False,
                          progress=progress)
    return cs, stats


def _add_direct(cs, lightmaps, settings, lightmap_ids=None):
    """Gathers direct light into the lightmaps (a cs.lightmaps or a copy of it); returns seconds."""
    from .engine import texel_gather as TG
    t0 = time.perf_counter()
    ids, E = TG.direct_texel_irradiance(cs, lightmap_ids, samples_per_texel=DIRECT_SAMPLES,
                                        seed=settings["seed"])
    TG.add_direct(lightmaps, ids, E)
    return time.perf_counter() - t0


def _file_name(name):
    # Object names may hold path separators or characters file systems refuse.
    return re.sub(r'[\\/:*?"<>|\x00-\x1f]', "_", name).strip() or "object"


# --------------------------------------------------------------------------------------
# bake_objects: prepare (main thread) -> compute (any thread) -> commit (main thread)
# --------------------------------------------------------------------------------------

@dataclass
class BakeJob:
    """A bake split in three, so an operator can run the photon pass off the UI thread."""
    scene: object                 # engine Scene (plain data)
    export_map: object
    targets: dict                 # object name -> engine instance id
    settings: dict
    direct: bool                  # gather direct light (False: --indirect-only)
    result: BakeResult
    t_start: float
    cs: object = None
    # CSG solid name -> {leaf object name: None (bake it) or why it is skipped}
    csg: dict = field(default_factory=dict)
    primitives: set = field(default_factory=set)   # stand-alone tagged primitives among targets
    # mesh name -> its Lightmap layer state before prepare_bake (rollback_bake puts it back)
    uv_undo: dict = field(default_factory=dict)


def _covering_ol(router, ob):
    """Name of the (non-backup) OL empty that takes this object's hits, else None."""
    key = router.route(ob) if router else None
    if key is None:
        return None
    empty = router.colls[key][1]
    return None if empty.photon_lightmaps.ol_backup else empty.name


def prepare_bake(context_or_depsgraph, objects, *, photons, seed, resolution=None,
                 indirect_only=False):
    """Main thread: Lightmap UV layers for the objects, then the scene export.

    On failure the UV layers are as they were; after it, rollback_bake(job) puts them
    back (a failed or cancelled compute or commit)."""
    from .export import _OLRouter

    t0 = time.perf_counter()
    result = BakeResult()
    depsgraph = _depsgraph(context_or_depsgraph)
    bscene = depsgraph.scene
    props = getattr(bscene, "photon_lightmaps", None)
    density = float(props.texel_density) if props is not None else 16.0
    if resolution is not None and int(resolution) < 1:
        raise SceneError(f"resolution: must be a positive number of texels, got {resolution}")
    wanted = []
    seen = set()
    operands = _csg_operands(depsgraph)
    ol_router = _OLRouter(bscene, lambda level, msg: None)
    for ob in objects:
        ob = _original(ob)
        if ob.name in seen:
            continue
        seen.add(ob.name)
        if ob.type != "MESH":
            result.skipped[ob.name] = f"a {ob.type.lower()}, not a mesh"
        elif _is_excluded(ob):
            result.skipped[ob.name] = "excluded from lightmaps (Object > Photon Lightmaps)"
        elif ob.name in operands:
            result.skipped[ob.name] = (f"a Boolean operand of '{operands[ob.name]}': it is baked into "
                                       "that solid's lightmap")
        elif _covering_ol(ol_router, ob) is not None:
            # no Lightmap UV layer either: its light lives in the OL, indexed by normal
            result.skipped[ob.name] = (f"covered by orientation lightmap '{_covering_ol(ol_router, ob)}': "
                                       "use Bake Orientation Lightmaps")
        else:
            wanted.append(ob)
    for ob in wanted:
        _check_finite(ob)
    uv_undo = _uv_snapshot({ob.data.name: ob.data for ob in wanted}.values())
    try:
        job = _prepare_export(context_or_depsgraph, depsgraph, wanted, result, density, resolution)
    except BaseException:
        _uv_restore(uv_undo)
        raise
    job.uv_undo = uv_undo
    job.settings.update(photons=int(photons), seed=int(seed))
    job.direct, job.t_start = not indirect_only, t0
    result.seconds["export"] = time.perf_counter() - t0
    return job


def _prepare_export(context_or_depsgraph, depsgraph, wanted, result, density, resolution):
    """prepare_bake after choosing the objects: their Lightmap UV layers, then the export."""
    from . import uv_layers
    from .export import export_scene
    bscene = depsgraph.scene
    from .engine.uv_atlas import UnwrapError
    changed = False
    for ob in list(wanted):
        try:
            status = uv_layers.ensure_lightmap_uv(ob, resolution=layout_resolution(ob, density, resolution))
        except UnwrapError as exc:
            # xatlas failed (or crashed in its worker) on this mesh alone: bake the others
            wanted.remove(ob)
            result.skipped[ob.name] = (f"no Lightmap UV layer: {exc.reason}; add a UV layer named "
                                       f"'{uv_layers.LAYER_NAME}' (e.g. UV > Lightmap Pack) and bake again")
            result.warnings.append(f"object '{ob.name}': {result.skipped[ob.name]}")
            continue
        except (ValueError, RuntimeError) as exc:
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
    scene, emap = export_scene(depsgraph, report=lambda level, msg: None)
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
            csg[ob.name] = _csg_leaf_plan(scene.prototypes[emap.instances[i].prototype], ob.name,
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
    # Only baked objects record photons: the others' lightmaps would cost memory and
    # time, and recording never changes where photons go.
    for i, inst in enumerate(scene.instances):
        inst.lightmap = i in targets.values()
        if inst.lightmap and resolution:
            inst.lightmap_resolution = int(resolution)
    return BakeJob(scene, emap, targets, _settings(bscene), True, result, 0.0, csg=csg,
                   primitives=primitives)


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
    from . import uv_layers
    return uv_layers.HASH_PROP, uv_layers.DIGEST_PROP, uv_layers.MIN_RES_PROP


def _uv_snapshot(meshes):
    """What uv_layers.ensure_lightmap_uv may change on each mesh, to put back on failure."""
    from . import uv_layers
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
    from . import uv_layers
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


def _csg_operands(depsgraph):
    """{operand object name: solid it cuts} over the scene's Boolean stacks (as export.py finds them)."""
    from . import csg_export
    out = {}
    for ob in depsgraph.objects:
        ob = _original(ob)
        if ob.type == "MESH" and not ob.hide_render and csg_export.boolean_modifiers(ob):
            csg_export.collect_operands(ob, out)
    return {o.name: solid for o, solid in out.items()}


def _csg_leaf_plan(proto, solid, others, warnings):
    """{leaf object name: None (baked into the solid's atlas) or why not} for one exported solid.

    A leaf is baked when it is a tagged Photon CSG primitive whose `Lightmap` layer is
    still the generated chart layout: only then can that layer be moved into the
    leaf's atlas block without touching anything of the user's.
    """
    import bpy

    from . import csg_export, uv_layers
    from .engine.scene import Primitive
    plan = {}
    taken = {leaf for p in others.values() for leaf, why in p.items() if why is None}
    for leaf in csg_export.tree_leaves(proto.csg[0]):
        name = leaf.name
        ob = bpy.data.objects.get(name)
        why = None
        if name in plan or name in taken:
            warnings.append(f"CSG solid '{solid}': operand '{name}' is used more than once as a Boolean "
                            f"operand; its '{uv_layers.LAYER_NAME}' layer can point at one atlas block "
                            "only, so only its first use is baked")
            plan.setdefault(name, "used more than once")
            continue
        elif ob is None or not isinstance(leaf, Primitive):
            why = (f"'{name}' is a mesh operand, not a Photon CSG primitive: its own "
                   f"'{uv_layers.LAYER_NAME}' UVs cannot share the solid's atlas without being rewritten")
        elif sum(1 for o in bpy.data.objects if o.data == ob.data) > 1:
            why = (f"'{name}' shares its mesh '{ob.data.name}' with other objects "
                   "(Object > Relations > Make Single User to bake it)")
        elif ob.library is not None or ob.data.library is not None:
            why = f"'{name}' is linked from a library"
        else:
            why = uv_layers.primitive_chart_uvs(ob)[2]
        if why is not None:
            warnings.append(f"CSG solid '{solid}': operand {why}; its surface is left out of the "
                            "solid's lightmap")
        plan[name] = why
    return plan


def compute_bake(job, progress=None):
    """Any thread: photon pass and per-object RGBA arrays. Raises Cancelled."""
    result = job.result
    t0 = time.perf_counter()
    if not job.targets:
        result.seconds["photon_pass"] = 0.0
        return job
    cs, stats = _photon_pass(job.scene, job.settings, progress)
    result.stats = stats
    result.lightmap_bytes = cs.lightmap_bytes()
    result.seconds["photon_pass"] = time.perf_counter() - t0
    solids = {name: _solid_leaves(cs, job, name) for name in job.csg}
    if job.direct:
        ids = [cs.instance_lightmaps[i][0] for n, i in job.targets.items() if n not in job.csg]
        result.seconds["direct"] = _add_direct(cs, cs.lightmaps, job.settings, ids) if ids else 0.0
        leaves = [(job.targets[n], d) for n, ls in solids.items() for d in ls]
        if leaves:
            result.seconds["direct"] += _add_direct_csg(cs, leaves, job.settings)
    if cs.lights.total_power <= 0.0:
        result.warnings.append("no photons were traced (no lights): lightmaps are black")
    elif stats.photons == 0:
        result.warnings.append("no photons were traced (zero photons): lightmaps hold "
                               + ("direct light only" if job.direct else "no light"))
    t1 = time.perf_counter()
    for name, i in job.targets.items():
        if name in job.csg:
            bm = _csg_atlas(cs, job, name, solids[name])
            if bm is not None:
                result.maps[name] = bm
            continue
        lm_id = cs.instance_lightmaps[i][0]
        result.maps[name] = BakedMap(name, lightmap_rgba(cs.lightmaps, lm_id), lm_id)
    result.seconds["extract"] = time.perf_counter() - t1
    job.cs = cs
    return job


def _solid_leaves(cs, job, name):
    """The leaves of CSG solid `name` that get a block in its atlas (engine/csg_bake.solid_leaves entries)."""
    from .engine import csg_bake
    plan = job.csg[name]
    out, seen = [], set()
    for d in csg_bake.solid_leaves(cs, job.targets[name]):
        # a leaf used twice gets two engine lightmaps, but one UV layer: the first one
        if d["kind"] == "prim" and plan.get(d["name"], "unknown") is None and d["name"] not in seen:
            seen.add(d["name"])
            out.append(d)
    return out


def _add_direct_csg(cs, leaves, settings):
    """Direct light of CSG leaf texels over their visible part (engine/csg_bake.py); -> seconds."""
    from .engine import csg_bake
    from .engine import texel_gather as TG
    t0 = time.perf_counter()
    ids, E = csg_bake.direct_csg_texels(cs, leaves, DIRECT_SAMPLES, seed=settings["seed"])
    TG.add_direct(cs.lightmaps, ids, E)
    return time.perf_counter() - t0


def _csg_atlas(cs, job, name, leaves):
    """One image for CSG solid `name`: its leaves' lightmaps packed into one atlas (or None)."""
    from .engine import csg_bake
    lm = cs.lightmaps
    inst = job.targets[name]
    skipped = {k: v for k, v in job.csg[name].items() if v is not None}
    info = dict(leaves=[d["name"] for d in leaves], skipped=skipped, split_texels=0,
                boundary_texels=0, atlas=None)
    job.result.csg[name] = info
    if not leaves:
        job.result.skipped[name] = ("a CSG solid none of whose operands can be baked "
                                    "(see the warnings)")
        return None
    blocks = []
    for d in leaves:
        lid = d["lightmap"]
        R = int(lm.height[lid])
        full = csg_bake.full_primitive_areas(cs, inst, d["row"], R)
        blocks.append(csg_bake.leaf_rgba(lm, lid, full))
        sl = LM.texel_slice(lm, lid)
        info["split_texels"] += int(np.count_nonzero(lm.split[sl] >= 0))
        info["boundary_texels"] += int(np.count_nonzero((lm.area[sl] < full.reshape(-1) * (1 - 1e-9))
                                                        & (lm.area[sl] > 0)))
    W, H, origins = csg_bake.pack_atlas([(b.shape[1], b.shape[0]) for b in blocks])
    atlas = np.zeros((H, W, 4), np.float32)
    tiles = {}
    for d, b, o in zip(leaves, blocks, origins):
        csg_bake.blit(atlas, b, o)
        tiles[d["name"]] = (o[0], o[1], b.shape[1], b.shape[0])
    info["atlas"] = (W, H)
    return BakedMap(name, atlas, leaves[0]["lightmap"], tiles)


def commit_bake(job, *, overwrite=False, save_dir=None, pack=False, hook_materials=False):
    """Main thread: writes the computed maps to images (and files, and material hooks)."""
    import bpy
    result = job.result
    t0 = time.perf_counter()
    blend_saved = bool(bpy.data.filepath)
    if result.maps:
        # A folder that cannot take the files fails here, before any image is touched.
        check_writable(save_dir or (None if pack or not blend_saved else f"//{LIGHTMAP_DIR}"))
    for name, bm in result.maps.items():
        ob = bpy.data.objects[name]
        img = _target_image(ob, bm.width, bm.height, overwrite, result.warnings)
        img.pixels.foreach_set(bm.rgba.reshape(-1))
        img.update()
        path = None
        if save_dir:
            path = os.path.join(os.path.abspath(bpy.path.abspath(save_dir)), _file_name(name) + ".exr")
            _save_exr(img, path, relative=False)
        elif pack:
            _pack_exr(img, f"//{LIGHTMAP_DIR}/{_file_name(name)}.exr")
        elif blend_saved:
            path = bpy.path.abspath(f"//{LIGHTMAP_DIR}/{_file_name(name)}.exr")
            _save_exr(img, path, relative=True)
        result.images[name] = img.name
        result.paths[name] = path
        if bm.tiles is not None:
            _place_leaf_uvs(name, bm, result.warnings)
        elif name in job.primitives:
            _place_leaf_uvs(name, BakedMap(name, bm.rgba, bm.lightmap_id, {name: None}),
                            result.warnings)
    if result.maps and not (save_dir or pack or blend_saved):
        result.warnings.append("the .blend is not saved yet: the lightmap images live only in memory "
                               "(save the .blend and bake again, or pack them)")
    if hook_materials and result.maps:
        baked = set(result.maps)
        for name, bm in result.maps.items():
            ob = bpy.data.objects[name]
            parts = sorted(bm.tiles) if bm.tiles else ()
            result.hooked += add_lightmap_hook(ob, bpy.data.images[result.images[name]],
                                               baked_objects=baked, warnings=result.warnings,
                                               parts=parts, materials=_solid_materials(ob, parts))
    result.seconds["bake"] = result.seconds.get("extract", 0.0) + time.perf_counter() - t0
    result.seconds["total"] = time.perf_counter() - job.t_start
    return result


def check_writable(folder):
    """Creates the output folder (a Blender "//" path is fine) -> raises an InputError if it cannot take files."""
    import bpy

    from .messages import InputError
    if not folder:
        return
    path = os.path.abspath(bpy.path.abspath(folder))
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".photon_lightmaps_probe"):
            pass
    except OSError as exc:
        raise InputError(f"{path}: cannot write the lightmaps there ({exc.strerror or exc}); "
                         "choose another folder") from exc


def _place_leaf_uvs(solid, bm, warnings):
    """Moves each baked leaf's generated `Lightmap` layer into its block of the solid's atlas.

    bm.tiles: leaf name -> (x, y, w, h) texels, or None for the plain chart layout
    (a stand-alone primitive whose layer an earlier CSG bake had moved).
    The layer is checked again here (the user may have edited it during the bake).
    """
    import bpy
    from . import uv_layers
    for leaf, tile in bm.tiles.items():
        ob = bpy.data.objects.get(leaf)
        if ob is None:
            continue
        unit, applied, why = uv_layers.primitive_chart_uvs(ob)
        if why is not None:
            if tile is not None:
                warnings.append(f"CSG solid '{solid}': {why}; that operand's part of the image is "
                                "not shown on the solid")
            continue
        if tile is None:
            rect = (0.0, 0.0, 1.0, 1.0)
        else:
            x, y, w, h = tile
            rect = (x / bm.width, y / bm.height, w / bm.width, h / bm.height)
        uv_layers.set_primitive_tile(ob, unit, applied, rect)


def _solid_materials(ob, parts):
    """Materials the evaluated object shows: its own slots, then (CSG solids) those the
    Boolean result carries over from its baked operands (Exact solver, Transfer)."""
    import bpy
    mats = []

    def add(m):
        if m is not None and m not in mats:
            mats.append(m)
    for slot in ob.material_slots:
        add(slot.material)
    if parts:
        try:
            ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
            for m in ev.data.materials:
                add(getattr(m, "original", None) or m)
        except Exception:  # noqa: BLE001  (no depsgraph in this context: the slots below suffice)
            pass
        for leaf in parts:
            op = bpy.data.objects.get(leaf)
            if op is not None and op is not ob:
                for slot in op.material_slots:
                    add(slot.material)
    return mats


def bake_objects(context_or_depsgraph, objects, *, photons, seed, resolution=None,
                 indirect_only=False, progress=None, overwrite=False, save_dir=None, pack=False,
                 hook_materials=False):
    """Bakes the lightmaps of mesh `objects` to images "<object>_Lightmap" -> BakeResult.

    One photon pass (indirect light) for all of them, plus the direct light
    gathered per texel unless `indirect_only`. `resolution` forces R x R texels per object; otherwise the object's
    own setting or the scene's texel density decides. `progress(done, total)`
    may return False to cancel: Cancelled is raised before any image changes.
    See the module docstring for image naming, overwriting and saving.
    """
    job = prepare_bake(context_or_depsgraph, objects, photons=photons, seed=seed,
                       resolution=resolution, indirect_only=indirect_only)
    try:
        compute_bake(job, progress)
    except BaseException:
        rollback_bake(job)
        raise
    return commit_bake(job, overwrite=overwrite, save_dir=save_dir, pack=pack,
                       hook_materials=hook_materials)


# --------------------------------------------------------------------------------------
# Images
# --------------------------------------------------------------------------------------

def _our_image(ob):
    import bpy
    base = ob.name + IMAGE_SUFFIX
    ours = [im for im in bpy.data.images if im.library is None and im.get(OWNER_PROP) == ob.name]
    ours.sort(key=lambda im: (im.name != base, im.name))
    return ours[0] if ours else None


def _new_image(name, w, h):
    import bpy
    img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    img.use_half_precision = False
    img.alpha_mode = "CHANNEL_PACKED"
    img.colorspace_settings.name = "Linear Rec.709"
    return img


def _target_image(ob, w, h, overwrite, warnings):
    """The image to write object `ob`'s lightmap into, following the module's policy."""
    import bpy
    base = ob.name + IMAGE_SUFFIX
    img = _our_image(ob)
    if img is None:
        existing = bpy.data.images.get(base)
        if existing is None:
            img = _new_image(base, w, h)
        elif overwrite and existing.library is None:
            img = existing
            warnings.append(f"image '{base}' was replaced (overwrite)")
        else:
            img = _new_image(base, w, h)   # Blender appends .001, .002, ...
            warnings.append(f"image '{base}' already exists and is not a Photon Lightmaps bake: "
                            f"kept it, wrote '{img.name}' instead (bake with overwrite to replace it)")
    if (not img.is_float or img.channels != 4 or tuple(img.size) != (w, h)
            or img.source not in ("GENERATED", "FILE") or img.packed_file is not None):
        # Rebuild it as a fresh float image; its users (materials) follow via remap.
        name = img.name
        fresh = _new_image(name + ".photon_tmp", w, h)
        img.user_remap(fresh)
        bpy.data.images.remove(img)
        fresh.name = name
        img = fresh
    img.alpha_mode = "CHANNEL_PACKED"
    img.use_half_precision = False
    img[OWNER_PROP] = ob.name
    return img


def _exr_scene():
    import bpy
    sc = bpy.data.scenes.new("photon_lightmaps_exr_settings")
    s = sc.render.image_settings
    s.file_format = "OPEN_EXR"
    s.color_depth = "32"
    s.exr_codec = "ZIP"
    s.color_mode = "RGBA"
    return sc


def write_exr(img, path):
    """Writes a float image as OpenEXR 32-bit RGBA, ZIP, values as stored (linear, no view transform)."""
    import bpy
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    sc = _exr_scene()
    try:
        # save_render takes format and codec from a scene; a scratch one leaves the user's alone.
        img.save_render(path, scene=sc)
    finally:
        bpy.data.scenes.remove(sc)


def _save_exr(img, path, relative):
    import bpy
    # Write beside the target, then rename: a crash never leaves half a file.
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.{os.getpid()}.tmp.exr"
    try:
        write_exr(img, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    img.filepath_raw = bpy.path.relpath(path) if relative else path
    img.file_format = "OPEN_EXR"
    if img.source != "FILE":
        img.source = "FILE"
    else:
        img.reload()


def _pack_exr(img, filepath):
    with tempfile.TemporaryDirectory() as d:
        tmp = os.path.join(d, "lightmap.exr")
        write_exr(img, tmp)
        img.filepath_raw = tmp
        img.file_format = "OPEN_EXR"
        if img.source != "FILE":
            img.source = "FILE"
        else:
            img.reload()
        img.pack()
    img.filepath_raw = filepath   # where "Unpack" will put it


# --------------------------------------------------------------------------------------
# Material hook
# --------------------------------------------------------------------------------------

def hook_nodes(tree, frame, origin, lookup, vector, image, group, out, surface, tag):
    """Image (read at `vector`, made by node `lookup`) -> lightmap group -> an
    EEVEE-only Material Output beside the user's. Shared by the UV lightmap
    hook and the orientation lightmap hook (ol_bake.py); returns the group node."""
    tex = tag(tree.nodes.new("ShaderNodeTexImage"), "Image")
    tex.image = image
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    grp = tag(tree.nodes.new("ShaderNodeGroup"), "Group")
    grp.node_tree = group
    eo = tag(tree.nodes.new("ShaderNodeOutputMaterial"), "Output")
    eo.target = "EEVEE"
    for n, dx in ((lookup, -700), (tex, -500), (grp, -200), (eo, 0)):
        n.parent = frame
        n.location = (origin[0] + dx, origin[1])
    tree.links.new(vector, tex.inputs["Vector"])
    tree.links.new(tex.outputs["Color"], grp.inputs["Lightmap"])
    if surface is not None:
        tree.links.new(surface, grp.inputs["Shader"])
    tree.links.new(grp.outputs["Shader"], eo.inputs["Surface"])
    if out is not None:
        for key in ("Volume", "Displacement"):
            src = _source(out.inputs[key])
            if src is not None:
                tree.links.new(src, eo.inputs[key])
    return grp


def _tag(node, role):
    node[HOOK_PROP] = role
    node.name = f"{HOOK_PREFIX} {role}" if role != "Group" else HOOK_PREFIX
    node.label = node.name
    return node


def _sock(sockets, identifier):
    # Mix nodes have several sockets of one name; the identifier tells them apart.
    return next(s for s in sockets if s.identifier == identifier)


def hook_group():
    """The shared node group: mixes emission = base colour x lightmap over the original surface."""
    import bpy
    for ng in bpy.data.node_groups:
        if ng.get(HOOK_PROP) and ng.library is None and ng.bl_idname == "ShaderNodeTree":
            return ng
    ng = bpy.data.node_groups.new(HOOK_GROUP, "ShaderNodeTree")
    ng[HOOK_PROP] = 1
    ng.description = "Photon Lightmaps: baked light (base colour x lightmap) shown in EEVEE"
    io = ng.interface
    io.new_socket("Shader", in_out="INPUT", socket_type="NodeSocketShader")
    base = io.new_socket("Base Color", in_out="INPUT", socket_type="NodeSocketColor")
    base.default_value = (0.8, 0.8, 0.8, 1.0)
    lmap = io.new_socket("Lightmap", in_out="INPUT", socket_type="NodeSocketColor")
    lmap.default_value = (0.0, 0.0, 0.0, 1.0)
    st = io.new_socket("Strength", in_out="INPUT", socket_type="NodeSocketFloat")
    st.default_value, st.min_value = 1.0, 0.0
    fac = io.new_socket("Factor", in_out="INPUT", socket_type="NodeSocketFloat")
    fac.default_value, fac.min_value, fac.max_value = 1.0, 0.0, 1.0
    fac.subtype = "FACTOR"
    io.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    n, l = ng.nodes, ng.links
    gi, go = n.new("NodeGroupInput"), n.new("NodeGroupOutput")
    mul = n.new("ShaderNodeMix")
    mul.data_type, mul.blend_type = "RGBA", "MULTIPLY"
    _sock(mul.inputs, "Factor_Float").default_value = 1.0
    em = n.new("ShaderNodeEmission")
    mix = n.new("ShaderNodeMixShader")
    gi.location, mul.location, em.location, mix.location, go.location = \
        (-500, 0), (-250, -100), (-50, -100), (150, 0), (350, 0)
    l.new(gi.outputs["Base Color"], _sock(mul.inputs, "A_Color"))
    l.new(gi.outputs["Lightmap"], _sock(mul.inputs, "B_Color"))
    l.new(_sock(mul.outputs, "Result_Color"), em.inputs["Color"])
    l.new(gi.outputs["Strength"], em.inputs["Strength"])
    l.new(gi.outputs["Factor"], mix.inputs[0])
    l.new(gi.outputs["Shader"], mix.inputs[1])
    l.new(em.outputs["Emission"], mix.inputs[2])
    l.new(mix.outputs["Shader"], go.inputs["Shader"])
    return ng


def _user_output(tree):
    outs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial" and not n.get(HOOK_PROP)]
    # The output Cycles renders: active first, then one meant for all engines.
    outs.sort(key=lambda n: (not n.is_active_output, n.target not in ("ALL", "CYCLES")))
    return outs[0] if outs else None


def _source(socket):
    """The output socket feeding `socket`, through reroutes (None if unlinked)."""
    seen = 0
    while socket.is_linked and seen < 64:
        link = socket.links[0]
        if link.from_node.bl_idname != "NodeReroute":
            return link.from_socket
        socket = link.from_node.inputs[0]
        seen += 1
    return None


def remove_hook_nodes(mat):
    """Deletes our nodes from one material -> how many."""
    tree = mat.node_tree
    if tree is None or mat.library is not None:
        return 0
    ours = [n for n in tree.nodes if n.get(HOOK_PROP)]
    for n in ours:
        tree.nodes.remove(n)
    return len(ours)


def add_lightmap_hook(ob, image, baked_objects=(), warnings=None, parts=(), materials=None):
    """Adds (or refreshes) our hook in every material of `ob`; returns the material names.

    materials: the materials to hook instead of `ob`'s slots (a CSG solid's Boolean
    result also shows its operands' materials); parts: objects whose surface is in
    this image (a CSG solid's operands), so sharing a material with them is fine.
    """
    import bpy
    warnings = warnings if warnings is not None else []
    from .uv_layers import LAYER_NAME
    ng = hook_group()
    done = []
    mats = []
    for m in (materials if materials is not None else [s.material for s in ob.material_slots]):
        if m is not None and m not in mats:
            mats.append(m)
    if not mats:
        warnings.append(f"object '{ob.name}' has no material: no lightmap hook added")
    for mat in mats:
        if mat.library is not None or mat.node_tree is None:
            why = "is linked from a library" if mat.library is not None else "uses no nodes"
            warnings.append(f"material '{mat.name}' {why}: no lightmap hook added")
            continue
        users = sorted({o.name for o in bpy.data.objects
                        if any(s.material == mat for s in o.material_slots)} - {ob.name} - set(parts))
        others_baked = [u for u in users if u in baked_objects]
        others = [u for u in users if u not in baked_objects]
        if others:
            warnings.append(f"material '{mat.name}' is shared with objects not baked now "
                            f"({', '.join(others)}): in EEVEE they show '{ob.name}''s lightmap")
        if others_baked:
            warnings.append(f"material '{mat.name}' is shared by baked objects "
                            f"({', '.join([ob.name] + others_baked)}): it can show only one of their "
                            f"lightmaps; give each object its own material")
        remove_hook_nodes(mat)
        tree = mat.node_tree
        out = _user_output(tree)
        surface = _source(out.inputs["Surface"]) if out is not None else None
        x0, y0 = (out.location.x, out.location.y - 400) if out is not None else (300, -400)
        frame = _tag(tree.nodes.new("NodeFrame"), "Frame")
        frame.label = "Photon Lightmap (baked light, EEVEE only; remove with Remove Lightmap Hook)"
        uv = _tag(tree.nodes.new("ShaderNodeUVMap"), "UV")
        uv.uv_map = LAYER_NAME
        grp = hook_nodes(tree, frame, (x0, y0), uv, uv.outputs["UV"], image, ng, out, surface, _tag)
        _link_base_color(tree, surface, grp, mat, warnings)
        # EEVEE prefers an output whose target is exactly EEVEE over an "All" one, active
        # or not, so ours needs no active flag (setting it would clear the user's).
        theirs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"
                  and n.target == "EEVEE" and not n.get(HOOK_PROP)]
        if theirs:
            warnings.append(f"material '{mat.name}' has its own EEVEE output ('{theirs[0].name}'), "
                            "which EEVEE keeps using: the lightmap hook is not shown there")
        done.append(mat.name)
    return done


def _link_base_color(tree, surface, grp, mat, warnings):
    node = surface.node if surface is not None else None
    key = {"ShaderNodeBsdfPrincipled": "Base Color", "ShaderNodeBsdfDiffuse": "Color"}.get(
        node.bl_idname if node is not None else None)
    if key is None:
        warnings.append(f"material '{mat.name}': no Principled or Diffuse BSDF on the surface; "
                        "the lightmap hook uses a white base colour")
        grp.inputs["Base Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        return
    sock = node.inputs[key]
    src = _source(sock)
    if src is not None:
        tree.links.new(src, grp.inputs["Base Color"])
    else:
        grp.inputs["Base Color"].default_value = tuple(sock.default_value)


def remove_lightmap_hook(materials=None):
    """Removes our hook nodes from `materials` (default: all); drops the group when unused. -> nodes removed."""
    import bpy
    mats = bpy.data.materials if materials is None else materials
    removed = sum(remove_hook_nodes(m) for m in mats)
    for ng in list(bpy.data.node_groups):
        if ng.get(HOOK_PROP) and ng.library is None and ng.users == 0:
            bpy.data.node_groups.remove(ng)
    return removed


# --------------------------------------------------------------------------------------
# RenderEngine bake API
# --------------------------------------------------------------------------------------

# One photon pass serves every object (and image) of a bake: keyed by a digest of
# the exported scene and the settings, so an edited scene is never served stale maps.
_cache = {"key": None, "value": None}


def clear_cache(*_args):
    """Frees the photon pass kept for Blender's bake (also a bake-complete/cancel handler)."""
    _cache["key"] = None
    _cache["value"] = None


def _digest_scene(scene, extra):
    h = hashlib.sha256(repr(extra).encode())

    def add(x):
        if isinstance(x, np.ndarray):
            h.update(str((x.dtype, x.shape)).encode())
            h.update(np.ascontiguousarray(x).tobytes())
        elif isinstance(x, (list, tuple)):
            h.update(b"[")
            for y in x:
                add(y)
            h.update(b"]")
        elif hasattr(x, "__dataclass_fields__"):
            h.update(type(x).__name__.encode())
            for k in x.__dataclass_fields__:
                add(getattr(x, k))
        else:
            h.update(repr(x).encode())

    add(scene)
    return h.hexdigest()


def _patch_missing_uvs(scene):
    """Gives meshes without a Lightmap layer the core's own xatlas UVs, per loop triangle.

    The core would unwrap them anyway; doing it here keeps the UVs in Blender's
    loop-triangle order, which is what the bake API's primitive ids index.
    """
    from .engine.uv_atlas import unwrap
    for proto in scene.prototypes:
        for tm in proto.meshes:
            if tm.uvs is None:
                try:
                    tm.uvs = unwrap(tm.vertices, tm.triangles)
                except ValueError as exc:   # NaN vertices, xatlas refusals: name the mesh
                    raise SceneError(f"mesh '{tm.name}' in prototype '{proto.name}': cannot unwrap its "
                                     f"lightmap UVs: {exc}") from exc


def _bake_lightmaps(depsgraph, modes, progress, report):
    """(scene, export map, {mode: (compiled scene, lightmaps)}) for the bake API, cached.

    Modes: "indirect" (the photon pass: hits after the first bounce), "direct"
    (the gathered direct light alone) and "total" (both). One photon pass serves
    all three; "direct" and "total" are copies of its lightmaps with the direct
    light added.
    """
    from .engine import texel_gather as TG
    from .export import export_scene
    scene, emap = export_scene(depsgraph, report=None)
    _patch_missing_uvs(scene)
    settings = _settings(depsgraph.scene)
    key = _digest_scene(scene, sorted(settings.items()))
    if _cache["key"] != key:
        clear_cache()
        for w in emap.warnings:
            report("WARNING", w)
        _cache["key"], _cache["value"] = key, (scene, emap, {})
    scene, emap, passes = _cache["value"]
    for mode in modes:
        if mode in passes:
            continue
        if "indirect" not in passes:
            cs, _ = _photon_pass(scene, settings, progress)
            passes["indirect"] = (cs, cs.lightmaps)
        cs, ind = passes["indirect"]
        if mode == "indirect":
            continue
        if "gathered" not in passes:
            # Blender's bake API addresses mesh triangles only (exact primitives and
            # CSG solids are refused below), so only mesh lightmaps need direct light.
            mesh_lms = [l for i, lids in enumerate(cs.instance_lightmaps)
                        if scene.prototypes[scene.instances[i].prototype].meshes for l in lids]
            passes["gathered"] = TG.direct_texel_irradiance(cs, mesh_lms, DIRECT_SAMPLES,
                                                            seed=settings["seed"])
        ids, E = passes["gathered"]
        lm = LM.Lightmaps(*(a.copy() for a in ind))
        if mode == "direct":
            lm.flux[...] = 0.0
        TG.add_direct(lm, ids, E)
        passes[mode] = (cs, lm)
    return scene, emap, passes


def _band3(x, nb):
    a = np.broadcast_to(np.asarray(x, np.float64).reshape(-1), (nb,))
    return a if nb == 3 else np.repeat(a.mean(), 3)


def _target_images(ob):
    """Images Blender bakes `ob` into, in its order: first active image node per material slot."""
    images = []
    for slot in _original(ob).material_slots:
        mat = slot.material
        if mat is None or mat.node_tree is None:
            continue
        node = mat.node_tree.nodes.active
        if node is not None and node.bl_idname == "ShaderNodeTexImage" and node.image is not None \
                and node.image not in images:
            images.append(node.image)
    return images


def _current_pixels(image, width, height):
    """An image's pixels as the linear RGBA Blender's bake would turn back into them."""
    if image is None or tuple(image.size) != (width, height):
        return None
    px = np.empty(width * height * image.channels, np.float32)
    image.pixels.foreach_get(px)
    px = px.reshape(height, width, image.channels)
    out = np.ones((height, width, 4), np.float32)
    out[..., :min(4, image.channels)] = px[..., :4]
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        c = out[..., :3]
        out[..., :3] = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return out


class BakeMixin:
    """RenderEngine.bake for Blender's Bake button (Render Properties > Bake).

    What Blender 5.0 passes (found by introspection): bake(depsgraph, object,
    pass_type, pass_filter, width, height) is called once per object and target
    image, on a fresh engine instance each time. `begin_result(0, 0, width,
    height, layer=...)` returns one layer with the passes "BakePrimitive" (3
    channels: barycentric u, barycentric v, loop-triangle index as int32 bits,
    -1 where no triangle covers the pixel), "BakeDifferential" and "Combined"
    (RGBA, rows bottom-up like the image); what we write to Combined is what
    Blender stores in the image after end_result. The barycentrics weigh the
    triangle's corners as (u, v, 1 - u - v). Blender writes the image even when
    a bake is cancelled or fails, so those paths write the image's current
    pixels back instead of black. (With "Clear Image" on, Blender blanks the
    image before any engine is called; what it blanked cannot come back.)

    Passes: DIFFUSE with DIRECT / INDIRECT / COLOR (no COLOR: E/pi, Cycles'
    convention), EMIT, and COMBINED (emission + diffuse; glossy and
    transmission are view-dependent and not in a lightmap). Others: an error.
    """

    def bake(self, depsgraph, obj, pass_type, pass_filter, width, height):
        index = getattr(self, "_photon_bake_calls", 0)
        self._photon_bake_calls = index + 1
        result = self.begin_result(0, 0, width, height, layer="Bake", view="")
        try:
            passes = result.layers[0].passes
            rgba = None
            try:
                prim = passes["BakePrimitive"]
                raw = np.empty(width * height * prim.channels, np.float32)
                prim.rect.foreach_get(raw)
                rgba = self._photon_bake_pixels(depsgraph, obj, pass_type, int(pass_filter),
                                                raw.reshape(-1, prim.channels))
            except Cancelled:
                self.report({"WARNING"}, "Photon Lightmaps bake cancelled; the image was left as it was")
            except Exception as e:  # noqa: BLE001  (any failure must still end the result)
                if not is_user_error(e):
                    import traceback
                    traceback.print_exception(e)
                self.report({"ERROR"}, describe(e))
            if rgba is None:
                # Blender writes the image whatever happens: give it back what it holds.
                imgs = _target_images(obj)
                old = _current_pixels(imgs[index] if index < len(imgs) else None, width, height)
                rgba = old if old is not None else np.zeros((height, width, 4), np.float32)
            passes["Combined"].rect.foreach_set(np.ascontiguousarray(rgba, np.float32).reshape(-1))
        finally:
            self.end_result(result)

    def _photon_should_stop(self):
        # Esc during Blender's bake. (A Python name of our own: RNA functions such as
        # test_break take precedence over class attributes, so tests patch this one.)
        return bool(self.test_break())

    def _photon_bake_pixels(self, depsgraph, obj, pass_type, pass_filter, raw):
        if pass_type not in ("DIFFUSE", "EMIT", "COMBINED"):
            raise SceneError(f"bake type {pass_type}: not supported by Photon Lightmaps "
                             "(use Diffuse, Emit or Combined, or bake it with Cycles)")
        direct = bool(pass_filter & FILTER_DIRECT)
        indirect = bool(pass_filter & FILTER_INDIRECT)
        if pass_type == "EMIT":
            want_light, want_color, want_emit = False, False, True
        elif pass_type == "DIFFUSE":
            want_light = direct or indirect
            want_color = bool(pass_filter & FILTER_COLOR)
            want_emit = False
            if not (want_light or want_color):
                raise SceneError("bake contributions: the Diffuse bake needs Direct, Indirect or Color")
        else:
            want_light = (direct or indirect) and bool(pass_filter & FILTER_DIFFUSE)
            want_color = True
            want_emit = bool(pass_filter & FILTER_EMIT)
        modes = []
        if want_light:
            modes = ["total"] if direct and indirect else ["indirect"] if indirect else ["direct"]

        def progress(done, total):
            self.update_progress(done / max(total, 1))
            return not self._photon_should_stop()

        def report(level, msg):
            self.report({level}, msg)

        if self._photon_should_stop():
            raise Cancelled("bake cancelled before the photon pass")
        scene, emap, passes = _bake_lightmaps(depsgraph, modes, progress, report)
        name = _original(obj).name
        ids = emap.object_instances(name)
        if not ids:
            raise SceneError(f"object '{name}' is not part of the exported scene")
        lit = [i for i in ids if emap.instances[i].lightmap]
        if want_light and not lit:
            raise SceneError(f"object '{name}' is excluded from lightmaps (Object > Photon Lightmaps)")
        inst = lit[0] if lit else ids[0]
        proto = scene.prototypes[emap.instances[inst].prototype]
        if not proto.meshes:
            # Exact primitives and CSG solids have analytic charts, not the bake
            # mesh's triangles: Blender's per-triangle bake cannot address them.
            raise SceneError(f"object '{name}' is an exact primitive or CSG solid; use "
                             "Render > Bake Photon Lightmaps, which bakes its analytic charts")
        tm = proto.meshes[0]

        prim_id = raw[:, 2].view(np.int32)
        ok = prim_id >= 0
        if ok.any() and prim_id[ok].max() >= tm.triangles.shape[0]:
            raise SceneError(f"object '{name}': Blender's bake mesh has more triangles than the "
                             "exported one (is the mesh being edited?)")
        k = prim_id[ok].astype(np.int64)
        u = raw[ok, 0].astype(np.float64)[:, None]
        v = raw[ok, 1].astype(np.float64)[:, None]
        uv = tm.uvs[k]
        st = u * uv[:, 0] + v * uv[:, 1] + (1.0 - u - v) * uv[:, 2]
        nb = scene.n_bands
        light = None
        if want_light:
            cs, lm = passes[modes[0]]
            light = np.zeros((k.shape[0], nb))
            _sample_bilinear(lm, cs.instance_lightmaps[inst][0], st[:, 0].copy(),
                             st[:, 1].copy(), light)
            light = (light if nb == 3 else np.repeat(light.mean(axis=1, keepdims=True), 3, axis=1)) / math.pi
        mids = np.asarray(tm.material_ids if tm.material_ids is not None else
                          np.full(tm.triangles.shape[0], tm.material))[k]
        albedo = np.array([_band3(m.diffuse, nb) for m in scene.materials])[mids]
        emission = np.array([_band3(m.emission, nb) for m in scene.materials])[mids]
        if pass_type == "DIFFUSE":
            val = light if want_light else np.ones((k.shape[0], 3))
            if want_color:
                val = val * albedo
        elif pass_type == "EMIT":
            val = emission
        else:
            val = np.zeros((k.shape[0], 3))
            if want_light:
                val += albedo * light
            if want_emit:
                val += emission
        if pass_type == "COMBINED" and (pass_filter & (FILTER_GLOSSY | FILTER_TRANSMISSION)):
            spec = [m.name for m in scene.materials if np.any(np.asarray(m.specular) > 0)
                    or np.any(np.asarray(m.transmission) > 0)]
            if spec:
                self.report({"WARNING"}, "glossy and transmitted light are not in photon lightmaps "
                                         f"(materials: {', '.join(spec[:5])})")
        out = np.zeros((raw.shape[0], 4), np.float32)
        out[ok, :3] = val
        out[ok, 3] = 1.0
        return out


# --------------------------------------------------------------------------------------
# Command line: python -m photon_lightmaps bake FILE.blend --out DIR
# --------------------------------------------------------------------------------------

def _peak_rss_bytes():
    try:
        import resource
        import sys
        r = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return int(r if sys.platform == "darwin" else r * 1024)
    except Exception:  # noqa: BLE001  (not on every platform)
        return None


def _ensure_registered():
    import bpy
    if not hasattr(bpy.types.Scene, "photon_lightmaps"):
        from . import register
        register()


def bake_main(args):
    """CLI: bakes every mesh object of a .blend (excluded ones skipped) to DIR/<object>.exr."""
    import json
    import sys

    import bpy
    from .headless import open_blend
    t0 = time.perf_counter()
    _ensure_registered()
    blend = open_blend(args.blend)
    _ensure_registered()
    context = bpy.context
    settings = _settings(context.scene)
    photons = settings["photons"] if args.photons is None else int(args.photons)
    seed = settings["seed"] if args.seed is None else int(args.seed)
    objects = [ob for ob in context.scene.objects if ob.type == "MESH"]
    out_dir = os.path.abspath(args.out)
    check_writable(out_dir)

    def progress(done, total):
        print(f"\rphotons {done}/{total}", end="", file=sys.stderr, flush=True)
        return True

    res = bake_objects(context, objects, photons=photons, seed=seed, resolution=args.resolution,
                       indirect_only=args.indirect_only, progress=progress, save_dir=out_dir,
                       overwrite=True)
    print(file=sys.stderr)
    stats = res.stats
    report = {
        "blend": str(blend),
        "photons": int(stats.photons) if stats else 0,
        "rays": int(stats.rays) if stats else 0,
        "seconds": {"photon_pass": res.seconds.get("photon_pass", 0.0),
                    "direct": res.seconds.get("direct", 0.0),
                    "bake": res.seconds.get("bake", 0.0),
                    "total": time.perf_counter() - t0},
        "objects": {name: {"path": res.paths[name], "width": bm.width, "height": bm.height,
                           "bytes": os.path.getsize(res.paths[name]), "mean": bm.mean()}
                    for name, bm in res.maps.items()},
        "skipped": res.skipped,
        "warnings": res.warnings,
        "memory": {"lightmap_bytes": res.lightmap_bytes, "peak_rss_bytes": _peak_rss_bytes()},
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text)
    return 0
