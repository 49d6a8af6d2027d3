"""Blender -> engine Scene export (export.py), checked against Blender's own answers.

bpy can be imported once per process; every test starts from an empty factory
file, and the add-on is registered once per session.
"""
import math

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

import photon_lightmaps  # noqa: E402
from photon_lightmaps import demo_blend, export, registration  # noqa: E402
from photon_lightmaps.engine.compile import compile_scene  # noqa: E402
from photon_lightmaps.engine.transport.renderer import compile_camera  # noqa: E402


from blender_session import addon  # noqa: E402,F401  (session-wide registration)


@pytest.fixture(autouse=True)
def empty_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene


def cube_mesh(name="cube", materials=()):
    v, f = demo_blend.box_mesh_data()
    me = bpy.data.meshes.new(name)
    me.from_pydata(v, [], f)
    for m in materials:
        me.materials.append(m)
    return me


def link(ob, scene=None):
    (scene or bpy.context.scene).collection.objects.link(ob)
    return ob


def export_current(**kw):
    warnings = []
    scene, emap = export.export_scene(bpy.context.evaluated_depsgraph_get(),
                                      report=lambda level, msg: warnings.append((level, msg)), **kw)
    return scene, emap, warnings


def world_matrix(ob):
    return np.array(ob.matrix_world)[:3]


# -- geometry and instancing ---------------------------------------------------------------

def test_linked_duplicates_share_one_prototype():
    me = cube_mesh()
    rng = np.random.default_rng(3)
    obs = []
    for i in range(100):
        ob = link(bpy.data.objects.new(f"dup{i:03d}", me))
        ob.location = rng.uniform(-10, 10, 3)
        ob.rotation_euler = rng.uniform(0, 3, 3)
        ob.scale = rng.uniform(0.5, 2, 3)
        obs.append(ob)
    bpy.context.view_layer.update()
    scene, emap, _ = export_current()
    assert len(scene.prototypes) == 1
    assert len(scene.instances) == 100
    tm = scene.prototypes[0].meshes[0]
    assert tm.triangles.shape == (12, 3) and tm.vertices.shape == (8, 3)
    by_name = {inst.name: inst for inst in scene.instances}
    for ob in obs:
        np.testing.assert_allclose(by_name[ob.name].transform, world_matrix(ob), atol=1e-6)
    assert all(not r.is_instance and r.prototype == 0 for r in emap.instances)
    assert emap.object_instances("dup042") == [[i.name for i in scene.instances].index("dup042")]
    # Vertices are object space: the mesh's own coordinates.
    co = np.array([v.co for v in me.vertices])
    np.testing.assert_allclose(tm.vertices, co, atol=1e-7)


