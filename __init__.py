"""Photon Lightmaps: lightmap-based photon tracing for Blender (A. Wilkie, TU Wien 2001).

The tracer core is `engine/` and never imports bpy; importing this package
outside Blender (tests, the CLI) must not need Blender either, so bpy is only
touched inside register()/unregister().
"""


def register():
    from . import registration
    registration.register()


def unregister():
    from . import registration
    registration.unregister()
