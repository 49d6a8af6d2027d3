"""Final gather for bakes (engine/transport/bake_gather.py): the same mean as the photon lookup,
less noise, deterministic, and no light read through the inside of a closed mesh."""
import math

import numba
import numpy as np
import pytest

from photon_lightmaps.engine.transport import bake_gather
from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.transport import texel_gather
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.core.scene import Light, Material, Scene, TriangleMesh, translate

RHO, FLUX = 0.5, 100.0


def all_lightmaps(cs):
    return sorted(int(l) for ids in cs.instance_lightmaps for l in ids)


def gather_bake(cs, photons, seed=0, points=16, rays=4, caustics=False):
    """Photon pass recording direct hits, then direct + gathered indirect per texel."""
    trace_photons(cs, photons, seed=seed, max_bounces=64, record_direct=True, caustics=caustics)
    lids = all_lightmaps(cs)
    ind = bake_gather.gathered_indirect(cs, lids, points=points, rays=rays, seed=seed)
    direct = texel_gather.direct_texel_irradiance(cs, lids, 16, seed=seed)
    bake_gather.set_gathered(cs.lightmaps, direct, ind)
    return direct, ind


def lookup_bake(cs, photons, seed=0):
    trace_photons(cs, photons, seed=seed, max_bounces=64, record_direct=False)
    texel_gather.bake_texels(cs, all_lightmaps(cs), 16, seed=seed)


def area_mean(lm, ids):
    a = lm.area[ids]
    return (lm.irradiance[ids] * a[:, None]).sum(axis=0) / a.sum()


@pytest.mark.parametrize("mesh", [False, True], ids=["analytic", "triangle_mesh"])
def test_furnace_gather_matches_closed_form(mesh):
    """A point light inside a closed sphere: the mean over the inside is Φ / (A (1 - ρ))."""
    cs = compile_scene(demo_scenes.furnace_sphere(RHO, FLUX, source=(0.3, -0.2, 0.1), mesh=mesh,
                                                  resolution=12))
    direct, ind = gather_bake(cs, 400_000, seed=3)
    ids = direct[0]
    A = cs.lightmaps.area[ids].sum()
    np.testing.assert_allclose(area_mean(cs.lightmaps, ids), FLUX / (A * (1 - RHO)), rtol=0.005)
    # the indirect part on its own is uniform: ρ Φ / (A (1 - ρ)) on every texel
    rel = ind[1][:, 0] / (RHO * FLUX / (A * (1 - RHO))) - 1.0
    assert np.percentile(np.abs(rel), 95) < 0.06


def room_rows(cs, scene):
    """The measured texel rows of the Cornell room's walls and box (not its balls)."""
    keep = [i for i, o in enumerate(scene.instances) if o.name not in ("mirror_ball", "glass_ball")]
    lids = [int(lid) for i in keep for lid in cs.instance_lightmaps[i]]
    lm = cs.lightmaps
    rows = np.concatenate([np.arange(lm.offset[lid], lm.offset[lid] + lm.width[lid] * lm.height[lid])
                           for lid in lids])
    return rows[lm.area[rows] > 0]


def test_gather_mean_agrees_with_lookup_in_the_cornell_room():
    """Walls and box, lookup (texels' own photons) vs gather: the same room mean within 1 %.
    The room has a mirror and a glass ball, so caustic photons take part."""
    scene = demo_scenes.cornell_box(n_bands=3)
    a = compile_scene(scene)
    lookup_bake(a, 1_000_000, seed=1)
    b = compile_scene(scene)
    gather_bake(b, 300_000, seed=2, caustics=True)
    assert b.caustics is not None and b.caustics_traced
    rows = room_rows(a, scene)
    np.testing.assert_allclose(area_mean(b.lightmaps, rows), area_mean(a.lightmaps, rows), rtol=0.01)


