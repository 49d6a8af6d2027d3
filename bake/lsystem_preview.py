"""The viewport preview of an L-system object: the grammar (export/lsystems.py conventions)
-> the object's Geometry Nodes group and, where needed, its realized mesh. Like the rest of
bake/, it turns engine results (the turtle's drawings, the scene graph's expansion) into
Blender data; bpy is imported inside the functions that write it. What to draw (the plan,
the flattened expansion, its mesh arrays) is bake/lsystem_plan.py, which needs no Blender.

The grammar (a Text datablock) is the source of truth; the node group is regenerated from it
for the viewport only, by one of two paths (recorded in ``ob["photon_lsys"]["path"]`` and
shown in the panel):

* ``"symbols"``: grammars that fit one Repeat Zone (`symbol_plan`: context-free,
  deterministic, successors whose structure does not depend on the depth, e.g. every ABOP
  bracketed system). Per rewritable symbol X (module and incoming turtle state) the zone
  holds a GEOMETRY item ``Geo X`` and a MATRIX item ``Exit X``; each step builds X's new
  geometry as Join over its successor of Transform(Geometry to Instance(Set Geometry
  Name(Geo Y, "Y")), T) and its new exit as the product of the turtle moves and the
  children's exits (needed where, as in F -> FF, offsets grow with the depth). Segments are
  Mesh Cylinder / Mesh Cone nodes, spheres UV Spheres, boxes Mesh Cubes, organs Object /
  Collection Info instances; ``;(i)`` sets the material index. Exact at the preview depth
  (every leaf where the engine puts a primitive).
* ``"flattened"``: everything else (stochastic, parametric with ever-changing parameters,
  context-sensitive). The engine's own expansion at the preview depth (`flat_preview`:
  DCSG.flatten, or derive + turtle for context-sensitive grammars) is realized in Python
  into the object's mesh (12-sided cylinders and frustums, UV spheres, boxes, a face
  attribute ``lsys_primitive`` numbering the primitives), and the group passes it through.
  Organs are not shown on this path; above MAX_PREVIEW_PRIMITIVES the depth is lowered.

The preview depth is min(preview iterations, render depth, 6): Blender (viewport and Cycles)
drops instances nested deeper than 6 levels. Renders with this engine trace the grammar at
the render depth. Editing the Text does not re-evaluate Geometry Nodes, so a timer
(operators/lsystem.py, every TEXT_POLL_SECONDS) runs `check_texts`, which regenerates
previews whose text changed and then stayed unchanged for one poll (not at every
keystroke); Update Preview runs `update_preview` on demand. A grammar error goes to the
panel's status and leaves the preview as it was.
"""
from __future__ import annotations

import numpy as np

from .. import messages
from ..engine.lsystem.grammar import LSystemError
from ..engine.core.scene import SceneError
from ..export import lsystems
from . import lsystem_plan
from .lsystem_plan import (MAX_PREVIEW_PRIMITIVES, PlanUnfit, flat_preview, plan_primitives, realize,
                           symbol_plan)

PRIMITIVE_ATTR = "lsys_primitive"
ITERATIONS = "Iterations"


# ---------------------------------------------------------------- preview plan


# ---------------------------------------------------------------- node-group generation

