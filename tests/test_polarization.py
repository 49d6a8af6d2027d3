"""Polarization algebra (engine/shading/polarization.py, thesis A.2): Fresnel with
retardance against the complex-amplitude Fresnel equations, Brewster's angle, Malus's
law, Mueller matrices against Jones calculus, and energy bounds along specular chains."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine.shading import polarization as P

ANGLES = np.radians(np.concatenate([np.linspace(0.0, 89.0, 90), [89.5, 89.9]]))
INTERFACES = {"glass 1.5": (1.5, 0.0), "glass 1.9": (1.9, 0.0), "inside glass 1.5": (1 / 1.5, 0.0),
              **{name: nk for name, nk in P.CONDUCTORS.items()}}


@pytest.mark.parametrize("name", list(INTERFACES))
def test_fresnel_with_retardance_matches_the_complex_amplitudes(name):
    """F_s = |r_s|², F_p = |r_p|² and δ = -arg r within 1e-6 at every incidence, for
    dielectrics from both sides (total internal reflection from inside) and metals."""
    n, k = INTERFACES[name]
    c = np.cos(ANGLES)
    f_s, f_p, d_s, d_p = P.fresnel_retardance(c, n, k)
    r_s, r_p = P.fresnel_amplitudes(c, n, k)
    np.testing.assert_allclose(f_s, np.abs(r_s) ** 2, atol=1e-6)
    np.testing.assert_allclose(f_p, np.abs(r_p) ** 2, atol=1e-6)
    # phases compared on the circle (a phase of 0 and of 2π are one)
    for d, r in ((d_s, r_s), (d_p, r_p)):
        ok = np.abs(r) > 1e-9                      # the phase of a vanishing amplitude (Brewster) is moot
        np.testing.assert_allclose(np.exp(1j * d[ok]), np.exp(-1j * np.angle(r[ok])), atol=1e-6)


def test_catalogued_reflectances():
    """1 -> 1.5 at normal incidence: 0.04; Cu, Au, Al near 560 nm: 0.6725, 0.8776, 0.9200."""
    assert P.fresnel_retardance(1.0, 1.5)[0] == pytest.approx(0.04, abs=1e-12)
    for name, r0 in (("Cu", 0.6725), ("Au", 0.8776), ("Al", 0.9200)):
        f_s, f_p, _, _ = P.fresnel_retardance(1.0, *P.CONDUCTORS[name])
        assert f_s == pytest.approx(r0, abs=1e-4) and f_p == pytest.approx(r0, abs=1e-4)


@pytest.mark.parametrize("n,deg", [(1.5, 56.31), (1.9, 62.24)])
def test_light_reflected_at_brewsters_angle_is_fully_s_polarized(n, deg):
    """At atan(n) (56.31° for 1.5, 62.24° for 1.9) F_p vanishes: unpolarized light comes back
    polarized along s, degree of polarization 1, S1 = S0."""
    theta = math.atan(n)
    assert math.degrees(theta) == pytest.approx(deg, abs=0.005)
    f_s, f_p, d_s, d_p = P.fresnel_retardance(math.cos(theta), n)
    assert f_p < 1e-15
    S = P.reflection(f_s, f_p, d_s, d_p) @ np.array([1.0, 0.0, 0.0, 0.0])
    assert S[0] == pytest.approx(f_s / 2) and S[1] == pytest.approx(S[0]) and P.degree_of_polarization(S) == \
        pytest.approx(1.0)
    # a degree away it is not
    f_s, f_p, d_s, d_p = P.fresnel_retardance(math.cos(theta + math.radians(1.0)), n)
    assert P.degree_of_polarization(P.reflection(f_s, f_p, d_s, d_p) @ [1.0, 0, 0, 0]) < 0.999


@pytest.mark.parametrize("name", list(INTERFACES))
def test_mueller_matrices_are_their_jones_matrices(name):
    """The reflection matrix from F and δ equals U (J ⊗ J*) U⁻¹ of J = diag(r_s, r_p) within
    1e-6 (this pins the sign of the retardance terms); so do the rotator and the polarizer."""
    n, k = INTERFACES[name]
    for t in ANGLES[::7]:
        c = math.cos(t)
        m = P.reflection(*(float(x) for x in P.fresnel_retardance(c, n, k)))
        r_s, r_p = P.fresnel_amplitudes(c, n, k)
        np.testing.assert_allclose(m, P.mueller_of_jones(np.diag([complex(r_s), complex(r_p)])), atol=1e-6)
    for phi in (0.3, -1.1, 2.0):
        c, s = math.cos(phi), math.sin(phi)
        # a frame turned by phi: components in the new frame are R(-phi) applied to the old ones
        np.testing.assert_allclose(P.rotator(phi), P.mueller_of_jones([[c, s], [-s, c]]), atol=1e-12)
        np.testing.assert_allclose(P.linear_polarizer(phi), P.mueller_of_jones([[c * c, c * s], [c * s, s * s]]),
                                   atol=1e-12)


def test_malus_law():
    """A polarizer at φ behind a linearly polarized source passes cos²φ of it."""
    source = P.linear_polarizer(0.0) @ np.array([2.0, 0.0, 0.0, 0.0])     # 1 W along x
    for phi in np.radians([0.0, 20.0, 45.0, 60.0, 90.0, 135.0]):
        assert (P.linear_polarizer(phi) @ source)[0] == pytest.approx(math.cos(phi) ** 2, abs=1e-12)


def test_frames_turn_with_the_ray():
    """frame_angle gives the rotator's argument: x turned by it about d lands on the new x, and
    re-expressing a polarized beam in a turned frame keeps its intensity and degree."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        x = P.s_direction(d, rng.normal(size=3))
        y = np.cross(d, x)
        phi = rng.uniform(-math.pi, math.pi)
        x2 = math.cos(phi) * x + math.sin(phi) * y
        assert P.frame_angle(x, x2, d) == pytest.approx(phi, abs=1e-12)
        S = np.array([1.0, 0.6, -0.3, 0.2])
        S2 = P.rotator(phi) @ S
        assert S2[0] == S[0] and P.degree_of_polarization(S2) == pytest.approx(P.degree_of_polarization(S))


