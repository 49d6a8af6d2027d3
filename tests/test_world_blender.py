"""World light through Blender (export/world.py): the Cycles-baked equirectangular map
has Blender's orientation, is cached by content, leaves the user's data alone and
falls back with one warning; bakes under an HDRI and under a Sky Texture agree with
Cycles' Diffuse bake per 4x4 block.

Maps are small here (64 x 32 to 512 x 256) so each test stays well under a minute.
"""
import math
import os
import time

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake  # noqa: E402
from photon_lightmaps.engine.shading import environment  # noqa: E402
from photon_lightmaps.engine import session  # noqa: E402
from photon_lightmaps.engine.core.scene import EnvironmentMap  # noqa: E402
from photon_lightmaps.export import export_scene  # noqa: E402
from photon_lightmaps.export import world as world_export  # noqa: E402

from blender_session import addon, bake_uv_cache, cycles_diffuse_bake  # noqa: E402,F401  (session-wide registration)


@pytest.fixture(autouse=True)
def fresh(bake_uv_cache, monkeypatch):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    world_export.clear_cache()
    monkeypatch.setattr(world_export, "ENV_RESOLUTION", (64, 32))
    monkeypatch.setattr(world_export, "ENV_SAMPLES", 16)
    yield
    world_export.clear_cache()


def new_world(name="World"):
    w = bpy.data.worlds.new(name)
    bpy.context.scene.world = w
    return w, w.node_tree, w.node_tree.nodes["Background"]


def direction_world():
    """Background colour = 0.5 + 0.5 * (the direction a camera ray looks along)."""
    w, nt, bg = new_world("Directions")
    tc = nt.nodes.new("ShaderNodeTexCoord")
    vm = nt.nodes.new("ShaderNodeVectorMath")
    vm.operation = "MULTIPLY_ADD"
    vm.inputs[1].default_value = vm.inputs[2].default_value = (0.5, 0.5, 0.5)
    nt.links.new(tc.outputs["Generated"], vm.inputs[0])
    nt.links.new(vm.outputs[0], bg.inputs["Color"])
    return w


def exported_world():
    scene, emap = export_scene(bpy.context.evaluated_depsgraph_get())
    return scene.environment, emap


def write_exr(path, rgb):
    """(H, world_export, 3) float, row 0 at the bottom, as a float EXR."""
    h, w = rgb.shape[:2]
    img = bpy.data.images.new("tmp_exr", w, h, float_buffer=True, alpha=True)
    px = np.ones((h, w, 4), np.float32)
    px[..., :3] = rgb
    img.pixels.foreach_set(px.reshape(-1))
    img.filepath_raw = str(path)
    img.file_format = "OPEN_EXR"
    img.save()
    bpy.data.images.remove(img)


def hdri_world(path, interpolation="Closest"):
    w, nt, bg = new_world("HDRI")
    tex = nt.nodes.new("ShaderNodeTexEnvironment")
    tex.image = bpy.data.images.load(str(path))
    tex.interpolation = interpolation
    nt.links.new(tex.outputs["Color"], bg.inputs["Color"])
    return w, tex


def pixel_directions(h, w):
    """Centre directions of the map's pixels by engine/shading/environment.py's convention."""
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    el = (v - 0.5) * math.pi
    phi = (0.5 - u) * 2 * math.pi
    EL, PHI = np.meshgrid(el, phi, indexing="ij")
    return np.stack([np.cos(EL) * np.cos(PHI), np.cos(EL) * np.sin(PHI), np.sin(EL)], axis=-1)


def user_data():
    return {k: sorted(x.name for x in getattr(bpy.data, k))
            for k in ("scenes", "objects", "cameras", "images", "worlds", "meshes", "materials")}


# --------------------------------------------------------------------------------------
# The map as Blender sees the world
# --------------------------------------------------------------------------------------

