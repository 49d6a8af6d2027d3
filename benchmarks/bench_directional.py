"""Directional lightmaps: what they cost. The Cornell room (demo_blend.build_cornell_blend,
mirror and glass balls too) at the scene's defaults (texel density 16, gather through the
irradiance cache), every mesh baked plain, with the dominant direction and with L1 SH per
colour, each reusing the same kept photon pass (so the photon pass is not in the times).

Per bake: the direct gather's, the final gather's and the direction images' seconds, the
whole bake's, the moments' memory and the images' bytes; and the lightmaps' largest
difference from the plain bake (the moments ride along in the gathers' rows, so there is
none where no glossy chain sums a ray's light in another order). Best of REPEATS, 2 threads.

    .venv/bin/python -m benchmarks.bench_directional      # about a minute on 2 cores
"""
import json
import os
import pathlib
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from photon_lightmaps import bake, demo_blend  # noqa: E402
from photon_lightmaps.registration import ensure_registered  # noqa: E402

OUT = ROOT / "benchmarks" / "charts" / "directional.json"
MODES = ("", "DOMINANT", "SH")
REPEATS = 3


def main():
    ensure_registered()
    demo_blend.build_cornell_blend(spheres=True)
    meshes = [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]
    for mode in MODES:                                   # warm-up: kernels loaded, the pass kept
        bake.bake_objects(bpy.context, meshes, seed=3, overwrite=True, directional=mode)
    out, plain = {}, None
    for mode in MODES:
        best = None
        for _ in range(REPEATS):
            t0 = time.perf_counter()
            res = bake.bake_objects(bpy.context, meshes, seed=3, overwrite=True, directional=mode)
            wall = time.perf_counter() - t0
            assert res.light_reuse["reused"] == "memory"
            if best is None or wall < best[0]:
                best = (wall, res)
        wall, res = best
        maps = {name: bm.rgba for name, bm in res.maps.items()}
        if plain is None:
            plain = maps
        diff = max(float(np.abs(maps[n][..., :3] - plain[n][..., :3]).max()) for n in maps)
        out[mode or "plain"] = {
            "bake_s": wall, "direct_s": res.seconds.get("direct", 0.0), "gather_s": res.seconds.get("gather", 0.0),
            "direction_s": res.seconds.get("direction", 0.0),
            "moment_bytes": (res.directional or {}).get("moment_bytes", 0),
            "image_bytes": (res.directional or {}).get("image_bytes", 0),
            "lightmap_bytes": int(sum(bm.rgba.nbytes for bm in res.maps.values())),
            "max_lightmap_difference": diff}
        print(mode or "plain", json.dumps(out[mode or "plain"]))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
