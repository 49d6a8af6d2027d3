"""Operators: entry points only (operators/bake.py, operators/csg_primitives.py,
operators/lsystem.py, operators/orientation_lightmaps.py) and the RenderEngine (render_engine.py).
Where the user finds them (menus, the Bake panel) is ui/menus.py.
"""
import bpy

from ..bake import bake_api
from . import bake, csg_primitives, lsystem
from . import orientation_lightmaps as ol_ops

# The photon pass kept for Blender's own Bake button is freed when that bake ends.
_HANDLERS = ("object_bake_complete", "object_bake_cancel")

classes = bake.classes + csg_primitives.classes + lsystem.classes + ol_ops.classes


@bpy.app.handlers.persistent
def _free_bake_cache(*_args):
    bake_api.clear_cache()


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for h in _HANDLERS:
        handlers = getattr(bpy.app.handlers, h)
        if _free_bake_cache not in handlers:
            handlers.append(_free_bake_cache)
    # Editing a Text does not re-evaluate Geometry Nodes: L-system previews follow their text.
    lsystem.register_timer()


def unregister():
    lsystem.unregister_timer()
    for h in _HANDLERS:
        handlers = getattr(bpy.app.handlers, h)
        if _free_bake_cache in handlers:
            handlers.remove(_free_bake_cache)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    bake_api.clear_cache()
