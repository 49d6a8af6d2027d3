"""Cyclic scene graphs (engine/dcsg.py) against the flattened instantiation.

The reference for every grammar is the derived string (engine/lsystem.py)
interpreted by the turtle (engine/turtle.py): the graph must stand for exactly
those primitives, with the same addresses, and rays through the graph must hit
what rays through those primitives hit.
"""
import numpy as np
import pytest

from photon_lightmaps.engine import dcsg as D
from photon_lightmaps.engine import lsystem as LS
from photon_lightmaps.engine import turtle as T
from photon_lightmaps.engine.primitives import KIND_IDS, hits_batch
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
    der = LS.derive(grammar)
    geom = T.interpret(der.modules, grammar.angle, grammar.width)
    prims = T.to_primitives(geom)
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
    flat = D.DCSG(g).flatten()
    kinds, xf, addresses = _reference(g)
    order = np.argsort(flat.kind == KIND_IDS["sphere"], kind="stable")   # string order otherwise
    flat = D.Flattened(*(a[order] for a in flat))
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


@pytest.mark.parametrize("cache_mb", [D.CACHE_MB, 0.0], ids=["cached", "lazy"])
@pytest.mark.parametrize("text", [ABOP_124A.format(n=4), TAPERED, STOCHASTIC.format(seed=3)])
def test_rays_agree_with_the_flattened_primitives(text, cache_mb):
    graph = D.DCSG(LS.parse(text), cache_mb=cache_mb)
    o, d = _rays(graph, 1500)
    t, row, address, _stub, normal = D.trace_closest(graph, o, d)
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
        own = _brute_force(D.Flattened(*(a[[index[int(address[r])]]] for a in flat)),
                           o[r:r + 1], d[r:r + 1])[0][0]
        assert own == pytest.approx(tb[r], rel=1e-9)
    assert np.mean(address[hit] == hb[hit]) > 0.8
    np.testing.assert_allclose(np.linalg.norm(normal[hit], axis=1), 1.0, rtol=1e-12)


@pytest.mark.parametrize("text", [ABOP_124A.format(n=5), TAPERED, STOCHASTIC.format(seed=3)])
def test_expansion_cache_changes_no_hit(text):
    """Rays through cached expansions (4.4) hit what the lazily expanded graph hits:
    the same t, stub and normal, and the same primitive up to ties (a cap where
    tapered segments join is hit by both at the same t; the walk order decides)."""
    cached, lazy = D.DCSG(LS.parse(text)), D.DCSG(LS.parse(text), cache_mb=0)
    st = cached.stats()
    if cached.grammar.is_stochastic:
        # every choice depends on the path hash: no expansion is shared, none is cached
        assert st["cache_subgraphs"] == 0
    else:
        assert st["cache_subgraphs"] > 0 and 0.0 < st["cache_hit_rate"] <= 1.0
        assert 0 < st["cache_bytes"] <= st["cache_limit_bytes"]
    assert lazy.stats()["cache_subgraphs"] == 0 and lazy.stats()["cache_hit_rate"] == 0.0
    o, d = _rays(cached, 2000, seed=5)
    a, b = D.trace_closest(cached, o, d), D.trace_closest(lazy, o, d)
    hit = b[1] >= 0
    assert hit.sum() > 300
    np.testing.assert_array_equal(a[1] >= 0, hit)
    np.testing.assert_array_equal(a[3], b[3])
    np.testing.assert_allclose(a[0][hit], b[0][hit], rtol=1e-12)
    flat = cached.flatten()
    index = {h: i for i, h in enumerate(flat.address.tolist())}
    tie = np.nonzero(hit & (a[2] != b[2]))[0]
    for r in tie:
        own = _brute_force(D.Flattened(*(x[[index[int(a[2][r])]]] for x in flat)),
                           o[r:r + 1], d[r:r + 1])[0][0]
        assert own == pytest.approx(b[0][r], rel=1e-9)
    assert tie.size < 0.1 * hit.sum()
    same = hit & (a[2] == b[2])
    np.testing.assert_allclose(a[4][same], b[4][same], atol=1e-12)


