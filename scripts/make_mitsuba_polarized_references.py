"""Regenerates the Mitsuba 3 polarized references the tests compare with (tests/data/mitsuba_polarized.json).

    .venv/bin/pip install mitsuba==3.9.1         # not a requirement of the add-on or its tests
    .venv/bin/python scripts/make_mitsuba_polarized_references.py

Mitsuba's `scalar_spectral_polarized` variant traces Stokes vectors with its own
Fresnel, frames and conductor data, and its `stokes` integrator writes what the
camera receives as S0..S3 in the sensor's frame. Scene (each case): a camera looks
along d0 at a chain of smooth mirrors; mirror i sits at points[i] with the normal
that turns d_i into d_(i+1); the last direction meets a white glowing wall (D65,
facing back) 50 m on. Mirrors are conductors (Mitsuba's `conductor` with its
material's measured n, k) or a dielectric (`dielectric`, index 1.5, whose reflection
is what a clear coat over black reflects). Stored per case: the camera's Stokes
vector per RGB channel over the wall's RGB seen directly (so the units cancel), from
two renders with different seeds (their difference bounds Mitsuba's own noise, which
here is its sampling of wavelengths).
"""
import json
import pathlib
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUT = ROOT / "tests" / "data" / "mitsuba_polarized.json"
SPP = 16384
SEEDS = (1, 2)


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _reflect_at(theta_deg):
    """d0 straight down, d1 after a reflection at incidence theta in the x-z plane."""
    t = np.radians(theta_deg)
    return [[0.0, 0.0, -1.0], [float(np.sin(2 * t)), 0.0, float(np.cos(2 * t))]]


D2 = _unit([0.5, 1.0, 0.5]).tolist()
# name -> (directions d0..dk, mirror points, mirror materials camera-side first)
CASES = {
    "gold at 60 deg": (_reflect_at(60.0), [[0, 0, 0]], ["Au"]),
    "coat at Brewster's angle": (_reflect_at(56.31), [[0, 0, 0]], ["dielectric"]),
    "copper at 75 deg": (_reflect_at(75.0), [[0, 0, 0]], ["Cu"]),
    "gold, gold (planes 65 deg apart)": ([[0, 0, -1], [1, 0, 0], D2], [[0, 0, 0], [3, 0, 0]], ["Au", "Au"]),
    "coat, copper (planes 65 deg apart)": ([[0, 0, -1], [1, 0, 0], D2], [[0, 0, 0], [3, 0, 0]], ["dielectric", "Cu"]),
    "aluminium, coat (planes 65 deg apart)": ([[0, 0, -1], [1, 0, 0], D2], [[0, 0, 0], [3, 0, 0]],
                                              ["Al", "dielectric"]),
}


def main():
    import mitsuba as mi
    mi.set_variant("scalar_spectral_polarized")

    def rect(centre, normal, half):
        n = _unit(normal)
        u = _unit(np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0]))
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = u * half, np.cross(n, u) * half, n, centre
        return {"type": "rectangle", "to_world": mi.ScalarTransform4f(m.tolist())}

    def render(dirs, points, mats, seed, direct=False):
        dirs = [_unit(d) for d in dirs]
        last = np.asarray(points[-1], float)
        wall = rect(last + 50.0 * dirs[-1], -dirs[-1], 100.0)
        wall.update(emitter={"type": "area", "radiance": {"type": "d65"}}, bsdf={"type": "diffuse", "reflectance": 0.0})
        scene = {"type": "scene", "integrator": {"type": "stokes", "integrator": {"type": "path", "max_depth": 8}},
                 "wall": wall}
        if direct:       # the wall straight ahead
            eye, target, up = last, last + dirs[-1], [0, 0, 1] if abs(dirs[-1][2]) < 0.9 else [0, 1, 0]
        else:
            eye, target, up = np.asarray(points[0], float) - 5.0 * dirs[0], points[0], [0, 1, 0]
            for i, (p, m) in enumerate(zip(points, mats)):
                r = rect(p, dirs[i + 1] - dirs[i], 0.5)
                r["bsdf"] = ({"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0} if m == "dielectric"
                             else {"type": "conductor", "material": m})
                scene[f"mirror{i}"] = r
        scene["sensor"] = {"type": "perspective", "fov": 0.05,
                           "to_world": mi.ScalarTransform4f().look_at(origin=list(map(float, eye)),
                                                                      target=list(map(float, target)), up=up),
                           "sampler": {"type": "independent", "sample_count": SPP},
                           "film": {"type": "hdrfilm", "width": 1, "height": 1, "rfilter": {"type": "box"},
                                    "pixel_format": "rgb"}}
        img = np.array(mi.render(mi.load_dict(scene), seed=seed)).reshape(-1)
        return img[3:15].reshape(4, 3)                # S0..S3, each RGB

    t0 = time.perf_counter()
    results = {}
    for name, (dirs, points, mats) in CASES.items():
        halves = []
        for seed in SEEDS:
            white = render(dirs, points, mats, seed, direct=True)[0]
            halves.append(render(dirs, points, mats, seed) / white[None, :])
        results[name] = dict(directions=dirs, points=points, mirrors=mats,
                             stokes=np.mean(halves, axis=0).tolist(),
                             half_spread=float(np.abs(halves[0] - halves[1]).max()))
    OUT.write_text(json.dumps(dict(
        renderer=f"Mitsuba {mi.__version__}, variant scalar_spectral_polarized, integrator stokes(path)",
        generator="scripts/make_mitsuba_polarized_references.py", samples_per_half=SPP, seeds=list(SEEDS),
        scene="camera 5 m before the first mirror along d0, 0.05 deg field, 1 pixel; smooth mirrors (1 m squares) "
              "turning d_i into d_(i+1); a D65 glowing wall 50 m along the last direction",
        quantity="the pixel's Stokes vector S0..S3 per RGB channel, in the sensor's frame (S1 > 0: along the "
                 "image's horizontal), over the wall's RGB seen directly",
        results=results, seconds=round(time.perf_counter() - t0, 1)), indent=1))
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
