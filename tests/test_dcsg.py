"""Cyclic scene graphs (engine/geometry/dcsg.py) against the flattened instantiation.

The reference for every grammar is the derived string (engine/lsystem/grammar.py)
interpreted by the turtle (engine/lsystem/turtle.py): the graph must stand for exactly
those primitives, with the same addresses, and rays through the graph must hit
what rays through those primitives hit.
"""
from types import SimpleNamespace

import numpy as np
import pytest

from photon_lightmaps.engine.geometry import dcsg
from photon_lightmaps.engine.geometry import dcsg_areas
from photon_lightmaps.engine.geometry import dcsg_blob
from photon_lightmaps.engine.geometry import dcsg_trace
from photon_lightmaps.engine.lsystem import grammar as LS
from photon_lightmaps.engine.lsystem import derivation
from photon_lightmaps.engine.lsystem import turtle
from photon_lightmaps.engine.geometry.primitives import KIND_IDS, hits_batch
from lsystem_grammars import ABOP_124A, TAPERED, quadrature_area

# stochastic, with alternatives that leave the turtle in the same place
STOCHASTIC = """axiom: F
derivation length: 4
angle: 22.5
seed: {seed}
production:
F --> F[+F]F : 0.33
F --> F[-F]F : 0.33
F --> F[&F][^F]F : 0.34
"""


def _reference(grammar):
    """(kinds, transforms, addresses) of derive -> turtle -> primitives."""
    der = derivation.derive(grammar)
    geom = turtle.interpret(der.modules, grammar.angle, grammar.width)
    prims = turtle.to_primitives(geom)
    assert prims.skipped == 0
    kinds = np.array([KIND_IDS[p.kind] for p in prims])
    xf = np.array([np.asarray(p.transform, float)[:3] for p in prims]).reshape(-1, 3, 4)
    # a drawn module's address is its hash in the derivation; to_primitives lists
    # the segments in string order, then the spheres
    drawn = ([i for i, m in enumerate(der.modules) if m.symbol == "F"]
             + [i for i, m in enumerate(der.modules) if m.symbol == "@O"])
    return kinds, xf, der.hashes[drawn]


def _brute_force(flat, origins, dirs):
    """Closest hit t and address over every flattened primitive."""
    n = origins.shape[0]
    tb = np.full(n, np.inf)
    hb = np.zeros(n, np.uint64)
    for i in range(flat.kind.shape[0]):
        full = np.eye(4)
        full[:3] = flat.transform[i]
        inv = np.linalg.inv(full)
        cnt, ts = hits_batch(int(flat.kind[i]), flat.params[i], origins @ inv[:3, :3].T + inv[:3, 3],
                             dirs @ inv[:3, :3].T)[:2]
        ts = np.where((np.arange(ts.shape[1]) < cnt[:, None]) & (ts > 0.0), ts, np.inf).min(axis=1)
        better = ts < tb
        tb[better] = ts[better]
        hb[better] = flat.address[i]
    return tb, hb


def _rays(graph, n, seed=1):
    """Rays from around the object toward points near its primitives (thin
    branches: aiming at the box would miss nearly always), about half hitting."""
    rng = np.random.default_rng(seed)
    lo, hi = graph.bounds()
    c, ext = 0.5 * (lo + hi), float((hi - lo).max())
    flat = graph.flatten(limit=100_000)
    k = rng.integers(0, flat.kind.shape[0], n)
    radius = np.linalg.norm(flat.transform[k, :, 0], axis=1)
    target = flat.transform[k, :, 3] + rng.normal(size=(n, 3)) * 1.5 * radius[:, None]
    o = c + rng.normal(size=(n, 3)) * ext
    return o, target - o


@pytest.mark.parametrize("text", [ABOP_124A.format(n=4), TAPERED] +
                         [STOCHASTIC.format(seed=s) for s in (0, 7, 12345)])
