"""Registers the add-on's parts in order; each listed submodule has register()/unregister().

Order matters: the PropertyGroups before anything that reads them, the render
engine before the operators and panels that poll for it, the panels last (they
draw the operators). Unregistering runs in reverse.
"""
import importlib

MODULES = ["ui.properties", "operators.render_engine", "operators", "ui"]

_registered = []


def _module(name):
    return importlib.import_module(f"{__package__}.{name}")


def is_registered():
    return bool(_registered)


def register():
    if _registered:
        return
    try:
        for name in MODULES:
            mod = _module(name)
            mod.register()
            _registered.append(mod)
    except Exception:
        # Leave Blender as it was rather than half-registered.
        unregister()
        raise


def unregister():
    while _registered:
        _registered.pop().unregister()


def engine_registered():
    """True when some copy of the add-on (e.g. the installed extension) has registered the engine."""
    import bpy

    from .operators.render_engine import ENGINE_ID
    return any(getattr(c, "bl_idname", None) == ENGINE_ID and c.is_registered
               for c in bpy.types.RenderEngine.__subclasses__())


def ensure_registered():
    """Registers the add-on unless some copy of it already is (the one copy, for the CLI and demo)."""
    if not engine_registered():
        from . import register as register_addon
        register_addon()
