"""Importance emission (engine/shading/photon_aim.py): photons aimed at what is baked
land there many times more often and still give each light's exact irradiance."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.shading import photon_aim
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.core.scene import Light, Material, Scene, compose, rotate, translate

SUN = 3.0          # W/m² on a plane facing the sun
TILT = 40.0        # degrees from the zenith


def _scene(lights, ground=True, world=None):
    """A 2 x 2 m target quad, with a black 60 x 60 m ground just under it: the
    target's top sees the lights and the world, its underside nothing."""
    s = Scene(n_bands=3, name="yard")
    w = s.add_material(Material("white", diffuse=np.full(3, 0.6)))
    black = s.add_material(Material("black", diffuse=np.zeros(3)))
    s.add_object(demo_scenes.quad_mesh((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), material=w,
                                       name="target"), name="target")
    if ground:
        s.add_object(demo_scenes.quad_mesh((-30, -30, -0.01), (30, -30, -0.01), (30, 30, -0.01),
                                           (-30, 30, -0.01), material=black, name="ground"), name="ground")
    s.lights.extend(lights)
    if world is not None:
        s.environment = world
    s.texel_density = 4.0
    return s


def _target(cs, photons, seed, aim=None, plain=False):
    """Mean irradiance of the target quad (area-weighted), its hits, and the stats."""
    if plain:
        cs.lights = cs.lights._replace(aim_fraction=0.0)
    stats = trace_photons(cs, photons, seed=seed, max_bounces=2, record_direct=True, aim=aim)
    lm = cs.lightmaps
    lo, hi = lm.offset[0], lm.offset[0] + lm.width[0] * lm.height[0]
    mean = lm.flux[lo:hi].sum(axis=0) / lm.area[lo:hi].sum()
    return mean, int(lm.hits[lo:hi].sum()), stats


def test_sphere_around_bounds_the_instances():
    cs = compile_scene(_scene([Light("sun", power=SUN)]))
    c, r = photon_aim.sphere_around(cs.geometry, [0])
    np.testing.assert_allclose(c, [0, 0, 0], atol=1e-6)
    assert r == pytest.approx(math.sqrt(2.0), rel=1e-6)
    c, r = photon_aim.sphere_around(cs.geometry, [0, 1])
    assert r == pytest.approx(math.hypot(30 * math.sqrt(2), 0.005), rel=1e-6)
    assert photon_aim.sphere_around(cs.geometry, []) is None


@pytest.mark.parametrize("kind", ["sun", "world"])
def test_aimed_parallel_light_keeps_the_exact_irradiance(kind):
    """Sun (S cos θ) or a uniform world (π L) on the target: aiming at it gives the
    same irradiance within noise, with many times the hits, and the energy audit
    still closes on each light's exact flux."""
    if kind == "sun":
        lights, world, exact = [Light("sun", power=SUN, transform=rotate("y", TILT)[:3])], None, \
            SUN * math.cos(math.radians(TILT))
    else:
        lights, world, exact = [], 0.5, math.pi * 0.5
    cs = compile_scene(_scene(lights, world=world))
    sphere = photon_aim.sphere_around(cs.geometry, [0])
    aimed, hits, stats = _target(cs, 1_000_000, seed=5, aim=sphere)
    # 1 σ is 0.4 % (sun) and 0.7 % (world) over seeds
    np.testing.assert_allclose(aimed, exact, rtol=0.02)
    assert stats.audit_error() < 1e-12
    np.testing.assert_allclose(stats.emitted, cs.lights.flux.sum(axis=0), rtol=0.02)
    plain_cs = compile_scene(_scene(lights, world=world))
    plain, plain_hits, _ = _target(plain_cs, 1_000_000, seed=5, plain=True)
    # the target is 4 m² of a ~5 600 m² disk: the plain pass lands a handful of photons
    assert hits > 50 * max(plain_hits, 1)
    assert plain_hits < 2_000


@pytest.mark.parametrize("kind", ["point", "spot", "area"])
def test_light_far_outside_the_scene_aims_at_it(kind):
    """A lamp 20 m above a lone 2 x 2 m quad: the scene's own sphere is aimed at by
    default (a light outside it wastes most photons otherwise), and the
    irradiance stays the analytic one."""
    d, power = 20.0, 4000.0
    xf = translate(0.0, 0.0, d)[:3]
    if kind == "point":
        light = Light("point", power=power, transform=xf)
        exact = lambda x, y: power / (4 * math.pi) * d / (x * x + y * y + d * d) ** 1.5
    elif kind == "spot":
        light = Light("spot", power=power, transform=xf, spot_size=math.radians(60), spot_blend=0.0)
        exact = lambda x, y: power / (4 * math.pi) * d / (x * x + y * y + d * d) ** 1.5
    else:
        # a 0.5 m disk light facing down: radiance Φ / (π A), E = L cos cos' A / r² far away
        light = Light("area", power=power, shape="disk", size=0.5, transform=xf)
        area = math.pi * 0.25 ** 2
        exact = lambda x, y: power / (math.pi * area) * area * d * d / (x * x + y * y + d * d) ** 2
    g = (np.arange(40) + 0.5) / 20.0 - 1.0
    want = np.mean([exact(x, y) for x in g for y in g])
    cs = compile_scene(_scene([light], ground=False))
    aimed, hits, stats = _target(cs, 200_000, seed=2)
    np.testing.assert_allclose(aimed, want, rtol=0.02)
    assert stats.audit_error() < 1e-12
    plain_cs = compile_scene(_scene([light], ground=False))
    _, plain_hits, _ = _target(plain_cs, 200_000, seed=2, plain=True)
    assert hits > 20 * max(plain_hits, 1)


def test_a_light_inside_the_aim_sphere_traces_the_photons_it_always_did():
    """Every object baked, lights in the room: the aim changes nothing, bit for bit."""
    scene = demo_scenes.cornell_box(with_primitives=False)
    a, b = compile_scene(scene), compile_scene(scene)
    trace_photons(a, 20_000, seed=4, max_bounces=3)
    b.lights = b.lights._replace(aim_fraction=0.0)
    trace_photons(b, 20_000, seed=4, max_bounces=3)
    assert np.array_equal(a.lightmaps.flux, b.lightmaps.flux)
