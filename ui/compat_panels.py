"""Built-in panels shown with this engine: Blender's engine-generic ones, minus those that mislead."""
import bpy

from ..operators.render_engine import ENGINE_ID

# Built-in panels that make sense for this engine (dimensions, output, camera, object
# data, ...), found by the BLENDER_RENDER marker. Left out: panels that would
# mislead (previews, EEVEE light probes, the bare light panel, which ui/panels.py
# replaces with one that shows the settings this engine reads).
_EXCLUDED_PANELS = {
    "DATA_PT_preview", "DATA_PT_light", "NODE_DATA_PT_light", "DATA_PT_spot",
    "DATA_PT_context_lightprobe", "DATA_PT_lightprobe", "DATA_PT_lightprobe_visibility",
    "DATA_PT_lightprobe_parallax", "DATA_PT_lightprobe_display",
    "EEVEE_MATERIAL_PT_viewport_settings", "MATERIAL_PT_freestyle_line",
}
_added_to = []


def get_panels():
    out = []
    stack = list(bpy.types.Panel.__subclasses__())
    seen = set()
    while stack:
        cls = stack.pop()
        if cls in seen:
            continue
        seen.add(cls)
        stack.extend(cls.__subclasses__())
        engines = getattr(cls, "COMPAT_ENGINES", None)
        # Only BLENDER_RENDER marks engine-generic panels; Cycles' own panels share one
        # COMPAT_ENGINES set across all of them, so adding to it would show them all.
        if isinstance(engines, set) and "BLENDER_RENDER" in engines and cls.__name__ not in _EXCLUDED_PANELS:
            out.append(cls)
    return out


def register():
    for panel in get_panels():
        if ENGINE_ID not in panel.COMPAT_ENGINES:
            panel.COMPAT_ENGINES.add(ENGINE_ID)
            _added_to.append(panel)


def unregister():
    for panel in _added_to:
        panel.COMPAT_ENGINES.discard(ENGINE_ID)
    _added_to.clear()
