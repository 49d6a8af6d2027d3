"""Direct light against closed forms, through both paths that compute it:
photons recorded in the lightmap (baking) and light sampling in the renderer.
"""
import math

import numpy as np
import pytest

from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.demo_scenes import quad_mesh
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.transport.renderer import render
from photon_lightmaps.engine.core.scene import (
    Camera, Light, Material, Scene, compose, rotate, translate)

H = 1.0      # light height above the floor
HALF = 4.0   # floor half size


def floor_scene(light, res=64):
    s = Scene(n_bands=3)
    m = s.add_material(Material("white", diffuse=1.0))
    s.add_object(quad_mesh((-HALF, -HALF, 0), (HALF, -HALF, 0), (HALF, HALF, 0), (-HALF, HALF, 0),
                           material=m), name="floor", lightmap_resolution=res)
    s.lights.append(light)
    # Orthographic camera straight down, 1 pixel per 0.25 m over the middle.
    s.camera = Camera(transform=translate(0, 0, 5), kind="orthographic", ortho_scale=2.0,
                      width=8, height=8)
    return s


def point_E(P, h, r):
    return P / (4 * math.pi) * h / (h * h + r * r) ** 1.5


def disk_E(P, a, h):
    L = P / (math.pi * math.pi * a * a)
    return math.pi * L * a * a / (h * h + a * a)


def disk_E_over_square(P, a, h, side, n=400, m=8):
    """Mean irradiance of a downward disk light (radius a, height h) over the
    square [0, side]² beside its axis: midpoint quadrature over the disk's polar
    grid (n x n) and the square (m x m)."""
    L = P / (math.pi * math.pi * a * a)
    r = (np.arange(n) + 0.5) / n * a
    t = (np.arange(n) + 0.5) / n * 2 * math.pi
    R, T = np.meshgrid(r, t)
    qx, qy = R * np.cos(T), R * np.sin(T)
    dA = (a / n) * (2 * math.pi / n) * R
    g = (np.arange(m) + 0.5) / m * side
    E = [(L * h * h / ((qx - x) ** 2 + (qy - y) ** 2 + h * h) ** 2 * dA).sum() for x in g for y in g]
    return float(np.mean(E))


def central_texels_mean(cs, res, k=2):
    """Mean irradiance over the k x k texels around the floor centre, and their centre offsets."""
    lm = cs.lightmaps
    E = lm.irradiance[lm.offset[0]: lm.offset[0] + res * res].reshape(res, res, -1)
    c = res // 2
    return E[c - k // 2: c + k // 2, c - k // 2: c + k // 2].mean(axis=(0, 1))


def texel_average(f, res, k=2, n=64):
    """Average of an analytic radial field over the same central texels (fine midpoint rule)."""
    size = 2 * HALF * 0.996 / res  # quad_mesh maps the floor to 0.996 of the atlas
    xs = (np.arange(n * k) + 0.5) / (n * k) * k * size - k * size / 2
    X, Y = np.meshgrid(xs, xs)
    return float(np.mean(f(np.sqrt(X * X + Y * Y))))


def test_point_light_lightmap_and_render():
    P = 100.0
    scene = floor_scene(Light("point", power=P, transform=translate(0, 0, H)))
    cs = compile_scene(scene)
    trace_photons(cs, 400_000, seed=5, max_bounces=0, record_direct=True)
    expected = texel_average(lambda r: point_E(P, H, r), 64)
    np.testing.assert_allclose(central_texels_mean(cs, 64), expected, rtol=0.05)
    # Renderer: an albedo-1 floor has radiance E/pi; direct only, no lightmap.
    img = render(cs, samples=1, indirect=False)
    # Pixel (4, 4) is centred 0.125 m off the axis in x and y.
    r = math.hypot(0.125, 0.125)
    assert img[4, 4, 0] == pytest.approx(point_E(P, H, r) / math.pi, rel=1e-6)


def test_point_light_irradiance_is_p_over_4_pi_r2():
    """Blender's definition: a point light of P W gives E = P / (4 pi r^2) facing it."""
    P = 50.0
    scene = floor_scene(Light("point", power=P, transform=translate(0, 0, 2.0)))
    cs = compile_scene(scene)
    img = render(cs, samples=1, indirect=False)
    r = math.hypot(0.125, 0.125)
    E = P / (4 * math.pi) * 2.0 / (4.0 + r * r) ** 1.5
    assert img[3, 3].mean() * math.pi == pytest.approx(E, rel=1e-6)


def test_disk_light_on_axis():
    P, a = 200.0, 0.5
    light = Light("area", power=P, shape="disk", size=2 * a, transform=translate(0, 0, H))
    scene = floor_scene(light)
    cs = compile_scene(scene)
    trace_photons(cs, 400_000, seed=6, max_bounces=0, record_direct=True)
    # The texels around the axis see nearly the on-axis value (checked against the field's curvature).
    expected = disk_E(P, a, H)
    np.testing.assert_allclose(central_texels_mean(cs, 64), expected, rtol=0.05)
    img = render(cs, samples=256, indirect=False, seed=1)
    centre = img[3:5, 3:5].mean()
    # The four central pixels each cover a 0.25 m square beside the axis, where the
    # field is 5 % below the axis value: their exact mean (quadrature over the disk
    # and the pixel), within the render's noise (0.9 % per pixel at 256 spp).
    assert centre * math.pi == pytest.approx(disk_E_over_square(P, a, H, 0.25), rel=0.02)
    assert disk_E_over_square(P, a, H, 0.25) == pytest.approx(0.949 * expected, rel=0.002)


def test_spot_light_flux_and_cone():
    P = 100.0
    spot = Light("spot", power=P, spot_size=math.radians(60), spot_blend=0.3,
                 transform=translate(0, 0, H))
    scene = floor_scene(spot)
    cs = compile_scene(scene)
    stats = trace_photons(cs, 200_000, seed=7, max_bounces=0, record_direct=True)
    cos_half = math.cos(math.radians(30))
    smooth = (1 - cos_half) * 0.3
    flux = P / (4 * math.pi) * 2 * math.pi * ((1 - cos_half) - smooth / 2)
    np.testing.assert_allclose(stats.emitted, flux, rtol=0.01)
    # Inside the inner cone the spot is as bright as a point light of the same power.
    img = render(cs, samples=1, indirect=False)
    r = math.hypot(0.125, 0.125)
    assert img[4, 4, 1] * math.pi == pytest.approx(point_E(P, H, r), rel=1e-6)
    # Outside the cone (tan 30 deg * 1 m = 0.58 m) no photon lands.
    lm = cs.lightmaps
    E = lm.irradiance[:64 * 64].reshape(64, 64, 3)
    assert E[32, 32 + 12, 0] == 0.0  # texel centre ~3 m off axis


def test_sun_irradiance():
    S = 3.0
    sun = Light("sun", power=S, transform=rotate("x", 30))  # tilted 30 degrees from vertical
    scene = floor_scene(sun)
    cs = compile_scene(scene)
    trace_photons(cs, 200_000, seed=8, max_bounces=0, record_direct=True)
    expected = S * math.cos(math.radians(30))
    lm = cs.lightmaps
    mean = lm.flux.sum(axis=0) / lm.area.sum()
    np.testing.assert_allclose(mean, expected, rtol=0.02)
    img = render(cs, samples=1, indirect=False)
    assert img.mean() * math.pi == pytest.approx(expected, rel=1e-9)
