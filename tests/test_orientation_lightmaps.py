"""Orientation lightmaps (thesis ch. 6): normal-indexed irradiance shared by a group.

Photon paths do not depend on where hits are stored (6.2.3), so a scene traced
with the same seed with and without OLs deposits bit-for-bit the same photons:
the tests compare the two storages directly.
"""
import itertools
import math

import numpy as np
import pytest

from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine.lightmaps import texel_areas
from photon_lightmaps.engine.lightmaps import orientation_lightmap
from photon_lightmaps.engine.lightmaps.area_estimation import estimate_areas
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.geometry.assembly import compile_geometry
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.transport.renderer import render
from photon_lightmaps.engine.core.scene import (
    Camera, Instance, Light, Material, OrientationLightmap, Primitive, Prototype, Scene,
    SceneError, compose, rotate, scale, translate)


def _scene(objects, ols=(), light=(1.0, 2.0, 4.0), floor=True):
    """objects: (primitive kind, transform, params); ols: OrientationLightmap list."""
    sc = Scene(n_bands=3)
    m = sc.add_material(Material(diffuse=0.6))
    for kind, xf, params in objects:
        sc.add_object(Primitive(kind, material=m, params=params), transform=xf, name=kind,
                      lightmap_resolution=16)
    if floor:
        sc.add_object(Primitive("quad", material=m), transform=compose(translate(0, 0, -1.5), scale(5)),
                      name="floor")
    sc.lights.append(Light("point", power=1000.0, transform=translate(*light)))
    sc.orientation_lightmaps.extend(ols)
    return sc


def _ol_slice(cs, k):
    return lightmap.texel_slice(cs.lightmaps, int(cs.orientation.lid[k]))


# ------------------------------------------------------------------ limit case and energy

def test_ol_on_a_sphere_equals_its_lightmap():
    """The thesis's limit case: the sphere chart is the OL's octahedral map, so
    bin j of the OL and texel j of the sphere hold the same photons; only the
    areas differ (stochastic against exact quadrature)."""
    obj = [("sphere", np.eye(4)[:3], ())]
    plain = compile_scene(_scene(obj))
    with_ol = compile_scene(_scene(obj, [OrientationLightmap("ball", [0], resolution=16,
                                                             samples=200_000)]))
    for cs in (plain, with_ol):
        trace_photons(cs, 200_000, seed=3, record_direct=True)
    a = lightmap.texel_slice(plain.lightmaps, plain.instance_lightmaps[0][0])
    b = _ol_slice(with_ol, 0)
    assert with_ol.instance_lightmaps[0] == [], "an OL-covered instance keeps no own lightmap"
    np.testing.assert_array_equal(plain.lightmaps.hits[a], with_ol.lightmaps.hits[b])
    np.testing.assert_allclose(plain.lightmaps.flux[a], with_ol.lightmaps.flux[b], rtol=1e-12)
    # bin areas estimate the texel areas within their reported error
    exact, est = plain.lightmaps.area[a], with_ol.lightmaps.area[b]
    rel = with_ol.info["orientation_lightmaps"][0]["bin_rel_error"]
    z = (est - exact) / (rel * est)
    assert np.abs(z).max() < 5.0 and abs(z.mean()) < 0.5
    e_plain = plain.lightmaps.irradiance[a].mean(1)
    e_ol = with_ol.lightmaps.irradiance[b].mean(1)
    lit = e_plain > 0.2 * e_plain.max()
    assert np.median(np.abs(e_ol[lit] / e_plain[lit] - 1.0)) < 0.03


