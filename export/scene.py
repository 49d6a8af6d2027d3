"""The export driver: walks `depsgraph.object_instances` and hands each object to its module.

Instances share one prototype per evaluated mesh datablock (and material
assignment), so 100 linked duplicates cost one prototype and 100 transforms.
"""
import numpy as np

from ..engine.scene import Instance
from . import csg, lsystems
from .camera import camera
from .context import ExportContext, InstanceRecord, matrix
from .lights import light
from .meshes import leaf_mesh, first_material, prototype
from .ol_routing import OLRouter
from .world import world


def export_scene(depsgraph, *, n_bands=3, report=None, camera_override=None, resolution=None,
                 orientation_lightmaps=True):
    """Exports the evaluated `depsgraph` to (engine Scene, ExportMap).

    report(level, message), level 'INFO' | 'WARNING', receives each
    approximation once. `camera_override` (an object) and `resolution`
    ((w, h) in pixels) replace the scene's camera and render size, as a
    RenderEngine may ask. orientation_lightmaps=False ignores OL empties (every
    object keeps its own lightmap), as the OL planner needs.
    """
    ctx = ExportContext(depsgraph, n_bands, report, orientation_lightmaps)
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
    viewport = dg.mode == "VIEWPORT"
    skipped_types = set()
    operands = csg.find_operands(dg)
    ctx.map.csg_operands = {o.name: solid for o, solid in operands.items()}
    router = OLRouter(bscene, ctx.report) if ctx.use_ols else None
    for inst in dg.object_instances:
        ob = inst.object
        parent = inst.parent if inst.is_instance else None
        if lsystems.is_preview(ob.original, parent):
            # An L-system's preview (its meshes, instances, organs): the engine traces the grammar.
            continue
        if ob.type not in ("MESH", "LIGHT"):
            if ob.type in ("CURVES", "POINTCLOUD", "VOLUME", "GREASEPENCIL"):
                skipped_types.add(ob.type)
            continue
        original = ob.original
        is_lsystem = parent is None and lsystems.is_lsystem(original)
        if viewport and _hidden_from_render(original, parent):
            continue
        if not inst.is_instance and not inst.show_self and not is_lsystem:
            continue
        if original in operands:
            # Visible in render or not, an operand is geometry of the solid it cuts.
            ctx.report("INFO", f"object '{original.name}' is a Boolean operand of "
                                f"'{operands[original]}': part of that solid, not exported on its own")
            continue
        xf = matrix(inst.matrix_world)
        if ob.type == "LIGHT":
            light(ctx, ob, xf)
            continue
        # Instances a geometry-nodes instancer makes of its own geometry are not the
        # original object's solid; real objects (even instanced ones) are.
        own_geometry = parent is None or parent.original is None or parent.original != original
        proto = (lsystems.lsystem_prototype(ctx, ob) if is_lsystem
                 else csg.csg_prototype(ctx, ob) if own_geometry else None)
        if proto is None:
            proto = prototype(ctx, ob, ob.data)
        if proto < 0:
            continue
        name = original.name if original is not None else ob.name
        if abs(np.linalg.det(xf[:, :3])) <= 1e-12 * max(np.abs(xf[:, :3]).max(), 1e-300) ** 3:
            ctx.report("WARNING", f"object '{name}': zero scale, skipped")
            continue
        exclude, res = _object_settings(original)
        if parent is not None and parent.original is not None and parent.original != original:
            # Instanced geometry also follows its instancer: excluding a collection
            # instance or particle emitter excludes what it instances.
            p_exclude, p_res = _object_settings(parent.original)
            exclude = exclude or p_exclude
            res = res or p_res
        ol_key = ol_name = None
        if router and not exclude:
            # Duplis (collection instances, particles) belong where their instancer is.
            instancer = parent.original if parent is not None and parent.original is not None else None
            ol_key = router.route(instancer if instancer is not None and instancer != original
                                  else original)
        own_lightmap = not exclude
        if ol_key is not None:
            router.add(ol_key, len(ctx.scene.instances))
            ol_empty = router.colls[ol_key][1]
            ol_name = ol_empty.name
            # Under a non-backup OL the hits go to the OL only (compile_scene does the same).
            own_lightmap = bool(ol_empty.photon_lightmaps.ol_backup)
        ctx.scene.instances.append(Instance(proto, xf, name=name, lightmap=own_lightmap,
                                             lightmap_resolution=res))
        ctx.map.instances.append(InstanceRecord(
            name, bool(inst.is_instance),
            (parent.original.name if parent is not None and parent.original is not None else None),
            tuple(inst.persistent_id), proto, own_lightmap, ol_name))
    for t in sorted(skipped_types):
        ctx.report("WARNING", f"{t.lower()} objects are not supported and were skipped")
    if router:
        seed = int(settings.seed) if settings is not None else 0
        ctx.scene.orientation_lightmaps, ctx.map.orientation_lightmaps = router.build(seed)

    r = bscene.render
    if resolution is None:
        resolution = (r.resolution_x * r.resolution_percentage // 100,
                      r.resolution_y * r.resolution_percentage // 100)
    w, h = (max(int(v), 1) for v in resolution)
    cam_ob = camera_override if camera_override is not None else bscene.camera
    if cam_ob is not None and not cam_ob.is_evaluated:
        cam_ob = cam_ob.evaluated_get(dg)
    ctx.scene.camera = camera(ctx, cam_ob, w, h)
    ctx.scene.environment = world(ctx, bscene.world)
    return ctx.scene, ctx.map


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


