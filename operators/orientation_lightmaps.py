"""Operators for orientation lightmaps (thesis ch. 6; export.py reads them):
Add Orientation Lightmap to Collection, Remove Orientation Lightmap, Suggest
Orientation Lightmaps (engine/transport/ol_planner.py) and Bake Orientation Lightmaps
(bake/orientation.py).

An OL is an Empty shown as a sphere, sized to its collection's bounds and
linked into that collection; Empties are never exported as geometry, so it
changes nothing but where the collection's photon hits are stored.
"""
import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

from .. import messages
from ..bake import orientation as ol_bake
from ..engine import session
from ..export import is_orientation_lightmap
from ..export.lsystems import is_lsystem
from .common import ImageOutputOptions, ObjectModeOperator


# --------------------------------------------------------------------------------------
# Helpers (also used by demo_blend.py and the tests)
# --------------------------------------------------------------------------------------

def scene_collections(scene):
    return list(scene.collection.children_recursive)


def ol_of_collection(scene, coll):
    """The OL empties of the scene attached to `coll`."""
    return [ob for ob in scene.objects
            if is_orientation_lightmap(ob) and ob.photon_lightmaps.ol_collection == coll]


def collection_bounds(coll):
    """World-space (min, max) over the bounding boxes of the collection's objects (None if none)."""
    from mathutils import Vector
    lo = hi = None
    for ob in coll.all_objects:
        if is_orientation_lightmap(ob) or ob.type in ("EMPTY", "LIGHT", "CAMERA"):
            continue
        for c in ob.bound_box:
            p = ob.matrix_world @ Vector(c)
            lo = p.copy() if lo is None else Vector(map(min, lo, p))
            hi = p.copy() if hi is None else Vector(map(max, hi, p))
    return None if lo is None else (lo, hi)


def add_orientation_lightmap(scene, coll, *, resolution=16, samples=20000, min_hits=16, backup=False,
                             name=None):
    """Creates the OL empty of collection `coll` (raises ValueError, changing nothing, on bad input)."""
    if coll is None:
        raise ValueError("no collection given")
    if coll == scene.collection or coll.as_pointer() not in {c.as_pointer() for c in scene_collections(scene)}:
        raise ValueError(f"'{coll.name}' is not a collection of scene '{scene.name}' (the scene's own "
                         "top collection cannot hold an orientation lightmap; make a child collection)")
    if coll.library is not None:
        raise ValueError(f"collection '{coll.name}' is linked from a library and cannot be edited")
    existing = ol_of_collection(scene, coll)
    if existing:
        raise ValueError(f"collection '{coll.name}' already has orientation lightmap '{existing[0].name}'")
    bounds = collection_bounds(coll)
    ob = bpy.data.objects.new(name or f"OL_{coll.name}", None)
    ob.empty_display_type = "SPHERE"
    if bounds is not None:
        lo, hi = bounds
        ob.location = (lo + hi) * 0.5
        ob.empty_display_size = max(0.5 * (hi - lo).length, 1e-3)
    else:
        ob.location = scene.cursor.location
        ob.empty_display_size = 1.0
    s = ob.photon_lightmaps
    s.orientation_lightmap = True
    s.ol_collection = coll
    s.ol_resolution, s.ol_samples, s.ol_min_hits, s.ol_backup = resolution, samples, min_hits, backup
    # Inside its collection, so it moves, hides and is deleted with it.
    coll.objects.link(ob)
    return ob


def _group_instances(emap, coll):
    """Engine instance ids of lightmapped objects in `coll` (child collections included)."""
    names = {o.name for o in coll.all_objects}
    out = []
    for i, r in enumerate(emap.instances):
        owner = r.instancer if r.is_instance and r.instancer else r.object_name
        if r.lightmap and owner in names:
            out.append(i)
    return out


