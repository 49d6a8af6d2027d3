"""Grammar presets (engine/lsystem/presets) and the turtle's box module in the scene graph.

Each preset must parse and render through the cyclic scene graph
(engine/geometry/dcsg.py), standing for exactly what its derived string draws; the
fractals are checked against their definitions (counts, an IFS iterated in
numpy, touching spheres, the sponge's grid), the sympodial tree against the
size and OL stubs a benchmark relies on.
"""
import fnmatch
import itertools
import math
import os
import tomllib

import numpy as np
import pytest

from photon_lightmaps.engine.geometry import dcsg
from photon_lightmaps.engine.geometry import dcsg_trace
from photon_lightmaps.engine.lsystem import grammar as lsystem_grammar
from photon_lightmaps.engine.lsystem import derivation
from photon_lightmaps.engine.lsystem import presets
from photon_lightmaps.engine.lsystem import turtle
from photon_lightmaps.engine.geometry.primitives import KIND_IDS

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PRESET_DIR = os.path.join(ROOT, "engine", "lsystem", "presets")
DRAWN = ("F", "@O", "@B")
SPHERE, BOX = KIND_IDS["sphere"], KIND_IDS["box"]


def drawn_count(grammar, steps=None):
    c = derivation.count(grammar, steps)
    assert c.exact
    return sum(c.per_symbol.get(s, 0) for s in DRAWN)


def derived_primitives(grammar, steps=None):
    """(derivation, primitives, addresses) of derive -> turtle -> to_primitives; the
    primitives come as segments, spheres, boxes, each in string order."""
    der = derivation.derive(grammar, steps)
    prims = turtle.to_primitives(turtle.interpret(der.modules, grammar.angle, grammar.width))
    order = [i for s in DRAWN for i, m in enumerate(der.modules) if m.symbol == s]
    return der, prims, der.hashes[order]


def sphere_centres(flat):
    keep = flat.kind == SPHERE
    return flat.transform[keep, :, 3], np.linalg.norm(flat.transform[keep, :, 0], axis=1)


def sorted_rows(x):
    return x[np.lexsort(np.round(x, 6).T)]


# ------------------------------------------------------------- the package

def test_every_file_is_a_preset_with_a_header():
    files = sorted(f[:-5] for f in os.listdir(PRESET_DIR) if f.endswith(".lsys"))
    assert files == sorted(presets.PRESETS)
    for name, (label, description) in presets.PRESETS.items():
        assert label and description
        text = presets.preset_text(name)
        with open(os.path.join(PRESET_DIR, name + ".lsys"), encoding="utf-8") as f:
            assert f.read() == text
        head = text.splitlines()[0]
        assert head.startswith("# ") and len(head) > 20, name


def test_unknown_preset_is_an_lsystem_error():
    with pytest.raises(lsystem_grammar.LSystemError, match="unknown.*sphereflake"):
        presets.load_preset("no_such_preset")
    with pytest.raises(lsystem_grammar.LSystemError):
        presets.preset_text("../__init__")


def test_the_preset_files_ship_in_the_extension():
    """No exclude pattern of blender_manifest.toml's [build] drops a .lsys file."""
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as f:
        patterns = tomllib.load(f)["build"]["paths_exclude_pattern"]
    for name in presets.PRESETS:
        rel = f"engine/lsystem/presets/{name}.lsys"
        parts = rel.split("/")
        for pat in patterns:
            anchored, body = pat.startswith("/"), pat.strip("/")
            if anchored:        # from the package root: a path prefix
                hit = any(fnmatch.fnmatch("/".join(parts[:k]), body) for k in range(1, len(parts) + 1))
            else:               # any component (a folder pattern ending in / too)
                hit = any(fnmatch.fnmatch(p, body) for p in parts)
            assert not hit, (rel, pat)


# ------------------------------------------------------------- every preset

