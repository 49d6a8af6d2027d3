"""L-systems authored in Blender: Add > Photon L-System, the generated preview, save and
reload, library linking, export, and grammar errors (operators/lsystem.py,
bake/lsystem_preview.py, export/lsystems.py).

The preview is checked against the engine: the generated node group, evaluated with
`evaluated_geometry()`, must draw the primitives of the engine's expansion at the preview
depth (count, and for the per-symbol Repeat Zone every leaf's centre).
"""
import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import export  # noqa: E402
from photon_lightmaps.engine.lsystem import grammar  # noqa: E402
from photon_lightmaps.engine.lsystem import derivation
from photon_lightmaps.engine.geometry.dcsg import DCSG, DCSGUnsupported  # noqa: E402
from photon_lightmaps.engine.lsystem.turtle import interpret, to_primitives  # noqa: E402
from photon_lightmaps.bake import lsystem_preview  # noqa: E402
from photon_lightmaps.export import lsystems  # noqa: E402
from photon_lightmaps.ui import panels  # noqa: E402

from blender_session import addon  # noqa: E402,F401  (session-wide registration)
from lsystem_grammars import CONTEXT, STOCHASTIC, TAPERED  # noqa: E402

ABOP_124A = lsystems.FALLBACK_PRESET_TEXT
# two rewritable symbols, F -> FF (exits that grow with the depth)
ABOP_124D = """axiom: X
derivation length: 5
angle: 22.5
production:
X --> F[+X][-X]FX
F --> FF
"""
# tapering segments (frustums), spheres, material slots, explicit angles
TAPER = """axiom: A
derivation length: 6
angle: 30
production:
A --> !(0.05) F [ + & B ] /(45) A
B --> ;(1) F(0.5) @O(0.2) !(0.02) F
"""
# parametric: every level has new parameter values (the flattened path)
PARAMETRIC = TAPERED


@pytest.fixture(autouse=True)
def empty_file():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene


def geometry(ob):
    dg = bpy.context.evaluated_depsgraph_get()
    return ob.evaluated_get(dg).evaluated_geometry()


def leaves(gs):
    """Bounding-box centres of every leaf mesh of a GeometrySet tree, in its space. Each
    distinct reference of an instances component is read once (the wrappers copy)."""
    out = []
    me = gs.mesh
    if me is not None and len(me.vertices):
        co = np.empty(len(me.vertices) * 3, np.float32)
        me.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3).astype(np.float64)
        out.append((0.5 * (co.min(0) + co.max(0)))[None])
    pc = gs.instances_pointcloud()
    if pc is not None:
        refs, n = gs.instance_references(), len(pc.points)
        ri = np.empty(n, np.int32)
        pc.attributes[".reference_index"].data.foreach_get("value", ri)
        xf = np.empty(n * 16, np.float32)
        pc.attributes["instance_transform"].data.foreach_get("value", xf)
        xf = xf.reshape(n, 4, 4).transpose(0, 2, 1).astype(np.float64)    # foreach_get is column-major
        local = [np.asarray(leaves(r)).reshape(-1, 3) for r in refs]
        for k, pts in enumerate(local):
            sel = xf[ri == k]
            if len(pts) and len(sel):
                out.append((np.einsum("nij,pj->npi", sel[:, :3, :3], pts) + sel[:, None, :3, 3]).reshape(-1, 3))
    return np.concatenate(out) if out else np.zeros((0, 3))


def reference_names(gs, out=None):
    out = set() if out is None else out
    if gs.instances_pointcloud() is not None:
        for r in gs.instance_references():
            if r.name:
                out.add(r.name)
            reference_names(r, out)
    return out


def realized_primitives(ob):
    gs = geometry(ob)               # the mesh lives as long as its GeometrySet
    me = gs.mesh
    if me is None:
        return 0
    ids = np.empty(len(me.polygons), np.int32)
    me.attributes[lsystem_preview.PRIMITIVE_ATTR].data.foreach_get("value", ids)
    return len(np.unique(ids))


