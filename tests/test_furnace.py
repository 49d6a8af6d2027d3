"""Furnace tests: a closed diffuse sphere with a source inside has a closed-form answer.

Every photon ends absorbed on the sphere, so with albedo rho the mean
irradiance over the inside is Phi / (A (1 - rho)) for any closed shape of area A,
and the indirect part rho Phi / (A (1 - rho)) is even uniform on a sphere.
"""
import math

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons

RHO, FLUX = 0.5, 100.0


def mean_irradiance(cs):
    lm = cs.lightmaps
    return lm.flux.sum(axis=0) / lm.area.sum()


def surface_area(cs):
    return cs.lightmaps.area.sum()


@pytest.mark.parametrize("mesh", [False, True], ids=["analytic", "triangle_mesh"])
def test_furnace_indirect_matches_closed_form(mesh):
    scene = demo_scenes.furnace_sphere(RHO, FLUX, source=(0.3, 0.1, -0.2), mesh=mesh)
    cs = compile_scene(scene)
    stats = trace_photons(cs, 200_000, seed=1, max_bounces=64, record_direct=False)
    A = surface_area(cs)
    if not mesh:
        assert A == pytest.approx(4 * math.pi, rel=1e-6), "exact texel areas must sum to 4 pi R^2"
    expected = RHO * FLUX / (A * (1 - RHO))
    got = mean_irradiance(cs)
    # ~2 hits per photon on average, 2e5 photons: statistical error well below 1 %.
    np.testing.assert_allclose(got, expected, rtol=0.015)
    assert stats.escaped.max() == 0.0, "nothing escapes a closed sphere"


def test_furnace_indirect_is_uniform_on_the_sphere():
    scene = demo_scenes.furnace_sphere(RHO, FLUX, source=(0.5, 0.0, 0.3), resolution=8)
    cs = compile_scene(scene)
    trace_photons(cs, 300_000, seed=2, max_bounces=64, record_direct=False)
    lm = cs.lightmaps
    E = lm.flux[:, 0] / np.where(lm.area > 0, lm.area, np.inf)
    expected = RHO * FLUX / (4 * math.pi * (1 - RHO))
    used = lm.hits > 200
    assert used.sum() > 0.9 * used.size
    # Per texel the relative noise is about 1/sqrt(hits); a non-uniform estimator
    # (e.g. wrong texel areas near the octahedral seams) would show a bias.
    rel = (E[used] - expected) / expected
    assert abs(rel.mean()) < 0.01
    assert np.percentile(np.abs(rel), 95) < 4.0 / np.sqrt(200)


@pytest.mark.parametrize("depth", [0, 1, 2, 5])
def test_furnace_truncated_series(depth):
    scene = demo_scenes.furnace_sphere(RHO, FLUX, source=(0.0, 0.2, 0.0))
    cs = compile_scene(scene)
    stats = trace_photons(cs, 100_000, seed=3, max_bounces=depth, record_direct=True)
    A = surface_area(cs)
    expected = FLUX / A * (1 - RHO ** (depth + 1)) / (1 - RHO)
    np.testing.assert_allclose(mean_irradiance(cs), expected, rtol=0.015)
    # Truncation is booked: what survives the last bounce is counted, not lost.
    assert stats.audit_error() < 1e-12
    if depth == 0:
        np.testing.assert_allclose(stats.truncated, FLUX, rtol=1e-9)


def test_kept_photon_points_lie_on_the_surface_and_carry_the_recorded_flux():
    """keep_points hands photon-map baselines exactly what the lightmaps received."""
    cs = compile_scene(demo_scenes.furnace_sphere(RHO, FLUX, radius=2.0))
    stats = trace_photons(cs, 20_000, seed=4, max_bounces=3, record_direct=True, keep_points=True)
    assert stats.points.shape == (stats.records, 6)
    np.testing.assert_allclose(np.linalg.norm(stats.points[:, :3], axis=1), 2.0, rtol=1e-9)
    np.testing.assert_allclose(stats.point_power.sum(axis=0), cs.lightmaps.flux.sum(axis=0), rtol=1e-12)
