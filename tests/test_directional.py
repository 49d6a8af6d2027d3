"""Directional lightmaps (engine/transport/directional_lightmap.py, bake --directional):
the dominant-light solve on its closed cases, and a normal-mapped plane under a sun,
EEVEE through the material hook against Cycles rendering the same material."""
import json
import math

import numpy as np

import bpy  # noqa: F401  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake
from photon_lightmaps.engine.transport import directional_lightmap as DL

from blender_session import addon  # noqa: F401  (session-wide registration)


def test_the_solve_is_exact_for_a_sun_a_sky_and_their_mix():
    """v = k s + (1 - k) 2/3 n gives back k and s: a distant light alone (k = 1), a
    uniform sky alone (k = 0), and mixtures at several angles."""
    rng = np.random.default_rng(3)
    n = np.tile([0.0, 0.0, 1.0], (200, 1))
    theta = rng.uniform(0.0, 1.4, 200)
    phi = rng.uniform(0.0, 2 * math.pi, 200)
    s = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
    k = rng.uniform(0.0, 1.0, 200)
    k[:3] = (1.0, 0.0, 1.0)
    v = k[:, None] * s + (1 - k)[:, None] * DL.AMBIENT_MOMENT * n
    u = DL.dominant(v, n)
    assert np.allclose(np.linalg.norm(u, axis=1), k, atol=1e-9)
    lit = k > 1e-6
    assert np.allclose(u[lit] / k[lit, None], s[lit], atol=1e-9)


