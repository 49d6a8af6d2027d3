"""Writes engine/shading/data/conductors.npz: measured complex indices n + ik of metals.

Conductor presets (engine/shading/conductor.py) need each metal's refractive
index n and extinction k over the visible range. These are measured optical
constants (Palik's Handbook of Optical Constants of Solids, as the luxpop.com
database lists them); this script takes them from the tables Mitsuba 3 ships
(mitsuba/data/ior/<metal>.eta.spd and .k.spd), keeping every sample from 360 to
800 nm, so nothing is typed by hand and the add-on does not need Mitsuba.

    .venv/bin/pip install mitsuba==3.9.1         # not a requirement of the add-on or its tests
    .venv/bin/python scripts/make_conductor_data.py
"""
import pathlib

import numpy as np

OUT = pathlib.Path(__file__).resolve().parents[1] / "engine" / "shading" / "data" / "conductors.npz"
METALS = ("Ag", "Al", "Au", "Cu")
LO, HI = 360.0, 800.0


def _spd(path):
    rows = [line.split() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    return np.array([[float(a), float(b)] for a, b in rows])


def main():
    import mitsuba
    ior = pathlib.Path(mitsuba.__file__).parent / "data" / "ior"
    out = {}
    for m in METALS:
        eta, k = _spd(ior / f"{m}.eta.spd"), _spd(ior / f"{m}.k.spd")
        if not np.array_equal(eta[:, 0], k[:, 0]):
            raise SystemExit(f"{m}: n and k are sampled at different wavelengths")
        keep = (eta[:, 0] >= LO) & (eta[:, 0] <= HI)
        out[m] = np.stack([eta[keep, 0], eta[keep, 1], k[keep, 1]], axis=1)     # nm, n, k
    OUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT, **out, source=np.array(
        f"Mitsuba {mitsuba.__version__} data/ior/<metal>.eta.spd, .k.spd (luxpop.com, after Palik), "
        f"{LO:.0f}-{HI:.0f} nm; columns: wavelength nm, n, k"))
    print(f"wrote {OUT} ({OUT.stat().st_size} bytes): " + ", ".join(f"{m} {len(v)} samples" for m, v in out.items()))


if __name__ == "__main__":
    main()
