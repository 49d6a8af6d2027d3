"""Fluorescence (engine/shading/fluorescence.py): the re-radiation matrix against its
integrals and energy bounds, photons moving power between bands, and the camera
pass showing a dye's glow under light it cannot reflect."""
import math
from dataclasses import replace

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes, spectral
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.core.scene import Camera, Light, Material, Scene, SceneError, translate
from photon_lightmaps.engine.shading import fluorescence as F
from photon_lightmaps.engine.shading import spectrum
from photon_lightmaps.engine.transport import renderer
from photon_lightmaps.engine.transport.photon_tracer import trace_photons

# the reference notes' test model: excitation 450/20 nm, emission 520/25 nm
MODEL = F.Fluorescence("test model", 450.0, 20.0, 520.0, 25.0, peak=0.7, quantum_yield=0.85)


@pytest.mark.parametrize("fl", [MODEL] + list(F.PRESETS.values()), ids=lambda f: f.name)
def test_every_input_band_sends_back_at_most_what_it_receives(fl):
    """Over the 16 bands and a white surface (reflectance 1): reflected (what the dye's
    absorption leaves) plus re-emitted <= 1 in every input band, nothing re-emitted at a
    shorter wavelength, and the dye's absorption taken from the reflectance."""
    bands = spectrum.Bands()
    M, kd = F.compile_fluorescence(fl, np.ones(bands.n), bands)
    assert np.all(M >= 0.0) and np.all(np.triu(M, 1) == 0.0)        # M[o, i] = 0 for o < i
    assert np.all(kd + M.sum(axis=0) <= 1.0 + 1e-12)
    np.testing.assert_allclose(kd, 1.0 - F.band_absorption(fl, bands))
    # what is re-emitted is at most the quantum yield of what is absorbed
    assert np.all(M.sum(axis=0) <= fl.quantum_yield * F.band_absorption(fl, bands) + 1e-12)


def _model_total(nm):
    """The test model's power re-emitted per unit absorbed-band power at nm: q a(nm) times the
    integral of e(λ) nm / λ over λ > nm (photons counted by the quantum yield), by the
    midpoint rule at 1e-3 nm out to 12 σ."""
    h = 1e-3
    lam = nm + (np.arange(int(12 * MODEL.emission_width / h + 200 / h)) + 0.5) * h
    return MODEL.quantum_yield * float(MODEL.absorption(nm)) * float(np.sum(MODEL.emission(lam) * nm / lam) * h)


def test_monochromatic_450_nm_light_re_emits_the_model_total():
    """With 1 nm bands, the band around 450 nm re-emits the model's total within 1e-4, and its
    excitation is the model's a(450) within 2e-4 (a Gaussian averaged over the band's 1 nm)."""
    bands = spectrum.Bands(400, 379.5, 779.5)
    k = 70                                                        # [449.5, 450.5] nm
    M = F.reradiation_matrix(MODEL, bands)
    assert M[:, k].sum() == pytest.approx(_model_total(450.0), rel=1e-4)
    assert F.band_absorption(MODEL, bands)[k] == pytest.approx(0.7, rel=2e-4)
    # the Stokes shift: what 450 nm light gains is green, around the emission peak
    peak = bands.lo + (np.argmax(M[:, k]) + 0.5) * (bands.hi - bands.lo) / bands.n
    assert abs(peak - 518.0) < 3.0


def _dye_plane(fl, kd=0.0, bands=None, sun=None, camera=False):
    """A 2 m plane of diffuse kd with fluorophore fl under a sun straight down (strength 2;
    `sun`: its spectrum per band instead of white), spectral over `bands`."""
    s = Scene(n_bands=3)
    m = s.add_material(Material("dye", diffuse=kd, fluorescence=fl))
    s.add_object(demo_scenes.quad_mesh((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), material=m, name="plane"),
                 name="plane", lightmap_resolution=4)
    s.lights.append(Light("sun", power=2.0, name="sun"))
    s.camera = Camera(transform=translate(0.0, 0.0, 3.0), fov=math.radians(20.0), width=8, height=8)
    s = spectral.spectral_scene(s, bands or spectrum.Bands())
    if sun is not None:
        s.lights = [replace(s.lights[0], color=np.asarray(sun, np.float64))]
    return s


