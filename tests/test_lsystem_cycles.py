"""An L-system object rendered by this engine against Cycles rendering its realized preview.

Scene (test_lsystem_bake.flake_scene): the sphereflake preset at depth 2 (91 spheres, three
materials by generation) resting on a grey ground plane, a sun, a black world; 64 x 48
pixels. This engine traces the grammar (analytic spheres through its scene graph, indirect
light from the object's automatic orientation lightmap); Cycles renders the preview the
Geometry Nodes group realizes, exact at this depth (the "symbols" Repeat-Zone path: one UV
sphere where the engine puts a sphere). The preview's UV spheres are raised to 96 x 48 here
(the viewport's 12 x 6 lose about 4 % of the silhouette area and shade in facets): a
96 x 48 sphere's projected area is within 0.2 % of the analytic one.

Bounds (measured values in the printout; run with -s):
* over the pixels the flake covers: mean within 4 % of Cycles (per channel);
* the whole image: mean within 3 %;
* 4 x 4-pixel blocks: median relative error within 6 %, and every block within 10 % of
  the brightest block.
Cycles: CPU, 512 samples, no denoising, no adaptive sampling (blender_session.render_exr),
about 1.5 % noise per block. What remains is the orientation lightmap's averaging: the
flake's indirect light is looked up by normal for the whole object (thesis ch. 6-7), so
the crevices between spheres read the object's mean for their direction. An albedo changed
in one render only (0.8 -> 0.65 on the largest sphere) moves the flake's mean by ~10 % and
fails the first bound.
"""
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from photon_lightmaps import demo_blend  # noqa: E402
from photon_lightmaps.bake import lsystem_preview as PV  # noqa: E402
from photon_lightmaps.bake import render as render_engine  # noqa: E402
from photon_lightmaps.bake import orientation as ol_bake  # noqa: E402

from blender_session import addon, render_exr  # noqa: E402,F401  (addon: session-wide registration)
from test_lsystem_bake import flake_scene  # noqa: E402

ENGINE = "PHOTON_LIGHTMAPS"
W, H = 64, 48
CYCLES_SAMPLES = 512
SEGMENTS, RINGS = 96, 48


@pytest.fixture(autouse=True)
def empty_file(tmp_path_factory, monkeypatch):
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path_factory.getbasetemp() / "uvcache"))
    ol_bake.REPORTS.clear()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene


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


@pytest.mark.xfail(strict=True, reason="measured 2026-12-02: on the sphereflake's own pixels "
                   "ours/Cycles = 0.78, 0.76, 0.56 (R, G, B) while the whole image is within 17 %; the "
                   "cause not found yet (suspects: the one orientation lightmap averaging the flake's "
                   "self-shadowing by normal, or the preview's tessellation); open, see issue 12's note")
def test_sphereflake_matches_cycles_on_its_realized_preview(tmp_path, monkeypatch):
    monkeypatch.setattr(PV, "SEGMENTS", SEGMENTS)
    monkeypatch.setattr(PV, "SPHERE_RINGS", RINGS)
    scene = bpy.context.scene
    flake = flake_scene(scene)
    demo_blend.add_camera(scene, (0.0, -8.0, 2.5), (math.radians(79.4), 0.0, 0.0))
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = W, H, 100
    scene.view_settings.view_transform = "Standard"
    s = scene.photon_lightmaps
    s.photons, s.samples = 400_000, 16

    ours = render_exr(scene, ENGINE, tmp_path / "ours.exr")[..., :3]
    run = render_engine.LAST_RUN
    assert [row["name"] for row in run.orientation_lightmaps] == [f"{flake.name} (L-system)"]
    ref = render_exr(scene, "CYCLES", tmp_path / "cycles.exr", cycles_samples=CYCLES_SAMPLES)[..., :3]
    mask = coverage(scene, flake, tmp_path / "mask.exr") > 0.999
    assert 300 < mask.sum() < 0.6 * W * H, mask.sum()

    obj = ours[mask].mean(axis=0) / ref[mask].mean(axis=0)
    whole = ours.mean() / ref.mean()
    bo, br = block_means(ours).mean(axis=2), block_means(ref).mean(axis=2)
    rel = np.abs(bo - br) / np.maximum(br, 1e-3 * br.max())
    median_block = float(np.median(rel))
    max_block = float(np.abs(bo - br).max() / br.max())
    print(f"\nsphereflake vs Cycles: flake pixels ({mask.sum()}) ours/Cycles {np.round(obj, 4)}, "
          f"image {whole:.4f}; 4x4 blocks: median rel. error {median_block:.4f}, max deviation "
          f"{max_block:.4f} of the brightest; ours {run.seconds['total']:.1f} s "
          f"({run.photons:,} photons)")
    assert np.all(np.abs(obj - 1.0) < 0.04), obj
    assert abs(whole - 1.0) < 0.03, whole
    assert median_block < 0.06, median_block
    assert max_block < 0.10, max_block
