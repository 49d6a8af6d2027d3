"""The engine's two exceptions: bad input, and a run the host stopped."""


class SceneError(ValueError):
    """Raised for scene input the tracer cannot represent (names the culprit)."""


class Cancelled(Exception):
    """The host asked to stop (e.g. Esc in Blender); partial results were discarded."""