def test_specular_chains_are_passive_and_keep_polarization_physical():
    """Random chains of metal and glass reflections and transmissions, each in its own frame:
    S0 never exceeds the S0 that came in, and the degree of polarization stays within 1.
    (It may exceed the product of unpolarized reflectances: light polarized by one
    reflection can be what the next reflects best.)"""
    rng = np.random.default_rng(7)
    names = list(INTERFACES)
    for _ in range(200):
        S = np.array([1.0, 0.0, 0.0, 0.0]) if rng.random() < 0.5 else \
            np.concatenate([[1.0], rng.normal(size=3)])
        S[1:] *= min(1.0, 1.0 / np.linalg.norm(S[1:])) if np.linalg.norm(S[1:]) > 0 else 1.0
        s0 = S[0]
        for _ in range(rng.integers(1, 6)):
            n, k = INTERFACES[names[rng.integers(len(names))]]
            c = rng.uniform(0.0, 1.0)
            f = [float(x) for x in P.fresnel_retardance(c, n, k)]
            m = P.reflection(*f) if (k > 0.0 or rng.random() < 0.5) else P.transmission(f[0], f[1])
            S = m @ (P.rotator(rng.uniform(-math.pi, math.pi)) @ S)
            assert S[0] <= s0 * (1.0 + 1e-12)
            assert P.degree_of_polarization(S) <= 1.0 + 1e-9
            s0 = S[0]