class _Tree:
    """Small helper over a node tree: nodes with inputs set, links, cached constants."""

    def __init__(self, ng):
        self.ng = ng
        self.consts = {}
        self.products = {}
        self.column = {}

    def node(self, idname, x=0, **inputs):
        n = self.ng.nodes.new(idname)
        y = self.column.get(x, 0)
        n.location = (x * 220, -y)
        self.column[x] = y + 160
        for k, v in inputs.items():
            n.inputs[k.replace("_", " ")].default_value = v
        return n

    def link(self, out, inp):
        self.ng.links.new(out, inp)

    def matrix(self, m, x=0):
        """Socket of a constant 4x4: a Combine Transform where m is translation x rotation x
        positive scale (every turtle frame and unit-shape placement), else a Combine Matrix.
        Only non-default inputs are set (each set costs a tree update)."""
        m = np.asarray(m, np.float64)
        key = np.round(m, 12).tobytes()
        s = self.consts.get(key)
        if s is None:
            trs = _trs(m)
            if trs is not None:
                n = self.node("FunctionNodeCombineTransform", x)
                t, euler, scale = trs
                if np.any(t != 0.0):
                    n.inputs["Translation"].default_value = t
                if np.any(euler != 0.0):
                    n.inputs["Rotation"].default_value = euler
                if np.any(scale != 1.0):
                    n.inputs["Scale"].default_value = scale
            else:
                n = self.node("FunctionNodeCombineMatrix", x)
                for c in range(4):
                    for r in range(4):
                        if m[r, c] != float(r == c):
                            n.inputs[f"Column {c + 1} Row {r + 1}"].default_value = float(m[r, c])
            n.hide = True
            s = self.consts[key] = n.outputs[0]
        return s

    def product(self, factors, exits, x=0):
        """Socket of the left-to-right product of factors (constants, or int k: exits[k]).
        Products are cached by prefix, so siblings share their common turtle path."""
        if not factors:
            return self.matrix(np.eye(4), x)
        keys = tuple(np.round(f, 12).tobytes() if isinstance(f, np.ndarray) else f for f in factors)
        cache = self.products.setdefault(id(exits), {})
        n = len(keys)
        while n > 1 and keys[:n] not in cache:
            n -= 1
        if n == 1:
            f = factors[0]
            cur = self.matrix(f, x) if isinstance(f, np.ndarray) else exits[f]
        else:
            cur = cache[keys[:n]]
        for i in range(n, len(keys)):
            f = factors[i]
            s = self.matrix(f, x) if isinstance(f, np.ndarray) else exits[f]
            mm = self.node("FunctionNodeMatrixMultiply", x)
            self.link(cur, mm.inputs[0])
            self.link(s, mm.inputs[1])
            cur = cache[keys[:i + 1]] = mm.outputs[0]
        return cur

    def transform(self, geo, mat, x=0):
        t = self.node("GeometryNodeTransform", x)
        t.inputs["Mode"].default_value = "Matrix"
        self.link(geo, t.inputs["Geometry"])
        self.link(mat, t.inputs["Transform"])
        return t.outputs[0]


def _trs(m):
    """(translation, XYZ Euler, scale) with m = T R S (S > 0 diagonal), or None."""
    from mathutils import Matrix
    if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0)):
        return None
    a = m[:3, :3]
    scale = np.linalg.norm(a, axis=0)
    if not np.all(scale > 1e-12):
        return None
    r = a / scale
    if not (np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0):
        return None
    euler = np.array(Matrix(r.tolist()).to_euler("XYZ"))
    scale = np.where(np.abs(scale - 1.0) < 1e-12, 1.0, scale)
    euler = np.where(np.abs(euler) < 1e-12, 0.0, euler)
    t = np.where(np.abs(m[:3, 3]) < 1e-15, 0.0, m[:3, 3])
    return t, euler, scale


# Unit shapes in the engine's canonical frames (engine/geometry/primitives.py): Mesh Cone spans
# z in [0, depth], so it is moved down by 1.
_CONE_SHIFT = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -1.0], [0, 0, 0, 1]])


