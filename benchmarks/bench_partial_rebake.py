"""Partial rebakes: rebaking one object of an unchanged scene, reusing the photon pass
(Keep Bake Light; a folder of saved passes, the CLI's --light-cache) against the same
rebake tracing its own pass, same run.

The Cornell room (demo_blend.build_cornell_blend, mirror and glass balls too) at the
scene's defaults (texel density 16, 256 gather rays through the irradiance cache),
with the default 300 k bake photons and with 3 M: every mesh baked once, then the
floor alone

* reusing the kept pass (memory),
* reusing the pass saved to a folder (disk: the scene compiled again, the pass read),
* tracing a pass of its own (what a rebake cost before).

Times are wall seconds of bake_objects, after a warm-up bake (kernels loaded), 2
threads; the floor's maps from the reused passes equal the full bake's within the
irradiance cache's noise (bit for bit with per-texel gathers: tests/test_bake_reuse.py).

    .venv/bin/python -m benchmarks.bench_partial_rebake      # about a minute on 2 cores
"""
import json
import os
import pathlib
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import bpy  # noqa: E402

from photon_lightmaps import bake, demo_blend  # noqa: E402
from photon_lightmaps.bake import pipeline  # noqa: E402
from photon_lightmaps.registration import ensure_registered  # noqa: E402

OUT = ROOT / "benchmarks" / "charts" / "partial_rebake.json"


PHOTONS = (300_000, 3_000_000)


def timed(objects, **kw):
    t0 = time.perf_counter()
    res = bake.bake_objects(bpy.context, objects, seed=3, overwrite=True, **kw)
    return res, time.perf_counter() - t0


def main():
    ensure_registered()
    demo_blend.build_cornell_blend(spheres=True)
    meshes = [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]
    timed(meshes, keep_light=False)                      # warm-up: kernels loaded
    out = {}
    for photons in PHOTONS:
        out[str(photons)] = rebakes(meshes, photons)
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=2))


def rebakes(meshes, photons):
    floor = [bpy.data.objects["floor"]]
    bpy.context.scene.photon_lightmaps.bake_photons = photons
    pipeline.BAKE_LIGHT.clear()
    with tempfile.TemporaryDirectory() as folder:
        full, t_full = timed(meshes, light_cache=folder)
        memory, t_memory = timed(floor)
        pipeline.BAKE_LIGHT.clear()
        disk, t_disk = timed(floor, light_cache=folder, keep_light=False)
        fresh, t_fresh = timed(floor, keep_light=False)
    assert memory.light_reuse["reused"] == "memory" and disk.light_reuse["reused"] == "disk"
    assert fresh.light_reuse is None
    rows = {
        "full_bake": {"objects": len(full.maps), "seconds": t_full,
                      "photon_pass": full.seconds["photon_pass"], "kept_bytes": full.light_reuse["kept_bytes"]},
        "floor_reusing_memory": {"seconds": t_memory, "photon_pass": memory.seconds["photon_pass"]},
        "floor_reusing_disk": {"seconds": t_disk, "photon_pass": disk.seconds["photon_pass"]},
        "floor_own_pass": {"seconds": t_fresh, "photon_pass": fresh.seconds["photon_pass"]},
    }
    rows["speedup_memory"] = t_fresh / t_memory
    rows["speedup_disk"] = t_fresh / t_disk
    print(f"{photons:,} photons")
    for name, row in rows.items():
        print(f"  {name:24s} {row}")
    return rows


if __name__ == "__main__":
    main()
