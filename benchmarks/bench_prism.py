"""The prism caustic: error against time of the rainbow a dispersive prism throws on the floor.

A 60° N-SF11 prism at minimum deviation for the d line under a narrow spot
beam (1° cone, 20 m back), and a 1.7 x 0.6 m patch of black floor 2 m below,
which takes the rainbow in a 64 x 64 lightmap. Spectral mode, 16 bands; the
lightmap is compared in Rec.709 (each texel's bands turned to RGB) against a
converged run of the same tracer (two runs of REFERENCE photons with other
seeds, averaged: their difference gives the reference's own noise, which is
removed from the curve as in run_all). Error: relative RMSE over the texels
the reference finds lit (above 2 % of its peak luminance).

No peer traces dispersion: Cycles 5.0 has no spectral rendering, and Mitsuba
3's spectral variants have no dispersive dielectric. What an RGB tracer gets is
shown instead: the same scene traced in RGB (the prism at n_d, every colour
down one path) against the spectral reference.

    .venv/bin/python -m benchmarks.bench_prism       # about a minute on 2 cores
"""
import json
import math
import os
import pathlib
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import numpy as np  # noqa: E402

import photon_lightmaps.engine  # noqa: E402,F401  (sets the numba cache before numba loads)
from photon_lightmaps.engine import demo_scenes, spectral  # noqa: E402
from photon_lightmaps.engine.compile import compile_scene  # noqa: E402
from photon_lightmaps.engine.core.scene import Light, Material, Scene, compose, rotate, translate  # noqa: E402
from photon_lightmaps.engine.shading import dispersion, spectrum  # noqa: E402
from photon_lightmaps.engine.transport.photon_tracer import trace_photons  # noqa: E402

GLASS = "N-SF11"
PHOTONS = [25_000 * 2 ** k for k in range(9)]          # 25 k to 6.4 M
REFERENCE = 12_800_000                                   # photons per reference half
RES = 64                                                 # the floor lightmap, texels per side
OUT = ROOT / "benchmarks" / "charts"


def prism_scene(spectral_bands=True):
    n_d = float(dispersion.sellmeier_index(dispersion.PRESETS[GLASS], dispersion.LINE_D))
    phi = math.asin(0.5 * n_d) - math.radians(30.0)
    d_in = np.array([math.cos(phi), 0.0, math.sin(phi)])
    s = Scene(n_bands=3)
    g = s.add_material(Material("glass", diffuse=0.0, transmission=1.0, glass=GLASS))
    black = s.add_material(Material("black", diffuse=0.0))
    s.add_object(demo_scenes.prism_mesh(material=g), name="prism", lightmap_resolution=4)
    z = -2.0
    s.add_object(demo_scenes.quad_mesh((3.2, -0.3, z), (4.9, -0.3, z), (4.9, 0.3, z), (3.2, 0.3, z), material=black,
                                       name="floor"), name="floor", lightmap_resolution=RES)
    mid = np.array([-0.25, 0.0, math.sqrt(3.0) / 4.0])
    s.lights.append(Light("spot", power=1e5, spot_size=math.radians(1.0), spot_blend=0.0,
                          transform=compose(translate(*(mid - 20.0 * d_in)), rotate("y", -(90.0 + math.degrees(phi)))),
                          name="beam"))
    return spectral.spectral_scene(s) if spectral_bands else s


def floor_rgb(scene, photons, seed):
    """(the floor's lightmap in Rec.709 (texels, 3), photon pass seconds)."""
    cs = compile_scene(scene)
    t0 = time.perf_counter()
    trace_photons(cs, photons, seed=seed, max_bounces=4, record_direct=True)
    seconds = time.perf_counter() - t0
    lm = cs.lightmaps
    lid = int(cs.instance_lightmaps[1][0])
    rows = slice(int(lm.offset[lid]), int(lm.offset[lid] + lm.width[lid] * lm.height[lid]))
    return spectral.to_rgb(cs, lm.irradiance[rows]), seconds