def _glare(theta_deg, polarizer, ior=1.5):
    """The camera's value (one ray) looking at a smooth dielectric surface at theta_deg from its
    normal (a black base under a clear coat of index `ior`, Principled's Specular IOR Level
    0.5: every camera ray reflects, weighted by Fresnel), seeing the reflection of a white
    glowing wall (radiance 1). The filter's axis is at `polarizer` from the camera's x,
    which is the s direction here (None: no filter)."""
    from photon_lightmaps.engine import demo_scenes
    from photon_lightmaps.engine.compile import compile_scene
    from photon_lightmaps.engine.core.scene import Camera, Material, Scene, compose, rotate, translate
    from photon_lightmaps.engine.transport import renderer
    s = Scene(n_bands=3)
    glass = s.add_material(Material("water", diffuse=0.0, roughness=0.0, ior=ior, specular_level=0.5))
    glow = s.add_material(Material("glow", diffuse=0.0, emission=1.0))
    s.add_object(demo_scenes.quad_mesh((-50, -50, 0), (50, -50, 0), (50, 50, 0), (-50, 50, 0), material=glass,
                                       name="water"), name="water", lightmap_resolution=2)
    s.add_object(demo_scenes.quad_mesh((-80, 60, 0), (80, 60, 0), (80, 60, 300), (-80, 60, 300), material=glow,
                                       name="wall"), name="wall", lightmap_resolution=2)
    t = math.radians(theta_deg)
    s.camera = Camera(transform=compose(translate(0.0, -5.0 * math.sin(t), 5.0 * math.cos(t)), rotate("x", theta_deg)),
                      fov=math.radians(0.01), width=1, height=1,
                      polarizer=None if polarizer is None else math.radians(polarizer))
    return renderer.render(compile_scene(s), samples=1, indirect=False)[0, 0]


@pytest.mark.parametrize("theta", [56.3099, 30.0, 75.0])
def test_a_polarizing_filter_takes_the_glare_off_water(theta):
    """The camera's filter across the plane of incidence (along s) passes F_s/2 of the glare,
    along the plane (p) F_p/2, none the unpolarized (F_s + F_p)/2, each within 1e-9; at
    Brewster's angle (56.31° for 1.5) the p filter removes the glare."""
    f_s, f_p, _, _ = P.fresnel(math.cos(math.radians(theta)), 1.5, 0.0)
    none, along_s, along_p = (_glare(theta, pol) for pol in (None, 0.0, 90.0))
    np.testing.assert_allclose(none, 0.5 * (f_s + f_p), rtol=1e-9)
    np.testing.assert_allclose(along_s, 0.5 * f_s, rtol=1e-9)
    np.testing.assert_allclose(along_p, 0.5 * f_p, rtol=1e-9, atol=1e-12)
    if abs(theta - 56.3099) < 1e-3:
        assert along_p.max() < 1e-8 * none.min()
    # a filter at 45° passes half of the (partly polarized) glare: S2 is 0 in this frame
    np.testing.assert_allclose(_glare(theta, 45.0), 0.5 * none, rtol=1e-9)


def _through_pane(theta_deg, polarizer, spp=16384, polarized=False):
    """The camera's value looking through a 1 cm glass pane (index 1.5, two smooth faces) at
    theta_deg from its normal onto a glowing floor (radiance 1) below; what the pane reflects
    goes up into a black world. Camera paths pick reflection or refraction at each face by
    Fresnel's odds, so this is a Monte Carlo estimate."""
    from photon_lightmaps.engine import demo_scenes
    from photon_lightmaps.engine.compile import compile_scene
    from photon_lightmaps.engine.core.scene import Camera, Material, Scene, compose, rotate, translate
    from photon_lightmaps.engine.transport import renderer
    s = Scene(n_bands=3)
    glass = s.add_material(Material("glass", diffuse=0.0, transmission=1.0, roughness=0.0, ior=1.5))
    glow = s.add_material(Material("glow", diffuse=0.0, emission=1.0))
    big = 50.0
    s.add_object([demo_scenes.quad_mesh((-big, -big, 0.01), (big, -big, 0.01), (big, big, 0.01), (-big, big, 0.01),
                                        material=glass, name="top"),
                  demo_scenes.quad_mesh((-big, -big, 0.0), (-big, big, 0.0), (big, big, 0.0), (big, -big, 0.0),
                                        material=glass, name="bottom")], name="pane", lightmap_resolution=2)
    s.add_object(demo_scenes.quad_mesh((-big, -big, -1), (big, -big, -1), (big, big, -1), (-big, big, -1),
                                       material=glow, name="floor"), name="floor", lightmap_resolution=2)
    t = math.radians(theta_deg)
    s.camera = Camera(transform=compose(translate(0.0, -5.0 * math.sin(t), 5.0 * math.cos(t)), rotate("x", theta_deg)),
                      fov=math.radians(0.01), width=1, height=1,
                      polarizer=None if polarizer is None else math.radians(polarizer), polarized=polarized)
    return renderer.render(compile_scene(s), samples=spp, seed=3, indirect=False, max_depth=16)[0, 0]


