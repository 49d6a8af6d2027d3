"""A bake's split passes (bake --pass): ambient occlusion against its closed form and
against Cycles' AO bake, and direct light alone against Cycles' Diffuse bake with
Direct only, on the same Lightmap UVs."""
import numpy as np
import pytest

import bpy  # noqa: F401  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake, demo_blend
from photon_lightmaps.engine import demo_scenes, session
from photon_lightmaps.engine.core.errors import SceneError
from photon_lightmaps.engine.core.scene import Light, Material, Scene, translate
from photon_lightmaps.engine.transport import ambient_occlusion

from blender_session import addon, cycles_diffuse_bake  # noqa: F401  (session-wide registration)
from test_bake import erode


def plates(h=0.5):
    """A 1 m floor under a 10 m ceiling h above it (facing down)."""
    s = Scene(n_bands=3, name="plates")
    m = s.add_material(Material("white", diffuse=np.full(3, 0.5)))
    s.add_object(demo_scenes.quad_mesh((-0.5, -0.5, 0), (0.5, -0.5, 0), (0.5, 0.5, 0), (-0.5, 0.5, 0),
                                       material=m, name="floor"), name="floor")
    s.add_object(demo_scenes.quad_mesh((-5, -5, h), (-5, 5, h), (5, 5, h), (5, -5, h), material=m,
                                       name="ceiling"), name="ceiling")
    s.lights.append(Light("point", power=10.0, transform=translate(0, 0, 0.25), name="lamp"))
    return session.compile(s)


@pytest.mark.parametrize("distance, expected", [(1.0, 0.25), (0.8, 0.390625), (0.4, 1.0)])
def test_ao_under_a_plane_is_the_cosine_share_beyond_it(distance, expected):
    """Under a plane h above, a cosine-weighted ray meets it within d when cos θ > h/d,
    so AO = (h/d)² for d > h (every hit lies within the 10 m ceiling), and 1 for d < h.
    256 rays per texel: each texel within 4.5 binomial standard deviations."""
    cs = plates()
    ids, ao = ambient_occlusion.texel_ao(cs, cs.instance_lightmaps[0], distance, points=16, rays=16)
    assert ids.size == 256
    sd = np.sqrt(expected * (1 - expected) / 256)
    assert abs(ao.mean() - expected) < max(sd / 4, 1e-12), ao.mean()
    assert np.all(np.abs(ao - expected) <= 4.5 * sd + 1e-12)


def test_ao_noise_falls_with_the_rays_per_point():
    """Four times the rays per point: the texels' spread about (h/d)² halves (within 25 %)."""
    cs = plates()
    spread = [np.std(ambient_occlusion.texel_ao(cs, cs.instance_lightmaps[0], 1.0, points=16, rays=r)[1] - 0.25)
              for r in (16, 64)]
    assert 0.375 < spread[1] / spread[0] < 0.625, spread


def test_ao_is_the_same_on_any_thread_count():
    import numba
    cs = plates()
    a = ambient_occlusion.texel_ao(cs, cs.instance_lightmaps[0], 1.0, seed=4)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        b = ambient_occlusion.texel_ao(cs, cs.instance_lightmaps[0], 1.0, seed=4)
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def occluded_floor(a=0.5, h=0.5, lamp=2.0):
    """A 2 m floor, an opaque a x a plate h above its centre, a point lamp `lamp` above
    the centre and a sun from 30 degrees off the vertical (along +x)."""
    import math
    from photon_lightmaps.engine.core.scene import compose, rotate
    s = Scene(n_bands=3, name="shadows")
    m = s.add_material(Material("white", diffuse=np.full(3, 0.5)))
    s.add_object(demo_scenes.quad_mesh((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), material=m,
                                       name="floor"), name="floor")
    r = a / 2
    s.add_object(demo_scenes.quad_mesh((-r, -r, h), (r, -r, h), (r, r, h), (-r, r, h), material=m,
                                       name="plate"), name="plate")
    s.lights.append(Light("point", power=10.0, transform=translate(0, 0, lamp), name="lamp"))
    s.lights.append(Light("sun", power=2.0, transform=compose(rotate("y", 30)), name="sun"))
    s.texel_density = 32.0
    assert math.isfinite(lamp)
    return s


