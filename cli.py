"""Command line for the bpy-module world: `python -m photon_lightmaps {demo,render,bake,bake-ol,lsystem}`.

The one command-line module: it parses arguments (so `--help` works without
importing Blender; each command imports bpy itself), runs the command and turns whatever a
command raises into what the user sees (messages.py): a user error is one
line "error: <culprit>: <what to do>" and exit code 2, a bug is one line
"error: internal error: ..." and exit code 1; `--debug` adds the traceback.
"""
import argparse
import json
import math
import os
import pathlib
import re
import sys
import time

from .registration import ensure_registered

# Commands import bpy, numba and the add-on's packages themselves: --help needs none of them.


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        # argparse prints usage plus "prog: error: argument --x: ..."; the user gets one line.
        if message.startswith("argument "):
            message = message[len("argument "):]
        sys.stderr.write(f"error: {message} (see {self.prog} --help)\n")
        sys.exit(2)


def _count(least, most=2 ** 31 - 1):
    # Blender's IntProperty holds 32 bits: a larger value would fail only after the file is loaded.
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not least <= value <= most:
            raise argparse.ArgumentTypeError(f"must be a whole number from {least} to {most:,}, got '{text}'")
        return value
    parse.__name__ = f"count >= {least}"
    return parse


def _open_interval(below, above, what):
    """A float strictly between `below` and `above`; `what` says so in the error."""
    def parse(text):
        try:
            value = float(text)
        except ValueError:
            value = float("nan")            # fails the range test below, NaN included
        if not below < value < above:
            raise argparse.ArgumentTypeError(f"must be {what}, got '{text}'")
        return value
    parse.__name__ = what
    return parse


# a relative error (0.01 is 1 %) and a time budget
_fraction = _open_interval(0.0, 1.0, "a fraction above 0 and below 1 (0.01 is 1 %)")
_seconds = _open_interval(0.0, 1e6, "a number of seconds above 0")
_metres = _open_interval(0.0, 1e6, "a distance in metres above 0")
_degrees = _open_interval(-360.0, 360.0, "an angle in degrees between -360 and 360")


def _polarizer_angle(text):
    """A filter angle in degrees, or 'off'."""
    return "off" if text.strip().lower() == "off" else _degrees(text)


def _size(text):
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        w = h = 0
    if not (1 <= w <= 16384 and 1 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"must be WIDTHxHEIGHT in pixels (e.g. 640x480), got '{text}'")
    return w, h


MAX_FRAME = 1_048_574      # Blender's last frame (MAXFRAME)


def _frames(text):
    """'A-B' or 'A..B' (Blender's -f form, which allows negative frames), or one frame 'A'."""
    m = re.fullmatch(r"\s*(-?\d+)\s*(?:(?:\.\.|-)\s*(-?\d+))?\s*", text)
    a, b = (int(m.group(1)), int(m.group(2) if m.group(2) is not None else m.group(1))) if m else (1, 0)
    if not (m and -MAX_FRAME <= a <= b <= MAX_FRAME):
        raise argparse.ArgumentTypeError(f"must be FIRST-LAST frames (e.g. 1-60, or -5..5), first <= last, "
                                         f"within ±{MAX_FRAME:,}; got '{text}'")
    return a, b


def frame_path(path, frame):
    """The output of one frame: a run of '#' in the name becomes the frame number,
    zero-padded to its length (as in Blender's output path); without one,
    '_####' goes before the extension."""
    p = pathlib.Path(path)
    name = p.name if "#" in p.name else f"{p.stem}_####{p.suffix}"
    m = re.search(r"#+", name)
    digits = f"{abs(frame):0{len(m.group(0))}d}"
    return p.with_name(name[:m.start()] + ("-" if frame < 0 else "") + digits + name[m.end():])


def _add_common(p):
    p.add_argument("--photons", type=_count(0), default=None, help="photons to shoot (default: scene setting)")
    p.add_argument("--seed", type=_count(0), default=None, help="random seed (default: scene setting)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--cluster", metavar="ADDRESS", default=None,
                       help="run the photon pass, render tiles and bake gathers on the Dask cluster whose scheduler "
                            "is at ADDRESS (tcp://host:8786); the result is the same, bit for bit "
                            "(default: scene setting)")
    where.add_argument("--workers", type=_count(1, 256), default=None,
                       help="run them on N worker processes on this machine (a local Dask cluster)")
    p.add_argument("--json", metavar="REPORT", default=None, help="write a JSON report here")
    # Also accepted after the command; SUPPRESS keeps a global --debug from being reset.
    p.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)


def _add_denoise(p):
    # --denoise / --no-denoise; neither keeps the scene's setting.
    p.add_argument("--denoise", action=argparse.BooleanOptionalAction, default=None,
                   help="OIDN denoising pass (needs the pyoidn package; default: scene setting)")
    p.add_argument("--spectral", action=argparse.BooleanOptionalAction, default=None,
                   help="trace 16 wavelength bands instead of RGB; results come back as RGB "
                        "(default: scene setting)")


