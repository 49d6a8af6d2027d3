"""Kernel warm-up: compile the kernels before a render needs them.

On a new machine or version the first render waits for numba to compile its
kernels (docs/kernels.md). A family is one pass (a render, a bake) on a tiny
scene of one kind of geometry the kernels specialise on (engine/core/features.py);
running it compiles its kernels into the on-disk cache.

* `WarmUp` compiles every family, two at a time in helper processes (numba
  compiles on one core per process): `python -m photon_lightmaps warmup`,
  and Blender in the background from the moment the add-on is enabled
  (`start`; `status` is what the render panel shows, and a render waits for it).
* `ahead` (through session.compile) compiles the passes that follow a
  host's photon pass in a helper process while the host compiles its scene
  and traces; `join` (session.render, session.bake_texels) waits for them, and
  the host then loads them from the cache.

The processes share one cache folder; engine/core/kernel_cache.py keeps their saves apart.
"""
import atexit
import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, replace

import numpy as np

from . import demo_scenes, session
from .core import features
from .core.scene import (
    CSGNode, Instance, OrientationLightmap, Primitive, Prototype, compose, scale, translate)

TREE = "axiom: F\nderivation length: 2\nangle: 25.7\nproduction:\nF --> F[+F]F[-F]F\n"


def _room(with_primitives=True, ol=True):
    s = demo_scenes.cornell_box(width=8, height=8, with_primitives=with_primitives)
    if ol:      # the ceiling shares an orientation lightmap: the OL kernels too (the floor
        # keeps its lightmap: the tall box standing on it compiles the open-area kernels)
        s.orientation_lightmaps.append(OrientationLightmap("wall", [1], resolution=4, samples=2000))
    return s


def _solid_room(ol=True):
    s = _room(with_primitives=False, ol=ol)
    block = CSGNode("difference", Primitive("box", transform=scale(0.3)),
                    Primitive("sphere", transform=scale(0.38)), name="block")
    s.prototypes.append(Prototype(name="block", csg=[block]))
    s.instances.append(Instance(len(s.prototypes) - 1, translate(0.0, 0.0, 0.5), name="block"))
    # a closed mesh resting on the floor: the open-area kernels compile for this kind too
    s.add_object(demo_scenes.uv_sphere_mesh(0.15, 6, 12), transform=translate(0.6, -0.6, 0.15),
                 name="pebble", lightmap=False)
    return s


def _tree():
    return demo_scenes.lsystem_studio(TREE, name="tree", width=8, height=8)


def _scene(mask, ol=True):
    """A tiny scene whose kernels specialise like those of any scene with feature `mask`.
    ol=False: no orientation lightmap and, for meshes, no primitives (kernels of
    the scene compile, which the host of a helper runs itself)."""
    if mask == features.DCSG:
        return _tree()
    s = _solid_room(ol) if mask & features.CSG else _room(with_primitives=ol, ol=ol)
    if mask & features.DCSG:
        from .core.scene import LSystem
        s.prototypes.append(Prototype(name="tree", lsystems=[LSystem(TREE, name="tree", materials=(0,))]))
        s.instances.append(Instance(len(s.prototypes) - 1, compose(translate(0.5, 0.5, 0.0), scale(0.05)),
                                    name="tree"))
    return s


def scene_mask(scene):
    """The feature mask a plain engine Scene compiles to (engine/core/features.py), as far
    as it can be told before compiling: an L-system whose grammar cannot be a
    scene graph is instanced as primitives instead (engine/geometry/assembly.py)."""
    protos = [scene.prototypes[inst.prototype] for inst in scene.instances
              if 0 <= inst.prototype < len(scene.prototypes)]
    return ((features.CSG if any(p.csg for p in protos) else 0)
            | (features.DCSG if any(p.lsystems for p in protos) else 0))


def _render(scene, photons=True):
    settings = session.Settings(photons=2000, samples=1, seed=1)
    cs = session.compile(scene)
    if photons:
        session.render_photon_pass(cs, settings)
    session.render(cs, settings)