@pytest.mark.parametrize("band", [1, 3])
def test_photons_carry_re_emitted_light_into_longer_bands(band):
    """Photons of one band onto a black dye plane: what escapes after one bounce is M's column
    of that band, band by band, within the photon noise; the energy ledger balances exactly
    and the photons lose power overall."""
    bands = spectrum.Bands()
    sun = np.zeros(bands.n)
    sun[band] = 1.0
    cs = compile_scene(_dye_plane(F.PRESETS["fluorescent yellow"], bands=bands, sun=sun))
    st = trace_photons(cs, 200_000, seed=4, max_bounces=4, record_direct=True)
    lm = cs.lightmaps
    incident = (lm.irradiance * lm.area[:, None]).sum(axis=0)      # what reached the plane (the rest missed it)
    assert np.all(incident[np.arange(bands.n) != band] == 0.0)
    M = cs.materials.fluor[0]
    want = M[:, band] * incident[band]
    left = st.escaped.copy()
    left[band] -= st.emitted[band] - incident[band]
    assert st.audit_error() < 1e-9
    assert abs(left.sum() / want.sum() - 1.0) < 0.01
    np.testing.assert_allclose(left, want, atol=0.01 * want.sum())
    assert st.absorbed.sum() > 0.0 and st.escaped[:band].sum() == 0.0


def test_the_camera_sees_the_dye_glow():
    """Looking down at the dye plane under the sun: each band's radiance is (kd E + M E) / π
    for the sun's irradiance E per band (direct light is sampled exactly), and under light
    the dye only absorbs (a band it cannot reflect) the plane glows in longer bands."""
    bands = spectrum.Bands()
    fl = F.PRESETS["fluorescent yellow"]
    cs = compile_scene(_dye_plane(fl, kd=0.5, bands=bands))
    img = renderer.render(cs, samples=4, seed=0, indirect=False)
    E = 2.0 * np.asarray(bands.white)                              # a grey sun is the white light
    kd, M = cs.materials.diffuse[0], cs.materials.fluor[0]
    np.testing.assert_allclose(img[4, 4], (kd * E + M @ E) / math.pi, rtol=1e-6)
    blue = np.zeros(bands.n)
    blue[2] = 1.0                                                  # 430-455 nm, where the dye absorbs
    glow = renderer.render(compile_scene(_dye_plane(fl, bands=bands, sun=2.0 * blue)), samples=4, indirect=False)
    assert np.all(glow[4, 4, :2] == 0.0) and glow[4, 4, 4:9].min() > 0.0
    rgb = spectrum.to_rgb(glow[4, 4], bands)
    assert rgb[1] > rgb[2]                                         # blue light in, green glow out


def test_rgb_ignores_fluorescence_and_bad_values_are_refused():
    s = Scene(n_bands=3)
    s.add_material(Material("dye", diffuse=0.5, fluorescence=F.PRESETS["fluorescein"]))
    s.add_object(demo_scenes.prism_mesh(), name="block")
    assert not compile_scene(s).materials.fluorescent.any()
    assert compile_scene(spectral.spectral_scene(s)).materials.fluorescent[0]
    for bad, words in ((replace(MODEL, peak=1.5), "absorption and quantum yield"),
                       (replace(MODEL, emission_width=0.0), "positive finite"), ("fluorescein", "a Fluorescence")):
        s.materials[0] = Material("dye", diffuse=0.5, fluorescence=bad)
        with pytest.raises(SceneError, match=f"material 'dye'.*{words}"):
            compile_scene(spectral.spectral_scene(s))


def test_a_uv_lamp_makes_an_optical_brightener_glow_blue():
    """A 395 nm lamp (15 nm wide, a line light) on white paper with and without an optical
    brightener: the eye hardly sees the lamp on plain paper, the brightened paper glows blue,
    over 10 times brighter (measured 41 times)."""
    bands = spectrum.Bands()
    seen = {}
    for fl in (F.PRESETS["optical brightener"], None):
        s = Scene(n_bands=3)
        m = s.add_material(Material("paper", diffuse=0.8, fluorescence=fl))
        s.add_object(demo_scenes.quad_mesh((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), material=m,
                                           name="paper"), name="paper", lightmap_resolution=4)
        s.lights.append(Light("sun", power=2.0, name="uv lamp", line_nm=395.0, line_width=15.0))
        s.camera = Camera(transform=translate(0.0, 0.0, 3.0), fov=math.radians(20.0), width=8, height=8)
        img = renderer.render(compile_scene(spectral.spectral_scene(s, bands)), samples=4, indirect=False)
        seen[fl is not None] = img[4, 4]
    glow, plain = (spectrum.luminance(seen[k], bands) for k in (True, False))
    assert glow > 10.0 * plain
    rgb = spectrum.to_rgb(seen[True], bands)
    assert rgb[2] > 5.0 * max(rgb[0], rgb[1])