def test_ol_energy_equals_what_the_group_received():
    """Hits on a group of objects land on its OL with exactly the power the
    objects' own lightmaps receive; the ledger still closes."""
    objs = [("sphere", compose(translate(x, 0, 0), scale(0.4)), ()) for x in (-1.0, 0.0, 1.0)]
    objs.append(("torus", compose(translate(0, 1.2, 0), scale(0.5)), (0.3,)))
    plain = compile_scene(_scene(objs))
    grouped = compile_scene(_scene(objs, [OrientationLightmap("group", [0, 1, 2, 3])]))
    s1 = trace_photons(plain, 100_000, seed=5)
    s2 = trace_photons(grouped, 100_000, seed=5)
    own = sum(plain.lightmaps.flux[lightmap.texel_slice(plain.lightmaps, l)].sum(0)
              for i in range(4) for l in plain.instance_lightmaps[i])
    np.testing.assert_allclose(grouped.lightmaps.flux[_ol_slice(grouped, 0)].sum(0), own, rtol=1e-10)
    # the floor keeps its lightmap, unchanged
    fa = lightmap.texel_slice(plain.lightmaps, plain.instance_lightmaps[4][0])
    fb = lightmap.texel_slice(grouped.lightmaps, grouped.instance_lightmaps[4][0])
    np.testing.assert_array_equal(plain.lightmaps.flux[fa], grouped.lightmaps.flux[fb])
    for s in (s1, s2):
        assert s.audit_error() < 1e-12
    np.testing.assert_array_equal(s1.absorbed, s2.absorbed)
    assert grouped.lightmap_bytes() < plain.lightmap_bytes()


def test_render_with_ol_matches_own_lightmap_on_a_sphere():
    obj = [("sphere", np.eye(4)[:3], ())]
    imgs = []
    for ols in ([], [OrientationLightmap("ball", [0], resolution=16, samples=100_000)]):
        sc = _scene(obj, ols)
        sc.camera = Camera(transform=compose(translate(0, -5, 0), rotate("x", 90)), width=48, height=48)
        cs = compile_scene(sc)
        trace_photons(cs, 200_000, seed=2)
        imgs.append(render(cs, samples=4, seed=1))
    a, b = imgs
    assert np.isfinite(b).all()
    assert abs(b.mean() / a.mean() - 1.0) < 0.01


# ------------------------------------------------------------------ area estimation

def _geometry(objects):
    sc = _scene(objects, floor=False)
    g, _ = compile_geometry(sc)
    return g


def _bin_of(n, R):
    s, t = orientation_lightmap.bin_coords(*n)
    return min(int(t * R), R - 1) * R + min(int(s * R), R - 1)


def _box_bins(xf, R):
    """Exact area per normal bin of a transformed box: its six faces."""
    out = np.zeros(R * R)
    M = np.asarray(xf)[:, :3]
    for axis in range(3):
        for sgn in (1.0, -1.0):
            e = np.eye(3)[[a for a in range(3) if a != axis]]
            c = np.cross(M @ e[0], M @ e[1])            # face of [-1,1]^3: area 4 |c|
            n = sgn * np.linalg.inv(M).T @ np.eye(3)[axis]
            out[_bin_of(n / np.linalg.norm(n), R)] += 4.0 * np.linalg.norm(c)
    return out


def _reference_bins(case, g, R):
    if case == "sphere":
        return 0.49 * texel_areas.primitive_texel_areas(1, np.zeros(4), np.eye(3), R).reshape(-1)
    if case == "box":
        return _box_bins(AREA_CASES["box"][0][1], R)
    return estimate_areas(g, [0], R, 4_000_000, seed=99, openness_samples=0).area


AREA_CASES = {
    "sphere": (("sphere", compose(translate(0.3, 0, 0), scale(0.7)), ()), 4 * math.pi * 0.49),
    "torus": (("torus", compose(rotate("x", 30), scale(1.5)), (0.25,)),
              4 * math.pi ** 2 * 1.5 * 0.375),
    # a 1 x 2 x 3 box: non-uniform scale, so the size proxy is not the area
    "box": (("box", compose(rotate("z", 20), scale(0.5, 1.0, 1.5)), ()), 2 * (1 * 2 + 2 * 3 + 1 * 3)),
}


@pytest.mark.parametrize("case", sorted(AREA_CASES))
def test_area_estimate_converges_like_one_over_sqrt_s(case):
    obj, exact = AREA_CASES[case]
    g = _geometry([obj])
    R = 8
    ref = _reference_bins(case, g, R)
    assert ref.sum() == pytest.approx(exact, rel=1e-3)
    errs = []
    for s in (1_000, 10_000, 100_000):
        runs = [estimate_areas(g, [0], R, s, seed=seed, openness_samples=0) for seed in range(8)]
        for r in runs:
            assert abs(r.total / exact - 1.0) < 5 * r.total_rel_error + 1e-9
        # RMS over seeds of the bin areas' error, relative to the total
        errs.append(math.sqrt(np.mean([((r.area - ref) ** 2).sum() for r in runs])) / exact)
    # 100x the samples -> 10x smaller error (within the scatter of 8 seeds)
    assert 5.0 < errs[0] / errs[2] < 20.0, errs
    assert errs[2] < 0.01


