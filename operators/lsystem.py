"""Add > Photon L-System, Update Preview, Edit Grammar, and the timer that keeps previews in
step with their grammar text. Each calls one function of bake/lsystem_preview.py, which
writes the preview; export/lsystems.py holds the conventions (where the grammar is stored,
the object settings).
"""
import bpy
from bpy.props import EnumProperty, FloatVectorProperty

from .. import messages
from ..bake.lsystem_preview import check_texts, new_lsystem_object, update_preview
from ..export import lsystems
from .common import select_only

# Editing a Text does not re-evaluate Geometry Nodes: the timer polls the grammar texts.
TEXT_POLL_SECONDS = 0.5


# ---------------------------------------------------------------- timer

def _timer():
    try:
        check_texts(settle=True)
    except Exception:  # noqa: BLE001  (a timer that raises is unregistered by Blender)
        import traceback
        traceback.print_exc()
    return TEXT_POLL_SECONDS


def register_timer():
    if not bpy.app.timers.is_registered(_timer):
        bpy.app.timers.register(_timer, first_interval=TEXT_POLL_SECONDS, persistent=True)


def unregister_timer():
    if bpy.app.timers.is_registered(_timer):
        bpy.app.timers.unregister(_timer)


# ---------------------------------------------------------------- operators

_PRESET_ITEMS = [(n, lab, desc) for n, lab, desc in lsystems.presets()]


class PHOTON_LIGHTMAPS_OT_lsystem_add(bpy.types.Operator):
    """Add an L-system object: the grammar in a Text datablock, previewed by Geometry Nodes; renders trace it"""
    bl_idname = "photon_lightmaps.lsystem_add"
    bl_label = "Photon L-System"
    bl_options = {"REGISTER", "UNDO"}

    preset: EnumProperty(name="Preset", items=_PRESET_ITEMS, description="Grammar to start from")
    location: FloatVectorProperty(name="Location", subtype="TRANSLATION", size=3)

    def invoke(self, context, event):
        self.location = context.scene.cursor.location
        return self.execute(context)

    def execute(self, context):
        try:
            ob = new_lsystem_object(preset=self.preset, location=tuple(self.location),
                                    collection=context.collection)
        except Exception as exc:  # noqa: BLE001  (reported to the user instead of a traceback)
            return messages.operator_failed(self, exc)
        select_only(context, ob)
        return {"FINISHED"}


class PHOTON_LIGHTMAPS_OT_lsystem_update(bpy.types.Operator):
    """Regenerate the viewport preview of the active L-system object from its grammar"""
    bl_idname = "photon_lightmaps.lsystem_update"
    bl_label = "Update Preview"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return lsystems.is_lsystem(context.object)

    def execute(self, context):
        status = update_preview(context.object)
        if status:
            self.report({"WARNING"}, status)
        return {"FINISHED"}


def text_editor_area(context):
    """The first Text editor of the current screen, None if there is none."""
    screen = getattr(context, "screen", None)
    for area in (screen.areas if screen is not None else ()):
        if area.type == "TEXT_EDITOR":
            return area
    return None


class PHOTON_LIGHTMAPS_OT_lsystem_edit_text(bpy.types.Operator):
    """Show the L-system's grammar in the Text editor"""
    bl_idname = "photon_lightmaps.lsystem_edit_text"
    bl_label = "Edit Grammar"

    @classmethod
    def poll(cls, context):
        return lsystems.is_lsystem(context.object) and text_editor_area(context) is not None

    def execute(self, context):
        area = text_editor_area(context)
        area.spaces.active.text = lsystems.grammar_text(context.object)
        return {"FINISHED"}


classes = (PHOTON_LIGHTMAPS_OT_lsystem_add, PHOTON_LIGHTMAPS_OT_lsystem_update,
           PHOTON_LIGHTMAPS_OT_lsystem_edit_text)