class _Shapes:
    def __init__(self, tree, organ, materials=()):
        # materials: per slot, the material of a mesh-linked slot (None otherwise). The
        # instances' own geometry has no material list, so an index alone leaves such
        # slots empty in the viewport and in Cycles: those shapes carry the material
        # (Set Material). Object-linked slots apply to the instances by index.
        self.t, self.organ, self.cache, self.materials = tree, organ, {}, tuple(materials)

    def unit(self, d):
        """(geometry socket of the unit shape, extra 4x4 into the canonical frame) or None."""
        t = self.t
        if d.kind == "organ":
            return self.organ(d.params[0])
        if d.kind == "cylinder":
            key = ("cylinder",)
        elif d.kind in ("frustum", "cone"):
            key = ("cone", round(float(d.params[0]) if d.kind == "frustum" and d.params else 0.0, 9))
        elif d.kind in ("sphere", "box"):
            key = (d.kind,)
        else:
            return None
        s = self.cache.get(key)
        if s is None:
            if key[0] == "cylinder":
                n = t.node("GeometryNodeMeshCylinder", 0, Vertices=lsystem_plan.SEGMENTS, Radius=1.0,
                           Depth=2.0)
                s = (n.outputs["Mesh"], np.eye(4))
            elif key[0] == "cone":
                n = t.node("GeometryNodeMeshCone", 0, Vertices=lsystem_plan.SEGMENTS, Radius_Top=key[1],
                           Radius_Bottom=1.0, Depth=2.0)
                s = (n.outputs["Mesh"], _CONE_SHIFT)
            elif key[0] == "box":
                n = t.node("GeometryNodeMeshCube", 0, Size=(2.0, 2.0, 2.0))
                s = (n.outputs["Mesh"], np.eye(4))
            else:
                n = t.node("GeometryNodeMeshUVSphere", 0, Segments=lsystem_plan.SEGMENTS,
                           Rings=lsystem_plan.SPHERE_RINGS, Radius=1.0)
                s = (n.outputs["Mesh"], np.eye(4))
            self.cache[key] = s
        return s

    def drawing(self, d, x=1):
        """Geometry socket of one drawing in its module's frame, or None (nothing drawn)."""
        key = ("drawing", d.kind, d.params, np.round(d.matrix, 12).tobytes(), d.material)
        if key in self.cache:
            return self.cache[key]
        u = self.unit(d)
        out = None
        if u is not None:
            geo, pre = u
            out = self.t.transform(geo, self.t.matrix(d.matrix @ pre, x), x)
            mat = (self.materials[min(int(d.material), len(self.materials) - 1)]
                   if self.materials and d.kind != "organ" else None)
            if mat is not None:
                sm = self.t.node("GeometryNodeSetMaterial", x)
                sm.inputs["Material"].default_value = mat
                self.t.link(out, sm.inputs["Geometry"])
                out = sm.outputs[0]
            elif d.kind != "organ" and d.material:
                sm = self.t.node("GeometryNodeSetMaterialIndex", x)
                sm.inputs["Material Index"].default_value = int(d.material)
                self.t.link(out, sm.inputs["Geometry"])
                out = sm.outputs[0]
        self.cache[key] = out
        return out


def _clear(ng):
    ng.nodes.clear()
    ng.interface.clear()
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    s = ng.interface.new_socket(ITERATIONS, in_out="INPUT", socket_type="NodeSocketInt")
    s.min_value, s.max_value = 0, lsystems.MAX_PREVIEW_DEPTH
    s.description = f"Preview depth (Blender shows at most {lsystems.MAX_PREVIEW_DEPTH} nested levels)"


def _join(tree, sockets, x):
    if len(sockets) == 1:
        return sockets[0]
    j = tree.node("GeometryNodeJoinGeometry", x)
    for s in reversed(sockets):     # a multi-input socket lists the last link first
        tree.link(s, j.inputs[0])
    return j.outputs[0]


