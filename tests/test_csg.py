"""Ray–CSG by interval classification (engine/geometry/csg.py) against brute-force membership."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine.geometry import csg

from photon_lightmaps.engine.geometry import csg_trace
from photon_lightmaps.engine.demo_scenes import uv_sphere_mesh
from photon_lightmaps.engine.core.scene import (
    CSGNode, Primitive, SceneError, TriangleMesh, compose, rotate, scale, translate)

KINDS = ["sphere", "box", "cylinder", "torus", "cone", "paraboloid"]


def _random_prim(rng, i):
    kind = KINDS[i % len(KINDS)] if i < len(KINDS) else rng.choice(KINDS)
    xf = compose(translate(*rng.uniform(-0.6, 0.6, 3)), rotate("x", rng.uniform(0, 180)),
                 rotate("z", rng.uniform(0, 180)), scale(*rng.uniform(0.4, 1.1, 3)))
    params = (rng.uniform(0.2, 0.5),) if kind == "torus" else ()
    return Primitive(kind, transform=xf, params=params, name=f"{kind}{i}")


def _random_tree(rng, depth, counter):
    if depth == 0:
        counter[0] += 1
        return _random_prim(rng, counter[0])
    op = ["union", "intersection", "difference"][rng.integers(3)]
    return CSGNode(op, _random_tree(rng, depth - 1 - (rng.random() < 0.3), counter),
                   _random_tree(rng, depth - 1, counter), name=f"n{depth}")


def _membership(ts, iv):
    """Interval membership of parameters ts (boundaries count as outside)."""
    inside = np.zeros(ts.shape, bool)
    for a, b in iv:
        inside |= (ts > a) & (ts < b)
    return inside


def _check_rays(table, root, rng, n_rays, n_march=1500, tol=1e-6):
    bad = 0
    checked = 0
    for _ in range(n_rays):
        o = rng.normal(size=3)
        o *= 4.0 / np.linalg.norm(o)
        target = rng.uniform(-0.8, 0.8, 3)
        d = target - o
        d *= rng.uniform(0.5, 2.0) / np.linalg.norm(d)      # not normalised on purpose
        res = csg_trace.csg_all_intervals(table, root, o, d)
        iv = res["intervals"]
        assert res["overflow"] == 0
        assert np.all(np.isfinite(iv))
        assert np.all(np.diff(iv.reshape(-1)) >= 0)
        t_far = 8.0 / np.linalg.norm(d)
        ts = np.linspace(0.0, t_far, n_march)
        pts = o + ts[:, None] * d
        brute = np.zeros(n_march, bool)
        csg_trace.csg_inside_batch(table.trace, root, pts, brute)
        got = _membership(ts, iv)
        near = np.zeros(n_march, bool)
        for t in iv.reshape(-1):
            near |= np.abs(ts - t) * np.linalg.norm(d) < tol * 10 + 1e-9
        bad += int(np.sum((brute != got) & ~near))
        checked += n_march
        # every reported boundary is a real change of membership
        for t in iv.reshape(-1):
            e = 1e-7 / np.linalg.norm(d)
            a = np.zeros(2, bool)
            csg_trace.csg_inside_batch(table.trace, root, np.array([o + (t - e) * d, o + (t + e) * d]), a)
            assert a[0] != a[1], f"boundary at t={t} is not a change of membership"
        # the first hit from t=0 is the first boundary, with a consistent normal
        hit, t, leaf, face, u, v, nx, ny, nz, entering = csg_trace.csg_first_hit(
            table.g, root, *o, *d, 0.0, math.inf)
        b = iv.reshape(-1)
        if b.size:
            assert hit and t == pytest.approx(b[0], abs=1e-12)
            assert entering
            assert nx * d[0] + ny * d[1] + nz * d[2] < 0.0
            assert 0.0 <= u <= 1.0 and 0.0 <= v <= 1.0
            assert leaf == res["leaves"].reshape(-1)[0]
            # from inside the first interval the hit is its exit
            tm = 0.5 * (b[0] + b[1])
            hit2, t2, *_, n2x, n2y, n2z, ent2 = csg_trace.csg_first_hit(table.g, root, *o, *d, tm,
                                                                 math.inf)
            assert hit2 and t2 == pytest.approx(b[1], abs=1e-12) and not ent2
            assert n2x * d[0] + n2y * d[1] + n2z * d[2] > 0.0
        else:
            assert not hit
    return bad, checked


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_trees_match_brute_force(seed):
    rng = np.random.default_rng(seed)
    tree = _random_tree(rng, 3, [0])
    table = csg.csg_table([tree])
    assert table.flat.info["csg_max_depth"] >= 3
    bad, checked = _check_rays(table, int(table.roots[0]), rng, 40)
    assert bad == 0, f"{bad} of {checked} march samples disagree"


def test_nested_known_tree():
    # ((sphere ∪ box) ∩ cylinder) \ torus, with transforms on the leaves
    s = Primitive("sphere", transform=scale(1.0), name="s")
    b = Primitive("box", transform=compose(translate(0.6, 0, 0), rotate("z", 30), scale(0.5)),
                  name="b")
    c = Primitive("cylinder", transform=compose(rotate("x", 90), scale(0.8, 0.8, 2.0)), name="c")
    t = Primitive("torus", transform=scale(0.9), params=(0.25,), name="t")
    tree = CSGNode("difference", CSGNode("intersection", CSGNode("union", s, b), c), t)
    table = csg.csg_table([tree])
    bad, checked = _check_rays(table, int(table.roots[0]), np.random.default_rng(7), 60)
    assert bad == 0


def test_mesh_operand():
    mesh = uv_sphere_mesh(0.9, 16, 32)
    mesh.name = "ball"
    tree = CSGNode("difference", Primitive("box", transform=scale(0.8), name="cube"), mesh)
    table = csg.csg_table([tree])
    bad, checked = _check_rays(table, int(table.roots[0]), np.random.default_rng(3), 30)
    assert bad == 0
    # an inward-oriented copy gives the same solid
    inward = uv_sphere_mesh(0.9, 16, 32, inward=True)
    t2 = csg.csg_table([CSGNode("difference", Primitive("box", transform=scale(0.8)), inward)])
    o, d = (-3.0, 0.05, 0.1), (1.0, 0.0, 0.0)
    a = csg_trace.csg_all_intervals(table, int(table.roots[0]), o, d)["intervals"]
    b = csg_trace.csg_all_intervals(t2, int(t2.roots[0]), o, d)["intervals"]
    np.testing.assert_allclose(a, b)


def test_coplanar_faces_are_resolved_and_counted():
    # box minus a box that shares its +z face (thesis 4.1.2)
    a = Primitive("box", name="a")
    b = Primitive("box", transform=compose(translate(0, 0, 0.5), scale(0.5, 0.5, 0.5)), name="b")
    table = csg.csg_table([CSGNode("difference", a, b)])
    r = int(table.roots[0])
    res = csg_trace.csg_all_intervals(table, r, (0.1, 0.2, 5.0), (0.0, 0.0, -1.0))
    assert res["ties"] > 0
    assert np.all(np.isfinite(res["intervals"]))
    # the shared face belongs to the cut: the ray enters at the pocket's floor z = 0
    np.testing.assert_allclose(res["intervals"], [[5.0, 6.0]])
    hit, t, leaf, face, u, v, nx, ny, nz, ent = csg_trace.csg_first_hit(table.g, r, 0.1, 0.2, 5.0,
                                                               0.0, 0.0, -1.0, 0.0, math.inf)
    assert hit and t == pytest.approx(5.0) and leaf == 1 and nz == pytest.approx(1.0)
    # union of two boxes touching face to face: one merged interval
    u2 = csg.csg_table([CSGNode("union", Primitive("box", transform=translate(-1, 0, 0)),
                              Primitive("box", transform=translate(1, 0, 0)))])
    res = csg_trace.csg_all_intervals(u2, int(u2.roots[0]), (-5.0, 0.1, 0.2), (1.0, 0.0, 0.0))
    np.testing.assert_allclose(res["intervals"], [[3.0, 7.0]])
    assert res["ties"] > 0
    # grazing along a shared face: finite, no crash
    res = csg_trace.csg_all_intervals(table, r, (-5.0, 0.1, 1.0), (1.0, 0.0, 0.0))
    assert np.all(np.isfinite(res["intervals"]))


def test_open_mesh_operand_is_rejected_by_name():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    open_mesh = TriangleMesh(v, np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2]]), name="leaky_tet")
    with pytest.raises(SceneError, match="leaky_tet"):
        csg.csg_table([CSGNode("union", Primitive("sphere"), open_mesh, name="u")])
    with pytest.raises(SceneError, match="open surface"):
        csg.csg_table([CSGNode("union", Primitive("sphere"), Primitive("quad", name="q"))])


def test_missing_operand_and_empty():
    with pytest.raises(SceneError, match="missing right operand"):
        csg.csg_table([CSGNode("difference", Primitive("sphere"), None, name="half")])
    with pytest.raises(SceneError, match="unknown CSG operation"):
        csg.csg_table([CSGNode("xor", Primitive("sphere"), Primitive("box"))])
    t = csg.csg_table([])
    assert t.flat.node_op.size == 0
    # an empty intersection: no hit, no NaN
    e = csg.csg_table([CSGNode("intersection", Primitive("sphere", transform=translate(-3, 0, 0)),
                             Primitive("sphere", transform=translate(3, 0, 0)))])
    hit, t_, *rest = csg_trace.csg_first_hit(e.g, int(e.roots[0]), -10.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0,
                                     math.inf)
    assert not hit and t_ == math.inf


def test_overflow_is_reported_not_corrupting():
    # a union of many separated spheres along a line: more intervals than a list holds
    tree = Primitive("sphere", transform=compose(translate(0, 0, 0), scale(0.3)))
    for i in range(1, csg.MAX_INTERVALS + 8):
        tree = CSGNode("union", tree, Primitive("sphere", transform=compose(
            translate(i, 0, 0), scale(0.3))))
    table = csg.csg_table([tree])
    res = csg_trace.csg_all_intervals(table, int(table.roots[0]), (-2.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    assert res["overflow"] > 0
    assert res["intervals"].shape[0] == csg.MAX_INTERVALS
    np.testing.assert_allclose(res["intervals"][:3, 0], [1.7, 2.7, 3.7])