def test_parts_of_very_different_size_share_samples_by_area():
    """A sphereflake-like group: one big sphere is a fifth of the area of 1000
    parts. Spreading samples evenly over parts would give it ~2 samples; the
    size proxy gives it its share, and with uniform scales the choice of part
    adds no variance: only the area element inside a sphere's chart varies."""
    rng = np.random.default_rng(3)
    sc = Scene()
    m = sc.add_material(Material())
    sc.prototypes.append(Prototype("ball", primitives=[Primitive("sphere", material=m)]))
    small = rng.uniform(0.05, 0.07, 1000)
    big = math.sqrt(0.25 * (small ** 2).sum())
    sc.instances = [Instance(0, scale(big))] + [
        Instance(0, compose(translate(*rng.uniform(-5, 5, 3)), scale(r))) for r in small]
    g, _ = compile_geometry(sc)
    est = estimate_areas(g, np.arange(1001), 8, 2000, seed=0, openness_samples=0)
    exact = 4 * math.pi * (big ** 2 + (small ** 2).sum())
    assert abs(est.total / exact - 1.0) < min(0.01, 5 * est.total_rel_error)
    ref = 4 * math.pi * (big ** 2 + (small ** 2).sum()) / (4 * math.pi) * \
        texel_areas.primitive_texel_areas(1, np.zeros(4), np.eye(3), 8).reshape(-1)
    # ~31 samples a bin: each bin within 5 of its reported standard errors
    z = (est.area - ref) / (est.rel_error * est.area)
    assert np.abs(z).max() < 5.0 and np.abs(est.area / ref - 1.0).mean() < 0.2


def test_sphere_bin_areas_are_the_solid_angle_shares():
    """A unit sphere's area per normal bin is the bin's solid angle, which the
    sphere's exact texel areas (quadrature) give independently."""
    g = _geometry([("sphere", np.eye(4)[:3], ())])
    est = estimate_areas(g, [0], 8, 1_000_000, seed=1, openness_samples=0)
    exact = texel_areas.primitive_texel_areas(1, np.zeros(4), np.eye(3), 8).reshape(-1)
    assert exact.sum() == pytest.approx(4 * math.pi, rel=1e-9)
    z = (est.area - exact) / (est.rel_error * est.area)
    assert np.abs(z).max() < 5.0
    np.testing.assert_allclose(est.area, exact, rtol=0.03)


def test_area_of_1e5_instanced_parts_with_20000_samples():
    """10^5 boxes of random non-uniform size and orientation: the size proxy
    (24 |det|^(2/3)) is not their area, so the estimate is genuinely random."""
    rng = np.random.default_rng(7)
    n = 100_000
    abc = rng.uniform(0.02, 0.08, (n, 3))
    pos = rng.uniform(-20, 20, (n, 3))
    ang = rng.uniform(0, 360, n)
    sc = Scene()
    m = sc.add_material(Material())
    sc.prototypes.append(Prototype("box", primitives=[Primitive("box", material=m)]))
    sc.instances = [Instance(0, compose(translate(*p), rotate("z", a), scale(*d)))
                    for p, a, d in zip(pos, ang, abc)]
    g, _ = compile_geometry(sc)
    est = estimate_areas(g, np.arange(n), 16, 20_000, seed=0, openness_samples=0)
    a, b, c = abc.T
    exact = float((8 * (a * b + b * c + c * a)).sum())
    assert est.parts == n and est.samples == 20_000
    assert abs(est.total / exact - 1.0) < 0.01
    assert abs(est.total / exact - 1.0) < 4 * est.total_rel_error