def build_symbol_tree(ng, plan, organ=lambda name: None, materials=()):
    """Fills `ng` with the per-symbol Repeat Zone of `plan` (a SymbolPlan).
    organ(name) -> (geometry socket maker) is asked for `~(name)` drawings;
    materials: the object's slot materials, which `;(i)` selects."""
    _clear(ng)
    tree = _Tree(ng)
    gin = tree.node("NodeGroupInput", -1)
    gout = tree.node("NodeGroupOutput", 8)
    shapes = _Shapes(tree, lambda name: _organ_socket(tree, organ(name)), materials)
    rin = tree.node("GeometryNodeRepeatInput", 2)
    rout = tree.node("GeometryNodeRepeatOutput", 6)
    rin.pair_with_output(rout)
    items = rout.repeat_items
    names = []
    for i, s in enumerate(plan.symbols):
        g, e = f"Geo {i} {s.label}", f"Exit {i} {s.label}"
        if i == 0:
            items[0].name = g
        else:
            items.new("GEOMETRY", g)
        items.new("MATRIX", e)
        names.append((g, e))
    tree.link(gin.outputs[ITERATIONS], rin.inputs["Iterations"])
    # step 0: what each symbol draws itself, and the turtle after it
    for s, (g, e) in zip(plan.symbols, names):
        draws = [shapes.drawing(d, 1) for d in s.initial]
        draws = [d for d in draws if d is not None]
        if draws:
            tree.link(_join(tree, draws, 1), rin.inputs[g])
        tree.link(tree.matrix(s.initial_exit, 1), rin.inputs[e])
    # one rewriting step
    exits = [rin.outputs[e] for _, e in names]
    inst = {}

    def instance(k):
        if k not in inst:
            sn = tree.node("GeometryNodeSetGeometryName", 3, Name=plan.symbols[k].label)
            tree.link(rin.outputs[names[k][0]], sn.inputs["Geometry"])
            gi = tree.node("GeometryNodeGeometryToInstance", 3)
            tree.link(sn.outputs[0], gi.inputs[0])
            inst[k] = gi.outputs[0]
        return inst[k]

    const_inst = {}

    def drawing_instance(d):
        geo = shapes.drawing(d, 3)
        if geo is None:
            return None
        key = id(geo)
        if key not in const_inst:
            gi = tree.node("GeometryNodeGeometryToInstance", 3)
            tree.link(geo, gi.inputs[0])
            const_inst[key] = gi.outputs[0]
        return const_inst[key]

    for s, (g, e) in zip(plan.symbols, names):
        parts = []
        for c in s.children:
            src = instance(c.symbol) if c.symbol is not None else drawing_instance(c.drawing)
            if src is not None:
                parts.append(tree.transform(src, tree.product(c.factors, exits, 4), 5))
        if parts:
            tree.link(_join(tree, parts, 5), rout.inputs[g])
        tree.link(tree.product(s.exit, exits, 4), rout.inputs[e])
    # the axiom, at the depth the zone reached (no extra instance level)
    final = [rout.outputs[e] for _, e in names]
    parts = []
    for c in plan.root:
        if c.symbol is not None:
            src = rout.outputs[names[c.symbol][0]]
        else:
            src = drawing_instance(c.drawing)
        if src is not None:
            parts.append(tree.transform(src, tree.product(c.factors, final, 7), 7))
    if parts:
        tree.link(_join(tree, parts, 7), gout.inputs[0])


def _organ_socket(tree, target):
    """(geometry socket, identity) instancing an organ object or collection, or None."""
    import bpy
    if target is None:
        return None
    if isinstance(target, bpy.types.Collection):
        n = tree.node("GeometryNodeCollectionInfo", 0)
        n.inputs["Collection"].default_value = target
        n.inputs["Reset Children"].default_value = True
        return n.outputs["Instances"], np.eye(4)
    n = tree.node("GeometryNodeObjectInfo", 0)
    n.inputs["Object"].default_value = target
    n.inputs["As Instance"].default_value = True
    n.transform_space = "ORIGINAL"
    return n.outputs["Geometry"], np.eye(4)


def build_passthrough_tree(ng):
    """The flattened path's group: the object's own (realized preview) mesh, unchanged."""
    _clear(ng)
    tree = _Tree(ng)
    gin = tree.node("NodeGroupInput", 0)
    gout = tree.node("NodeGroupOutput", 2)
    tree.link(gin.outputs[0], gout.inputs[0])


# ---------------------------------------------------------------- realized preview mesh


