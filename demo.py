"""`python -m photon_lightmaps demo`: the built-in demo scene, rendered end to end."""
import json
import os
import time


def demo_main(args):
    from .engine import demo_scenes
    from .engine.compile import compile_scene
    from .engine.imageio import write_png
    from .engine.photon_tracer import trace_photons
    from .engine.renderer import render

    os.makedirs(args.out, exist_ok=True)
    t0 = time.perf_counter()
    scene = demo_scenes.cornell_box(width=256, height=256)
    cs = compile_scene(scene)
    seed = 0 if args.seed is None else args.seed
    stats = trace_photons(cs, args.photons or 1_000_000, seed=seed)
    img = render(cs, samples=args.samples or 16, seed=seed)
    path = os.path.join(args.out, "cornell.png")
    write_png(path, img)
    report = {"scene": scene.name, "image": path, "photons": stats.photons, "rays": stats.rays,
              "seconds": {"setup": cs.timings["setup"], "photon_pass": stats.seconds,
                          "render": cs.timings["render"], "total": time.perf_counter() - t0},
              "memory": {"lightmap_bytes": cs.lightmap_bytes()},
              "energy_audit_error": stats.audit_error()}
    text = json.dumps(report, indent=2)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(text)
    return 0
