"""User interface: the PropertyGroups (properties.py, registered first by registration.py),
Properties-editor panels (panels.py) and the built-in panels shown with this engine (compat_panels.py)."""
import bpy

from . import compat_panels, panels


def register():
    for cls in panels.classes:
        bpy.utils.register_class(cls)
    compat_panels.register()


def unregister():
    compat_panels.unregister()
    for cls in reversed(panels.classes):
        bpy.utils.unregister_class(cls)
