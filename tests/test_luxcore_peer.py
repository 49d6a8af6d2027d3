"""The LuxCore peer (benchmarks/luxcore_peer.py): Blender's light units as exported
to LuxCore, and the worker process's image.

A Lambertian plane (albedo 0.8) seen straight down through a ~2 degree camera:
every pixel is rho/pi * E with E the irradiance at the plane's centre, known in
closed form for each light type. The scenes are built in a scene of their own
and removed afterwards, so nothing leaks into other tests.
"""
import math

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import demo_blend  # noqa: E402
from benchmarks import luxcore_peer  # noqa: E402

# Not imported here: importing pyluxcore next to bpy aborts the process (their
# bundled libraries clash), which is one more reason the renders run in a worker.
# The test setup installs it (requirements.txt), so a missing one is an error, not a skip.
if not luxcore_peer.available():
    pytest.fail("pyluxcore is not installed: run `make setup` (requirements.txt)", pytrace=False)

RHO = 0.8
H = 1.5
# Direct light only (one plane, black world) and a camera ray grid: the only
# errors are float noise and the sub-degree spread of incidence over the view.
TOL = 0.01


@pytest.fixture
def plane_scene():
    made = []

    def build(light_type, res=16, **light):
        sc = bpy.data.scenes.new("luxcore_test")
        made.append(sc)
        mat = demo_blend.principled("luxcore_test_white", (RHO, RHO, RHO))
        demo_blend.mesh_object("luxcore_test_floor", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [(0, 1, 2, 3)],
                      mat, collection=sc.collection)
        demo_blend.add_light(sc, light_type, "luxcore_test_light", **light)
        demo_blend.add_camera(sc, (0.0, 0.0, 0.5), (0.0, 0.0, 0.0), lens=50.0, sensor=2.0)
        demo_blend.set_world(sc)
        w, h = (res, res) if isinstance(res, int) else res
        sc.render.resolution_x, sc.render.resolution_y, sc.render.resolution_percentage = w, h, 100
        vl = sc.view_layers[0]
        vl.update()
        return luxcore_peer.export_scene(vl.depsgraph)

    yield build
    for sc in made:
        for ob in list(sc.collection.objects):
            data = ob.data
            bpy.data.objects.remove(ob)
            if data is not None and data.users == 0:
                getattr(bpy.data, {"MESH": "meshes", "LIGHT": "lights", "CAMERA": "cameras"}[data.id_type])\
                    .remove(data)
        if sc.world is not None:
            bpy.data.worlds.remove(sc.world)
        bpy.data.scenes.remove(sc)
    for m in [m for m in bpy.data.materials if m.name.startswith("luxcore_test")]:
        bpy.data.materials.remove(m)


def _mean(spec_arrays, spp=4):
    img, st = luxcore_peer.render_spec(*spec_arrays, mode="path", spp=spp, seed=1)
    assert np.all(np.isfinite(img))
    return float(img.mean()), st


@pytest.mark.parametrize("kind", ["POINT", "SPOT"])
def test_point_light_irradiance(plane_scene, kind):
    """Point light of P W at height h: E = P / (4 pi h^2) (Cycles' convention); a spot
    of P W on its axis likewise (Blender's spot is the point light, masked)."""
    P = 100.0
    got, _ = _mean(plane_scene(kind, power=P, location=(0.0, 0.0, H), radius=0.0, spot_size=math.radians(60.0)))
    want = RHO / math.pi * P / (4.0 * math.pi * H * H)
    assert got == pytest.approx(want, rel=TOL)


def test_sun_and_area_irradiance(plane_scene):
    """Sun of S W/m^2 at 30 degrees: E = S cos 30; square area light of P W, side a, at
    height h: L = P / (pi a^2) and E = 4 L x atan(x), x = (a/2) / sqrt((a/2)^2 + h^2)."""
    S = 3.0
    got, _ = _mean(plane_scene("SUN", power=S, rotation=(math.radians(30.0), 0.0, 0.0), angle=math.radians(2.0)))
    assert got == pytest.approx(RHO / math.pi * S * math.cos(math.radians(30.0)), rel=TOL)
    P, a, h = 60.0, 1.0, 0.8
    got, _ = _mean(plane_scene("AREA", power=P, shape="SQUARE", size=a, location=(0.0, 0.0, h)), spp=64)
    x = 0.5 * a / math.hypot(0.5 * a, h)
    E = 4.0 * P / (math.pi * a * a) * x * math.atan(x)
    # The light's emission is sampled: 64 spp leaves ~0.1 % noise.
    assert got == pytest.approx(RHO / math.pi * E, rel=TOL)


def test_worker_image_shape_and_rows(plane_scene):
    """A non-square image comes back (H, W, 3), finite, rows top-down: a point light
    off to the camera's top side (+Y in Blender's camera) lights the top rows more."""
    spec, arrays = plane_scene("POINT", res=(24, 16), power=100.0, location=(0.0, 0.05, 0.3), radius=0.0)
    img, st = luxcore_peer.render_spec(spec, arrays, mode="path", spp=2, seed=3)
    assert img.shape == (16, 24, 3) and img.dtype == np.float32
    assert np.all(np.isfinite(img)) and img.min() >= 0.0 and img.max() > 0.0
    assert img[:4].mean() > 1.01 * img[-4:].mean()
    assert st["spp"] >= 2 and st["seconds_wall"] >= st["seconds"] > 0.0


def test_worker_failure_raises(plane_scene):
    spec, arrays = plane_scene("POINT", power=10.0, location=(0.0, 0.0, H))
    spec["meshes"][0]["material"] = "no such material"
    with pytest.raises(Exception):
        luxcore_peer.render_spec(spec, arrays, mode="path", spp=1)
