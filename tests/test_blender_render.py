"""The Photon Lightmaps render engine inside Blender, measured against Cycles.

Agreement bounds (stated here, measured values in the test messages; run with
-s to print them):
* one light over a white Lambertian floor (direct light only): image mean
  within 0.5 % of Cycles, and every 4x4-block mean within 1.5 % of the brightest
  block (measured over the ten light kinds: mean <= 0.14 %, blocks <= 0.64 %);
* the Cornell room (direct + photon-lightmap indirect): mean of each colour
  channel within 1 % of Cycles, 4x4 blocks within 2 % (measured <= 0.31 % / 0.69 %).
Cycles runs on the CPU, 128 samples, no denoising, no adaptive sampling, light
threshold 0, view transform Standard; images are compared as linear EXR.
"""
import json
import os
import pathlib
import struct
import subprocess
import sys
import time
import types

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

import photon_lightmaps  # noqa: E402
from photon_lightmaps import cli as headless  # noqa: E402
from photon_lightmaps import demo_blend, registration  # noqa: E402
from photon_lightmaps.bake import render as render_engine  # noqa: E402
from photon_lightmaps.ui import compat_panels  # noqa: E402

ENGINE = "PHOTON_LIGHTMAPS"
REPO = pathlib.Path(__file__).resolve().parents[1]


from blender_session import addon, read_image, render_exr  # noqa: E402,F401  (addon: session-wide registration)


@pytest.fixture(autouse=True)
def empty_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield


