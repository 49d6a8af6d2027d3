"""Command line for the bpy-module world: `python -m photon_lightmaps {demo,render,bake}`."""
import argparse
import json
import os
import sys
import time


def _demo(args):
    from .engine import demo_scenes
    from .engine.compile import compile_scene
    from .engine.imageio import write_png
    from .engine.photon_tracer import trace_photons
    from .engine.renderer import render

    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    scene = demo_scenes.cornell_box(width=args.width, height=args.height)
    cs = compile_scene(scene)
    stats = trace_photons(cs, args.photons, seed=args.seed)
    img = render(cs, samples=args.samples, seed=args.seed)
    path = os.path.join(args.out, "cornell.png")
    write_png(path, img)
    report = {"scene": scene.name, "image": path, "photons": stats.photons, "rays": stats.rays,
              "seconds": {"setup": cs.timings.get("setup", 0.0), "photon_pass": stats.seconds,
                          "render": cs.timings.get("render", 0.0),
                          "total": time.perf_counter() - t0},
              "memory": {"lightmap_bytes": cs.lightmap_bytes()},
              "energy_audit_error": stats.audit_error()}
    print(json.dumps(report, indent=2))
    return 0


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m photon_lightmaps",
                                description="Photon Lightmaps: lightmap-based photon tracing (Wilkie 2001).")
    sub = p.add_subparsers(dest="command", required=True)
    d = sub.add_parser("demo", help="render the built-in demo scene")
    d.add_argument("--out", default="out/demo", help="output folder")
    d.add_argument("--photons", type=int, default=1_000_000)
    d.add_argument("--samples", type=int, default=8)
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--width", type=int, default=256)
    d.add_argument("--height", type=int, default=256)
    d.set_defaults(func=_demo)
    args = p.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
