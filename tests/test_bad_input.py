"""Bad input: a clear, typed error or a documented fallback, and never a NaN in any output."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine.core.memory_budget import BudgetError
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.transport.renderer import render
from photon_lightmaps.engine.core.scene import (
    Camera, Instance, Light, Material, OrientationLightmap, Primitive, Prototype, Scene,
    SceneError, TriangleMesh, compose, scale, translate)


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


def _lightmap_of(cs, inst):
    lid = cs.instance_lightmaps[inst][0]
    return lightmap.texel_slice(cs.lightmaps, lid)


def test_zero_uv_area_triangles_own_no_texels_and_record_no_photons():
    """A triangle whose UVs collapse to a point (an untriangulated Boolean's
    sliver, a broken unwrap) keeps no texel area and records no photon, so no
    texel can get ~1e296 from a photon landing there; it still casts shadows."""
    s = small_scene()
    v = np.array([[-0.5, 0, 0.5], [0.5, 0, 0.5], [0, 0.5, 0.5]], dtype=float)
    uv = np.full((1, 3, 2), 0.5)  # the whole triangle maps to one UV point
    s.add_object(TriangleMesh(v, np.array([[0, 1, 2]]), uvs=uv, name="collapsed_uv"),
                 name="collapsed_uv", lightmap_resolution=4)
    cs, stats, img = run_all(s, photons=20000)
    sl = _lightmap_of(cs, -1)
    assert cs.lightmaps.area[sl].sum() == 0.0
    assert cs.lightmaps.hits[sl].sum() == 0
    # it is still geometry: the floor under it is shadowed compared with the scene without it
    bare = compile_scene(small_scene())
    trace_photons(bare, 20000, max_bounces=4)
    floor = lambda c: c.lightmaps.flux[_lightmap_of(c, 0)].sum()
    assert floor(cs) < floor(bare)


def test_sliver_texels_never_give_absurd_irradiance():
    """A texel that a chart grazes by 1e-9 of its area is dilated from its
    neighbours instead of reading flux / 1e-9·A."""
    s = small_scene()
    v = np.array([[-0.5, -0.5, 0.5], [0.5, -0.5, 0.5], [0.5, 0.5, 0.5], [-0.5, 0.5, 0.5]], float)
    eps = 1e-9
    # one quad over texels 0..3 of a 4x4 map, reaching eps into column 4's first texel row
    uv = np.array([[[0, 0], [0.5 + eps, 0], [0.5 + eps, 0.5]], [[0, 0], [0.5 + eps, 0.5], [0, 0.5]]])
    s.add_object(TriangleMesh(v, np.array([[0, 2, 1], [0, 3, 2]]), uvs=uv, name="grazing"),
                 name="grazing", lightmap_resolution=4)
    cs, stats, img = run_all(s, photons=40000)
    lightmap.finalize(cs.lightmaps)
    sl = _lightmap_of(cs, -1)
    area, irr = cs.lightmaps.area[sl], cs.lightmaps.irradiance[sl]
    full = area > 0.1 * area.max()
    sliver = (area > 0) & ~full
    assert sliver.any() and full.sum() == 4
    assert np.all(cs.lightmaps.state[sl][sliver] != lightmap.STATE_MEASURED)
    assert irr.max() <= 2.0 * irr[full].max()


def test_uvs_outside_the_atlas_are_clamped_and_reported():
    s = small_scene()
    v = np.array([[-0.5, 0, 0.5], [0.5, 0, 0.5], [0, 0.5, 0.5]], dtype=float)
    uv = np.array([[[0.2, 0.2], [1.7, 0.2], [0.2, 0.9]]])
    s.add_object(TriangleMesh(v, np.array([[0, 1, 2]]), uvs=uv, name="spills"), name="spills")
    cs, stats, img = run_all(s)
    assert any("spills" in w and "clamped" in w for w in cs.info["warnings"])
    assert cs.geometry.tri_uv.max() <= 1.0


def test_degenerate_triangles_are_named_in_the_warnings():
    s = small_scene()
    v = np.array([[0, 0, 0.5], [0.2, 0, 0.5], [0.4, 0, 0.5], [0, 0.3, 0.5]], dtype=float)
    s.add_object(TriangleMesh(v, np.array([[0, 1, 2], [0, 1, 3]]), name="sliver"), name="sliver")
    cs = compile_scene(s)
    assert [w for w in cs.info["warnings"] if "sliver" in w and "1 zero-area" in w]


def test_mesh_of_only_degenerate_triangles_renders():
    s = small_scene()
    v = np.array([[0, 0, 0.5], [0.2, 0, 0.5], [0.4, 0, 0.5]], dtype=float)
    s.add_object(TriangleMesh(v, np.array([[0, 1, 2], [1, 1, 2]]), name="flat"), name="flat")
    cs, stats, img = run_all(s)
    assert cs.info["n_degenerate"] == 2


def test_emptied_meshes_take_no_lightmap_slot():
    """A mesh whose triangles are all degenerate has no surface: lightmap ids of
    the surfaces and instances after it must not shift (they pointed one past
    their lightmap and the kernels wrote out of bounds: the fuzz cases that
    segfaulted: a zero-area triangle must not crash the render)."""
    s = small_scene()
    flat = TriangleMesh(np.array([[0, 0, 0.5], [0.2, 0, 0.5], [0.4, 0, 0.5]]), np.array([[0, 1, 2]]),
                        uvs=np.full((1, 3, 2), 0.5), name="all_degenerate")
    s.prototypes.append(Prototype("mixed", meshes=[flat], primitives=[Primitive("sphere")]))
    s.instances.append(Instance(len(s.prototypes) - 1, compose(translate(0, 0, 0.5), scale(0.2)),
                                name="mixed", lightmap_resolution=4))
    s.prototypes.append(Prototype("empty", meshes=[flat]))
    s.instances.append(Instance(len(s.prototypes) - 1, name="empty"))
    s.add_object(Primitive("sphere"), compose(translate(0.5, 0, 0.3), scale(0.2)), name="after",
                 lightmap_resolution=4)
    cs, stats, img = run_all(s, photons=20000)
    g, lm = cs.geometry, cs.lightmaps
    n_lm = lm.offset.shape[0]
    for i, ids in enumerate(cs.instance_lightmaps):
        base = int(g.inst_lm_base[i])
        assert ids == list(range(base, base + len(ids))) or (base < 0 and ids == [])
        assert int(g.proto_n_surfaces[g.inst_proto[i]]) == len(ids) or base < 0
        assert all(0 <= k < n_lm for k in ids)
    assert cs.instance_lightmaps[-3:-1] == [[cs.instance_lightmaps[-3][0]], []]
    # the sphere after the emptied prototype records into its own lightmap
    assert lm.hits[lightmap.texel_slice(lm, cs.instance_lightmaps[-1][0])].sum() > 0


@pytest.mark.parametrize("k", [1e-6, 1e7], ids=["tiny", "huge"])
def test_tiny_and_huge_scales_render_the_same_scene(k):
    """The Cornell box scaled by k everywhere (geometry, camera, the light by its
    transform and its power by k², so irradiance stays) gives the same image:
    no precision cliff at 1e-6 or 1e7."""
    ref = small_scene()
    s = small_scene()
    S = scale(k)
    for inst in s.instances:
        inst.transform = compose(S, inst.transform)
    for light in s.lights:
        light.transform = compose(S, light.transform)
        light.power *= k * k
    s.camera.transform = compose(S, s.camera.transform)
    s.texel_density = ref.texel_density / k
    a = run_all(ref, photons=20000)[2]
    b = run_all(s, photons=20000)[2]
    assert np.allclose(a.mean(), b.mean(), rtol=0.02)


def test_mirrored_instance_records_the_same_light():
    """A mirrored (det < 0) sphere under a light on the mirror plane receives what the plain one does."""
    def scene(mirror):
        s = Scene()
        s.materials.append(Material("grey", diffuse=0.5))
        s.add_object(Primitive("sphere"), scale(-1.0 if mirror else 1.0, 1, 1), name="ball",
                     lightmap_resolution=8)
        s.lights.append(Light("point", power=100.0, transform=translate(0, 0, 3)))
        # at (0, -5, 0) looking along +y
        s.camera = Camera(transform=np.array([[1, 0, 0, 0], [0, 0, -1, -5], [0, 1, 0, 0]], float),
                          width=8, height=8)
        return s
    a, b = (run_all(scene(m), photons=20000)[0] for m in (False, True))
    fa, fb = (c.lightmaps.flux[_lightmap_of(c, 0)].sum() for c in (a, b))
    assert fb == pytest.approx(fa, rel=0.03)


def test_far_away_geometry_is_refused_by_name():
    s = small_scene()
    s.add_object(Primitive("sphere"), translate(3e12, 0, 0), name="moon")
    with pytest.raises(SceneError, match="moon.*closer"):
        compile_scene(s)


def test_lightmaps_beyond_memory_are_refused_before_allocating(monkeypatch):
    monkeypatch.setenv("PHOTON_LIGHTMAPS_MEMORY_LIMIT", str(200 * 2 ** 20))
    s = small_scene()
    s.add_object(TriangleMesh(np.array([[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]], float),
                              np.array([[0, 1, 2], [0, 2, 3]]),
                              uvs=np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], float)),
                 name="big floor")
    with pytest.raises(BudgetError, match=r"texels/m.*needs about .*GiB.*'big floor'.*lower the texel density"):
        compile_scene(s, texel_density=1000.0, max_resolution=1 << 14)
    compile_scene(s, texel_density=10.0)          # the suggested kind of density fits


def test_forced_resolution_out_of_range_is_refused():
    s = small_scene()
    s.instances[0].lightmap_resolution = -3
    with pytest.raises(SceneError, match="resolution"):
        compile_scene(s)


def test_area_samples_and_render_size_beyond_memory_are_refused(monkeypatch):
    monkeypatch.setenv("PHOTON_LIGHTMAPS_MEMORY_LIMIT", str(64 * 2 ** 20))
    s = small_scene()
    s.orientation_lightmaps.append(OrientationLightmap("cluster", instances=[0], samples=10 ** 9))
    with pytest.raises(BudgetError, match="cluster.*area samples"):
        compile_scene(s)
    s = small_scene()
    s.camera = Camera(transform=s.camera.transform, width=40000, height=40000)
    with pytest.raises(BudgetError, match="render resolution 40000x40000"):
        compile_scene(s)


def test_unwrap_failure_falls_back_to_the_fast_layout(monkeypatch):
    """Where xatlas fails (crashes in its worker), the mesh gets the fast
    box-projection layout and keeps its own lightmap; the warning names the
    mesh. Only where that layout cannot fit either is the object lit through
    an automatic OL."""
    from photon_lightmaps.engine.lightmaps import fast_layout
    from photon_lightmaps.engine.lightmaps import uv_atlas
    s = small_scene()
    s.add_object(demo_scenes.uv_sphere_mesh(0.3, 8, 16), translate(0, 0, 0.5), name="ball")
    s.prototypes[-1].meshes[0].name = "ball"

    def fail_all(jobs, progress=None, should_stop=None):
        return [uv_atlas.UnwrapError("xatlas crashed (SIGSEGV)", 224) for _ in jobs]
    monkeypatch.setattr(uv_atlas, "unwrap_many", fail_all)
    cs, stats, img = run_all(s, photons=20000)
    assert any("'ball'" in w and "SIGSEGV" in w and "fast box-projection layout" in w
               for w in cs.info["warnings"])
    row, = [r for r in cs.info["layouts"] if r["mesh"] == "ball"]
    assert row["layout"] == "fast layout" and "SIGSEGV" in row["reason"]
    assert not cs.info.get("orientation_lightmaps") and cs.geometry.inst_lm_base[-1] >= 0
    lid = int(cs.instance_lightmaps[-1][0])
    assert cs.lightmaps.hits[lightmap.texel_slice(cs.lightmaps, lid)].sum() > 0

    def no_fit(*args, **kw):
        raise fast_layout.LayoutError("224 separate charts do not fit a 1024×1024 lightmap 3 texels apart")
    monkeypatch.setattr(fast_layout, "layout", no_fit)
    cs, stats, img = run_all(s, photons=20000)
    assert any("'ball'" in w and "SIGSEGV" in w and "do not fit" in w and "orientation lightmap" in w
               for w in cs.info["warnings"])
    rows = cs.info["orientation_lightmaps"]
    assert [r["name"] for r in rows] == ["ball (automatic)"] and rows[0]["instances"] == 1
    k = int(cs.orientation.inst_ol[-1])
    assert k == 0 and cs.geometry.inst_lm_base[-1] == -1
    assert cs.lightmaps.hits[lightmap.texel_slice(cs.lightmaps, int(cs.orientation.lid[k]))].sum() > 0
    assert s.prototypes[-1].meshes[0].uvs is None     # the caller's scene is not modified


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
