"""The orientation-lightmap bake for L-system objects (thesis 7.3, bake/orientation.py).

An L-system object no collection OL covers is lit through an automatic OL of its own
("<object> (L-system)", engine/compile._lsystem_orientation). The OL bake writes it to an
image the object owns ("<object>_Lightmap", the image policy of bake/images.py), hooks it
into the object's materials with the normal-indexed OL hook (bake/hooks.add_ol_hook) and
Remove Orientation Lightmap on the object takes both away again, leaving the object.

Scene: the sphereflake preset at depth 2 (91 spheres) resting on a grey ground plane, lit
by a sun from the side; no world light, so bins facing away from the sun see only the
light the ground and the flake reflect.
"""
import math

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import demo_blend  # noqa: E402
from photon_lightmaps.bake import hooks  # noqa: E402
from photon_lightmaps.bake import lsystem_preview  # noqa: E402
from photon_lightmaps.bake import orientation as ol_bake  # noqa: E402
from photon_lightmaps.export import lsystems  # noqa: E402

from blender_session import empty_blender_file, addon  # noqa: E402,F401  (session-wide registration)

SUN_ROTATION = (math.radians(50.0), 0.0, math.radians(30.0))


@pytest.fixture(autouse=True)
def empty_file(tmp_path_factory, monkeypatch):
    yield from empty_blender_file(tmp_path_factory, monkeypatch)


def flake_scene(scene, link="DATA"):
    """Ground (6 x 6 m, 'Lightmap' UVs), a sphereflake of depth 2 touching it, a sun;
    the three materials (slot g for generation g) linked to the mesh or the object (`link`)."""
    ground = demo_blend.principled("ground", (0.5, 0.5, 0.5))
    s = 3.0
    demo_blend.mesh_object("ground", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)],
                           ground, uvs=demo_blend.quad_uvs())
    ob = lsystem_preview.new_lsystem_object("flake", preset="sphereflake", location=(0.0, 0.0, 1.0))
    props = ob.photon_lightmaps.lsystem
    props.use_render_iterations, props.render_iterations = True, 2
    for name, rgb in (("flake_0", (0.8, 0.8, 0.8)), ("flake_1", (0.8, 0.5, 0.3)), ("flake_2", (0.3, 0.6, 0.3))):
        ob.data.materials.append(demo_blend.principled(name, rgb))      # ;(g): slot g
    if link == "OBJECT":
        for slot in ob.material_slots:
            m = slot.material
            slot.link, slot.material = "OBJECT", m
    lsystem_preview.update_preview(ob)
    assert lsystems.info(ob)["depth"] == 2
    demo_blend.add_light(scene, "SUN", "sun", power=3.0, rotation=SUN_ROTATION)
    demo_blend.set_world(scene)
    return ob


def to_sun():
    from mathutils import Euler, Vector
    return np.array(Euler(SUN_ROTATION, "XYZ").to_matrix() @ Vector((0.0, 0.0, 1.0)))


def material_state(mat):
    t = mat.node_tree
    return (sorted((n.name, n.bl_idname, tuple(n.location)) for n in t.nodes),
            sorted((lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier)
                   for lk in t.links))