def normal_mapped_plane(amplitude=0.35):
    """A 2 m plane whose Diffuse BSDF (0.8) takes a tangent-space normal map of 2 x 2
    bumps (slopes up to `amplitude`), under a sun 45 degrees up (3 W/m²) in a black
    world (a sky would light the open plane's back too, which its lightmap adds to the
    front's and a render of the front does not show)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    me = bpy.data.meshes.new("plane")
    me.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
    uv = me.uv_layers.new(name="UVMap")
    for loop, xy in zip(uv.data, ((0, 0), (1, 0), (1, 1), (0, 1))):
        loop.uv = xy
    ob = bpy.data.objects.new("plane", me)
    scene.collection.objects.link(ob)
    res = 128
    x = (np.arange(res) + 0.5) / res
    U, V = np.meshgrid(x, x)                   # rows: v (bottom-up, as Blender's pixels)
    f = 2 * math.pi * 2
    dhdu = amplitude * np.cos(f * U) * np.sin(f * V)
    dhdv = amplitude * np.sin(f * U) * np.cos(f * V)
    nt = np.stack([-dhdu, -dhdv, np.ones_like(U)], axis=-1)
    nt /= np.linalg.norm(nt, axis=-1, keepdims=True)
    img = bpy.data.images.new("bumps", res, res, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    px = np.ones((res, res, 4), np.float32)
    px[..., :3] = 0.5 + 0.5 * nt
    img.pixels.foreach_set(px.ravel())
    mat = bpy.data.materials.new("bumpy")
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    nmap = tree.nodes.new("ShaderNodeNormalMap")
    nmap.uv_map = "UVMap"
    bsdf = tree.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(tex.outputs["Color"], nmap.inputs["Color"])
    tree.links.new(nmap.outputs["Normal"], bsdf.inputs["Normal"])
    tree.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    me.materials.append(mat)
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy, sun.data.angle = 3.0, math.radians(0.5)
    sun.rotation_euler = (math.radians(45), 0.0, math.radians(30))
    scene.collection.objects.link(sun)
    scene.world = bpy.data.worlds.new("black")
    scene.world.color = (0.0, 0.0, 0.0)
    for node in scene.world.node_tree.nodes if scene.world.node_tree else ():
        if node.type == "BACKGROUND":
            node.inputs["Strength"].default_value = 0.0
    cam = bpy.data.objects.new("top", bpy.data.cameras.new("top"))
    cam.data.type, cam.data.ortho_scale = "ORTHO", 1.6        # the plane's inner 1.6 m
    cam.location = (0, 0, 3)
    scene.collection.objects.link(cam)
    scene.camera = cam
    r = scene.render
    r.resolution_x = r.resolution_y = 64
    r.image_settings.file_format = "OPEN_EXR"
    scene.view_settings.view_transform = "Standard"
    return scene, ob


def render(scene, engine):
    scene.render.engine = engine
    if engine == "CYCLES":
        scene.cycles.samples, scene.cycles.filter_width, scene.cycles.device = 256, 0.01, "CPU"
    else:
        scene.render.filter_size = 0.0
        scene.eevee.taa_render_samples = 1
    path = bpy.app.tempdir + f"directional_{engine}.exr"
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    try:
        return np.array(img.pixels[:], np.float64).reshape(64, 64, 4)[..., :3]
    finally:
        bpy.data.images.remove(img)


def test_normal_maps_show_under_a_directional_lightmap():
    """EEVEE through the material hook against Cycles rendering the normal-mapped
    material itself (256 samples, the same camera): with the directional lightmap the
    relative RMSE is 0.0044 (bound 0.02); the plain lightmap, which cannot see the
    bumps, is 0.18 off (bound: above 0.15)."""
    scene, ob = normal_mapped_plane()
    cycles = render(scene, "CYCLES")
    errors, reports = {}, {}
    for directional in (False, True):
        res = bake.bake_objects(bpy.context, [ob], resolution=32, seed=1, hook_materials=True,
                                directional=directional, overwrite=True)
        reports[directional] = res
        eevee = render(scene, "BLENDER_EEVEE")
        errors[directional] = float(np.sqrt(np.mean((eevee - cycles) ** 2)) / cycles.mean())
    print(f"\n{errors}")
    u = reports[True].direction_maps["plane"].rgba
    u = u[..., :3][u[..., 3] >= 1.0 - 1e-6]
    sun = np.array(bpy.data.objects["sun"].matrix_world.to_3x3().col[2])    # toward the sun
    assert np.allclose(u, sun, atol=0.01)                 # the sun alone: k = 1
    assert errors[True] < 0.02 and errors[False] > 0.15


def test_cli_directional_writes_the_direction_image(tmp_path):
    from test_cli_commands import run
    normal_mapped_plane()
    blend = tmp_path / "plane.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    run("bake", blend, "--out", tmp_path / "maps", "--resolution", "16", "--photons", "10000", "--directional",
        "--json", tmp_path / "r.json")
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["seconds"]["direction"] > 0.0
    img = bpy.data.images.load(rep["objects"]["plane"]["direction_image"])
    px = np.array(img.pixels[:], np.float32).reshape(-1, 4)
    bpy.data.images.remove(img)
    covered = px[:, 3] >= 1.0 - 1e-6
    assert covered.sum() > 50
    u = px[covered, :3]
    sun = np.array(bpy.data.objects["sun"].matrix_world.to_3x3().col[2])
    assert np.allclose(u / np.linalg.norm(u, axis=1, keepdims=True), sun, atol=0.01)


def test_a_directional_bake_leaves_the_lightmap_as_it_was():
    """The moments ride along in the direct gather's rows: the lightmap itself is the
    plain bake's, bit for bit (the same photon pass, reused)."""
    from test_seam_stitch import halves_and_ball
    _, objs = halves_and_ball()
    plain = bake.bake_objects(bpy.context, objs, seed=1, resolution=16)
    directional = bake.bake_objects(bpy.context, objs, seed=1, resolution=16, directional=True, overwrite=True)
    assert directional.light_reuse["reused"] == "memory"
    for name, bm in plain.maps.items():
        assert np.array_equal(bm.rgba, directional.maps[name].rgba), name
    assert set(directional.direction_maps) == set(plain.maps)
