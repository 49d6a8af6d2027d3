"""Bad input: a clear, typed error or a documented fallback, and never a NaN in any output."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.photon_tracer import trace_photons
from photon_lightmaps.engine.renderer import render
from photon_lightmaps.engine.scene import (Camera, Light, Material, Primitive, Scene, SceneError,
                                           TriangleMesh, translate)


def run_all(scene, photons=5000):
    cs = compile_scene(scene)
    stats = trace_photons(cs, photons, max_bounces=4)
    img = render(cs, samples=1)
    for arr in (cs.lightmaps.flux, cs.lightmaps.irradiance, cs.lightmaps.area, img,
                stats.emitted, stats.absorbed, stats.escaped):
        assert np.all(np.isfinite(arr))
    return cs, stats, img


def small_scene():
    s = demo_scenes.cornell_box(width=16, height=16, with_primitives=False)
    return s


def test_empty_scene_renders_black():
    s = Scene()
    s.camera = Camera(width=8, height=8)
    cs, stats, img = run_all(s)
    assert stats.photons == 0 and img.max() == 0.0


def test_scene_without_lights_renders_environment_only():
    s = small_scene()
    s.lights.clear()
    s.environment = 0.0
    cs, stats, img = run_all(s)
    assert img.max() == 0.0 and stats.rays == 0


def test_zero_power_lights_emit_nothing():
    s = small_scene()
    s.lights = [Light("point", power=0.0), Light("area", power=0.0, size=1.0)]
    cs, stats, img = run_all(s)
    assert cs.lights.kind.size == 0 and img.max() == 0.0


def test_degenerate_triangles_are_dropped_and_counted():
    s = small_scene()
    v = np.array([[0, 0, 0.5], [0.2, 0, 0.5], [0.4, 0, 0.5], [0, 0.3, 0.5]], dtype=float)
    # Triangle 0 is collinear (zero area), triangle 1 repeats a vertex, triangle 2 is fine.
    t = np.array([[0, 1, 2], [0, 0, 3], [0, 1, 3]])
    s.add_object(TriangleMesh(v, t, name="sliver"), name="sliver")
    cs, stats, img = run_all(s)
    assert cs.info["n_degenerate"] == 2
    assert any("sliver" in name for name in cs.info["degenerate"])


def test_zero_uv_area_triangles_keep_their_area():
    s = small_scene()
    v = np.array([[-0.5, 0, 0.5], [0.5, 0, 0.5], [0, 0.5, 0.5]], dtype=float)
    uv = np.full((1, 3, 2), 0.5)  # the whole triangle maps to one UV point
    s.add_object(TriangleMesh(v, np.array([[0, 1, 2]]), uvs=uv, name="collapsed_uv"),
                 name="collapsed_uv", lightmap_resolution=4)
    cs, stats, img = run_all(s, photons=20000)
    lid = cs.instance_lightmaps[-1][0]
    a = cs.lightmaps.area[cs.lightmaps.offset[lid]: cs.lightmaps.offset[lid] + 16]
    assert a.sum() == pytest.approx(0.25, rel=1e-9)


@pytest.mark.parametrize("bad", [np.full((4, 4), np.nan), np.zeros((4, 4)),
                                 np.diag([1.0, 1.0, 0.0, 1.0])], ids=["nan", "zero", "flat"])
def test_bad_transforms_raise_scene_error(bad):
    s = small_scene()
    s.add_object(Primitive("sphere"), bad, name="broken")
    with pytest.raises(SceneError, match="broken"):
        compile_scene(s)


def test_nan_vertices_and_bad_indices_raise():
    s = small_scene()
    v = np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], dtype=float)
    s.add_object(TriangleMesh(v, np.array([[0, 1, 2]]), name="nan_mesh"), name="nan_mesh")
    with pytest.raises(SceneError, match="nan_mesh"):
        compile_scene(s)
    s = small_scene()
    v = np.zeros((3, 3))
    s.add_object(TriangleMesh(v, np.array([[0, 1, 5]]), name="bad_index"), name="bad_index")
    with pytest.raises(SceneError, match="bad_index"):
        compile_scene(s)


def test_energy_creating_material_is_rejected():
    s = small_scene()
    s.materials.append(Material("too_bright", diffuse=0.8, specular=0.5))
    with pytest.raises(SceneError, match="too_bright"):
        compile_scene(s)


def test_invalid_photon_settings_raise():
    cs = compile_scene(small_scene())
    with pytest.raises(ValueError):
        trace_photons(cs, -1)
    with pytest.raises(ValueError):
        trace_photons(cs, 10, max_bounces=10_000)
