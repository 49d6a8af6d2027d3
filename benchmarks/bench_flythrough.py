"""A 60-frame camera fly-through of a furnished room: our total time against
Cycles' total at equal mean per-frame error, measured in one run.

    .venv/bin/python -m benchmarks.bench_flythrough [--frames 60] [--size 96x64] [--quick]

The room is scenes.py's `window` room (sun through a window, spot on the back
wall) furnished with a table, two chairs, a sofa and a shelf, and a ceiling
lamp. The camera walks across the room and turns; nothing else moves.

* **Ours** renders every frame as the CLI's `render --frames` does
  (cli._render_frames: export, then the light of frame 1 reused by every later
  frame, then each frame's render pass, EXR written): the total is the loop's
  wall time. "Without reuse" renders the scored frames with the light let go
  between frames (compile and photon pass each time) and scales their mean to
  all frames.
* **Cycles** renders the scored frames at each spp of a sweep; its total for
  all frames is the mean per-frame wall time times the frame count (a Cycles
  animation renders every frame the same way). Its time at our error is
  interpolated on the log-log curve of total time against error.
* **Error**: relative RMSE per frame against a two-half Cycles reference of that
  frame (its own noise removed, run_all.Scorer), averaged over the scored
  frames (every tenth frame and the last).

References are cached in benchmarks/cache/ by scene hash. Prints one JSON
object and writes it to benchmarks/out/flythrough.json.
"""
import argparse
import json
import math
import pathlib
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT.parent))
    __package__ = "photon_lightmaps.benchmarks"      # noqa: A001 - run as a script

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from photon_lightmaps import cli as headless  # noqa: E402
from photon_lightmaps import demo_blend, registration  # noqa: E402
from photon_lightmaps.bake import render as render_engine  # noqa: E402

from . import methods  # noqa: E402
from . import scenes  # noqa: E402
from .quiet import quiet  # noqa: E402
from .run_all import Scorer, loglog_interp  # noqa: E402

OUT = ROOT / "benchmarks" / "out"
CHARTS = ROOT / "benchmarks" / "charts"
CACHE = ROOT / "benchmarks" / "cache"


def build_furnished(width, height, frames):
    """The window room with furniture and a ceiling lamp; the camera keyframed
    from frame 1 to `frames` (linear), walking along the front wall and turning."""
    scene = scenes.build_window(width, height)
    wood = demo_blend.principled("wood", (0.45, 0.3, 0.18))
    cloth = demo_blend.principled("cloth", (0.6, 0.15, 0.12))
    pale = demo_blend.principled("pale", (0.8, 0.78, 0.7))
    box = scenes._box
    box("table_top", (-0.2, -0.5, 0.72), (1.0, 0.3, 0.76), wood)
    for i, (x, y) in enumerate(((-0.15, -0.45), (0.95, -0.45), (-0.15, 0.25), (0.95, 0.25))):
        box(f"table_leg{i}", (x - 0.03, y - 0.03, 0.0), (x + 0.03, y + 0.03, 0.72), wood)
    for i, x in enumerate((0.1, 0.7)):
        box(f"chair{i}_seat", (x - 0.2, -0.95, 0.42), (x + 0.2, -0.55, 0.46), wood)
        box(f"chair{i}_back", (x - 0.2, -0.99, 0.46), (x + 0.2, -0.95, 0.9), wood)
        box(f"chair{i}_legs", (x - 0.18, -0.93, 0.0), (x + 0.18, -0.57, 0.42), wood)
    box("sofa_seat", (-1.95, -1.3, 0.0), (-1.1, 0.6, 0.42), cloth)
    box("sofa_back", (-1.95, -1.3, 0.42), (-1.75, 0.6, 0.85), cloth)
    box("sofa_arm", (-1.95, 0.45, 0.42), (-1.1, 0.6, 0.6), cloth)
    box("shelf", (0.4, 1.15, 0.0), (1.6, 1.45, 1.8), pale)
    box("shelf_board", (0.42, 1.1, 0.9), (1.58, 1.15, 0.93), pale)
    demo_blend.add_light(scene, "AREA", "lamp", power=60.0, location=(0.3, 0.0, 2.45))
    for ob in scene.objects:
        if ob.type == "MESH" and ob.data.materials[0].users > 1:
            ob.data.materials[0] = ob.data.materials[0].copy()
    scenes._finish_common(scene, width, height)
    cam = scene.camera
    path = (((-1.4, -1.35, 1.35), (math.radians(80.0), 0.0, math.radians(-35.0))),
            ((1.5, -1.35, 1.2), (math.radians(78.0), 0.0, math.radians(30.0))))
    for frame, (loc, rot) in zip((1, frames), path):
        cam.location, cam.rotation_euler = loc, rot
        cam.keyframe_insert("location", frame=frame)
        cam.keyframe_insert("rotation_euler", frame=frame)
    for fc in cam.animation_data.action.fcurves if hasattr(cam.animation_data.action, "fcurves") else ():
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"
    scene.frame_start, scene.frame_end = 1, frames
    return scene