def fill_mesh(me, flat):
    """Replaces `me`'s geometry with the realized primitives of a FlatPreview."""
    v, sizes, corners, mats, prim = realize(flat)
    me.clear_geometry()
    if len(sizes) == 0:
        me.attributes.new(PRIMITIVE_ATTR, "INT", "FACE")
        me.update()
        return
    me.vertices.add(len(v))
    me.vertices.foreach_set("co", v.astype(np.float32).reshape(-1))
    me.loops.add(len(corners))
    me.loops.foreach_set("vertex_index", corners.astype(np.int32))
    me.polygons.add(len(sizes))
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int32)
    me.polygons.foreach_set("loop_start", starts)
    me.polygons.foreach_set("material_index", mats.astype(np.int32))
    attr = me.attributes.new(PRIMITIVE_ATTR, "INT", "FACE")
    attr.data.foreach_set("value", prim.astype(np.int32))
    me.update(calc_edges=True)


# ---------------------------------------------------------------- preview update

def _status(ob, text):
    try:
        ob.photon_lightmaps.lsystem.status = text
    except AttributeError:
        pass


def _editable(ob):
    return ob.library is None and (ob.override_library is None or not ob.override_library.is_system_override)


def _preview_key(ob, src):
    """What the preview follows: the grammar text and the slot materials it carries."""
    mats = "|".join(f"{s.link}:{s.material.name if s.material else ''}" for s in ob.material_slots)
    return lsystems.text_hash(src + "\0" + mats)


def update_preview(ob, force=True):
    """Regenerates the preview of L-system object `ob` from its grammar.
    Returns the status text ("" when fine). A grammar the engine refuses sets the status
    and leaves the preview as it was; nothing raises for the user's input."""
    if not _editable(ob):
        return ""
    text = lsystems.grammar_text(ob)
    if text is None:
        msg = f"object '{ob.name}': no grammar Text (set one in the panel)" if lsystems.is_lsystem(ob) else \
            "not an L-system object"
        _status(ob, msg)
        return msg
    src = text.as_string()
    h = _preview_key(ob, src)
    meta = lsystems.info(ob)
    if not force and meta.get("checked") == h:
        return ob.photon_lightmaps.lsystem.status
    meta["checked"] = h
    settings = lsystems.settings_of(ob)
    try:
        user, grammar = lsystems.parse(src, text.name, settings)
        depth = lsystems.preview_depth(grammar, settings)
        try:
            plan = symbol_plan(grammar)
            expect = None
            if grammar.is_context_free:
                from ..engine.geometry.dcsg import DCSG
                expect = DCSG(grammar, steps=depth).implicit_primitives
            if expect is not None and plan_primitives(plan, depth) != expect:
                raise PlanUnfit("the per-symbol plan disagrees with the engine's expansion")
            flat, why = None, ""
        except PlanUnfit as exc:
            plan, why = None, str(exc)
            flat = flat_preview(grammar, depth)
        try:
            stats = lsystems.statistics(grammar, settings.steps, settings.cache_mb)
        except (LSystemError, SceneError) as exc:
            stats = {"error": messages.describe(exc)}
    except (LSystemError, SceneError) as exc:
        msg = messages.describe(exc)
        ob[lsystems.INFO_PROP] = meta
        _status(ob, msg)
        return msg
    mod = _ensure_modifier(ob, text)
    # Duplicates share the node group and mesh: regenerating must not change the other's.
    if mod.node_group.users > 1:
        mod.node_group = mod.node_group.copy()
    if ob.data.users > 1:
        ob.data = ob.data.copy()
    ng = mod.node_group
    approx = []             # where the preview differs from what a render traces
    if plan is not None:
        build_symbol_tree(ng, plan, lsystems.organ_resolver(ob),
                          [s.material if s.link == "DATA" else None for s in ob.material_slots])
        ob.data.clear_geometry()
        path, labels, note = "symbols", [s.label for s in plan.symbols], ""
    else:
        build_passthrough_tree(ng)
        fill_mesh(ob.data, flat)
        path, labels = "flattened", []
        note = f"the engine's expansion, realized as a mesh: {why}"
        if flat.depth < depth:
            approx.append(f"depth lowered to {flat.depth} to stay under {MAX_PREVIEW_PRIMITIVES:,} primitives")
            depth = flat.depth
        if lsystems.organ_names(src):
            approx.append("organs (~) are not shown on this path")
    ident = {i.name: i.identifier for i in ng.interface.items_tree
             if i.item_type == "SOCKET" and i.in_out == "INPUT"}
    mod[ident[ITERATIONS]] = int(depth)
    steps = lsystems.render_steps(grammar, settings)
    if steps is not None and steps > depth:
        approx.append(f"shows depth {depth} of {steps}; renders with this engine trace all {steps}")
    meta.update({"version": lsystems.FORMAT_VERSION, "hash": lsystems.text_hash(src), "path": path,
                 "depth": int(depth), "symbols": labels, "note": note, "approximate": approx, "stats": stats,
                 "ol_stubs": lsystems.ol_stub_lines(user), "organs": lsystems.organ_names(src)})
    ob[lsystems.INFO_PROP] = meta
    ng[lsystems.INFO_PROP] = {k: meta[k] for k in ("version", "hash", "path", "depth")}
    ng[lsystems.TEXT_PROP] = text
    ob.data.update()
    ob.update_tag()
    _status(ob, "")
    return ""