def rel_rmse(x, ref, lit):
    return float(np.sqrt(np.mean((x[lit] - ref[lit]) ** 2)) / np.mean(ref[lit]))


def main():
    scene = prism_scene()
    floor_rgb(scene, 2000, 0)                                # kernels loaded outside the timing
    a, _ = floor_rgb(scene, REFERENCE, 101)
    b, _ = floor_rgb(scene, REFERENCE, 102)
    ref = 0.5 * (a + b)
    y = ref @ np.linalg.inv(spectrum.Bands().xyz_to_rgb)[1]
    lit = y > 0.02 * y.max()
    # the halves differ by twice the reference's variance: its own noise, relative
    floor = rel_rmse(a, b, lit) / 2.0
    points = []
    for n in PHOTONS:
        img, sec = floor_rgb(scene, n, 7)
        raw = rel_rmse(img, ref, lit)
        err = math.sqrt(max(raw ** 2 - floor ** 2, 0.0))
        points.append(dict(photons=n, seconds=sec, rel_rmse=err, raw_rel_rmse=raw))
        print(f"{n / 1e3:7.0f} k photons: {sec:6.3f} s, relRMSE {err:.4f}", flush=True)
    rgb_img, rgb_sec = floor_rgb(prism_scene(False), PHOTONS[-1], 7)
    rgb_err = rel_rmse(rgb_img, ref, lit)
    print(f"RGB tracing, {PHOTONS[-1] / 1e6:g} M photons: {rgb_sec:.3f} s, relRMSE {rgb_err:.3f} (no rainbow)")
    result = dict(scene=f"60 degree {GLASS} prism, 16 bands, floor {RES} x {RES} texels",
                  reference_photons=2 * REFERENCE, reference_noise=floor, lit_texels=int(lit.sum()), points=points,
                  rgb=dict(photons=PHOTONS[-1], seconds=rgb_sec, rel_rmse=rgb_err))
    (OUT / "prism.json").write_text(json.dumps(result, indent=1))
    chart(result, ref.reshape(RES, RES, 3), rgb_img.reshape(RES, RES, 3))


def chart(result, ref, rgb_img):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), gridspec_kw=dict(width_ratios=[3, 2]))
    ax = axes[0]
    xs = [p["seconds"] for p in result["points"]]
    ys = [p["rel_rmse"] for p in result["points"]]
    ax.loglog(xs, ys, color="C0", marker="o", label="photon lightmap, spectral (ours)")
    for p in (result["points"][0], result["points"][-1]):
        ax.annotate(f"{p['photons'] / 1e3:g}k", (p["seconds"], p["rel_rmse"]), fontsize=7,
                    textcoords="offset points", xytext=(3, 3))
    r = result["rgb"]
    ax.loglog([r["seconds"]], [r["rel_rmse"]], color="C3", marker="^", ls="none",
              label="RGB tracing (no dispersion: what an RGB renderer gets)")
    ax.axhline(result["reference_noise"], color="0.6", ls=":", lw=1, label="reference noise (removed)")
    ax.set_xlabel("photon pass, wall-clock seconds (2 cores)")
    ax.set_ylabel("relative RMSE vs converged spectral run")
    ax.set_title("prism rainbow on the floor: error vs time", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    peak = max(float(ref.max()), 1e-12)

    def show(img):
        x = np.clip(img / peak, 0.0, 1.0)
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)[::-1]
    axes[1].imshow(np.concatenate([show(ref), np.ones((RES, 4, 3)), show(rgb_img)], axis=1))
    axes[1].set_title("floor lightmaps: spectral reference | RGB", fontsize=9)
    axes[1].axis("off")
    fig.tight_layout()
    fig.savefig(OUT / "prism_error_vs_time.png", dpi=72)
    plt.close(fig)


if __name__ == "__main__":
    main()