def test_gather_lights_keep_the_cornell_mean_with_caustics():
    """The Cornell room lit by a point and a spot light (both sampled at gather hits),
    with its mirror and glass balls: gathered with Bake Gather Lights against the
    lookup, the same room mean within 1 %. The lights' caustic photons (through the
    glass, off the mirror) are the part gather rays cannot sample, so they must stay
    in the main lightmaps (left out, the area-lit room read 1.7 % dark)."""
    scene = demo_scenes.cornell_box(n_bands=3)
    scene.lights = [Light("point", power=60.0, transform=translate(0.3, 0.2, 1.7), name="point"),
                    Light("spot", power=120.0, transform=translate(-0.5, -0.4, 1.8), spot_size=math.radians(70.0),
                          name="spot")]
    a = compile_scene(scene)
    lookup_bake(a, 1_000_000, seed=1)
    b = compile_scene(scene)
    trace_photons(b, 300_000, seed=2, max_bounces=64, record_direct=True, caustics=True, gather=True,
                  gather_lights=True)
    assert b.gather_light_set is not None and b.gather_light_set.kind.shape[0] == 2
    lids = all_lightmaps(b)
    ind = bake_gather.gathered_indirect(b, lids, points=16, rays=4, seed=2)
    bake_gather.set_gathered(b.lightmaps, texel_gather.direct_texel_irradiance(b, lids, 16, seed=2), ind)
    rows = room_rows(a, scene)
    np.testing.assert_allclose(area_mean(b.lightmaps, rows), area_mean(a.lightmaps, rows), rtol=0.01)


def _patch_scene(floor_res):
    """A sun straight down on a 2 x 2 m floor, half of it shaded by a roof over x < 0
    (the shadow's edge at x = 0), and a small panel facing down 0.15 m above the shaded
    floor next to the edge: its light comes from the floor just below, one bounce away."""
    s = Scene(n_bands=1)
    m = s.add_material(Material("grey", diffuse=0.7))
    black = s.add_material(Material("black", diffuse=0.0))
    s.add_object(demo_scenes.quad_mesh((-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), material=m, name="floor"),
                 name="floor", lightmap_resolution=floor_res)
    s.add_object(demo_scenes.quad_mesh((-3, -3, 1), (-3, 3, 1), (0, 3, 1), (0, -3, 1), material=black,
                                       name="roof"), name="roof", lightmap_resolution=2)
    s.add_object(demo_scenes.quad_mesh((-0.3, -0.1, 0.15), (-0.3, 0.1, 0.15), (-0.05, 0.1, 0.15),
                                       (-0.05, -0.1, 0.15), material=m, name="panel"),
                 name="panel", lightmap_resolution=4)
    s.lights.append(Light("sun", power=3.0, name="sun"))
    return s


def _panel_mean(floor_res, gather_lights, seed):
    cs = compile_scene(_patch_scene(floor_res))
    # one bounce: the panel's light is the floor's first-hit light, which has a closed form
    trace_photons(cs, 200_000, seed=seed, max_bounces=1, record_direct=True, gather=True,
                  gather_lights=gather_lights)
    panel = [int(l) for l in cs.instance_lightmaps[2]]
    ind = bake_gather.gathered_indirect(cs, panel, points=16, rays=64, seed=seed)
    a = cs.lightmaps.area[ind.ids]
    return float((ind.E[:, 0] * a).sum() / a.sum())


def _panel_exact(n=400):
    """The panel's mean irradiance from the sunlit floor (x in [0, 1]) by the midpoint
    rule: E(p) = L ∫ h² / r⁴ dA for a panel facing down at height h, L = ρ E_sun / π."""
    L, h = 0.7 * 3.0 / math.pi, 0.15
    x = (np.arange(n) + 0.5) / n
    y = -1.0 + 2.0 * (np.arange(2 * n) + 0.5) / (2 * n)
    X, Y = np.meshgrid(x, y)
    E = [L * np.sum(h * h / ((X - px) ** 2 + (Y - py) ** 2 + h * h) ** 2) * (1.0 / n) ** 2
         for px in -0.3 + 0.25 * (np.arange(20) + 0.5) / 20 for py in -0.1 + 0.2 * (np.arange(8) + 0.5) / 8]
    return float(np.mean(E))


