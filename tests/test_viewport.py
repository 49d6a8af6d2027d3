"""The Rendered viewport's logic, headless (bake/viewport.py): the photon pass runs
when the scene changes and not when the view moves; a new view restarts the
samples with a low-resolution preview; the samples accumulate to exactly the
image an F12 render with the same samples and seed gives; the worker thread
finishes and an error stays in the session. Drawing needs a GPU context and is
not run here."""
import math
import time
from types import SimpleNamespace

import numpy as np
import pytest

from photon_lightmaps.bake import viewport
from photon_lightmaps.engine import demo_scenes, session
from photon_lightmaps.engine.core.scene import Camera, compose, rotate, translate

SETTINGS = session.Settings(photons=3000, samples=3, seed=7, gather_rays=2)


def room():
    return demo_scenes.cornell_box(width=16, height=12, with_primitives=True)


def moved(cam, dx):
    return Camera(transform=compose(translate(dx, 0.0, 0.0), cam.transform), kind=cam.kind, fov=cam.fov,
                  width=cam.width, height=cam.height)


def run_out(s, limit=50):
    for _ in range(limit):
        if not s.step():
            return
    raise AssertionError("the session never finished")


def test_samples_add_up_to_the_f12_render_and_a_moved_view_keeps_the_photons():
    scene = room()
    s = viewport.ViewportSession()
    s.update_scene(scene, SETTINGS)
    assert s.update_view(scene.camera) and not s.update_view(scene.camera)   # the same view: no restart
    assert s.step() and s.photon_passes == 1 and s.image() is None         # compile + photons
    assert s.step() and s.samples == 0
    assert s.image().shape[:2] == (12 // viewport.PREVIEW_DIVISOR, 16 // viewport.PREVIEW_DIVISOR)   # the preview
    run_out(s)
    assert s.samples == SETTINGS.samples and not s.busy()
    f12 = session.render(s.cs, SETTINGS)
    assert np.allclose(s.image(), f12, rtol=1e-9, atol=1e-12)
    # the view moves: samples restart, photons stay
    assert s.update_view(moved(scene.camera, 0.3))
    assert s.busy() and s.step() and s.samples == 0 and s.image().shape[:2] == (3, 4)
    run_out(s)
    assert s.photon_passes == 1 and s.samples == SETTINGS.samples
    assert not np.allclose(s.image(), f12)
    # the scene changes: photons again
    s.update_scene(room(), SETTINGS)
    assert s.step() and s.photon_passes == 2 and s.samples == 0


def test_the_worker_thread_finishes_and_errors_stay_in_the_session():
    scene = room()
    s = viewport.ViewportSession()
    s.update_scene(scene, SETTINGS)
    s.update_view(scene.camera)
    s.start()
    try:
        t0 = time.perf_counter()
        while s.busy() and time.perf_counter() - t0 < 300:
            time.sleep(0.05)
        assert not s.busy() and s.samples == SETTINGS.samples and s.error is None
        bad = room()
        bad.camera = Camera(width=8, height=8, fov=4.0)      # no such field of view: a SceneError
        s.update_scene(bad, SETTINGS)
        s.update_view(bad.camera)
        t0 = time.perf_counter()
        while s.error is None and time.perf_counter() - t0 < 60:
            time.sleep(0.05)
        assert s.error is not None and not s.busy()
    finally:
        s.stop()
    assert not s._thread.is_alive()


@pytest.mark.parametrize("width,height", [(400, 300), (300, 400)])
def test_the_view_camera_matches_the_viewport_projection(width, height):
    """A perspective window matrix of a known field of view, and an orthographic one."""
    fov = math.radians(50.0)
    t = 1.0 / math.tan(0.5 * fov)          # the larger side spans fov
    sx, sy = (t, t * width / height) if width >= height else (t * height / width, t)
    view = np.linalg.inv(np.vstack([compose(translate(1.0, -4.0, 2.0), rotate("x", 80.0)), [0, 0, 0, 1]]))
    persp = np.diag([sx, sy, -1.0, 0.0])
    cam = viewport.view_camera(SimpleNamespace(view_matrix=view, window_matrix=persp, is_perspective=True),
                        width, height)
    assert cam.kind == "perspective" and abs(cam.fov - fov) < 1e-12
    assert np.allclose(cam.transform, np.linalg.inv(view)[:3])
    ortho = np.diag([2.0 / 6.0, 2.0 / 6.0 * max(width, height) / min(width, height), -0.1, 1.0])
    if height > width:
        ortho = np.diag([2.0 / 6.0 * height / width, 2.0 / 6.0, -0.1, 1.0])
    cam = viewport.view_camera(SimpleNamespace(view_matrix=view, window_matrix=ortho, is_perspective=False),
                        width, height)
    assert cam.kind == "orthographic" and abs(cam.ortho_scale - 6.0) < 1e-12


def test_the_engine_draws_the_rendered_viewport():
    from photon_lightmaps.operators.render_engine import PhotonLightmapsRenderEngine
    assert "view_update" in PhotonLightmapsRenderEngine.__dict__ and "view_draw" in PhotonLightmapsRenderEngine.__dict__
    assert PhotonLightmapsRenderEngine.bl_use_eevee_viewport          # Material Preview stays EEVEE's
