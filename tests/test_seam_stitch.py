"""Seam stitching (engine/transport/seam_stitch.py): which edges are seams, how far the
two sides' bilinear reads disagree along them before and after, and what EEVEE shows
there, against the plain bake of the same photon pass."""
import json

import numpy as np

import bpy  # noqa: F401  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake
from photon_lightmaps.engine import demo_scenes, session
from photon_lightmaps.engine.core.scene import Light, Material, Scene, translate
from photon_lightmaps.engine.transport import seam_stitch

from blender_session import addon  # noqa: F401  (session-wide registration)


def _seams_of(scene):
    cs = session.compile(scene)
    charts = seam_stitch.mesh_charts(cs, [ids[0] for ids in cs.instance_lightmaps])
    lm = cs.lightmaps
    shapes = {k: (int(lm.height[lid]), int(lm.width[lid])) for k, (lid, *_) in enumerate(charts)}
    return charts, seam_stitch.find_seams(charts, shapes)


def test_seams_are_shared_smooth_edges_and_creases_are_not():
    """Two quads sharing an edge: one seam (each quad's diagonal lies inside its chart).
    A wall standing on that edge meets both at 90 degrees: no seam with it."""
    s = Scene(n_bands=3, name="halves")
    m = s.add_material(Material("white", diffuse=np.full(3, 0.5)))
    q = demo_scenes.quad_mesh
    s.add_object(q((-1, -1, 0), (0, -1, 0), (0, 1, 0), (-1, 1, 0), material=m, name="a"), name="a")
    s.add_object(q((0, -1, 0), (1, -1, 0), (1, 1, 0), (0, 1, 0), material=m, name="b"), name="b")
    s.lights.append(Light("point", power=10.0, transform=translate(0, 0, 1), name="lamp"))
    charts, seams = _seams_of(s)
    assert seams.edges == 1
    assert set(seams.ia.tolist()) | set(seams.ib.tolist()) == {0, 1}
    s.add_object(q((0, -1, 0), (0, 1, 0), (0, 1, 1), (0, -1, 1), material=m, name="wall"), name="wall")
    assert _seams_of(s)[1].edges == 1


def test_a_sphere_has_seams_where_its_charts_meet():
    """A UV sphere unwrapped by xatlas: its charts meet along smooth edges, each a seam
    drawn by two faces less than SMOOTH_DEGREES apart; the reads sample every one."""
    s = Scene(n_bands=3, name="ball")
    m = s.add_material(Material("white", diffuse=np.full(3, 0.5)))
    s.add_object(demo_scenes.uv_sphere_mesh(0.5, n_theta=12, n_phi=24, material=m), name="ball")
    s.lights.append(Light("point", power=10.0, transform=translate(0, 0, 2), name="lamp"))
    charts, seams = _seams_of(s)
    assert seams.edges > 0 and np.all(seams.ia == 0) and np.all(seams.ib == 0)
    assert np.allclose(seams.wa.sum(axis=1), 1.0) and np.allclose(seams.wb.sum(axis=1), 1.0)
    assert seams.ia.size >= 2 * seams.edges