def build_parser():
    p = _Parser(
        prog="python -m photon_lightmaps",
        description="Photon Lightmaps: lightmap-based photon tracing (Wilkie 2001) for Blender files.")
    p.add_argument("--debug", action="store_true",
                   help="print the traceback of an error (for bug reports)")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)

    d = sub.add_parser("demo", help="render and bake the built-in demo scene")
    d.add_argument("--out", default="out/demo", help="output folder")
    _add_common(d)
    d.add_argument("--samples", type=_count(1), default=None, help="pixel samples of the render")
    d.add_argument("--size", type=_size, default=(256, 256), metavar="WxH", help="render size")
    d.add_argument("--denoise", action="store_true", help="denoise the render (OIDN, pyoidn)")
    d.set_defaults(func=demo_main)

    r = sub.add_parser("render", help="render a .blend with the Photon Lightmaps engine")
    r.add_argument("blend", metavar="FILE.blend")
    r.add_argument("--out", required=True, metavar="IMG", help="output image (.png or .exr)")
    _add_common(r)
    r.add_argument("--samples", type=_count(1), default=None, help="pixel samples")
    r.add_argument("--indirect", choices=("gather", "lookup"), default=None,
                   help="indirect light by final gather or by the hit's own lightmap")
    r.add_argument("--gather-rays", type=_count(1), default=None, help="final-gather rays per sample")
    r.add_argument("--irradiance-cache", action=argparse.BooleanOptionalAction, default=None,
                   help="final gather through a sparse irradiance cache, made once per photon pass "
                        "(default: scene setting)")
    r.add_argument("--frames", type=_frames, default=None, metavar="A-B",
                   help="render frames A to B (one image each: a run of '#' in --out is the frame "
                        "number, else _#### goes before the extension); where only the camera moves, "
                        "the first frame's photon pass is reused")
    r.add_argument("--polarizer", type=_polarizer_angle, default=None, metavar="DEGREES",
                   help="put the camera's polarizing filter in at this angle (from the image's horizontal "
                        "toward its vertical: 90 takes the glare off level water), or 'off'; "
                        "default: the camera's setting")
    r.add_argument("--polarization", action=argparse.BooleanOptionalAction, default=None,
                   help="camera paths carry polarization through smooth glass and coats (the camera's "
                        "polarizing filter traces it either way; default: scene setting)")
    _add_denoise(r)
    r.set_defaults(func=render_main)

    b = sub.add_parser("bake", help="bake photon lightmaps of a .blend to OpenEXR images")
    b.add_argument("blend", metavar="FILE.blend")
    b.add_argument("--out", required=True, metavar="DIR", help="folder for <object name>.exr")
    _add_common(b)
    b.add_argument("--resolution", type=_count(1), default=None, metavar="R", help="force R x R lightmaps")
    b.add_argument("--indirect-only", action="store_true", help="leave direct light out of the maps")
    b.add_argument("--pass", dest="bake_pass", choices=("combined", "direct", "indirect", "ao", "shadowmask"),
                   default=None,
                   help="what the maps hold: all light (default), direct or indirect light alone (indirect: "
                        "as --indirect-only), ambient occlusion (see --ao-distance), or a shadowmask (see "
                        "--shadowmask-lights); ao and shadowmask trace no photons")
    b.add_argument("--ao-distance", type=_metres, default=None, metavar="M",
                   help="--pass ao: rays that meet nothing within M metres are unoccluded (default 1)")
    b.add_argument("--pass-rays", type=_count(1, 65536), default=None, metavar="N",
                   help="--pass ao and shadowmask: rays (light samples) per point, 16 points a texel "
                        "(default 16): noise falls as 1/sqrt(N)")
    b.add_argument("--texel-validity", action="store_true",
                   help="fill texels that lie inside geometry (most of their rays meet back faces) from their "
                        "neighbours, count them in the JSON report, and write DIR/<object>_validity.exr (R: "
                        "the share of rays meeting back faces; invalid texels red, valid ones green)")
    b.add_argument("--directional", nargs="?", const="dominant", choices=("dominant", "sh"),
                   help="also bake which way each texel's light comes from, so normal maps show under baked "
                        "light: 'dominant' (the default) writes DIR/<object>_direction.exr (RGB: the distant "
                        "light's share times its direction, world space); 'sh' writes first-order spherical "
                        "harmonics per colour, DIR/<object>_l1x.exr, _l1y.exr, _l1z.exr (RGB: that axis's "
                        "coefficient; L0 = lightmap - L1 . normal)")
    b.add_argument("--stitch-seams", action="store_true",
                   help="make texels that meet across UV seams and edges objects share agree where they meet "
                        "(smooth edges; a crease keeps its jump); the JSON reports the jump along the seams "
                        "before and after")
    b.add_argument("--shadowmask-lights", metavar="NAMES", default=None,
                   help="--pass shadowmask: up to four lights, comma-separated, for channels R, G, B, A "
                        "(default: every light, when there are at most four)")
    b.add_argument("--objects", metavar="NAMES", default=None,
                   help="bake only these objects (comma-separated); the other objects' files in DIR stay "
                        "as they are")
    b.add_argument("--light-cache", metavar="DIR", default=None,
                   help="a folder of saved photon passes: a pass saved there for this scene and these photon "
                        "settings is reused (a rebake of some objects skips the photon pass), and one traced "
                        "is saved there")
    b.add_argument("--indirect", choices=("gather", "lookup"), default=None,
                   help="indirect light by final gather over the photon lightmaps or from each texel's photons")
    b.add_argument("--direct-samples", type=_count(1), default=None, metavar="N",
                   help="light samples per texel for its direct light (default: the scene's Bake Direct "
                        "Samples, 64): noise falls about as 1/sqrt(N)")
    b.add_argument("--bake-gather-rays", type=_count(1), default=None, metavar="N",
                   help="final-gather rays per texel and lit side")
    b.add_argument("--target-error", type=_fraction, default=None, metavar="E",
                   help="texels whose estimated relative error is above E (e.g. 0.01) get more "
                        "gather rays, up to the scene's Bake Max Rays; the JSON reports each object's error")
    b.add_argument("--time", type=_seconds, default=None, metavar="S",
                   help="bake in about S seconds: after one pass of gather rays everywhere, the time "
                        "left goes to the texels with the highest estimated error")
    b.add_argument("--irradiance-cache", action=argparse.BooleanOptionalAction, default=None,
                   help="gather mesh texels through a sparse irradiance cache (fewer rays, lower "
                        "error; default: the scene's Bake Irradiance Cache, on)")
    b.add_argument("--gather-lights", action=argparse.BooleanOptionalAction, default=None,
                   help="gather rays sample point, spot and sun lights where they land, so light one "
                        "bounce away is as sharp as the light (default: the scene's Bake Gather Lights)")
    b.add_argument("--error-images", action="store_true",
                   help="also write DIR/<object>_error.exr: each texel's estimated relative error "
                        "(gathered bakes)")
    b.add_argument("--spectral-exr", action="store_true",
                   help="with --spectral (or the scene's Spectral): also write DIR/<object>_spectral.exr, "
                        "every wavelength band as a channel (the spectral OpenEXR layout)")
    _add_denoise(b)
    b.set_defaults(func=bake_main)

    o = sub.add_parser("bake-ol", help="bake the orientation lightmaps of a .blend to OpenEXR images")
    o.add_argument("blend", metavar="FILE.blend")
    o.add_argument("--out", required=True, metavar="DIR", help="folder for <empty name>.exr")
    _add_common(o)
    o.set_defaults(func=ol_bake_main)

    w = sub.add_parser("warmup", help="compile the kernels renders and bakes need, so the first one "
                                      "starts at once (takes minutes once; cached afterwards)")
    w.add_argument("--json", metavar="REPORT", default=None, help="write a JSON report here")
    w.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    w.set_defaults(func=warmup_main)

    g = sub.add_parser("export-gltf", help="write a .blend's scene as glTF 2.0 with its baked lightmaps "
                                           "(MOZ_lightmap, through Blender's glTF exporter)")
    g.add_argument("blend", metavar="FILE.blend")
    g.add_argument("out", metavar="OUT.glb", help="the file to write (.glb, or .gltf with a .bin beside it)")
    g.add_argument("--encoding", choices=("rgbm", "exr"), default="rgbm",
                   help="rgbm: 8-bit RGBM PNGs inside the file (default); exr: float OpenEXR files beside it")
    g.add_argument("--bake", action="store_true",
                   help="bake every mesh object first, with the scene's settings (--photons, --seed)")
    g.add_argument("--resolution", type=_count(1), default=None, metavar="R", help="with --bake: R x R lightmaps")
    _add_common(g)
    g.set_defaults(func=export_gltf_main)

    wk = sub.add_parser("worker", help="run a Dask worker for photon passes, renders and bakes (--cluster): it "
                                       "joins the scheduler at ADDRESS and runs until stopped")
    wk.add_argument("scheduler", metavar="ADDRESS", help="the scheduler's address, e.g. tcp://host:8786")
    wk.add_argument("--nthreads", type=_count(1, 1024), default=None,
                    help="threads of the worker (default: this machine's cores)")
    wk.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    wk.set_defaults(func=worker_main)

    ls = sub.add_parser("lsystem", help="count an L-system grammar file through its scene graph (JSON)")
    ls.add_argument("grammar", metavar="FILE", help="grammar text (see docs/lsystems.md)")
    ls.add_argument("--json", metavar="REPORT", nargs="?", const="-", default="-",
                    help="write the JSON report here (default: standard output)")
    ls.add_argument("--string", action="store_true", help="include the derived string")
    ls.add_argument("--steps", type=_count(0), default=None, help="derivation length (default: the grammar's)")
    ls.add_argument("--render", metavar="IMG", default=None,
                    help="also render it through its scene graph in a default studio (.png or .exr)")
    ls.add_argument("--photons", type=_count(0), default=200_000, help="photons for --render")
    ls.add_argument("--samples", type=_count(1), default=4, help="pixel samples for --render")
    ls.add_argument("--size", type=_size, default=(320, 320), metavar="WxH", help="image size for --render")
    ls.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    ls.set_defaults(func=lsystem_main)
    return p


