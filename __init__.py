"""Photon Lightmaps: lightmap-based photon tracing for Blender (A. Wilkie, TU Wien 2001).

The tracer core is `engine/` and never imports bpy; importing this package
outside Blender (tests, the CLI) must not need Blender either, so bpy is only
touched inside register()/unregister().
"""


def register():
    from . import blender_addon
    blender_addon.register()


def unregister():
    from . import blender_addon
    blender_addon.unregister()
