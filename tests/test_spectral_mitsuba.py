"""Spectral mode against Mitsuba 3's scalar_spectral renderer (an independent spectral
reference, stored as data: tests/data/mitsuba_spectral.json, from
scripts/make_mitsuba_references.py, with its provenance).

A coloured diffuse patch under a light whose spectrum is not white: what the camera
sees, relative to a white patch, channel by channel. RGB tracing multiplies RGB
colours and gets the patch's own colour back whatever the light; a spectrum times a
spectrum does not, and Mitsuba and spectral mode agree on by how much."""
import json
import math
import pathlib

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes, spectral
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.core.scene import Camera, Light, Material, Scene, translate
from photon_lightmaps.engine.shading import spectrum
from photon_lightmaps.engine.transport import renderer

REF = json.loads((pathlib.Path(__file__).parent / "data" / "mitsuba_spectral.json").read_text())
KELVIN = {"blackbody 3000 K": 3000.0, "blackbody 5000 K": 5000.0, "D65": 0.0}


def patch_rgb(rgb, kelvin, spectral_mode=True):
    """The camera's RGB of the middle of a 2 x 2 m patch of colour rgb, a point light 1 m above:
    a blackbody at kelvin (pure Planck: its colour is the blackbody's own), or white (0)."""
    bands = spectrum.Bands()
    s = Scene(n_bands=3)
    m = s.add_material(Material("patch", diffuse=np.asarray(rgb, np.float64)))
    s.add_object(demo_scenes.quad_mesh((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), material=m, name="patch"),
                 name="patch", lightmap_resolution=2)
    colour = spectrum.to_rgb(spectrum.blackbody_spectrum(kelvin, bands), bands) if kelvin else np.ones(3)
    s.lights.append(Light("point", power=100.0, color=colour, temperature=kelvin, transform=translate(0, 0, 1),
                          name="lamp"))
    s.camera = Camera(transform=translate(0.0, 0.0, 3.0), fov=math.radians(1.0), width=2, height=2)
    if spectral_mode:
        s = spectral.spectral_scene(s, bands)
    cs = compile_scene(s)
    return spectral.to_rgb(cs, renderer.render(cs, samples=4, indirect=False)).reshape(-1, 3).mean(axis=0)


@pytest.mark.parametrize("illuminant", list(KELVIN))
def test_coloured_patches_under_coloured_light_match_mitsuba(illuminant):
    """Every patch within 0.01 of Mitsuba's ratio in every channel (measured: 0.0064 at 3000 K,
    0.0015 at 5000 K, 0.0006 under D65, where Mitsuba's two halves differ by at most 0.0008);
    RGB tracing is off by up to 0.175 at 3000 K and 0.040 at 5000 K."""
    kelvin = KELVIN[illuminant]
    white = patch_rgb([1.0, 1.0, 1.0], kelvin)
    worst_rgb = 0.0
    for name, rgb in REF["patches"].items():
        want = np.asarray(REF["results"][illuminant][name]["ratio"])
        got = patch_rgb(rgb, kelvin) / white
        np.testing.assert_allclose(got, want, atol=0.01, err_msg=f"{illuminant}, {name}")
        worst_rgb = max(worst_rgb, float(np.abs(np.asarray(rgb) - want).max()))
    if kelvin == 3000.0:
        assert worst_rgb > 0.1            # what RGB tracing gets (the colour itself) is far off
