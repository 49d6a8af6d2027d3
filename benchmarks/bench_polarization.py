"""What polarization costs: photon pass and render with it off, with the camera's filter,
and with the Polarization setting (photons and camera paths carry Stokes vectors).

Two scenes in RGB: the Cornell room (demo_scenes.cornell_box: its mirror and glass
balls are the smooth surfaces polarization acts at), and the worst case, a glass
pane (two smooth faces) every camera ray and every sun photon passes, over a lit
floor. 2 threads, one warm-up run per variant (its kernels loaded), then best of
three: photons/s of a render's photon pass and the seconds of a 128 x 128 render at
16 samples. Ratios are against polarization off, in the same run. Only smooth
interactions pay for the 4 x 4 algebra; the rest of a path pays for a branch.

    .venv/bin/python -m benchmarks.bench_polarization      # about three minutes on 2 cores
"""
import math
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


def pane_scene():
    """A 1 cm glass pane 1 m over a white floor under a sun, seen through at 60°."""
    from photon_lightmaps.engine.core.scene import Camera, Light, Material, Scene, compose, rotate, translate
    s = Scene(n_bands=3)
    glass = s.add_material(Material("glass", diffuse=0.0, transmission=1.0, roughness=0.0, ior=1.5))
    white = s.add_material(Material("white", diffuse=0.8))
    q = demo_scenes.quad_mesh
    big = 3.0
    s.add_object([q((-big, -big, 1.01), (big, -big, 1.01), (big, big, 1.01), (-big, big, 1.01), material=glass),
                  q((-big, -big, 1.0), (-big, big, 1.0), (big, big, 1.0), (big, -big, 1.0), material=glass)],
                 name="pane")
    s.add_object(q((-big, -big, 0), (big, -big, 0), (big, big, 0), (-big, big, 0), material=white), name="floor")
    s.lights.append(Light("sun", power=3.0, transform=rotate("x", 20.0), angle=math.radians(1.0)))
    s.camera = Camera(transform=compose(translate(0.0, -2.0, 2.6), rotate("x", 60.0)), fov=math.radians(40.0),
                      width=128, height=128)
    return s


def variants(base):
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
    report = dict(photons=PHOTONS, samples=SAMPLES, size="128x128", scenes={})
    for scene_name, base in (("cornell_box", demo_scenes.cornell_box(n_bands=3, width=128, height=128)),
                             ("glass pane", pane_scene())):
        rows = {}
        for name, scene in variants(base).items():
            measure(scene, replace(settings, photons=2000, samples=1), 1)      # warm-up: kernels loaded
            p, r = measure(scene, settings, 3)
            rows[name] = dict(photon_seconds=p, photons_per_second=PHOTONS / p, render_seconds=r)
            print(f"{scene_name:12s} {name:16s} {PHOTONS / p / 1e3:7.0f} k photons/s, render {r:.2f} s", flush=True)
        off = rows["off"]
        ratio = {name: dict(photons_per_second=row["photons_per_second"] / off["photons_per_second"],
                            render_seconds=row["render_seconds"] / off["render_seconds"])
                 for name, row in rows.items() if name != "off"}
        for name, q in ratio.items():
            print(f"{scene_name}, {name} / off: photons/s {q['photons_per_second']:.2f}x, "
                  f"render {q['render_seconds']:.2f}x the time")
        report["scenes"][scene_name] = dict(runs=rows, ratio=ratio)
    OUT.write_text(json.dumps(report, indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