def suggest(context, *, photons=None, pilot_photons=30_000, min_photons_per_texel=4.0, max_mib=16.0,
            resolution=16):
    """Pilot pass + planner over the scene's collections without an OL.

    Returns (all proposals, kept: {collection name: Proposal}) where kept are
    the proposed ones not nested inside another proposed collection (their
    savings would be counted twice)."""
    from ..engine.transport.ol_planner import plan
    from ..export import export_scene
    scene = context.scene
    settings = session.Settings.read(scene.photon_lightmaps, photons=photons or None)
    budget = settings.photons
    dg = context.evaluated_depsgraph_get()
    escene, emap = export_scene(dg, report=lambda level, msg: None, orientation_lightmaps=False)
    colls = {c.name: c for c in scene_collections(scene) if not ol_of_collection(scene, c)}
    groups = {}
    for name, c in colls.items():
        ids = _group_instances(emap, c)
        # A collection that holds everything lightmapped is the whole scene, not a group.
        if ids and len(ids) < sum(r.lightmap for r in emap.instances):
            groups[name] = ids
    if not groups:
        return [], {}
    cs = session.compile(escene)
    props = plan(cs, budget, groups, pilot_photons=pilot_photons, seed=int(settings.seed),
                 max_bounces=int(settings.max_bounces), min_photons_per_texel=min_photons_per_texel,
                 max_bytes=int(max_mib * 2 ** 20), resolution=resolution)
    proposed = {p.group for p in props if p.proposed}
    kept = {}
    for p in props:
        if not p.proposed:
            continue
        outer = [q for q in proposed if q != p.group and p.group in
                 {c.name for c in colls[q].children_recursive}]
        if not outer:
            kept[p.group] = p
    return props, kept


def _removable(ob):
    """An OL empty, or an L-system object (whose automatic OL the bake may have baked)."""
    return ob is not None and (is_orientation_lightmap(ob) or is_lsystem(ob))


def _active_ol(context):
    ob = context.object
    return ob if _removable(ob) else None


# --------------------------------------------------------------------------------------
# Operators
# --------------------------------------------------------------------------------------

class PHOTON_LIGHTMAPS_OT_add_orientation_lightmap(ObjectModeOperator, bpy.types.Operator):
    """Add an orientation lightmap to the active collection: its objects store photon hits per
    surface normal in one shared map instead of per-object lightmaps"""
    bl_idname = "photon_lightmaps.add_orientation_lightmap"
    bl_label = "Add Orientation Lightmap to Collection"
    bl_options = {"REGISTER", "UNDO"}

    collection: StringProperty(
        name="Collection", default="",
        description="Collection to attach it to; empty uses the active collection")
    resolution: IntProperty(name="Resolution", default=16, min=2, max=512,
                            description="Octahedral direction bins per side")
    backup: BoolProperty(name="Backup", default=False,
                         description="Objects keep their lightmaps; the OL stands in for noisy texels")

    def execute(self, context):
        if self.collection:
            coll = bpy.data.collections.get(self.collection)
            if coll is None:
                self.report({"ERROR"}, f"No collection named '{self.collection}'")
                return {"CANCELLED"}
        else:
            coll = context.collection
        try:
            ob = add_orientation_lightmap(context.scene, coll, resolution=self.resolution, backup=self.backup)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for o in context.selected_objects:
            o.select_set(False)
        if context.view_layer.objects.get(ob.name) is not None:
            ob.select_set(True)
            context.view_layer.objects.active = ob
        self.report({"INFO"}, f"Added orientation lightmap '{ob.name}' to collection '{coll.name}'")
        return {"FINISHED"}


class PHOTON_LIGHTMAPS_OT_remove_orientation_lightmap(bpy.types.Operator):
    """Remove an orientation lightmap: deletes only its Empty, its baked image and the material
    nodes its bake added; the objects use their own lightmaps again. On an L-system object:
    deletes the baked image and material nodes of its own orientation lightmap, keeps the object"""
    bl_idname = "photon_lightmaps.remove_orientation_lightmap"
    bl_label = "Remove Orientation Lightmap"
    bl_options = {"REGISTER", "UNDO"}

    name: StringProperty(name="Name", default="",
                         description="Orientation lightmap Empty (or L-system object whose baked "
                                     "orientation lightmap) to remove; empty uses the active object")

    @classmethod
    def poll(cls, context):
        return context.scene is not None

    def execute(self, context):
        ob = bpy.data.objects.get(self.name) if self.name else _active_ol(context)
        if not _removable(ob):
            what = f"'{self.name}'" if self.name else "the active object"
            self.report({"ERROR"}, f"{what} is not an orientation lightmap")
            return {"CANCELLED"}
        info = ol_bake.remove_orientation_lightmap(ob)
        what = "orientation lightmap" if info["removed_object"] else "the baked orientation lightmap of"
        self.report({"INFO"}, f"Removed {what} '{info['empty']}' ({len(info['images'])} "
                              f"image(s), {info['nodes']} material node(s))")
        return {"FINISHED"}


