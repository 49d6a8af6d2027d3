"""The "Photon Lightmaps" RenderEngine: each callback delegates to bake/ in a line, as Cycles'
add-on does, so the class is only Blender's entry point."""
import bpy

from ..bake import bake_api, render

ENGINE_ID = "PHOTON_LIGHTMAPS"


class PhotonLightmapsRenderEngine(bpy.types.RenderEngine):
    bl_idname = ENGINE_ID
    bl_label = "Photon Lightmaps"
    bl_use_preview = False
    bl_use_postprocess = True
    # Materials are Cycles/EEVEE shader nodes (Principled BSDF), so keep those nodes visible,
    # and let EEVEE draw material previews in the viewport.
    bl_use_shading_nodes_custom = False
    bl_use_eevee_viewport = True

    def render(self, depsgraph):
        render.render(self, depsgraph)

    def bake(self, depsgraph, obj, pass_type, pass_filter, width, height):
        bake_api.bake(self, depsgraph, obj, pass_type, pass_filter, width, height)

    def _photon_should_stop(self):
        # Esc during Blender's bake. (A Python name of our own: RNA functions such as
        # test_break take precedence over class attributes, so tests patch this one.)
        return bool(self.test_break())


def register():
    bpy.utils.register_class(PhotonLightmapsRenderEngine)


def unregister():
    bpy.utils.unregister_class(PhotonLightmapsRenderEngine)
