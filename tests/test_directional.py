"""Directional lightmaps (engine/transport/directional_lightmap.py, bake --directional):
the dominant-light solve on its closed cases, and a normal-mapped plane under a sun,
EEVEE through the material hook against Cycles rendering the same material."""
import json
import math

import numpy as np

import bpy  # noqa: F401  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake
from photon_lightmaps.engine.transport import directional_lightmap as DL

from blender_session import addon, cycles_diffuse_bake  # noqa: F401  (session-wide registration)


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


SUN = (3.0, (45, 0, 30), (1.0, 1.0, 1.0))


def normal_mapped_plane(amplitude=0.35, suns=(SUN,), wall=False):
    """A 2 m plane whose Diffuse BSDF (0.8) takes a tangent-space normal map of 2 x 2
    bumps (slopes up to `amplitude`), under a sun 45 degrees up (3 W/m²) in a black
    world (a sky would light the open plane's back too, which its lightmap adds to the
    front's and a render of the front does not show). suns: (W/m², rotation in
    degrees, colour) each; wall: a 3 x 2 m white wall just beyond the plane's far
    edge (y = 1.1, from 0.2 m up: no contact, whose light changes faster than a
    texel), facing the sun, whose light reaches the plane only as indirect light."""
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
    for i, (energy, rotation, colour) in enumerate(suns):
        name = "sun" if i == 0 else f"sun{i}"
        sun = bpy.data.objects.new(name, bpy.data.lights.new(name, "SUN"))
        sun.data.energy, sun.data.angle, sun.data.color = energy, math.radians(0.5), colour
        sun.rotation_euler = tuple(math.radians(a) for a in rotation)
        scene.collection.objects.link(sun)
    if wall:
        wm = bpy.data.meshes.new("wall")
        wm.from_pydata([(-1.5, 1.1, 0.2), (1.5, 1.1, 0.2), (1.5, 1.1, 2.2), (-1.5, 1.1, 2.2)], [], [(0, 1, 2, 3)])
        white = bpy.data.materials.new("white")
        white.use_nodes = True
        white.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.8, 0.8, 0.8, 1.0)
        white.node_tree.nodes["Principled BSDF"].inputs["Roughness"].default_value = 1.0
        wm.materials.append(white)
        scene.collection.objects.link(bpy.data.objects.new("wall", wm))
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
    bumps, is 0.18 off (bound: above 0.15). L1 SH, which widens the sun's lobe, lies
    between (0.074)."""
    scene, ob = normal_mapped_plane()
    cycles = render(scene, "CYCLES")
    errors, reports = {}, {}
    for directional in (False, True, "SH"):
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
    assert errors[True] < errors["SH"] < errors[False]


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


def _tilted_normals(ob, res):
    """Cycles' object-space normal bake of `ob`'s material (normal map and all) on its
    Lightmap UVs -> (res, res, 3) unit shading normals, rows bottom-up (the plane's
    object space is world space)."""
    px = cycles_diffuse_bake(ob, res, 16, bake_type="NORMAL", pass_filter=(), normal_space="OBJECT")
    n = 2.0 * px[..., :3].astype(np.float64) - 1.0
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)


def _read_for(res, mode, n_shading):
    """The hook's reading of a bake (BakeResult) for shading normals n_shading (flat
    plane: true normal +z), in numpy -> (h, w, 3) E/pi per colour."""
    lm = res.maps["plane"].rgba[..., :3].astype(np.float64)
    n = np.array([0.0, 0.0, 1.0])
    if mode == "NONE":
        return lm
    if mode == "AMBIENT":       # all light as if from the whole hemisphere
        return lm * ((1.0 + n_shading @ n) / 2.0)[..., None]
    if mode == "SH":
        L1 = np.stack([res.l1_maps[a]["plane"].rgba[..., :3] for a in "xyz"], axis=-1).astype(np.float64)
        return np.maximum(lm + np.einsum("hwcj,hwj->hwc", L1, n_shading - n), 0.0)
    u = res.direction_maps["plane"].rgba[..., :3].astype(np.float64)
    k = np.linalg.norm(u, axis=-1)
    s = np.divide(u, k[..., None], out=np.zeros_like(u), where=k[..., None] > 1e-12)
    lit = np.maximum(np.einsum("hwj,hwj->hw", n_shading, s), 0.0) / np.maximum(s @ n, DL.MIN_COS)
    return lm * (k * lit + (1.0 - k) * (1.0 + n_shading @ n) / 2.0)[..., None]


def _interior_error(ours, ref, cover):
    keep = cover >= 1.0 - 1e-6
    return float(np.sqrt(np.mean((ours[keep] - ref[keep]) ** 2)) / ref[keep].mean())


def test_indirect_light_keeps_its_direction():
    """The plane's indirect light comes from the lit wall on one side. An indirect-only
    directional bake, read for the normal map's normals, against Cycles' Diffuse bake
    (Indirect only, no Color) of the normal-mapped material on the same UVs: the
    dominant direction and L1 SH both come from the gather rays. Taking that light as
    uniform over the hemisphere instead (what a bake whose gather kept no directions
    would give) is clearly worse. The wall stands clear of the plane: at a contact the
    light changes faster than a texel, where a texel's mean and Cycles' value at its
    centre part (docs/baking.md)."""
    scene, ob = normal_mapped_plane(amplitude=0.5, wall=True)
    res_px = 32
    bakes = {mode: bake.bake_objects(bpy.context, [ob], resolution=res_px, seed=1, bake_pass="INDIRECT",
                                     directional=mode, overwrite=True) for mode in ("DOMINANT", "SH")}
    n_shading = _tilted_normals(ob, res_px)
    ref = cycles_diffuse_bake(ob, res_px, 1024, pass_filter=("INDIRECT",))
    cover = bakes["DOMINANT"].maps["plane"].rgba[..., 3]
    errors = {"plain": _interior_error(_read_for(bakes["DOMINANT"], "NONE", n_shading), ref[..., :3], cover),
              "ambient": _interior_error(_read_for(bakes["DOMINANT"], "AMBIENT", n_shading), ref[..., :3], cover),
              "dominant": _interior_error(_read_for(bakes["DOMINANT"], "DOMINANT", n_shading), ref[..., :3], cover),
              "sh": _interior_error(_read_for(bakes["SH"], "SH", n_shading), ref[..., :3], cover)}
    print(f"\n{errors}")
    # the light comes from the wall's side (+y) and from above it
    u = bakes["DOMINANT"].direction_maps["plane"].rgba[..., :3][cover >= 1.0 - 1e-6]
    assert u[:, 1].mean() > 0.2
    # measured: ambient 0.29, dominant 0.056, L1 SH 0.16 (L1 widens the wall's lobe)
    assert errors["dominant"] < 0.08 and errors["sh"] < 0.2 and errors["ambient"] > 0.25
    assert bakes["SH"].directional["mode"] == "sh" and bakes["SH"].directional["moment_bytes"] > 0


def test_l1_sh_keeps_colours_from_two_sides():
    """A red sun from +x and a blue one from -x: a bump facing +x is red, one facing
    -x blue. One dominant direction per texel cannot show that (both colours share
    it); L1 per colour can. EEVEE through the material hook against Cycles rendering
    the normal-mapped material itself."""
    scene, ob = normal_mapped_plane(suns=((3.0, (0, 50, 0), (1.0, 0.1, 0.1)), (3.0, (0, -50, 0), (0.1, 0.1, 1.0))))
    cycles = render(scene, "CYCLES")
    errors = {}
    for mode in ("", "DOMINANT", "SH"):
        res = bake.bake_objects(bpy.context, [ob], resolution=32, seed=1, hook_materials=True,
                                directional=mode, overwrite=True)
        eevee = render(scene, "BLENDER_EEVEE")
        errors[mode] = float(np.sqrt(np.mean((eevee - cycles) ** 2)) / cycles.mean())
    print(f"\n{errors}")
    assert set(res.l1_images) == {"x", "y", "z"} and all("plane" in res.l1_images[a] for a in "xyz")
    # measured: plain 0.19, dominant 0.19, L1 SH 0.088
    assert errors["SH"] < 0.12 and errors["DOMINANT"] > 0.15 and errors[""] > 0.15


def test_l1_coefficients_on_their_closed_cases():
    """A uniform sky (k = 0) is exact in L1: E (1 + n'.n) / 2. A sun alone (k = 1, from
    s) is the clamped cosine's first-order lobe 1/4 + (n'.s)/2, scaled to read E at n:
    L1 = E (s / 2) / (1/4 + (n.s)/2)."""
    rng = np.random.default_rng(5)
    n = np.tile([0.0, 0.0, 1.0], (50, 1))
    E = rng.uniform(0.1, 2.0, (50, 3))
    L1 = DL.l1_coefficients(E, np.zeros((50, 3, 3)), n)
    tilt = rng.normal(size=(50, 3))
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    read = E + np.einsum("kbj,kj->kb", L1, tilt - n)
    assert np.allclose(read, E * ((1 + tilt @ np.array([0.0, 0.0, 1.0])) / 2)[:, None], atol=1e-12)
    s = rng.normal(size=(50, 3, 3))
    s[..., 2] = np.abs(s[..., 2]) + 0.2
    s /= np.linalg.norm(s, axis=2, keepdims=True)
    L1 = DL.l1_coefficients(E, s, n)
    cos = s[..., 2]
    assert np.allclose(L1, E[..., None] * (s / 2) / (0.25 + cos / 2)[..., None], atol=1e-12)


def test_cli_directional_sh_writes_three_images(tmp_path):
    from test_cli_commands import run
    normal_mapped_plane()
    blend = tmp_path / "plane.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    run("bake", blend, "--out", tmp_path / "maps", "--resolution", "16", "--photons", "10000", "--directional",
        "sh", "--json", tmp_path / "r.json")
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["directional"]["mode"] == "sh" and rep["directional"]["image_bytes"] == 3 * 16 * 16 * 4 * 4
    paths = rep["objects"]["plane"]["l1_images"]
    assert [p[-8:] for p in paths] == ["_l1x.exr", "_l1y.exr", "_l1z.exr"]
    sun = np.array(bpy.data.objects["sun"].matrix_world.to_3x3().col[2])
    L1 = []
    for p in paths:
        img = bpy.data.images.load(p)
        px = np.array(img.pixels[:], np.float32).reshape(-1, 4)
        bpy.data.images.remove(img)
        L1.append(px[px[:, 3] >= 1.0 - 1e-6, 0])
    d = np.stack(L1, axis=1)
    # a white sun alone: each colour's L1 points at it
    assert np.allclose(d / np.linalg.norm(d, axis=1, keepdims=True), sun, atol=0.02)


def test_an_unknown_directional_mode_is_one_clear_error():
    from photon_lightmaps.engine.core.scene import SceneError
    _, ob = normal_mapped_plane()
    before = [uv.name for uv in ob.data.uv_layers]
    try:
        bake.bake_objects(bpy.context, [ob], resolution=8, directional="l2")
    except SceneError as e:
        assert "directional: must be one of dominant, sh, got 'l2'" in str(e)
    else:
        raise AssertionError("no SceneError")
    assert [uv.name for uv in ob.data.uv_layers] == before
