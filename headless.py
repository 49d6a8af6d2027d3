"""`python -m photon_lightmaps render FILE.blend --out IMG [--json REPORT]`, without the Blender UI.

The image comes from bpy.ops.render.render(), i.e. from the registered
PhotonLightmapsRenderEngine, exactly as `blender -b FILE.blend -E
PHOTON_LIGHTMAPS -f 1` or F12 would make it; the engine leaves the numbers of
its last run in render_engine.LAST_RUN for the JSON report.
"""
import json
import os
import pathlib
import time

ENGINE_ID = "PHOTON_LIGHTMAPS"
FORMATS = {".png": "PNG", ".exr": "OPEN_EXR"}


def engine_registered():
    import bpy
    return any(getattr(c, "bl_idname", None) == ENGINE_ID and c.is_registered
               for c in bpy.types.RenderEngine.__subclasses__())


def ensure_registered():
    """Registers the add-on unless some copy of it (e.g. the installed extension) already is."""
    if not engine_registered():
        from . import register
        register()


def check_format(path):
    ext = pathlib.Path(path).suffix.lower()
    if ext not in FORMATS:
        from .messages import InputError
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

    Raises what the engine's render() kept in render_engine.LAST_ERROR: Blender only
    prints an exception raised inside a RenderEngine, the caller would never see it.
    """
    import bpy
    from . import render_engine
    scene.render.engine = ENGINE_ID
    configure_output(scene, out_path)
    render_engine.LAST_RUN = render_engine.LAST_ERROR = None
    render_engine.RAISE_BUGS = False    # we re-raise it below; Blender would print it first
    try:
        bpy.ops.render.render(write_still=False, scene=scene.name)
    finally:
        render_engine.RAISE_BUGS = True
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
    t0 = time.perf_counter()
    out = pathlib.Path(args.out).resolve()
    check_format(args.out)      # before the (slow) load
    ensure_registered()
    blend = open_blend(args.blend)
    import bpy
    scene = bpy.context.scene
    if scene.camera is None:
        raise InputError(f"scene '{scene.name}': no camera; add one and set it as the scene camera "
                         "(Scene Properties > Camera)")
    settings = scene.photon_lightmaps
    for name in ("photons", "samples", "seed"):
        value = getattr(args, name, None)
        if value is not None:
            setattr(settings, name, value)
    t_load = time.perf_counter()
    run = render_to_file(scene, out)
    t_end = time.perf_counter()
    report = run.as_dict()
    report.update(blend=str(blend), image=str(out), engine=ENGINE_ID,
                  settings={k: getattr(settings, k) for k in ("photons", "max_bounces", "texel_density",
                                                              "reconstruction", "samples", "seed")})
    # "total" is the whole command (load, render, save); "pipeline" is export to last tile.
    report["seconds"].update(load=t_load - t0, pipeline=run.seconds["total"], total=t_end - t0)
    print(f"{out}: {run.width}x{run.height}, {run.photons:,} photons in {run.seconds['photon_pass']:.2f} s, "
          f"render {run.seconds['render']:.2f} s, total {t_end - t0:.2f} s")
    for ol in run.orientation_lightmaps:
        print(f"  orientation lightmap '{ol['name']}': {ol['photons']:,} photons, "
              f"{ol['memory_bytes'] / 1024:.1f} KiB, area {ol['area']:.4g} m², {len(ol['warnings'])} warnings")
    if args.json:
        path = pathlib.Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(report, indent=2) + os.linesep)
    return 0
