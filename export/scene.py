"""The export driver: walks `depsgraph.object_instances` and hands each object to its module.

Instances share one prototype per evaluated mesh datablock (and material
assignment), so 100 linked duplicates cost one prototype and 100 transforms.
"""
import numpy as np

from ..engine.core.scene import Instance
from . import csg, lsystems, textures
from .camera import camera
from .context import ExportContext, InstanceRecord, matrix
from .lights import light
from .meshes import leaf_mesh, first_material, prototype
from .ol_routing import OLRouter
from .world import world


def export_scene(depsgraph, *, n_bands=3, report=None, camera_override=None, resolution=None,
                 orientation_lightmaps=True, mesh_results=()):
    """Exports the evaluated `depsgraph` to (engine Scene, ExportMap).

    report(level, message), level 'INFO' | 'WARNING', receives each
    approximation once. `camera_override` (an object) and `resolution`
    ((w, h) in pixels) replace the scene's camera and render size, as a
    RenderEngine may ask. orientation_lightmaps=False ignores OL empties (every
    object keeps its own lightmap), as the OL planner needs. mesh_results:
    names of Booleans of plain meshes to export as Blender's result mesh rather
    than an exact CSG tree (the same polyhedron; a bake needs its UVs).
    """
    ctx = ExportContext(depsgraph, n_bands, report, orientation_lightmaps)
    ctx.mesh_results = frozenset(mesh_results)
    ctx.csg = csg.CSGBuilder(depsgraph, lambda ob: first_material(ctx, ob),
                             lambda mesh, ob: leaf_mesh(ctx, mesh, ob), ctx.report)
    return _run(ctx, camera_override, resolution)


def _run(ctx, camera_override, resolution):
    dg = ctx.dg
    bscene = dg.scene
    settings = getattr(bscene, "photon_lightmaps", None)
    ctx.scene.name = bscene.name
    if settings is not None:
        ctx.scene.texel_density = float(settings.texel_density)
        ctx.scene.caustic_resolution = float(getattr(settings, "caustic_resolution", 4.0))
        ctx.scene.unwrap_limit = int(getattr(settings, "unwrap_limit", ctx.scene.unwrap_limit))
    operands = csg.find_operands(dg)
    ctx.map.csg_operands = {o.name: solid for o, solid in operands.items()}
    router = OLRouter(bscene, ctx.report) if ctx.use_ols else None
    skipped_types = set()
    for inst in dg.object_instances:
        _instance(ctx, inst, operands, router, skipped_types, dg.mode == "VIEWPORT")
    for t in sorted(skipped_types):
        ctx.report("WARNING", f"{t.lower()} objects are not supported and were skipped")
    if router:
        seed = int(settings.seed) if settings is not None else 0
        ctx.scene.orientation_lightmaps, ctx.map.orientation_lightmaps = router.build(seed)
    _camera_and_world(ctx, bscene, camera_override, resolution)
    # last: the bakes add and remove datablocks, so no evaluated one is read after them
    textures.bake_queued(ctx)
    return ctx.scene, ctx.map


def _instance(ctx, inst, operands, router, skipped_types, viewport):
    """One entry of depsgraph.object_instances -> a light, an instance, or nothing."""
    ob = inst.object
    parent = inst.parent if inst.is_instance else None
    if lsystems.is_preview(ob.original, parent):
        # An L-system's preview (its meshes, instances, organs): the engine traces the grammar.
        return
    if ob.type not in ("MESH", "LIGHT"):
        if ob.type in ("CURVES", "POINTCLOUD", "VOLUME", "GREASEPENCIL"):
            skipped_types.add(ob.type)
        return
    original = ob.original
    is_lsystem = parent is None and lsystems.is_lsystem(original)
    if viewport and _hidden_from_render(original, parent):
        return
    if not inst.is_instance and not inst.show_self and not is_lsystem:
        return
    if original in operands:
        # Visible in render or not, an operand is geometry of the solid it cuts.
        ctx.report("INFO", f"object '{original.name}' is a Boolean operand of "
                           f"'{operands[original]}': part of that solid, not exported on its own")
        return
    xf = matrix(inst.matrix_world)
    if ob.type == "LIGHT":
        light(ctx, ob, xf)
        return
    # Instances a geometry-nodes instancer makes of its own geometry are not the
    # original object's solid; real objects (even instanced ones) are.
    own_geometry = parent is None or parent.original is None or parent.original != original
    proto = (lsystems.lsystem_prototype(ctx, ob) if is_lsystem
             else csg.csg_prototype(ctx, ob) if own_geometry else None)
    if proto is None:
        proto = prototype(ctx, ob, ob.data)
    if proto < 0:
        return
    name = original.name if original is not None else ob.name
    if abs(np.linalg.det(xf[:, :3])) <= 1e-12 * max(np.abs(xf[:, :3]).max(), 1e-300) ** 3:
        ctx.report("WARNING", f"object '{name}': zero scale, skipped")
        return
    exclude, res = _object_settings(original)
    instancer = parent.original if parent is not None and parent.original is not None else None
    if instancer is not None and instancer != original:
        # Instanced geometry also follows its instancer: excluding a collection
        # instance or particle emitter excludes what it instances.
        p_exclude, p_res = _object_settings(instancer)
        exclude = exclude or p_exclude
        res = res or p_res
    own_lightmap, ol_name = _route(ctx, router, original, instancer, exclude)
    ctx.scene.instances.append(Instance(proto, xf, name=name, lightmap=own_lightmap,
                                        lightmap_resolution=res))
    ctx.map.instances.append(InstanceRecord(
        name, bool(inst.is_instance), instancer.name if instancer is not None else None,
        tuple(inst.persistent_id), proto, own_lightmap, ol_name))


def _route(ctx, router, original, instancer, exclude):
    """The orientation lightmap the next instance goes to -> (own lightmap?, OL Empty name)."""
    if not router or exclude:
        return not exclude, None
    # Duplis (collection instances, particles) belong where their instancer is.
    ol_key = router.route(instancer if instancer is not None and instancer != original else original)
    if ol_key is None:
        return True, None
    router.add(ol_key, len(ctx.scene.instances))
    ol_empty = router.colls[ol_key][1]
    # Under a non-backup OL the hits go to the OL only (compile_scene does the same).
    return bool(ol_empty.photon_lightmaps.ol_backup), ol_empty.name


def _camera_and_world(ctx, bscene, camera_override, resolution):
    r = bscene.render
    if resolution is None:
        resolution = (r.resolution_x * r.resolution_percentage // 100,
                      r.resolution_y * r.resolution_percentage // 100)
    w, h = (max(int(v), 1) for v in resolution)
    cam_ob = camera_override if camera_override is not None else bscene.camera
    if cam_ob is not None and not cam_ob.is_evaluated:
        cam_ob = cam_ob.evaluated_get(ctx.dg)
    ctx.scene.camera = camera(ctx, cam_ob, w, h)
    ctx.scene.environment = world(ctx, bscene.world)


def _object_settings(ob):
    props = getattr(ob, "photon_lightmaps", None) if ob is not None else None
    if props is None:
        return False, 0
    return bool(props.exclude), max(int(props.lightmap_resolution), 0)


def _hidden_from_render(original, parent):
    if original is not None and parent is None and original.hide_render:
        return True
    if parent is not None and parent.original is not None and parent.original.hide_render:
        return True
    return False