def engine_primitives(text, depth):
    """What the engine expands at `depth`: (count, object-space centres or None)."""
    g = grammar.parse(text)
    try:
        d = DCSG(g, steps=depth)
    except DCSGUnsupported:
        prims = to_primitives(interpret(derivation.derive(g, depth).modules, g.angle, g.width))
        return len(prims), None
    f = d.flatten()
    if not g.is_stochastic:
        assert len(f.kind) == d.implicit_primitives
    return len(f.kind), f.transform[:, :, 3]


def nearest(a, b):
    """Distance from each row of a to the nearest row of b."""
    out = np.empty(len(a))
    for i in range(0, len(a), 512):
        d = np.linalg.norm(a[i:i + 512, None, :] - b[None, :, :], axis=2)
        out[i:i + 512] = d.min(axis=1)
    return out


def assert_same_points(got, want, tol=1e-5, what=""):
    """The two point sets agree (as multisets, within tol x their extent). Sorted on a
    coarse grid first; only rows that a grid boundary put out of step are searched."""
    got, want = np.asarray(got, np.float64).reshape(-1, 3), np.asarray(want, np.float64).reshape(-1, 3)
    assert len(got) == len(want), what
    tol *= max(1.0, float(np.abs(want).max(initial=0.0)))
    a = got[np.lexsort(np.round(got / (100 * tol)).T)]
    b = want[np.lexsort(np.round(want / (100 * tol)).T)]
    off = np.linalg.norm(a - b, axis=1) >= tol
    assert nearest(a[off], want).max(initial=0.0) < tol, what
    assert nearest(b[off], got).max(initial=0.0) < tol, what


def lsystem(text, name="LSys", **settings):
    ob = lsystem_preview.new_lsystem_object(name, text=text)
    for k, v in settings.items():
        setattr(ob.photon_lightmaps.lsystem, k, v)
    return ob


def test_add_preset_creates_object_text_and_modifier():
    name, _, _ = lsystems.presets()[0]
    assert bpy.ops.photon_lightmaps.lsystem_add(preset=name) == {"FINISHED"}
    ob = bpy.context.view_layer.objects.active
    assert ob is not None and ob.type == "MESH"
    text = ob[lsystems.TEXT_PROP]
    assert isinstance(text, bpy.types.Text) and text.as_string() == lsystems.preset_text(name)
    mod = lsystems.lsystem_modifier(ob)
    assert mod is not None and mod.type == "NODES"
    ng = mod.node_group
    assert ng[lsystems.TEXT_PROP] == text and ng[lsystems.INFO_PROP]["version"] == lsystems.FORMAT_VERSION
    meta = lsystems.info(ob)
    assert meta["hash"] == lsystems.text_hash(text.as_string()) and ob.photon_lightmaps.lsystem.status == ""
    if meta["path"] == "symbols":
        kinds = {n.bl_idname for n in ng.nodes}
        assert {"GeometryNodeRepeatInput", "GeometryNodeRepeatOutput", "GeometryNodeSetGeometryName",
                "GeometryNodeGeometryToInstance"} <= kinds
        assert len(ng.nodes["Repeat Output"].repeat_items) == 2 * len(meta["symbols"])


@pytest.mark.parametrize("text,depth", [(ABOP_124A, 3), (ABOP_124A, 4), (ABOP_124D, 4), (TAPER, 5)])
def test_symbol_preview_draws_the_engines_expansion(text, depth):
    ob = lsystem(text, preview_iterations=depth)
    meta = lsystems.info(ob)
    assert meta["path"] == "symbols" and meta["depth"] == depth
    gs = geometry(ob)
    got = leaves(gs)
    n, centres = engine_primitives(text, depth)
    assert len(got) == n == DCSG(grammar.parse(text), steps=depth).implicit_primitives
    assert_same_points(got, centres)
    # every rewritable symbol that is instanced carries its name (the axiom's are not instanced)
    plan = lsystem_preview.symbol_plan(grammar.parse(text))
    assert [s.label for s in plan.symbols] == meta["symbols"]
    instanced = {plan.symbols[c.symbol].label for s in plan.symbols for c in s.children if c.symbol is not None}
    assert reference_names(gs) == instanced