def test_expansion_cache_keeps_to_its_size():
    g = LS.parse(ABOP_124A.format(n=6))            # 5^6 primitives; subtrees of 125 and 25
    sizes = [D.DCSG(g, cache_mb=mb).stats() for mb in (0, 0.001, 0.01, 64)]
    for st in sizes:
        assert st["cache_bytes"] <= st["cache_limit_bytes"]
    # a subtree too big for the cache gives way to its children: 1 kB holds one of
    # 5 primitives, 10 kB two of 25, 64 MB the whole graph
    assert [st["cache_primitives"] for st in sizes] == [0, 5, 50, 5 ** 6]
    assert [st["cache_subgraphs"] for st in sizes] == [0, 1, 2, 1]


def test_node_count_follows_the_steps_not_the_primitives():
    # 5^30 primitives: counted through the graph, never unrolled
    graph = D.DCSG(LS.parse(ABOP_124A.format(n=30)))
    assert graph.implicit_primitives == 5 ** 30
    assert graph.stats()["dcsg_nodes"] <= 2 * 30 + 10
    # rays still find the object (aimed as at the depth the flattening allows)
    o, d = _rays(D.DCSG(LS.parse(ABOP_124A.format(n=5))), 200)
    t, row = D.trace_closest(graph, o, d)[:2]
    assert (row >= 0).sum() > 20 and np.all(np.isfinite(t[row >= 0]))


def test_stochastic_count_is_the_expectation():
    g = LS.parse(STOCHASTIC.format(seed=0))
    graph = D.DCSG(g)
    # each rewrite draws 3, 3 or 4 F with probabilities .33, .33, .34
    assert graph.implicit_primitives == pytest.approx((0.33 * 3 + 0.33 * 3 + 0.34 * 4) ** 4)
    # one seed's instantiation has its own count, the derived string's
    assert len(graph.flatten().kind) == \
        sum(m.symbol == "F" for m in LS.derive(g).modules)


def test_ol_stubs_get_exactly_their_subtrees_hits():
    text = """axiom: A
derivation length: 4
angle: 40
ol stub: A levels 2
production:
A --> F [ + A ] [ - A ] A
"""
    g = LS.parse(text)
    graph = D.DCSG(g)
    flat = graph.flatten()
    # 3^2 modules A at level 2 -> 9 stubs, each owning the primitives below it
    der2 = LS.derive(g, steps=2)
    level2 = {h for m, h in zip(der2.modules, der2.hashes) if m.symbol == "A"}
    assert set(np.unique(flat.stub[flat.stub != 0]).tolist()) == level2
    assert np.sum(flat.stub == 0) == 1 + 3                         # the F drawn by the A of levels 0, 1
    o, d = _rays(graph, 1500, seed=5)
    _t, row, address, stub = D.trace_closest(graph, o, d)[:4]
    table = D.stub_addresses(graph).tolist()
    assert table == sorted(level2)
    owner = dict(zip(flat.address.tolist(), flat.stub.tolist()))
    hit = row >= 0
    assert hit.sum() > 200
    # each hit reports its own primitive's stub (index into the sorted table, -1: none)
    assert all(owner[a] == (table[s] if s >= 0 else 0)
               for a, s in zip(address[hit].tolist(), stub[hit].tolist()))


def test_grammars_that_cannot_be_a_graph_are_refused():
    with pytest.raises(D.DCSGUnsupported, match="context-sensitive"):
        D.DCSG(LS.parse("axiom: F\nderivation length: 2\nproduction:\nF < F --> FF\n"))
    # the choice decides where the next sibling starts
    with pytest.raises(D.DCSGUnsupported, match="different places"):
        D.DCSG(LS.parse("axiom: A F\nderivation length: 2\nproduction:\n"
                        "A --> F : 0.5\nA --> F F : 0.5\n"))


def test_area_estimate_is_unbiased_under_an_instance_transform():
    g = LS.parse(TAPERED.replace("derivation length: 5", "derivation length: 3"))
    graph = D.DCSG(g)
    views = D.dcsg_table([graph])[0]
    c, s = np.cos(0.7), np.sin(0.7)
    xf = np.eye(4)
    xf[:3, :3] = 2.0 * np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    xf[:3, 3] = (1, 2, 3)
    inv = np.linalg.inv(xf)[:3]
    area, var = D.estimate_graph_areas(views, graph, D.node_areas(graph), graph.arrays().root,
                                       graph.root_hash, np.eye(3), inv, 8, 40000, seed=3)
    exact = 4.0 * quadrature_area(graph.flatten())           # scale 2: area x 4
    assert abs(area.sum() - exact) < 4 * np.sqrt(var.sum())
    assert np.sqrt(var.sum()) < 0.02 * exact
