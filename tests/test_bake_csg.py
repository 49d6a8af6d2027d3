"""Baking exact CSG solids: one atlas image per solid, split texels
written with their dominant sub-texel, operand Lightmap layers moved into their
atlas blocks (so Blender's Boolean result shows the image), nothing of the user's
rewritten, re-baking idempotent, and the light itself right (analytic direct light).

One bake of a shared scene serves most tests (module fixture); tests that change
the scene build their own small one.
"""
import math

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake  # noqa: E402
from photon_lightmaps.export import uv_layers  # noqa: E402
from photon_lightmaps.engine.transport import csg_bake  # noqa: E402
from photon_lightmaps.engine.lightmaps import lightmap  # noqa: E402
from photon_lightmaps.engine.geometry import primitives  # noqa: E402
from photon_lightmaps.engine.core.errors import Cancelled  # noqa: E402
from photon_lightmaps.operators import csg_primitives  # noqa: E402

from blender_session import addon  # noqa: E402,F401  (session-wide registration)

RES = 16
POWER = 1000.0
LIGHT = (4.3, 0.2, 3.5)
SLAB_TOP = 1.5


def pixels(img):
    w, h = img.size
    a = np.empty(w * h * img.channels, np.float32)
    img.pixels.foreach_get(a)
    return a.reshape(h, w, img.channels)


def material(name, rgb):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    m.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (*rgb, 1.0)
    return m


def difference(base, cutter):
    m = base.modifiers.new(f"cut {cutter.name}", "BOOLEAN")
    m.operation = "DIFFERENCE"
    m.solver = "EXACT"
    m.object = cutter
    cutter.hide_render = True
    return m


def point_light(location=LIGHT, power=POWER):
    ld = bpy.data.lights.new("Lamp", "POINT")
    ld.energy = power
    ld.shadow_soft_size = 0.0
    lo = bpy.data.objects.new("Lamp", ld)
    lo.location = location
    bpy.context.scene.collection.objects.link(lo)
    return lo


def cylinder_minus_sphere():
    cyl = csg_primitives.new_primitive_object("cylinder", "Cyl", segments=32, material=material("CylMat", (0.8, 0.8, 0.8)))
    sph = csg_primitives.new_primitive_object("sphere", "Sph", location=(0, 0, 1.0), segments=32,
                                  material=material("SphMat", (0.6, 0.7, 0.8)))
    sph.scale = (0.7,) * 3
    difference(cyl, sph)
    return cyl, sph


def slotted_slab():
    """A 2 x 2 x 1 box (top at z = 1.5) cut through by a slot 0.04 wide at x in [4.01, 4.05]:
    texel columns of width 0.125 straddling the slot fall apart into an 8% and a 60% part."""
    slab = csg_primitives.new_primitive_object("box", "Slab", location=(4.0, 0.0, 1.0),
                                   material=material("SlabMat", (0.8, 0.8, 0.8)))
    slab.scale = (1.0, 1.0, 0.5)
    slot = csg_primitives.new_primitive_object("box", "Slot", location=(4.03, 0.0, 1.0))
    slot.scale = (0.02, 2.0, 2.0)
    difference(slab, slot)
    return slab, slot


def block(bm, leaf):
    x, y, w, h = bm.tiles[leaf]
    return bm.rgba[y:y + h, x:x + w]


@pytest.fixture(scope="module")
def baked():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bake.clear_cache()
    cyl, sph = cylinder_minus_sphere()
    slab, slot = slotted_slab()
    point_light()
    objs = [cyl, sph, slab, slot]
    job = bake.prepare_bake(bpy.context, objs, photons=200_000, seed=5, resolution=RES, error_images=True)
    bake.compute_bake(job)
    res = bake.commit_bake(job, hook_materials=True)
    return job, res


# -- one image, blocks, pixel values --------------------------------------------------------

def test_one_image_per_solid_and_operands_are_part_of_it(baked):
    job, res = baked
    assert set(res.maps) == {"Cyl", "Slab"}
    assert "Boolean operand of 'Cyl'" in res.skipped["Sph"]
    assert "Boolean operand of 'Slab'" in res.skipped["Slot"]
    for name, leaves in (("Cyl", {"Cyl", "Sph"}), ("Slab", {"Slab", "Slot"})):
        bm = res.maps[name]
        assert set(bm.tiles) == leaves
        img = bpy.data.images[res.images[name]]
        assert tuple(img.size) == (bm.width, bm.height)
        assert np.array_equal(pixels(img), bm.rgba)
        # blocks keep square texels: F faces x R by R texels
        for leaf, (x, y, w, h) in bm.tiles.items():
            F = int(primitives.N_FACES[primitives.KIND_IDS[bpy.data.objects[leaf]["photon_csg_primitive"]]])
            assert (w, h) == (F * RES, RES)
    # hooked: the base's material and the cutter's (which the Boolean result carries over)
    assert {"CylMat", "SphMat", "SlabMat"} <= set(res.hooked)
    print(f"\nCSG bake: {res.csg}; seconds {res.seconds}")


