"""Rendering: export -> engine/session.py -> the Render Result, for the RenderEngine and the CLI.

`run_render` is the whole pipeline with host callbacks; the RenderEngine
(operators/render_engine.py) and `python -m photon_lightmaps render` both go
through it (the CLI by calling bpy.ops.render.render, which lands in
PhotonLightmapsRenderEngine.render -> render() here), and the last run's
numbers are kept in LAST_RUN for the JSON report. It sits in bake/ because,
like a bake, it turns engine results into a Blender image.
"""
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from ..engine import light_reuse, session, spectral
from ..engine.lightmaps import uv_atlas
from ..engine.core.errors import Cancelled
from ..export import export_scene
from ..messages import bug_text, describe, record

TILE = 64


@dataclass
class RenderRun:
    """What one render did; the CLI writes it as the JSON report (cli.py --json)."""
    scene: str = ""
    width: int = 0
    height: int = 0
    photons: int = 0
    rays: int = 0
    photons_per_second: float = 0.0
    samples: int = 0
    seconds: dict = field(default_factory=dict)
    lightmap_bytes: int = 0
    lightmaps: int = 0
    texels: int = 0
    warnings: list = field(default_factory=list)
    cancelled: bool = False
    image: np.ndarray = None
    orientation_lightmaps: list = field(default_factory=list)   # ol_bake.summarize rows
    environment: dict = None    # the world's map: name, width, height, bytes, bake_seconds
    denoised: bool = False      # image is OIDN's output (the tiles shown while rendering were not)
    layouts: list = field(default_factory=list)   # per unwrapped mesh: the layout chosen and why
    xatlas_workers: int = 0     # xatlas child processes this render started
    kernels: dict = field(default_factory=dict)   # kernel compiles during the render (first runs)
    light_from_frame: int = None   # the frame whose photon pass this one reused (only the camera moved)

    def as_dict(self):
        return {"scene": self.scene, "width": self.width, "height": self.height,
                "photons": self.photons, "rays": self.rays,
                "photons_per_second": self.photons_per_second, "samples": self.samples,
                "seconds": dict(self.seconds),
                "memory": {"lightmap_bytes": self.lightmap_bytes, "peak_rss_bytes": peak_rss_bytes()},
                "lightmaps": self.lightmaps, "texels": self.texels,
                "warnings": list(self.warnings), "cancelled": self.cancelled,
                "orientation_lightmaps": [dict(r) for r in self.orientation_lightmaps],
                "denoised": self.denoised,
                "layouts": [dict(r) for r in self.layouts], "xatlas_workers": self.xatlas_workers,
                "kernels": dict(self.kernels), "light_from_frame": self.light_from_frame,
                "environment": dict(self.environment) if self.environment else None}


LAST_RUN = None
# The last render's traced scene, kept for the next frame of an animation (only
# the camera moved: no compile, no photon pass); let go when the render job ends
# (operators/__init__.py) unless Persistent Data is on, or while the CLI holds it.
LIGHT = light_reuse.LightCache()
# What a reusing frame reports of the run that traced its light.
_KEPT = ("photons", "rays", "photons_per_second", "lightmap_bytes", "lightmaps", "texels", "layouts",
         "orientation_lightmaps", "environment", "xatlas_workers")
# The exception the last render() failed with (the CLI raises it again), and
# whether render() prints it (the CLI, which reports it itself, turns that off).
LAST_ERROR = None
PRINT_ERRORS = True


