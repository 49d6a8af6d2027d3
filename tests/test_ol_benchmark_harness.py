"""The orientation-lightmap benchmark scenes (benchmarks/ol_scenes.py) have the
documented sizes: counts only, no bpy, no timing, no rendering.

* sphereflake level 4: 1 + 9 + 81 + 729 + 6561 = 7381 spheres, nine
  first-generation branches of 820 spheres each;
* Menger sponge level 3: 20^3 = 8000 cubes;
* the "ol9" method: a root OL holding the root sphere plus nine child OLs, one
  per first-generation sphere, each with the root OL as parent.
"""
import numpy as np
import pytest

from benchmarks import ol_scenes
from photon_lightmaps.engine.lightmaps import orientation_lightmap


def test_sphereflake_has_7381_spheres_in_nine_branches():
    sp = ol_scenes.spec("sphereflake")
    assert sp.kind == "sphere"
    assert sp.transforms.shape == (7381, 3, 4)
    assert np.bincount(sp.generation).tolist() == [1, 9, 81, 729, 6561]
    assert (sp.branch == -1).sum() == 1 and sp.branch[0] == -1
    assert np.bincount(sp.branch[sp.branch >= 0]).tolist() == [820] * 9
    # children are a third of their parent and every sphere sits on or above the floor
    r = np.linalg.norm(sp.transforms[:, :, 0], axis=1)
    assert np.allclose(sorted(set(np.round(r / r[0], 9))), sorted(3.0 ** -np.arange(5)))
    assert (sp.transforms[:, 2, 3] - r).min() == pytest.approx(0.0, abs=1e-12)


def test_menger_sponge_has_8000_cubes_and_the_cube_one():
    sp = ol_scenes.spec("menger")
    assert sp.kind == "box" and sp.transforms.shape == (8000, 3, 4)
    c, half = ol_scenes.menger()
    assert c.shape == (8000, 3) and half == pytest.approx(1.2 / 27 / 2)
    assert np.unique(np.round(c, 9), axis=0).shape[0] == 8000
    assert ol_scenes.spec("cube").transforms.shape == (1, 3, 4)
    assert ol_scenes.spec("torus").transforms.shape == (1, 3, 4)


def test_engine_scenes_and_orientation_lightmaps():
    sp = ol_scenes.spec("sphereflake")
    sc, ids = ol_scenes.engine_scene(sp, "ol9")
    assert len(sc.instances) == 7382 and ids.tolist() == list(range(1, 7382))
    ols = sc.orientation_lightmaps
    assert len(ols) == 10
    assert ols[0].parent == -1 and ols[0].instances == [1]
    assert [ol.parent for ol in ols[1:]] == [0] * 9
    assert [len(ol.instances) for ol in ols[1:]] == [820] * 9
    maps = orientation_lightmap.plan(sc)
    assert orientation_lightmap.covered_instances(maps, 0).size == 7381
    assert orientation_lightmap.levels(maps) == 2
    sc1, _ = ol_scenes.engine_scene(sp, "ol")
    assert len(sc1.orientation_lightmaps) == 1 and len(sc1.orientation_lightmaps[0].instances) == 7381
    sc0, _ = ol_scenes.engine_scene(sp, "lightmaps")
    assert sc0.orientation_lightmaps == []
    for name in ol_scenes.SCENES:
        assert set(ol_scenes.METHODS[name]) >= {"lightmaps", "ol"}
    assert ol_scenes.exact_area(ol_scenes.spec("cube")) == pytest.approx(6.0)
