"""Kernel warm-up: compile the kernels before the first render needs them.

On a new machine or version the first render waits for numba to compile its
kernels (docs/kernels.md). `warm` runs the passes a render and a bake make on
tiny scenes of each kind of geometry the kernels specialise on
(engine/features.py), so their kernels compile, and land in the on-disk
cache, ahead of time.

Blender starts it on a background thread when the add-on is enabled (`start`).
numba compiles under one lock and keeps what it compiled, so a render started
meanwhile shares every kernel the warm-up has compiled or is compiling, and
nothing compiles twice; `status` is what the render panel shows.
"""
import os
import threading
import time

import numpy as np

from . import demo_scenes, session
from .scene import CSGNode, Instance, OrientationLightmap, Primitive, Prototype, scale, translate

TREE = "axiom: F\nderivation length: 2\nangle: 25.7\nproduction:\nF --> F[+F]F[-F]F\n"


def _room(with_primitives=True):
    s = demo_scenes.cornell_box(width=8, height=8, with_primitives=with_primitives)
    # the walls' first one shares an orientation lightmap: the OL kernels too
    s.orientation_lightmaps.append(OrientationLightmap("wall", [0], resolution=4, samples=2000))
    return s


def _solid_room():
    s = _room(with_primitives=False)
    block = CSGNode("difference", Primitive("box", transform=scale(0.3)),
                    Primitive("sphere", transform=scale(0.38)), name="block")
    s.prototypes.append(Prototype(name="block", csg=[block]))
    s.instances.append(Instance(len(s.prototypes) - 1, translate(0.0, 0.0, 0.5), name="block"))
    return s


def _tree():
    return demo_scenes.lsystem_studio(TREE, name="tree", width=8, height=8)


def _render(scene):
    settings = session.Settings(photons=2000, samples=1, seed=1)
    cs = session.compile(scene)
    session.render_photon_pass(cs, settings)
    session.render(cs, settings)


def _bake(scene):
    from .csg_bake import chart_uv_error, full_primitive_areas, solid_leaves
    settings = session.Settings(photons=2000, seed=1, bake_gather_rays=16)
    cs, _ = session.compile_and_trace_bake(scene, settings)
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


# (what it serves, the work): the order a user meets them, the first render first
FAMILIES = [
    ("meshes and primitives: render", lambda: _render(_room())),
    ("meshes and primitives: bake", lambda: _bake(_room())),
    ("exact CSG solids: render", lambda: _render(_solid_room())),
    ("exact CSG solids: bake", lambda: _bake(_solid_room())),
    ("L-systems: render", lambda: _render(_tree())),
]


def _marker():
    # in the kernel cache's own folder, which is keyed by the engine's sources:
    # a new version warms up again
    import numba
    return os.path.join(numba.config.CACHE_DIR, "warmed-up")


def is_warm():
    """True if a warm-up has finished with this engine version and kernel cache."""
    return os.path.isfile(_marker())


class WarmUp:
    """One warm-up's progress: families done of total, the one under way, the error if any."""

    def __init__(self):
        self.done = 0
        self.total = len(FAMILIES)
        self.current = ""
        self.error = None
        self.seconds = 0.0
        self.finished = threading.Event()

    @property
    def fraction(self):
        return self.done / self.total if self.total else 1.0

    def run(self, before=None, after=None):
        """Every family in turn; before(k, name) and after(k, name) around family k (1-based).
        An error stops the warm-up and is kept in .error (the host goes on: the
        render then compiles what it needs itself)."""
        t0 = time.perf_counter()
        try:
            for k, (name, work) in enumerate(FAMILIES, 1):
                self.current = name
                if before is not None:
                    before(k, name)
                work()
                self.done = k
                self.seconds = time.perf_counter() - t0
                if after is not None:
                    after(k, name)
            try:
                os.makedirs(os.path.dirname(_marker()), exist_ok=True)
                with open(_marker(), "w") as f:
                    f.write(f"{self.seconds:.1f} s\n")
            except OSError:
                pass                    # a read-only cache: the next start warms up again
        except Exception as e:          # a warm-up must never take the host down
            self.error = f"{self.current}: {type(e).__name__}: {e}"
        finally:
            self.current = ""
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
