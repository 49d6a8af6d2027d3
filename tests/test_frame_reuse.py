"""Camera animations reuse the first frame's photon pass (engine/light_reuse.py).

* The light key sees everything but the camera: moving the camera keeps it,
  moving an object or a light, changing a material or the photon count does not.
* A camera fly-through renders every frame as a single-frame render of that
  frame does (same seed: the same photons), bit for bit, and frames after the
  first report whose light they reused.
* A frame where a light moved traces its own photons.
* The kept light is let go when the render job ends, unless Persistent Data is on.
"""
from dataclasses import replace

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes, light_reuse, session


def small_scene():
    return demo_scenes.cornell_box(width=16, height=16, with_primitives=False)


def shifted(m, by=(0.0, 0.0, 0.01)):
    m = np.array(m, np.float64)
    m[:3, 3] += by
    return m


def test_light_key_ignores_the_camera_and_render_settings_only():
    st = session.Settings(photons=1000, seed=1)
    s = small_scene()
    key = light_reuse.light_key(s, st)
    assert light_reuse.light_key(small_scene(), st) == key          # deterministic over rebuilds
    moved_cam = replace(s, camera=replace(s.camera, transform=shifted(s.camera.transform), width=24))
    assert light_reuse.light_key(moved_cam, st) == key
    assert light_reuse.light_key(s, replace(st, samples=64, denoise=True)) == key
    assert light_reuse.light_key(s, replace(st, photons=2000)) != key
    assert light_reuse.light_key(s, replace(st, seed=2)) != key
    assert light_reuse.light_key(s, replace(st, indirect="LOOKUP")) != key

    s2 = small_scene()
    s2.instances[0] = replace(s2.instances[0], transform=shifted(s2.instances[0].transform))
    assert light_reuse.light_key(s2, st) != key
    s3 = small_scene()
    s3.lights[0] = replace(s3.lights[0], power=s3.lights[0].power * 1.01)
    assert light_reuse.light_key(s3, st) != key
    s4 = small_scene()
    s4.materials[0] = replace(s4.materials[0], diffuse=np.asarray(s4.materials[0].diffuse) * 0.99)
    assert light_reuse.light_key(s4, st) != key


def test_light_cache_holds_and_lets_go():
    c = light_reuse.LightCache()
    c.put("k", "cs", 1, {})
    assert c.get("k") == "cs"
    c.end_of_job()
    assert c.get("k") is None                     # a finished job lets go
    c.put("k", "cs", 1, {})
    c.end_of_job(keep=True)                       # Persistent Data
    assert c.get("k") == "cs"
    assert c.get("other") is None and c.cs is None   # a mismatch lets go at once
    with c.held():
        c.put("k", "cs", 1, {})
        c.end_of_job()                            # each still render of a held frame loop
        assert c.get("k") == "cs"
    assert c.cs is None                           # the loop's end lets go


def test_with_camera_shares_the_light():
    cs = session.compile(small_scene())
    cam = replace(small_scene().camera, width=8, height=6)
    other = light_reuse.with_camera(cs, cam)
    assert other.lightmaps is cs.lightmaps and other.geometry is cs.geometry
    assert (other.camera.width, other.camera.height) == (8, 6)
    assert (cs.camera.width, cs.camera.height) == (16, 16)


# ---- in Blender -----------------------------------------------------------------------

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from blender_session import addon, read_image  # noqa: E402,F401

from photon_lightmaps import cli as headless  # noqa: E402
from photon_lightmaps import demo_blend  # noqa: E402
from photon_lightmaps.bake import render as render_engine  # noqa: E402


@pytest.fixture
def cornell():
    scene = demo_blend.build_cornell_blend(width=24, height=24)
    scene.photon_lightmaps.photons = 40_000
    scene.photon_lightmaps.samples = 2
    scene.photon_lightmaps.seed = 3
    render_engine.LIGHT.clear()
    yield scene
    render_engine.LIGHT.clear()


def keyframe(ob, frame, location):
    ob.location = location
    ob.keyframe_insert("location", frame=frame)


def test_camera_flythrough_reuses_the_light_and_matches_single_frames(cornell, tmp_path):
    cam = cornell.camera
    x, y, z = cam.location
    keyframe(cam, 1, (x, y, z))
    keyframe(cam, 3, (x + 0.3, y + 0.4, z - 0.2))
    report = headless._render_frames(cornell, tmp_path / "f_#.exr", (1, 3))
    assert [r["light_from_frame"] for r in report["frames"]] == [None, 1, 1]
    assert report["frames_reusing_light"] == 2
    assert [r["photons"] for r in report["frames"]] == [40_000] * 3
    assert render_engine.LIGHT.cs is None          # the loop let its light go
    frames = {f: read_image(tmp_path / f"f_{f}.exr") for f in (1, 2, 3)}
    assert not np.array_equal(frames[1], frames[3])     # the camera did move
    for f in (2, 3):
        cornell.frame_set(f)
        run = headless.render_to_file(cornell, tmp_path / f"single_{f}.exr")
        assert run.light_from_frame is None and run.photons == 40_000
        np.testing.assert_array_equal(read_image(tmp_path / f"single_{f}.exr"), frames[f])


def test_a_moving_light_traces_every_frame(cornell, tmp_path):
    light = next(ob for ob in cornell.objects if ob.type == "LIGHT")
    x, y, z = light.location
    keyframe(light, 1, (x, y, z))
    keyframe(light, 2, (x + 0.2, y, z))
    report = headless._render_frames(cornell, tmp_path / "g_##.exr", (1, 2))
    assert [r["light_from_frame"] for r in report["frames"]] == [None, None]
    assert sorted(p.name for p in tmp_path.glob("g_*.exr")) == ["g_01.exr", "g_02.exr"]


def test_end_of_a_render_job_lets_the_light_go_unless_persistent(cornell, tmp_path):
    from photon_lightmaps import operators
    headless.render_to_file(cornell, tmp_path / "a.exr")
    # bpy.ops.render.render ran the render_complete handler: nothing is kept
    assert render_engine.LIGHT.cs is None
    cornell.render.use_persistent_data = True
    headless.render_to_file(cornell, tmp_path / "b.exr")
    assert render_engine.LIGHT.cs is not None
    run = headless.render_to_file(cornell, tmp_path / "c.exr")
    assert run.light_from_frame == cornell.frame_current
    cornell.render.use_persistent_data = False
    operators._end_of_render_job(cornell)
    assert render_engine.LIGHT.cs is None


def test_frame_paths():
    assert headless.frame_path("out/a_###.png", 7).name == "a_007.png"
    assert headless.frame_path("out/a.png", 12).name == "a_0012.png"
    assert headless.frame_path("out/a_#.exr", -3).name == "a_-3.exr"
