"""Operators: entry points only (operators/bake.py, operators/csg_primitives.py,
operators/lsystem.py, operators/orientation_lightmaps.py) and the RenderEngine (render_engine.py).
Where the user finds them (menus, the Bake panel) is ui/menus.py.
"""
import bpy

from ..bake import bake_api, pipeline
from ..bake import render as render_pipeline
from . import bake, csg_primitives, lsystem
from . import orientation_lightmaps as ol_ops

# The photon pass kept for Blender's own Bake button is freed when that bake ends.
_HANDLERS = ("object_bake_complete", "object_bake_cancel")
# A bake's kept photon pass belongs to the file it was traced in.
_FILE_HANDLERS = ("load_pre",)
# The light a render keeps for the next frame is let go when the render job (a
# still or a whole animation) ends, unless Persistent Data is on; and on file load.
_RENDER_HANDLERS = ("render_complete", "render_cancel", "load_pre")

classes = bake.classes + csg_primitives.classes + lsystem.classes + ol_ops.classes


@bpy.app.handlers.persistent
def _free_bake_cache(*_args):
    bake_api.clear_cache()
    render_pipeline.LIGHT.clear()


@bpy.app.handlers.persistent
def _end_of_render_job(*args):
    scene = args[0] if args and isinstance(args[0], bpy.types.Scene) else None
    keep = scene is not None and scene.render.use_persistent_data
    render_pipeline.LIGHT.end_of_job(keep=keep)


@bpy.app.handlers.persistent
def _free_bake_light(*_args):
    pipeline.BAKE_LIGHT.clear()


def _handler_pairs():
    return ([(h, _free_bake_cache) for h in _HANDLERS]
            + [(h, _end_of_render_job) for h in _RENDER_HANDLERS]
            + [(h, _free_bake_light) for h in _FILE_HANDLERS])


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for h, fn in _handler_pairs():
        handlers = getattr(bpy.app.handlers, h)
        if fn not in handlers:
            handlers.append(fn)
    # Editing a Text does not re-evaluate Geometry Nodes: L-system previews follow their text.
    lsystem.register_timer()


def unregister():
    lsystem.unregister_timer()
    for h, fn in _handler_pairs():
        handlers = getattr(bpy.app.handlers, h)
        if fn in handlers:
            handlers.remove(fn)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    bake_api.clear_cache()
    render_pipeline.LIGHT.clear()
    pipeline.BAKE_LIGHT.clear()