def test_light_through_a_tilted_pane_is_partly_p_polarized():
    """Through both faces of a pane at 60° (every internal reflection added up, incoherently):
    (1 - R)/(1 + R) of each component, so a filter along p passes more than one along s;
    within 1 % (measured 0.15 % and 0.27 %; the estimate's noise at 16384 paths: 0.3 %).
    Without a filter nothing is polarized: every face reflects the mean (R_s + R_p)/2, and
    the pane passes (1 - R)/(1 + R) of that, 1.4 % less than the two components do; with
    the scene's Polarization on, the camera sees the components' sum."""
    f_s, f_p, _, _ = P.fresnel(math.cos(math.radians(60.0)), 1.5, 0.0)
    t_s, t_p = (1 - f_s) / (1 + f_s), (1 - f_p) / (1 + f_p)
    np.testing.assert_allclose(_through_pane(60.0, 0.0), 0.5 * t_s, rtol=0.01)
    np.testing.assert_allclose(_through_pane(60.0, 90.0), 0.5 * t_p, rtol=0.01)
    r = 0.5 * (f_s + f_p)
    np.testing.assert_allclose(_through_pane(60.0, None), (1 - r) / (1 + r), rtol=0.01)
    # with Polarization on and no filter, the camera sees both components' sum
    np.testing.assert_allclose(_through_pane(60.0, None, polarized=True), 0.5 * (t_s + t_p), rtol=0.01)


# ---------------------------------------------------------------- mirror chains, by 3-D Jones calculus

def _quad(centre, normal, half, material, name):
    """A square of side 2 half at `centre` facing `normal`."""
    from photon_lightmaps.engine import demo_scenes
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    u *= half / np.linalg.norm(u)
    v = np.cross(n, u)
    c = np.asarray(centre, float)
    return demo_scenes.quad_mesh(c - u - v, c + u - v, c + u + v, c - u + v, material=material, name=name)


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# the camera looks down (its x is the world's x) at mirror 2, which sends the ray along +x to
# mirror 1, which sends it on along D2 to a glowing wall: two planes of incidence 65° apart,
# incidence 45° and 57°
D0, D1, D2 = np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]), _unit([0.5, 1.0, 0.5])


def _chain_render(materials, polarizer, spectral=False):
    from photon_lightmaps.engine import spectral as spectral_mode
    from photon_lightmaps.engine.compile import compile_scene
    from photon_lightmaps.engine.core.scene import Camera, Material, Scene, translate
    from photon_lightmaps.engine.transport import renderer
    s = Scene(n_bands=3)
    m2, m1 = (s.add_material(m) for m in materials)
    glow = s.add_material(Material("glow", diffuse=0.0, emission=1.0))
    p1 = np.array([3.0, 0.0, 0.0])
    s.add_object(_quad([0, 0, 0], D1 - D0, 0.5, m2, "mirror2"), name="mirror2", lightmap_resolution=2)
    s.add_object(_quad(p1, D2 - D1, 0.5, m1, "mirror1"), name="mirror1", lightmap_resolution=2)
    s.add_object(_quad(p1 + 50 * D2, -D2, 100.0, glow, "wall"), name="wall", lightmap_resolution=2)
    s.camera = Camera(transform=translate(0.0, 0.0, 5.0), fov=math.radians(0.01), width=1, height=1,
                      polarizer=None if polarizer is None else math.radians(polarizer), polarized=True)
    if spectral:
        s = spectral_mode.spectral_scene(s)
    return renderer.render(compile_scene(s), samples=1, indirect=False)[0, 0]


# a metal without an index (Schlick's colour, or a constant) reflects as a perfect conductor
# does, without telling s from p: amplitudes -√F and √F
CHROME = "chrome"


def _amplitudes(c, index):
    if isinstance(index, str):          # CHROME
        return -math.sqrt(0.9), math.sqrt(0.9)
    return P.fresnel_amplitudes(c, *index)