class _LineTracker:
    """sys.stderr that remembers whether its last write ended a line (progress uses "\\r")."""

    def __init__(self, stream):
        self._stream = stream
        self.at_line_start = True
        self.transient = False      # the last line is the compile line: end it before other output

    def write(self, s):
        if s and self.transient:
            self._stream.write("\n")
            self.transient = False
        if s:
            self.at_line_start = s.endswith("\n")
        return self._stream.write(s)

    def write_transient(self, s):
        self._stream.write(s)
        self._stream.flush()
        self.transient, self.at_line_start = True, False

    def __getattr__(self, name):
        return getattr(self._stream, name)


def progress_line(label, stream=None, clock=time.perf_counter):
    """A progress(done, total) callback that redraws one line of `stream` (stderr):
    "photons 131,072/1,000,000  13 %  210,000/s  ETA 4 s", rewritten with a carriage
    return so a run's log holds one line per phase, not one per update."""
    t0 = clock()
    width = [0]

    def progress(done, total):
        out = stream or sys.stderr
        dt = max(clock() - t0, 1e-9)
        rate = done / dt
        eta = f"ETA {(total - done) / rate:,.0f} s" if 0 < done < total else f"{dt:,.1f} s"
        pct = 100.0 * done / total if total > 0 else 100.0
        text = f"{label} {done:,}/{total:,}  {pct:3.0f} %  {rate:,.0f}/s  {eta}"
        # spaces over what a longer previous line left (no terminal escapes: logs stay plain)
        out.write("\r" + text.ljust(width[0]))
        width[0] = len(text)
        out.flush()
        return True
    return progress