def _instance_on_points_group(source):
    ng = bpy.data.node_groups.new("scatter", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    iop = ng.nodes.new("GeometryNodeInstanceOnPoints")
    info = ng.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = source
    ng.links.new(gin.outputs[0], iop.inputs["Points"])
    ng.links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    ng.links.new(iop.outputs[0], gout.inputs[0])
    return ng


def test_geometry_nodes_instances_share_one_prototype():
    source = link(bpy.data.objects.new("source", cube_mesh()))
    source.hide_render = True  # only its instances should render
    pts_mesh = bpy.data.meshes.new("points")
    grid = np.stack(np.meshgrid(np.arange(10.0), np.arange(10.0), [0.0]), -1).reshape(-1, 3) * 3.0
    pts_mesh.vertices.add(len(grid))
    pts_mesh.vertices.foreach_set("co", grid.astype(np.float32).ravel())
    pts = link(bpy.data.objects.new("scatter", pts_mesh))
    pts.location = (1.0, 2.0, 3.0)
    pts.modifiers.new("gn", "NODES").node_group = _instance_on_points_group(source)
    scene, emap, _ = export_current()
    assert len(scene.prototypes) == 1
    assert len(scene.instances) == 100
    assert all(r.is_instance and r.instancer == "scatter" for r in emap.instances)
    assert len({r.persistent_id for r in emap.instances}) == 100
    origins = np.array(sorted(map(tuple, np.array([i.transform[:, 3] for i in scene.instances]).round(6))))
    expected = np.array(sorted(map(tuple, (grid + (1.0, 2.0, 3.0)).round(6))))
    np.testing.assert_allclose(origins, expected, atol=1e-5)
    assert scene.prototypes[0].meshes[0].triangles.shape == (12, 3)


def test_collection_and_particle_instances():
    me = cube_mesh()
    coll = bpy.data.collections.new("kit")
    coll.objects.link(bpy.data.objects.new("kit_cube", me))  # not in the scene itself
    for i in range(3):
        e = link(bpy.data.objects.new(f"kit_instance{i}", None))
        e.instance_type = "COLLECTION"
        e.instance_collection = coll
        e.location = (5.0 * i, 0.0, 0.0)
    emitter = link(bpy.data.objects.new("emitter", bpy.data.meshes.new("grid")))
    emitter.data.from_pydata([(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)], [], [(0, 1, 2, 3)])
    emitter.location = (0.0, 10.0, 0.0)
    psys = emitter.modifiers.new("particles", "PARTICLE_SYSTEM").particle_system
    ps = psys.settings
    ps.count, ps.frame_start, ps.frame_end = 7, 1, 1
    ps.render_type, ps.instance_object, ps.particle_size = "OBJECT", bpy.data.objects["kit_cube"], 0.1
    bpy.context.scene.frame_set(1)
    scene, emap, _ = export_current()
    kinds = {}
    for r in emap.instances:
        kinds.setdefault(r.instancer, []).append(r)
    # 3 collection instances + 7 particles share the cube; the emitter quad is its own prototype.
    assert sorted(len(v) for v in kinds.values()) == [1, 1, 1, 1, 7]
    assert sum(1 for r in emap.instances if r.is_instance) == 10
    cube_protos = {r.prototype for r in emap.instances if r.is_instance}
    assert len(cube_protos) == 1 and len(scene.prototypes) == 2
    assert emap.object_instances("emitter") and scene.prototypes[
        emap.instances[emap.object_instances("emitter")[0]].prototype].meshes[0].triangles.shape == (2, 3)


def test_modifiers_materials_and_hidden_objects():
    red = demo_blend.principled("red", (0.8, 0.1, 0.1))
    blue = demo_blend.principled("blue", (0.1, 0.1, 0.8))
    me = cube_mesh("two_tone", materials=(red, blue))
    mi = np.array([0, 1, 0, 1, 0, 1], dtype=np.int32)
    me.polygons.foreach_set("material_index", mi)
    ob = link(bpy.data.objects.new("subdivided", me))
    ob.modifiers.new("subsurf", "SUBSURF").levels = 1
    hidden = link(bpy.data.objects.new("hidden", cube_mesh("hidden")))
    hidden.hide_render = True
    scene, emap, _ = export_current()
    assert [r.object_name for r in emap.instances] == ["subdivided"]
    tm = scene.prototypes[0].meshes[0]
    # One subdivision level: each quad becomes 4 quads = 8 triangles.
    assert tm.triangles.shape == (6 * 8, 3)
    eval_mesh = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).data
    eval_mi = np.array([t.material_index for t in eval_mesh.loop_triangles])
    names = [scene.materials[i].name for i in tm.material_ids]
    assert names == [["red", "blue"][k] for k in eval_mi]
    assert names.count("red") == names.count("blue") == 24
    assert emap.materials == ["red", "blue"]