def test_shadowmask_of_a_plate_is_its_shadow_exactly():
    """Visibility of a point lamp and a sun under an opaque plate: 0 in the shadow, 1
    outside, and the floor's area-weighted mean is 1 - shadow area / floor area (the
    lamp's shadow is the plate scaled by H/(H-h): 0.667 m square; the sun's is the
    plate itself, shifted). Texels the shadow's edge misses are exactly 0 or 1."""
    from photon_lightmaps.engine.transport import shadowmask
    scene = occluded_floor()
    cs = session.compile(scene)
    rows = shadowmask.light_rows(scene, ["sun", "lamp"])
    ids, V = shadowmask.texel_visibility(cs, cs.instance_lightmaps[0], rows)
    area = cs.lightmaps.area[ids]
    mean = (V * area[:, None]).sum(axis=0) / area.sum()
    np.testing.assert_allclose(mean, [1 - 0.25 / 4, 1 - (0.5 * 2 / 1.5) ** 2 / 4], atol=2e-3)
    assert np.isin(V, [0.0, 1.0]).mean() > 0.85
    assert (V == 0.0).any(axis=0).all() and (V == 1.0).any(axis=0).all()
    with pytest.raises(SceneError, match="not a light"):
        shadowmask.light_rows(scene, ["moon"])


RES = 32
OBJECTS = ("floor", "back", "left", "tall_box")


def _interior_agreement(ours, ref, keep=None):
    m = erode(ours[..., 3] >= 1.0 - 1e-6, 2)
    if keep is not None:
        m &= keep
    a, b = ours[..., :3][m], ref[..., :3][m]
    return float(np.sqrt(np.mean((a - b) ** 2)) / b.mean()), float(a.mean() / b.mean() - 1.0), int(m.sum())


@pytest.fixture
def room():
    demo_blend.build_cornell_blend(spheres=True)
    scene = bpy.context.scene
    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    return scene


def test_ao_pass_matches_cycles_ao_bake(room):
    """bake_objects(bake_pass="AO") against Cycles' AO bake with the world's AO distance
    (0.5 m), 1024 samples, on the same texels: relative RMSE and mean bias per object
    (measured: RMSE 0.017-0.031, the noise of 256 rays a texel; bias within 0.0024)."""
    room.world.light_settings.distance = 0.5
    objs = [bpy.data.objects[n] for n in OBJECTS]
    res = bake.bake_objects(bpy.context, objs, resolution=RES, bake_pass="AO", ao_distance=0.5, seed=2)
    assert res.bake_pass == "AO" and res.stats.photons == 0
    for ob in objs:
        ref = cycles_diffuse_bake(ob, RES, 1024, bake_type="AO", pass_filter=())
        # Floor texels under the box lie inside it: Cycles' rays start below the box's
        # bottom face, which lies in the floor, and all meet it (AO exactly 0); ours
        # start above it, and steep rays leave through the box's inside unoccluded
        # within 0.5 m. Nothing shows there; those texels are left out, and counted.
        # (with their neighbours, which straddle the box's edge)
        ours = res.maps[ob.name].rgba
        inside = (ref[..., 0] == 0.0) & (ours[..., 3] >= 1.0 - 1e-6)
        rmse, bias, n = _interior_agreement(ours, ref, erode(~inside, 1))
        print(f"\n{ob.name}: AO rel RMSE {rmse:.4f}, bias {bias:+.4f} over {n} texels "
              f"({inside.sum()} inside geometry left out)")
        # the floor under the box (9 % of it), the box's bottom face (10 %); nothing on the walls
        touching = ob.name in ("floor", "tall_box")
        assert inside.sum() <= (0.2 * (ours[..., 3] >= 1.0 - 1e-6).sum() if touching else 0), ob.name
        assert n > 50 and rmse < 0.04 and abs(bias) < 0.005, ob.name