def peak_rss_bytes():
    """Peak resident memory of this process in bytes (0 where the platform will not say)."""
    if sys.platform == "win32":
        import ctypes
        from ctypes import wintypes

        class Counters(ctypes.Structure):
            _fields_ = [("cb", wintypes.DWORD), ("PageFaultCount", wintypes.DWORD)] + [
                (name, ctypes.c_size_t) for name in (
                    "PeakWorkingSetSize", "WorkingSetSize", "QuotaPeakPagedPoolUsage",
                    "QuotaPagedPoolUsage", "QuotaPeakNonPagedPoolUsage", "QuotaNonPagedPoolUsage",
                    "PagefileUsage", "PeakPagefileUsage")]

        c = Counters()
        c.cb = ctypes.sizeof(c)
        proc = ctypes.windll.kernel32.GetCurrentProcess()
        ok = ctypes.windll.psapi.GetProcessMemoryInfo(proc, ctypes.byref(c), c.cb)
        return int(c.PeakWorkingSetSize) if ok else 0
    import resource
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    # ru_maxrss is in KiB on Linux, in bytes on macOS.
    return int(rss if sys.platform == "darwin" else rss * 1024)


def _mib(n):
    return n / (1024.0 * 1024.0)


def _export(depsgraph, run, report, camera_override, resolution):
    """Phase 1: the engine scene, with a warning where nothing would show."""
    scene, _ = export_scene(depsgraph, report=report, camera_override=camera_override, resolution=resolution)
    run.width, run.height = scene.camera.width, scene.camera.height
    world = getattr(scene.environment, "pixels", scene.environment)   # constant or map
    has_light = bool(scene.lights) or np.any(np.asarray(world) > 0) or any(
        np.any(np.asarray(m.emission) > 0) for m in scene.materials)
    if not scene.instances:
        report("WARNING", "Photon Lightmaps: the scene has no renderable geometry")
    if not has_light:
        report("WARNING", "Photon Lightmaps: the scene has no lights, emissive materials or world light; "
                          "the image is black")
    return scene


def _compile(scene, run, report, stats, should_stop):
    """Phase 2: the compiled scene, its warnings and lightmap numbers."""
    launches = uv_atlas.worker_launches

    def unwrapping(done, total):
        stats(f"Compiling scene | xatlas unwraps {done}/{total} meshes without a Lightmap UV layer")
    # A first run compiles the render pass meanwhile (ahead).
    cs = session.compile(scene, ahead=("render",), unwrap_progress=unwrapping,
                         should_stop=should_stop)
    run.xatlas_workers = uv_atlas.worker_launches - launches
    for text in cs.info.get("warnings", ()):   # dropped triangles, unwrap fallbacks, clamped UVs
        report("WARNING", f"Photon Lightmaps: {text}")
    run.layouts = list(cs.info.get("layouts", ()))
    for row in run.layouts:
        if row["layout"] == "fast layout" and "unwrap limit" in row["reason"]:
            report("INFO", f"Photon Lightmaps: mesh '{row['mesh']}' got a fast box-projection layout "
                           f"({row['charts']:,} charts on {row['resolution']}×{row['resolution']} texels): "
                           f"{row['reason']} (raise Unwrap Limit, or add a 'Lightmap' UV layer, for a "
                           "tighter one)")
    run.lightmap_bytes = cs.lightmap_bytes()
    if cs.info.get("csg_ties"):
        report("WARNING", f"Photon Lightmaps: coincident CSG operand faces ({cs.info['csg_ties']:,} ties on "
                          f"{cs.info['csg_tie_texels']:,} texels), resolved by the tie rule (thesis 4.1.2)")
    run.lightmaps, run.texels = int(cs.info.get("lightmaps", 0)), int(cs.info.get("texels", 0))
    env = cs.info.get("environment")
    if env:
        run.environment = dict(env)
        how = f"baked in {env['bake_seconds']:.1f} s" if env["bake_seconds"] > 0 else "cached"
        report("INFO", f"Photon Lightmaps: world '{env['name']}' as a {env['width']}x{env['height']} "
                       f"map ({_mib(env['bytes']):.1f} MiB), {how}")
    return cs