# --------------------------------------------------------------------------------------
# Commands
# --------------------------------------------------------------------------------------

FORMATS = {".png": "PNG", ".exr": "OPEN_EXR"}


def check_format(path):
    from .messages import InputError
    ext = pathlib.Path(path).suffix.lower()
    if ext not in FORMATS:
        raise InputError(f"--out '{path}': the image must end in .png or .exr")
    return ext


def configure_output(scene, path):
    """Output format from the file extension; 8-bit PNG through the 'Standard' view
    transform (no tone curve), or 32-bit float linear OpenEXR."""
    ext = check_format(path)
    im = scene.render.image_settings
    im.file_format = FORMATS[ext]
    if ext == ".png":
        im.color_mode = "RGBA"
        im.color_depth = "8"
        vs = scene.view_settings
        vs.view_transform = "Standard"
        vs.look = "None"
        vs.exposure = 0.0
        vs.gamma = 1.0
    else:
        im.color_mode = "RGBA"
        im.color_depth = "32"


def open_blend(path):
    """Opens a .blend for a command; a missing or unreadable file is an InputError."""
    import bpy

    from .messages import InputError
    path = pathlib.Path(path).resolve()
    if not path.is_file():
        raise InputError(f"{path}: no such .blend file (check the path)")
    try:
        bpy.ops.wm.open_mainfile(filepath=str(path), load_ui=False)
    except RuntimeError as exc:
        # Blender's message holds the reason (not a .blend, truncated, newer version).
        raise InputError(f"{path}: cannot open it as a .blend file: {exc}") from None
    return path


def render_to_file(scene, out_path):
    """Renders `scene` with this engine and writes the image; returns the RenderRun.

    Raises what the engine's render() kept in bake/render.LAST_ERROR: Blender only
    prints an exception raised inside a RenderEngine, the caller would never see it.
    """
    import bpy
    from .bake import render as render_engine
    from .operators.render_engine import ENGINE_ID
    scene.render.engine = ENGINE_ID
    configure_output(scene, out_path)
    render_engine.LAST_RUN = render_engine.LAST_ERROR = None
    render_engine.PRINT_ERRORS = False    # we raise it again below, to be reported once
    try:
        bpy.ops.render.render(write_still=False, scene=scene.name)
    finally:
        render_engine.PRINT_ERRORS = True
    if render_engine.LAST_ERROR is not None:
        raise render_engine.LAST_ERROR
    run = render_engine.LAST_RUN
    if run is None or run.image is None:
        raise RuntimeError("the render did not finish" + (" (cancelled)" if run is not None and run.cancelled else ""))
    t0 = time.perf_counter()
    pathlib.Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    bpy.data.images["Render Result"].save_render(filepath=str(out_path), scene=scene)
    run.seconds["save"] = time.perf_counter() - t0
    return run


def render_main(args):
    from .messages import InputError
    from .operators.render_engine import ENGINE_ID
    t0 = time.perf_counter()
    out = pathlib.Path(args.out).resolve()
    check_format(args.out)      # before the (slow) load
    ensure_registered()
    blend = open_blend(args.blend)
    _use_cluster(args)
    import bpy
    scene = bpy.context.scene
    if scene.camera is None:
        raise InputError(f"scene '{scene.name}': no camera; add one and set it as the scene camera "
                         "(Scene Properties > Camera)")
    settings = scene.photon_lightmaps
    for name in ("photons", "samples", "seed", "gather_rays", "denoise", "irradiance_cache", "spectral",
                 "polarization"):
        value = getattr(args, name, None)
        if value is not None:
            setattr(settings, name, value)
    if getattr(args, "indirect", None):
        settings.indirect = args.indirect.upper()
    if getattr(args, "polarizer", None) is not None:
        cam_settings = scene.camera.data.photon_lightmaps
        cam_settings.use_polarizer = args.polarizer != "off"
        if args.polarizer != "off":
            cam_settings.polarizer_angle = math.radians(args.polarizer)
    t_load = time.perf_counter()
    used = {k: getattr(settings, k) for k in ("photons", "max_bounces", "texel_density", "reconstruction",
                                              "samples", "seed", "indirect", "gather_rays", "denoise",
                                              "irradiance_cache", "spectral", "polarization", "cluster")}
    cam_settings = getattr(scene.camera.data, "photon_lightmaps", None)
    used["polarizer"] = (round(math.degrees(cam_settings.polarizer_angle), 3)
                         if cam_settings is not None and cam_settings.use_polarizer else None)
    if args.frames is not None:
        report = _render_frames(scene, out, args.frames)
    else:
        run = render_to_file(scene, out)
        report = run.as_dict()
        report["image"] = str(out)
        report["seconds"]["pipeline"] = run.seconds["total"]
        _print_run(out, run)
    t_end = time.perf_counter()
    report.update(blend=str(blend), engine=ENGINE_ID, settings=used)
    # "total" is the whole command (load, render, save); "pipeline" is export to last tile.
    report["seconds"].update(load=t_load - t0, total=t_end - t0)
    report["kernels"] = kernels_report()
    if args.frames is not None:
        print(f"{len(report['frames'])} frames, {report['frames_reusing_light']} of them on the first's light, "
              f"total {t_end - t0:.2f} s")
    else:
        print(f"  total {t_end - t0:.2f} s")
    if args.json:
        write_report(args.json, json.dumps(report, indent=2))
    return 0


