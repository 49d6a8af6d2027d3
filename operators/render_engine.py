"""The "Photon Lightmaps" RenderEngine: each callback delegates to bake/ in a line, as Cycles'
add-on does, so the class is only Blender's entry point."""
import bpy

from ..bake import bake_api, render, viewport

ENGINE_ID = "PHOTON_LIGHTMAPS"


class PhotonLightmapsRenderEngine(bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "Photon Lightmaps"
    bl_use_preview = False
    bl_use_postprocess = True
    # Materials are Cycles/EEVEE shader nodes (Principled BSDF), so keep those nodes visible,
    # and let EEVEE draw Material Preview; Rendered shading is ours (view_update, view_draw).
    bl_use_shading_nodes_custom = False
    bl_use_eevee_viewport = True

    def render(self, depsgraph):
        render.render(self, depsgraph)

    def bake(self, depsgraph, obj, pass_type, pass_filter, width, height):
        bake_api.bake(self, depsgraph, obj, pass_type, pass_filter, width, height)

    def view_update(self, context, depsgraph):
        viewport.view_update(self, context, depsgraph)

    def view_draw(self, context, depsgraph):
        viewport.view_draw(self, context, depsgraph)

    def __del__(self):
        # Blender may have freed the engine's data (ReferenceError), or Python be shutting
        # down with this module's globals gone: then there is no worker left to stop.
        if viewport is None:
            return
        try:
            viewport.free(self)
        except ReferenceError:
            pass

    def _photon_should_stop(self):
        # Esc during Blender's bake. (A Python name of our own: RNA functions such as
        # test_break take precedence over class attributes, so tests patch this one.)
        return bool(self.test_break())


def _redraw_while_warming():
    """Timer: the render panel's "Preparing kernels" line follows the warm-up."""
    from ..engine import warmup
    w = warmup.status()
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == "PROPERTIES":
                area.tag_redraw()
    return None if w is None or w.finished.is_set() else 1.0


def start_warmup():
    """Kernels compile on a background thread from the moment the add-on is enabled
    (engine/warmup.py), so an interactive user's first F12 does not wait minutes.
    Headless runs (the CLI, pipelines, tests) compile what they use, or run
    `python -m photon_lightmaps warmup`."""
    from ..engine import warmup
    if bpy.app.background or warmup.is_warm():
        return None
    w = warmup.start()
    if not bpy.app.timers.is_registered(_redraw_while_warming):
        bpy.app.timers.register(_redraw_while_warming, first_interval=1.0, persistent=True)
    return w


def register():
    bpy.utils.register_class(PhotonLightmapsRenderEngine)
    start_warmup()


def unregister():
    if bpy.app.timers.is_registered(_redraw_while_warming):
        bpy.app.timers.unregister(_redraw_while_warming)
    bpy.utils.unregister_class(PhotonLightmapsRenderEngine)