def test_ol_bake_bakes_and_hooks_an_lsystem_object_and_remove_restores_it():
    ob = flake_scene(bpy.context.scene)
    mats = [s.material for s in ob.material_slots]
    before = {m.name: material_state(m) for m in mats}
    groups_before = sorted(ng.name for ng in bpy.data.node_groups)
    images_before = sorted(im.name for im in bpy.data.images)

    res = ol_bake.bake_orientation_lightmaps(bpy.context, photons=60_000, seed=1, pack=True)
    # the object's own automatic OL, baked to an image the object owns
    assert res.lsystems == {ob.name: f"{ob.name} (L-system)"}
    img = bpy.data.images[res.images[ob.name]]
    assert img.name == f"{ob.name}_Lightmap" and img.is_float and img.packed_file is not None
    assert img.get(ol_bake.OL_IMAGE_PROP) == ob.name and img.get("photon_lightmaps_object") == ob.name
    rgba = res.maps[ob.name]
    r = rgba.shape[0]
    assert tuple(img.size) == (r, r) and r == 16
    px = np.empty(r * r * 4, np.float32)
    img.pixels.foreach_get(px)
    np.testing.assert_array_equal(px.reshape(r, r, 4), rgba)
    assert ol_bake.last_report(bpy.context.scene.name, ob)["name"] == res.lsystems[ob.name]

    # bins where the flake has area hold finite positive irradiance (E = pi * RGB)
    has_area = rgba[..., 3] > 0
    assert has_area.mean() > 0.9                 # spheres: (almost) every direction
    e = math.pi * rgba[..., :3].astype(np.float64).mean(axis=2)
    assert np.all(np.isfinite(e[has_area])) and np.all(e[has_area] > 0.0)
    # the bins facing the sun receive more than those facing away (indirect light only)
    c = (np.arange(r) + 0.5) / r
    normals = ol_bake.octa_decode(np.tile(c, r), np.repeat(c, r)).reshape(r, r, 3)   # [y, x]
    cos = normals @ to_sun()
    lit, away = has_area & (cos > 0.5), has_area & (cos < -0.5)
    assert lit.sum() > 10 and away.sum() > 10
    e_lit, e_away = e[lit].mean(), e[away].mean()
    print(f"\nL-system OL bake: {r}x{r} bins, {has_area.sum()} with area; E facing the sun "
          f"{e_lit:.3f}, facing away {e_away:.3f} W/m^2")
    # a 3 W/m^2 sun: unshadowed, the bins at cos > 0.5 would average 2.25 W/m^2 directly; the
    # spheres shade each other (measured 1.58 against 0.25 facing away)
    assert e_lit > 1.0 and e_lit > 3.0 * e_away

    # the normal-indexed hook in every material of the object, reading that image
    assert sorted(res.hooked) == sorted(m.name for m in mats)
    for m in mats:
        ours = [n for n in m.node_tree.nodes if n.get(ol_bake.OL_HOOK_PROP) == ob.name]
        kinds = {n.bl_idname for n in ours}
        assert {"NodeFrame", "ShaderNodeGroup", "ShaderNodeTexImage", "ShaderNodeOutputMaterial"} <= kinds
        assert next(n for n in ours if n.bl_idname == "ShaderNodeTexImage").image == img
        assert next(n for n in ours if n.bl_idname == "ShaderNodeOutputMaterial").target == "EEVEE"
        assert any(n.bl_idname == "ShaderNodeGroup" and n.node_tree.name == hooks.OL_GROUP for n in ours)

    # baking again writes the same image (a packed one is rebuilt under its name, bake/images.py)
    name = img.name
    res2 = ol_bake.bake_orientation_lightmaps(bpy.context, photons=20_000, seed=2, pack=True)
    assert res2.images[ob.name] == name and len([i for i in bpy.data.images if i.name.startswith(name)]) == 1

    # Remove Orientation Lightmap on the L-system object: image and nodes go, the object stays
    bpy.context.view_layer.objects.active = ob
    assert bpy.ops.photon_lightmaps.remove_orientation_lightmap() == {"FINISHED"}
    assert bpy.data.objects.get("flake") is not None and lsystems.is_lsystem(bpy.data.objects["flake"])
    assert {m.name: material_state(m) for m in mats} == before
    assert sorted(ng.name for ng in bpy.data.node_groups) == groups_before
    assert sorted(im.name for im in bpy.data.images) == images_before
    assert ol_bake.REPORT_PROP not in ob.keys()


def test_a_collection_ol_covering_an_lsystem_bakes_it_in_its_own_image():
    scene = bpy.context.scene
    ob = flake_scene(scene)
    from photon_lightmaps.operators import orientation_lightmaps
    coll = bpy.data.collections.new("plants")
    scene.collection.children.link(coll)
    coll.objects.link(ob)
    scene.collection.objects.unlink(ob)
    empty = orientation_lightmaps.add_orientation_lightmap(scene, coll, resolution=8, samples=4000)
    res = ol_bake.bake_orientation_lightmaps(bpy.context, photons=20_000, seed=1, pack=True)
    assert res.lsystems == {} and ob.name not in res.images
    assert res.covered[empty.name] == [ob.name]
    mat = ob.material_slots[0].material
    assert {n.get(ol_bake.OL_HOOK_PROP) for n in mat.node_tree.nodes if n.get(ol_bake.OL_HOOK_PROP)} == {empty.name}


def test_stubs_are_baked_into_the_objects_image():
    scene = bpy.context.scene
    ob = flake_scene(scene)
    text = lsystems.grammar_text(ob)
    text.from_string(text.as_string().replace("derivation length:", "ol stub: @O levels 1\nderivation length:"))
    lsystem_preview.update_preview(ob)
    res = ol_bake.bake_orientation_lightmaps(bpy.context, photons=20_000, seed=1, pack=True, hook_materials=False)
    names = [row["name"] for row in res.rows]
    assert sum(n.startswith(f"{ob.name} stub ") for n in names) == 9
    assert list(res.images) == [ob.name] and not res.hooked
    assert any("OL stubs" in w for w in res.warnings)
