"""Where the user finds the operators: the Render and Object menus, Add > Photon
CSG Primitive, Add > Photon L-System, the orientation-lightmap entries, and a Bake
panel in Render Properties.

The panel exists because Blender's own Bake panel belongs to Cycles (it is shown
for Cycles only); with this engine active it offers Blender's Bake button, which
lands in bake/bake_api.py, next to our lightmap bake.
"""
import bpy

from ..operators import bake, csg_primitives, lsystem
from ..operators import orientation_lightmaps as ol_ops
from ..operators.render_engine import ENGINE_ID


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


def menu_add(self, context):
    self.layout.operator_menu_enum(csg_primitives.PHOTON_LIGHTMAPS_OT_csg_primitive_add.bl_idname, "kind",
                                   text="Photon CSG Primitive", icon="MOD_BOOLEAN")
    self.layout.operator_menu_enum(lsystem.PHOTON_LIGHTMAPS_OT_lsystem_add.bl_idname, "preset",
                                   text="Photon L-System", icon="OUTLINER_OB_CURVES")


def ol_menu(self, context):
    layout = self.layout
    layout.separator()
    layout.operator(ol_ops.PHOTON_LIGHTMAPS_OT_add_orientation_lightmap.bl_idname, icon="SPHERE")
    layout.operator(ol_ops.PHOTON_LIGHTMAPS_OT_remove_orientation_lightmap.bl_idname)
    layout.operator_context = "INVOKE_DEFAULT"
    layout.operator(ol_ops.PHOTON_LIGHTMAPS_OT_suggest_orientation_lightmaps.bl_idname)
    layout.operator(ol_ops.PHOTON_LIGHTMAPS_OT_bake_orientation_lightmaps.bl_idname, icon="LIGHT")


def export_menu(self, context):
    self.layout.operator("photon_lightmaps.export_gltf", text="glTF with Photon Lightmaps (.glb)")


_MENUS = (("TOPBAR_MT_render", _menu), ("VIEW3D_MT_object", _menu), ("VIEW3D_MT_add", menu_add),
          ("VIEW3D_MT_object", ol_menu), ("TOPBAR_MT_file_export", export_menu))
classes = (PHOTON_LIGHTMAPS_PT_bake,)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for name, fn in _MENUS:
        getattr(bpy.types, name).append(fn)


def unregister():
    for name, fn in reversed(_MENUS):
        getattr(bpy.types, name).remove(fn)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