def export_gltf_main(args):
    """CLI: a .blend's scene as glTF with its baked lightmaps; --bake bakes them first."""
    import bpy

    from .bake import bake_objects, gltf_export
    t0 = time.perf_counter()
    ensure_registered()
    blend = open_blend(args.blend)
    _use_cluster(args)
    context = bpy.context
    baked = None
    if args.bake:
        objects = [ob for ob in context.scene.objects if ob.type == "MESH"]
        res = bake_objects(context, objects, photons=args.photons, seed=args.seed, resolution=args.resolution,
                           overwrite=True, pack=True)
        baked = sorted(res.maps)
    out = gltf_export.export_gltf(context, args.out, encoding=args.encoding)
    report = {"blend": str(blend), "baked": baked, **out, "seconds": time.perf_counter() - t0}
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text)
    return 0


def worker_main(args):
    """CLI: a Dask worker process for photon passes, renders and bakes (engine/cluster.py)."""
    from .engine.cluster import run_worker
    run_worker(args.scheduler, nthreads=args.nthreads)
    return 0


def _use_cluster(args):
    """--cluster ADDRESS or --workers N onto the scene's Cluster setting, which passes read."""
    import bpy
    spec = args.cluster or (f"local:{args.workers}" if getattr(args, "workers", None) else None)
    if spec is not None:
        bpy.context.scene.photon_lightmaps.cluster = spec


def _print_run(out, run):
    how = (f"light of frame {run.light_from_frame} reused" if run.light_from_frame is not None else
           f"{run.photons:,} photons in {run.seconds['photon_pass']:.2f} s")
    print(f"{out}: {run.width}x{run.height}, {how}, render {run.seconds['render']:.2f} s")
    for ol in run.orientation_lightmaps:
        print(f"  orientation lightmap '{ol['name']}': {ol['photons']:,} photons, "
              f"{ol['memory_bytes'] / 1024:.1f} KiB, area {ol['area']:.4g} m², {len(ol['warnings'])} warnings")


def _render_frames(scene, out, frames):
    """Renders frames first..last to frame_path(out, f), keeping the traced light
    from frame to frame (a frame where more than the camera moved traces its own).
    -> the report: one entry per frame, and the seconds summed over them."""
    from .bake import render as render_engine
    first, last = frames
    rows = []
    seconds = {}
    with render_engine.LIGHT.held():
        for f in range(first, last + 1):
            scene.frame_set(f)
            path = frame_path(out, f)
            run = render_to_file(scene, path)
            _print_run(path, run)
            row = run.as_dict()
            row.update(frame=f, image=str(path))
            rows.append(row)
            for k, v in run.seconds.items():
                seconds[k] = seconds.get(k, 0.0) + v
    seconds["pipeline"] = seconds.pop("total", 0.0)
    return {"frames": rows, "seconds": seconds,
            "frames_reusing_light": sum(r["light_from_frame"] is not None for r in rows)}