def _ensure_modifier(ob, text):
    import bpy
    mod = lsystems.lsystem_modifier(ob)
    if mod is None:
        mod = ob.modifiers.new(lsystems.MODIFIER_NAME, "NODES")
    if mod.node_group is None:
        mod.node_group = bpy.data.node_groups.new(f"{ob.name} L-System", "GeometryNodeTree")
    ng = mod.node_group
    if lsystems.INFO_PROP not in ng.keys():
        ng[lsystems.INFO_PROP] = {"version": lsystems.FORMAT_VERSION}
    ng[lsystems.TEXT_PROP] = text
    return mod


def new_lsystem_object(name=None, *, preset=None, text=None, location=(0.0, 0.0, 0.0), collection=None):
    """Creates and links an L-system object: a Text datablock with the grammar (`text`, or
    the preset's), an empty mesh and the Geometry Nodes modifier, with its preview built."""
    import bpy
    if text is None:
        preset = preset or lsystems.presets()[0][0]
        text = lsystems.preset_text(preset)
    label = next((lab for n, lab, _ in lsystems.presets() if n == preset), None) if preset else None
    name = name or (label.split(" (")[0] if label else "L-System")
    tb = bpy.data.texts.new(f"{name}.lsys")
    tb.from_string(text)
    me = bpy.data.meshes.new(name)
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    ob[lsystems.TEXT_PROP] = tb
    ob[lsystems.INFO_PROP] = {"version": lsystems.FORMAT_VERSION}
    (collection or bpy.context.scene.collection).objects.link(ob)
    _ensure_modifier(ob, tb)
    update_preview(ob)
    return ob


# object name -> hash of its text at the previous poll (the timer waits for typing to pause)
_SEEN = {}


def check_texts(settle=False):
    """Regenerates every editable L-system object whose grammar text changed (the timer's
    body). settle=True (the timer): only texts unchanged since the previous call, so a
    preview is not rebuilt at every keystroke."""
    import bpy
    for ob in bpy.data.objects:
        if lsystems.INFO_PROP not in ob.keys() or not _editable(ob):
            continue
        text = lsystems.grammar_text(ob)
        if text is None:
            continue
        h = _preview_key(ob, text.as_string())
        previous, _SEEN[ob.name] = _SEEN.get(ob.name), h
        if lsystems.info(ob).get("checked") != h and (not settle or previous == h):
            update_preview(ob, force=False)
