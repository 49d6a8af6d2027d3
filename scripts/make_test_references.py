"""Regenerates the Cycles references the tests compare with (tests/data/).

    .venv/bin/python scripts/make_test_references.py [--samples N]

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

SEEDS = (1001, 2002)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=2048, help="Cycles samples per bake half")
    args = ap.parse_args(argv)
    photon_lightmaps.register()
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
        "renderer": f"Cycles (bpy {bpy.app.version_string}), CPU, Diffuse bake, Direct + Indirect, "
                    "no Color, no clamping, no denoising, no adaptive sampling",
        "samples_per_half": args.samples, "seeds": list(SEEDS),
        "max_bounces": BS.MAX_BOUNCES, "diffuse_bounces": BS.MAX_BOUNCES, "resolution": BS.RES,
        "scene_script": "tests/bias_scenes.py", "scene_hash": BS.scene_hash(),
        "generator": "scripts/make_test_references.py",
        "half_means": halves, "seconds": round(time.perf_counter() - t0, 1)}, indent=1) + "\n")
    print(f"wrote {BS.REFERENCE.relative_to(ROOT)} and {BS.PROVENANCE.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