def bake_main(args):
    """CLI: bakes every mesh object of a .blend (excluded ones skipped) to DIR/<object>.exr."""
    import bpy

    from .bake import bake_objects, check_writable
    from .bake.render import peak_rss_bytes
    from .engine.session import Settings
    t0 = time.perf_counter()
    ensure_registered()
    blend = open_blend(args.blend)
    _use_cluster(args)
    context = bpy.context
    settings = Settings.read(context.scene.photon_lightmaps, photons=args.photons, seed=args.seed,
                             denoise=getattr(args, "denoise", None), spectral=getattr(args, "spectral", None),
                             indirect=args.indirect.upper() if args.indirect else None,
                             bake_gather_rays=args.bake_gather_rays, bake_direct_samples=args.direct_samples,
                             bake_target_error=args.target_error, bake_time=args.time,
                             bake_irradiance_cache=args.irradiance_cache,
                             bake_gather_lights=args.gather_lights)
    if args.spectral is not None:
        context.scene.photon_lightmaps.spectral = bool(args.spectral)   # the bake reads the scene's setting
    photons = settings.photons if args.photons is not None else settings.bake_photon_count
    seed = settings.seed
    objects = _bake_selection(context.scene, args.objects)
    out_dir = os.path.abspath(args.out)
    check_writable(out_dir)
    light_cache = os.path.abspath(args.light_cache) if args.light_cache else None
    if light_cache:
        check_writable(light_cache, "the photon pass (--light-cache)")

    progress = progress_line("photons")

    res = bake_objects(context, objects, photons=photons, seed=seed, resolution=args.resolution,
                       indirect_only=args.indirect_only, progress=progress, save_dir=out_dir,
                       overwrite=True, denoise=settings.denoise, indirect=settings.indirect,
                       bake_gather_rays=settings.bake_gather_rays,
                       bake_target_error=settings.bake_target_error, bake_time=settings.bake_time,
                       error_images=args.error_images or None,
                       irradiance_cache=settings.bake_irradiance_cache,
                       gather_lights=settings.bake_gather_lights, spectral_exr=args.spectral_exr or None,
                       bake_pass=args.bake_pass, ao_distance=args.ao_distance,
                       shadowmask_lights=args.shadowmask_lights, texel_validity=args.texel_validity or None,
                       pass_rays=args.pass_rays, light_cache=light_cache, stitch_seams=args.stitch_seams or None,
                       direct_samples=settings.bake_direct_samples, directional=args.directional or None,
                       # this process does not save the .blend: every mesh gets the Lightmap UVs
                       # the full bake gave it, so its saved photon pass serves this one
                       lay_out=[ob for ob in context.scene.objects if ob.type == "MESH"] if args.objects else ())
    print(file=sys.stderr)
    stats = res.stats
    report = {
        "blend": str(blend),
        "photons": int(stats.photons) if stats else 0,
        "rays": int(stats.rays) if stats else 0,
        "photons_aimed_at": stats.as_dict()["aimed_at"] if stats else None,
        "seconds": {"photon_pass": res.seconds.get("photon_pass", 0.0),
                    "direct": res.seconds.get("direct", 0.0),
                    "gather": res.seconds.get("gather", 0.0),
                    "ao": res.seconds.get("ao", 0.0),
                    "shadowmask": res.seconds.get("shadowmask", 0.0),
                    "validity": res.seconds.get("validity", 0.0),
                    "seams": res.seconds.get("seams", 0.0),
                    "direction": res.seconds.get("direction", 0.0),
                    "bake": res.seconds.get("bake", 0.0),
                    "denoise": res.seconds.get("denoise", 0.0),
                    "total": time.perf_counter() - t0},
        "denoised": bool(settings.denoise),
        "indirect": "gather" if settings.bake_gathers else "lookup",
        "bake_gather_rays": int(settings.bake_gather_rays) if settings.bake_gathers else 0,
        "direct_samples": int(settings.bake_direct_samples),
        "pass": res.bake_pass,
        "shadowmask_lights": res.mask_lights,
        "pass_rays": int(res.pass_rays) if res.pass_rays else None,
        "texel_validity": res.validity,
        "light_reuse": res.light_reuse,
        "seams": res.seams,
        "directional": res.directional,
        "irradiance_cache": res.irradiance_cache,
        "cluster": res.cluster,
        "target_error": float(settings.bake_target_error) if settings.bake_gathers else 0.0,
        "time_budget": float(settings.bake_time) if settings.bake_gathers else 0.0,
        "objects": {name: {"path": res.paths[name], "width": bm.width, "height": bm.height,
                           "bytes": os.path.getsize(res.paths[name]), "mean": bm.mean(),
                           **({"error": res.error[name]} if name in res.error else {}),
                           **({"error_image": res.error_paths[name]} if name in res.error_paths else {}),
                           **({"validity_image": res.validity_paths[name]} if name in res.validity_paths else {}),
                           **({"direction_image": res.direction_paths[name]} if name in res.direction_paths else {}),
                           **({"l1_images": [res.l1_paths[a][name] for a in "xyz"]}
                              if name in res.l1_paths["x"] else {}),
                           **({"spectral_exr": res.spectral_paths[name]} if name in res.spectral_paths else {})}
                    for name, bm in res.maps.items()},
        "skipped": res.skipped,
        "warnings": res.warnings,
        "memory": {"lightmap_bytes": res.lightmap_bytes, "peak_rss_bytes": peak_rss_bytes()},
        "kernels": kernels_report(),
    }
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text)
    return 0


def _bake_selection(scene, names):
    """The objects `bake` bakes: every mesh, or the ones named (comma-separated);
    an unknown name is the user's to fix (InputError: exit code 2)."""
    from .messages import InputError
    if names is None:
        return [ob for ob in scene.objects if ob.type == "MESH"]
    chosen = [n.strip() for n in names.split(",") if n.strip()]
    by_name = {ob.name: ob for ob in scene.objects}
    missing = [n for n in chosen if n not in by_name]
    if missing or not chosen:
        raise InputError(f"--objects: no object named {', '.join(repr(n) for n in missing)} in scene "
                         f"'{scene.name}'" if missing else "--objects: name at least one object")
    return [by_name[n] for n in chosen]


def ol_bake_main(args):
    """CLI: bakes every orientation lightmap of a .blend to DIR/<empty>.exr (+ JSON report)."""
    import bpy

    from .bake import check_writable
    from .bake.orientation import bake_orientation_lightmaps
    t0 = time.perf_counter()
    ensure_registered()
    blend = open_blend(args.blend)
    _use_cluster(args)
    out_dir = os.path.abspath(args.out)
    check_writable(out_dir)
    res = bake_orientation_lightmaps(bpy.context, photons=args.photons, seed=args.seed,
                                     save_dir=out_dir, overwrite=True, hook_materials=False)
    report = {"blend": str(blend),
              "photons": int(res.stats.photons) if res.stats else 0,
              "orientation_lightmaps": {
                  name: {"path": res.paths[name], "resolution": int(rgba.shape[0]),
                         "objects": res.covered.get(name, []),
                         **next((r for r in res.rows if r["name"] == name), {})}
                  for name, rgba in res.maps.items()},
              "warnings": res.warnings,
              "kernels": kernels_report(),
              "seconds": {"photon_pass": res.seconds.get("photon_pass", 0.0),
                          "total": time.perf_counter() - t0}}
    text = json.dumps(report, indent=2)
    print(text)
    if getattr(args, "json", None):
        with open(args.json, "w") as f:
            f.write(text)
    return 0