def test_constant_world_stays_a_constant():
    w, nt, bg = new_world()
    bg.inputs["Color"].default_value = (0.2, 0.4, 0.6, 1.0)
    bg.inputs["Strength"].default_value = 2.0
    env, _ = exported_world()
    assert not hasattr(env, "pixels")
    np.testing.assert_allclose(env, [0.4, 0.8, 1.2], rtol=1e-6)
    rgb = nt.nodes.new("ShaderNodeRGB")
    rgb.outputs[0].default_value = (1.0, 0.5, 0.25, 1.0)
    nt.links.new(rgb.outputs[0], bg.inputs["Color"])
    env, _ = exported_world()
    np.testing.assert_allclose(env, [2.0, 1.0, 0.5], rtol=1e-6)


def test_map_orientation_is_blenders_world_mapping():
    """Each pixel of the Cycles-rendered map holds the direction of its centre by
    environment.py's mapping (a linear field: the pixel mean is the centre value up to
    the curvature over a pixel, ~0.2 %, and sampling noise)."""
    direction_world()
    before = user_data()
    env, emap = exported_world()
    assert user_data() == before                       # nothing of the bake is left
    assert isinstance(env, EnvironmentMap) and env.pixels.shape == (32, 64, 3)
    assert env.bake_seconds > 0
    got = env.pixels * 2 - 1
    want = pixel_directions(32, 64)
    err = np.abs(got - want).max(axis=2)
    assert np.percentile(err, 99) < 0.02 and err.max() < 0.05, err.max()
    # the engine's lookup returns the pixel of a direction: +x, +y, up, down
    ev = environment.compile_environment(env, 3)
    out = np.empty(3)
    for d in ((1, 0, 0), (0, 1, 0), (0, -1, 0), (-1, 0, 0.3), (0.1, 0.2, 1), (0.3, -0.1, -1)):
        d = np.asarray(d, float) / np.linalg.norm(d)
        environment.radiance(ev, *d, out)
        assert np.abs(out * 2 - 1 - d).max() < 0.08, (d, out * 2 - 1)


def test_environment_texture_comes_back_as_its_image(tmp_path):
    """An HDRI of the map's own size, Closest interpolation: every pixel is the image's
    (row 0 at the bottom, u from -atan2(y, x)): no flip, no shift, no mirror."""
    rng = np.random.default_rng(1)
    img = rng.random((32, 64, 3)).astype(np.float32) * 4
    write_exr(tmp_path / "env.exr", img)
    hdri_world(tmp_path / "env.exr")
    env, _ = exported_world()
    close = np.isclose(env.pixels, img, rtol=1e-4, atol=1e-5).all(axis=2)
    assert close.mean() > 0.99, close.mean()


def test_bake_is_cached_by_content(tmp_path):
    rng = np.random.default_rng(2)
    write_exr(tmp_path / "env.exr", rng.random((32, 64, 3)).astype(np.float32))
    w, tex = hdri_world(tmp_path / "env.exr")
    env1, _ = exported_world()
    env2, _ = exported_world()
    assert env1.bake_seconds > 0 and env2.bake_seconds == 0.0
    assert np.array_equal(env1.pixels, env2.pixels)
    # a node setting changes the key
    w.node_tree.nodes["Background"].inputs["Strength"].default_value = 3.0
    env3, _ = exported_world()
    assert env3.bake_seconds > 0
    np.testing.assert_allclose(env3.pixels, 3 * env1.pixels, rtol=1e-5)
    # the image file edited on disk (new content, new date) changes it too
    time.sleep(0.01)
    write_exr(tmp_path / "env.exr", np.full((32, 64, 3), 0.5, np.float32))
    os.utime(tmp_path / "env.exr", ns=(time.time_ns() + 10**9,) * 2)
    tex.image.reload()
    env4, _ = exported_world()
    assert env4.bake_seconds > 0
    np.testing.assert_allclose(env4.pixels, 1.5, rtol=1e-4)
    # and the compiled scene reports the map
    scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    info = session.compile(scene).info["environment"]
    assert (info["width"], info["height"]) == (64, 32) and info["bytes"] > 64 * 32 * 3 * 8
    assert info["name"] == "HDRI" and info["bake_seconds"] == 0.0