def scored_frames(frames):
    return sorted({1, frames, *range(10, frames, 10)})


def references(scene, frames, spp, log):
    """{frame: (A, B)} two-half Cycles references of the scored frames, cached."""
    key = scenes.scene_hash((bpy.app.version_string, methods.MAX_BOUNCES, "flythrough", spp, frames))
    path = CACHE / f"flythrough_{key}.npz"
    if path.exists():
        with np.load(path) as z:
            return {f: (z[f"A{f}"], z[f"B{f}"]) for f in scored_frames(frames)}, "cache"
    out, arrays = {}, {}
    for f in scored_frames(frames):
        scene.frame_set(f)
        halves = []
        for seed in (1001, 2002):
            with quiet():
                img, t = methods.cycles_render(spp, seed)
            halves.append(img)
        log(f"  reference frame {f}: 2 x {spp} spp, {t:.1f} s each")
        out[f] = tuple(halves)
        arrays[f"A{f}"], arrays[f"B{f}"] = halves
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return out, "made"


def configure(scene, photons, samples, gather_rays, cache=False):
    pl = scene.photon_lightmaps
    pl.photons, pl.samples, pl.gather_rays, pl.seed, pl.indirect = photons, samples, gather_rays, 1, "GATHER"
    pl.irradiance_cache = cache
    pl.max_bounces = methods.MAX_BOUNCES


def ours(scene, frames, refs, photons, samples, gather_rays, cache=False):
    """The CLI's frame loop -> dict with total seconds and mean per-frame error.
    cache: the final gather through the irradiance cache (its records made with frame 1's light)."""
    configure(scene, photons, samples, gather_rays, cache)
    with tempfile.TemporaryDirectory() as tmp:
        with quiet():      # kernels compiled or loaded outside the timing (a first run's cost)
            scene.frame_set(1)
            headless.render_to_file(scene, pathlib.Path(tmp) / "warm.exr")
        render_engine.LIGHT.clear()
        t0 = time.perf_counter()
        with quiet():
            report = headless._render_frames(scene, pathlib.Path(tmp) / "f_###.exr", (1, frames))
        total = time.perf_counter() - t0
        errs = {f: Scorer(*refs[f])(methods.read_rgb(pathlib.Path(tmp) / f"f_{f:03d}.exr"))["rel_rmse"] for f in refs}
    per = [r["seconds"]["total"] for r in report["frames"]]
    return dict(photons=photons, samples=samples, gather_rays=gather_rays, irradiance_cache=cache, seconds=total,
                first_frame_seconds=per[0], later_frame_seconds=float(np.mean(per[1:])) if len(per) > 1 else 0.0,
                frames_reusing_light=report["frames_reusing_light"],
                rel_rmse=float(np.mean(list(errs.values()))), per_frame=errs)


def ours_without_reuse(scene, frames, refs, photons, samples, gather_rays):
    """The scored frames with the light let go between them -> per-frame mean x frames."""
    configure(scene, photons, samples, gather_rays)
    secs = []
    with tempfile.TemporaryDirectory() as tmp:
        for f in refs:
            scene.frame_set(f)
            render_engine.LIGHT.clear()
            t0 = time.perf_counter()
            with quiet():
                headless.render_to_file(scene, pathlib.Path(tmp) / "one.exr")
            secs.append(time.perf_counter() - t0)
    return dict(photons=photons, samples=samples, gather_rays=gather_rays,
                seconds=float(np.mean(secs)) * frames, frame_seconds=float(np.mean(secs)))


def cycles(scene, frames, refs, spps):
    rows = []
    for spp in spps:
        secs, errs = [], []
        for f in refs:
            scene.frame_set(f)
            with quiet():
                img, t = methods.cycles_render(spp, 7)
            secs.append(t)
            errs.append(Scorer(*refs[f])(img)["rel_rmse"])
        rows.append(dict(samples=spp, frame_seconds=float(np.mean(secs)), seconds=float(np.mean(secs)) * frames,
                         rel_rmse=float(np.mean(errs))))
    return rows