def test_error_image_has_the_atlas_layout_and_the_error_bars(baked):
    job, res = baked
    assert set(res.error_maps) == set(res.maps)
    for name, bm in res.maps.items():
        em = res.error_maps[name]
        assert em.tiles == bm.tiles
        assert np.array_equal(em.rgba[..., 3], bm.rgba[..., 3])     # the same texels
        rel = em.rgba[..., 0][bm.rgba[..., 3] > 0]
        assert rel.max() == pytest.approx(res.error[name]["rel_error_max"], rel=1e-5)
        assert 0.0 < rel.mean() < 1.0
        img = bpy.data.images[res.error_images[name]]
        assert img.name == f"{name}_LightmapError" and img.name != res.images[name]
        assert np.array_equal(pixels(img), em.rgba)


def test_visible_texels_lie_exactly_in_their_leaf_blocks(baked):
    job, res = baked
    cs = job.cs
    lm = cs.lightmaps
    n_removed = 0
    for name, bm in res.maps.items():
        inside = np.zeros(bm.rgba.shape[:2], bool)
        for d in csg_bake.solid_leaves(cs, job.targets[name]):
            x, y, w, h = bm.tiles[d["name"]]
            inside[y:y + h, x:x + w] = True
            sl = lightmap.texel_slice(lm, d["lightmap"])
            vis = lm.area[sl].copy()
            for j in np.flatnonzero(lm.split[sl] >= 0):
                vis[j] = lm.area[csg_bake.split_regions(lm, sl.start + j)].sum()
            # coverage > 0 exactly at the texels with visible area
            assert np.array_equal(block(bm, d["name"])[..., 3].reshape(-1) > 0, vis > 0), d["name"]
            assert (vis > 0).any()
            n_removed += int((vis == 0).sum())
        assert not (bm.rgba[..., 3][~inside] > 0).any()
    assert n_removed > 0     # the sphere carves whole texels out of the cylinder's cap


def test_pixels_are_the_lightmap_and_split_texels_their_dominant_region(baked):
    job, res = baked
    lm = job.cs.lightmaps
    n_split = n_not_first = 0
    for name, bm in res.maps.items():
        for d in csg_bake.solid_leaves(job.cs, job.targets[name]):
            sl = lightmap.texel_slice(lm, d["lightmap"])
            px = block(bm, d["name"]).reshape(-1, 4)
            rows = np.arange(sl.start, sl.stop)
            plain = lm.split[sl] < 0
            want = (lm.irradiance[rows[plain]] / math.pi).astype(np.float32)
            assert np.array_equal(px[plain, :3], want)
            for j in np.flatnonzero(~plain):
                reg = csg_bake.split_regions(lm, int(rows[j]))
                best = reg[np.argmax(lm.area[reg])]
                assert np.array_equal(px[j, :3], (lm.irradiance[best] / math.pi).astype(np.float32))
                n_split += 1
                if best != reg[0] and not np.allclose(lm.irradiance[best], lm.irradiance[reg[0]]):
                    n_not_first += 1
    print(f"\nsplit texels {n_split}, dominant region not the texel's own: {n_not_first}")
    # the slot splits texels, and the dominant region is not always region 0
    assert n_split > 0 and n_not_first > 0


def test_top_face_matches_the_analytic_point_light(baked):
    """Nothing is above the slab's top face: E = P cos(theta) / (4 pi r^2), averaged over each texel."""
    job, res = baked
    slab = bpy.data.objects["Slab"]
    M = np.array(slab.matrix_world)
    top = block(res.maps["Slab"], "Slab")[:, 4 * RES:5 * RES]      # face 4: +z
    full = top[..., 3] >= 1.0 - 1e-9
    assert full.sum() > 100
    k = 12
    g = (np.arange(k) + 0.5) / k
    p4 = np.zeros(4)
    L = np.array(LIGHT)
    got, want = [], []
    for y, x in zip(*np.nonzero(full)):
        pts = np.array([primitives.prim_point(np.int32(primitives.BOX), p4, np.int64(4), (x + a) / RES, (y + b) / RES)[:3]
                        for a in g for b in g])
        w = pts @ M[:3, :3].T + M[:3, 3]
        assert np.allclose(w[:, 2], SLAB_TOP)
        d = L - w
        r = np.linalg.norm(d, axis=1)
        want.append(np.mean(POWER * (d[:, 2] / r) / (4 * math.pi * r ** 2)) / math.pi)
        got.append(top[y, x, 0])
    got, want = np.array(got), np.array(want)
    rel = np.abs(got / want - 1.0)
    print(f"\ntop face vs analytic: max rel err {rel.max():.4f}, mean {rel.mean():.5f} over {got.size} texels")
    assert rel.max() < 0.01


