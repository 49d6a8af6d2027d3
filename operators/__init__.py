"""Operators (operators/bake.py, operators/csg_primitives.py) and where the user finds
them: the Render menu, the Object menu, a Bake panel in Render Properties, and
Add > Photon CSG Primitive in the 3D viewport.

The panel exists because Blender's own Bake panel belongs to Cycles (it is shown
for Cycles only); with this engine active it offers Blender's Bake button, which
lands in bake/bake_api.py, next to our lightmap bake.
"""
import bpy

from ..bake import bake_api
from . import bake, csg_primitives
from . import orientation_lightmaps as ol_ops
from .render_engine import ENGINE_ID


def _menu(self, context):
    layout = self.layout
    layout.separator()
    layout.operator_context = "INVOKE_DEFAULT"
    layout.operator(bake.PHOTON_LIGHTMAPS_OT_bake.bl_idname, icon="LIGHT")
    layout.operator(bake.PHOTON_LIGHTMAPS_OT_remove_lightmap_hook.bl_idname)


class PHOTON_LIGHTMAPS_PT_bake(bpy.types.Panel):
    bl_label = "Bake"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_options = {"DEFAULT_CLOSED"}
    COMPAT_ENGINES = {ENGINE_ID}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.operator_context = "INVOKE_DEFAULT"
        col.operator(bake.PHOTON_LIGHTMAPS_OT_bake.bl_idname, icon="LIGHT")
        col.operator(bake.PHOTON_LIGHTMAPS_OT_remove_lightmap_hook.bl_idname, icon="X")
        col.operator(ol_ops.PHOTON_LIGHTMAPS_OT_bake_orientation_lightmaps.bl_idname, icon="LIGHT")
        col.operator(ol_ops.PHOTON_LIGHTMAPS_OT_suggest_orientation_lightmaps.bl_idname)

        # Blender's bake into the active Image Texture node (Diffuse, Emit, Combined).
        cbk = context.scene.render.bake
        box = layout.box()
        box.label(text="Bake to Active Image Texture")
        box.prop(cbk, "type")
        if cbk.type in {"DIFFUSE", "COMBINED"}:
            row = box.row(align=True, heading="Contributions")
            row.prop(cbk, "use_pass_direct", toggle=True)
            row.prop(cbk, "use_pass_indirect", toggle=True)
            if cbk.type == "DIFFUSE":
                row.prop(cbk, "use_pass_color", toggle=True)
            else:
                sub = box.column(heading="Include", align=True)
                sub.prop(cbk, "use_pass_diffuse")
                sub.prop(cbk, "use_pass_emit")
        box.prop(cbk, "margin_type", text="Margin Type")
        box.prop(cbk, "margin", text="Size")
        box.prop(cbk, "use_clear", text="Clear Image")
        op = box.operator("object.bake", icon="RENDER_STILL")
        op.type = cbk.type


_MENUS = ("TOPBAR_MT_render", "VIEW3D_MT_object")
# The photon pass kept for Blender's own Bake button is freed when that bake ends.
_HANDLERS = ("object_bake_complete", "object_bake_cancel")

classes = bake.classes + csg_primitives.classes + ol_ops.classes + (PHOTON_LIGHTMAPS_PT_bake,)


@bpy.app.handlers.persistent
def _free_bake_cache(*_args):
    bake_api.clear_cache()


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for name in _MENUS:
        getattr(bpy.types, name).append(_menu)
    bpy.types.VIEW3D_MT_add.append(csg_primitives.menu_add)
    bpy.types.VIEW3D_MT_object.append(ol_ops.menu)
    for h in _HANDLERS:
        handlers = getattr(bpy.app.handlers, h)
        if _free_bake_cache not in handlers:
            handlers.append(_free_bake_cache)


def unregister():
    for h in _HANDLERS:
        handlers = getattr(bpy.app.handlers, h)
        if _free_bake_cache in handlers:
            handlers.remove(_free_bake_cache)
    bpy.types.VIEW3D_MT_object.remove(ol_ops.menu)
    bpy.types.VIEW3D_MT_add.remove(csg_primitives.menu_add)
    for name in _MENUS:
        getattr(bpy.types, name).remove(_menu)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    bake_api.clear_cache()
