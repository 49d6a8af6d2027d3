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

Bakes keep their photon pass the same way (`BakeLight`): baking other objects
of an unchanged scene reuses the last pass instead of tracing it again, from
memory or from a folder of saved passes (the CLI's --light-cache), so a
rebaked object reads the very light its neighbours were baked from.
"""
import copy
import dataclasses
import hashlib
import json
import os

import numpy as np

from .compile import checked_camera
from .lightmaps.lightmap import STATE_DILATED, Lightmaps


def light_key(scene, settings):
    """Digest of what the photon pass of `scene` under `settings` depends on
    (not the camera, the scene's name, the pixel samples or the denoiser)."""
    h = hashlib.sha256()
    _feed(h, dataclasses.replace(scene, camera=None, name=""), {})
    _feed(h, (int(settings.photons), int(settings.max_bounces), int(settings.seed),
              bool(settings.gathers)), {})
    return h.hexdigest()


def bake_key(scene, settings):
    """Digest of what a bake's photon pass depends on: the scene without its
    camera, its name and which instances record photons (a bake records its
    targets; recording never moves a photon, so a pass that recorded more serves
    a bake of fewer), and the settings the pass reads."""
    bare = dataclasses.replace(scene, camera=None, name="",
                               instances=[dataclasses.replace(i, lightmap=False) for i in scene.instances])
    h = hashlib.sha256()
    _feed(h, bare, {})
    _feed(h, ("bake", int(settings.photons), int(settings.max_bounces), int(settings.seed),
              bool(settings.bake_gathers), bool(settings.bake_gather_lights)), {})
    return h.hexdigest()


def recording(scene):
    """Which instances of `scene` record photons on their own lightmaps (bool per instance)."""
    return np.array([bool(i.lightmap) for i in scene.instances], bool)


def covers(recorded, needs):
    """A pass that recorded `recorded` holds every lightmap a bake recording `needs` reads."""
    return recorded.shape == needs.shape and not np.any(needs & ~recorded)


def aim_sphere(cs, instances):
    """The sphere a photon pass of `cs` aimed at `instances` (engine ids; None:
    the scene) sends its aimed photons toward -> (centre, radius)."""
    from .shading import photon_aim
    sphere = None if instances is None else photon_aim.sphere_around(cs.geometry, instances)
    ls = photon_aim.aimed(cs.lights, sphere)
    return np.asarray(ls.aim_center, np.float64), float(ls.aim_radius)


def _holds(outer, inner):
    """Sphere `outer` contains sphere `inner` (both (centre, radius))."""
    gap = float(np.linalg.norm(np.asarray(outer[0]) - np.asarray(inner[0])))
    return gap + inner[1] <= outer[1] * (1.0 + 1e-9) + 1e-12


@dataclasses.dataclass
class KeptPass:
    """A bake's photon pass: its compiled scene, the lightmaps as the pass left
    them (the bake then writes its texels into the scene's own), and its stats."""
    key: str
    recording: np.ndarray        # bool per instance: what the pass recorded
    aim: tuple                   # (centre, radius) its aimed photons went toward
    cs: object
    lightmaps: object            # Lightmaps, copied after the pass
    stats: object

    def nbytes(self):
        return int(sum(a.nbytes for a in self.lightmaps))

    def serves(self, key, needs, aim_at):
        """This pass can stand in for a bake with key `key` that records `needs`
        (bool per instance) and aims at instances `aim_at` -> why not, or "" when it can."""
        if key != self.key:
            return "the scene or the photon settings changed"
        if not covers(self.recording, needs):
            return "it did not record every object baked now"
        if not _holds(self.aim, aim_sphere(self.cs, aim_at)):
            return "its photons were aimed at other objects"
        return ""

    def fresh_scene(self):
        """The kept compiled scene with the pass's lightmaps, as a bake finds it
        after the photon pass (the kept copy stays as it is)."""
        cs = copy.copy(self.cs)
        cs.lightmaps = Lightmaps(*(a.copy() for a in self.lightmaps))
        cs.info = {k: v for k, v in self.cs.info.items() if k not in ("cluster", "irradiance_cache")}
        cs.timings, cs.rays = {}, {}
        cs.__dict__.pop("bake_error", None)
        cs.__dict__.pop("bake_moments", None)
        return cs


# What a saved pass keeps: the lightmap fields its photons (and the open-area
# estimate before them) filled in; the layout (offsets, areas, split texels) comes
# from compiling the same scene again. And the flags the pass set on the scene.
_PASS_FIELDS = ("open", "flux", "flux_sq", "hits", "irradiance", "state")
_PASS_FLAGS = ("caustics_traced", "lightmaps_hold_direct")
_STATS_ARRAYS = ("emitted", "absorbed", "escaped", "truncated")


class BakeLight:
    """The last bake's photon pass (KeptPass), kept for the next bake, and the
    folder of saved passes a pipeline's runs share."""

    def __init__(self):
        self.kept = None

    def clear(self):
        self.kept = None

    def keep(self, key, needs, aim, cs, stats):
        self.kept = KeptPass(key, needs, aim, cs, Lightmaps(*(a.copy() for a in cs.lightmaps)), stats)
        return self.kept

    def take(self, key, needs, aim_at):
        """The kept pass when it serves (KeptPass.serves) -> (KeptPass or None, why not)."""
        if self.kept is None:
            return None, "no photon pass was kept"
        why = self.kept.serves(key, needs, aim_at)
        return (self.kept, "") if not why else (None, why)


def pass_file(folder, key):
    return os.path.join(folder, f"photon_pass_{key[:32]}.npz")


def save_pass(folder, kept):
    """Writes `kept` to the folder (one file per key; written whole, then renamed,
    so a reader never sees half of one) -> its path."""
    os.makedirs(folder, exist_ok=True)
    arrays = {f"lm_{name}": getattr(kept.lightmaps, name) for name in _PASS_FIELDS}
    cs = kept.cs
    if cs.caustics is not None and cs.caustics_traced:
        arrays.update({f"caustic_{name}": getattr(cs.caustics, name) for name in _PASS_FIELDS})
    arrays.update({f"stats_{name}": getattr(kept.stats, name) for name in _STATS_ARRAYS})
    meta = {"key": kept.key, "aim": [list(map(float, kept.aim[0])), float(kept.aim[1])],
            "flags": {name: bool(getattr(cs, name)) for name in _PASS_FLAGS},
            "stats": {name: getattr(kept.stats, name) for name in ("photons", "rays", "records", "seconds")},
            "stats_aim": None if kept.stats.aim is None else
            [list(map(float, kept.stats.aim[0])), float(kept.stats.aim[1])]}
    path = pass_file(folder, kept.key)
    tmp = path + ".part.npz"
    np.savez(tmp, recording=kept.recording, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    os.replace(tmp, path)
    return path


def saved_recording(folder, key):
    """What the pass saved under `key` recorded (bool per instance), or None
    when there is none (or it cannot be read)."""
    try:
        with np.load(pass_file(folder, key)) as f:
            return np.array(f["recording"], bool)
    except (OSError, KeyError, ValueError):
        return None


def load_pass(folder, key, cs, aim, stats_type):
    """The pass saved under `key` into the compiled scene `cs` (compiled with the
    saved pass's recording) -> (KeptPass, "") or (None, why not): its photons aimed
    at a sphere that misses `aim`, or its arrays do not fit `cs` (shapes, types,
    finite values, texel states: a damaged file is not read)."""
    try:
        with np.load(pass_file(folder, key)) as f:
            meta = json.loads(bytes(f["meta"]).decode())
            saved_aim = (np.asarray(meta["aim"][0], np.float64), float(meta["aim"][1]))
            if meta["key"] != key:
                return None, "the saved pass is of another scene"
            if not _holds(saved_aim, aim):
                return None, "the saved pass was aimed at other objects"
            main = {name: f[f"lm_{name}"] for name in _PASS_FIELDS}
            caustic = ({name: f[f"caustic_{name}"] for name in _PASS_FIELDS}
                       if "caustic_flux" in f.files else None)
            arrays = {name: f[f"stats_{name}"] for name in _STATS_ARRAYS}
            recorded = np.array(f["recording"], bool)
    except (OSError, KeyError, ValueError):
        return None, "the saved pass cannot be read"
    if not _fits(cs.lightmaps, main) or (caustic is not None and
                                         (cs.caustics is None or not _fits(cs.caustics, caustic))):
        return None, "the saved pass does not fit the scene (or is damaged)"
    for name in _PASS_FIELDS:
        getattr(cs.lightmaps, name)[...] = main[name]
        if caustic is not None:
            getattr(cs.caustics, name)[...] = caustic[name]
    for name, value in meta["flags"].items():
        setattr(cs, name, value)
    stats = stats_type(**meta["stats"], **arrays,
                       aim=None if meta["stats_aim"] is None else
                       (np.asarray(meta["stats_aim"][0]), float(meta["stats_aim"][1])))
    return KeptPass(key, recorded, saved_aim, cs, Lightmaps(*(a.copy() for a in cs.lightmaps)), stats), ""


def _fits(lm, arrays):
    """Saved pass arrays that can go into `lm` as they are: its shapes and types,
    finite values, and texel states the kernels know."""
    for name in _PASS_FIELDS:
        a, b = getattr(lm, name), arrays[name]
        if a.shape != b.shape or a.dtype != b.dtype:
            return False
        if b.dtype.kind == "f" and not np.all(np.isfinite(b)):
            return False
    state = arrays["state"]
    return bool(np.all((state >= 0) & (state <= STATE_DILATED)))


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