# -- UVs of the operands and of Blender's Boolean result ------------------------------------

def _rect(bm, leaf):
    x, y, w, h = bm.tiles[leaf]
    return np.array([x / bm.width, y / bm.height]), np.array([w / bm.width, h / bm.height])


def test_evaluated_boolean_uvs_fall_in_their_operands_blocks(baked):
    """Each face of Blender's Boolean result maps into one operand's block, and into the
    right one: its UV centroid, taken back through that operand's chart, lands on the face."""
    job, res = baked
    dg = bpy.context.evaluated_depsgraph_get()
    for name in res.maps:
        bm = res.maps[name]
        ev = bpy.data.objects[name].evaluated_get(dg)
        me = ev.data
        uv = uv_layers.read_uvs(me.uv_layers["Lightmap"]).astype(np.float64)
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3)
        Mb = np.array(ev.matrix_world)
        rects = {leaf: _rect(bm, leaf) for leaf in bm.tiles}
        counts = dict.fromkeys(rects, 0)
        for poly in me.polygons:
            loops = list(poly.loop_indices)
            u = uv[loops]
            hits = [leaf for leaf, (o, s) in rects.items()
                    if np.all(u >= o - 1e-6) and np.all(u <= o + s + 1e-6)]
            assert len(hits) == 1, (name, poly.index, u)
            leaf = hits[0]
            counts[leaf] += 1
            o, s = rects[leaf]
            ob = bpy.data.objects[leaf]
            kind = primitives.KIND_IDS[ob["photon_csg_primitive"]]
            F = int(primitives.N_FACES[kind])
            unit = (u.mean(axis=0) - o) / s
            f = min(int(unit[0] * F), F - 1)
            p = np.array(primitives.prim_point(np.int32(kind), np.zeros(4), np.int64(f), unit[0] * F - f, unit[1])[:3])
            Ml = np.array(ob.matrix_world)
            pw = Ml[:3, :3] @ p + Ml[:3, 3]
            cw = Mb[:3, :3] @ co[[me.loops[i].vertex_index for i in loops]].mean(axis=0) + Mb[:3, 3]
            # within the display mesh's facet size of the face's centroid
            assert np.linalg.norm(pw - cw) < 0.25, (name, leaf, pw, cw)
        assert all(c > 0 for c in counts.values()), counts


def test_rebake_leaves_uvs_unchanged_and_cancel_writes_nothing():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bake.clear_cache()
    cyl, sph = cylinder_minus_sphere()
    point_light()
    before = {o.name: uv_layers.read_uvs(o.data.uv_layers["Lightmap"]).copy() for o in (cyl, sph)}
    r1 = bake.bake_objects(bpy.context, [cyl], photons=2000, seed=1, resolution=8)
    once = {o.name: uv_layers.read_uvs(o.data.uv_layers["Lightmap"]).copy() for o in (cyl, sph)}
    assert not np.array_equal(once["Sph"], before["Sph"])        # moved into its block
    r2 = bake.bake_objects(bpy.context, [cyl], photons=2000, seed=2, resolution=8)
    for o in (cyl, sph):
        assert np.array_equal(uv_layers.read_uvs(o.data.uv_layers["Lightmap"]), once[o.name])
        # still recognised as the generated layout, with its block remembered
        unit, rect, why = uv_layers.primitive_chart_uvs(o)
        assert why is None and rect != (0.0, 0.0, 1.0, 1.0)
        assert np.abs(unit - before[o.name]).max() < 1e-5
    assert r1.maps["Cyl"].tiles == r2.maps["Cyl"].tiles
    img = bpy.data.images[r2.images["Cyl"]]
    saved = pixels(img).copy()

    # a cancelled bake changes neither the image nor the layers
    with pytest.raises(Cancelled):
        bake.bake_objects(bpy.context, [cyl], photons=50_000, seed=3, resolution=12,
                       progress=lambda done, total: False)
    assert np.array_equal(pixels(img), saved)
    for o in (cyl, sph):
        assert np.array_equal(uv_layers.read_uvs(o.data.uv_layers["Lightmap"]), once[o.name])

    # without its Boolean, the sphere bakes on its own: its layer goes back to the chart layout
    cyl.modifiers.clear()
    sph.hide_render = False
    r3 = bake.bake_objects(bpy.context, [sph], photons=2000, seed=1, resolution=8)
    assert "Sph" in r3.maps
    assert np.abs(uv_layers.read_uvs(sph.data.uv_layers["Lightmap"]) - before["Sph"]).max() < 1e-6
    assert uv_layers.TILE_PROP not in sph.data


