"""Spectral mode (engine/spectral.py): an RGB scene traced in 16 wavelength bands
gives back its RGB result where colour does not mix (greys, direct light) and
stays close where it does; what it cannot take yet is refused by name."""
import math
from dataclasses import replace

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes, session, spectral
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.core.scene import (Camera, EnvironmentMap, Light, Material, Scene, SceneError, Texture,
                                                translate)
from photon_lightmaps.engine.shading import spectrum
from photon_lightmaps.engine.transport import renderer, texel_gather
from photon_lightmaps.engine.transport.photon_tracer import trace_photons

RHO, FLUX = 0.5, 100.0


def lookup_bake(scene, photons, seed):
    cs = compile_scene(scene)
    trace_photons(cs, photons, seed=seed, max_bounces=64, record_direct=False)
    lids = sorted(int(lid) for ids in cs.instance_lightmaps for lid in ids)
    texel_gather.bake_texels(cs, lids, 16, seed=seed)
    return cs


def area_mean(cs):
    lm = cs.lightmaps
    rows = np.flatnonzero(lm.area > 0)
    E = (lm.irradiance[rows] * lm.area[rows, None]).sum(axis=0) / lm.area[rows].sum()
    return spectral.to_rgb(cs, E)


def test_spectral_furnace_is_the_rgb_furnace_and_the_closed_form():
    """A point light in a closed grey sphere: the same photons take the same paths in
    both modes (greys are flat), so the spectral bake comes back as the RGB bake to
    rounding, and both at Φ / (A (1 - ρ))."""
    rgb = demo_scenes.furnace_sphere(RHO, FLUX, source=(0.3, -0.2, 0.1), resolution=12)
    spec = spectral.spectral_scene(rgb)
    assert spec.n_bands == spectrum.N_BANDS and spec.spectral is not None
    a, b = lookup_bake(rgb, 300_000, 3), lookup_bake(spec, 300_000, 3)
    assert b.spectral is spec.spectral and b.n_bands == 16
    ma, mb = area_mean(a), area_mean(b)
    np.testing.assert_allclose(mb, ma, rtol=1e-9)
    A = a.lightmaps.area[a.lightmaps.area > 0].sum()
    np.testing.assert_allclose(ma, FLUX / (A * (1 - RHO)), rtol=0.005)


def test_direct_light_comes_back_as_in_rgb():
    """Direct light per texel in the Cornell room, in both modes with the same
    samples: a texel's irradiance is the light's spectrum times geometry, and the
    light's RGB survives the bands (within 1e-4)."""
    scene = demo_scenes.cornell_box(n_bands=3, with_primitives=False)
    scene.lights[0].color = np.array([1.0, 0.8, 0.6])
    out = []
    for sc in (scene, spectral.spectral_scene(scene)):
        cs = compile_scene(sc)
        lids = sorted(int(lid) for ids in cs.instance_lightmaps for lid in ids)
        ids, E = texel_gather.direct_texel_irradiance(cs, lids, 16, seed=1)
        out.append(spectral.to_rgb(cs, E))
    scale = out[0].max()
    assert scale > 0
    np.testing.assert_allclose(out[1], out[0], atol=1e-4 * scale)


def test_colour_bleeding_stays_close_to_rgb():
    """The Cornell room's red and green walls bleed onto the others; in bands the
    product of two colours is not the product of their RGB, so the modes differ
    there, but by little: the room's mean within 1 % per channel (measured 0.3 %)."""
    scene = demo_scenes.cornell_box(n_bands=3, with_primitives=False)
    a = lookup_bake(scene, 400_000, 2)
    b = lookup_bake(spectral.spectral_scene(scene), 400_000, 2)
    ma, mb = area_mean(a), area_mean(b)
    print("\nroom mean RGB", ma, "spectral", mb)
    np.testing.assert_allclose(mb, ma, rtol=0.01)