def test_failed_bake_warns_once_and_averages(monkeypatch):
    w, nt, bg = new_world("Broken")
    bg.inputs["Color"].default_value = (0.3, 0.3, 0.3, 1.0)
    sky = nt.nodes.new("ShaderNodeTexSky")
    nt.links.new(sky.outputs[0], bg.inputs["Color"])

    def fail(*a, **k):
        raise RuntimeError("no Cycles here")

    monkeypatch.setattr(world_export, "render_world", fail)
    env, emap = exported_world()
    np.testing.assert_allclose(env, 0.3, rtol=1e-6)
    world_lines = [m for m in emap.warnings if "Broken" in m]
    assert len(world_lines) == 1 and "Cycles" in world_lines[0] and "no Cycles here" in world_lines[0]


def test_subprocess_bake_matches_the_in_process_one(monkeypatch):
    """The path for render threads (a background Blender) gives the same map."""
    direction_world()
    a, _ = world_export.baked_map(bpy.context.scene.world)
    world_export.clear_cache()
    monkeypatch.setattr(world_export, "BAKE_MODE", "subprocess")
    b, _ = world_export.baked_map(bpy.context.scene.world)
    np.testing.assert_allclose(a, b, atol=1e-6)


# --------------------------------------------------------------------------------------
# Against Cycles' Diffuse bake
# --------------------------------------------------------------------------------------

RES = 64
# Ours is the mean over each texel, Cycles' bake the value at its centre: at the
# sun's sharp shadow edges these differ by design, so Cycles bakes SUPER x SUPER
# points per texel (the same Lightmap UVs on a finer grid) and the test compares means.
SUPER = 4
CYCLES_SPP = 64
PHOTONS = 1_000_000


def slab_with_block():
    """A 3 m x 3 m slab (a closed box: one lit side, as Cycles bakes it) with a block on it."""
    sc = bpy.context.scene
    mat = bpy.data.materials.new("grey")
    p = mat.node_tree.nodes["Principled BSDF"]
    p.inputs["Base Color"].default_value = (0.6, 0.6, 0.6, 1.0)
    p.inputs["Specular IOR Level"].default_value = 0.0
    p.inputs["Roughness"].default_value = 1.0
    obs = []
    for name, loc, size in (("slab", (0, 0, -0.05), (1.5, 1.5, 0.05)), ("block", (0.4, 0.2, 0.4), (0.3, 0.5, 0.4))):
        me = bpy.data.meshes.new(name)
        s = np.array(size)
        v = [tuple(np.array(c) * s) for c in ((-1, -1, -1), (1, -1, -1), (1, 1, -1), (-1, 1, -1),
                                               (-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1))]
        f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
        me.from_pydata(v, [], f)
        me.materials.append(mat)
        ob = bpy.data.objects.new(name, me)
        ob.location = loc
        sc.collection.objects.link(ob)
        obs.append(ob)
    return obs[0]


def erode(mask, k):
    out = mask.copy()
    p = np.pad(mask, k, constant_values=False)
    h, w = mask.shape
    for dy in range(2 * k + 1):
        for dx in range(2 * k + 1):
            out &= p[dy:dy + h, dx:dx + w]
    return out


def top_face_texels(ob, res):
    """Texels whose centre lies in the Lightmap chart of the mesh's upward face."""
    me = ob.data
    face = next(p for p in me.polygons if p.normal.z > 0.99)
    uv = np.array([me.uv_layers["Lightmap"].data[i].uv[:] for i in face.loop_indices])
    c = (np.arange(res) + 0.5) / res
    X, Y = np.meshgrid(c, c)          # row = v (image rows bottom-up), column = u
    inside = np.ones((res, res), bool)
    sign = np.sign(np.cross(uv[1] - uv[0], uv[2] - uv[0]))
    for k in range(len(uv)):
        a, b = uv[k], uv[(k + 1) % len(uv)]
        inside &= sign * ((b[0] - a[0]) * (Y - a[1]) - (b[1] - a[1]) * (X - a[0])) > 0
    return inside