def test_gather_lights_read_a_sun_patch_as_sharp_as_the_sun():
    """The panel next to the sun's edge reads the floor below it, one bounce. Through
    3 x 3 floor texels the middle column holds the edge smeared over 0.67 m, and the
    gather reads light that is not there (+170 %); sampling the sun where gather rays
    land gives the closed form within the noise, whatever the floor's texels."""
    exact = _panel_exact()
    coarse = _panel_mean(3, False, 2)
    sharp = _panel_mean(3, True, 3)
    assert abs(sharp / exact - 1) < 0.02, (sharp, exact, coarse)   # seeds spread 0.7 % (measured)
    assert coarse / exact - 1 > 0.5, (sharp, exact, coarse)


def _room_indirect(rays, seed, points=4):
    cs = compile_scene(demo_scenes.cornell_box(n_bands=1, with_primitives=False))
    trace_photons(cs, 200_000, seed=0, max_bounces=64, record_direct=True)
    return bake_gather.gathered_indirect(cs, all_lightmaps(cs), points=points, rays=rays, seed=seed)[1][:, 0]


def test_gather_noise_falls_as_one_over_sqrt_rays():
    """Two seeds differ by the gather's own noise only (same photons). 16x the rays must cut
    the spread at least 4x, less a margin; the rays of a point are a shifted lattice, so it
    falls faster than plain Monte Carlo (about 10x measured)."""
    d1 = np.std(_room_indirect(1, 10) - _room_indirect(1, 11))
    d16 = np.std(_room_indirect(16, 10) - _room_indirect(16, 11))
    assert d1 / d16 > 3.5


def _room_gather(seed, rays=2, **kw):
    cs = compile_scene(demo_scenes.cornell_box(n_bands=1, with_primitives=False))
    trace_photons(cs, 200_000, seed=0, max_bounces=64, record_direct=True)
    lids = all_lightmaps(cs)
    direct = texel_gather.direct_texel_irradiance(cs, lids, 16, seed=0)
    return cs, direct, bake_gather.gathered_indirect(cs, lids, points=16, rays=rays, seed=seed, direct=direct, **kw)


def test_error_estimate_matches_the_spread_over_seeds():
    """Per texel, the estimated standard error against the spread of E over 8 gather seeds
    (same photons). The estimate treats the texel's stratified points as independent, so it
    may only err high: never more than 20 % below the spread, and not wildly above it."""
    runs = [_room_gather(seed) for seed in range(8)]
    E = np.stack([g.E[:, 0] for _, _, g in runs])
    spread = E.std(axis=0, ddof=1)
    se = np.sqrt(np.mean([g.se ** 2 for _, _, g in runs], axis=0))
    ok = spread > 0
    ratio = np.sqrt(np.mean(se[ok] ** 2) / np.mean(spread[ok] ** 2))
    assert 0.8 < ratio < 3.0, ratio