class PHOTON_LIGHTMAPS_OT_suggest_orientation_lightmaps(ObjectModeOperator, bpy.types.Operator):
    """Find collections whose per-object lightmaps would get too few photons per texel, or cost
    too much memory, for the photon budget, and state what an orientation lightmap saves"""
    bl_idname = "photon_lightmaps.suggest_orientation_lightmaps"
    bl_label = "Suggest Orientation Lightmaps"
    bl_options = {"REGISTER", "UNDO"}

    photons: IntProperty(name="Photon Budget", default=0, min=0,
                         description="Photons of the real pass; 0 uses the scene's setting")
    pilot_photons: IntProperty(name="Pilot Photons", default=30_000, min=1000, soft_max=200_000,
                               description="Photons of the quick pass that measures where photons land")
    min_photons_per_texel: FloatProperty(name="Min Photons per Texel", default=4.0, min=0.0,
                                         description="Propose an OL where fewer are expected")
    max_mib: FloatProperty(name="Max Lightmap MiB", default=16.0, min=0.0,
                           description="Propose an OL where a collection's lightmaps cost more")
    create: BoolProperty(name="Create", default=False,
                         description="Add the proposed orientation lightmaps (off: only report them)")

    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    def execute(self, context):
        try:
            props, kept = suggest(context, photons=self.photons, pilot_photons=self.pilot_photons,
                                  min_photons_per_texel=self.min_photons_per_texel, max_mib=self.max_mib)
        except Exception as exc:  # noqa: BLE001  (reported to the user instead of a traceback)
            return messages.operator_failed(self, exc)
        for p in props:
            verdict = "propose" if p.group in kept else ("nested in a proposal" if p.proposed else "keep")
            self.report({"INFO"}, f"'{p.group}' ({p.instances} objects): {verdict}; {p.reason}; "
                                  f"lightmaps {p.lightmap_bytes / 1024:.1f} KiB vs OL {p.ol_bytes / 1024:.1f} KiB")
        saving = sum(p.saving_bytes for p in kept.values())
        if not kept:
            self.report({"INFO"}, "No collection needs an orientation lightmap at this photon budget")
            return {"FINISHED"}
        created = []
        if self.create:
            for name in kept:
                try:
                    created.append(add_orientation_lightmap(context.scene, bpy.data.collections[name]).name)
                except ValueError as exc:
                    self.report({"WARNING"}, str(exc))
        self.report({"INFO"}, f"Orientation lightmaps for {', '.join(repr(n) for n in kept)} would save "
                              f"{saving / 1024:.1f} KiB of lightmap memory"
                              + (f"; created {', '.join(created)}" if created else " (run with Create to add them)"))
        return {"FINISHED"}


class PHOTON_LIGHTMAPS_OT_bake_orientation_lightmaps(ObjectModeOperator, ImageOutputOptions, bpy.types.Operator):
    """Bake every orientation lightmap (direct + indirect irradiance per normal) to an image its
    Empty owns, and optionally hook it into the covered objects' materials for EEVEE"""
    bl_idname = "photon_lightmaps.bake_orientation_lightmaps"
    bl_label = "Bake Orientation Lightmaps"
    bl_options = {"REGISTER"}

    photons: IntProperty(name="Photons", default=0, min=0,
                         description="Photons to shoot; 0 uses the scene's setting")
    hook_materials: BoolProperty(name="Hook Materials", default=True,
                                 description="Show the baked light in EEVEE through removable material nodes")

    def execute(self, context):
        try:
            res = ol_bake.bake_orientation_lightmaps(context, photons=self.photons or None,
                                                     overwrite=self.overwrite, pack=self.pack,
                                                     hook_materials=self.hook_materials)
        except Exception as exc:  # noqa: BLE001  (reported to the user instead of a traceback)
            return messages.operator_failed(self, exc, context.scene, "orientation bake")
        for w in res.warnings:
            self.report({"WARNING"}, w)
        messages.record(context.scene.name, "orientation bake", res.warnings)
        self.report({"INFO"}, f"Baked {len(res.images)} orientation lightmap(s) "
                              f"({res.stats.photons:,} photons, {res.seconds.get('total', 0.0):.1f} s)")
        return {"FINISHED"}


classes = (PHOTON_LIGHTMAPS_OT_add_orientation_lightmap, PHOTON_LIGHTMAPS_OT_remove_orientation_lightmap,
           PHOTON_LIGHTMAPS_OT_suggest_orientation_lightmaps, PHOTON_LIGHTMAPS_OT_bake_orientation_lightmaps)
