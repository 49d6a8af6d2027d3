"""An L-system object rendered by this engine against Cycles rendering its realized preview.

Scene (test_lsystem_bake.flake_scene): the sphereflake preset at depth 2 (91 spheres, three
materials by generation) resting on a grey ground plane, a sun, a black world; 64 x 48
pixels. This engine traces the grammar (analytic spheres through its scene graph, indirect
light from the object's automatic orientation lightmap); Cycles renders the preview the
Geometry Nodes group realizes, exact at this depth (the "symbols" Repeat-Zone path: one UV
sphere where the engine puts a sphere). The preview's UV spheres are raised to 96 x 48 here:
the viewport's 12 x 6 lose about 4.5 % of the silhouette (a 12-gon has 0.955 of its
circle's area) and shade in facets; a 96-gon has 0.9993.

Bounds (measured values in the printout; run with -s), Cycles with a 1-pixel box filter
(this engine averages each pixel over its square), CPU, 512 samples, no denoising, no
adaptive sampling (blender_session.render_exr):
* over the pixels the flake covers: mean within 4 % of Cycles, per channel (measured
  -3.4, -3.1 and -1.7 %);
* the whole image: mean within 2 % (measured -1.2 %);
* 4 x 4-pixel blocks holding light (above 5 % of the brightest): median relative error
  within 2 % (measured 1.1 %; the noise floor is about 1 %), and every block within
  7 % of the brightest block (measured 4.7 %).
The largest block errors are where direct light does not reach, in the crevices between a
lit sphere and its neighbours: Cycles has 0.1-0.2 there from the neighbours' light bounced
at close range, this engine reads the flake's one orientation lightmap (thesis ch. 6-7),
which averages indirect light by normal over the whole object, and shows about 0.04.
An albedo changed in the Cycles render only (render_pair's albedo_cycles: 0.8 -> 0.65 on
the largest sphere, slot 0) fails three bounds (measured when the preview's spheres were
12-sided: flake +9.6 to +12.5 %, image +4.4 %, a block 20 % of the brightest off).
"""
import math

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import demo_blend  # noqa: E402
from photon_lightmaps.bake import lsystem_plan  # noqa: E402
from photon_lightmaps.bake import lsystem_preview as PV  # noqa: E402
from photon_lightmaps.bake import render as render_engine  # noqa: E402
from photon_lightmaps.bake import orientation as ol_bake  # noqa: E402

from blender_session import empty_blender_file, addon, render_exr  # noqa: E402,F401  (addon: session-wide registration)
from test_lsystem_bake import flake_scene  # noqa: E402

ENGINE = "PHOTON_LIGHTMAPS"
W, H = 64, 48
CYCLES_SAMPLES = 512
SEGMENTS, RINGS = 96, 48


@pytest.fixture(autouse=True)
def empty_file(tmp_path_factory, monkeypatch):
    yield from empty_blender_file(tmp_path_factory, monkeypatch)