@pytest.mark.parametrize("name", list(presets.PRESETS))
def test_preset_builds_a_scene_graph_standing_for_its_string(name):
    g = presets.load_preset(name)
    assert g.source_name == f"{name}.lsys"
    assert g.is_context_free and not g.is_stochastic
    graph = dcsg.DCSG(g)                           # no DCSGUnsupported
    n = graph.implicit_primitives
    assert n == drawn_count(g) > 0
    if derivation.count(g).length > 400_000:
        return
    der, prims, addresses = derived_primitives(g)
    assert prims.skipped == 0
    assert sum(m.symbol in DRAWN for m in der.modules) == n == len(prims)
    flat = graph.flatten()
    # the same primitives (by address: the graph lists them in string order)
    index = {a: i for i, a in enumerate(flat.address.tolist())}
    assert len(index) == n
    rows = [index[a] for a in addresses.tolist()]
    assert [KIND_IDS[p.kind] for p in prims] == flat.kind[rows].tolist()
    centre = np.array([np.asarray(p.transform)[:, 3] for p in prims])
    np.testing.assert_allclose(flat.transform[rows, :, 3], centre, rtol=0, atol=1e-9)


def test_known_counts():
    assert drawn_count(presets.load_preset("abop_1_24a")) == 3125
    der = derivation.derive(presets.load_preset("abop_1_24a"))
    assert sum(m.symbol == "F" for m in der.modules) == 3125
    assert dcsg.DCSG(presets.load_preset("menger_sponge")).implicit_primitives == 20 ** 3 == 8000
    assert dcsg.DCSG(presets.load_preset("ternary_tree")).implicit_primitives == 1 + 4 * (3 ** 6 - 1) // 2
    flake = presets.load_preset("sphereflake")
    assert flake.derivation_length == 4
    for d in range(6):
        assert dcsg.DCSG(flake, steps=d).implicit_primitives == sum(9 ** k for k in range(d + 1))
    assert dcsg.DCSG(flake).implicit_primitives == 7381            # the thesis's level 4
    tet = presets.load_preset("sierpinski_tetrahedron")
    assert tet.derivation_length == 6
    for n in range(8):
        assert dcsg.DCSG(tet, steps=n).implicit_primitives == 4 ** n
    sponge = presets.load_preset("menger_sponge")
    for n in range(5):
        assert dcsg.DCSG(sponge, steps=n).implicit_primitives == 20 ** n


@pytest.mark.parametrize("name,axiom", [("abop_1_24a", "F"), ("abop_1_24b", "F"), ("abop_1_24c", "F"),
                                        ("abop_1_24d", "X"), ("abop_1_24e", "X"), ("abop_1_24f", "X")])
def test_abop_1_24_axioms_and_counts(name, axiom):
    g = presets.load_preset(name)
    assert lsystem_grammar.format_string(g.axiom) == axiom
    n = g.derivation_length
    # F --> F... with k F in the successor: k^n; X-plants: F doubles, X adds its own
    k = {"abop_1_24a": 5, "abop_1_24b": 5, "abop_1_24c": 8}.get(name)
    if k is not None:
        assert drawn_count(g) == k ** n
    else:
        x_f = {"abop_1_24d": (3, 2), "abop_1_24e": (3, 2), "abop_1_24f": (4, 3)}[name]
        xs, fs = 1, 0                           # X and F counts, step by step
        for _ in range(n):
            xs, fs = x_f[0] * xs, x_f[1] * xs + 2 * fs
        assert drawn_count(g) == fs


# ------------------------------------------------------------- the fractals

@pytest.mark.parametrize("n", [2, 3])
def test_hilbert_curve_visits_every_lattice_point_once(n):
    der = derivation.derive(presets.load_preset("hilbert_3d"), n)
    geom = turtle.interpret(der.modules, 90)
    assert geom.n_segments == 8 ** n - 1
    pts = np.vstack([geom.seg_start[:1], geom.seg_end])
    q = np.round(pts)
    assert np.abs(pts - q).max() < 1e-9
    np.testing.assert_allclose(np.abs(geom.seg_end - geom.seg_start).sum(axis=1), 1.0)  # unit steps
    assert len({tuple(p) for p in q.astype(int)}) == 8 ** n                           # self-avoiding
    assert np.ptp(q, axis=0).tolist() == [2 ** n - 1] * 3                            # a cube