@pytest.mark.parametrize("text,depth", [(PARAMETRIC, 4), (STOCHASTIC, 3), (CONTEXT, 3)])
def test_flattened_preview_draws_the_engines_expansion(text, depth):
    ob = lsystem(text, preview_iterations=depth)
    meta = lsystems.info(ob)
    assert meta["path"] == "flattened" and meta["depth"] == depth and meta["note"]
    n, centres = engine_primitives(text, depth)
    assert realized_primitives(ob) == n
    if not grammar.parse(text).is_stochastic and centres is not None:
        assert n == DCSG(grammar.parse(text), steps=depth).implicit_primitives


def test_every_preset_previews_the_engines_expansion():
    for name, _, _ in lsystems.presets():
        ob = lsystem_preview.new_lsystem_object(name, preset=name)
        assert ob.photon_lightmaps.lsystem.status == "", name
        meta = lsystems.info(ob)
        n, centres = engine_primitives(lsystems.preset_text(name), meta["depth"])
        if meta["path"] == "symbols":
            got = leaves(geometry(ob))
            assert len(got) == n, name
            assert_same_points(got, centres, what=name)
        else:
            assert realized_primitives(ob) == n, name


def test_preview_depth_is_capped_at_what_blender_displays():
    ob = lsystem(ABOP_124A, use_render_iterations=True, render_iterations=8)
    s = ob.photon_lightmaps.lsystem
    s.preview_iterations = 9
    assert s.preview_iterations == lsystems.MAX_PREVIEW_DEPTH
    assert lsystems.info(ob)["depth"] == lsystems.MAX_PREVIEW_DEPTH
    dg = bpy.context.evaluated_depsgraph_get()
    shown = sum(1 for i in dg.object_instances if i.is_instance and i.parent is not None
                and i.parent.original == ob)
    assert shown == 5 ** lsystems.MAX_PREVIEW_DEPTH          # all six nested levels reach the depsgraph
    lines = [t for t, _ in panels.lsystem_summary(ob)]
    assert any("at most 6 nested" in t for t in lines)
    assert any("shows depth 6 of 8" in t for t in lines)
    # the render depth bounds the preview depth
    s.render_iterations = 2
    assert lsystems.info(ob)["depth"] == 2 and len(leaves(geometry(ob))) == 25