def _bake(scene, photons=True):
    from .transport.csg_bake import chart_uv_error, full_primitive_areas, solid_leaves
    settings = session.Settings(photons=2000, seed=1, bake_gather_rays=16)
    if photons:
        cs, _ = session.compile_and_trace_bake(scene, settings)
    else:
        cs = session.compile(replace(scene, caustic_resolution=1.0))
    csg = {i for i in range(len(cs.instance_lightmaps)) if scene.prototypes[scene.instances[i].prototype].csg}
    ids = [cs.instance_lightmaps[i][0] for i in range(len(cs.instance_lightmaps))
           if i not in csg and cs.instance_lightmaps[i]]
    leaves = [(i, leaf) for i in sorted(csg) for leaf in solid_leaves(cs, i)]
    session.bake_texels(cs, ids, leaves, settings)
    for i, leaf in leaves:      # a solid's image atlas measures its leaves uncut (bake/csg_atlas.py)
        if leaf["kind"] == "prim":
            full_primitive_areas(cs, i, leaf["row"], int(cs.lightmaps.height[leaf["lightmap"]]))
    if leaves:                  # ... and the export checks its operands' UVs against the charts
        chart_uv_error("box", (1.0, 1.0, 1.0, 0.0), np.zeros((3, 3)), np.arange(3),
                       np.array([[0.1, 0.1], [0.2, 0.1], [0.1, 0.2]]), np.zeros(1, np.int64), np.full(1, 3))


PASSES = {"render": _render, "bake": _bake}


@dataclass(frozen=True)
class Family:
    """The kernels one pass compiles for one kind of scene. photons=False leaves
    out the photon pass (a helper compiling ahead of a host that traces its own)."""
    name: str
    mask: int
    pass_: str
    photons: bool = True

    def __call__(self):
        PASSES[self.pass_](_scene(self.mask, ol=self.photons), photons=self.photons)

    @property
    def spec(self):
        """The family as a helper process's argument."""
        return f"{self.mask}:{self.pass_}:{int(self.photons)}"

    @classmethod
    def parse(cls, spec):
        mask, pass_, photons = spec.split(":")
        if pass_ not in PASSES:
            raise ValueError(f"unknown pass {pass_!r}")
        return cls(f"{pass_} ({mask})", int(mask), pass_, bool(int(photons)))


# The first render first. Two run at once (lanes()), so a kind's bake comes
# after its render, whose photon pass and traversal it then loads from the cache.
FAMILIES = [
    Family("meshes and primitives: render", 0, "render"),
    Family("exact CSG solids: render", features.CSG, "render"),
    Family("meshes and primitives: bake", 0, "bake"),
    Family("L-systems: render", features.DCSG, "render"),
    Family("exact CSG solids: bake", features.CSG, "bake"),
]


def _marker(name="warmed-up"):
    # in the kernel cache's own folder, which is keyed by the engine's sources:
    # a new version warms up again
    import numba
    return os.path.join(numba.config.CACHE_DIR, name)


def _touch(path, text=""):
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as f:
            f.write(text)
    except OSError:
        pass                    # a read-only cache: it warms up again next time


def is_warm():
    """True if a warm-up has finished with this engine version and kernel cache."""
    return os.path.isfile(_marker())


def lanes():
    """Families compiled at once: numba compiles on one core, so one per core, at most two
    (each compiling process holds about a GiB)."""
    return max(1, min(2, os.cpu_count() or 1))


# --------------------------------------------------------------- helper processes
# A helper imports the engine package under its own name (`bl_ext.user_default.
# photon_lightmaps.engine` inside Blender) without running the packages above
# it (the add-on's __init__ imports bpy): numba's cache index keys hold the
# types' module paths, so the names must be the host's.
_BOOT = """
import importlib, os, sys, types
name, where = sys.argv[1], sys.argv[2]
parts = name.split(".")
for k in range(1, len(parts)):
    pkg = types.ModuleType(".".join(parts[:k]))
    pkg.__path__ = [os.path.normpath(os.path.join(where, *[os.pardir] * (len(parts) - k)))]
    sys.modules[pkg.__name__] = pkg
sys.exit(importlib.import_module(name + ".warmup").helper_main(sys.argv[3:]))
"""
_TAG = "photon_lightmaps.warmup:"


def helper_main(specs):
    """A helper process: compiles the families `specs` (Family.spec) in order and
    prints one report line per family (kernels compiled, seconds)."""
    from .core import kernel_watch
    for spec in specs:
        family = Family.parse(spec)
        t0 = time.perf_counter()
        with kernel_watch.watching() as watch:
            family()
        _touch(_marker(f"compiled-{family.mask}-{family.pass_}"))
        print(_TAG, json.dumps({"spec": spec, "seconds": time.perf_counter() - t0, "compiled": watch.compiled,
                                "kernel_seconds": watch.by_kernel}), flush=True)
    return 0