def test_graph_stands_for_the_derived_string(text):
    g = LS.parse(text)
    flat = dcsg.DCSG(g).flatten()
    kinds, xf, addresses = _reference(g)
    order = np.argsort(flat.kind == KIND_IDS["sphere"], kind="stable")   # string order otherwise
    flat = dcsg.Flattened(*(a[order] for a in flat))
    np.testing.assert_array_equal(flat.kind, kinds)
    tol = 1e-11 * (1 + np.abs(xf).max())
    seg = kinds != KIND_IDS["sphere"]
    np.testing.assert_allclose(flat.transform[seg], xf[seg], rtol=0, atol=tol)
    # a sphere's frame is the turtle's in the graph, the axes in the string: same solid
    np.testing.assert_allclose(flat.transform[~seg, :, 3], xf[~seg, :, 3], rtol=0, atol=tol)
    np.testing.assert_allclose(np.linalg.norm(flat.transform[~seg, :, :3], axis=1),
                               np.linalg.norm(xf[~seg, :, :3], axis=1), rtol=1e-12)
    np.testing.assert_array_equal(flat.address, addresses)
    assert np.unique(flat.address).size == flat.address.size       # addresses are unique


@pytest.mark.parametrize("cache_mb", [dcsg.CACHE_MB, 0.0], ids=["cached", "lazy"])
@pytest.mark.parametrize("text", [ABOP_124A.format(n=4), TAPERED, STOCHASTIC.format(seed=3)])
def test_rays_agree_with_the_flattened_primitives(text, cache_mb):
    graph = dcsg.DCSG(LS.parse(text), cache_mb=cache_mb)
    o, d = _rays(graph, 1500)
    t, row, address, _stub, normal = dcsg_trace.trace_closest(graph, o, d)
    tb, hb = _brute_force(graph.flatten(), o, d)
    hit = np.isfinite(tb)
    assert 300 < hit.sum() < 1500                                  # the test sees hits and misses
    np.testing.assert_array_equal(row >= 0, hit)
    np.testing.assert_allclose(t[hit], tb[hit], rtol=1e-9)
    # the same primitive, or one that touches it at the same t (the caps where
    # segments join, a sphere at a tip): such ties may go either way
    flat = graph.flatten()
    index = {a: i for i, a in enumerate(flat.address.tolist())}
    for r in np.nonzero(hit & (address != hb))[0]:
        own = _brute_force(dcsg.Flattened(*(a[[index[int(address[r])]]] for a in flat)),
                           o[r:r + 1], d[r:r + 1])[0][0]
        assert own == pytest.approx(tb[r], rel=1e-9)
    assert np.mean(address[hit] == hb[hit]) > 0.8
    np.testing.assert_allclose(np.linalg.norm(normal[hit], axis=1), 1.0, rtol=1e-12)


@pytest.mark.parametrize("text", [ABOP_124A.format(n=5), TAPERED, STOCHASTIC.format(seed=3)])
def test_expansion_cache_changes_no_hit(text):
    """Rays through cached expansions (4.4) hit what the lazily expanded graph hits:
    the same t, stub and normal, and the same primitive up to ties (a cap where
    tapered segments join is hit by both at the same t; the walk order decides)."""
    cached, lazy = dcsg.DCSG(LS.parse(text)), dcsg.DCSG(LS.parse(text), cache_mb=0)
    st = cached.stats()
    if cached.grammar.is_stochastic:
        # every choice depends on the path hash: no expansion is shared, none is cached
        assert st["cache_subgraphs"] == 0
    else:
        assert st["cache_subgraphs"] > 0 and 0.0 < st["cache_hit_rate"] <= 1.0
        assert 0 < st["cache_bytes"] <= st["cache_limit_bytes"]
    assert lazy.stats()["cache_subgraphs"] == 0 and lazy.stats()["cache_hit_rate"] == 0.0
    o, d = _rays(cached, 2000, seed=5)
    a, b = dcsg_trace.trace_closest(cached, o, d), dcsg_trace.trace_closest(lazy, o, d)
    hit = b[1] >= 0
    assert hit.sum() > 300
    np.testing.assert_array_equal(a[1] >= 0, hit)
    np.testing.assert_array_equal(a[3], b[3])
    np.testing.assert_allclose(a[0][hit], b[0][hit], rtol=1e-12)
    flat = cached.flatten()
    index = {h: i for i, h in enumerate(flat.address.tolist())}
    tie = np.nonzero(hit & (a[2] != b[2]))[0]
    for r in tie:
        own = _brute_force(dcsg.Flattened(*(x[[index[int(a[2][r])]]] for x in flat)),
                           o[r:r + 1], d[r:r + 1])[0][0]
        assert own == pytest.approx(b[0][r], rel=1e-9)
    assert tie.size < 0.1 * hit.sum()
    same = hit & (a[2] == b[2])
    np.testing.assert_allclose(a[4][same], b[4][same], atol=1e-12)


