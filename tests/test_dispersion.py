"""Dispersion (engine/shading/dispersion.py): Sellmeier presets against their
catalogue values, Cauchy from an Abbe number, a prism's minimum deviation."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine.shading import dispersion as D


@pytest.mark.parametrize("name", sorted(D.PRESETS))
def test_presets_give_the_catalogue_n_d_and_abbe_number(name):
    """n_d within 1e-5 of the catalogue (diamond's is catalogued to four decimals:
    within half of its last digit), V_d within half of its last digit."""
    g = D.PRESETS[name]
    assert abs(float(D.sellmeier_index(g, D.LINE_D)) - g.n_d) < (5e-5 if name == "diamond" else 1e-5)
    assert abs(D.abbe_number(lambda wl: float(D.sellmeier_index(g, wl))) - g.abbe) < (0.05 if name == "diamond"
                                                                                       else 0.005)


def test_a_60_degree_bk7_prism_deviates_the_f_d_c_lines_as_catalogued():
    """39.138, 38.647 and 38.429 degrees at the F, d and C lines (within 0.05)."""
    bk7 = D.PRESETS["N-BK7"]
    got = [D.minimum_deviation(float(D.sellmeier_index(bk7, wl))) for wl in (D.LINE_F, D.LINE_D, D.LINE_C)]
    np.testing.assert_allclose(got, [39.138, 38.647, 38.429], atol=0.05)
    # shorter waves bend more: normal dispersion over the visible range
    wl = np.linspace(380.0, 780.0, 41)
    assert np.all(np.diff(D.sellmeier_index(bk7, wl)) < 0.0)


def test_cauchy_from_n_d_and_abbe_number():
    A, B = D.cauchy_from_abbe(1.5168, 64.17)
    assert abs(D.cauchy_index(A, B, D.LINE_D) - 1.5168) < 1e-12
    assert abs(D.abbe_number(lambda wl: D.cauchy_index(A, B, wl)) - 64.17) < 1e-9
    # close to the Sellmeier glass it stands in for, over the visible range
    wl = np.linspace(400.0, 700.0, 31)
    assert np.abs(D.cauchy_index(A, B, wl) - D.sellmeier_index(D.PRESETS["N-BK7"], wl)).max() < 1e-3
    for bad in ((1.0, 60.0), (1.5, 0.0), (math.nan, 40.0)):
        with pytest.raises(ValueError):
            D.cauchy_from_abbe(*bad)
