"""Booleans of plain meshes bake (bake/boolean_meshes.py): a mesh cube minus a mesh
cylinder (tests/boolean_scene.py) gets a lightmap of Blender's own result, whose
texels agree with Cycles' bake of the applied result (tests/data/, made by
scripts/make_test_references.py); without layers of the user's, the bake lays
the operands out as one atlas that the result's UVs carry, and lays it out the
same way again on the next bake. A layer the user made is never touched."""
import json

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake  # noqa: E402
from photon_lightmaps.bake import boolean_meshes  # noqa: E402
from photon_lightmaps.export import uv_layers  # noqa: E402

import boolean_scene  # noqa: E402
from blender_session import addon, bake_uv_cache  # noqa: E402,F401  (session-wide registration)
from test_bake_bias import erode  # noqa: E402

TOLERANCE = 0.01        # ours against Cycles over the interior texels (measured -0.4 %, the hole's wall -0.5 %)


@pytest.fixture(autouse=True)
def uv_cache(bake_uv_cache):
    yield


def reference():
    meta = json.loads(boolean_scene.PROVENANCE.read_text())
    assert meta["scene_hash"] == boolean_scene.scene_hash(), (
        "tests/boolean_scene.py or Blender changed since the Cycles reference was made: "
        "run .venv/bin/python scripts/make_test_references.py --only boolean")
    with np.load(boolean_scene.REFERENCE) as z:
        return z["cube"].astype(np.float64), meta


def layers(ob):
    return {l.name: uv_layers.read_uvs(l).copy() for l in ob.data.uv_layers}


def result_uvs():
    dg = bpy.context.evaluated_depsgraph_get()
    me = bpy.data.objects["cube"].evaluated_get(dg).data
    return uv_layers.read_uvs(me.uv_layers[uv_layers.LAYER_NAME])


def test_a_mesh_boolean_bakes_like_cycles_bakes_its_result():
    ref, meta = reference()
    boolean_scene.build(user_uvs=True)
    cube, cyl = bpy.data.objects["cube"], bpy.data.objects["cylinder"]
    before = {ob.name: layers(ob) for ob in (cube, cyl)}
    # 1 M photons, not the gathered default's 300 k: the cube's mean inherits the
    # photon noise of the few lightmaps its gather rays read, +-0.4 % at 300 k
    # (measured over seeds), which this Boolean check should not have to absorb
    res = bake.bake_objects(bpy.context, [cube], seed=3, resolution=boolean_scene.RES, photons=1_000_000)
    assert not res.skipped and set(res.maps) == {"cube"}, (res.skipped, res.warnings)
    rgba = res.maps["cube"].rgba
    inner = erode(rgba[..., 3] >= 1.0 - 1e-6)
    assert inner.sum() >= 400
    ours, theirs = float(rgba[..., :3][inner].mean()), float(ref[inner].mean())
    # the cylinder's wall in the cube (right half) is lit: the hole is baked, not dropped
    wall = inner.copy()
    wall[:, :boolean_scene.RES // 2] = False
    print(f"\nmesh Boolean, interior texels: ours {ours:.4f}, Cycles {theirs:.4f} "
          f"({ours / theirs - 1:+.4f}; Cycles {2 * meta['samples_per_half']} spp); "
          f"hole wall {rgba[..., :3][wall].mean():.4f} vs {ref[wall].mean():.4f}")
    assert wall.sum() >= 100 and rgba[..., :3][wall].mean() > 0.0
    assert abs(ours / theirs - 1) <= TOLERANCE
    assert abs(rgba[..., :3][wall].mean() / ref[wall].mean() - 1) <= 1.5 * TOLERANCE
    # the user's layers are theirs: used as they are, never written
    after = {ob.name: layers(ob) for ob in (cube, cyl)}
    for name in before:
        assert before[name].keys() == after[name].keys()
        for k in before[name]:
            assert np.array_equal(before[name][k], after[name][k]), (name, k)


def _rects(*obs):
    return [tuple(ob.data[boolean_meshes.BLOCK_PROP]) for ob in obs]


def test_without_layers_the_bake_lays_the_operands_out_as_one_atlas():
    boolean_scene.build(user_uvs=False)
    cube, cyl = bpy.data.objects["cube"], bpy.data.objects["cylinder"]
    uvmap = layers(cube)["UVMap"]
    res = bake.bake_objects(bpy.context, [cube], seed=3)
    assert not res.skipped and set(res.maps) == {"cube"}, (res.skipped, res.warnings)
    (a, b) = _rects(cube, cyl)
    for x, y, w, h in (a, b):
        assert 0.0 <= x and 0.0 <= y and x + w <= 1.0 and y + h <= 1.0
    assert a[0] + a[2] <= b[0] or b[0] + b[2] <= a[0] or a[1] + a[3] <= b[1] or b[1] + b[3] <= a[1]
    uv = result_uvs()
    assert uv.min() >= 0.0 and uv.max() <= 1.0
    bm = res.maps["cube"]
    covered = bm.rgba[..., 3] > 0.0
    assert covered.mean() > 0.2 and bm.rgba[..., :3][covered].mean() > 0.0
    # the image lies on both operands' blocks: the cube's faces and the hole's wall
    for x, y, w, h in (a, b):
        blk = covered[int(y * bm.height):int((y + h) * bm.height), int(x * bm.width):int((x + w) * bm.width)]
        assert blk.any()
    # a second bake maps the layers back first: the same layout, bit for bit
    first = {ob.name: layers(ob)[uv_layers.LAYER_NAME] for ob in (cube, cyl)}
    res2 = bake.bake_objects(bpy.context, [cube], seed=3)
    assert not res2.skipped and _rects(cube, cyl) == [a, b]
    for ob in (cube, cyl):
        assert np.abs(layers(ob)[uv_layers.LAYER_NAME] - first[ob.name]).max() <= 1e-6
        assert uv_layers.layer_is_ours(ob.data)
    assert np.array_equal(layers(cube)["UVMap"], uvmap)


def test_a_mix_of_user_and_generated_layers_is_refused_by_name():
    boolean_scene.build(user_uvs=False)
    cube, cyl = bpy.data.objects["cube"], bpy.data.objects["cylinder"]
    lay = cyl.data.uv_layers.new(name=uv_layers.LAYER_NAME)
    before = layers(cyl)[uv_layers.LAYER_NAME].copy()
    res = bake.bake_objects(bpy.context, [cube], seed=3)
    assert "cube" in res.skipped and "'cylinder'" in res.skipped["cube"] and not res.maps
    assert lay.name in cyl.data.uv_layers and np.array_equal(layers(cyl)[uv_layers.LAYER_NAME], before)
    assert uv_layers.LAYER_NAME not in cube.data.uv_layers
