"""The Rendered viewport: a progressive image of the viewport's view.

Photon lightmaps hold light on surfaces, not on the view, so the viewport
traces photons only when the scene changes; moving the view only restarts the
render pass. `ViewportSession` keeps the compiled scene and its lightmaps,
and the samples added for the current view:

* `update_scene` (view_update, main thread: the export reads bpy) hands over
  a newly exported scene; the next step compiles it and runs the photon pass.
* `update_view` (view_draw) hands over the view's camera; a different one
  restarts the samples.
* `step` does one unit of work: the compile and photon pass, or after a
  restart a quarter-resolution preview, or one more sample of the full
  image. Sample k is the k-th sample of an F12 render with the scene's
  samples and seed (renderer.add_samples), so the finished viewport is the
  render's image.
* A worker thread runs the steps (the kernels release the GIL, so Blender's
  interface stays live); view_draw shows `image()` and keeps redrawing while
  the session is busy.

`view_update` and `view_draw` below are the RenderEngine's callbacks. Every
error ends in the session's `error` (shown on the viewport's stats line),
never in Blender.
"""
import threading
from dataclasses import replace

import numpy as np

from ..engine import session
from ..engine.transport.renderer import add_samples, compile_camera
from ..engine.core.scene import Camera

PREVIEW_DIVISOR = 4         # the first image after a restart: a quarter of the resolution


def _same_camera(a, b):
    return (a is not None and b is not None and a.kind == b.kind and a.width == b.width
            and a.height == b.height and np.array_equal(np.asarray(a.transform), np.asarray(b.transform))
            and a.fov == b.fov and a.ortho_scale == b.ortho_scale)


