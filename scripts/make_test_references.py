"""Regenerates the Cycles references the tests compare with (tests/data/).

    .venv/bin/python scripts/make_test_references.py [--samples N] [--only bias|boolean]

Each reference is Cycles' own output, never this add-on's: the mean of two
Diffuse bakes with different seeds, stored as float16, with a JSON of its
provenance (Blender and Cycles version, samples, seeds, bounces, the scene
script's hash and each half's per-object mean, whose spread bounds the
reference's own noise). A test whose scene script changed fails and names
this script.
"""
import argparse
import json
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import photon_lightmaps  # noqa: E402
import bias_scenes as BS  # noqa: E402
import boolean_scene as BOOL  # noqa: E402

SEEDS = (1001, 2002)
RENDERER = ("Cycles (bpy {}), CPU, Diffuse bake, Direct + Indirect, no Color, no clamping, "
            "no denoising, no adaptive sampling")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2048, help="Cycles samples per bake half")
    ap.add_argument("--only", choices=("bias", "boolean"), help="regenerate one set of references")
    args = ap.parse_args(argv)
    photon_lightmaps.register()
    if args.only != "boolean":
        bias(args)
    if args.only != "bias":
        boolean(args)


def boolean(args):
    """The mesh Boolean (tests/boolean_scene.py): Cycles bakes its applied result."""
    from blender_session import cycles_diffuse_bake
    t0 = time.perf_counter()
    BOOL.build(user_uvs=True)
    ob = BOOL.applied_result()
    a, b = (cycles_diffuse_bake(ob, BOOL.RES, args.samples, seed=seed, bounces=BOOL.MAX_BOUNCES, margin=2,
                                uv_layer="Lightmap")[..., :3] for seed in SEEDS)
    np.savez_compressed(BOOL.REFERENCE, cube=(0.5 * (a + b)).astype(np.float16))
    BOOL.PROVENANCE.write_text(json.dumps({
        "renderer": RENDERER.format(bpy.app.version_string),
        "what": "the cube's Boolean result applied to a mesh (its carried Lightmap UVs), baked",
        "samples_per_half": args.samples, "seeds": list(SEEDS), "max_bounces": BOOL.MAX_BOUNCES,
        "diffuse_bounces": BOOL.MAX_BOUNCES, "resolution": BOOL.RES,
        "scene_script": "tests/boolean_scene.py", "scene_hash": BOOL.scene_hash(),
        "generator": "scripts/make_test_references.py --only boolean",
        "half_means": [float(a.mean()), float(b.mean())], "seconds": round(time.perf_counter() - t0, 1)},
        indent=1) + "\n")
    print(f"wrote {BOOL.REFERENCE.relative_to(ROOT)} and {BOOL.PROVENANCE.relative_to(ROOT)}")


def bias(args):
    """The rooms of tests/bias_scenes.py: Cycles bakes every object."""
    arrays, halves = {}, {}
    t0 = time.perf_counter()
    for scene in BS.SCENES:
        BS.build(scene)
        a, b = (BS.cycles_bake(args.samples, seed) for seed in SEEDS)
        for name in a:
            arrays[f"{scene}/{name}"] = (0.5 * (a[name] + b[name])).astype(np.float16)
            halves[f"{scene}/{name}"] = [float(a[name].mean()), float(b[name].mean())]
        print(f"{scene}: {len(a)} objects, {time.perf_counter() - t0:.0f} s", flush=True)
    BS.DATA.mkdir(exist_ok=True)
    np.savez_compressed(BS.REFERENCE, **arrays)
    BS.PROVENANCE.write_text(json.dumps({
        "renderer": RENDERER.format(bpy.app.version_string),
        "samples_per_half": args.samples, "seeds": list(SEEDS),
        "max_bounces": BS.MAX_BOUNCES, "diffuse_bounces": BS.MAX_BOUNCES, "resolution": BS.RES,
        "scene_script": "tests/bias_scenes.py", "scene_hash": BS.scene_hash(),
        "generator": "scripts/make_test_references.py",
        "half_means": halves, "seconds": round(time.perf_counter() - t0, 1)}, indent=1) + "\n")
    print(f"wrote {BS.REFERENCE.relative_to(ROOT)} and {BS.PROVENANCE.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