def test_lightmap_uv_layer_becomes_uvs():
    ob = demo_blend.mesh_object("panel", [(0, 0, 0), (2, 0, 0), (2, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)],
                                uvs=[(0.1, 0.2), (0.9, 0.2), (0.9, 0.6), (0.1, 0.6)])
    ob.data.uv_layers.new(name="UVMap")  # another layer must not be taken
    plain = link(bpy.data.objects.new("plain", cube_mesh("plain")))
    plain.location = (5, 0, 0)
    bad = demo_blend.mesh_object("tiled", [(0, 0, 0), (1, 0, 0), (1, 1, 0)], [(0, 1, 2)],
                                 uvs=[(0, 0), (2, 0), (2, 1)])
    bad.location = (0, 5, 0)
    scene, emap, warnings = export_current()
    by = {p.name: p.meshes[0] for p in scene.prototypes}
    tm = by["panel"]
    me = ob.data
    corner_uv = {l.vertex_index: tuple(me.uv_layers["Lightmap"].uv[l.index].vector) for l in me.loops}
    expect = np.array([[corner_uv[v] for v in tri] for tri in tm.triangles])
    assert tm.uvs.shape == (2, 3, 2)
    np.testing.assert_allclose(tm.uvs, expect, atol=1e-7)
    assert by["plain"].uvs is None and by["tiled"].uvs is None
    assert {r.mesh_name: r.uv_source for r in emap.prototypes} == {
        "panel": "Lightmap", "plain": "xatlas", "tiled": "xatlas"}
    assert any("tiled" in m and "[0,1]" in m for _, m in warnings)


def test_object_settings_exclude_and_resolution():
    me = cube_mesh()
    a = link(bpy.data.objects.new("a", me))
    b = link(bpy.data.objects.new("b", me))
    b.location = (4, 0, 0)
    a.photon_lightmaps.exclude = True
    b.photon_lightmaps.lightmap_resolution = 24
    bpy.context.scene.photon_lightmaps.texel_density = 5.0
    scene, emap, _ = export_current()
    inst = {i.name: i for i in scene.instances}
    assert inst["a"].lightmap is False and inst["b"].lightmap is True
    assert inst["b"].lightmap_resolution == 24 and inst["a"].lightmap_resolution == 0
    assert scene.texel_density == 5.0
    assert [r.lightmap for r in emap.instances] == [i.lightmap for i in scene.instances]
    # The excluded object still blocks light but owns no lightmap; b's is 24 x 24.
    cs = compile_scene(scene)
    ids = {i.name: cs.instance_lightmaps[k] for k, i in enumerate(scene.instances)}
    assert ids["a"] == [] and len(ids["b"]) == 1
    assert (int(cs.lightmaps.width[ids["b"][0]]), int(cs.lightmaps.height[ids["b"][0]])) == (24, 24)