def block_means(img, n=4):
    h, w = img.shape[:2]
    return img[: h - h % n, : w - w % n].reshape(h // n, n, w // n, n, -1).mean(axis=(1, 3))


def coverage(scene, flake, path):
    """Pixels the flake covers: Cycles alpha with everything else hidden from the camera."""
    hidden = [o for o in scene.objects if o != flake and o.type == "MESH"]
    for o in hidden:
        o.visible_camera = False
    scene.render.film_transparent = True
    try:
        img = render_exr(scene, "CYCLES", path, cycles_samples=16)
    finally:
        scene.render.film_transparent = False
        for o in hidden:
            o.visible_camera = True
    return img[..., 3]


def render_pair(scene, tmp_path, albedo_cycles=None):
    """(ours, Cycles) RGB of the scene; albedo_cycles: base colour of material slot 0 in the
    Cycles render only (to check that the comparison can fail)."""
    ours = render_exr(scene, ENGINE, tmp_path / "ours.exr")[..., :3]
    if albedo_cycles is not None:
        flake = bpy.data.objects["flake"]
        bsdf = flake.material_slots[0].material.node_tree.nodes["Principled BSDF"]
        bsdf.inputs["Base Color"].default_value = (*albedo_cycles, 1.0)
    ref = render_exr(scene, "CYCLES", tmp_path / "cycles.exr", cycles_samples=CYCLES_SAMPLES)[..., :3]
    return ours, ref


def test_sphereflake_matches_cycles_on_its_realized_preview(tmp_path, monkeypatch):
    monkeypatch.setattr(lsystem_plan, "SEGMENTS", SEGMENTS)
    monkeypatch.setattr(lsystem_plan, "SPHERE_RINGS", RINGS)
    scene = bpy.context.scene
    # Object-linked slots: see test_preview_instances_show_the_objects_materials.
    flake = flake_scene(scene, link="OBJECT")
    demo_blend.add_camera(scene, (0.0, -8.0, 2.5), (math.radians(79.4), 0.0, 0.0))
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = W, H, 100
    scene.view_settings.view_transform = "Standard"
    # this engine averages each pixel over its square: Cycles' box filter of 1 pixel is the same
    scene.cycles.pixel_filter_type, scene.cycles.filter_width = "BOX", 1.0
    s = scene.photon_lightmaps
    s.photons, s.samples = 400_000, 16

    ours, ref = render_pair(scene, tmp_path)
    run = render_engine.LAST_RUN
    assert [row["name"] for row in run.orientation_lightmaps] == [f"{flake.name} (L-system)"]
    mask = coverage(scene, flake, tmp_path / "mask.exr") > 0.999
    assert 300 < mask.sum() < 0.6 * W * H, mask.sum()

    obj = ours[mask].mean(axis=0) / ref[mask].mean(axis=0)
    whole = ours.mean() / ref.mean()
    bo, br = block_means(ours).mean(axis=2), block_means(ref).mean(axis=2)
    lit = br > 0.05 * br.max()                  # blocks with something to compare
    rel = np.abs(bo - br)[lit] / br[lit]
    median_block, p90_block = float(np.median(rel)), float(np.percentile(rel, 90))
    max_block = float(np.abs(bo - br).max() / br.max())
    print(f"\nsphereflake vs Cycles: flake pixels ({mask.sum()}) ours/Cycles {np.round(obj, 4)}, "
          f"image {whole:.4f}; {lit.sum()} 4x4 blocks: median rel. error {median_block:.4f}, "
          f"90th percentile {p90_block:.4f}, max deviation {max_block:.4f} of the brightest; "
          f"ours {run.seconds['total']:.1f} s ({run.photons:,} photons)")
    assert np.all(np.abs(obj - 1.0) < 0.04), obj
    assert abs(whole - 1.0) < 0.02, whole
    assert median_block < 0.02, median_block
    assert max_block < 0.07, max_block


@pytest.mark.parametrize("link", ["OBJECT", "DATA"])
def test_preview_instances_show_the_objects_materials(link):
    """The symbols-path preview's instances render the slot material `;(g)` selects (one
    sphere of generation 0, 9 of 1, 81 of 2), with the slots linked to the object (by
    index) or to the mesh (the shapes carry the material), and a changed slot material
    reaches the preview through the timer's check."""
    from collections import Counter
    flake = flake_scene(bpy.context.scene, link=link)

    def rendered():
        dg = bpy.context.evaluated_depsgraph_get()
        c = Counter()
        for inst in dg.object_instances:
            if inst.is_instance and inst.parent is not None and inst.parent.original == flake:
                slots = [sl.material for sl in inst.object.material_slots]
                for i in {p.material_index for p in inst.object.data.polygons}:
                    m = slots[min(i, len(slots) - 1)] if slots else None
                    c[m.name if m else None] += 1
        return c

    assert rendered() == {"flake_0": 1, "flake_1": 9, "flake_2": 81}
    other = demo_blend.principled("other", (0.2, 0.2, 0.9))
    if link == "OBJECT":
        flake.material_slots[1].material = other
    else:
        flake.data.materials[1] = other
    PV.check_texts()
    assert rendered() == {"flake_0": 1, "other": 9, "flake_2": 81}
