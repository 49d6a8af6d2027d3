"""User interface: the PropertyGroups (properties.py, registered first by registration.py),
Properties-editor panels (panels.py), menus and the Bake panel (menus.py) and the
built-in panels shown with this engine (compat_panels.py)."""
import bpy

from . import compat_panels, menus, panels


def register():
    for cls in panels.classes:
        bpy.utils.register_class(cls)
    menus.register()
    compat_panels.register()


def unregister():
    compat_panels.unregister()
    menus.unregister()
    for cls in reversed(panels.classes):
        bpy.utils.unregister_class(cls)