def block_means(img, n=4):
    h, w = img.shape[:2]
    return img[: h - h % n, : w - w % n, :3].reshape(n, h // n, n, w // n, 3).mean(axis=(1, 3, 4))


LIGHT_CASES = ["POINT", "POINT_SPHERE", "POINT_UNNORMALIZED", "POINT_HARD", "SPOT", "SUN", "AREA_SQUARE", "AREA_RECTANGLE", "AREA_DISK",
               "AREA_ELLIPSE"]


@pytest.mark.parametrize("case", LIGHT_CASES)
def test_light_agrees_with_cycles(case, tmp_path):
    scene = demo_blend.build_light_test_blend(case, width=32, height=32, photons=20_000, samples=64)
    ours = render_exr(scene, ENGINE, tmp_path / "ours.exr")
    run = render_engine.LAST_RUN
    t0 = time.perf_counter()
    ref = render_exr(scene, "CYCLES", tmp_path / "cycles.exr")
    t_cycles = time.perf_counter() - t0
    assert ref[..., :3].mean() > 0.01, "the test scene must be lit"
    np.testing.assert_allclose(ours[..., 3], 1.0)
    ratio = ours[..., :3].mean() / ref[..., :3].mean()
    bo, br = block_means(ours), block_means(ref)
    block_dev = float(np.abs(bo - br).max() / br.max())
    print(f"\n{case}: mean ours/Cycles = {ratio:.4f}, max block deviation {block_dev:.4f}, "
          f"ours {run.seconds['total']:.2f} s, Cycles {t_cycles:.2f} s")
    assert abs(ratio - 1.0) < 0.005, f"{case}: mean ratio {ratio:.4f}"
    assert block_dev < 0.015, f"{case}: block deviation {block_dev:.4f}"


def test_cornell_agrees_with_cycles(tmp_path):
    scene = demo_blend.build_cornell_blend(width=48, height=48, photons=300_000, samples=32)
    ours = render_exr(scene, ENGINE, tmp_path / "ours.exr")
    run = render_engine.LAST_RUN
    t0 = time.perf_counter()
    ref = render_exr(scene, "CYCLES", tmp_path / "cycles.exr")
    t_cycles = time.perf_counter() - t0
    per_channel = ours[..., :3].mean(axis=(0, 1)) / ref[..., :3].mean(axis=(0, 1))
    bo, br = block_means(ours), block_means(ref)
    block_dev = float(np.abs(bo - br).max() / br.max())
    print(f"\nCornell: ours/Cycles per channel {np.round(per_channel, 4)}, max block deviation "
          f"{block_dev:.4f}; ours {run.seconds['total']:.2f} s ({run.photons:,} photons, "
          f"{run.seconds['photon_pass']:.2f} s photon pass); Cycles {t_cycles:.2f} s")
    assert run.photons == 300_000 and run.lightmaps == 6
    assert np.all(np.abs(per_channel - 1.0) < 0.01), per_channel
    assert block_dev < 0.02, block_dev


def test_tiles_and_outputs_carry_the_image_exactly(tmp_path):
    """Odd size over several tiles: the EXR Blender writes equals the engine's image (no flips,
    no offsets), and the PNG is that image through the Standard view transform."""
    scene = demo_blend.build_cornell_blend(width=150, height=70, photons=20_000, samples=2)
    scene.render.dither_intensity = 0.0
    exr = render_exr(scene, ENGINE, tmp_path / "tiles.exr")
    run = render_engine.LAST_RUN
    assert run.image.shape == (70, 150, 3) and render_engine.TILE < 70  # 3 x 2 tiles, partial ones too
    np.testing.assert_allclose(exr[..., :3], run.image.astype(np.float32), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(exr[..., 3], 1.0)
    # Red wall on the left, green on the right (the image is not mirrored).
    left, right = exr[35, 10, :3], exr[35, 140, :3]
    assert left[0] > left[1] and right[1] > right[0]

    png_path = tmp_path / "tiles.png"
    run = headless.render_to_file(scene, png_path)
    png = read_image(png_path)[..., :3]
    lin = np.clip(run.image, 0.0, 1.0)
    srgb = np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)
    assert np.abs(png - srgb).max() <= 1.0 / 255 + 1e-6


@pytest.mark.parametrize("crop", [False, True])
def test_render_region(crop, tmp_path):
    """A render region (border) receives exactly its part of the frame."""
    scene = demo_blend.build_cornell_blend(width=100, height=80, photons=10_000, samples=1)
    r = scene.render
    r.use_border, r.use_crop_to_border = True, crop
    r.border_min_x, r.border_max_x, r.border_min_y, r.border_max_y = 0.236, 0.7, 0.1, 0.65
    img = render_exr(scene, ENGINE, tmp_path / "region.exr")
    full = render_engine.LAST_RUN.image
    x0, x1, y0, y1 = 23, 70, 8, 52  # Blender truncates border * size; y counted from the bottom
    region = full[80 - y1:80 - y0, x0:x1]
    if crop:
        assert img.shape[:2] == (44, 47)
        got = img
    else:
        assert img.shape[:2] == (80, 100)
        got = img[80 - y1:80 - y0, x0:x1]
        outside = np.ones((80, 100), bool)
        outside[80 - y1:80 - y0, x0:x1] = False
        assert np.all(img[outside][:, 3] == 0.0)
    np.testing.assert_allclose(got[..., :3], region.astype(np.float32), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(got[..., 3], 1.0)


def test_scene_without_lights_or_geometry_renders_black(tmp_path):
    scene = demo_blend.build_light_test_blend("AREA")
    bpy.data.objects.remove(bpy.data.objects["light"])
    img = render_exr(scene, ENGINE, tmp_path / "dark.exr")
    assert np.all(img[..., :3] == 0.0)
    assert any("no lights" in w for w in render_engine.LAST_RUN.warnings)
    bpy.data.objects.remove(bpy.data.objects["floor"])
    demo_blend.add_light(scene, "POINT")
    img = render_exr(scene, ENGINE, tmp_path / "empty.exr")
    assert np.all(img[..., :3] == 0.0)
    assert any("no renderable geometry" in w for w in render_engine.LAST_RUN.warnings)


def test_cancel_stops_cleanly():
    demo_blend.build_cornell_blend(width=130, height=130, photons=50_000, samples=1)
    dg = bpy.context.evaluated_depsgraph_get()
    tiles = []
    run = render_engine.run_render(dg, on_tile=lambda x, y, t: tiles.append((x, y)),
                                   should_stop=lambda: len(tiles) >= 2)
    assert run.cancelled and run.image is None and len(tiles) == 2
    # The first run's photon pass had finished: it is kept for the next frame. Let it
    # go (as the end of a render job does), so this run's photon pass is cancelled.
    render_engine.LIGHT.clear()
    progress = []
    run = render_engine.run_render(dg, progress=progress.append, should_stop=lambda: len(progress) >= 1)
    assert run.cancelled and run.image is None and max(progress) <= 0.5


def test_render_refines_progressively_and_ends_on_the_full_image():
    """F12 shows the whole frame after 1 sample, then 2, 4, ... (each pass's tiles
    replace the last ones); the last tiles are the finished image."""
    demo_blend.build_cornell_blend(width=70, height=40, photons=20_000, samples=4)
    dg = bpy.context.evaluated_depsgraph_get()
    tiles, texts = [], []
    run = render_engine.run_render(dg, on_tile=lambda x, y, t: tiles.append((x, y, t.copy())),
                                   stats=texts.append)
    assert not run.cancelled
    assert len(tiles) == 3 * 2                       # passes of 1, 1, 2 samples over 2 tiles
    assert [(x, y) for x, y, _ in tiles] == [(0, 0), (64, 0)] * 3
    last = np.concatenate([tiles[-2][2], tiles[-1][2]], axis=1)
    np.testing.assert_array_equal(last, run.image)
    assert not np.array_equal(tiles[0][2], tiles[-2][2])      # 1 sample, then 4
    assert any(t.startswith("Pass 3/3, 4/4 samples") for t in texts)


def test_registration_round_trip():
    fmt = bpy.types.RENDER_PT_format
    assert ENGINE in fmt.COMPAT_ENGINES and registration.engine_registered()
    assert ENGINE not in bpy.types.DATA_PT_preview.COMPAT_ENGINES  # excluded: no previews
    assert "CYCLES_RENDER_PT_sampling" not in {p.__name__ for p in compat_panels.get_panels()}
    registration.unregister()
    try:
        assert not registration.engine_registered()
        assert ENGINE not in fmt.COMPAT_ENGINES
        assert not hasattr(bpy.types.Scene, "photon_lightmaps")
    finally:
        registration.register()
    assert registration.engine_registered() and ENGINE in fmt.COMPAT_ENGINES
    assert bpy.context.scene.photon_lightmaps.photons == 1_000_000


def test_scene_properties_default_to_the_engine_settings():
    """Every engine setting is a scene property with the engine's default, so a
    new .blend, the CLI and a script without Blender bake and render alike."""
    import dataclasses
    from photon_lightmaps.engine.session import Settings
    props = bpy.types.Scene.bl_rna.properties["photon_lightmaps"].fixed_type.bl_rna.properties
    for f in dataclasses.fields(Settings):
        assert f.name in props, f"Scene.photon_lightmaps has no '{f.name}'"
        prop = props[f.name]
        default = prop.default
        if prop.type == "FLOAT":
            assert default == pytest.approx(f.default, rel=1e-6), f.name
        else:
            assert default == f.default, f.name


def _png_size(path):
    data = pathlib.Path(path).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])