def test_csg_leaves_count_only_their_visible_surface():
    """A sphere with a box cut out of it: the estimate follows the solid's
    boundary, including the inward-facing faces of the cut."""
    from photon_lightmaps.engine.core.scene import CSGNode
    sc = Scene()
    m = sc.add_material(Material())
    # unit sphere minus the box [0,2]x[-2,2]x[-2,2]: a hemisphere plus its flat disk
    cut = Primitive("box", transform=compose(translate(1.0, 0, 0), scale(1.0, 2.0, 2.0)), material=m)
    sc.prototypes.append(Prototype("half", csg=[CSGNode("difference", Primitive("sphere", material=m), cut)]))
    sc.instances.append(Instance(0, scale(2.0)))
    g, _ = compile_geometry(sc)
    est = estimate_areas(g, [0], 8, 200_000, seed=0, openness_samples=0)
    exact = 4.0 * (2 * math.pi + math.pi)
    assert est.total == pytest.approx(exact, rel=0.02)
    # the flat cut faces +x (normal of the solid: out of the remaining half)
    s, t = orientation_lightmap.bin_coords(1.0, 0.0, 0.0)
    b = min(int(t * 8), 7) * 8 + min(int(s * 8), 7)
    assert est.area[b] == pytest.approx(4.0 * math.pi, rel=0.02)


# ------------------------------------------------------------------ hierarchy and backup

def _cluster():
    return [("sphere", compose(translate(x, y, 0), scale(0.3)), ())
            for x, y in itertools.product((-1.0, 0.0, 1.0), (-0.5, 0.5))]


def test_hierarchy_routes_hits_to_innermost_and_every_level_above():
    objs = _cluster()
    ols = [OrientationLightmap("all", [4, 5]),                 # 0: top level, own: 4, 5
           OrientationLightmap("left", [0, 1], parent=0),     # 1
           OrientationLightmap("mid", [2, 3], parent=0)]      # 2
    plain = compile_scene(_scene(objs))
    cs = compile_scene(_scene(objs, ols))
    trace_photons(plain, 100_000, seed=9)
    trace_photons(cs, 100_000, seed=9)
    lm, pl = cs.lightmaps, plain.lightmaps

    def own(ids):
        return sum(pl.flux[lightmap.texel_slice(pl, l)].sum(0) for i in ids for l in plain.instance_lightmaps[i])

    def ol_flux(k):
        return lm.flux[_ol_slice(cs, k)].sum(0)

    np.testing.assert_allclose(ol_flux(1), own([0, 1]), rtol=1e-10)
    np.testing.assert_allclose(ol_flux(2), own([2, 3]), rtol=1e-10)
    np.testing.assert_allclose(ol_flux(0), own(range(6)), rtol=1e-10)
    hits = [int(lm.hits[_ol_slice(cs, k)].sum()) for k in range(3)]
    own_hits = int(sum(pl.hits[lightmap.texel_slice(pl, l)].sum() for i in (4, 5)
                       for l in plain.instance_lightmaps[i]))
    assert hits[0] == hits[1] + hits[2] + own_hits
    # a parent's bin areas are its subtree's
    a = [lm.area[_ol_slice(cs, k)] for k in range(3)]
    assert a[0].sum() > a[1].sum() + a[2].sum()
    rows = orientation_lightmap.report(cs)
    assert [r["photons"] for r in rows] == hits


def test_lookup_moves_up_while_a_bin_is_too_noisy():
    objs = _cluster()
    ols = [OrientationLightmap("all", [4, 5]),
           OrientationLightmap("left", [0, 1], parent=0, min_hits=1)]
    cs = compile_scene(_scene(objs, ols))
    trace_photons(cs, 50_000, seed=1, record_direct=True)
    out = np.zeros(3)
    n = np.array([0.3, 0.4, 0.866])
    n /= np.linalg.norm(n)
    ol = cs.orientation
    orientation_lightmap.lookup(cs.lightmaps, ol, 1, n[0], n[1], n[2], lightmap.MODE_CONSTANT, out)
    child = cs.lightmaps.irradiance[orientation_lightmap.bin_index(cs.lightmaps, ol, 1, *n)]
    np.testing.assert_array_equal(out, child)
    # demand more photons than the child bin holds: the parent level answers
    strict = ol._replace(max_rel_error=np.array([1e-9, 1e-9]))
    orientation_lightmap.lookup(cs.lightmaps, strict, 1, n[0], n[1], n[2], lightmap.MODE_CONSTANT, out)
    parent = cs.lightmaps.irradiance[orientation_lightmap.bin_index(cs.lightmaps, ol, 0, *n)]
    np.testing.assert_array_equal(out, parent)
    assert child.min() > 0 and parent.min() > 0 and not np.array_equal(child, parent)


