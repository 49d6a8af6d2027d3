"""Spectral bands (engine/shading/spectrum.py): RGB -> spectrum -> RGB round trips,
the white light, and the CIE data against colour-science's own integration."""
import colour
import numpy as np
import pytest

from photon_lightmaps.engine.shading import spectrum as S

BANDS = S.Bands()
# sRGB's XYZ -> linear RGB as published (IEC 61966-2-1), for D65 at x, y = 0.3127, 0.3290
PUBLISHED_XYZ_TO_REC709 = np.array([[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415],
                                    [0.0557, -0.2040, 1.0570]])


def test_bands_cover_the_visible_range():
    assert BANDS.n == S.N_BANDS == 16
    np.testing.assert_allclose(BANDS.edges[[0, -1]], [380.0, 780.0])
    np.testing.assert_allclose(np.diff(BANDS.edges), 25.0)
    with pytest.raises(ValueError):
        S.Bands(2)


def test_reflectances_round_trip_within_1e3_and_stay_inside_0_1():
    """20 000 random colours of the whole RGB cube: back within 1e-3 (measured 9e-5:
    a sigmoid never reaches 0 or 1, so channels are held 1e-4 inside), every band
    strictly between 0 and 1."""
    rgb = np.random.default_rng(1).random((20_000, 3))
    sp = S.reflectance_spectrum(rgb, BANDS)
    assert sp.shape == (20_000, BANDS.n)
    assert np.all(sp > 0.0) and np.all(sp < 1.0)
    assert np.abs(sp @ BANDS.reflectance_matrix - rgb).max() < 1e-3
    # away from the cube's faces the fit is exact to the solver's tolerance
    inner = np.random.default_rng(2).uniform(0.01, 0.99, (2000, 3))
    assert np.abs(S.reflectance_spectrum(inner, BANDS) @ BANDS.reflectance_matrix - inner).max() < 1e-8


def test_a_grey_is_flat():
    sp = S.reflectance_spectrum(np.array([0.5, 0.5, 0.5]), BANDS)
    np.testing.assert_allclose(sp, 0.5, atol=1e-6)


def test_emission_round_trips_at_any_brightness():
    rgb = np.random.default_rng(3).random((500, 3)) * np.array([[100.0], [1.0], [0.01], [1e3], [5.0]]).repeat(100, 0)
    back = S.to_rgb(S.emission_spectrum(rgb, BANDS), BANDS)
    assert np.all(np.abs(back - rgb) <= 1e-3 * rgb.max(axis=1, keepdims=True))
    assert np.all(S.emission_spectrum(np.zeros(3), BANDS) == 0.0)


def test_the_white_light_is_rgb_one_and_d65():
    """The bands' white gives RGB (1, 1, 1) and luminance 1, and its chromaticity is
    D65's within the bands' discretisation (measured 4e-4)."""
    np.testing.assert_allclose(S.to_rgb(BANDS.white, BANDS), 1.0, atol=1e-12)
    assert abs(S.luminance(BANDS.white, BANDS) - 1.0) < 1e-12
    xyz = BANDS.white @ BANDS.cmf
    np.testing.assert_allclose(xyz[:2] / xyz.sum(), [0.3127, 0.3290], atol=1e-3)
    # the matrix of Rec.709's primaries with this white is the published one (measured 0.006 apart)
    np.testing.assert_allclose(BANDS.xyz_to_rgb, PUBLISHED_XYZ_TO_REC709, atol=0.01)


@pytest.mark.parametrize("kelvin", [2700, 5000, 6500])
def test_blackbody_chromaticity_matches_colour_science(kelvin):
    """Planck's law over the bands against colour-science's blackbody integrated at
    1 nm with the same observer: xy within 1e-3 (measured 4e-4)."""
    sd = colour.sd_blackbody(kelvin, colour.SpectralShape(360, 780, 1))
    ref = colour.sd_to_XYZ(sd, method="Integration")
    ours = S.blackbody_spectrum(kelvin, BANDS) @ BANDS.cmf
    np.testing.assert_allclose(ours[:2] / ours.sum(), ref[:2] / ref.sum(), atol=1e-3)
    assert abs(S.luminance(S.blackbody_spectrum(kelvin, BANDS), BANDS) - 1.0) < 1e-12


def test_band_cmfs_integrate_the_observer():
    """Each band's x̄ȳz̄ is the observer's integral over it: summed, the bands hold
    the observer's whole 380-780 nm integral (colour-science's tables)."""
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    wl = cmfs.wavelengths
    keep = (wl >= 380) & (wl <= 780)
    ref = np.trapz(cmfs.values[keep], wl[keep], axis=0)
    np.testing.assert_allclose(BANDS.cmf.sum(axis=0), ref, rtol=1e-4)