def halves_and_ball():
    """Two 1 x 2 m halves of a floor meeting along x = 0, a smooth UV sphere on the left
    half and a lamp close above the right one: light that changes across the seam."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    for name, x0, x1 in (("left_half", -1.0, 0.0), ("right_half", 0.0, 1.0)):
        me = bpy.data.meshes.new(name)
        me.from_pydata([(x0, -1, 0), (x1, -1, 0), (x1, 1, 0), (x0, 1, 0)], [], [(0, 1, 2, 3)])
        scene.collection.objects.link(bpy.data.objects.new(name, me))
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=0.3, location=(-0.4, 0.4, 0.3))
    bpy.context.active_object.name = "ball"
    bpy.ops.object.shade_smooth()
    data = bpy.data.lights.new("lamp", "POINT")
    data.energy = 100.0
    lamp = bpy.data.objects.new("lamp", data)
    lamp.location = (0.3, -0.2, 1.2)
    scene.collection.objects.link(lamp)
    return scene, [bpy.data.objects[n] for n in ("left_half", "right_half", "ball")]


def test_stitching_closes_the_seams_and_keeps_the_surface():
    """Across the halves' shared edge and the sphere's UV seams, the two sides' bilinear
    reads differ by 6.9 % of the light on average in the plain bake, and by 0.13 %
    stitched: far below the plain bake, and below the texels' own estimated error (0.3
    to 33 %). Covered texels move by 0.15 % on average: the gutters take up the change."""
    _, objs = halves_and_ball()
    plain = bake.bake_objects(bpy.context, objs, seed=1, resolution=32)
    stitched = bake.bake_objects(bpy.context, objs, seed=1, resolution=32, stitch_seams=True, overwrite=True,
                                 directional=True)
    assert stitched.light_reuse["reused"] == "memory"          # the same light, stitched
    rep = stitched.seams
    print(f"\n{rep}")
    assert rep["edges"] > 1 and rep["samples"] >= 2 * rep["edges"]
    assert rep["jump_after"] < rep["jump_before"] / 10 and rep["jump_after"] < 0.005
    noise = np.mean([e["rel_error_mean"] for e in stitched.error.values()])
    assert rep["jump_after"] < noise
    # the direction images are stitched along the same seams
    assert rep["direction_jump_after"] < rep["direction_jump_before"] / 10
    moved = []
    for name, bm in plain.maps.items():
        a, b = bm.rgba, stitched.maps[name].rgba
        covered = a[..., 3] >= 1.0 - 1e-6
        moved.append(np.abs(b[..., :3] - a[..., :3])[covered].mean() / a[..., :3][covered].mean())
        assert np.array_equal(a[..., 3], b[..., 3])
    assert max(moved) < 0.01, moved
    assert 0 < rep["texels_changed"] < sum(bm.rgba[..., 0].size for bm in plain.maps.values()) / 4


def _eevee_row_steps(images):
    """EEVEE (Linear image filter) renders the halves from above, lit by the maps alone
    (emission = the lightmap's value): the mean step between the two pixel columns
    beside the seam, over the typical step between neighbouring columns nearby."""
    scene = bpy.context.scene
    scene.render.engine = "BLENDER_EEVEE"
    scene.render.resolution_x = scene.render.resolution_y = 128
    scene.render.filter_size = 0.0
    scene.eevee.taa_render_samples = 1
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.world = bpy.data.worlds.new("black")
    scene.world.color = (0, 0, 0)
    cam = bpy.data.objects.new("top", bpy.data.cameras.new("top"))
    cam.data.type, cam.data.ortho_scale = "ORTHO", 2.0
    cam.location = (0, 0, 3)
    scene.collection.objects.link(cam)
    scene.camera = cam
    for name in ("left_half", "right_half"):
        ob = bpy.data.objects[name]
        mat = bpy.data.materials.new(name + "_lit")
        mat.use_nodes = True
        nt = mat.node_tree
        nt.nodes.clear()
        uv = nt.nodes.new("ShaderNodeUVMap")
        uv.uv_map = "Lightmap"
        tex = nt.nodes.new("ShaderNodeTexImage")
        tex.image, tex.interpolation, tex.extension = images[name], "Linear", "EXTEND"
        emit = nt.nodes.new("ShaderNodeEmission")
        out = nt.nodes.new("ShaderNodeOutputMaterial")
        nt.links.new(uv.outputs["UV"], tex.inputs["Vector"])
        nt.links.new(tex.outputs["Color"], emit.inputs["Color"])
        nt.links.new(emit.outputs["Emission"], out.inputs["Surface"])
        ob.data.materials.clear()
        ob.data.materials.append(mat)
    path = bpy.app.tempdir + "seam.exr"
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(path)
    px = np.array(img.pixels[:], np.float64).reshape(128, 128, 4)[..., :3].mean(axis=2)
    bpy.data.images.remove(img)
    rows = px[16:112]                                  # away from the halves' far edges
    steps = np.abs(np.diff(rows, axis=1)).mean(axis=0)  # step between columns k and k+1
    near = [k for k in range(44, 84) if k != 63]
    return float(steps[63] / np.median(steps[near])), float(rows.mean())


def test_eevee_shows_no_line_along_a_stitched_seam():
    """EEVEE over the halves, lit by their maps alone: with the plain maps the step
    across the seam is 7.5 times the steps beside it (a line); stitched, 0.53 times."""
    _, objs = halves_and_ball()
    halves = objs[:2]
    images, reports = {}, {}
    for stitch in (False, True):
        res = bake.bake_objects(bpy.context, halves, seed=1, resolution=16, photons=100_000,
                                stitch_seams=stitch, overwrite=True)
        reports[stitch] = res.seams
        for name, bm in res.maps.items():
            img = bpy.data.images.new(f"{name}_{stitch}", bm.width, bm.height, alpha=True, float_buffer=True)
            img.alpha_mode = "CHANNEL_PACKED"     # as the bake's own images: A is coverage, not opacity
            img.pixels.foreach_set(bm.rgba.ravel())
            images[name, stitch] = img
    ratios = {stitch: _eevee_row_steps({n: images[n, stitch] for n in ("left_half", "right_half")})
              for stitch in (False, True)}
    print(f"\n{ratios} {reports[True]}")
    assert ratios[False][0] > 2.0 and ratios[True][0] < 1.5


def test_cli_stitch_seams_reports_the_jump(tmp_path):
    """bake --stitch-seams: the JSON's seams (edges, the jump before and after, time)."""
    from test_cli_commands import run
    halves_and_ball()
    blend = tmp_path / "halves.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    run("bake", blend, "--out", tmp_path / "maps", "--resolution", "16", "--photons", "50000",
        "--stitch-seams", "--json", tmp_path / "r.json")
    rep = json.loads((tmp_path / "r.json").read_text())
    seams = rep["seams"]
    assert seams["edges"] > 1 and seams["jump_after"] < seams["jump_before"] / 5
    assert rep["seconds"]["seams"] > 0


def test_primitives_are_stitched_where_their_charts_meet_themselves():
    """A sphere primitive (one octahedral chart, folded along its border) and a cylinder
    primitive (its side wrapping around; its caps meet the side at a crease) under a
    lamp: their seams are found from the charts themselves, and stitching closes them."""
    from photon_lightmaps.operators import csg_primitives
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ball = csg_primitives.new_primitive_object("sphere", "ball", location=(-0.8, 0.0, 0.6), segments=32)
    post = csg_primitives.new_primitive_object("cylinder", "post", location=(0.8, 0.0, 0.6), segments=32)
    data = bpy.data.lights.new("lamp", "POINT")
    data.energy = 300.0
    lamp = bpy.data.objects.new("lamp", data)
    lamp.location = (0.3, -1.5, 1.8)
    bpy.context.scene.collection.objects.link(lamp)
    res = bake.bake_objects(bpy.context, [ball, post], seed=1, resolution=16, stitch_seams=True)
    rep = res.seams
    print(f"\n{rep}")
    # the sphere's fold: 4 border sides of 16 cells, each folded onto itself (32 pairs);
    # the cylinder's wrap: 16 cells. Measured: the jump falls from 1.52 to 0.025.
    assert rep["edges"] == 32 + 16
    assert rep["jump_after"] < rep["jump_before"] / 40