def _jones_reflect(E, d_in, d_out, n, r_s, r_p):
    """The field E (3-D, across d_in) after a reflection off normal n with amplitudes r_s, r_p:
    s across the plane of incidence, p = s × d on each side (so that at normal incidence a
    mirror scales the field by r_s, as Fresnel's sign convention has it)."""
    s = np.cross(d_in, n)
    s = s / np.linalg.norm(s)
    return r_s * np.dot(E, s) * s + r_p * np.dot(E, np.cross(s, d_in)) * np.cross(s, d_out)


def _chain_expected(indices, polarizer):
    """What the camera sees of the wall (radiance 1, unpolarized) through both mirrors:
    the two orthogonal input polarizations' intensities after both reflections, halved,
    through the filter (|a · E|²) or not (|E|²). indices: (n, k) of mirror 2, mirror 1."""
    out = 0.0
    for e in (np.cross(D2, [0.0, 0.0, 1.0]), None):
        e = _unit(e) if e is not None else _unit(np.cross(D2, _unit(np.cross(D2, [0.0, 0.0, 1.0]))))
        # light runs backwards along the camera's path: wall -> mirror 1 -> mirror 2 -> camera
        n1v, n2v = _unit(D2 - D1), _unit(D1 - D0)
        c1 = float(np.dot(D2, n1v))
        E = _jones_reflect(e.astype(complex), -D2, -D1, n1v, *_amplitudes(c1, indices[1]))
        c2 = float(np.dot(D1, n2v))
        E = _jones_reflect(E, -D1, -D0, n2v, *_amplitudes(c2, indices[0]))
        if polarizer is None:
            out += 0.5 * float(np.vdot(E, E).real)
        else:
            a = np.array([math.cos(math.radians(polarizer)), math.sin(math.radians(polarizer)), 0.0])
            out += 0.5 * abs(np.dot(a, E)) ** 2
    return out


def _mirrors(pair):
    """Materials of mirrors named 'glass' (a clear coat) or a conductor preset, and their (n, k) per RGB band."""
    from photon_lightmaps.engine.core.scene import Material
    from photon_lightmaps.engine.shading import conductor
    mats, idx = [], []
    for name in pair:
        if name == "glass":
            mats.append(Material("coat", diffuse=0.0, roughness=0.0, ior=1.5, specular_level=0.5))
            idx.append([(1.5, 0.0)] * 3)
        elif name == "chrome":          # a metal without an index: reflects 0.9 at every angle
            mats.append(Material("chrome", diffuse=0.0, specular=0.9, roughness=0.0, metallic=1.0))
            idx.append([CHROME] * 3)
        else:
            mats.append(Material(name, diffuse=0.0, roughness=0.0, metallic=1.0, conductor=name))
            idx.append([tuple(x) for x in conductor.rgb_index(name)])
    return mats, idx


@pytest.mark.parametrize("pair", [("Au", "Au"), ("Cu", "glass"), ("glass", "Al"), ("chrome", "glass")])
def test_two_mirror_chain_matches_jones_calculus(pair):
    """Camera paths through two smooth mirrors in planes of incidence 65° apart (metals at
    their complex index, a metal without one, or a glass coat), behind filters at 0°, 45°,
    90°, 135° and none: the Mueller path (frame turns, retardance) equals 3-D Jones
    calculus within 1e-9 per band."""
    mats, idx = _mirrors(pair)
    for pol in (None, 0.0, 45.0, 90.0, 135.0):
        got = _chain_render(mats, pol)
        want = [_chain_expected((idx[0][b], idx[1][b]), pol) for b in range(3)]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    # the 45° and 135° filters see the retardance, and a metal's mirroring of the field: they differ
    assert abs(_chain_render(mats, 45.0)[0] - _chain_render(mats, 135.0)[0]) > 1e-3


def test_two_mirror_chain_in_spectral_mode_turns_each_band_by_its_own_index():
    """Spectral mode: each of the 16 bands reflects at its own complex index (gold and copper
    change colour across the visible), so each band's row differs; every band equals Jones
    calculus within 1e-9."""
    from photon_lightmaps.engine.core.scene import Material
    from photon_lightmaps.engine.shading import conductor
    from photon_lightmaps.engine.shading.spectrum import Bands
    mats = [Material(n, diffuse=0.0, roughness=0.0, metallic=1.0, conductor=n) for n in ("Au", "Cu")]
    idx = [conductor.band_index(n, 16, Bands()) for n in ("Au", "Cu")]
    for pol in (45.0, 135.0):
        got = _chain_render(mats, pol, spectral=True)
        # the wall glows white: D65 in the bands
        want = [Bands().white[b] * _chain_expected((idx[0][b], idx[1][b]), pol) for b in range(16)]
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------- photons

