"""L-systems in the photon tracer (thesis ch. 7): traced through their DCSG, lit
through orientation lightmaps, never unrolled.

Photon paths do not depend on how the geometry is stored, so the same scene with
the L-system given as its flattened primitives (under one OL of the same
resolution) must receive the same photons: the tests compare the two directly.
"""
import math

import numpy as np
import pytest

from lsystem_grammars import quadrature_area
from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine.geometry import dcsg
from photon_lightmaps.engine.lsystem import grammar
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.transport.renderer import render
from photon_lightmaps.engine.core.scene import (
    Camera, Instance, LSystem, Light, Material, OrientationLightmap, Primitive, Prototype, Scene,
    compose, rotate, scale, translate)

TREE = """axiom: !(0.25) A(1)
derivation length: 4
angle: 32
production:
A(s) : s > 0.1 --> F(s) !(s * 0.15) [ + A(s * 0.7) ] [ - ;(1) A(s * 0.65) @O(0.06) ] / A(s * 0.75)
"""
STUBS = TREE.replace("angle: 32", "angle: 32\nol stub: A levels 1 2")
XF = compose(translate(0.2, -0.1, 0.0), rotate("z", 20), scale(1.3))


def _scene(lsystem=None, flattened=None, ols=()):
    sc = Scene(n_bands=3)
    bark = sc.add_material(Material(diffuse=(0.5, 0.4, 0.3)))
    leaf = sc.add_material(Material(diffuse=(0.2, 0.6, 0.2)))
    floor = sc.add_material(Material(diffuse=0.5))
    sc.add_object(Primitive("quad", material=floor), transform=scale(6), name="floor",
                  lightmap_resolution=8)
    if lsystem is not None:
        sc.prototypes.append(Prototype(name="tree", lsystems=[
            LSystem(lsystem, name="tree", materials=(bark, leaf))]))
    else:
        sc.prototypes.append(Prototype(name="tree", primitives=flattened(bark, leaf)))
    sc.instances.append(Instance(len(sc.prototypes) - 1, XF, name="tree"))
    sc.lights.append(Light("point", power=2000.0, transform=translate(2.0, -1.5, 4.0)))
    sc.orientation_lightmaps.extend(ols)
    sc.camera = Camera(transform=compose(translate(0, -7, 2.0), rotate("x", 80)),
                       width=48, height=36)
    return sc


def _flattened(text):
    flat = dcsg.DCSG(grammar.parse(text)).flatten()
    names = {v: k for k, v in __import__("photon_lightmaps.engine.geometry.primitives",
                                         fromlist=["KIND_IDS"]).KIND_IDS.items()}

    def make(bark, leaf):
        return [Primitive(names[int(k)], transform=xf, material=(bark, leaf)[min(int(m), 1)],
                          params=tuple(p[:1]) if names[int(k)] == "frustum" else ())
                for k, p, xf, m in zip(flat.kind, flat.params, flat.transform, flat.material)]
    return make


def test_an_lsystem_gets_one_orientation_lightmap_of_its_own():
    cs = compile_scene(_scene(TREE))
    rows = cs.info["orientation_lightmaps"]
    assert [r["name"] for r in rows] == ["tree (L-system)"]
    assert cs.instance_lightmaps[1] == []            # no per-primitive lightmaps (7.2)
    # its area estimate is the flattened primitives' area (scale 1.3: x 1.69)
    flat = dcsg.DCSG(grammar.parse(TREE)).flatten()
    assert rows[0]["area"] == pytest.approx(1.69 * quadrature_area(flat, 16), rel=4 * rows[0]["area_rel_error"])
    # the row counts the graph's samples once (no meshes under it) and their time
    assert rows[0]["samples"] == OrientationLightmap("x", []).samples
    assert rows[0]["area_seconds"] > 0.0


def test_photons_on_the_graph_are_the_photons_on_its_flattening():
    ol = [OrientationLightmap("tree", [1], resolution=12, samples=4000)]
    graph = compile_scene(_scene(TREE, ols=ol))
    flat = compile_scene(_scene(flattened=_flattened(TREE), ols=ol))
    s1 = trace_photons(graph, 60_000, seed=11, record_direct=True)
    s2 = trace_photons(flat, 60_000, seed=11, record_direct=True)
    a = lightmap.texel_slice(graph.lightmaps, int(graph.orientation.lid[0]))
    b = lightmap.texel_slice(flat.lightmaps, int(flat.orientation.lid[0]))
    hits1, hits2 = graph.lightmaps.hits[a], flat.lightmaps.hits[b]
    assert hits1.sum() > 1500
    # the same paths: equal hits per bin but where a grazing tie went the other way
    assert np.abs(hits1 - hits2).sum() <= 1e-3 * hits1.sum()
    np.testing.assert_allclose(graph.lightmaps.flux[a].sum(0), flat.lightmaps.flux[b].sum(0), rtol=2e-3)
    np.testing.assert_allclose(s1.absorbed, s2.absorbed, rtol=2e-3)
    # the energy ledger closes on the graph too
    assert s1.emitted.sum() > 0


def test_stubs_receive_exactly_their_subtrees_and_the_parent_everything():
    cs = compile_scene(_scene(STUBS))
    rows = cs.info["orientation_lightmaps"]
    # 1 object OL + 3 stubs at level 1 + 9 at level 2
    assert len(rows) == 1 + 3 + 9
    parents = [r["parent"] for r in rows]
    assert parents[0] == -1 and all(0 <= p < len(rows) for p in parents[1:])
    trace_photons(cs, 60_000, seed=2, record_direct=True)
    lm = cs.lightmaps
    flux = [lm.flux[lightmap.texel_slice(lm, int(cs.orientation.lid[k]))].sum() for k in range(len(rows))]
    # every level holds its subtree: a parent's flux is at least the sum of its children's
    for k, p in enumerate(parents):
        if p >= 0:
            assert flux[p] >= flux[k] - 1e-9
    top = flux[0]
    level1 = [k for k, p in enumerate(parents) if p == 0]
    assert len(level1) == 3 and sum(flux[k] for k in level1) < top


def test_render_of_a_graph_matches_its_flattening():
    ol = [OrientationLightmap("tree", [1], resolution=12, samples=4000)]
    images = []
    for sc in (_scene(TREE, ols=ol), _scene(flattened=_flattened(TREE), ols=ol)):
        cs = compile_scene(sc)
        trace_photons(cs, 40_000, seed=4)
        images.append(render(cs, samples=4, seed=1))
    a, b = images
    assert a.max() > 0
    # the floor and the direct light are the same image to rounding; where the tree
    # shows its OL, the two area estimators (graph descent, flattened parts) differ
    # within their sampling error, so only there may the images differ, and little
    same = np.isclose(a, b, rtol=1e-6, atol=1e-9).all(axis=-1)
    assert 0.6 < same.mean() < 1.0
    diff = ~same
    rel = np.abs(a[diff] - b[diff]).sum() / b[diff].sum()
    assert rel < 0.05
    assert a.sum() == pytest.approx(b.sum(), rel=0.01)


@pytest.mark.parametrize("text,match", [
    ("axiom: F\nderivation length: 60\nangle: 25.7\nproduction:\nF --> F[+F]F[-F]F\n", "reaches"),
    ("axiom: + -\n", "no finite extent"),
])
def test_an_lsystem_out_of_range_is_refused_by_name(text, match):
    from photon_lightmaps.engine.core.scene import SceneError
    with pytest.raises(SceneError, match=f"L-system 'tree'.*{match}"):
        compile_scene(_scene(text))
