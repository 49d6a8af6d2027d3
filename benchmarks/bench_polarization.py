"""What polarization costs: photon pass and render with it off, with the camera's filter,
and with the Polarization setting (photons and camera paths carry Stokes vectors).

The Cornell room (demo_scenes.cornell_box: its mirror and glass balls are the smooth
surfaces polarization acts at) in RGB, 2 threads, one warm-up run per variant (its
kernels loaded), then best of three: photons/s of a render's photon pass and the
seconds of a 128 x 128 render at 16 samples. Ratios are against polarization off,
measured in the same run. Only smooth interactions pay for the 4 x 4 algebra; the
rest of a path pays for a branch.

    .venv/bin/python -m benchmarks.bench_polarization      # about two minutes on 2 cores
"""
import json
import os
import pathlib
import time
from dataclasses import replace

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import photon_lightmaps.engine  # noqa: E402,F401  (sets the numba cache before numba loads)
from photon_lightmaps.engine import demo_scenes, session  # noqa: E402

PHOTONS = 400_000
SAMPLES = 16
OUT = ROOT / "benchmarks" / "charts" / "polarization.json"


def variants():
    base = demo_scenes.cornell_box(n_bands=3, width=128, height=128)
    return {"off": base,
            "camera filter": replace(base, camera=replace(base.camera, polarizer=0.0)),
            "Polarization on": replace(base, camera=replace(base.camera, polarized=True))}


def measure(scene, settings, repeats):
    """(photon pass seconds, render seconds), best of `repeats`."""
    photons, renders = [], []
    for _ in range(repeats):
        cs = session.compile(scene)
        stats = session.render_photon_pass(cs, settings)
        photons.append(stats.seconds)
        t0 = time.perf_counter()
        session.render(cs, settings)
        renders.append(time.perf_counter() - t0)
    return min(photons), min(renders)


def main():
    settings = session.Settings(photons=PHOTONS, samples=SAMPLES, seed=1)
    rows = {}
    for name, scene in variants().items():
        measure(scene, replace(settings, photons=2000, samples=1), 1)      # warm-up: kernels loaded
        p, r = measure(scene, settings, 3)
        rows[name] = dict(photon_seconds=p, photons_per_second=PHOTONS / p, render_seconds=r)
        print(f"{name:16s} {PHOTONS / p / 1e3:7.0f} k photons/s, render {r:.2f} s", flush=True)
    off = rows["off"]
    ratio = {name: dict(photons_per_second=row["photons_per_second"] / off["photons_per_second"],
                        render_seconds=row["render_seconds"] / off["render_seconds"])
             for name, row in rows.items() if name != "off"}
    for name, q in ratio.items():
        print(f"{name} / off: photons/s {q['photons_per_second']:.2f}x, render {q['render_seconds']:.2f}x the time")
    OUT.write_text(json.dumps(dict(photons=PHOTONS, samples=SAMPLES, scene="cornell_box 128x128", runs=rows,
                                   ratio=ratio), indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
