"""Dispersion in the passes (spectral mode): a narrow beam through a 60° N-BK7
prism, traced by the photon pass onto a far screen and a floor, and seen by the
camera pass; every band's light lands where Snell's law at its wavelengths puts it.

The beam enters the prism's left face at its middle at the d line's
minimum-deviation incidence, so inside the prism the d line runs parallel to the
base and leaves from the middle of the right face. Deviation is stationary
there: the F and C lines, at the same incidence, leave within 2e-5 rad of their
own minimum deviation."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes, spectral
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.core.scene import Camera, Light, Material, Scene, SceneError, compose, rotate, translate
from photon_lightmaps.engine.shading import dispersion, spectrum
from photon_lightmaps.engine.transport import renderer
from photon_lightmaps.engine.transport.photon_tracer import trace_photons

BK7 = dispersion.PRESETS["N-BK7"]
N_D = float(dispersion.sellmeier_index(BK7, dispersion.LINE_D))
PHI = math.asin(N_D * 0.5) - math.radians(30.0)          # the beam's elevation: θ1 - A/2
D_IN = np.array([math.cos(PHI), 0.0, math.sin(PHI)])
E_OUT = np.array([math.cos(PHI), 0.0, -math.sin(PHI)])   # the d line's way out
UP = np.array([-math.sin(PHI), 0.0, math.cos(PHI)])       # the beam frame's +x (a camera's film x)
S3 = math.sqrt(3.0)
LEFT_MID, RIGHT_MID = np.array([-0.25, 0.0, S3 / 4]), np.array([0.25, 0.0, S3 / 4])
N_LEFT, N_RIGHT = np.array([-S3 / 2, 0.0, 0.5]), np.array([S3 / 2, 0.0, 0.5])
SCREEN = RIGHT_MID + 50.0 * E_OUT                         # a far screen across the d line's way out
ACROSS = np.array([E_OUT[2], 0.0, -E_OUT[0]])             # the screen's direction in the plane of the beam
FLOOR_Z = -2.0


def _facing(corners, towards, material, name):
    """A quad through `corners` whose front faces along `towards`."""
    q = demo_scenes.quad_mesh(*corners, material=material, name=name)
    v = q.vertices
    if np.dot(np.cross(v[1] - v[0], v[2] - v[0]), towards) < 0.0:
        q = demo_scenes.quad_mesh(corners[0], corners[3], corners[2], corners[1], material=material, name=name)
    return q


def _beam_frame(at):
    """A light's or camera's transform at `at`, looking along D_IN (local -z), film x along UP."""
    return compose(translate(*at), rotate("y", -(90.0 + math.degrees(PHI))))


def prism_scene(target, bands=None, glass="N-BK7", abbe=0.0, ior=1.5):
    """The prism and a narrow spot beam (0.2° cone, 20 m back) onto `target`: 'screen' (4 x 2 m,
    black) or 'floor' (black, at z = -2); bands None: RGB."""
    s = Scene(n_bands=3)
    g = s.add_material(Material("glass", diffuse=0.0, transmission=1.0, ior=ior, glass=glass, abbe=abbe))
    black = s.add_material(Material("black", diffuse=0.0))
    s.add_object(demo_scenes.prism_mesh(material=g), name="prism", lightmap_resolution=4)
    if target == "screen":
        u, y = 2.0 * ACROSS, np.array([0.0, 1.0, 0.0])
        corners = [SCREEN - u - y, SCREEN + u - y, SCREEN + u + y, SCREEN - u + y]
        s.add_object(_facing(corners, -E_OUT, black, "screen"), name="screen", lightmap_resolution=8)
    else:
        z = FLOOR_Z
        s.add_object(demo_scenes.quad_mesh((0, -1.5, z), (12, -1.5, z), (12, 1.5, z), (0, 1.5, z), material=black,
                                           name="floor"), name="floor", lightmap_resolution=8)
    s.lights.append(Light("spot", power=100.0, spot_size=math.radians(0.2), spot_blend=0.0,
                          transform=_beam_frame(LEFT_MID - 20.0 * D_IN), name="spot"))
    return s if bands is None else spectral.spectral_scene(s, bands)


def landed(scene, on, photons=200_000, seed=1):
    """(hit points (K, 3), power (K, bands), stats) of the photons that reached the target
    (on(points) -> mask)."""
    cs = compile_scene(scene)
    st = trace_photons(cs, photons, seed=seed, max_bounces=4, record_direct=True, keep_points=True)
    p, w = st.points[:, :3], st.point_power
    keep = on(p)
    return p[keep], w[keep], st


def on_screen(p):
    return np.abs((p - SCREEN) @ E_OUT) < 1e-6


def band_deviations(p, w):
    """Deviation (degrees) of each band's centroid on the screen, seen from the right face's middle."""
    out = []
    for k in range(w.shape[1]):
        v = (p * w[:, k:k + 1]).sum(axis=0) / w[:, k].sum() - RIGHT_MID
        out.append(math.degrees(math.acos(np.clip(v @ D_IN / np.linalg.norm(v), -1.0, 1.0))))
    return np.array(out)


def narrow_bands(nm):
    """Three 0.2 nm bands, the middle one centred on nm."""
    return spectrum.Bands(3, nm - 0.3, nm + 0.3)


@pytest.mark.parametrize("line,nm,catalogue", [("F", dispersion.LINE_F, 39.138), ("d", dispersion.LINE_D, 38.647),
                                               ("C", dispersion.LINE_C, 38.429)])
def test_traced_photons_leave_the_prism_at_its_minimum_deviation(line, nm, catalogue):
    """The catalogue's minimum deviation at the F, d and C lines within 0.05° (measured:
    within 0.002°), the light that gets through as Fresnel's equations at the line's
    index say, and the energy audit exact although photons move their power into the
    band they keep."""
    p, w, st = landed(prism_scene("screen", narrow_bands(nm)), on_screen)
    assert abs(band_deviations(p, w)[1] - catalogue) < 0.05
    assert st.audit_error() < 1e-9
    # what reaches the screen: the band's light less both faces' Fresnel reflection at its index
    # (each face unpolarized: polarization is not traced)
    n = float(dispersion.sellmeier_index(BK7, nm))
    t1 = math.asin(math.sin(PHI + math.radians(30.0)) / n)
    through = (1.0 - _fresnel(PHI + math.radians(30.0), n)) * (1.0 - _fresnel(math.radians(60.0) - t1, 1.0 / n))
    assert abs(w[:, 1].sum() / st.emitted[1] - through) < 0.01


def _fresnel(theta, eta):
    """Unpolarized Fresnel reflectance at incidence theta into relative index eta."""
    c = math.cos(theta)
    ct = math.sqrt(1.0 - (1.0 - c * c) / (eta * eta))
    rs = (c - eta * ct) / (c + eta * ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return 0.5 * (rs * rs + rp * rp)


def test_an_abbe_number_disperses_by_cauchy():
    """A glass given as n_d and V_d (Cauchy's fit): the d line at N-BK7's deviation, the F
    line at what Cauchy's index gives there."""
    A, B = dispersion.cauchy_from_abbe(N_D, BK7.abbe)
    for nm in (dispersion.LINE_D, dispersion.LINE_F):
        p, w, _ = landed(prism_scene("screen", narrow_bands(nm), glass="", abbe=BK7.abbe, ior=N_D), on_screen,
                         photons=50_000)
        want = dispersion.minimum_deviation(float(dispersion.cauchy_index(A, B, nm)))
        assert abs(band_deviations(p, w)[1] - want) < 0.05


def test_rgb_traces_a_preset_at_its_n_d():
    """RGB mode does not disperse: every channel leaves at the d line's deviation, whatever the
    material's own IOR says (the preset replaces it)."""
    p, w, _ = landed(prism_scene("screen", None, ior=1.3), on_screen, photons=50_000)
    np.testing.assert_allclose(band_deviations(p, w), 38.647, atol=0.05)


def _snell(d, n, eta):
    """Refraction of unit d through a surface of unit normal n (against d), eta = n1 / n2."""
    c = -d @ n
    return eta * d + (eta * c - math.sqrt(1.0 - eta * eta * (1.0 - c * c))) * n


def _through_prism(origin, d, n):
    """A ray through the left face, out of the right one (index n) -> (exit point, direction)."""
    p = origin + ((LEFT_MID - origin) @ N_LEFT) / (d @ N_LEFT) * d
    d = _snell(d, N_LEFT, 1.0 / n)
    p = p + ((RIGHT_MID - p) @ N_RIGHT) / (d @ N_RIGHT) * d
    return p, _snell(d, -N_RIGHT, n)


def _band_nm(bands, k, m=41):
    w = (bands.hi - bands.lo) / bands.n
    return bands.lo + (k + (np.arange(m) + 0.5) / m) * w


def test_the_rainbow_on_the_floor_follows_snells_law():
    """16 bands on the floor 2 m below: each band's centroid where the beam's central ray lands
    by Snell's law, averaged over the band's wavelengths (bands land 2 to 10 cm apart;
    measured within 3 mm), in order from violet (nearest) to red. The same seed twice gives
    the same photons."""
    bands = spectrum.Bands()
    scene = prism_scene("floor", bands)
    p, w, _ = landed(scene, lambda q: np.abs(q[:, 2] - FLOOR_Z) < 1e-6, seed=2)
    got = (p[:, :1] * w).sum(axis=0) / w.sum(axis=0)
    want = []
    for k in range(bands.n):
        xs = []
        for nm in _band_nm(bands, k):
            q, d = _through_prism(LEFT_MID - D_IN, D_IN, float(dispersion.sellmeier_index(BK7, nm)))
            xs.append(q[0] + (FLOOR_Z - q[2]) / d[2] * d[0])
        want.append(np.mean(xs))
    np.testing.assert_allclose(got, want, atol=0.006)
    assert np.all(np.diff(got) > 0.01)
    p2, w2, _ = landed(scene, lambda q: np.abs(q[:, 2] - FLOOR_Z) < 1e-6, seed=2)
    assert np.array_equal(p, p2) and np.array_equal(w, w2)


def _camera_column(n, width, fov):
    """The film column (pixels) at which a camera 3 m before the prism on the beam's axis sees
    the middle of a thin strip on the far screen through the prism (index n)."""
    cam = LEFT_MID - 3.0 * D_IN

    def across(alpha):
        q, d = _through_prism(cam, math.cos(alpha) * D_IN + math.sin(alpha) * UP, n)
        return ((q + ((SCREEN - q) @ E_OUT) / (d @ E_OUT) * d) - SCREEN) @ ACROSS

    lo, hi = -0.05, 0.05
    f_lo = across(lo)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        f = across(mid)
        lo, hi, f_lo = (mid, hi, f) if (f > 0.0) == (f_lo > 0.0) else (lo, mid, f_lo)
    return (math.tan(0.5 * (lo + hi)) / math.tan(0.5 * fov) + 1.0) * 0.5 * width


def test_the_camera_sees_a_white_strip_split_by_snells_law():
    """The camera pass through the prism at a thin glowing strip on the far screen: each band's
    image centroid at the film column Snell's law gives, averaged over the band (within 2
    pixels of 0.012°; measured within 1.2), and the bands in order."""
    bands = spectrum.Bands()
    width, fov = 256, math.radians(3.0)
    s = Scene(n_bands=3)
    g = s.add_material(Material("glass", diffuse=0.0, transmission=1.0, glass="N-BK7"))
    glow = s.add_material(Material("glow", diffuse=0.0, emission=1.0))
    s.add_object(demo_scenes.prism_mesh(material=g), name="prism", lightmap_resolution=4)
    u, y = 0.025 * ACROSS, np.array([0.0, 2.0, 0.0])
    s.add_object(_facing([SCREEN - u - y, SCREEN + u - y, SCREEN + u + y, SCREEN - u + y], -E_OUT, glow, "strip"),
                 name="strip", lightmap_resolution=2)
    s.camera = Camera(transform=_beam_frame(LEFT_MID - 3.0 * D_IN), fov=fov, width=width, height=4)
    img = renderer.render(compile_scene(spectral.spectral_scene(s, bands)), samples=64, seed=1, indirect=False)
    profile = img.sum(axis=0)
    got = ((np.arange(width) + 0.5)[:, None] * profile).sum(axis=0) / profile.sum(axis=0)
    want = [np.mean([_camera_column(float(dispersion.sellmeier_index(BK7, nm)), width, fov)
                     for nm in _band_nm(bands, k, 21)]) for k in range(bands.n)]
    np.testing.assert_allclose(got, want, atol=2.0)
    assert np.all(np.diff(got) < -3.0)


def test_bad_dispersion_is_refused_by_name():
    for kw, words in (({"glass": "crown"}, "unknown glass 'crown'"), ({"abbe": 40.0, "ior": 0.9}, "Abbe number"),
                      ({"abbe": float("nan")}, "Abbe number")):
        s = Scene(n_bands=3)
        s.add_material(Material("lens", transmission=1.0, diffuse=0.0, **kw))
        s.add_object(demo_scenes.prism_mesh(), name="prism")
        with pytest.raises(SceneError, match=f"material 'lens'.*{words}"):
            compile_scene(spectral.spectral_scene(s))