def block_errors(ours, ref, region):
    """Relative error of 4x4 block means over interior texels of `region` (blocks at
    least half interior), relative to the region's mean."""
    interior = erode(ours[..., 3] >= 1.0 - 1e-6, 1) & erode(region, 1)
    scale = ref[..., :3][interior].mean()
    errs = []
    for y in range(0, RES, 4):
        for x in range(0, RES, 4):
            m = interior[y:y + 4, x:x + 4]
            if m.sum() < 8:
                continue
            a = ours[y:y + 4, x:x + 4, :3][m].mean(axis=0)
            b = ref[y:y + 4, x:x + 4, :3][m].mean(axis=0)
            errs.append(np.abs(a - b).max() / scale)
    a, b = ours[..., :3][interior], ref[..., :3][interior]
    return np.array(errs), float(a.mean() / b.mean() - 1.0), int(interior.sum())


def compare_with_cycles(label, max_block=0.10, mean_block=0.04, max_bias=0.02):
    """Bakes the slab both ways; bounds on the top face's 4x4 blocks (measured: HDRI max
    0.068, mean 0.022, bias +0.001; Sky max 0.068, mean 0.026, bias -0.011)."""
    ob = slab_with_block()
    bpy.context.scene.photon_lightmaps.max_bounces = 8
    t0 = time.perf_counter()
    res = bake.bake_objects(bpy.context, [ob], photons=PHOTONS, seed=3, resolution=RES)
    t_ours = time.perf_counter() - t0
    t0 = time.perf_counter()
    fine = cycles_diffuse_bake(ob, RES * SUPER, CYCLES_SPP)
    ref = fine.reshape(RES, SUPER, RES, SUPER, 4).mean(axis=(1, 3))
    t_cycles = time.perf_counter() - t0
    errs, bias, n = block_errors(res.maps["slab"].rgba, ref, top_face_texels(ob, RES))
    env = res.environment
    print(f"\n{label}: {len(errs)} blocks over {n} texels, block error max {errs.max():.4f} "
          f"mean {errs.mean():.4f}, mean bias {bias:+.4f}; ours {t_ours:.1f} s "
          f"(map {env['width']}x{env['height']} baked in {env['bake_seconds']:.1f} s), "
          f"Cycles {CYCLES_SPP} spp x {SUPER * SUPER} points per texel {t_cycles:.1f} s")
    assert len(errs) >= 20
    assert errs.max() <= max_block
    assert errs.mean() <= mean_block
    assert abs(bias) <= max_bias


def test_hdri_lit_slab_matches_cycles(tmp_path, monkeypatch):
    """A synthetic HDRI (dim sky, darker ground, a bright patch at 40 degrees) lighting a
    slab with a block: the block's shadow and the patch's direction must match."""
    monkeypatch.setattr(world_export, "ENV_RESOLUTION", (256, 128))
    h, w = 128, 256
    img = np.zeros((h, w, 3), np.float32)
    img[h // 2:] = (0.3, 0.4, 0.6)          # sky
    img[:h // 2] = (0.1, 0.08, 0.05)        # ground
    img[int(h * (0.5 + 40 / 180)):int(h * (0.5 + 50 / 180)), 40:56] = (40.0, 35.0, 30.0)
    write_exr(tmp_path / "hdri.exr", img)
    hdri_world(tmp_path / "hdri.exr", interpolation="Closest")
    compare_with_cycles("HDRI")


def test_sky_lit_slab_matches_cycles(monkeypatch):
    """Blender's default daylight: a Sky Texture with its sun disc (no Sun lamp: the disc
    is the sun, as in Cycles). The sun is widened to 2 degrees so a 512 x 256 map resolves it."""
    monkeypatch.setattr(world_export, "ENV_RESOLUTION", (512, 256))
    monkeypatch.setattr(world_export, "ENV_SAMPLES", 32)
    w, nt, bg = new_world("Sky")
    sky = nt.nodes.new("ShaderNodeTexSky")
    sky.sun_elevation = math.radians(35)
    sky.sun_rotation = math.radians(60)
    sky.sun_size = math.radians(2.0)
    sky.sun_disc = True
    nt.links.new(sky.outputs[0], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = 0.1
    compare_with_cycles("Sky")
