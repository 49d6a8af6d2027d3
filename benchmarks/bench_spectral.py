"""Spectral mode against RGB: what 16 bands cost the photon pass and a gathered bake.

The Cornell room (demo_scenes.cornell_box, with its mirror and glass balls)
traced as RGB and as the same scene made spectral (engine/spectral.py), one
run each after a warm-up, best of three, 2 threads: photons/s of the photon
pass (a bake's: direct hits recorded, caustics apart), the seconds of a
gathered bake's texel pass (direct light and final gather), and the bytes the
lightmaps take. The ratios are spectral over RGB, measured in the same run.

    .venv/bin/python -m benchmarks.bench_spectral          # about a minute on 2 cores
"""
import json
import os
import pathlib
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import photon_lightmaps.engine  # noqa: E402,F401  (sets the numba cache before numba loads)
from photon_lightmaps.engine import demo_scenes, session, spectral  # noqa: E402

PHOTONS = 300_000
OUT = ROOT / "benchmarks" / "charts" / "spectral.json"


def measure(scene, settings):
    """(photon pass seconds, texel pass seconds, lightmap bytes), best of three."""
    photons, texels = [], []
    for _ in range(3):
        cs, stats = session.compile_and_trace_bake(scene, settings)
        photons.append(stats.seconds)
        lids = sorted({int(lid) for ids in cs.instance_lightmaps for lid in ids})
        t0 = time.perf_counter()
        session.bake_texels(cs, lids, [], settings)
        texels.append(time.perf_counter() - t0)
    return min(photons), min(texels), int(cs.lightmaps.flux.nbytes + cs.lightmaps.irradiance.nbytes)


def main():
    rgb = demo_scenes.cornell_box(n_bands=3)
    spec = spectral.spectral_scene(rgb)
    settings = session.Settings(photons=PHOTONS, bake_photons=PHOTONS, seed=1, bake_gather_rays=64)
    warm = session.Settings(photons=2000, bake_photons=2000, seed=1, bake_gather_rays=4)
    for scene in (rgb, spec):               # kernels loaded, the first-run cost outside the timing
        cs, _ = session.compile_and_trace_bake(scene, warm)
        session.bake_texels(cs, sorted({int(lid) for ids in cs.instance_lightmaps for lid in ids}), [], warm)
    rows = {}
    for name, scene in (("rgb", rgb), ("spectral", spec)):
        p, t, nbytes = measure(scene, settings)
        rows[name] = dict(bands=int(scene.n_bands), photon_seconds=p, photons_per_second=PHOTONS / p,
                          texel_seconds=t, lightmap_bytes=nbytes)
        print(f"{name:9s} {scene.n_bands:2d} bands: {PHOTONS / p / 1e3:7.0f} k photons/s, "
              f"texels {t:.2f} s, lightmaps {nbytes / 2**20:.1f} MiB", flush=True)
    ratio = dict(photons_per_second=rows["spectral"]["photons_per_second"] / rows["rgb"]["photons_per_second"],
                 texel_seconds=rows["spectral"]["texel_seconds"] / rows["rgb"]["texel_seconds"],
                 lightmap_bytes=rows["spectral"]["lightmap_bytes"] / rows["rgb"]["lightmap_bytes"])
    print(f"spectral / RGB: photons/s {ratio['photons_per_second']:.2f}x, texel pass "
          f"{ratio['texel_seconds']:.2f}x the time, lightmaps {ratio['lightmap_bytes']:.2f}x the bytes")
    OUT.write_text(json.dumps(dict(photons=PHOTONS, scene="cornell_box", runs=rows, ratio=ratio), indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
