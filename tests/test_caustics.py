"""Caustic lightmaps: photons that reach a surface only through sharp glass or mirrors are
stored at caustic_resolution x the texel density (engine/compile.py, photon_tracer.py)."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine.transport import renderer
from photon_lightmaps.engine.core import scene
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.demo_scenes import quad_mesh
from photon_lightmaps.engine.transport.photon_tracer import trace_photons


def glass_ball_scene(k):
    sc = scene.Scene(texel_density=8.0, caustic_resolution=k)
    floor = sc.add_material(scene.Material("floor", diffuse=0.8))
    glass = sc.add_material(scene.Material("glass", diffuse=0.0, transmission=1.0, roughness=0.0, ior=1.5))
    sc.add_object(quad_mesh((-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0), material=floor), name="floor")
    sc.add_object(scene.Primitive("sphere", scene.compose(scene.translate(0, 0, 0.8), scene.scale(0.5)), material=glass),
                  name="ball", lightmap=False)
    # a slanted sun puts the focus beside the ball, where an orthographic camera from
    # above sees it directly (through the ball it would be magnified)
    sc.lights.append(scene.Light("sun", power=3.0, angle=math.radians(1.0), transform=scene.rotate("x", 40.0)))
    sc.camera = scene.Camera(scene.translate(0, 0, 5), kind="orthographic", ortho_scale=4.0, width=48, height=48)
    return sc


def test_caustic_photons_move_to_the_finer_lightmap_and_keep_their_energy():
    plain = compile_scene(glass_ball_scene(1.0))
    fine = compile_scene(glass_ball_scene(4.0))
    # at 1x the caustic maps exist at the lightmaps' own density (the final gather needs them)
    assert plain.caustics.area.shape[0] == plain.lightmaps.area.shape[0]
    assert fine.caustics.area.shape[0] == 16 * fine.lightmaps.area.shape[0]
    s1 = trace_photons(plain, 200_000, seed=4)          # every photon in the one map
    s2 = trace_photons(fine, 200_000, seed=4, caustics=True)
    assert s1.audit_error() < 1e-9 and s2.audit_error() < 1e-9
    total_plain = plain.lightmaps.flux.sum(axis=0)
    regular, caustic = fine.lightmaps.flux.sum(axis=0), fine.caustics.flux.sum(axis=0)
    # the same photons, split between the two maps: nothing lost, nothing doubled
    np.testing.assert_allclose(regular + caustic, total_plain, rtol=1e-9)
    # under the sun, the ball focuses a good share of the light it catches
    assert caustic.sum() > 0.05 * total_plain.sum()
    # the focus: 16x smaller texels see a higher peak irradiance than the coarse map (1.85x)
    assert fine.caustics.irradiance.max() > 1.5 * plain.lightmaps.irradiance.max()
    # bakes (no caustics=True) leave the caustic map empty
    fine.reset_lightmaps()
    trace_photons(fine, 50_000, seed=4)
    assert fine.caustics.flux.sum() == 0.0 and not fine.caustics_traced


def test_render_with_caustic_lightmaps_keeps_the_floor_energy():
    """Away from the focus both renders see the same light; the total differs only by noise."""
    imgs = []
    for k in (1.0, 4.0):
        cs = compile_scene(glass_ball_scene(k))
        trace_photons(cs, 400_000, seed=2, caustics=True)
        imgs.append(renderer.render(cs, samples=4, seed=1))
    a, b = imgs
    # pixels (4 x 4 m seen from above) outside the ball's silhouette
    y, x = (np.mgrid[0:48, 0:48] + 0.5) / 48 * 4.0 - 2.0
    outside = np.hypot(x, y) > 0.6
    assert b[outside].mean() == pytest.approx(a[outside].mean(), rel=0.03)
    assert b[outside].max() > 1.3 * a[outside].max()   # the focus is sharper, so brighter (1.45x)