def test_menger_sponge_boxes_tile_the_sponge():
    graph = dcsg.DCSG(presets.load_preset("menger_sponge"))
    flat = graph.flatten()
    assert flat.kind.shape == (8000,) and np.all(flat.kind == BOX)
    lin, c = flat.transform[:, :, :3], flat.transform[:, :, 3]
    # axis-aligned cubes of side 1/27 (half side 1/54 along each axis, either sign)
    np.testing.assert_allclose(np.abs(lin), np.broadcast_to(np.eye(3) / 54, lin.shape), atol=1e-12)
    assert np.all(np.abs(c) + 1 / 54 <= 0.5 + 1e-12)            # inside the depth-0 cube
    g = (c + 0.5) * 27 - 0.5                                    # grid cell of each centre
    cell = np.round(g).astype(int)
    assert np.abs(g - cell).max() < 1e-9
    assert cell.min() >= 0 and cell.max() <= 26
    assert len({tuple(x) for x in cell}) == 8000                # no two overlap
    digits = np.stack([cell // 9, cell // 3 % 3, cell % 3], axis=1)   # (box, level, axis)
    removed = ((digits == 1).sum(axis=2) >= 2).any(axis=1)
    assert not removed.any()                                    # ...so exactly the sponge's cells


def test_menger_sponge_rays_hit_the_boxes():
    graph = dcsg.DCSG(presets.load_preset("menger_sponge"))
    flat = graph.flatten()
    c = flat.transform[:, :, 3]
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.5, 0.5, (400, 2))
    xy[0] = (0.01, 0.02)                                        # down the central tunnel
    o = np.column_stack([xy, np.full(len(xy), -2.0)])
    t = dcsg_trace.trace_closest(graph, o, np.tile([0.0, 0.0, 1.0], (len(xy), 1)))[0]
    # along +z a ray enters the lowest box whose footprint holds it, at its bottom face
    inside = np.all(np.abs(xy[:, None, :] - c[None, :, :2]) < 1 / 54, axis=2)
    z0 = np.where(inside, c[None, :, 2] - 1 / 54, np.inf).min(axis=1)
    expected = z0 + 2.0
    assert math.isinf(t[0]) and math.isinf(expected[0])
    hit = np.isfinite(expected)
    assert 200 < hit.sum() < 400
    np.testing.assert_array_equal(np.isfinite(t), hit)
    np.testing.assert_allclose(t[hit], expected[hit], rtol=0, atol=1e-9)


def _ifs(n, r0):
    """Leaf centres of the Sierpinski tetrahedron by iterating its four maps x -> (x + v)/2."""
    theta = math.acos(-1.0 / 3.0)
    d1 = np.array([0.0, math.sin(theta), math.cos(theta)])
    rot = lambda a: np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    corners = r0 * math.sqrt(6) / 2 * np.array([[0, 0, 1.0], d1, rot(2 * math.pi / 3) @ d1,
                                                 rot(-2 * math.pi / 3) @ d1])
    pts = np.zeros((1, 3))
    for _ in range(n):
        pts = np.concatenate([(pts + v) / 2 for v in corners])
    return pts, corners


@pytest.mark.parametrize("n", [1, 3, 6])
def test_sierpinski_leaves_are_the_ifs_points(n):
    g = presets.load_preset("sierpinski_tetrahedron")
    centre, radius = sphere_centres(dcsg.DCSG(g, steps=n).flatten())
    assert centre.shape == (4 ** n, 3)
    r0 = g.axiom[0].params[0]
    np.testing.assert_allclose(radius, r0 / 2 ** n, rtol=1e-12)
    expected, corners = _ifs(n, r0)
    # the corners form a regular tetrahedron (all edges equal): the IFS is the right one
    edges = [np.linalg.norm(a - b) for a, b in itertools.combinations(corners, 2)]
    np.testing.assert_allclose(edges, 2 * r0 * math.sqrt(6) / 2 * math.sqrt(2 / 3), rtol=1e-12)
    np.testing.assert_allclose(sorted_rows(centre), sorted_rows(expected), rtol=0, atol=1e-9)
    if n <= 3:  # neighbouring leaves touch, none overlap
        dist = np.linalg.norm(centre[:, None] - centre[None], axis=2) + np.eye(len(centre)) * 1e9
        assert dist.min() == pytest.approx(2 * r0 / 2 ** n, rel=1e-9)


def _flake_parents(der, geom):
    """(parent sphere index or -1) per sphere of the derived sphereflake string: the
    last sphere drawn one bracket level up."""
    last, depth, parent = {}, 0, []
    for m in der.modules:
        if m.symbol == "[":
            depth += 1
        elif m.symbol == "]":
            depth -= 1
        elif m.symbol == "@O":
            parent.append(last.get(depth - 1, -1))
            last[depth] = len(parent) - 1
    assert len(parent) == len(geom.spheres.radius)
    return np.array(parent)


def test_sphereflake_children_touch_their_parent():
    g = presets.load_preset("sphereflake")
    der = derivation.derive(g, 3)
    geom = turtle.interpret(der.modules, g.angle, g.width)
    c, r = geom.spheres.center, geom.spheres.radius
    assert len(r) == 1 + 9 + 81 + 729
    parent = _flake_parents(der, geom)
    assert (parent < 0).sum() == 1
    kid = np.nonzero(parent >= 0)[0]
    p = parent[kid]
    np.testing.assert_allclose(r[kid], r[p] / 3, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(c[kid] - c[p], axis=1), r[p] + r[kid], rtol=0, atol=1e-9)
    assert np.bincount(p).max() == 9 and set(np.bincount(p)[np.bincount(p) > 0]) == {9}
    # no child in its parent's lower hemisphere (where the parent hangs), and no two spheres overlap
    for k, q in zip(kid, p):
        if parent[q] >= 0:
            up = c[q] - c[parent[q]]
            assert np.dot(c[k] - c[q], up) >= -1e-9
    dist = np.linalg.norm(c[:, None] - c[None], axis=2)
    gap = dist - (r[:, None] + r[None])
    np.fill_diagonal(gap, np.inf)
    touching = np.zeros_like(gap, bool)
    touching[kid, p] = touching[p, kid] = True
    assert np.all(gap[~touching] > 1e-6) and np.all(np.abs(gap[touching]) < 1e-9)
    # materials: generation k is slot k
    gen = np.zeros(len(r), int)
    for i in kid:
        gen[i] = gen[parent[i]] + 1
    assert geom.spheres.material.tolist() == gen.tolist()


# ------------------------------------------------------------- the sympodial tree

def test_sympodial_tree_size_and_ol_stubs():
    g = presets.load_preset("sympodial_tree")
    assert g.ol_stubs
    graph = dcsg.DCSG(g)
    n = graph.implicit_primitives
    assert 30_000 <= n <= 60_000
    assert n == drawn_count(g)
    assert len(graph.nodes) < 2000                               # congruent subtrees are shared
    flat = graph.flatten()
    assert len(flat.kind) == n
    stubs, owned = np.unique(flat.stub, return_counts=True)
    assert 0 not in stubs                                        # every primitive has its OL
    assert len(stubs) == 1 + 17                                  # the stem, 16 branches and the apex
    assert sorted(owned)[0] == 16                                # the stem's own internodes
    # the branches taper (frustums), and leaves are organs at the twigs' ends
    assert (flat.kind == KIND_IDS["frustum"]).sum() > n // 2
    assert derivation.count(g).per_symbol["~"] == (n - 16 + 17) // 2
    lo, hi = graph.bounds()
    assert lo[2] == pytest.approx(-0.0, abs=0.2) and 8 < hi[2] < 20  # grows up +Z


# ------------------------------------------------------------- boxes in the scene graph

def test_box_terminals_in_the_scene_graph():
    text = """axiom: &(30) A
derivation length: 3
angle: 35
production:
A --> F(0.5) !(0.3) [ + ;(2) @B ] / [ - @B(0.2) A ]
"""
    g = lsystem_grammar.parse(text)
    graph = dcsg.DCSG(g)
    flat = graph.flatten()
    der, prims, addresses = derived_primitives(g)
    boxes = [p for p in prims if p.kind == "box"]
    assert len(boxes) == 6 and graph.implicit_primitives == len(prims)
    index = {a: i for i, a in enumerate(flat.address.tolist())}
    for p, a in zip(prims, addresses.tolist()):
        i = index[a]
        assert flat.kind[i] == KIND_IDS[p.kind] and flat.material[i] == p.material
        if p.kind == "box":
            np.testing.assert_allclose(flat.transform[i], np.asarray(p.transform)[:3], rtol=0, atol=1e-12)
    assert sorted(flat.material[flat.kind == BOX].tolist()) == [0, 0, 0, 2, 2, 2]
    # a ray down the first box's heading axis hits its face at half its side
    i = index[addresses[[k for k, p in enumerate(prims) if p.kind == "box"][0]]]
    m = flat.transform[i]
    h = m[:, 2] / np.linalg.norm(m[:, 2])
    t = dcsg_trace.trace_closest(graph, (m[:, 3] - 3 * h)[None], h[None])[0]
    assert t[0] == pytest.approx(3 - np.linalg.norm(m[:, 2]), abs=1e-9)