def _photons(cs, scene, settings, run, report, stats, progress, should_stop, lm_text):
    """Phase 3: the photon pass (indirect light only: the render gathers direct light itself)."""
    t0 = time.perf_counter()

    def photon_progress(done, total):
        rate = done / max(time.perf_counter() - t0, 1e-9)
        stats(f"Photons {done:,}/{total:,} | {rate:,.0f} photons/s | {lm_text}")
        progress(0.5 * done / max(total, 1))
        return not should_stop()

    if scene.instances and settings.photons > 0 and cs.lights.total_power > 0.0:
        ps = session.render_photon_pass(cs, settings, progress=photon_progress)
        run.photons, run.rays = ps.photons, ps.rays
        run.photons_per_second = ps.photons / max(ps.seconds, 1e-9)
    if cs.info.get("orientation_lightmaps"):   # also the automatic ones (unwrap fallbacks)
        # Per-OL numbers for the JSON report and the OL panel; averaging warnings to the user.
        from .orientation import record_report
        run.orientation_lightmaps = record_report(cs, run.scene, "render", report)
    if should_stop():
        raise Cancelled("stopped after the photon pass")
    return t0


def _render(cs, settings, run, stats, progress, on_tile, should_stop, lm_text):
    """Phase 4: the render pass, progressive: the whole frame at 1 sample, then 2, 4, ...
    (each tile shown as it refines); the last pass gives the same image as one pass would."""
    from ..engine.transport.renderer import progressive_passes
    passes = progressive_passes(settings.samples)
    starts = np.cumsum([0] + passes)        # samples done before each pass
    n_tiles = max(1, -(-run.width // TILE) * -(-run.height // TILE))
    calls = [0]

    def tile_progress(x0, y0, tile, img):
        k, t = divmod(calls[0], n_tiles)      # pass k, its tile t + 1 (every pass covers the frame)
        calls[0] += 1
        if on_tile is not None:
            on_tile(x0, y0, tile)
        progress(0.5 + 0.5 * (starts[k] + passes[k] * (t + 1) / n_tiles) / max(settings.samples, 1))
        stats(f"Pass {k + 1}/{len(passes)}, {starts[k + 1]}/{settings.samples} samples | "
              f"tile {t + 1}/{n_tiles} | {run.photons:,} photons | {lm_text}")
        return not should_stop()

    def waiting(seconds):
        stats(f"Compiling the render kernels in a second process (first run): {seconds:.0f} s | {lm_text}")
        return not should_stop()

    return session.render(cs, settings, tile=TILE, progress=tile_progress, passes=passes, waiting=waiting)


def _wait_for_warmup(stats, should_stop):
    """A render started while the background warm-up compiles waits for it, saying
    so (engine/warmup.py); the kernels it compiled are then the render's. False:
    cancelled meanwhile."""
    from ..engine import warmup

    def poll(w):
        stats(f"Preparing kernels (first run): {w.fraction:.0%}, {w.current or 'finishing'}")
        return not (should_stop is not None and should_stop())
    return warmup.wait(poll)


def run_render(depsgraph, *, report=None, stats=None, progress=None, on_tile=None, should_stop=None,
               camera_override=None, resolution=None):
    """_run_render, with the stats line saying so while kernels compile (a first
    run compiles for minutes; later runs load them from the cache)."""
    from ..engine.core import kernel_watch
    stats = stats or (lambda text: None)
    t0 = []

    def on_compile(watch, name):
        t0 or t0.append(time.perf_counter())
        stats(f"Compiling kernels (first run, cached afterwards): {watch.started} so far, "
              f"{time.perf_counter() - t0[0]:.0f} s")

    if not _wait_for_warmup(stats, should_stop):
        run = RenderRun(scene=depsgraph.scene.name, cancelled=True)
        return run
    with kernel_watch.watching(on_compile) as watch:
        run = _run_render(depsgraph, report=report, stats=stats, progress=progress, on_tile=on_tile,
                          should_stop=should_stop, camera_override=camera_override,
                          resolution=resolution)
    run.kernels = watch.summary()
    return run


def _run_render(depsgraph, *, report=None, stats=None, progress=None, on_tile=None, should_stop=None,
                camera_override=None, resolution=None):
    """Renders the evaluated depsgraph with the scene's Photon Lightmaps settings.

    report(level, msg); stats(text); progress(fraction in [0, 1]);
    on_tile(x0, y0, tile) with y0 counted from the top and tile (h, w, 3);
    should_stop() -> True cancels (the run returns with cancelled=True).
    Returns a RenderRun whose image is (H, W, 3) linear radiance (None if cancelled).
    """
    global LAST_RUN
    host_report = report or (lambda level, msg: None)
    stats = stats or (lambda text: None)
    progress = progress or (lambda f: None)
    should_stop = should_stop or (lambda: False)
    settings = session.Settings.read(depsgraph.scene.photon_lightmaps)
    run = RenderRun(scene=depsgraph.scene.name, samples=settings.samples, denoised=settings.denoise)
    LAST_RUN = run
    t0 = time.perf_counter()
    if settings.denoise:
        from ..engine.transport import denoise
        denoise.require()       # missing pyoidn: say so before the photon pass, not after

    def report(level, msg):
        if level == "WARNING" and msg not in run.warnings:
            run.warnings.append(msg)
        host_report(level, msg)

    stats("Exporting scene")
    scene = _export(depsgraph, run, report, camera_override, resolution)
    if settings.spectral:
        scene = spectral.spectral_scene(scene)
    key = light_reuse.light_key(scene, settings)
    t_export = time.perf_counter()
    try:
        kept = LIGHT.get(key)
        if kept is not None:
            cs = light_reuse.with_camera(kept, scene.camera)
            for name in _KEPT:
                setattr(run, name, LIGHT.summary[name])
            run.light_from_frame = LIGHT.frame
            report("INFO", f"Photon Lightmaps: the light traced for frame {LIGHT.frame} is reused "
                           "(only the camera moved)")
            t_compile = t_photon0 = t_photons = time.perf_counter()
            lm_text = f"Lightmaps {_mib(run.lightmap_bytes):.1f} MiB, light of frame {LIGHT.frame}"
        else:
            stats("Compiling scene")
            cs = _compile(scene, run, report, stats, should_stop or (lambda: False))
            lm_text = f"Lightmaps {_mib(run.lightmap_bytes):.1f} MiB ({run.texels:,} texels)"
            t_compile = time.perf_counter()
            t_photon0 = _photons(cs, scene, settings, run, report, stats, progress, should_stop, lm_text)
            t_photons = time.perf_counter()
            LIGHT.put(key, cs, depsgraph.scene.frame_current, {name: getattr(run, name) for name in _KEPT})
        img = _render(cs, settings, run, stats, progress, on_tile, should_stop, lm_text)
        t_render = time.perf_counter()
    except Cancelled:
        run.cancelled = True
        run.seconds = {"total": time.perf_counter() - t0}
        return run
    run.image = img
    run.seconds = {"export": t_export - t0, "compile": t_compile - t_export,
                   "photon_pass": t_photons - t_photon0, "render": t_render - t_photons,
                   "total": t_render - t0}
    if "denoise" in cs.timings:     # part of "render" (session.render denoises the finished image)
        run.seconds["denoise"] = cs.timings["denoise"]
    if "records" in cs.timings:     # part of "render": the irradiance cache's records (0: kept)
        run.seconds["records"] = cs.timings["records"]
    return run


def render_region(render, width, height):
    """Pixel rectangle (x, y from the bottom, w, h) that Blender's render result covers.

    With a render region (border) the result holds only that part of the frame;
    Blender truncates border * size in single precision, so the same is done here.
    """
    if not render.use_border:
        return 0, 0, width, height
    f = np.float32
    x0, x1 = (int(f(v) * f(width)) for v in (render.border_min_x, render.border_max_x))
    y0, y1 = (int(f(v) * f(height)) for v in (render.border_min_y, render.border_max_y))
    x0, y0 = min(max(x0, 0), width), min(max(y0, 0), height)
    return x0, y0, max(min(x1, width) - x0, 0), max(min(y1, height) - y0, 0)


def render(self, depsgraph):
    """PhotonLightmapsRenderEngine.render: runs run_render, writing tiles into Blender's result.

    Never raises into Blender: any failure, a bug included, ends this render
    with error_set and one line on the console, and Blender goes on."""
    global LAST_RUN, LAST_ERROR
    LAST_RUN = LAST_ERROR = None
    try:
        _render_into(self, depsgraph)
    except Exception as exc:  # noqa: BLE001 - shown to the user instead of a silent black frame
        # The kept exception outlives this render; its frames' locals (this engine,
        # the depsgraph) must not, or they are freed by Python after Blender freed
        # them. Files, lines and functions stay for a traceback; this frame, still
        # running, leaves it.
        import traceback
        exc = exc.with_traceback(exc.__traceback__.tb_next)
        traceback.clear_frames(exc.__traceback__)
        LAST_ERROR = exc
        text = describe(exc)
        try:
            self.error_set(text)
            _empty_result(self)
            record(depsgraph.scene.name, "render", LAST_RUN.warnings if LAST_RUN is not None else [],
                   error=text)
        except Exception:  # noqa: BLE001 - Blender's data may be what failed; the line below still tells
            pass
        if PRINT_ERRORS:
            _print_error(exc)


def _empty_result(engine):
    """A black frame in the Render Result of a failed render: Blender 5.0 crashes
    writing a still (Render > write_still, an animation's frames) as OpenEXR
    from a result no engine ever filled."""
    result = engine.begin_result(0, 0, int(engine.resolution_x), int(engine.resolution_y))
    engine.end_result(result)


def _print_error(exc):
    """One console line for a failed render: a pipeline running Blender headless
    sees no error_set."""
    print(f"Photon Lightmaps: {bug_text(exc)}", file=sys.stderr, flush=True)


def _render_into(self, depsgraph):
    scene = depsgraph.scene
    width, height = int(self.resolution_x), int(self.resolution_y)
    layer = depsgraph.view_layer.name
    rx, ry, rw, rh = render_region(scene.render, width, height)

    def on_tile(x0, y0, tile):
        th, tw = tile.shape[:2]
        # Blender's rows run bottom to top; the renderer's run top to bottom.
        bx, by = x0, height - y0 - th
        ix0, ix1 = max(bx, rx), min(bx + tw, rx + rw)
        iy0, iy1 = max(by, ry), min(by + th, ry + rh)
        if ix1 <= ix0 or iy1 <= iy0:
            return
        rgba = np.ones((th, tw, 4), np.float32)
        rgba[..., :3] = tile[..., :3] if tile.shape[2] >= 3 else tile[..., :1]
        sub = np.ascontiguousarray(rgba[::-1][iy0 - by:iy1 - by, ix0 - bx:ix1 - bx])
        # Result coordinates are relative to the render region.
        result = self.begin_result(ix0 - rx, iy0 - ry, ix1 - ix0, iy1 - iy0, layer=layer)
        result.layers[0].passes["Combined"].rect.foreach_set(sub.reshape(-1))
        self.end_result(result)

    run = run_render(depsgraph,
                     report=lambda level, msg: self.report({level}, msg),
                     stats=lambda text: self.update_stats("", text),
                     progress=self.update_progress,
                     on_tile=on_tile,
                     should_stop=self.test_break,
                     camera_override=self.camera_override,
                     resolution=(width, height))
    record(scene.name, "render", run.warnings)
    if run.cancelled:
        return
    if run.denoised:
        on_tile(0, 0, run.image)    # the tiles went out noisy, as they finished: replace them all
    self.update_memory_stats(memory_used=_mib(run.lightmap_bytes), memory_peak=_mib(peak_rss_bytes()))
    self.update_stats("", f"Done | {run.photons:,} photons in {run.seconds['photon_pass']:.2f} s "
                          f"({run.photons_per_second:,.0f} photons/s) | render {run.seconds['render']:.2f} s | "
                          f"Lightmaps {_mib(run.lightmap_bytes):.1f} MiB"
                          + (f" | {len(run.orientation_lightmaps)} orientation lightmaps"
                             if run.orientation_lightmaps else ""))
