"""World light: constant worlds unchanged bit for bit, the environment map's importance
sampling (pdf, chi-square, estimator), furnaces, the photon audit with a map, and
(tests/test_world_blender.py) the map as Blender bakes it and bakes against Cycles.
"""
import math

import numpy as np
from numba import njit
from scipy import stats as sps

from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.shading import environment
from photon_lightmaps.engine.shading import lights
from photon_lightmaps.engine.transport import texel_gather
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.core.sampling import (
    cosine_hemisphere, next_float, stream_state, to_world, uniform_sphere)
from photon_lightmaps.engine.core.scene import (
    EnvironmentMap, Material, Primitive, Scene, scale, translate)


def random_map(h=8, w=16, seed=0, patch=True):
    """A dim random map with a bright patch (a 'sun') and a black row: what sampling must handle."""
    rng = np.random.default_rng(seed)
    px = rng.random((h, w, 3)) * np.array([1.0, 0.7, 0.4])
    px[h // 2] = 0.0                           # a black row (zero marginal weight)
    if patch:
        px[h - 3, w // 4] = (60.0, 50.0, 30.0)
    return px


def pixel_centres_grid(h, w, k):
    """Directions on a k x k grid per pixel, uniform in (phi, sin(elevation)): equal solid angles."""
    s_edges = -np.cos(np.arange(h + 1) * math.pi / h)
    s = np.concatenate([s_edges[j] + (np.arange(k) + 0.5) / k * (s_edges[j + 1] - s_edges[j])
                        for j in range(h)])
    u = (np.arange(w * k) + 0.5) / (w * k)
    phi = (0.5 - u) * 2 * math.pi
    S, PHI = np.meshgrid(s, phi, indexing="ij")
    c = np.sqrt(1 - S ** 2)
    return np.stack([c * np.cos(PHI), c * np.sin(PHI), S], axis=-1), np.repeat(s_edges[1:] - s_edges[:-1], k) / k


@njit(cache=True)
def _pdfs(ev, dirs):
    out = np.empty(dirs.shape[0])
    for i in range(dirs.shape[0]):
        out[i] = environment.pdf(ev, dirs[i, 0], dirs[i, 1], dirs[i, 2])
    return out


@njit(cache=True)
def _samples(ev, n, seed):
    out = np.empty((n, 4))
    rad = np.empty((n, ev.pixels.shape[2]))
    state = stream_state(seed, 0)
    for i in range(n):
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        wx, wy, wz, p = environment.sample_radiance(ev, u1, u2, rad[i])
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = wx, wy, wz, p
    return out, rad


@njit(cache=True)
def _radiances(ev, dirs):
    out = np.empty((dirs.shape[0], ev.pixels.shape[2]))
    for i in range(dirs.shape[0]):
        environment.radiance(ev, dirs[i, 0], dirs[i, 1], dirs[i, 2], out[i])
    return out


# --------------------------------------------------------------------------------------
# Constant worlds: exactly as before maps
# --------------------------------------------------------------------------------------

@njit(cache=True)
def _old_env_photon(ls, li, state):
    """The ENVIRONMENT branch of emit_photon before maps (the same random numbers)."""
    state, u0 = next_float(state)
    state, u1 = next_float(state)
    state, u2 = next_float(state)
    state, u3 = next_float(state)
    state, u4 = next_float(state)
    state, u5 = next_float(state)
    nx, ny, nz = uniform_sphere(u1, u2)
    R = ls.radius[li]
    lx, ly, lz = cosine_hemisphere(u3, u4)
    dx, dy, dz = to_world(lx, ly, lz, -nx, -ny, -nz)
    return (state, li, ls.center[0] + R * nx, ls.center[1] + R * ny, ls.center[2] + R * nz,
            dx, dy, dz, 1.0)


@njit(cache=True)
def _photons(ls, g, n, old):
    out = np.empty((n, 8))
    for i in range(n):
        state = stream_state(5, i)
        if old:
            r = _old_env_photon(ls, 0, state)
        else:
            r = lights.emit_photon(ls, g, state)
        st, li, ox, oy, oz, dx, dy, dz, wt = r
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = li, ox, oy, oz
        out[i, 4], out[i, 5], out[i, 6], out[i, 7] = dx, dy, dz, wt
    return out


def world_scene(env, n_bands=3):
    """An open box of primitives on a floor quad, a sphere, lit by the world only."""
    s = Scene(n_bands=n_bands)
    white = s.add_material(Material("white", diffuse=0.7))
    red = s.add_material(Material("red", diffuse=[0.7, 0.2, 0.1][:n_bands] if n_bands == 3 else 0.4))
    s.add_object(Primitive("quad", material=white), scale(2.0), name="floor", lightmap_resolution=16)
    s.add_object(Primitive("box", material=red), translate(0.3, -0.2, 0.5) @ np.diag([0.5, 0.4, 0.5, 1.0]),
                 name="box", lightmap_resolution=8)
    s.add_object(Primitive("sphere", material=white), translate(-0.8, 0.6, 0.4) @ np.diag([0.4] * 3 + [1.0]),
                 name="ball", lightmap_resolution=8)
    s.environment = env
    return s


def test_constant_world_is_bit_identical_to_the_uniform_path():
    env = np.array([0.3, 0.5, 0.7])
    cs = compile_scene(world_scene(env))
    ls = cs.lights
    assert ls.env_constant and ls.kind.tolist() == [lights.ENVIRONMENT]
    R = ls.bound_radius
    # radiance, flux and the compiled world exactly as the constant formulas give them
    assert np.array_equal(ls.radiance[0], env)
    assert np.array_equal(ls.flux[0], env * math.pi * 4.0 * math.pi * R ** 2)
    assert np.array_equal(np.asarray(cs.environment, dtype=np.float64), env)
    assert "environment" not in cs.info
    # photons: the very numbers of the uniform-sphere emission
    new, old = _photons(ls, cs.geometry, 2000, False), _photons(ls, cs.geometry, 2000, True)
    assert np.array_equal(new, old)


@njit(cache=True)
def _light_samples(ls, g, li, n):
    rad = np.empty(ls.radiance.shape[1])
    a = np.empty((n, 6))
    b = np.empty((n, 6 + rad.shape[0]))
    state = stream_state(3, 0)
    for i in range(n):
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        state, u3 = next_float(state)
        r = lights.sample_light(ls, g, li, 0.1, 0.2, 0.3, u1, u2, u3)
        q = lights.sample_light_radiance(ls, g, li, 0.1, 0.2, 0.3, u1, u2, u3, rad)
        a[i, 0], a[i, 1], a[i, 2], a[i, 3], a[i, 4], a[i, 5] = r
        b[i, 0], b[i, 1], b[i, 2], b[i, 3], b[i, 4], b[i, 5] = q
        for k in range(rad.shape[0]):
            b[i, 6 + k] = rad[k]
    return a, b


def test_sample_light_radiance_matches_sample_light_for_constant_lights():
    cs = compile_scene(demo_scenes.cornell_box(width=8, height=8))
    cs2 = compile_scene(world_scene(0.25))
    for ls, g in ((cs.lights, cs.geometry), (cs2.lights, cs2.geometry)):
        for li in range(ls.kind.shape[0]):
            a, b = _light_samples(ls, g, li, 500)
            assert np.array_equal(a, b[:, :6])
            assert np.array_equal(b[:, 6:], np.broadcast_to(ls.radiance[li], b[:, 6:].shape))


# --------------------------------------------------------------------------------------
# Importance sampling of a map
# --------------------------------------------------------------------------------------

def test_map_pdf_integrates_to_one_and_power_is_the_integral():
    px = random_map()
    ev = environment.compile_environment(EnvironmentMap(px), 3)
    h, w = px.shape[:2]
    dirs, ds = pixel_centres_grid(h, w, 4)
    d_omega = ds[:, None] * (2 * math.pi / (w * 4))           # per grid point
    p = _pdfs(ev, dirs.reshape(-1, 3)).reshape(dirs.shape[:2])
    assert abs(float((p * d_omega).sum()) - 1.0) < 1e-9
    L_grid = _radiances(ev, dirs.reshape(-1, 3)).reshape(dirs.shape)
    np.testing.assert_allclose((L_grid * d_omega[..., None]).sum(axis=(0, 1)), ev.power, rtol=1e-9)
    # pdf proportional to luminance, zero on the black row
    lum = L_grid.mean(axis=2)
    assert np.all(p[lum == 0] == 0)
    np.testing.assert_allclose(p[lum > 0] / lum[lum > 0], 1.0 / ev.total, rtol=1e-12)
    # the mean radiance a host without maps sees
    np.testing.assert_allclose(np.asarray(ev), ev.power / (4 * math.pi))


def test_map_samples_follow_the_pdf_chi_square():
    """Histogram of sample() on a grid 3x finer than the map (pixel and in-pixel placement)
    against the expected counts N * pdf * dOmega (pbrt / Mitsuba style chi-square)."""
    px = random_map(h=6, w=12)
    ev = environment.compile_environment(EnvironmentMap(px), 3)
    n = 400_000
    smp, rad = _samples(ev, n, 1)
    d = smp[:, :3]
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    # sample's pdf is pdf() of its direction and rad is radiance() there (bar pixel edges)
    p = _pdfs(ev, d)
    same = np.isclose(p, smp[:, 3], rtol=1e-12)
    assert same.mean() > 0.9999
    np.testing.assert_array_equal(_radiances(ev, d)[same], rad[same])
    k = 3
    h, w = px.shape[:2]
    u = -np.arctan2(d[:, 1], d[:, 0]) / (2 * math.pi) + 0.5
    s = d[:, 2]
    s_edges = np.concatenate([-np.cos(np.arange(h + 1)[:-1] * math.pi / h)[:, None] +
                              np.arange(k)[None] / k * np.diff(-np.cos(np.arange(h + 1) * math.pi / h))[:, None]
                              ]).reshape(-1)
    s_edges = np.append(s_edges, 1.0)
    hist, _, _ = np.histogram2d(s, u, bins=[s_edges, np.linspace(0, 1, w * k + 1)])
    dirs, ds = pixel_centres_grid(h, w, k)
    expected = n * _pdfs(ev, dirs.reshape(-1, 3)).reshape(dirs.shape[:2]) * ds[:, None] * (2 * math.pi / (w * k))
    assert abs(expected.sum() - n) < 1e-6 * n
    keep = expected > 5
    assert np.all(hist[expected == 0] == 0)
    chi2 = float((((hist - expected) ** 2)[keep] / expected[keep]).sum())
    dof = int(keep.sum()) - 1
    assert sps.chi2.sf(chi2, dof) > 1e-3, (chi2, dof)


def test_importance_estimate_of_irradiance_equals_quadrature():
    px = random_map(h=16, w=32, seed=4)
    ev = environment.compile_environment(EnvironmentMap(px), 3)
    h, w = px.shape[:2]
    dirs, ds = pixel_centres_grid(h, w, 8)
    d_omega = ds[:, None] * (2 * math.pi / (w * 8))
    Lg = _radiances(ev, dirs.reshape(-1, 3)).reshape(dirs.shape)
    smp, rad = _samples(ev, 200_000, 2)
    for n in (np.array([0.0, 0.0, 1.0]), np.array([0.6, -0.48, 0.64]), np.array([-1.0, 0.0, 0.0])):
        quad = (Lg * (np.clip(dirs @ n, 0, None) * d_omega)[..., None]).sum(axis=(0, 1))
        f = rad * (np.clip(smp[:, :3] @ n, 0, None) / smp[:, 3])[:, None]
        est, err = f.mean(axis=0), f.std(axis=0) / math.sqrt(len(f))
        assert np.all(np.abs(est - quad) < 4 * err + 1e-9), (n, est, quad, err)
        assert np.all(err < 0.01 * quad)


def test_direction_mapping_is_blenders():
    """u = -atan2(y, x) / 2pi + 0.5, v = atan2(z, hypot) / pi + 0.5, row 0 at the bottom."""
    h, w = 8, 16
    px = np.zeros((h, w, 1))
    px[..., 0] = np.arange(h)[:, None] * 100 + np.arange(w)[None, :]
    ev = environment.compile_environment(EnvironmentMap(px), 1)
    out = np.empty(1)
    for d, (j, i) in (((1, 0, 0.01), (4, 8)), ((0, 1, 0.01), (4, 4)), ((-1, 1e-9, 0.01), (4, 0)),
                      ((0, -1, 0.01), (4, 12)), ((0.01, 0, 1), (7, 8)), ((0.01, 0, -1), (0, 8)),
                      ((1, 1, -0.01), (3, 6))):
        environment.radiance(ev, *d, out)
        assert out[0] == j * 100 + i, (d, out[0])


# --------------------------------------------------------------------------------------
# Furnaces and the photon audit
# --------------------------------------------------------------------------------------

def plane_scene(env, res=4):
    s = Scene(n_bands=3)
    m = s.add_material(Material("white", diffuse=0.5))
    s.add_object(Primitive("quad", material=m), scale(1.0), name="floor", lightmap_resolution=res)
    s.environment = env
    return s


def test_furnace_plane_under_a_uniform_and_a_half_map():
    """A quad (open: both sides add into its texels) under a map world of radiance L:
    everywhere L -> E = 2 pi L, L above the horizon only -> E = pi L, from the texel
    gather (light sampling) and from first-hit photons alike."""
    Lc = np.array([1.0, 0.5, 0.25])
    h, w = 32, 64
    full = np.broadcast_to(Lc, (h, w, 3)).copy()
    upper = full.copy()
    upper[: h // 2] = 0.0
    for px, expect in ((full, 2 * math.pi * Lc), (upper, math.pi * Lc)):
        cs = compile_scene(plane_scene(EnvironmentMap(px)))
        assert not cs.lights.env_constant
        np.testing.assert_allclose(cs.lights.flux[0], cs.lights.env_power * math.pi * cs.lights.bound_radius ** 2)
        ids, e = texel_gather.direct_texel_irradiance(cs, samples_per_texel=4096, seed=1)
        # L / pdf is constant here; what is left is the receiver cosine's variance
        np.testing.assert_allclose(e.mean(axis=0), expect, rtol=0.03)
        np.testing.assert_allclose(e, np.broadcast_to(expect, e.shape), rtol=0.15)
        # colour exact: every sample has the map's one colour
        np.testing.assert_allclose(e / e[:, :1], np.broadcast_to(Lc / Lc[0], e.shape), rtol=1e-12)
        cs.reset_lightmaps()
        st = trace_photons(cs, 400_000, seed=2, max_bounces=0, record_direct=True)
        assert st.audit_error() < 1e-12
        lm = cs.lightmaps
        got = lm.irradiance[lm.area > 0].mean(axis=0)
        np.testing.assert_allclose(got, expect, rtol=0.02)


def test_photon_audit_closes_with_an_environment_map():
    px = random_map(h=32, w=64, seed=7)
    cs = compile_scene(world_scene(EnvironmentMap(px)))
    assert not cs.lights.env_constant
    st = trace_photons(cs, 200_000, seed=3, max_bounces=6, record_direct=True)
    assert st.audit_error() < 1e-12
    # photons carry the map's colour along their direction (photon_tint), so each band's
    # emitted power equals the exact flux in expectation: 200k photons, within 1 %
    np.testing.assert_allclose(st.emitted, cs.lights.flux.sum(axis=0), rtol=0.01)
    assert np.all(st.escaped > 0) and np.all(st.absorbed > 0)
    info = cs.info["environment"]
    assert (info["width"], info["height"]) == (64, 32) and info["bytes"] >= px.nbytes


def test_map_photons_light_a_plane_like_the_gather():
    """A bright patch off-zenith: photon irradiance on a floor (first hits) against the
    gathered direct light, texel by texel (the emission's direction, disk and flux)."""
    px = np.full((32, 64, 3), 0.05)
    px[24:27, 40:44] = 40.0
    cs = compile_scene(plane_scene(EnvironmentMap(px)))
    ids, e = texel_gather.direct_texel_irradiance(cs, samples_per_texel=256, seed=1)
    st = trace_photons(cs, 1_000_000, seed=5, max_bounces=0, record_direct=True)
    assert st.audit_error() < 1e-12
    got = cs.lightmaps.irradiance[ids]
    np.testing.assert_allclose(got.mean(axis=0), e.mean(axis=0), rtol=0.02)
    np.testing.assert_allclose(got, e, rtol=0.08)


@njit(cache=True)
def _tints(ls, g, n):
    out = np.empty((n, ls.radiance.shape[1]))
    for i in range(n):
        r = lights.emit_photon(ls, g, stream_state(8, i))
        lights.photon_tint(ls, r[1], r[5], r[6], r[7], out[i])
    return out


def test_photon_tint_keeps_the_flux_per_band():
    """Tinting environment photons by their direction's colour leaves each band's
    emitted flux unchanged in expectation (and is 1 for a constant world)."""
    px = random_map(h=16, w=32, seed=2)
    cs = compile_scene(plane_scene(EnvironmentMap(px)))
    t = _tints(cs.lights, cs.geometry, 400_000)
    assert t.min() >= 0 and t.std(axis=0).min() > 0.05
    np.testing.assert_allclose(t.mean(axis=0), 1.0, atol=4 * t.std(axis=0).max() / math.sqrt(len(t)))
    cs1 = compile_scene(plane_scene(0.4))
    assert np.all(_tints(cs1.lights, cs1.geometry, 100) == 1.0)