def chart(result, path):
    """Mean per-frame error against the time for all frames: ours (light reused),
    ours with the light traced for every frame, and Cycles."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4))
    for cache, style, label in ((False, "P-", "ours, light of frame 1 reused"),
                                (True, "*-", "ours, + irradiance cache")):
        pts = sorted((r for r in result["ours"] if r.get("irradiance_cache", False) == cache),
                     key=lambda r: r["seconds"])
        if pts:
            ax.plot([r["seconds"] for r in pts], [r["rel_rmse"] for r in pts], style,
                    color="C8" if cache else "C4", label=label)
    ours = [r for r in result["ours"] if not r.get("irradiance_cache", False)]
    for r in result["ours_without_reuse"]:
        match = next((o for o in ours if (o["photons"], o["samples"], o["gather_rays"]) ==
                      (r["photons"], r["samples"], r["gather_rays"])), None)
        if match:
            ax.plot([r["seconds"]], [match["rel_rmse"]], "P", mfc="none", color="C4",
                    label="ours, photon pass every frame")
    cyc = result["cycles"]
    ax.plot([r["seconds"] for r in cyc], [r["rel_rmse"] for r in cyc], "^-", color="C3", label="Cycles")
    for r in cyc:
        ax.annotate(f"{r['samples']} spp", (r["seconds"], r["rel_rmse"]), fontsize=7, xytext=(3, 3),
                    textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(f"seconds for {result['frames']} frames ({result['size'][0]}x{result['size'][1]}, 2 cores)")
    ax.set_ylabel("mean per-frame relative RMSE")
    ax.set_title("camera fly-through of a furnished room")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=72)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--size", type=headless._size, default=(96, 64))
    ap.add_argument("--quick", action="store_true", help="12 frames, 48x32, small sweeps (a smoke run)")
    args = ap.parse_args(argv)
    frames, (w, h) = (12, (48, 32)) if args.quick else (args.frames, args.size)
    ref_spp = 64 if args.quick else 1024
    cyc_spps = (4, 16) if args.quick else (16, 32, 64, 128, 256)
    ours_cfgs = ((20_000, 2, 4, False), (20_000, 2, 4, True)) if args.quick else (
        (300_000, 8, 8, False), (1_000_000, 16, 8, False), (1_000_000, 32, 16, False),
        (300_000, 8, 8, True), (1_000_000, 16, 8, True), (1_000_000, 32, 16, True), (1_000_000, 64, 16, True))

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    if not registration.is_registered():
        registration.ensure_registered()
    scene = build_furnished(w, h, frames)
    t0 = time.perf_counter()
    refs, src = references(scene, frames, ref_spp, log)
    log(f"references ({src}) in {time.perf_counter() - t0:.0f} s")
    out = {"frames": frames, "size": [w, h], "scored_frames": list(refs), "reference_spp": ref_spp,
           "ours": [], "ours_without_reuse": [], "cycles": []}
    for photons, spp, rays, cache in ours_cfgs:
        r = ours(scene, frames, refs, photons, spp, rays, cache)
        log(f"ours {photons:,} photons {spp} spp {rays} rays{' cache' if cache else ''}: {r['seconds']:.1f} s, "
            f"relRMSE {r['rel_rmse']:.4f}")
        out["ours"].append(r)
    photons, spp, rays, _ = ours_cfgs[0 if args.quick else 1]
    out["ours_without_reuse"].append(ours_without_reuse(scene, frames, refs, photons, spp, rays))
    out["cycles"] = cycles(scene, frames, refs, cyc_spps)
    for r in out["cycles"]:
        log(f"cycles {r['samples']} spp: {r['seconds']:.1f} s, relRMSE {r['rel_rmse']:.4f}")
    cyc = out["cycles"]
    for r in out["ours"]:
        t_cyc, extra = loglog_interp([c["seconds"] for c in cyc], [c["rel_rmse"] for c in cyc], r["rel_rmse"])
        r.update(cycles_seconds_at_equal_error=t_cyc, extrapolated=extra, ratio=t_cyc / r["seconds"])
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "flythrough.json").write_text(json.dumps(out, indent=2))
    if not args.quick:
        CHARTS.mkdir(parents=True, exist_ok=True)
        chart(out, CHARTS / "flythrough.png")
        (CHARTS / "flythrough.json").write_text(json.dumps(out, indent=2))
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