def _frame_along(z):
    """A rotation whose local z is `z` (a light emits along its local -z)."""
    z = _unit(z)
    x = _unit(np.cross([0.0, 0.0, 1.0], z))
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, z
    return m


def _chain_photons(materials, polarized, light_polarizer=None, photons=4000):
    """Photon pass through the mirror chain run the other way: a 0.05° spot 500 m out along
    D2 lights mirror 1 only; what both mirrors pass lands on a white receiver above mirror 2.
    -> (the receiver's recorded flux per band, the ledger's audit error, the spot's axis)."""
    from photon_lightmaps.engine.compile import compile_scene
    from photon_lightmaps.engine.core.scene import Camera, Light, Material, Scene
    from photon_lightmaps.engine.lightmaps import lightmap
    from photon_lightmaps.engine.transport import photon_tracer
    s = Scene(n_bands=3)
    m2, m1 = (s.add_material(m) for m in materials)
    white = s.add_material(Material("white", diffuse=0.8))
    p1 = np.array([3.0, 0.0, 0.0])
    s.add_object(_quad([0, 0, 0], D1 - D0, 0.5, m2, "mirror2"), name="mirror2", lightmap_resolution=2)
    s.add_object(_quad(p1, D2 - D1, 0.5, m1, "mirror1"), name="mirror1", lightmap_resolution=2)
    s.add_object(_quad([0, 0, 3], [0, 0, -1], 1.0, white, "receiver"), name="receiver", lightmap_resolution=2)
    xf = _frame_along(D2)
    xf[:3, 3] = p1 + 500.0 * D2
    s.lights.append(Light("spot", power=1000.0, transform=xf, spot_size=math.radians(0.05), spot_blend=0.0,
                          polarizer=None if light_polarizer is None else math.radians(light_polarizer)))
    s.camera = Camera(polarized=polarized)
    cs = compile_scene(s)
    stats = photon_tracer.trace_photons(cs, photons, seed=7)
    lm = cs.lightmaps
    flux = lm.flux[lightmap.texel_slice(lm, cs.instance_lightmaps[2][0])].sum(axis=0)
    t = math.radians(light_polarizer or 0.0)
    axis = xf[:3, 0] * math.cos(t) + xf[:3, 1] * math.sin(t)
    return flux, stats.audit_error(), axis


def _chain_transmits(indices, field=None):
    """Jones calculus of light from the spot through mirror 1 then mirror 2: the fraction of
    its S0 that comes out, unpolarized light (field None) or linearly polarized along `field`."""
    n1v, n2v = _unit(D2 - D1), _unit(D1 - D0)
    e1 = _unit(np.cross(D2, [0.0, 0.0, 1.0]))
    basis = [e1, np.cross(D2, e1)] if field is None else [_unit(field - np.dot(field, D2) * D2)]
    out = 0.0
    for e in basis:
        E = _jones_reflect(e.astype(complex), -D2, -D1, n1v, *_amplitudes(float(np.dot(D2, n1v)), indices[1]))
        E = _jones_reflect(E, -D1, -D0, n2v, *_amplitudes(float(np.dot(D1, n2v)), indices[0]))
        out += float(np.vdot(E, E).real) / len(basis)
    return out