# -- camera ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["PERSP", "ORTHO"])
def test_camera_matches_blender_projection(kind):
    """The engine's image-plane extents equal those of Blender's own projection matrix."""
    scene = bpy.context.scene
    cam_ob = demo_blend.add_camera(scene, (1.0, -2.0, 3.0), (1.1, 0.2, 0.3), lens=35.0, sensor=32.0)
    cam = cam_ob.data
    cam.type = kind
    cam.sensor_height = 20.0
    cam.ortho_scale = 5.0
    checked = 0
    for fit in ("AUTO", "HORIZONTAL", "VERTICAL"):
        for w, h in ((160, 90), (90, 160), (64, 64)):
            cam.sensor_fit = fit
            scene.render.resolution_x, scene.render.resolution_y = w, h
            scene.render.resolution_percentage = 50
            dg = bpy.context.evaluated_depsgraph_get()
            s, _, _ = export_current()
            assert (s.camera.width, s.camera.height) == (w // 2, h // 2)
            cd = compile_camera(s.camera)
            P = np.array(cam_ob.calc_matrix_camera(dg, x=w, y=h))
            assert cd.kind == (1 if kind == "ORTHO" else 0)
            np.testing.assert_allclose([cd.sx, cd.sy], [1.0 / P[0, 0], 1.0 / P[1, 1]], rtol=1e-6)
            checked += 1
    np.testing.assert_allclose(s.camera.transform, world_matrix(cam_ob), atol=1e-6)
    assert checked == 9


# -- materials ----------------------------------------------------------------------------------------

def _assign(ob, mat):
    ob.data.materials.append(mat)


def _mat_objects(mats):
    for i, m in enumerate(mats):
        ob = link(bpy.data.objects.new(f"ob_{m.name}", cube_mesh(f"me_{m.name}", materials=(m,))))
        ob.location = (3 * i, 0, 0)


def test_principled_material_mapping():
    base = (0.6, 0.5, 0.4)
    metal = demo_blend.principled("metal", base, metallic=0.25, transmission=0.5, roughness=0.3, ior=1.33,
                                  emission=(1.0, 0.5, 0.25, 4.0))
    hot = demo_blend.principled("hot", (2.0, 0.5, 0.5))  # over-unity base colour
    _mat_objects([metal, hot])
    scene, emap, warnings = export_current()
    m = {mm.name: mm for mm in scene.materials}
    b = np.array(base)
    np.testing.assert_allclose(m["metal"].specular, b * 0.25, rtol=1e-6)
    np.testing.assert_allclose(m["metal"].diffuse, b * 0.75 * 0.5, rtol=1e-6)
    np.testing.assert_allclose(m["metal"].transmission, b * 0.75 * 0.5, rtol=1e-6)
    np.testing.assert_allclose(m["metal"].emission, [4.0, 2.0, 1.0], rtol=1e-6)
    assert m["metal"].roughness == pytest.approx(0.3) and m["metal"].ior == pytest.approx(1.33)
    np.testing.assert_allclose(m["hot"].diffuse, [1.0, 0.25, 0.25], rtol=1e-6)
    assert any("hot" in w and "scaled" in w for _, w in warnings)
    for mm in scene.materials:
        assert np.all(mm.diffuse + mm.specular + mm.transmission <= 1.0 + 1e-12)


def test_material_dispersion_setting_is_exported():
    """The material panel's Dispersion: a catalogue glass replaces the shader's IOR by its n_d,
    an Abbe number spreads the IOR, None leaves a material as it was."""
    crown = demo_blend.principled("crown", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.45)
    crown.photon_lightmaps.dispersion = "N_BK7"
    flint = demo_blend.principled("flint", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.7)
    flint.photon_lightmaps.dispersion = "ABBE"
    flint.photon_lightmaps.abbe = 30.0
    plain = demo_blend.principled("plain", (1.0, 1.0, 1.0), transmission=1.0, ior=1.33)
    plain.photon_lightmaps.abbe = 30.0        # not chosen: no dispersion
    _mat_objects([crown, flint, plain])
    scene, _, _ = export_current()
    m = {mm.name: mm for mm in scene.materials}
    assert (m["crown"].glass, m["flint"].glass, m["plain"].glass) == ("N-BK7", "", "")
    assert (m["crown"].abbe, m["flint"].abbe, m["plain"].abbe) == (0.0, 30.0, 0.0)
    from photon_lightmaps.engine import spectral
    ms = compile_scene(spectral.spectral_scene(scene)).materials
    idx = {mm.name: i for i, mm in enumerate(scene.materials)}
    assert ms.ior[idx["crown"]] == pytest.approx(1.5168, abs=1e-4) and ms.ior[idx["flint"]] == pytest.approx(1.7)
    assert ms.dispersion[idx["plain"], 0] == 0 and ms.dispersion[idx["flint"], 0] > 0


def test_conductors_are_exported():
    """Blender's Metallic BSDF (Physical Conductor: its IOR and Extinction per channel; F82 Tint:
    Schlick's colour) and the material panel's Conductor preset on a Principled metal."""
    def metallic(name, fresnel):
        mat = bpy.data.materials.new(name)
        mat.use_nodes = True
        nodes = mat.node_tree.nodes
        nodes.remove(nodes["Principled BSDF"])
        node = nodes.new("ShaderNodeBsdfMetallic")
        node.inputs["Roughness"].default_value = 0.2
        node.inputs["Base Color"].default_value = (0.9, 0.6, 0.3, 1.0)
        node.fresnel_type = "PHYSICAL_CONDUCTOR"         # (a mode's sockets are reachable in that mode)
        node.inputs["IOR"].default_value = (0.2, 0.4, 1.4)
        node.inputs["Extinction"].default_value = (3.4, 2.4, 1.8)
        node.fresnel_type = fresnel
        mat.node_tree.links.new(node.outputs[0], nodes["Material Output"].inputs["Surface"])
        return mat
    gold = demo_blend.principled("gold", (1.0, 1.0, 1.0), metallic=1.0, roughness=0.1)
    gold.photon_lightmaps.conductor = "AU"
    _mat_objects([metallic("physical", "PHYSICAL_CONDUCTOR"), metallic("f82", "F82"), gold])
    scene, _, _ = export_current()
    m = {mm.name: mm for mm in scene.materials}
    n, k = m["physical"].conductor
    np.testing.assert_allclose(n, [0.2, 0.4, 1.4], rtol=1e-6)
    np.testing.assert_allclose(k, [3.4, 2.4, 1.8], rtol=1e-6)
    assert m["physical"].metallic == 1.0 and m["physical"].roughness == pytest.approx(0.2)
    assert m["f82"].conductor == "" and m["f82"].metal_fresnel
    np.testing.assert_allclose(m["f82"].specular, [0.9, 0.6, 0.3], rtol=1e-6)
    assert m["gold"].conductor == "Au"
    from photon_lightmaps.engine.shading import bsdf
    bt = compile_scene(scene).bsdf
    idx = {mm.name: i for i, mm in enumerate(scene.materials)}
    assert bt.metal_fresnel[idx["physical"]] == bsdf.METAL_CONDUCTOR == bt.metal_fresnel[idx["gold"]]
    np.testing.assert_allclose(bt.conductor[idx["physical"], :, :2], np.array([n, k]).T)


def test_blackbody_node_on_an_emission_colour():
    """A Blackbody node (3000 K) on an Emission shader's colour: RGB mode glows its colour
    (within 2 % of Blender's own blackbody colour, here a light's at that temperature;
    measured 0.9 % in blue: our colour is Planck's through the 16 bands),
    and spectral mode emits Planck's spectrum at that colour's luminance."""
    mat = bpy.data.materials.new("ember")
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    em = tree.nodes.new("ShaderNodeEmission")
    bb = tree.nodes.new("ShaderNodeBlackbody")
    bb.inputs["Temperature"].default_value = 3000.0
    em.inputs["Strength"].default_value = 2.0
    tree.links.new(bb.outputs["Color"], em.inputs["Color"])
    tree.links.new(em.outputs["Emission"], out.inputs["Surface"])
    _mat_objects([mat])
    lamp = bpy.data.lights.new("ref", "POINT")
    lamp.use_temperature, lamp.temperature = True, 3000.0
    scene, _, warnings = export_current()
    m = next(mm for mm in scene.materials if mm.name == "ember")
    assert m.emission_temperature == 3000.0 and not [w for w in warnings if "ember" in w[1]]
    np.testing.assert_allclose(m.emission, 2.0 * np.asarray(lamp.temperature_color), rtol=0.02)
    from photon_lightmaps.engine import spectral
    from photon_lightmaps.engine.shading import spectrum
    bands = spectrum.Bands()
    glow = next(mm for mm in spectral.spectral_scene(scene, bands).materials if mm.name == "ember").emission
    planck = spectrum.blackbody_spectrum(3000.0, bands)
    np.testing.assert_allclose(glow / glow.sum(), planck / planck.sum(), rtol=0.02)
    y = np.linalg.inv(bands.xyz_to_rgb)[1]
    assert spectrum.luminance(glow, bands) == pytest.approx(float(y @ m.emission), rel=1e-6)


def test_material_fluorescence_setting_is_exported():
    """The material panel's Fluorescence: a preset (its absorption scaled by Strength), custom
    spectra, or none."""
    from photon_lightmaps.engine.shading import fluorescence
    dye = demo_blend.principled("dye", (0.9, 0.9, 0.2))
    dye.photon_lightmaps.fluorescence = "FLUORESCEIN"
    dye.photon_lightmaps.fl_strength = 0.5
    own = demo_blend.principled("own", (0.9, 0.9, 0.9))
    s = own.photon_lightmaps
    s.fluorescence = "CUSTOM"
    s.fl_excitation_nm, s.fl_excitation_width, s.fl_emission_nm, s.fl_emission_width = 400.0, 10.0, 600.0, 30.0
    s.fl_absorption, s.fl_quantum_yield = 0.6, 0.5
    plain = demo_blend.principled("plain", (0.5, 0.5, 0.5))
    _mat_objects([dye, own, plain])
    scene, _, _ = export_current()
    m = {mm.name: mm for mm in scene.materials}
    fl = fluorescence.PRESETS["fluorescein"]
    assert m["dye"].fluorescence == fluorescence.Fluorescence("fluorescein", fl.excitation_nm, fl.excitation_width,
                                                              fl.emission_nm, fl.emission_width, 0.5 * fl.peak,
                                                              fl.quantum_yield)
    got = m["own"].fluorescence
    assert (got.excitation_nm, got.excitation_width, got.emission_nm, got.emission_width) == (400, 10, 600, 30)
    assert got.peak == pytest.approx(0.6) and got.quantum_yield == pytest.approx(0.5)
    assert m["plain"].fluorescence is None


def test_image_texture_is_baked_and_other_shaders_fall_back():
    tex_mat = demo_blend.principled("textured", (0.1, 0.1, 0.1))
    tree = tex_mat.node_tree
    img = bpy.data.images.new("checker", 2, 2, alpha=True)  # byte image, sRGB
    img.pixels.foreach_set(np.array([1, 1, 1, 1, .5, .5, .5, 1, 1, 1, 1, 1, .5, .5, .5, 1], np.float32))
    node = tree.nodes.new("ShaderNodeTexImage")
    node.image = img
    tree.links.new(node.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    toon = bpy.data.materials.new("toon")
    toon.diffuse_color = (0.2, 0.3, 0.4, 1.0)
    nodes = toon.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    shader = nodes.new("ShaderNodeBsdfToon")
    out = next(n for n in nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    toon.node_tree.links.new(shader.outputs[0], out.inputs["Surface"])
    _mat_objects([tex_mat, toon])
    bpy.data.meshes["me_textured"].uv_layers.new(name="UVMap")   # each face on the whole image
    scene, emap, warnings = export_current()
    m = {mm.name: mm for mm in scene.materials}     # the textured variant comes last
    # Half white, half sRGB-grey texels (stored as bytes), baked by Cycles to scene linear
    # (export/textures.py; tests/test_textures.py checks texel by texel).
    grey = 128 / 255
    expect = (1.0 + ((grey + 0.055) / 1.055) ** 2.4) / 2
    texture = scene.textures[m["textured"].textures["base_color"]]
    assert texture.encoding == "srgb"                  # an 8-bit sRGB image: kept encoded
    from photon_lightmaps.engine.shading.texture import srgb_to_linear
    tex = srgb_to_linear(texture.pixels)
    assert tex.shape == (2, 2, 3)                      # the image's own resolution
    np.testing.assert_allclose(tex.mean(axis=(0, 1)), [expect] * 3, atol=5e-3)
    np.testing.assert_allclose(m["toon"].diffuse, [0.2, 0.3, 0.4], rtol=1e-6)
    text = " ".join(w for _, w in warnings)
    assert "checker" not in text and "averaged" not in text
    assert "'toon'" in text and "ShaderNodeBsdfToon" in text
    assert emap.warnings == [w for level, w in warnings if level == "WARNING"]


def test_world_colour():
    world = demo_blend.set_world(bpy.context.scene, color=(0.2, 0.4, 0.6), strength=2.5)
    link(bpy.data.objects.new("c", cube_mesh()))
    scene, _, _ = export_current()
    np.testing.assert_allclose(scene.environment, [0.5, 1.0, 1.5], rtol=1e-6)
    grey, _ = export.export_scene(bpy.context.evaluated_depsgraph_get(), n_bands=1)
    np.testing.assert_allclose(grey.environment, [1.0], rtol=1e-6)
    assert grey.n_bands == 1 and grey.materials[0].diffuse.shape == (1,)
    world.node_tree.nodes.remove(next(n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground"))
    scene, _, _ = export_current()
    assert np.all(np.asarray(scene.environment) == 0.0)


# -- lights --------------------------------------------------------------------------------------------

def test_light_units():
    sc = bpy.context.scene
    p = demo_blend.add_light(sc, "POINT", "point", power=100.0, location=(1, 2, 3), radius=0.25)
    p.data.color = (1.0, 0.5, 0.25)
    p.data.exposure = 1.0
    s = demo_blend.add_light(sc, "SPOT", "spot", power=50.0, radius=0.0, spot_size=math.radians(40),
                             spot_blend=0.2, rotation=(0.3, 0.0, 0.0))
    s.data.use_soft_falloff = False
    sun = demo_blend.add_light(sc, "SUN", "sun", power=4.0, angle=math.radians(3.0))
    sun.data.use_temperature = True
    sun.data.temperature = 4000.0
    areas = {}
    for shape, sx, sy in (("SQUARE", 0.5, 9.0), ("RECTANGLE", 0.6, 0.3), ("DISK", 0.7, 9.0), ("ELLIPSE", 0.8, 0.4)):
        areas[shape] = demo_blend.add_light(sc, "AREA", f"area_{shape.lower()}", power=30.0, shape=shape,
                                            size=sx, size_y=sy)
    un = demo_blend.add_light(sc, "AREA", "unnormalised", power=30.0, shape="RECTANGLE", size=2.0, size_y=0.5)
    un.data.normalize = False
    un.scale = (1.5, 1.0, 1.0)
    unp = demo_blend.add_light(sc, "POINT", "unnormalised_point", power=10.0, radius=0.5)
    unp.data.normalize = False
    scene, emap, _ = export_current()
    L = {l.name: l for l in scene.lights}
    assert emap.lights == [l.name for l in scene.lights]
    assert L["point"].kind == "point" and L["point"].power == pytest.approx(200.0)
    np.testing.assert_allclose(L["point"].color, [1.0, 0.5, 0.25])
    assert L["point"].radius == pytest.approx(0.25) and L["point"].soft_falloff is True
    np.testing.assert_allclose(L["point"].transform, world_matrix(p), atol=1e-7)
    assert L["spot"].spot_size == pytest.approx(math.radians(40)) and L["spot"].spot_blend == pytest.approx(0.2)
    assert L["spot"].soft_falloff is False
    assert L["sun"].kind == "sun" and L["sun"].power == pytest.approx(4.0)
    assert L["sun"].angle == pytest.approx(math.radians(3.0))
    np.testing.assert_allclose(L["sun"].color, np.array(sun.data.temperature_color), rtol=1e-6)
    assert L["sun"].color[0] > L["sun"].color[2]  # 4000 K is warm
    assert L["sun"].temperature == pytest.approx(4000.0) and L["point"].temperature == 0.0
    # spectral mode emits Planck's spectrum: back in RGB within 2 % of Blender's own
    # temperature colour (measured 0.4 % at 4000 K, 1.5 % at 2700 K), its luminance kept
    from photon_lightmaps.engine import spectral
    from photon_lightmaps.engine.shading import spectrum
    bands = spectrum.Bands()
    sun_spectrum = {lt.name: lt for lt in spectral.spectral_scene(scene).lights}["sun"].color
    np.testing.assert_allclose(spectrum.to_rgb(sun_spectrum, bands), L["sun"].color, rtol=0.02)
    y = np.linalg.inv(bands.xyz_to_rgb)[1]
    assert spectrum.luminance(sun_spectrum, bands) == pytest.approx(float(y @ L["sun"].color), rel=1e-9)
    for shape, ob in areas.items():
        l = L[ob.name]
        assert l.kind == "area" and l.shape == shape.lower() and l.power == pytest.approx(30.0)
        assert l.size == pytest.approx(ob.data.size)
        assert l.size_y == pytest.approx(ob.data.size if shape in ("SQUARE", "DISK") else ob.data.size_y)
    # Unnormalised: power per unit area (world size, so object scale counts).
    assert L["unnormalised"].power == pytest.approx(30.0 * 2.0 * 1.5 * 0.5)
    assert L["unnormalised_point"].power == pytest.approx(10.0 * 4.0 * math.pi * 0.25)


def test_line_spectrum_light_is_exported():
    """The light panel's Spectrum = Line: the wavelength and width reach the engine, and RGB
    gets the line's colour (a 395 nm lamp: violet, clipped into Rec.709)."""
    sc = bpy.context.scene
    uv = demo_blend.add_light(sc, "POINT", "uv_lamp", power=10.0)
    uv.data.photon_lightmaps.spectrum = "LINE"
    uv.data.photon_lightmaps.line_nm = 395.0
    uv.data.photon_lightmaps.line_width = 15.0
    plain = demo_blend.add_light(sc, "POINT", "plain", power=10.0)
    plain.data.photon_lightmaps.line_nm = 500.0      # Spectrum stays Colour: no line
    scene, _, _ = export_current()
    L = {l.name: l for l in scene.lights}
    assert (L["uv_lamp"].line_nm, L["uv_lamp"].line_width) == (395.0, 15.0) and L["plain"].line_nm == 0.0
    c = np.asarray(L["uv_lamp"].color)
    assert np.all(c >= 0.0) and c[2] > 5.0 * max(c[0], c[1])


def test_light_polarizer_is_exported():
    """The light panel's Polarizer: its angle when on (None when off); the compiled light
    passes half its power, polarized along the light's local axis at that angle."""
    sc = bpy.context.scene
    lamp = demo_blend.add_light(sc, "SPOT", "lamp", power=10.0)
    lamp.rotation_euler = (0.0, 0.0, math.radians(30.0))
    lamp.data.photon_lightmaps.use_polarizer = True
    lamp.data.photon_lightmaps.polarizer_angle = math.radians(60.0)
    plain = demo_blend.add_light(sc, "SPOT", "plain", power=10.0)
    plain.data.photon_lightmaps.polarizer_angle = math.radians(60.0)     # not on: none
    scene, _, _ = export_current()
    L = {l.name: l for l in scene.lights}
    assert L["lamp"].polarizer == pytest.approx(math.radians(60.0)) and L["plain"].polarizer is None
    ls = compile_scene(scene).lights
    i = [l.name for l in scene.lights].index("lamp")
    j = [l.name for l in scene.lights].index("plain")
    np.testing.assert_allclose(ls.flux[i], 0.5 * ls.flux[j], rtol=1e-12)
    # local x turned 30° about z, then the axis 60° from it: 90° from the world's x
    np.testing.assert_allclose(ls.pol[i], [0.0, 1.0, 0.0, 1.0], atol=1e-6)
    assert not ls.pol[j].any()


def test_camera_polarizing_filter_is_exported():
    """The camera panel's Polarizing Filter: its angle when on, None when off; the render
    panel's Polarization reaches the camera too."""
    sc = bpy.context.scene
    cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    link(cam)
    sc.camera = cam
    c = export_current()[0].camera
    assert c.polarizer is None and c.polarized is False
    cam.data.photon_lightmaps.use_polarizer = True
    cam.data.photon_lightmaps.polarizer_angle = math.radians(90.0)
    sc.photon_lightmaps.polarization = True
    c = export_current()[0].camera
    assert c.polarizer == pytest.approx(math.pi / 2) and c.polarized is True