def test_user_edited_operand_layer_is_left_alone_with_a_warning():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bake.clear_cache()
    cyl, sph = cylinder_minus_sphere()
    point_light()
    layer = sph.data.uv_layers["Lightmap"]
    uv = uv_layers.read_uvs(layer).copy()
    uv[:40] = uv[:40] * 0.5 + 0.25          # the user's edit
    layer.uv.foreach_set("vector", uv.reshape(-1))
    res = bake.bake_objects(bpy.context, [cyl], photons=2000, seed=1, resolution=8)
    assert set(res.maps["Cyl"].tiles) == {"Cyl"}
    assert any("'Sph'" in w and "left out" in w for w in res.warnings), res.warnings
    assert np.array_equal(uv_layers.read_uvs(sph.data.uv_layers["Lightmap"]), uv)
    assert res.csg["Cyl"]["skipped"].keys() == {"Sph"}


def test_ao_pass_bakes_csg_solids_over_their_boundary():
    """The slotted slab under a 4 x 4 m plate 0.5 m above its top: every top texel's
    AO within 1 m is the share of cosine rays that pass the plate's height first,
    (h / d)² = 0.25 (the plate reaches past the slab by more than any occluded ray
    goes sideways, sqrt(d² - h²)), split texels beside the slot too: only the
    points on the solid's boundary count. The slot's walls, 4 cm apart, see each
    other: nearly no AO."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    slab, _ = slotted_slab()
    me = bpy.data.meshes.new("plate")
    z = SLAB_TOP + 0.5
    me.from_pydata([(2, -2, z), (6, -2, z), (6, 2, z), (2, 2, z)], [], [(0, 1, 2, 3)])
    bpy.context.scene.collection.objects.link(bpy.data.objects.new("plate", me))
    res = bake.bake_objects(bpy.context, [slab], resolution=RES, seed=3, bake_pass="AO", ao_distance=1.0)
    assert "Slab" in res.maps and not res.skipped
    top = block(res.maps["Slab"], "Slab")[:, 4 * RES:5 * RES]      # face 4: +z
    full = top[..., 3] >= 1.0 - 1e-9
    split = (top[..., 3] > 0.05) & ~full
    ao = top[..., 0]
    print(f"\nAO on the top: {ao[full].mean():.4f} over {full.sum()} texels, split {ao[split]}")
    assert full.sum() > 200 and split.sum() >= RES
    # 256 stratified rays a texel: a texel's sd is 0.025 (measured), the mean's 0.0017;
    # seeds 2 to 5 gave means 0.2548, 0.2507, 0.2498 and 0.2497
    assert abs(ao[full].mean() - 0.25) < 0.005 and np.abs(ao[full] - 0.25).max() < 0.1
    assert np.abs(ao[split] - 0.25).max() < 0.1
    walls = [block(res.maps["Slab"], leaf) for leaf in res.maps["Slab"].tiles if leaf != "Slab"]
    seen = np.concatenate([w[..., 0][w[..., 3] > 0.5] for w in walls])
    assert seen.size and seen.mean() < 0.1


def test_texel_validity_finds_the_part_of_a_solid_inside_a_box():
    """The slotted slab (x from 3 to 5) with its left quarter inside a closed box (x < 3.5):
    the top's texels there see only the box's inside (back faces) and are invalid,
    the rest valid; the validity image shows it in the solid's atlas (R = 1 inside,
    G = 1 outside), and the report counts the solid's texels."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    slab, _ = slotted_slab()
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(2.75, 0.0, 1.0))
    box = bpy.context.active_object
    box.scale = (1.5, 4.0, 2.0)                    # x from 2 to 3.5
    point_light()
    res = bake.bake_objects(bpy.context, [slab], resolution=RES, seed=3, photons=20_000, texel_validity=True)
    counts = res.validity["Slab"]
    top = block(res.validity_maps["Slab"], "Slab")[:, 4 * RES:5 * RES]      # face 4: +z
    full = top[..., 3] >= 1.0 - 1e-9
    x = 3.0 + 2.0 * (np.arange(RES) + 0.5) / RES                            # texel centres along the top's u
    print(f"\n{counts}; top R by column: {np.round(top[..., 0].mean(axis=0), 2)}")
    cols_in, cols_out = x < 3.5 - 0.2, x > 3.5 + 0.2
    assert np.all(top[full & cols_in[None, :], 0] > 0.9) and np.all(top[full & cols_out[None, :], 0] < 0.1)
    assert np.all(top[full & cols_out[None, :], 1] > 0.9)
    assert counts["texels"] > 6 * RES * RES * 0.5 and counts["invalid"] >= (RES // 4) * RES
    # the invalid texels hold their valid neighbours' light, not the box's darkness
    light = block(res.maps["Slab"], "Slab")[:, 4 * RES:5 * RES, 0]
    first_valid = int(np.argmax(cols_out))
    assert np.all(light[:, :4][full[:, :4]] > 0.5 * light[:, first_valid].min())


def test_shadowmask_of_a_csg_solid_is_one_light_per_channel():
    """Four point lights, two above the slotted slab and two below it: its top sees
    the two above fully and cannot be lit by the two below, exactly (hard shadows,
    stratified samples): R = 1, G = 0, B = 0, A = 1, in the solid's atlas, with A
    the fourth light as on a mesh."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    slab, _ = slotted_slab()
    lamps = [point_light(location=loc) for loc in ((4.3, 0.2, 3.5), (4.0, 0.0, -1.0), (3.5, 0.5, -2.0),
                                                   (4.6, -0.3, 2.5))]
    for i, lamp in enumerate(lamps):
        lamp.name = f"Lamp{i}"
    res = bake.bake_objects(bpy.context, [slab], resolution=RES, seed=3, bake_pass="SHADOWMASK",
                            shadowmask_lights="Lamp0,Lamp1,Lamp2,Lamp3")
    assert "Slab" in res.maps and not res.skipped and res.mask_lights == ["Lamp0", "Lamp1", "Lamp2", "Lamp3"]
    top = block(res.maps["Slab"], "Slab")[:, 4 * RES:5 * RES]      # face 4: +z
    x = 3.0 + 2.0 * (np.arange(RES) + 0.5) / RES
    whole = np.abs(x - 4.03)[None, :].repeat(RES, axis=0) > 2.0 / RES      # columns clear of the slot
    assert np.all(top[whole] == np.array([1.0, 0.0, 0.0, 1.0], np.float32))


def test_directional_bake_of_a_csg_solid_points_at_the_light():
    """A point lamp above the slotted slab, nothing else: every full texel of its top
    is lit by that lamp alone, so its direction image (in the solid's atlas) holds
    the unit direction from the texel to the lamp (k = 1), and the hook reads it."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    slab, _ = slotted_slab()
    point_light()
    res = bake.bake_objects(bpy.context, [slab], resolution=RES, seed=3, photons=20_000, directional=True,
                            hook_materials=True)
    assert not [w for w in res.warnings if "directional" in w]
    u = block(res.direction_maps["Slab"], "Slab")[:, 4 * RES:5 * RES]      # face 4: +z
    full = u[..., 3] >= 1.0 - 1e-9
    M = np.array(slab.matrix_world)
    p4 = np.zeros(4)
    angles = []
    for y, x in zip(*np.nonzero(full)):
        c = np.array(primitives.prim_point(np.int32(primitives.BOX), p4, np.int64(4), (x + 0.5) / RES,
                                           (y + 0.5) / RES)[:3])
        d = np.array(LIGHT) - (M[:3, :3] @ c + M[:3, 3])
        d /= np.linalg.norm(d)
        angles.append(math.degrees(math.acos(min(1.0, float(u[y, x, :3] @ d / np.linalg.norm(u[y, x, :3]))))))
    angles = np.array(angles)
    print(f"\nangle to the lamp: mean {angles.mean():.2f}, max {angles.max():.2f} degrees; "
          f"|u| {np.linalg.norm(u[full][:, :3], axis=1).min():.4f}")
    assert full.sum() > 200 and angles.max() < 0.5             # measured: 0.07 degrees at most
    assert np.all(np.linalg.norm(u[full][:, :3], axis=1) > 0.99)  # measured: 0.999
    mats = {s.material.name for s in slab.material_slots}
    assert any(n.get("photon_lightmaps_hook") == "Direction Image" for m in mats
               for n in bpy.data.materials[m].node_tree.nodes)