@pytest.mark.parametrize("pair", [("glass", "glass"), ("Au", "Cu")])
def test_photons_through_a_mirror_chain_carry_their_polarization(pair):
    """The same photons (same seed, same choices) through two mirrors in planes 65° apart:
    with polarization traced, what reaches the receiver changes by Jones calculus's ratio
    over the product of the mirrors' unpolarized reflectances (within 1e-3: the spot's
    0.05° spread), and the ledger still balances exactly."""
    mats, idx = _mirrors(pair)
    plain, audit_plain, _ = _chain_photons(mats, False)
    traced, audit, _ = _chain_photons(mats, True)
    assert audit < 1e-12 and audit_plain < 1e-12
    assert np.all(plain > 0.0)
    for b in range(3):
        r1 = 0.5 * sum(P.fresnel(float(np.dot(D2, _unit(D2 - D1))), *idx[1][b])[:2])
        r2 = 0.5 * sum(P.fresnel(float(np.dot(D1, _unit(D1 - D0))), *idx[0][b])[:2])
        want = _chain_transmits((idx[0][b], idx[1][b])) / (r1 * r2)
        assert traced[b] / plain[b] == pytest.approx(want, rel=1e-3)
    if pair == ("glass", "glass"):
        assert abs(traced[0] / plain[0] - 1.0) > 0.1          # it matters here (metals polarize little)


@pytest.mark.parametrize("angle", [0.0, 60.0, 90.0])
def test_a_polarized_light_through_a_mirror_chain(angle):
    """A light behind a linear polarizer passes half its power, polarized along the
    polarizer's axis: through the chain, the receiver gets Jones calculus's share of that
    half, against the same light unpolarized (within 1e-3)."""
    mats, idx = _mirrors(("glass", "Au"))
    plain, _, _ = _chain_photons(mats, True)
    polarized, audit, axis = _chain_photons(mats, False, light_polarizer=angle)
    assert audit < 1e-12
    for b in range(3):
        want = 0.5 * _chain_transmits((idx[0][b], idx[1][b]), axis) / _chain_transmits((idx[0][b], idx[1][b]))
        assert polarized[b] / plain[b] == pytest.approx(want, rel=1e-3)


def test_a_bad_light_polarizer_is_refused_by_name():
    from photon_lightmaps.engine.compile import compile_scene
    from photon_lightmaps.engine.core.scene import Light, Scene, SceneError
    s = Scene(lights=[Light("spot", name="lamp", polarizer=float("nan"))])
    with pytest.raises(SceneError, match="light 'lamp'.*polarizer"):
        compile_scene(s)


@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0, 135.0])
def test_malus_law_through_a_mirror(angle):
    """A camera behind a filter at 0° sees, in a chrome mirror, an area light behind a
    polarizer at `angle`: half the light, mirrored (Jones calculus), then cos² of what is
    left between the two axes, within 1e-9 of the light seen unpolarized without a filter."""
    from photon_lightmaps.engine.compile import compile_scene
    from photon_lightmaps.engine.core.scene import Camera, Light, Material, Scene, translate
    from photon_lightmaps.engine.transport import renderer

    def render(polarizer, light_polarizer):
        s = Scene(n_bands=3)
        m = s.add_material(Material("chrome", diffuse=0.0, specular=0.9, roughness=0.0, metallic=1.0))
        s.add_object(_quad([0, 0, 0], D1 - D0, 0.5, m, "mirror"), name="mirror", lightmap_resolution=2)
        xf = _frame_along(D1)             # emits along -D1, back at the mirror
        xf[:3, 3] = 20.0 * D1
        s.lights.append(Light("area", power=1000.0, size=4.0, transform=xf, name="panel",
                              polarizer=None if light_polarizer is None else math.radians(light_polarizer)))
        s.camera = Camera(transform=translate(0.0, 0.0, 5.0), fov=math.radians(0.01), width=1, height=1,
                          polarizer=None if polarizer is None else math.radians(polarizer), polarized=True)
        return renderer.render(compile_scene(s), samples=1, indirect=False)[0, 0], xf

    plain, _ = render(None, None)
    got, xf = render(0.0, angle)
    t = math.radians(angle)
    axis = xf[:3, 0] * math.cos(t) + xf[:3, 1] * math.sin(t)
    E = _jones_reflect(_unit(axis - np.dot(axis, D1) * D1).astype(complex), -D1, -D0, _unit(D1 - D0),
                       *_amplitudes(0.0, CHROME))
    want = 0.5 * abs(E[0]) ** 2 / 0.9                 # the filter passes the field's x part
    assert plain[0] > 0.0
    np.testing.assert_allclose(got / plain, want, rtol=1e-9, atol=1e-12)