def test_ao_ignores_spectral_mode(room):
    """AO is geometry alone: with the scene's Spectral on, the same image, bit for bit
    (not a flat spectrum sent through the spectral-to-RGB conversion)."""
    back = [bpy.data.objects["back"]]
    plain = bake.bake_objects(bpy.context, back, resolution=16, bake_pass="AO", ao_distance=0.5, seed=2)
    room.photon_lightmaps.spectral = True
    try:
        spectral = bake.bake_objects(bpy.context, back, resolution=16, bake_pass="AO", ao_distance=0.5, seed=2,
                                     overwrite=True)
    finally:
        room.photon_lightmaps.spectral = False
    assert np.array_equal(plain.maps["back"].rgba, spectral.maps["back"].rgba)
    assert 0.0 < plain.maps["back"].rgba[..., 0].max() <= 1.0


def test_direct_pass_matches_cycles_direct_bake(room):
    """bake_pass="DIRECT" (light samples only, no photons) against Cycles' Diffuse bake
    with Direct alone (no Color), 512 samples (measured: RMSE 0.005-0.049, the floor's
    soft shadows the noisiest; bias within 0.0034)."""
    objs = [bpy.data.objects[n] for n in OBJECTS]
    res = bake.bake_objects(bpy.context, objs, resolution=RES, bake_pass="DIRECT", seed=2)
    assert res.stats.photons == 0
    for ob in objs:
        ref = cycles_diffuse_bake(ob, RES, 512, pass_filter=("DIRECT",))
        rmse, bias, n = _interior_agreement(res.maps[ob.name].rgba, ref)
        print(f"\n{ob.name}: direct rel RMSE {rmse:.4f}, bias {bias:+.4f} over {n} texels")
        assert n > 50 and rmse < 0.06 and abs(bias) < 0.01, ob.name


def test_direct_samples_trade_noise_for_time(room):
    """Bake Direct Samples (bake_objects(direct_samples=), CLI --direct-samples): against
    a 4096-sample bake of the same texels, 4x the samples at least halves the error (the
    points are stratified, so it falls faster than 1/sqrt(N))."""
    objs = [bpy.data.objects[n] for n in ("floor", "back")]
    maps = {n: bake.bake_objects(bpy.context, objs, resolution=16, bake_pass="DIRECT", seed=5, overwrite=True,
                                 direct_samples=n).maps for n in (16, 64, 4096)}
    err = {}
    for n in (16, 64):
        err[n] = np.sqrt(np.mean([np.mean((maps[n][o.name].rgba[..., :3] - maps[4096][o.name].rgba[..., :3]) ** 2)
                                  for o in objs]))
    print(f"\n{err}")
    assert err[64] < 0.5 * err[16]


def test_a_pass_that_contradicts_indirect_only_is_refused(room):
    with pytest.raises(SceneError, match="choose one"):
        bake.bake_objects(bpy.context, [bpy.data.objects["floor"]], bake_pass="AO", indirect_only=True)
    with pytest.raises(SceneError, match="use one of"):
        bake.bake_objects(bpy.context, [bpy.data.objects["floor"]], bake_pass="shadow")
    with pytest.raises(SceneError, match="direct samples: must be 1 to"):
        bake.bake_objects(bpy.context, [bpy.data.objects["floor"]], direct_samples=0)