def demo_main(args):
    import bpy  # noqa: F401  (bmesh and friends need bpy loaded first)

    from . import demo_blend
    from .engine import warmup

    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    t0 = time.perf_counter()
    ensure_registered()
    blend = os.path.join(out, "demo.blend")
    width, height = args.size
    demo_blend.build_cornell_blend(blend, width=width, height=height, spheres=True, csg=True, ol=True)
    spectral_blend = os.path.join(out, "spectral.blend")
    demo_blend.build_spectral_blend(spectral_blend, width=width, height=height)
    polarization_blend = os.path.join(out, "polarization.blend")
    demo_blend.build_polarization_blend(polarization_blend, width=width, height=height)
    common = [f"--{name}={getattr(args, name)}" for name in ("photons", "seed", "cluster", "workers")
              if getattr(args, name) is not None]
    render_json = os.path.join(out, "render.json")
    bake_json = os.path.join(out, "bake.json")
    ol_json = os.path.join(out, "orientation_lightmaps.json")
    spectral_json = os.path.join(out, "spectral.json")
    polarizer_json = {a: os.path.join(out, f"polarizer_{a}.json") for a in (0, 90)}
    lightmaps = os.path.join(out, "lightmaps")
    samples = [f"--samples={args.samples}"] if args.samples is not None else []
    samples += ["--denoise"] if args.denoise else []
    warmup.expect("bake")   # on a first run, the bake's kernels compile in a second process during the render
    # Each step goes through the same parser as on the command line, so it gets
    # every option's default; a failing step raises, and cli.main turns that
    # into the one "error: ..." line.
    for argv in (["render", blend, "--out", os.path.join(out, "render.png"), "--json", render_json,
                  *samples, *common],
                 ["bake", blend, "--out", lightmaps, "--json", bake_json, *common],
                 ["bake-ol", blend, "--out", lightmaps, "--json", ol_json, *common],
                 # the prism's rainbow and a brightener under a UV lamp, in 16 wavelength bands
                 ["render", spectral_blend, "--out", os.path.join(out, "spectral.png"), "--json", spectral_json,
                  "--spectral", *samples, *common],
                 # water under a bright sky through the camera's polarizing filter: with the glare, without
                 *(["render", polarization_blend, "--out", os.path.join(out, f"polarizer_{a}.png"),
                    "--json", polarizer_json[a], "--polarizer", str(a), *samples, *common] for a in (0, 90))):
        step = build_parser().parse_args(argv)
        step.func(step)
    with open(render_json) as f:
        render_report = json.load(f)
    with open(bake_json) as f:
        bake_report = json.load(f)
    with open(ol_json) as f:
        ol_report = json.load(f)
    with open(spectral_json) as f:
        spectral_report = json.load(f)
    polarizer_reports = {}
    for a, path in polarizer_json.items():
        with open(path) as f:
            polarizer_reports[f"{a} deg"] = json.load(f)
    report = {"blend": blend, "render": render_report, "bake": bake_report, "orientation_lightmaps": ol_report,
              "spectral": spectral_report, "polarizer": polarizer_reports,
              "seconds": {"total": time.perf_counter() - t0}}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)
    print(f"demo: {render_report['image']}, {spectral_report['image']}, "
          f"{' and '.join(r['image'] for r in polarizer_reports.values())} and {len(bake_report['objects'])} baked "
          f"lightmaps in {os.path.join(out, 'lightmaps')} ({report['seconds']['total']:.1f} s)")
    return 0


def _render_lsystem(grammar, args, report):
    """The grammar in engine/demo_scenes.lsystem_studio, through its scene graph -> report."""
    from .engine import demo_scenes, session
    text = pathlib.Path(args.grammar).read_text()
    b = report["bounds"]
    scene = demo_scenes.lsystem_studio(text, name=grammar.source_name, steps=args.steps,
                                       width=args.size[0], height=args.size[1],
                                       bounds=None if not report.get("bounds_exact") else (b["min"], b["max"]))
    settings = session.Settings(photons=args.photons, samples=args.samples)
    t0 = time.perf_counter()
    cs = session.compile(scene)
    t1 = time.perf_counter()
    stats = session.render_photon_pass(cs, settings)
    t2 = time.perf_counter()
    image = session.render(cs, settings)
    t3 = time.perf_counter()
    save_image(image, args.render)
    return {"image": str(pathlib.Path(args.render).resolve()), "width": args.size[0],
            "height": args.size[1], "photons": int(stats.photons),
            "orientation_lightmaps": len(cs.info.get("orientation_lightmaps", [])),
            "seconds": {"compile": t1 - t0, "photon_pass": t2 - t1, "render": t3 - t2}}