def test_render_returns_rec709_and_its_tiles_too():
    scene = spectral.spectral_scene(demo_scenes.cornell_box(n_bands=3, width=16, height=16,
                                                            with_primitives=False))
    cs = session.compile(scene)
    settings = session.Settings(photons=20_000, samples=2, gather_rays=2)
    session.render_photon_pass(cs, settings)
    tiles = []
    img = session.render(cs, settings, tile=8, progress=lambda x0, y0, t, im: tiles.append(t.shape))
    assert img.shape == (16, 16, 3) and np.all(np.isfinite(img)) and img.mean() > 0
    assert tiles and all(s[2] == 3 for s in tiles)


def _patch(colour, textured, kelvin=0.0, bands=None):
    """The camera's RGB of a sunlit patch of `colour`, its base colour a constant or a 2 x 2
    texture of it, in spectral mode; the sun white, or a blackbody at kelvin."""
    bands = bands or spectrum.Bands()
    s = Scene(n_bands=3)
    c = np.asarray(colour, np.float64)
    m = s.add_material(Material("patch", diffuse=c, base_color=c))
    if textured:
        s.textures.append(Texture(np.tile(c.astype(np.float32), (2, 2, 1)), name="paint"))
        s.materials[m].textures = {"base_color": 0}
    s.add_object(demo_scenes.quad_mesh((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), material=m, name="patch"),
                 name="patch", lightmap_resolution=2)
    sun = spectrum.to_rgb(spectrum.blackbody_spectrum(kelvin, bands), bands) if kelvin else np.ones(3)
    s.lights.append(Light("sun", power=2.0, color=sun, temperature=kelvin, name="sun"))
    s.camera = Camera(transform=translate(0.0, 0.0, 3.0), fov=math.radians(10.0), width=2, height=2)
    cs = compile_scene(spectral.spectral_scene(s, bands))
    return spectral.to_rgb(cs, renderer.render(cs, samples=4, indirect=False)).reshape(-1, 3).mean(axis=0)


@pytest.mark.parametrize("colour", [(0.8, 0.1, 0.1), (0.2, 0.5, 0.7), (0.6, 0.6, 0.6), (0.05, 0.9, 0.3)])
def test_textured_colours_become_spectra_per_hit(colour):
    """A base-colour texture in spectral mode: under the white light it gives back its RGB as
    the constant colour does (within 5e-5: grid colours at 0 and 1 are held 1e-4 inside, as
    a sigmoid never reaches them); under 3000 K light, where the spectrum's shape matters,
    it stays within 0.001 of the constant colour's (measured: 0.0005)."""
    for kelvin, tol in ((0.0, 5e-5), (3000.0, 0.001)):
        flat, tex = _patch(colour, False, kelvin), _patch(colour, True, kelvin)
        white = _patch((1.0, 1.0, 1.0), False, kelvin)
        np.testing.assert_allclose(tex / white, flat / white, atol=tol, err_msg=f"{kelvin} K")
    np.testing.assert_allclose(_patch(colour, True) / _patch((1.0, 1.0, 1.0), False), colour, atol=5e-5)


def test_a_world_map_keeps_its_colours_as_spectra():
    """A world image map in spectral mode: every pixel a non-negative spectrum whose RGB is the
    pixel's (within 2e-4 of its brightest channel: a sigmoid never reaches 1), grey pixels the
    white light; the camera sees the sky it sees in RGB, and the world's power per RGB
    channel is kept."""
    rng = np.random.default_rng(3)
    sky = (rng.random((8, 16, 3)) * np.array([2.0, 1.0, 0.5])).astype(np.float32)
    sky[0, 0] = 0.7                                                  # a grey pixel
    s = Scene(n_bands=3)
    s.environment = EnvironmentMap(sky, name="sky")
    s.camera = Camera(fov=math.radians(120.0), width=8, height=8)
    bands = spectrum.Bands()
    sp = spectral.spectral_scene(s, bands)
    px = sp.environment.pixels
    assert px.shape == (8, 16, bands.n) and np.all(px >= 0.0)
    np.testing.assert_allclose(spectrum.to_rgb(px, bands), sky, atol=2e-4 * sky.max())
    np.testing.assert_allclose(px[0, 0], 0.7 * bands.white, rtol=1e-3)
    rgb_cs, sp_cs = compile_scene(s), compile_scene(sp)
    img_rgb = renderer.render(rgb_cs, samples=4, indirect=False)
    img_sp = spectral.to_rgb(sp_cs, renderer.render(sp_cs, samples=4, indirect=False))
    np.testing.assert_allclose(img_sp, img_rgb, atol=2e-4 * sky.max())
    np.testing.assert_allclose(spectrum.to_rgb(sp_cs.environment.power, bands), rgb_cs.environment.power, rtol=1e-3)