class ViewportSession:
    """One Rendered viewport's state (see the module docstring)."""

    def __init__(self):
        self._lock = threading.Lock()
        self._scene = None
        self._settings = None
        self._scene_gen = 0
        self._camera = None
        self._view_gen = 0
        self.cs = None
        self._cs_gen = -1
        self._acc = None            # (view generation, image sum)
        self.samples = 0            # full-resolution samples in the image
        self._preview = None
        self.photon_passes = 0
        self.error = None
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = None

    # ------------------------------------------------------------------ inputs
    def update_scene(self, scene, settings):
        """A new export of the scene (and its settings): photons are traced again."""
        with self._lock:
            self._scene, self._settings = scene, settings
            self._scene_gen += 1
            self.error = None
        self._wake.set()

    def update_view(self, camera):
        """The view's camera; a different one restarts the samples. -> True if it did."""
        with self._lock:
            if _same_camera(camera, self._camera):
                return False
            self._camera = camera
            self._view_gen += 1
        self._wake.set()
        return True

    def has_scene(self):
        """True once a scene was handed over."""
        return self._scene is not None

    # ------------------------------------------------------------------- work
    def target(self):
        s = self._settings
        return max(1, int(s.samples)) if s is not None else 0

    def busy(self):
        """True while steps are left to do (or running)."""
        with self._lock:
            if self.error is not None or self._scene is None or self._camera is None:
                return False
            return (self._cs_gen != self._scene_gen or self._acc is None or self._acc[0] != self._view_gen
                    or self.samples < self.target())

    def step(self):
        """One unit of work -> True if it changed the image or the lightmaps."""
        with self._lock:
            scene, settings, sgen = self._scene, self._settings, self._scene_gen
            camera, vgen = self._camera, self._view_gen
        if scene is None or camera is None or self.error is not None:
            return False
        if self._cs_gen != sgen:
            cs = session.compile(scene)
            if cs.lights.total_power > 0.0 and settings.photons > 0:
                session.render_photon_pass(cs, settings)
            self.photon_passes += 1
            with self._lock:
                self.cs, self._cs_gen = cs, sgen
                self._acc, self.samples, self._preview = None, 0, None
            return True
        if self._acc is None or self._acc[0] != vgen:
            with self._lock:
                self._acc, self.samples, self._preview = (vgen, None), 0, None
        n = self.target()
        if self.samples >= n:
            return False
        gather = int(settings.gather_rays) if settings.gathers else 0
        kw = dict(seed=int(settings.seed), mode=settings.mode, max_depth=int(settings.max_bounces),
                  gather=gather)
        if gather and settings.irradiance_cache:
            # made once per photon pass, then every view reads them
            kw["records"] = session.render_records(self.cs, settings)
        if self.samples == 0 and self._preview is None:
            small = replace(camera, width=max(1, camera.width // PREVIEW_DIVISOR),
                            height=max(1, camera.height // PREVIEW_DIVISOR))
            img = np.zeros((small.height, small.width, self.cs.n_bands))
            add_samples(replace(self.cs, camera=compile_camera(small)), img, 1, 0, 1, **kw)
            with self._lock:
                if self._acc[0] == vgen:
                    self._preview = img
            return True
        with self._lock:
            total = self._acc[1]
        if total is None:
            total = np.zeros((camera.height, camera.width, self.cs.n_bands))
        add = np.zeros_like(total)
        add_samples(replace(self.cs, camera=compile_camera(camera)), add, n, self.samples, self.samples + 1,
                    **kw)
        with self._lock:
            if self._acc[0] == vgen:        # the view did not move meanwhile
                self._acc = (vgen, total + add)
                self.samples += 1
        return True

    def image(self):
        """(H, W, n_bands) radiance to show: the samples so far (their mean), the
        preview before the first one, or None."""
        with self._lock:
            if self._acc is not None and self._acc[1] is not None and self.samples:
                return self._acc[1] * (self.target() / self.samples)
            return self._preview

    # ----------------------------------------------------------------- thread
    def start(self):
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="photon_lightmaps viewport", daemon=True)
            self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                worked = self.step()
            except Exception as exc:  # noqa: BLE001  (shown on the viewport; Blender goes on)
                from ..messages import describe
                with self._lock:
                    self.error = describe(exc)
                worked = False
            if not worked:
                self._wake.wait(0.25)
                self._wake.clear()

    def stop(self):
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout=30)


# ------------------------------------------------------------- Blender side
def view_camera(region_data, width, height):
    """The engine Camera of a 3D viewport's view (perspective, orthographic, or the
    camera view as the region frames it; a panned camera view's offset is ignored)."""
    view = np.array(region_data.view_matrix, np.float64)
    proj = np.array(region_data.window_matrix, np.float64)
    cam = Camera(transform=np.linalg.inv(view)[:3].copy(), width=int(width), height=int(height))
    larger = proj[0, 0] if width >= height else proj[1, 1]
    if region_data.is_perspective:
        cam.kind, cam.fov = "perspective", 2.0 * float(np.arctan(1.0 / larger))
    else:
        cam.kind, cam.ortho_scale = "orthographic", 2.0 / float(larger)
    return cam


def _guarded(callback):
    """A RenderEngine viewport callback that never raises into Blender: what escapes
    its own handling (the engine's data already freed, a bug) is one console line."""
    import functools

    @functools.wraps(callback)
    def call(*args):
        try:
            return callback(*args)
        except Exception as exc:  # noqa: BLE001  (Blender's draw loop must go on)
            import sys
            from ..messages import bug_text
            print(f"Photon Lightmaps viewport: {bug_text(exc)}", file=sys.stderr, flush=True)
        return None
    return call


def _session(engine):
    s = getattr(engine, "_photon_viewport", None)
    if s is None:
        s = engine._photon_viewport = ViewportSession()
    return s


def _scene_changed(depsgraph):
    import bpy
    for u in depsgraph.updates:
        if u.is_updated_geometry or u.is_updated_transform or u.is_updated_shading:
            return True
        if isinstance(u.id, (bpy.types.Material, bpy.types.Light, bpy.types.World, bpy.types.Scene,
                             bpy.types.Image, bpy.types.NodeTree)):
            return True
    return False


@_guarded
def view_update(engine, context, depsgraph):
    """RenderEngine.view_update: exports the scene again when it changed."""
    s = _session(engine)
    try:
        if not s.has_scene() or _scene_changed(depsgraph):
            from ..export import export_scene
            region = context.region
            scene, _ = export_scene(depsgraph, resolution=(max(region.width, 1), max(region.height, 1)))
            s.update_scene(scene, session.Settings.read(depsgraph.scene.photon_lightmaps))
        s.start()
    except Exception as exc:  # noqa: BLE001  (never into Blender: the viewport says it)
        from ..messages import describe
        s.error = describe(exc)
    _stats(engine, s)


@_guarded
def view_draw(engine, context, depsgraph):
    """RenderEngine.view_draw: the session's image, scaled to the region."""
    s = _session(engine)
    try:
        region = context.region
        s.update_view(view_camera(context.region_data, max(region.width, 1), max(region.height, 1)))
        img = s.image()
        if img is not None:
            _draw(engine, depsgraph.scene, img, region.width, region.height)
    except Exception as exc:  # noqa: BLE001
        from ..messages import describe
        s.error = describe(exc)
    _stats(engine, s)
    if s.busy():
        engine.tag_redraw()


def _stats(engine, s):
    if s.error is not None:
        text = f"Error: {s.error}"
    elif s.cs is None:
        text = "Compiling scene and tracing photons"
    elif s.samples == 0:
        text = "Preview"
    else:
        text = f"Sample {s.samples}/{s.target()}"
    engine.update_stats("", text)


def _draw(engine, scene, img, width, height):
    import gpu      # not in background mode: imported only when drawing
    from gpu_extras.presets import draw_texture_2d
    h, w = img.shape[:2]
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = img[::-1, :, :3] if img.shape[2] >= 3 else img[::-1, :, :1]   # rows bottom-up
    buf = gpu.types.Buffer("FLOAT", w * h * 4, rgba.reshape(-1))
    tex = gpu.types.GPUTexture((w, h), format="RGBA16F", data=buf)
    gpu.state.blend_set("ALPHA_PREMULT")
    engine.bind_display_space_shader(scene)
    draw_texture_2d(tex, (0, 0), width, height)
    engine.unbind_display_space_shader()
    gpu.state.blend_set("NONE")


def free(engine):
    """The engine goes (viewport closed or shading changed): stop its worker."""
    s = getattr(engine, "_photon_viewport", None)
    if s is not None:
        s.stop()