class Helper:
    """A helper process compiling families, in order, into the shared kernel cache."""

    def __init__(self, families):
        from .core import kernel_cache
        kernel_cache.install()
        self.families = list(families)
        self.reports = []               # one per family compiled, in order
        self.error = None
        self._changed = threading.Condition()
        env = dict(os.environ, NUMBA_NUM_THREADS="1")
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)   # Blender's numpy, our wheels
        pkg = __name__.rsplit(".", 1)[0]
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _BOOT, pkg, os.path.dirname(os.path.abspath(__file__)),
             *[f.spec for f in self.families]],
            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
            creationflags=getattr(subprocess, "CREATE_NO_WINDOW", 0))
        _helpers.add(self)
        self._err = []
        threading.Thread(target=self._read_errors, daemon=True).start()
        threading.Thread(target=self._read_reports, daemon=True).start()

    def _read_errors(self):
        for line in self.proc.stderr:
            self._err = (self._err + [line.decode("utf-8", "replace").rstrip()])[-5:]

    def _read_reports(self):
        for line in self.proc.stdout:
            line = line.decode("utf-8", "replace")
            if line.startswith(_TAG):
                with self._changed:
                    self.reports.append(json.loads(line[len(_TAG):]))
                    self._changed.notify_all()
        rc = self.proc.wait()
        with self._changed:
            if rc != 0 or len(self.reports) != len(self.families):
                tail = [ln for ln in self._err if ln.strip()][-1:] or [f"exit code {rc}"]
                self.error = f"a kernel helper process failed: {tail[0]}"
            self.finished = True
            self._changed.notify_all()
        _helpers.discard(self)

    finished = False

    def running(self):
        return not self.finished

    def wait(self, family=None, poll=None, interval=0.25):
        """Blocks until the helper has compiled `family` (None: all of them, and
        ended) -> True if it did. poll(helper) every `interval` s may return
        False to stop waiting (-> False)."""
        k = len(self.families) if family is None else self.families.index(family) + 1
        with self._changed:
            while len(self.reports) < k and not self.finished:
                self._changed.wait(interval)
                if poll is not None and len(self.reports) < k and not self.finished and poll(self) is False:
                    return False
            if family is None:
                while not self.finished:
                    self._changed.wait(interval)
            return len(self.reports) >= k

    def stop(self):
        if self.proc.poll() is None:
            self.proc.kill()
        _helpers.discard(self)


_helpers = set()


@atexit.register
def _stop_helpers():
    # a host that ends (a CLI render that failed, Blender quitting) leaves no compiler behind
    for h in list(_helpers):
        h.stop()


# ------------------------------------------------------------------- the warm-up
class WarmUp:
    """One warm-up's progress: families done of total, those under way, the error if any."""

    def __init__(self):
        self.done = 0
        self.total = len(FAMILIES)
        self.under_way = []
        self.error = None
        self.seconds = 0.0
        self.reports = []           # per family: name, seconds, kernels compiled, kernel seconds
        self.finished = threading.Event()

    @property
    def fraction(self):
        return self.done / self.total if self.total else 1.0

    @property
    def current(self):
        return ", ".join(self.under_way)

    def run(self, before=None, after=None, processes=None):
        """Every family, `processes` at a time (default: lanes()); before(k, name) and
        after(k, name) around family k (1-based), called one at a time.

        With more than one lane each family compiles in a helper process (numba
        compiles under one lock per process); with one, here. An error stops the
        warm-up once the families under way end, and is kept in .error (the host
        goes on: the render then compiles what it needs itself)."""
        t0 = time.perf_counter()
        n = lanes() if processes is None else max(1, int(processes))
        todo = list(enumerate(FAMILIES, 1))
        lock = threading.Lock()

        def one(k, family):
            t = time.perf_counter()
            if n > 1 and hasattr(family, "spec"):
                h = Helper([family])
                if not h.wait():
                    raise RuntimeError(h.error or "a kernel helper process failed")
                rep = h.reports[0]
            else:
                from .core import kernel_watch
                with kernel_watch.watching() as watch:
                    family()
                rep = {"compiled": watch.compiled, "kernel_seconds": watch.by_kernel}
            return dict(rep, family=family.name, seconds=time.perf_counter() - t)

        def lane():
            while True:
                with lock:
                    if not todo or self.error is not None:
                        return
                    k, family = todo.pop(0)
                    self.under_way.append(family.name)
                    if before is not None:
                        before(k, family.name)
                try:
                    rep = one(k, family)
                except Exception as e:      # a warm-up must never take the host down
                    with lock:
                        self.under_way.remove(family.name)
                        self.error = self.error or f"{family.name}: {type(e).__name__}: {e}"
                    return
                with lock:
                    self.under_way.remove(family.name)
                    self.reports.append(rep)
                    self.done += 1
                    self.seconds = time.perf_counter() - t0
                    if after is not None:
                        after(k, family.name)

        try:
            threads = [threading.Thread(target=lane, name=f"photon_lightmaps warm-up {i}", daemon=True)
                       for i in range(1, min(n, len(todo)))]
            for t in threads:
                t.start()
            lane()
            for t in threads:
                t.join()
            if self.error is None:
                _touch(_marker(), f"{time.perf_counter() - t0:.1f} s\n")
        finally:
            self.seconds = time.perf_counter() - t0
            self.finished.set()
        return self


