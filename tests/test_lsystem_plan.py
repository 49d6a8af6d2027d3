"""The L-system preview's plan, without Blender (bake/lsystem_plan.py): which grammars fit
one Repeat Zone, and that the plan and the flattened expansion draw exactly the engine's
primitives. tests/test_lsystem_blender.py checks the node group built from them."""
import numpy as np
import pytest

from photon_lightmaps.bake import lsystem_plan
from photon_lightmaps.engine.geometry.dcsg import DCSG
from photon_lightmaps.engine.lsystem import derivation, grammar
from photon_lightmaps.export import lsystems

from lsystem_grammars import CONTEXT, STOCHASTIC


@pytest.mark.parametrize("name", ["abop_1_24a", "abop_1_24d", "hilbert_3d"])
def test_a_bracketed_preset_fits_the_plan_and_draws_the_engines_primitives(name):
    g = grammar.parse(lsystems.preset_text(name))
    plan = lsystem_plan.symbol_plan(g)
    assert plan.symbols
    for depth in range(0, 4):
        assert lsystem_plan.plan_primitives(plan, depth) == DCSG(g, steps=depth).implicit_primitives, depth


@pytest.mark.parametrize("text", [STOCHASTIC, CONTEXT])
def test_what_does_not_fit_is_refused_and_flattened(text):
    g = grammar.parse(text)
    with pytest.raises(lsystem_plan.PlanUnfit):
        lsystem_plan.symbol_plan(g)
    flat = lsystem_plan.flat_preview(g, 3)
    assert flat.depth == 3 and len(flat.kinds) == flat.transforms.shape[0] == flat.materials.shape[0] > 0
    assert flat.source == ("dcsg" if g.is_context_free else "derived")
    # the same choices as the derived string (module hashes): one segment per F
    assert len(flat.kinds) == sum(m.symbol == "F" for m in derivation.derive(g, 3).modules)


def test_a_flat_preview_above_its_limit_lowers_the_depth_and_realizes_every_primitive():
    g = grammar.parse(lsystems.preset_text("abop_1_24a"))
    full = DCSG(g, steps=3).implicit_primitives
    flat = lsystem_plan.flat_preview(g, 3, limit=full - 1)
    assert flat.depth == 2 and len(flat.kinds) == DCSG(g, steps=2).implicit_primitives
    v, sizes, corners, mats, prim = lsystem_plan.realize(flat)
    # every primitive is one closed tube of SEGMENTS quads and two caps
    n = len(flat.kinds)
    assert sizes.shape[0] == prim.shape[0] == n * (lsystem_plan.SEGMENTS + 2)
    assert v.shape == (n * 2 * lsystem_plan.SEGMENTS, 3) and np.all(np.isfinite(v))
    assert corners.max() < v.shape[0] and sizes.sum() == corners.shape[0]
    assert np.array_equal(np.unique(prim), np.arange(n))