def test_adaptive_gather_spends_rays_where_the_error_is():
    """target_error: texels above it after the first pass get more rays (at most max_rays),
    the others none; their estimated error then meets the target about; the room's
    mean stays the uniform pass's (the extra rays are a second, independent estimate)."""
    target = 0.02
    cs, direct, uni = _room_gather(3, rays=2)
    _, _, ada = _room_gather(3, rays=2, target_error=target, max_rays=64)
    assert np.array_equal(uni.ids, ada.ids)
    total = uni.E[:, 0] + direct[1][:, 0]
    rel0 = uni.se / np.maximum(total, 0.1 * np.median(total))
    more = ada.rays > 2
    assert np.array_equal(more, rel0 > target)         # exactly the noisy texels
    assert 0 < more.sum() < more.size and ada.rays.max() <= 64
    uncapped = more & (ada.rays < 64)
    rel1 = ada.se / np.maximum(total, 0.1 * np.median(total))
    assert np.median(rel1[uncapped]) < 1.5 * target < np.median(rel0[uncapped])
    a = cs.lightmaps.area[uni.ids]
    np.testing.assert_allclose((ada.E[:, 0] * a).sum(), (uni.E[:, 0] * a).sum(), rtol=0.01)
    # same seed, same texels, same rays: deterministic
    _, _, again = _room_gather(3, rays=2, target_error=target, max_rays=64)
    assert np.array_equal(again.E, ada.E) and np.array_equal(again.rays, ada.rays)


def test_same_seed_same_result_on_any_thread_count():
    n = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = _room_indirect(2, 5)
        numba.set_num_threads(max(n, 2))
        b = _room_indirect(2, 5)
    finally:
        numba.set_num_threads(n)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, _room_indirect(2, 6))