_lock = threading.Lock()
_background = None


def start():
    """Starts the warm-up on a daemon thread (once per process) -> its WarmUp."""
    global _background
    with _lock:
        if _background is None:
            _background = WarmUp()
            threading.Thread(target=_background.run, name="photon_lightmaps warm-up", daemon=True).start()
        return _background


def status():
    """The background warm-up (None if none was started)."""
    return _background


def wait(poll=None, interval=0.25):
    """Blocks while a background warm-up runs; poll(warmup) every `interval` s may
    return False to stop waiting. Returns True if none is running any more."""
    w = _background
    while w is not None and not w.finished.wait(interval):
        if poll is not None and poll(w) is False:
            return False
    return True


# ------------------------------------------------------------- compiling ahead
# A first render compiles its photon pass, then its render pass, one after the
# other on one core. With a second core, a helper compiles the render pass's
# kernels (on a tiny scene of the same kind) while the host compiles and runs
# its photon pass; the host then loads them from the cache.
_ahead = {}                 # (mask, pass) -> the Helper compiling it
_expected = set()           # passes a host will run later (the demo: a bake after its render)


def expect(*passes):
    """Says that this process will also run `passes` later ("render", "bake"), so the
    next ahead() compiles them too."""
    _expected.update(p for p in passes if p in PASSES)


def _compiled(mask, pass_):
    return is_warm() or os.path.isfile(_marker(f"compiled-{mask}-{pass_}"))


def ahead(scene, passes):
    """Starts a helper process compiling the kernels of the passes that follow the
    photon pass ("render", "bake") for `scene`'s kind, unless they are compiled
    already, a warm-up is doing it, or there is no second core. -> the Helper or None."""
    if lanes() < 2 or (_background is not None and not _background.finished.is_set()):
        return None
    mask = scene_mask(scene)
    todo = [p for p in PASSES if (p in passes or p in _expected)
            and (mask, p) not in _ahead and not _compiled(mask, p)]
    if not todo:
        return None
    families = [Family(f"{p} ({mask})", mask, p, photons=False) for p in todo]
    try:
        h = Helper(families)
    except OSError:             # no interpreter to start: the host compiles it all itself
        return None
    for f in families:
        _ahead[(mask, f.pass_)] = (h, f)
    return h


# A helper compiles one pass in a minute or two on 2 cores; past this the host
# stops waiting and compiles what it needs itself (a stuck helper never hangs a render).
JOIN_LIMIT_S = 600.0


def join(mask, pass_, poll=None):
    """Before the host runs `pass_` on a scene of feature `mask`: waits for a helper
    compiling it ahead (poll(seconds waited) every 0.25 s may return False to stop
    waiting), so the host loads those kernels instead of compiling them again."""
    h, family = _ahead.pop((int(mask), pass_), (None, None))
    if h is not None:
        t0 = time.perf_counter()

        def keep_waiting(_):
            waited = time.perf_counter() - t0
            return waited < JOIN_LIMIT_S and (poll is None or poll(waited) is not False)
        h.wait(family, keep_waiting)


def done(mask, pass_):
    """The host compiled (or loaded) `pass_` for feature `mask`: no helper for it again."""
    if not os.path.isfile(_marker(f"compiled-{mask}-{pass_}")):
        _touch(_marker(f"compiled-{mask}-{pass_}"))