def test_headless_command_line(tmp_path):
    blend = tmp_path / "room.blend"
    demo_blend.build_cornell_blend(blend, width=48, height=32, photons=10_000, samples=2)
    png, report = tmp_path / "out" / "room.png", tmp_path / "out" / "room.json"
    env = dict(os.environ, NUMBA_CACHE_DIR=os.environ.get("NUMBA_CACHE_DIR", str(REPO / ".numba_cache")))
    cmd = [sys.executable, "-m", "photon_lightmaps", "render", str(blend), "--out", str(png),
           "--json", str(report), "--photons", "30000", "--samples", "3", "--seed", "5"]
    proc = subprocess.run(cmd, env=env, cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert _png_size(png) == (48, 32)
    r = json.loads(report.read_text())
    assert r["photons"] == 30000 and r["rays"] >= 30000
    for key in ("photon_pass", "render", "total"):
        assert r["seconds"][key] > 0.0
    assert r["seconds"]["total"] >= r["seconds"]["photon_pass"] + r["seconds"]["render"]
    assert r["memory"]["lightmap_bytes"] > 0 and r["memory"]["peak_rss_bytes"] > 10 * 2 ** 20
    assert r["image"] == str(png)
    assert r["settings"]["samples"] == 3 and r["settings"]["seed"] == 5

    bad = subprocess.run([sys.executable, "-m", "photon_lightmaps", "render", str(tmp_path / "missing.blend"),
                          "--out", str(png)], env=env, cwd=tmp_path, capture_output=True, text=True,
                         timeout=120)
    assert bad.returncode == 2 and "no such" in bad.stderr


class _RecordingLayout:
    """Stands in for UILayout: checks every drawn property exists on its data block."""

    def __init__(self):
        self.drawn = []

    def _prop(self, data, name, **_kw):
        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property '{name}'"
        self.drawn.append(name)

    def __getattr__(self, name):
        if name == "prop":
            return self._prop
        if name in ("row", "column", "split", "box", "grid_flow", "column_flow"):
            return lambda *a, **k: self
        return lambda *a, **k: None


def test_panels_draw_existing_properties():
    from photon_lightmaps.ui import panels
    scene = demo_blend.build_light_test_blend("SPOT")
    ob = bpy.data.objects["floor"]
    ctx = types.SimpleNamespace(engine=ENGINE, scene=scene, object=ob, material=ob.active_material,
                                world=scene.world, light=None, space_data=None, camera=scene.camera.data)
    ob.active_material.photon_lightmaps.conductor = "AU"          # draws the preset's index too
    drawn = {}
    for light_type in ("POINT", "SPOT", "SUN", "AREA"):
        ctx.light = bpy.data.lights.new(f"l_{light_type}", light_type)
        for cls in panels.classes:
            if cls is panels.PHOTON_LIGHTMAPS_PT_lsystem:
                # shown on L-system objects only (drawn in tests/test_lsystem_blender.py)
                assert not cls.poll(ctx)
                continue
            assert cls.poll(ctx), cls.__name__
            fake = types.SimpleNamespace(layout=_RecordingLayout(), bl_space_type="PROPERTIES")
            cls.draw(fake, ctx)
            drawn.setdefault(cls.__name__, set()).update(fake.layout.drawn)
    assert {"photons", "max_bounces", "texel_density", "reconstruction", "samples", "seed", "cluster"} <= \
        drawn["PHOTON_LIGHTMAPS_PT_render"]
    assert {"exclude", "lightmap_resolution"} <= drawn["PHOTON_LIGHTMAPS_PT_object"]
    assert {"spot_size", "spot_blend", "angle", "shape", "shadow_soft_size", "energy"} <= \
        drawn["PHOTON_LIGHTMAPS_PT_light"]
    assert {"dispersion"} <= drawn["PHOTON_LIGHTMAPS_PT_material_dispersion"]
    assert {"fluorescence"} <= drawn["PHOTON_LIGHTMAPS_PT_material_fluorescence"]
    assert {"conductor"} <= drawn["PHOTON_LIGHTMAPS_PT_material_conductor"]
    assert {"polarizer_angle"} <= drawn["PHOTON_LIGHTMAPS_PT_light_polarizer"]
    assert {"polarizer_angle"} <= drawn["PHOTON_LIGHTMAPS_PT_camera_polarizer"]
    ctx.engine = "CYCLES"
    assert not any(cls.poll(ctx) for cls in panels.classes)
