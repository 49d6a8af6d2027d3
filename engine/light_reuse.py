"""Stored light reused across frames: the thesis's view independence, as a cache.

A camera animation compiles the same scene and traces the same photons every
frame; only the camera moves. `light_key` digests everything the compiled
scene and its photon pass depend on (the scene without its camera, and the
settings the photon pass reads), and `LightCache` keeps the last traced scene
under that key. A frame whose key matches renders the kept light through its
own camera (`with_camera`): the same seed gives the same photons, so the frame
is the image a single-frame render of it gives. Anything else that moves (an
object, a light, a material, the photon count) changes the key, and the frame
is traced afresh.
"""
import dataclasses
import hashlib

import numpy as np

from .compile import checked_camera


def light_key(scene, settings):
    """Digest of what the photon pass of `scene` under `settings` depends on
    (not the camera, the scene's name, the pixel samples or the denoiser)."""
    h = hashlib.sha256()
    _feed(h, dataclasses.replace(scene, camera=None, name=""), {})
    _feed(h, (int(settings.photons), int(settings.max_bounces), int(settings.seed),
              bool(settings.gathers)), {})
    return h.hexdigest()


def _feed(h, x, seen):
    """Adds x to the digest: arrays by dtype, shape and bytes; dataclasses and
    plain objects field by field (a second visit of an object, as in the cyclic
    graphs of L-systems, by its first visit's number); anything else by repr,
    which for an object without fields names its address, so such a scene never
    matches another: a missed reuse, never a wrong one."""
    if x is None or isinstance(x, (bool, int, float, str, bytes, np.generic)):
        h.update(f"{type(x).__name__}:{x!r};".encode())
    elif isinstance(x, np.ndarray):
        h.update(f"nd{x.dtype.str}{x.shape};".encode())
        if x.dtype.hasobject:
            for item in x.reshape(-1):
                _feed(h, item, seen)
        else:
            h.update(np.ascontiguousarray(x).data)
    elif isinstance(x, (list, tuple)):
        h.update(f"{type(x).__name__}{len(x)}[".encode())
        for item in x:
            _feed(h, item, seen)
        h.update(b"]")
    elif isinstance(x, dict):
        h.update(f"dict{len(x)}{{".encode())
        for k in sorted(x, key=repr):
            _feed(h, k, seen)
            _feed(h, x[k], seen)
        h.update(b"}")
    elif isinstance(x, (set, frozenset)):
        h.update(f"set{sorted(map(repr, x))};".encode())
    elif id(x) in seen:
        h.update(f"ref{seen[id(x)]};".encode())
    elif dataclasses.is_dataclass(x) or hasattr(x, "__dict__"):
        seen[id(x)] = len(seen)
        h.update(f"{type(x).__module__}.{type(x).__qualname__}(".encode())
        names = ([f.name for f in dataclasses.fields(x)] if dataclasses.is_dataclass(x)
                 else sorted(vars(x)))
        for name in names:
            h.update(name.encode())
            _feed(h, getattr(x, name), seen)
        h.update(b")")
    else:
        h.update(repr(x).encode())


def with_camera(cs, camera):
    """The traced compiled scene `cs` seen through `camera` (an engine Camera); the
    lightmaps, BVHs and everything else are shared, not copied."""
    return dataclasses.replace(cs, camera=checked_camera(camera, cs.n_bands))


class LightCache:
    """The last traced scene, its key, the frame it was traced for and a summary
    of the run that traced it (for the reusing frames' reports); `held` keeps it
    past the end of a render job (the CLI's frame loop)."""

    def __init__(self):
        self.key = self.cs = self.frame = self.summary = None
        self.holds = 0

    def get(self, key):
        """The kept compiled scene when `key` matches, else None (and the kept one
        is let go, so a changed scene never holds two in memory)."""
        if self.key is not None and self.key == key:
            return self.cs
        self.clear()
        return None

    def put(self, key, cs, frame, summary):
        self.key, self.cs, self.frame, self.summary = key, cs, frame, summary

    def clear(self):
        self.key = self.cs = self.frame = self.summary = None

    def end_of_job(self, keep=False):
        """A render job ended: the light is let go unless held or `keep` (Blender's
        Persistent Data)."""
        if not (self.holds or keep):
            self.clear()

    def held(self):
        cache = self

        class _Hold:
            def __enter__(self):
                cache.holds += 1
                return cache

            def __exit__(self, *exc):
                cache.holds -= 1
                if not cache.holds:
                    cache.clear()
        return _Hold()
