"""What the user is told when a run fails or warns: one text for the CLI and for Blender.

A user error (bad scene data, a missing file, an option value out of range) is
a SceneError (engine/core/scene.py; InputError below is one for what is not scene
data). Its message starts with the culprit, "<object or setting>: <what is
wrong and what to do>", and is shown as it is: the CLI prints
"error: <message>" and exits 2 (cli.main), Blender shows it with report() or
RenderEngine.error_set. Any other exception is a bug: "internal error:
<type>: <message>", exit 1, and the traceback goes to the console.

LAST keeps the last render's or bake's warnings (and error) per scene for the
UI panel (ui/panels.py).
"""
import time

from .engine.core.scene import SceneError


class InputError(SceneError):
    """Bad input that is not scene data: a missing or unreadable file, an option value, no camera."""


def is_user_error(exc):
    # OSError: a file that cannot be read or written is the user's to fix, not a bug.
    return isinstance(exc, (SceneError, OSError))


def describe(exc):
    """The one-line text for an exception (without the "error: " prefix)."""
    if isinstance(exc, SceneError):
        text = str(exc)
    elif isinstance(exc, OSError) and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}" if exc.filename else exc.strerror
    else:
        text = f"internal error: {type(exc).__name__}: {exc}"
    return " ".join(text.split())   # one line, whatever the message held


DEBUG_HINT = " (start Blender with --debug, or set PHOTON_LIGHTMAPS_DEBUG=1, for the traceback)"


def bug_text(exc):
    """describe(exc), and for a bug its traceback on the console where one was asked
    for (Blender's --debug, PHOTON_LIGHTMAPS_DEBUG), else a hint how to get it."""
    text = describe(exc)
    if is_user_error(exc):
        return text
    import os
    try:
        import bpy
        debug = bool(bpy.app.debug)
    except Exception:  # noqa: BLE001  (no Blender: the variable alone decides)
        debug = False
    if debug or os.environ.get("PHOTON_LIGHTMAPS_DEBUG"):
        import traceback
        traceback.print_exception(exc)
        return text
    return text + DEBUG_HINT


def operator_failed(op, exc, scene=None, source="bake"):
    """report()s a failed operator's error (bugs also print their traceback) -> {'CANCELLED'}."""
    text = describe(exc)
    if not is_user_error(exc):
        import traceback
        traceback.print_exception(exc)
        text += " (see the system console for the traceback)"
    op.report({"ERROR"}, text)
    if scene is not None:
        record(scene.name, source, [], error=text)
    return {"CANCELLED"}


# scene name -> {"source": "render" | "bake" | "orientation bake", "warnings": [...], "error": str | None,
# "time": time.time()}
LAST = {}


def record(scene_name, source, warnings, error=None):
    LAST[scene_name] = {"source": source, "warnings": list(dict.fromkeys(warnings)), "error": error,
                        "time": time.time()}


def last(scene_name):
    return LAST.get(scene_name)
