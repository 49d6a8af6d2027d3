"""`python -m photon_lightmaps demo`: builds the demo .blend, renders it and bakes its lightmaps
and its orientation lightmap (the sphere cluster, thesis ch. 6).

The demo goes through exactly what a user's file goes through (export from
the depsgraph, RenderEngine, bake), so a working demo means a working add-on.
It grows with the project's capabilities.
"""
import argparse
import json
import os
import time


def demo_main(args):
    import bpy  # noqa: F401  (bmesh and friends need bpy loaded first)

    from . import bake, demo_blend, headless, ol_bake

    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    t0 = time.perf_counter()
    headless.ensure_registered()
    blend = os.path.join(out, "demo.blend")
    demo_blend.build_cornell_blend(blend, width=256, height=256, spheres=True, csg=True, ol=True)
    common = dict(blend=blend, photons=args.photons, seed=args.seed)
    render_json = os.path.join(out, "render.json")
    bake_json = os.path.join(out, "bake.json")
    # A failing step raises; cli.main turns that into the one "error: ..." line.
    headless.render_main(argparse.Namespace(out=os.path.join(out, "render.png"),
                                            samples=args.samples, json=render_json, **common))
    bake.bake_main(argparse.Namespace(out=os.path.join(out, "lightmaps"), resolution=None,
                                      indirect_only=False, json=bake_json, **common))
    ol_json = os.path.join(out, "orientation_lightmaps.json")
    ol_bake.ol_bake_main(argparse.Namespace(out=os.path.join(out, "lightmaps"), json=ol_json, **common))
    with open(render_json) as f:
        render_report = json.load(f)
    with open(bake_json) as f:
        bake_report = json.load(f)
    with open(ol_json) as f:
        ol_report = json.load(f)
    report = {"blend": blend, "render": render_report, "bake": bake_report, "orientation_lightmaps": ol_report,
              "seconds": {"total": time.perf_counter() - t0}}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)
    print(f"demo: {render_report['image']} and {len(bake_report['objects'])} baked lightmaps in "
          f"{os.path.join(out, 'lightmaps')} ({report['seconds']['total']:.1f} s)")
    return 0