def test_backup_ol_keeps_lightmaps_and_records_both():
    objs = _cluster()
    cs = compile_scene(_scene(objs, [OrientationLightmap("backup", list(range(6)), backup=True)]))
    assert all(len(cs.instance_lightmaps[i]) == 1 for i in range(6))
    trace_photons(cs, 50_000, seed=4)
    lm = cs.lightmaps
    own = sum(lm.flux[lightmap.texel_slice(lm, cs.instance_lightmaps[i][0])].sum(0) for i in range(6))
    np.testing.assert_allclose(lm.flux[_ol_slice(cs, 0)].sum(0), own, rtol=1e-10)


def test_zero_area_bins_are_never_blended_in():
    """A box has six normal bins with area; a bilinear lookup at a face normal
    returns that bin's flux / area exactly, whatever its empty neighbours hold."""
    cs = compile_scene(_scene([("box", scale(0.5), ())],
                              [OrientationLightmap("box", [0], resolution=8)]))
    trace_photons(cs, 50_000, seed=2)
    lm = cs.lightmaps
    sl = _ol_slice(cs, 0)
    assert int((lm.area[sl] > 0).sum()) == 6
    out = np.zeros(3)
    for n in ((0, 0, 1), (1, 0, 0), (0, -1, 0)):
        i = orientation_lightmap.bin_index(lm, cs.orientation, 0, *map(float, n))
        orientation_lightmap.lookup(lm, cs.orientation, 0, *map(float, n), lightmap.MODE_BILINEAR, out)
        np.testing.assert_allclose(out, lm.flux[i] / lm.area[i], rtol=1e-12)


# ------------------------------------------------------------------ failure cases and bad input

def _menger(level):
    cells, size = [(0.0, 0.0, 0.0)], 1.0
    for _ in range(level):
        size /= 3.0
        cells = [(c[0] + i * size, c[1] + j * size, c[2] + k * size) for c in cells
                 for i, j, k in itertools.product((-1, 0, 1), repeat=3)
                 if (i == 0) + (j == 0) + (k == 0) < 2]
    return [("box", compose(translate(*c), scale(size)), ()) for c in cells]


@pytest.mark.parametrize("level", [0, 2])
def test_failure_cases_finish_and_say_averaging_is_strong(level):
    objs = _menger(level)
    assert len(objs) == 20 ** level
    sc = _scene(objs, [OrientationLightmap("sponge", list(range(len(objs))))], light=(3, 2, 4))
    sc.camera = Camera(transform=compose(translate(0, -5, 1), rotate("x", 80)), width=32, height=32)
    cs = compile_scene(sc)
    trace_photons(cs, 30_000, seed=1)
    img = render(cs, samples=1)
    assert np.isfinite(img).all() and img.max() > 0
    warn = " ".join(cs.info["orientation_lightmaps"][0]["warnings"])
    assert "only 6 normal directions" in warn
    assert ("cavities swallow light" in warn) == (level > 0)


def test_bad_orientation_lightmaps_are_rejected_by_name():
    objs = _cluster()
    with pytest.raises(SceneError, match="two orientation lightmaps"):
        compile_scene(_scene(objs, [OrientationLightmap("a", [0, 1]), OrientationLightmap("b", [1])]))
    with pytest.raises(SceneError, match="loops"):
        compile_scene(_scene(objs, [OrientationLightmap("a", [0], parent=1),
                                    OrientationLightmap("b", [1], parent=0)]))
    with pytest.raises(SceneError, match="resolution of its parent"):
        compile_scene(_scene(objs, [OrientationLightmap("a", [0]),
                                    OrientationLightmap("b", [1], parent=0, resolution=8)]))
    with pytest.raises(SceneError, match="no instance 99"):
        compile_scene(_scene(objs, [OrientationLightmap("a", [99])]))
    with pytest.raises(SceneError, match="resolution"):
        compile_scene(_scene(objs, [OrientationLightmap("a", [0], resolution=1)]))