def test_cli_shadowmask_writes_one_light_per_channel(tmp_path):
    """bake --pass shadowmask: the room's one light in R (the floor in the box's shadow
    is darker than in the open), nothing traced, the lights reported; its visibility
    is near 1 where direct light is strongest. An unknown light: exit 2 and one line.
    bake --texel-validity reports the texels it filled."""
    import json
    from test_cli_commands import run
    from photon_lightmaps.registration import ensure_registered
    ensure_registered()
    blend = tmp_path / "room.blend"
    demo_blend.build_cornell_blend(str(blend), width=24, height=16)
    run("bake", blend, "--out", tmp_path / "masks", "--pass", "shadowmask", "--resolution", "16",
        "--json", tmp_path / "m.json")
    rep = json.loads((tmp_path / "m.json").read_text())
    assert rep["pass"] == "SHADOWMASK" and rep["photons"] == 0 and rep["seconds"]["shadowmask"] > 0
    light = rep["shadowmask_lights"]
    assert len(light) == 1
    img = bpy.data.images.load(rep["objects"]["floor"]["path"])
    px = np.array(img.pixels[:], np.float32).reshape(img.size[1], img.size[0], 4)
    bpy.data.images.remove(img)
    r = px[..., 0]
    assert 0.0 <= r.min() and r.max() <= 1.0 and r.max() > 0.99 and r.min() < 0.05
    assert np.all(px[..., 1:] == 0.0)
    bad = run("bake", blend, "--out", tmp_path / "m2", "--pass", "shadowmask", "--shadowmask-lights", "moon",
              check=False)
    assert bad.returncode == 2 and "shadowmask light 'moon': not a light" in bad.stderr
    # --texel-validity (with the AO pass here): the floor's texels under the box, counted
    run("bake", blend, "--out", tmp_path / "ao", "--pass", "ao", "--texel-validity", "--resolution", "16",
        "--pass-rays", "4", "--json", tmp_path / "v.json")
    assert json.loads((tmp_path / "v.json").read_text())["pass_rays"] == 4
    run("bake", blend, "--out", tmp_path / "d", "--pass", "direct", "--direct-samples", "16", "--resolution", "8",
        "--json", tmp_path / "d.json")
    assert json.loads((tmp_path / "d.json").read_text())["direct_samples"] == 16
    rep = json.loads((tmp_path / "v.json").read_text())
    valid = rep["texel_validity"]
    assert valid["floor"]["invalid"] > 0 and valid["back"]["invalid"] == 0
    # the validity image: as many red (invalid) texels as counted, none on the wall
    for name in ("floor", "back"):
        img = bpy.data.images.load(rep["objects"][name]["validity_image"])
        px = np.array(img.pixels[:], np.float32).reshape(-1, 4)
        bpy.data.images.remove(img)
        red = (px[:, 0] > 0.5) & (px[:, 1] == 0.0) & (px[:, 3] > 0.0)
        assert red.sum() == valid[name]["invalid"], name
        assert np.all(px[:, 0] + px[:, 1] <= 1.0 + 1e-6)


def test_texel_validity_fills_the_floor_under_the_box(room):
    """Texel Validity: the floor's texels under the tall box (their rays meet the box's
    inside) are found, about the box's share of the floor, and none on the walls; filled
    from their neighbours, the AO there is no longer the box's inside: Cycles' AO bake
    reads 0 there, the plain bake reads the rays leaving through the box."""
    room.world.light_settings.distance = 0.5
    objs = [bpy.data.objects[n] for n in ("floor", "back")]
    plain = bake.bake_objects(bpy.context, objs, resolution=RES, bake_pass="AO", ao_distance=0.5, seed=2)
    valid = bake.bake_objects(bpy.context, objs, resolution=RES, bake_pass="AO", ao_distance=0.5, seed=2,
                              texel_validity=True, overwrite=True)
    counts = valid.validity
    print(f"\n{counts}")
    assert counts["back"]["invalid"] == 0
    share = counts["floor"]["invalid"] / counts["floor"]["texels"]
    assert 0.05 < share < 0.12            # the box's footprint: 0.36 of the floor's 4 m²
    for name in ("floor", "back"):        # the validity image: red where invalid, as counted
        px = valid.validity_maps[name].rgba
        assert np.count_nonzero((px[..., 0] > 0.5) & (px[..., 1] == 0.0)) == counts[name]["invalid"]
        assert bpy.data.images[valid.validity_images[name]].get("photon_lightmaps_validity_of") == name
    ref = cycles_diffuse_bake(objs[0], RES, 256, bake_type="AO", pass_filter=())
    under = erode(ref[..., 0] == 0.0, 1)           # well inside the footprint
    a, b = plain.maps["floor"].rgba[..., 0], valid.maps["floor"].rgba[..., 0]
    assert under.sum() > 10
    assert not np.array_equal(a[under], b[under])
    outside = erode(ref[..., 0] > 0.0, 2) & erode(valid.maps["floor"].rgba[..., 3] >= 1 - 1e-6, 2)
    assert np.array_equal(a[outside], b[outside])     # valid texels keep their values exactly