def save_image(rgb, path):
    """Writes an (H, W, 3) linear float image, top row first, as the extension says
    (configure_output: 8-bit 'Standard' PNG or float OpenEXR)."""
    import numpy as np
    import bpy
    h, w = rgb.shape[:2]
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = rgb[::-1, :, :3]            # Blender stores the bottom row first
    img = bpy.data.images.new("photon_lightmaps_output", w, h, float_buffer=True)
    sc = bpy.data.scenes.new("photon_lightmaps_output")
    try:
        img.pixels.foreach_set(rgba.ravel())
        configure_output(sc, path)
        pathlib.Path(path).resolve().parent.mkdir(parents=True, exist_ok=True)
        img.save_render(str(pathlib.Path(path).resolve()), scene=sc)
    finally:
        bpy.data.images.remove(img)
        bpy.data.scenes.remove(sc)


def lsystem_main(args):
    """CLI: the grammar's counts, bounds and scene-graph statistics as JSON (no bpy)."""
    from .bake.render import peak_rss_bytes
    from .engine.lsystem import grammar as lsystem
    from .engine import lsystem_stats
    from .messages import InputError
    try:
        grammar = lsystem.load(args.grammar)
    except OSError as exc:
        raise InputError(f"{args.grammar}: cannot read the grammar ({exc.strerror or exc})") from None
    if args.render:
        check_format(args.render)           # before the work
    t0 = time.perf_counter()
    report = lsystem_stats.summary(grammar, args.steps, with_string=args.string)
    if args.render:
        report["render"] = _render_lsystem(grammar, args, report)
    report["timings"]["total"] = time.perf_counter() - t0
    report["memory"]["peak_rss_bytes"] = peak_rss_bytes()
    report["kernels"] = kernels_report()
    text = json.dumps(report, indent=2)
    if args.json == "-":
        print(text)
    else:
        write_report(args.json, text)
    return 0


def warmup_main(args):
    """CLI: runs each kernel family once at a tiny size (engine/warmup.py, what
    Blender runs in the background), so its kernels compile, and land in the
    cache, now rather than in the first real render. Families compile side by
    side in helper processes, one per core (at most two)."""
    from .engine import warmup
    t0 = time.perf_counter()
    total = len(warmup.FAMILIES)
    w = warmup.WarmUp()

    def before(k, name):
        sys.stderr.write(f"warmup {k}/{total}: {name}\n")

    def after(k, name):
        rep = w.reports[-1]
        sys.stderr.write(f"warmup {w.done}/{total}: done {name} in {rep['seconds']:.0f} s, "
                         f"{rep['compiled']} kernels compiled ({time.perf_counter() - t0:.0f} s in all)\n")

    w.run(before, after)
    if w.error:
        raise RuntimeError(f"warm-up failed: {w.error}")
    families = [{"family": r["family"], "seconds": round(r["seconds"], 2), "compiled": r["compiled"],
                 "kernel_seconds": {n: round(v, 2) for n, v in sorted(r["kernel_seconds"].items(),
                                                                      key=lambda kv: -kv[1])}}
                for r in w.reports]
    compiled = sum(f["compiled"] for f in families)
    report = {"families": families, "lanes": warmup.lanes(),
              "kernels": {"compiled": compiled,
                          "seconds": round(sum(sum(f["kernel_seconds"].values()) for f in families), 2)},
              "seconds": time.perf_counter() - t0}
    if args.json:
        write_report(args.json, json.dumps(report, indent=2))
    print(f"warmup: {compiled} kernels compiled in {report['seconds']:.0f} s; "
          "renders and bakes now start without compiling")
    return 0


def write_report(path, text):
    """A command's JSON report at `path`, its folder made if missing."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text + os.linesep)


def compile_line(tracker, clock=time.perf_counter):
    """An on_compile callback (engine/core/kernel_watch.py) that redraws one stderr line
    while kernels compile, so a first run says why it waits."""
    t0 = []

    def on_compile(watch, name):
        t0 or t0.append(clock())
        tracker.write_transient(f"\rcompiling kernels (first run; cached for later runs): "
                                f"{watch.started} so far, {clock() - t0[0]:.0f} s ")
    return on_compile


def kernels_report():
    """The running command's kernel compiles, for its JSON report."""
    return _WATCH[-1].summary() if _WATCH else {"compiled": 0, "seconds": 0.0}


_WATCH = []


def main(argv=None):
    from .engine.core import kernel_watch
    args = build_parser().parse_args(argv)
    stderr = sys.stderr
    sys.stderr = tracker = _LineTracker(stderr)
    try:
        with kernel_watch.watching(compile_line(tracker)) as watch:
            _WATCH.append(watch)
            try:
                return args.func(args)
            finally:
                _WATCH.pop()
                if watch.compiled:
                    tracker.write(("" if tracker.at_line_start or tracker.transient else "\n")
                                  + f"compiled {watch.compiled} kernels in {watch.seconds:.0f} s "
                                  "(cached: later runs start at once)\n")
    except Exception as exc:  # noqa: BLE001  (the one place a command's failure reaches the user)
        from .messages import describe, is_user_error
        user = is_user_error(exc)
        if not tracker.at_line_start:
            stderr.write("\n")
        if args.debug:
            import traceback
            traceback.print_exception(exc, file=stderr)
        hint = "" if user or args.debug else " (rerun with --debug for the traceback)"
        stderr.write(f"error: {describe(exc)}{hint}\n")
        stderr.flush()
        return 2 if user else 1
    finally:
        sys.stderr = stderr


if __name__ == "__main__":
    sys.exit(main())