def test_expansion_cache_keeps_to_its_size():
    g = LS.parse(ABOP_124A.format(n=6))            # 5^6 primitives; subtrees of 125 and 25
    sizes = [dcsg.DCSG(g, cache_mb=mb).stats() for mb in (0, 0.001, 0.01, 64)]
    for st in sizes:
        assert st["cache_bytes"] <= st["cache_limit_bytes"]
    # a subtree too big for the cache gives way to its children: 1 kB holds one of
    # 5 primitives, 10 kB two of 25, 64 MB the whole graph
    assert [st["cache_primitives"] for st in sizes] == [0, 5, 50, 5 ** 6]
    assert [st["cache_subgraphs"] for st in sizes] == [0, 1, 2, 1]


def test_node_count_follows_the_steps_not_the_primitives():
    # 5^30 primitives: counted through the graph, never unrolled
    graph = dcsg.DCSG(LS.parse(ABOP_124A.format(n=30)))
    assert graph.implicit_primitives == 5 ** 30
    assert graph.stats()["dcsg_nodes"] <= 2 * 30 + 10
    # rays still find the object (aimed as at the depth the flattening allows)
    o, d = _rays(dcsg.DCSG(LS.parse(ABOP_124A.format(n=5))), 200)
    t, row = dcsg_trace.trace_closest(graph, o, d)[:2]
    assert (row >= 0).sum() > 20 and np.all(np.isfinite(t[row >= 0]))


def test_stochastic_count_is_the_expectation():
    g = LS.parse(STOCHASTIC.format(seed=0))
    graph = dcsg.DCSG(g)
    # each rewrite draws 3, 3 or 4 F with probabilities .33, .33, .34
    assert graph.implicit_primitives == pytest.approx((0.33 * 3 + 0.33 * 3 + 0.34 * 4) ** 4)
    # one seed's instantiation has its own count, the derived string's
    assert len(graph.flatten().kind) == \
        sum(m.symbol == "F" for m in derivation.derive(g).modules)


@pytest.mark.parametrize("cache_mb", [dcsg.CACHE_MB, 0.0], ids=["cached", "lazy"])
def test_ol_stubs_get_exactly_their_subtrees_hits(cache_mb):
    text = """axiom: A
derivation length: 4
angle: 40
ol stub: A levels 2
production:
A --> F [ + A ] [ - A ] A
"""
    g = LS.parse(text)
    graph = dcsg.DCSG(g, cache_mb=cache_mb)
    # cached: the whole graph is one expansion, its stubs found along each chain
    assert graph.stats()["cache_subgraphs"] == (1 if cache_mb else 0)
    flat = graph.flatten()
    # 3^2 modules A at level 2 -> 9 stubs, each owning the primitives below it
    der2 = derivation.derive(g, steps=2)
    level2 = {h for m, h in zip(der2.modules, der2.hashes) if m.symbol == "A"}
    assert set(np.unique(flat.stub[flat.stub != 0]).tolist()) == level2
    assert np.sum(flat.stub == 0) == 1 + 3                         # the F drawn by the A of levels 0, 1
    o, d = _rays(graph, 1500, seed=5)
    _t, row, address, stub = dcsg_trace.trace_closest(graph, o, d)[:4]
    table = dcsg_blob.stub_addresses(graph).tolist()
    assert table == sorted(level2)
    owner = dict(zip(flat.address.tolist(), flat.stub.tolist()))
    hit = row >= 0
    assert hit.sum() > 200
    # each hit reports its own primitive's stub (index into the sorted table, -1: none)
    assert all(owner[a] == (table[s] if s >= 0 else 0)
               for a, s in zip(address[hit].tolist(), stub[hit].tolist()))