def test_only_rgb_scenes_become_spectral():
    with pytest.raises(SceneError, match="must be RGB"):
        spectral.spectral_scene(demo_scenes.cornell_box(n_bands=1))


@pytest.mark.parametrize("kelvin", [math.inf, math.nan, 1e9])
def test_blackbody_temperatures_are_checked_by_name(kelvin):
    """A light's or glowing material's temperature that Planck's law cannot take is refused
    with its owner named, not turned into a black or NaN spectrum."""
    s = demo_scenes.cornell_box(n_bands=3, with_primitives=False)
    s.lights[0] = replace(s.lights[0], temperature=kelvin)
    with pytest.raises(SceneError, match="light 'ceiling_light'.*blackbody temperature"):
        spectral.spectral_scene(s)
    s = demo_scenes.cornell_box(n_bands=3, with_primitives=False)
    s.materials[0] = replace(s.materials[0], emission=1.0, emission_temperature=kelvin)
    with pytest.raises(SceneError, match="material 'white'.*blackbody temperature"):
        spectral.spectral_scene(s)


def test_no_material_makes_light_in_any_band():
    """Lobes fitted one by one may sum above 1 in a band; they are scaled down there."""
    from photon_lightmaps.engine.core.scene import Material, Scene
    s = Scene(n_bands=3)
    s.add_material(Material("mix", diffuse=np.array([0.1, 0.5, 0.02]), specular=np.array([0.88, 0.49, 0.97])))
    m = spectral.spectral_scene(s).materials[0]
    total = np.asarray(m.diffuse) + np.asarray(m.specular) + np.asarray(m.transmission)
    assert np.all(total <= 1.0 + 1e-12)


def test_a_blackbody_light_emits_plancks_spectrum():
    """A light at 3000 K whose colour is that blackbody's RGB (no tint) emits Planck's
    spectrum at the colour's luminance, so it comes back as its colour; a tint
    multiplies the spectrum and keeps the luminance."""
    from photon_lightmaps.engine.core.scene import Light, Scene
    bands = spectrum.Bands()
    planck_rgb = spectrum.to_rgb(spectrum.blackbody_spectrum(3000.0, bands), bands)
    s = Scene(n_bands=3)
    s.lights += [Light("point", color=2.0 * planck_rgb, temperature=3000.0, name="plain"),
                 Light("point", color=planck_rgb * np.array([0.5, 1.0, 0.8]), temperature=3000.0, name="tinted")]
    plain, tinted = (lt.color for lt in spectral.spectral_scene(s).lights)
    ratio = plain / spectrum.blackbody_spectrum(3000.0, bands)
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-3)          # Planck's shape
    np.testing.assert_allclose(spectrum.to_rgb(plain, bands), 2.0 * planck_rgb, rtol=1e-3)
    y = np.linalg.inv(bands.xyz_to_rgb)[1]
    assert spectrum.luminance(tinted, bands) == pytest.approx(float(y @ (planck_rgb * [0.5, 1.0, 0.8])), rel=1e-9)


def test_a_line_light_emits_its_line_with_a_white_lights_power():
    """A 395 nm line (15 nm wide) puts 94 % of its power into the 380-405 nm band and carries
    what the white light of that power carries over the bands; a line outside the bands is
    refused by name."""
    bands = spectrum.Bands()
    s = Scene(n_bands=3)
    s.lights.append(Light("point", power=10.0, name="uv lamp", line_nm=395.0, line_width=15.0))
    c = spectral.spectral_scene(s, bands).lights[0].color
    assert c[0] > 0.9 * c.sum() and c.sum() == pytest.approx(bands.white.sum(), rel=0.02)
    s.lights[0] = replace(s.lights[0], line_nm=300.0)
    with pytest.raises(SceneError, match="light 'uv lamp'.*outside the spectral bands"):
        spectral.spectral_scene(s, bands)
