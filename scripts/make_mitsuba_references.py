"""Regenerates the Mitsuba 3 spectral references the tests compare with (tests/data/mitsuba_spectral.json).

    .venv/bin/pip install mitsuba==3.9.1         # not a requirement of the add-on or its tests
    .venv/bin/python scripts/make_mitsuba_references.py

Mitsuba's `scalar_spectral` variant is an independent spectral renderer: its
own RGB upsampling (Jakob & Hanika's tables), blackbody and D65 emitters, and
spectral-to-sRGB film. Where its features overlap ours it answers what a
coloured diffuse patch looks like under a light whose spectrum is not white,
which products of RGB colours get wrong. Scene: a Lambertian 2 x 2 m
rectangle, reflectance an sRGB colour, a point light 1 m above its middle, a
camera looking at the middle (direct illumination: the patch sees nothing
else). Stored per illuminant: each patch's camera RGB over the white patch's,
channel by channel, from two renders with different seeds (their difference
bounds Mitsuba's own noise).
"""
import json
import pathlib
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "tests" / "data" / "mitsuba_spectral.json"
SPP = 16384
SEEDS = (1, 2)
# sRGB colours (linear): saturated primaries, a yellow and a cyan (both partly out of what
# 3000 K light keeps in gamut) and two Macbeth-like naturals (skin, foliage)
PATCHES = {"red": [0.8, 0.1, 0.1], "green": [0.1, 0.6, 0.15], "blue": [0.1, 0.2, 0.8],
           "yellow": [0.9, 0.8, 0.1], "cyan": [0.1, 0.7, 0.8], "skin": [0.45, 0.32, 0.25],
           "foliage": [0.12, 0.18, 0.06]}
# name -> Mitsuba intensity spectrum; the tests build the same light (a blackbody at
# that temperature, or our white light, D65)
ILLUMINANTS = {"blackbody 3000 K": {"type": "blackbody", "temperature": 3000.0},
               "blackbody 5000 K": {"type": "blackbody", "temperature": 5000.0},
               "D65": {"type": "d65"}}


def main():
    import mitsuba as mi
    mi.set_variant("scalar_spectral")

    def render(rgb, intensity, seed):
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "direct"},
            "sensor": {"type": "perspective", "fov": 1.0,
                       "to_world": mi.ScalarTransform4f().look_at(origin=[0, -1, 2], target=[0, 0, 0], up=[0, 0, 1]),
                       "sampler": {"type": "independent", "sample_count": SPP},
                       "film": {"type": "hdrfilm", "width": 2, "height": 2, "rfilter": {"type": "box"},
                                "pixel_format": "rgb"}},
            "patch": {"type": "rectangle", "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": rgb}}},
            "light": {"type": "point", "position": [0, 0, 1], "intensity": intensity},
        })
        return np.array(mi.render(scene, seed=seed)).reshape(-1, 3).mean(axis=0)

    t0 = time.perf_counter()
    results = {}
    for name, intensity in ILLUMINANTS.items():
        halves = []
        for seed in SEEDS:
            white = render([1.0, 1.0, 1.0], intensity, seed)
            halves.append({p: (render(rgb, intensity, seed) / white).tolist() for p, rgb in PATCHES.items()})
        results[name] = {p: dict(ratio=np.mean([h[p] for h in halves], axis=0).tolist(),
                                 half_spread=np.abs(np.subtract(halves[0][p], halves[1][p])).max())
                         for p in PATCHES}
    OUT.write_text(json.dumps(dict(
        renderer=f"Mitsuba {mi.__version__}, variant scalar_spectral, integrator direct",
        generator="scripts/make_mitsuba_references.py", samples_per_half=SPP, seeds=list(SEEDS),
        scene="Lambertian rectangle [-1, 1]^2 (sRGB reflectance), point light at (0, 0, 1), camera at its middle",
        quantity="camera RGB of the patch over that of a white patch, per channel",
        patches=PATCHES, illuminants=list(ILLUMINANTS), results=results,
        seconds=round(time.perf_counter() - t0, 1)), indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
