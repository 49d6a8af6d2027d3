"""Command line for the bpy-module world: `python -m photon_lightmaps {demo,render,bake}`.

Each command lives with the code it drives: `render` in headless.py, `bake`
in bake.py, `demo` in demo.py; this module only parses arguments, so
`--help` works without importing Blender.
"""
import argparse
import importlib
import sys


def _add_common(p):
    p.add_argument("--photons", type=int, default=None, help="photons to shoot (default: scene setting)")
    p.add_argument("--seed", type=int, default=None, help="random seed (default: scene setting)")
    p.add_argument("--json", metavar="REPORT", default=None, help="write a JSON report here")


def build_parser():
    p = argparse.ArgumentParser(
        prog="python -m photon_lightmaps",
        description="Photon Lightmaps: lightmap-based photon tracing (Wilkie 2001) for Blender files.")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser("demo", help="render and bake the built-in demo scene")
    d.add_argument("--out", default="out/demo", help="output folder")
    _add_common(d)
    d.add_argument("--samples", type=int, default=None)
    d.set_defaults(module="demo", func="demo_main")

    r = sub.add_parser("render", help="render a .blend with the Photon Lightmaps engine")
    r.add_argument("blend", metavar="FILE.blend")
    r.add_argument("--out", required=True, metavar="IMG", help="output image (.png or .exr)")
    _add_common(r)
    r.add_argument("--samples", type=int, default=None, help="pixel samples")
    r.set_defaults(module="headless", func="render_main")

    b = sub.add_parser("bake", help="bake photon lightmaps of a .blend to OpenEXR images")
    b.add_argument("blend", metavar="FILE.blend")
    b.add_argument("--out", required=True, metavar="DIR", help="folder for <object name>.exr")
    _add_common(b)
    b.add_argument("--resolution", type=int, default=None, metavar="R", help="force R x R lightmaps")
    b.add_argument("--indirect-only", action="store_true", help="leave direct light out of the maps")
    b.set_defaults(module="bake", func="bake_main")

    o = sub.add_parser("bake-ol", help="bake the orientation lightmaps of a .blend to OpenEXR images")
    o.add_argument("blend", metavar="FILE.blend")
    o.add_argument("--out", required=True, metavar="DIR", help="folder for <empty name>.exr")
    _add_common(o)
    o.set_defaults(module="ol_bake", func="ol_bake_main")
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
    module = importlib.import_module(f"{__package__}.{args.module}")
    return getattr(module, args.func)(args)


if __name__ == "__main__":
    sys.exit(main())
