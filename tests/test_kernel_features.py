"""Kernels specialise on the scene's features: a scene of meshes and primitives
never compiles the CSG or L-system traversal cores (engine/core/features.py)."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from photon_lightmaps.engine.core import features
from photon_lightmaps.engine.geometry.assembly import compile_geometry
from photon_lightmaps.engine.geometry.trace_layout import trace_buf
from photon_lightmaps.engine.core.scene import (
    CSGNode, Instance, LSystem, Primitive, Prototype, Scene, scale, translate)

from photon_lightmaps.engine.demo_scenes import uv_sphere_mesh
from tests.lsystem_grammars import ABOP_124A


def _mask(scene):
    g, _ = compile_geometry(scene)
    return features.mask_of(np.asarray(g.trace_features))


def _meshes():
    s = Scene()
    s.add_object(uv_sphere_mesh(1.0, 8, 16), name="ball")
    s.add_object(Primitive("box"), translate(3, 0, 0), name="box")
    return s


def _add_solid(s):
    """A box minus a larger sphere (its corners are left) at y = 3."""
    s.prototypes.append(Prototype(name="solid", csg=[CSGNode(
        "difference", Primitive("box"), Primitive("sphere", transform=scale(1.2)))]))
    s.instances.append(Instance(len(s.prototypes) - 1, translate(0, 3, 0), name="solid"))


def test_marker_says_what_the_scene_holds():
    assert _mask(_meshes()) == 0
    s = _meshes()
    _add_solid(s)
    assert _mask(s) == features.CSG
    s = _meshes()
    s.prototypes.append(Prototype(name="tree", lsystems=[LSystem(ABOP_124A.format(n=1), name="tree")]))
    s.instances.append(Instance(len(s.prototypes) - 1, name="tree"))
    assert _mask(s) == features.DCSG
    assert [features.mask_of(features.marker(m)) for m in range(4)] == [0, 1, 2, 3]
    with pytest.raises(ValueError):
        features.marker(4)
    assert len(trace_buf(compile_geometry(_meshes())[0])) == 5


_PROBE = r"""
import json, sys
from numba.core import event
names = []
class L(event.Listener):
    def on_start(self, ev):
        f = getattr((ev.data or {}).get("dispatcher"), "py_func", None)
        if f is not None:
            names.append(f.__module__.rsplit(".", 1)[-1] + "." + f.__qualname__)
    def on_end(self, ev):
        pass
event.register("numba:compile", L())
import numpy as np
from photon_lightmaps.engine.geometry import raycast
from photon_lightmaps.engine.geometry.assembly import compile_geometry
from tests.test_kernel_features import _add_solid, _meshes
s = _meshes()
if sys.argv[1] == "csg":
    _add_solid(s)
g, _ = compile_geometry(s)
# the sphere; over everything; the solid's corner region; through the solid's hollow centre
o = np.array([[-5.0, 0.0, 0.0], [0.0, -5.0, 5.0], [-5.0, 3.9, 0.9], [-5.0, 3.0, 0.0]])
d = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
t, inst, shape = raycast.trace_closest_batch(g, o, d)
hit = raycast.occluded_batch(g, o, d)
t = [x if x < 1e30 else None for x in t.tolist()]
print(json.dumps({"names": sorted(set(names)), "t": t, "occluded": hit.tolist()}))
"""


def _compiled(kind, tmp_path):
    """Dispatchers compiled by closest and any-hit rays on an empty kernel cache."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("PHOTON_LIGHTMAPS_NUMBA_CACHE", None)
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    r = subprocess.run([sys.executable, "-c", _PROBE, kind], cwd=root, env=env, capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_mesh_scene_compiles_no_csg_or_lsystem_core(tmp_path):
    got = _compiled("meshes", tmp_path)
    assert got["t"][0] == pytest.approx(4.0, abs=0.01)       # the sphere's pole at x = -1
    assert got["t"][1:] == [None, None, None]
    assert got["occluded"] == [True, False, False, False]
    assert "raycast.closest_core" in got["names"]
    kinds = ("csg", "csg_trace", "dcsg", "dcsg_trace", "dcsg_areas")
    assert not [n for n in got["names"] if n.split(".")[0] in kinds], got["names"]


def test_csg_scene_compiles_the_csg_core(tmp_path):
    got = _compiled("csg", tmp_path)
    # the box minus a larger sphere leaves the box's corners: a ray near an edge
    # hits the box face, one through the centre crosses only the hollow
    assert got["t"][2] == pytest.approx(4.0, abs=1e-9)
    assert got["t"][3] is None
    assert got["occluded"] == [True, False, True, False]
    assert "csg_trace.csg_closest_core" in got["names"]
    assert "dcsg_trace.dcsg_closest_core" not in got["names"]