def test_save_and_reload_keep_grammar_and_settings(tmp_path):
    ob = lsystem(ABOP_124D, name="Weed", preview_iterations=3, use_seed=True, seed=7, use_angle=True,
                 angle=30.0, use_render_iterations=True, render_iterations=4)
    count = len(leaves(geometry(ob)))
    path = str(tmp_path / "lsys.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert "Weed" not in bpy.data.objects
    bpy.ops.wm.open_mainfile(filepath=path)
    ob = bpy.data.objects["Weed"]
    assert lsystems.grammar_text(ob).as_string() == ABOP_124D
    s = ob.photon_lightmaps.lsystem
    assert (s.preview_iterations, s.use_seed, s.seed, s.use_angle, s.angle, s.use_render_iterations,
            s.render_iterations) == (3, True, 7, True, 30.0, True, 4)
    assert lsystems.info(ob)["hash"] == lsystems.text_hash(ABOP_124D)
    assert lsystems.lsystem_modifier(ob).node_group[lsystems.TEXT_PROP] == lsystems.grammar_text(ob)
    assert len(leaves(geometry(ob))) == count
    # nothing to regenerate after loading: the text is the one previewed
    lsystem_preview.check_texts()
    assert lsystems.info(ob)["hash"] == lsystems.text_hash(ABOP_124D)


def test_library_linked_lsystem_keeps_its_grammar_and_exports(tmp_path):
    lsystem(ABOP_124A, name="Linked", preview_iterations=3)
    path = str(tmp_path / "lib.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with bpy.data.libraries.load(path, link=True) as (src, dst):
        dst.objects = ["Linked"]
    ob = dst.objects[0]
    bpy.context.scene.collection.objects.link(ob)
    text = lsystems.grammar_text(ob)
    assert ob.library is not None and text is not None and text.library is not None
    assert text.as_string() == ABOP_124A
    assert len(leaves(geometry(ob))) == 125
    lsystem_preview.check_texts()                    # linked data is not written to
    scene, _, _ = export_current()
    assert [p.lsystems[0].grammar for p in scene.prototypes] == [ABOP_124A]


def export_current():
    msgs = []
    scene, emap = export.export_scene(bpy.context.evaluated_depsgraph_get(),
                                      report=lambda level, msg: msgs.append((level, msg)))
    return scene, emap, msgs


@pytest.mark.parametrize("text", [ABOP_124A, PARAMETRIC])
def test_export_one_lsystem_object(text):
    ob = lsystem(text, name="Tree")
    ob.location = (1.0, -2.0, 0.5)
    ob.rotation_euler = (0.3, 0.0, 1.1)
    ob.scale = (2.0, 2.0, 2.0)
    for name in ("Bark", "Leaf"):
        ob.data.materials.append(bpy.data.materials.new(name))
    bpy.context.view_layer.update()
    scene, emap, msgs = export_current()
    assert len(scene.prototypes) == 1
    proto = scene.prototypes[0]
    assert proto.meshes == [] and proto.primitives == [] and proto.csg == []
    assert len(proto.lsystems) == 1
    ls = proto.lsystems[0]
    assert ls.grammar == text and ls.steps is None and ls.seed is None and ls.name == "Tree"
    assert [emap.materials[i] for i in ls.materials] == ["Bark", "Leaf"]
    assert len(scene.instances) == 1
    inst = scene.instances[0]
    assert inst.prototype == 0
    np.testing.assert_allclose(inst.transform, np.array(ob.matrix_world)[:3], atol=1e-12)
    assert emap.prototypes[0].uv_source == "lsystem"
    assert not [m for level, m in msgs if level == "WARNING" and "camera" not in m], msgs


def test_export_carries_the_overrides():
    ob = lsystem(ABOP_124A, use_render_iterations=True, render_iterations=9, use_seed=True, seed=11,
                 use_angle=True, angle=40.0)
    scene, _, _ = export_current()
    ls = scene.prototypes[0].lsystems[0]
    assert (ls.steps, ls.seed) == (9, 11)
    g = grammar.parse(ls.grammar)
    assert g.angle == 40.0 and g.productions[0].text == grammar.parse(ABOP_124A).productions[0].text
    assert ls.grammar.count("\n") == ABOP_124A.count("\n")      # line numbers kept
    ob.photon_lightmaps.lsystem.use_angle = False
    scene, _, _ = export_current()
    assert scene.prototypes[0].lsystems[0].grammar == ABOP_124A


def test_syntax_error_shows_line_and_column_and_keeps_the_preview():
    ob = lsystem(ABOP_124A, preview_iterations=3)
    ng = lsystems.lsystem_modifier(ob).node_group
    before = (len(leaves(geometry(ob))), len(ng.nodes), lsystems.info(ob)["hash"])
    text = lsystems.grammar_text(ob)
    text.from_string(ABOP_124A.replace("F --> F[+F]F[-F]F", "F --> F[+F]F[-F]F)"))
    with pytest.raises(grammar.LSystemSyntaxError) as err:
        grammar.parse(text.as_string())
    assert (err.value.line, err.value.column) == (6, 18)
    lsystem_preview.check_texts()                    # what the timer runs; must not raise
    status = ob.photon_lightmaps.lsystem.status
    assert "line 6, column 18" in status and text.name in status
    assert status in [t for t, _ in panels.lsystem_summary(ob)]
    assert (len(leaves(geometry(ob))), len(ng.nodes), lsystems.info(ob)["hash"]) == before
    # Update Preview reports it too, without raising
    bpy.context.view_layer.objects.active = ob
    assert bpy.ops.photon_lightmaps.lsystem_update() == {"FINISHED"}
    assert "line 6, column 18" in ob.photon_lightmaps.lsystem.status
    # editing the text again regenerates the preview
    text.from_string(ABOP_124A.replace("F --> F[+F]F[-F]F", "F --> F[+F]F"))
    lsystem_preview.check_texts()
    assert ob.photon_lightmaps.lsystem.status == ""
    assert len(leaves(geometry(ob))) == 3 ** 3 == DCSG(grammar.parse(text.as_string()), steps=3).implicit_primitives


def test_panel_statistics_come_from_the_engine():
    ob = lsystem(ABOP_124A)
    st = lsystems.info(ob)["stats"]
    d = DCSG(grammar.parse(ABOP_124A))
    s = d.stats()
    assert st["primitives"] == d.implicit_primitives == 5 ** 5
    assert st["dcsg_nodes"] == s["dcsg_nodes"] and st["graph_bytes"] == s["bytes"]
    assert st["flat_bytes"] == 5 ** 5 * lsystems.CYCLES_BYTES_PER_INSTANCE
    lines = [t for t, _ in panels.lsystem_summary(ob)]
    assert any("3,125" in t for t in lines) and any("DCSG nodes" in t for t in lines)
    assert any("OL stubs: none" in t for t in lines)
    stub = lsystem("axiom: A\nderivation length: 2\nol stub: A levels 1 2\nproduction:\nA --> F[+A]A\n",
                   name="Stubbed")
    assert lsystems.info(stub)["ol_stubs"] == ["A (levels 1, 2)"]


def test_duplicates_share_one_prototype_and_regenerate_independently():
    ob = lsystem(ABOP_124A, name="A", preview_iterations=3)
    dup = ob.copy()                     # what Alt+D does: same mesh, same node group
    dup.location = (5.0, 0.0, 0.0)
    bpy.context.scene.collection.objects.link(dup)
    bpy.context.view_layer.update()
    scene, _, _ = export_current()
    assert len(scene.prototypes) == 1 and [i.prototype for i in scene.instances] == [0, 0]
    np.testing.assert_allclose(sorted(i.transform[0, 3] for i in scene.instances), [0.0, 5.0])
    dup.photon_lightmaps.lsystem.preview_iterations = 2
    assert lsystems.lsystem_modifier(dup).node_group != lsystems.lsystem_modifier(ob).node_group
    assert (len(leaves(geometry(ob))), len(leaves(geometry(dup)))) == (125, 25)


def test_a_deleted_grammar_text_is_reported_and_not_exported_as_a_mesh():
    ob = lsystem(PARAMETRIC, name="Orphan")       # the flattened preview is the object's mesh
    assert len(ob.data.polygons) > 0
    bpy.data.texts.remove(lsystems.grammar_text(ob))
    assert lsystems.is_lsystem(ob) and lsystems.grammar_text(ob) is None
    scene, _, msgs = export_current()
    assert scene.prototypes == [] and scene.instances == []
    assert any("Orphan" in m and "no grammar Text" in m for _, m in msgs)
    lsystem_preview.check_texts()
    assert "no grammar Text" in lsystem_preview.update_preview(ob)


class _Layout:
    """Records what a panel draws (labels and operator/prop texts); accepts any layout call."""

    def __init__(self, out=None):
        self.out = [] if out is None else out

    def __getattr__(self, name):
        def call(*args, **kw):
            if name in ("label", "operator", "prop"):
                self.out.append((name, kw.get("text", args[-1] if args else "")))
            return _Layout(self.out)
        return call

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)


def test_panel_draws_the_grammar_status_and_statistics():
    ob = lsystem(ABOP_124A, name="Drawn")
    lsystems.grammar_text(ob).from_string("axiom: F\nproduction:\nF -> FF\n")
    lsystem_preview.update_preview(ob)
    panel = panels.PHOTON_LIGHTMAPS_PT_lsystem
    layout = _Layout()
    ctx = type("Ctx", (), {"object": ob, "screen": None})()
    panel.draw(type("P", (), {"layout": layout})(), ctx)
    texts = [t for _, t in layout.out]
    assert f"Grammar: {lsystems.grammar_text(ob).name}" in texts        # no Text editor: just the name
    assert any("line 3, column" in t for t in texts)
    assert any("DCSG nodes" in t for t in texts)


def test_timer_waits_for_typing_to_pause():
    ob = lsystem(ABOP_124A, preview_iterations=2)
    text = lsystems.grammar_text(ob)
    lsystem_preview.check_texts(settle=True)
    text.from_string(ABOP_124A.replace("F[+F]F[-F]F", "F[+F]F"))
    lsystem_preview.check_texts(settle=True)             # changed since the last poll: wait
    assert lsystems.info(ob)["hash"] == lsystems.text_hash(ABOP_124A)
    lsystem_preview.check_texts(settle=True)             # unchanged for one poll: regenerate
    assert lsystems.info(ob)["hash"] == lsystems.text_hash(text.as_string())
    assert len(leaves(geometry(ob))) == 9