def test_grammars_that_cannot_be_a_graph_are_refused():
    with pytest.raises(dcsg.DCSGUnsupported, match="context-sensitive"):
        dcsg.DCSG(LS.parse("axiom: F\nderivation length: 2\nproduction:\nF < F --> FF\n"))
    # the choice decides where the next sibling starts
    with pytest.raises(dcsg.DCSGUnsupported, match="different places"):
        dcsg.DCSG(LS.parse("axiom: A F\nderivation length: 2\nproduction:\n"
                        "A --> F : 0.5\nA --> F F : 0.5\n"))


def test_area_estimate_is_unbiased_under_an_instance_transform():
    g = LS.parse(TAPERED.replace("derivation length: 5", "derivation length: 3"))
    graph = dcsg.DCSG(g)
    views = dcsg_trace.dcsg_table([graph])[0]
    c, s = np.cos(0.7), np.sin(0.7)
    xf = np.eye(4)
    xf[:3, :3] = 2.0 * np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    xf[:3, 3] = (1, 2, 3)
    inv = np.linalg.inv(xf)[:3]
    area, var = dcsg_areas.estimate_graph_areas(views, graph, dcsg_areas.node_areas(graph), graph.arrays().root,
                                       graph.root_hash, np.eye(3), inv, 8, 40000, seed=3)
    exact = 4.0 * quadrature_area(graph.flatten())           # scale 2: area x 4
    assert abs(area.sum() - exact) < 4 * np.sqrt(var.sum())
    assert np.sqrt(var.sum()) < 0.02 * exact


# a kite-shaped leaf in the organ's frame (x -> L, z -> H: it grows along the heading)
LEAF = SimpleNamespace(vertices=np.array([[0.0, 0, 0], [0.5, 0, 0.5], [0, 0, 1.0], [-0.5, 0, 0.5]]),
                       triangles=np.array([[0, 1, 2], [0, 2, 3]]), material=0)
LEAVES = """axiom: A
derivation length: 4
angle: 30
production:
A --> F [ +(40) A ] [ -(25) /(90) A ] ~(leaf, 0.5)
"""


def _organ_triangles(graph):
    """World triangles (n, 3, 3) of every organ the flattened graph places, and their addresses."""
    flat = graph.flatten()
    out, addr = [], []
    for kind, params, xf, a in zip(flat.kind, flat.params, flat.transform, flat.address):
        if kind == dcsg.ORGAN:
            q = graph.organs.tri[int(params[0])].reshape(-1, 3, 3)
            out.append(q @ xf[:, :3].T + xf[:, 3])
            addr += [a] * q.shape[0]
    return np.concatenate(out), np.array(addr, np.uint64)


