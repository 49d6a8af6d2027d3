"""Conductors (engine/shading/conductor.py): measured complex indices in the metal lobe."""
import numpy as np
import pytest

from photon_lightmaps.engine.core.scene import Instance, Material, Scene, SceneError
from photon_lightmaps.engine.demo_scenes import quad_mesh
from photon_lightmaps.engine.shading import bsdf, conductor, polarization
from photon_lightmaps.engine.shading.spectrum import Bands

from test_bsdf import _albedo, wo_of


def closure(mat, nb=3, bands=None, roughness=0.0, cos_o=0.6):
    bt = bsdf.compile_bsdf([mat], nb, bands)
    p = np.empty(bsdf.closure_size(nb))
    bsdf.closure_scalars(bt, 0, roughness, 1.5, True, cos_o, p)
    return p


def test_measured_data_gives_the_catalogued_reflectances():
    """Palik's n, k at 563.6 nm reflect what the physics notes catalogue at normal incidence."""
    for name, r0 in (("Cu", 0.6725), ("Au", 0.8776), ("Al", 0.9200)):
        wl, n, k = conductor.measured(name)
        i = int(np.argmin(abs(wl - 563.56)))
        assert (n[i], k[i]) == pytest.approx(polarization.CONDUCTORS[name], abs=1e-3)
        assert conductor.normal_reflectance(n[i], k[i]) == pytest.approx(r0, abs=1e-4)


@pytest.mark.parametrize("name", conductor.PRESETS)
@pytest.mark.parametrize("spectral", [False, True])
def test_smooth_conductor_reflects_fresnel_per_band(name, spectral):
    """A mirror of preset `name` reflects metallic x Fresnel(n_b, k_b) in every band, at every angle."""
    bands = Bands() if spectral else None
    nb = bands.n if spectral else 3
    nk = conductor.band_index(name, nb, bands)
    mat = Material(diffuse=0.0, metallic=0.8, conductor=name)
    for cos_o in (0.95, 0.5, 0.1):
        p = closure(mat, nb, bands, cos_o=cos_o)
        w = np.empty(nb)
        ok, ix, iy, iz, pdf, delta = bsdf.sample_glossy(p, np.zeros(nb), np.zeros(nb), 0.0, 1.0, 0.0,
                                                        *wo_of(cos_o), 0.3, 0.5, 0.5, 0.5, w)
        assert ok and delta
        want = [0.8 * conductor.reflectance(cos_o, a, b) for a, b in nk]
        assert w == pytest.approx(want, rel=1e-12)
    if spectral:                # band means of the measured table
        wl, n, k = conductor.measured(name)
        fine = np.linspace(bands.edges[3], bands.edges[4], 201)
        assert nk[3, 0] == pytest.approx(np.interp(fine, wl, n).mean(), rel=2e-3)


@pytest.mark.parametrize("name", conductor.PRESETS)
def test_rough_conductor_albedo(name):
    """A slightly rough conductor reflects its Fresnel at the viewing angle (within 0.01;
    measured 0.006 at roughness 0.3); a rougher one less, and never more than 1."""
    cos_o = 0.6
    fresnel = np.array([conductor.reflectance(cos_o, a, b) for a, b in conductor.rgb_index(name)])
    for roughness in (0.1, 0.3, 0.8):
        p = closure(Material(diffuse=0.0, metallic=1.0, conductor=name), roughness=roughness, cos_o=cos_o)
        alb, _ = _albedo(p, np.zeros(3), np.zeros(3), 0.0, 1.0, 0.0, *wo_of(cos_o), 40000, 3)
        assert np.all(alb <= 1.0)
        if roughness < 0.5:
            assert alb == pytest.approx(fresnel, abs=0.01)
        else:
            assert np.all(alb < fresnel) and np.all(alb > 0.7 * fresnel)


def test_white_conductor_furnace():
    """A conductor that reflects all light at every angle (k huge) is a white furnace."""
    p = closure(Material(diffuse=0.0, metallic=1.0, conductor=(1e-3, 1e4)), roughness=0.7, cos_o=0.4)
    alb, _ = _albedo(p, np.zeros(3), np.zeros(3), 0.0, 1.0, 0.0, *wo_of(0.4), 40000, 5)
    assert alb == pytest.approx(np.ones(3), abs=0.02)


def test_rgb_index_is_interpolated_in_spectral_mode():
    nk = conductor.band_index(((0.2, 0.4, 1.4), (3.4, 2.4, 1.8)), 16, Bands())
    assert nk[0] == pytest.approx([1.4, 1.8])                 # below 460 nm: blue's
    assert nk[-1] == pytest.approx([0.2, 3.4])                # above 650 nm: red's
    assert np.all(np.diff(nk[:, 0]) <= 1e-12)                  # n falls from blue to red


@pytest.mark.parametrize("bad", ["Unobtainium", (-1.0, 2.0), (0.5, float("nan")), "x"])
def test_bad_conductor_is_refused_by_name(bad):
    from photon_lightmaps.engine.compile import compile_scene
    quad = quad_mesh((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0))
    scene = Scene(materials=[Material(name="shiny", conductor=bad, metallic=1.0)], prototypes=[quad],
                  instances=[Instance(0)])
    with pytest.raises(SceneError, match="material 'shiny'"):
        compile_scene(scene)
