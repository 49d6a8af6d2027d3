"""Registers the add-on's parts in order; each listed submodule has register()/unregister().

Order matters: properties before anything that reads them, the render engine
before the panels that poll for it. Unregistering runs in reverse.
"""
import importlib

MODULES = ["properties", "render_engine", "ui", "operators"]

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