def _brute_triangles(tris, o, d):
    """Closest t over triangles (Moller-Trumbore in numpy), inf on a miss."""
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    best = np.full(o.shape[0], np.inf)
    for i in range(tris.shape[0]):
        p = np.cross(d, e2[i])
        det = p @ e1[i]
        s = o - tris[i, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.einsum("ij,ij->i", s, p) / det
            q = np.cross(s, e1[i])
            v = np.einsum("ij,ij->i", d, q) / det
            t = (q @ e2[i]) / det
        ok = (det != 0) & (u >= 0) & (u <= 1) & (v >= 0) & (u + v <= 1) & (t > 0)
        best = np.where(ok & (t < best), t, best)
    return best


@pytest.mark.parametrize("cache_mb", [dcsg.CACHE_MB, 0.0], ids=["cached", "lazy"])
def test_organs_are_hit_where_their_meshes_are(cache_mb):
    """`~(leaf, s)` with a mesh: rays hit the leaves the flattened graph places (world
    triangles from the organ's mesh in the turtle frame) at the same t, and the
    segments as before; every organ hit reports an organ row."""
    graph = dcsg.DCSG(LS.parse(LEAVES), organs={"leaf": LEAF}, cache_mb=cache_mb)
    assert graph.implicit_primitives == 2 * 15                  # 15 F and 15 leaves
    tris, _ = _organ_triangles(graph)
    rng = np.random.default_rng(4)
    lo, hi = graph.bounds()
    target = tris[rng.integers(0, tris.shape[0], 1500)].mean(axis=1) + rng.normal(size=(1500, 3)) * 0.05
    o = 0.5 * (lo + hi) + rng.normal(size=(1500, 3)) * 4.0
    d = target - o
    t, row, _, _, normal = dcsg_trace.trace_closest(graph, o, d)
    flat = graph.flatten()
    seg = dcsg.Flattened(*(a[flat.kind != dcsg.ORGAN] for a in flat))
    t_ref = np.minimum(_brute_triangles(tris, o, d), _brute_force(seg, o, d)[0])
    hit = np.isfinite(t_ref)
    assert 300 < hit.sum() < 1500
    np.testing.assert_array_equal(row >= 0, hit)
    np.testing.assert_allclose(t[hit], t_ref[hit], rtol=1e-9)
    organ_rows = np.flatnonzero(graph.arrays().prim_kind == dcsg.ORGAN)
    on_leaf = np.isin(row, organ_rows)
    assert on_leaf.sum() > 200
    np.testing.assert_allclose(np.linalg.norm(normal[hit], axis=1), 1.0, rtol=1e-12)


def test_organ_area_is_estimated_through_the_graph():
    graph = dcsg.DCSG(LS.parse(LEAVES), organs={"leaf": LEAF})
    views = dcsg_trace.dcsg_table([graph])[0]
    area, var = dcsg_areas.estimate_graph_areas(views, graph, dcsg_areas.node_areas(graph), graph.arrays().root,
                                       graph.root_hash, np.eye(3), np.eye(4)[:3], 8, 40000, seed=5)
    tris, _ = _organ_triangles(graph)
    leaves = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1).sum()
    flat = graph.flatten()
    exact = leaves + quadrature_area(dcsg.Flattened(*(a[flat.kind != dcsg.ORGAN] for a in flat)))
    assert leaves == pytest.approx(15 * 0.5 * 0.25)           # kite area 0.5, scaled by 0.5^2
    assert abs(area.sum() - exact) < 4 * np.sqrt(var.sum())
    assert np.sqrt(var.sum()) < 0.02 * exact


def test_unchecked_scratch_views_read_and_write_what_numpy_views_do():
    from numba import njit
    from photon_lightmaps.engine.core.jit import as_float32, as_float64, as_uint64

    @njit
    def poke(stack):
        f, u, s = as_float64(stack), as_uint64(stack), as_float32(stack)
        f[3] = 2.5
        u[5] = np.uint64(7)
        s[1] = np.float32(-1.5)
        return f.shape[0], u.shape[0], s.shape[0], f[3] + s[1]

    st = np.zeros(64, np.int32)
    assert poke(st) == (32, 32, 64, 1.0)
    assert st.view(np.float64)[3] == 2.5 and st.view(np.uint64)[5] == 7
    assert st.view(np.float32)[1] == -1.5