def _box(lo, hi, inward=False):
    """An axis-aligned closed box mesh, wound outward (inward=True: reversed)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = np.array([[x, y, z] for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)], float)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    f = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    if inward:
        f = f[:, ::-1]
    return v, f


def _box_scene(light_at, inward=False):
    s = Scene(n_bands=1)
    m = s.add_material(Material("grey", diffuse=0.6))
    v, f = _box((-0.3, -0.3, 0.0), (0.3, 0.3, 0.6), inward)
    s.add_object(TriangleMesh(v, f, material=m, name="box"), name="box", lightmap_resolution=8)
    fv = np.array([[-2, -2, 0], [2, -2, 0], [2, 2, 0], [-2, 2, 0]], float)
    s.add_object(TriangleMesh(fv, np.array([[0, 1, 2], [0, 2, 3]]), material=m, name="floor"),
                 name="floor", lightmap_resolution=32)   # 12 cm texels: the gather reads them
    s.lights.append(Light("point", power=50.0, transform=translate(*light_at)))
    return s


@pytest.mark.parametrize("inward", [False, True], ids=["outward", "inward"])
def test_lit_sides_of_closed_and_open_meshes(inward):
    cs = compile_scene(_box_scene((0.8, -0.6, 1.5), inward))
    box, floor = 0, 1
    assert texel_gather.lit_sides(cs, floor) == 0                       # open: both sides
    side = texel_gather.lit_sides(cs, box)
    assert side == (-1 if inward else 1)                      # the outside, whatever the winding
    assert texel_gather.lit_sides(compile_scene(_box_scene((0.0, 0.0, 0.3), inward)), box) == 0   # light inside


def test_closed_box_inside_adds_no_light():
    """A box on a lit floor: gathering its outside only, its mean agrees with the lookup;
    gathering both sides would read its outer texels again from inside (about ρ times more)."""
    scene = _box_scene((0.8, -0.6, 1.5))
    a = compile_scene(scene)
    lookup_bake(a, 400_000, seed=1)
    b = compile_scene(scene)
    gather_bake(b, 200_000, seed=2)
    lid = int(a.instance_lightmaps[0][0])
    rows = np.arange(a.lightmaps.offset[lid], a.lightmaps.offset[lid] + a.lightmaps.width[lid]
                     * a.lightmaps.height[lid])
    rows = rows[a.lightmaps.area[rows] > 0]
    np.testing.assert_allclose(area_mean(b.lightmaps, rows), area_mean(a.lightmaps, rows), rtol=0.03)


def test_gather_needs_recorded_direct_light():
    cs = compile_scene(demo_scenes.furnace_sphere(RHO, FLUX, resolution=4))
    trace_photons(cs, 10_000, seed=0, record_direct=False)
    with pytest.raises(ValueError, match="recorded direct light"):
        bake_gather.gathered_indirect(cs, all_lightmaps(cs))


def test_time_budget_shares_rays_by_relative_error():
    """The rays a time budget buys go out so that texels' total rays follow their
    relative error (Neyman allocation), each within its room, the sum within the budget."""
    rel = np.array([0.0, 0.005, 0.01, 0.02, 0.04, 0.08])
    e = bake_gather._share(rel, rays=4, room=60, budget=80)
    assert 75 <= e.sum() <= 80 and e.max() <= 60
    assert e[0] == 0 and np.all(np.diff(e) >= 0)
    total = 4 + e
    got = e > 0
    # uncapped texels with extra rays: totals proportional to rel (within rounding)
    lam = total[got & (e < 60)] / rel[got & (e < 60)]
    assert lam.max() / lam.min() < 1.15
    assert np.array_equal(bake_gather._share(rel, 4, 60, 10 ** 9), np.full(rel.size, 60))
    assert not bake_gather._share(rel, 4, 60, 0).any()


def test_a_bake_time_budget_is_spent_and_kept():
    """Bake Time (--time): after its first pass the gather spends the time left on
    the noisiest texels and ends by the deadline (planned from the first pass's
    speed, so allowed 25 % and 0.2 s over); a budget shorter than the first pass
    adds no rays."""
    import time
    from photon_lightmaps.engine import session

    def bake(budget):
        settings = session.Settings(photons=50_000, bake_photons=50_000, seed=3, bake_gather_rays=64,
                                    bake_irradiance_cache=False, bake_time=budget)
        cs, _ = session.compile_and_trace_bake(
            demo_scenes.cornell_box(n_bands=1, with_primitives=False), settings)
        t0 = time.perf_counter()
        deadline = t0 + budget if budget > 0 else None
        session.bake_texels(cs, all_lightmaps(cs), [], settings, deadline=deadline)
        return time.perf_counter() - t0, int(cs.bake_error[2].sum())

    bake(0.0)                                  # the kernels, compiled or loaded
    base_seconds, base_rays = bake(0.0)
    budget = 4.0 * base_seconds + 0.5
    seconds, rays = bake(budget)
    assert seconds <= 1.25 * budget + 0.2, (seconds, budget)
    assert seconds > 0.5 * budget and rays > 2 * base_rays, (seconds, budget, rays, base_rays)
    assert bake(1e-3)[1] == base_rays


@pytest.mark.parametrize("indirect, gather_lights", [("GATHER", False), ("GATHER", True), ("LOOKUP", False)],
                         ids=["gather", "gather_lights", "lookup"])
@pytest.mark.parametrize("bounces", [1, 2])
def test_bake_keeps_the_bounce_limit(indirect, gather_lights, bounces):
    """A furnace baked at max_bounces K holds light of 0..K bounces, Φ/A Σ_{k≤K} ρ^k,
    whether indirect light is gathered or looked up. Gather rays add a bounce of
    their own, so the lightmaps they read keep K - 1; with K they would hold one
    bounce too many (here 7-14 % too bright). With Bake Gather Lights the point
    light's first hits stay out of the lightmaps and gather rays sample it where
    they land: the same sum."""
    from photon_lightmaps.engine import session
    settings = session.Settings(photons=400_000, seed=5, max_bounces=bounces, indirect=indirect,
                                bake_gather_lights=gather_lights)
    cs, _ = session.compile_and_trace_bake(demo_scenes.furnace_sphere(RHO, FLUX, source=(0.3, -0.2, 0.1),
                                                                      resolution=12), settings)
    assert (cs.gather_light_set is not None) == gather_lights
    session.bake_texels(cs, all_lightmaps(cs), [], settings)
    lm = cs.lightmaps
    rows = np.flatnonzero(lm.area > 0)
    expected = FLUX / lm.area[rows].sum() * sum(RHO ** k for k in range(bounces + 1))
    np.testing.assert_allclose(area_mean(lm, rows), expected, rtol=0.01)
