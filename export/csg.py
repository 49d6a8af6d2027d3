"""Blender Boolean-modifier stacks -> exact CSG trees (thesis 4.1), for the export.

Conventions (shared with operators/csg_primitives.py, bake/ and ui/panels.py):

* A *tagged CSG primitive* is a mesh object with the custom properties
  ``obj["photon_csg_primitive"]`` (a kind of engine.geometry.primitives: sphere, box,
  cylinder, cone, torus, paraboloid) and ``obj["photon_csg_params"]`` (float
  list; torus: ``[minor_radius]``, others ``[]``). Its mesh is only a display
  mesh in the primitive's canonical local frame, so the object's transform *is*
  the primitive's transform and the tracer uses the exact surface.
* An object whose modifier stack holds enabled (``show_render``) Boolean
  modifiers is a CSG solid: its own geometry combined with each modifier's
  operand in stack order, ``((base op1 A) op2 B) ...``, exactly as Blender
  applies the stack. An operand that has Boolean modifiers itself is a subtree.
  A collection operand is the union of its mesh objects for Union and
  Difference; for Intersect Blender intersects with *every* object of the
  collection (checked against Blender 5.0's Exact solver), so it is a chain of
  intersections.
* The solid's prototype space is the base object's local space: each leaf
  carries ``base.matrix_world^-1 @ leaf.matrix_world`` (primitives in their
  transform, meshes baked into their vertices). Each leaf keeps its own
  object's first material.

Fallbacks, each reported with the object's name (WARNING, so it also lands in
ExportMap.warnings): a mesh leaf that is not a closed, consistently oriented
2-manifold (vertices welded by position), or a base object whose stack also
holds enabled non-Boolean modifiers (which exact CSG cannot express), makes
the *whole* solid fall back to its evaluated mesh, i.e. Blender's own Boolean
result, exported as a plain mesh. An *operand* with such modifiers enters the
tree as a mesh leaf of its evaluated mesh (what Blender cuts with), and a
tagged primitive with other modifiers as its evaluated display mesh. A modifier without operand, an empty
collection, a dependency cycle or a zero-scale operand is reported and that
modifier (or operand) is skipped, as Blender itself does.

Nothing here imports bpy at module level, so the core's tests can import it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..engine.core.scene import CSGNode, Primitive, Prototype
from .context import LIGHTMAP_UV, PrototypeRecord

PRIMITIVE_PROP = "photon_csg_primitive"
PARAMS_PROP = "photon_csg_params"
# Kinds the Add menu creates: the engine's closed solids (disk and quad are open).
SOLID_KINDS = ("sphere", "box", "cylinder", "cone", "torus", "paraboloid")
OPS = {"UNION": "union", "INTERSECT": "intersection", "DIFFERENCE": "difference"}


class CSGFallback(Exception):
    """The solid cannot be exact CSG; the message says why (names the object)."""


class _SkipOperand(Exception):
    """One operand is dropped (already reported); the rest of the tree stands."""


@dataclass
class CSGSolid:
    root: object                              # CSGNode, or a lone Primitive / TriangleMesh
    operands: list = field(default_factory=list)   # original objects used as operands
    leaves: int = 0


def primitive_tag(ob):
    """(kind, params tuple) of a tagged CSG primitive, None if untagged.

    Raises ValueError (message names the object) for a malformed tag.
    """
    ob = getattr(ob, "original", None) or ob
    if ob is None or ob.type != "MESH" or PRIMITIVE_PROP not in ob.keys():
        return None
    kind = str(ob[PRIMITIVE_PROP])
    if kind not in SOLID_KINDS:
        raise ValueError(f"object '{ob.name}': '{PRIMITIVE_PROP}' is '{kind}', "
                         f"not one of {', '.join(SOLID_KINDS)}")
    raw = ob.get(PARAMS_PROP, ())
    try:
        params = tuple(float(x) for x in raw)
    except TypeError:
        params = (float(raw),)
    if kind == "torus":
        if len(params) < 1 or not 0.0 < params[0] < 1.0:
            raise ValueError(f"object '{ob.name}': a torus needs '{PARAMS_PROP}' = [minor radius] "
                             f"with 0 < minor radius < 1 (major radius is 1), got {list(params)}")
        params = params[:1]
    else:
        params = ()
    return kind, params


def boolean_modifiers(ob):
    """The Boolean modifiers that take part in the final render (show_render)."""
    ob = getattr(ob, "original", None) or ob
    return [m for m in ob.modifiers if m.type == "BOOLEAN" and m.show_render]


def other_modifiers(ob):
    ob = getattr(ob, "original", None) or ob
    return [m for m in ob.modifiers if m.type != "BOOLEAN" and m.show_render]


def modifier_operands(base, mod):
    """(original mesh objects, problem or None) named by one Boolean modifier."""
    base = base.original or base
    where = f"object '{base.name}': Boolean modifier '{mod.name}'"
    if mod.operand_type == "COLLECTION":
        col = mod.collection
        if col is None:
            return [], f"{where} has no operand collection; it is skipped"
        obs = [o.original or o for o in col.all_objects if o.type == "MESH"]
        # Blender never cuts an object with itself, even when it is in the collection.
        obs = [o for o in obs if o != base]
        if not obs:
            return [], f"{where}: collection '{col.name}' holds no mesh objects; it is skipped"
        return sorted(obs, key=lambda o: o.name), None
    ob = mod.object
    if ob is None:
        return [], f"{where} has no operand object; it is skipped"
    ob = ob.original or ob
    if ob == base:
        return [], f"{where} uses the object itself as operand; it is skipped"
    if ob.type != "MESH":
        return [], f"{where}: operand '{ob.name}' is a {ob.type.lower()}, not a mesh; it is skipped"
    return [ob], None


def collect_operands(ob, out=None, stack=()):
    """{operand original object: name of the solid it cuts}, recursively, for one solid."""
    out = {} if out is None else out
    ob = ob.original or ob
    if ob in stack:
        return out
    for mod in boolean_modifiers(ob):
        obs, _ = modifier_operands(ob, mod)
        for o in obs:
            out.setdefault(o, ob.name)
            collect_operands(o, out, stack + (ob,))
    return out


def closed_mesh_problem(vertices, triangles):
    """None if the triangles form a closed, consistently oriented 2-manifold, else why not.

    Vertices are welded by exact position first, like the core's check
    (engine/geometry/csg.py), so meshes split along UV seams still count as closed.
    """
    t = np.asarray(triangles, np.int64).reshape(-1, 3)
    if t.shape[0] < 4:
        return f"is not a closed mesh (only {t.shape[0]} triangle(s))"
    _, weld = np.unique(np.asarray(vertices, np.float64).reshape(-1, 3), axis=0, return_inverse=True)
    t = weld.reshape(-1)[t]
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e = e[e[:, 0] != e[:, 1]]
    _, cnt = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    bad = int(np.count_nonzero(cnt != 2))
    if bad:
        open_ = int(np.count_nonzero(cnt == 1))
        return (f"is not a closed 2-manifold mesh ({open_} open edge(s), "
                f"{bad - open_} edge(s) shared by more than two triangles)")
    # Consistently oriented and closed: each edge is walked once in each direction.
    _, dcnt = np.unique(e, axis=0, return_counts=True)
    if np.any(dcnt != 1):
        return (f"has inconsistent face orientation ({int(np.count_nonzero(dcnt != 1))} edge(s); "
                "recalculate normals)")
    return None


def manifold_problem(mesh):
    """closed_mesh_problem of a Blender mesh's loop triangles."""
    mesh.calc_loop_triangles()
    nv, nt = len(mesh.vertices), len(mesh.loop_triangles)
    if nt == 0:
        return "has no faces"
    co = np.empty(nv * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    tri = np.empty(nt * 3, np.int32)
    mesh.loop_triangles.foreach_get("vertices", tri)
    return closed_mesh_problem(co.reshape(-1, 3), tri.reshape(-1, 3))


def _mat4(m):
    return np.array(m, dtype=np.float64).reshape(4, 4)


def _checked_tag(ob):
    """The object's Photon CSG primitive tag; a malformed tag makes the solid fall back."""
    try:
        return primitive_tag(ob)
    except ValueError as exc:
        raise CSGFallback(str(exc)) from None


class CSGBuilder:
    """Builds one CSG solid per base object; the exporter supplies the conversions.

    depsgraph: the evaluated depsgraph (world matrices and evaluated meshes).
    material_of(ob) -> engine material index of the object's first material.
    triangle_mesh(mesh, ob) -> TriangleMesh (prototype space = mesh space) or None.
    report(level, message).
    """

    def __init__(self, depsgraph, material_of, triangle_mesh, report):
        self.dg = depsgraph
        self.material_of = material_of
        self.triangle_mesh = triangle_mesh
        self.report = report

    def _evaluated(self, ob):
        return ob.evaluated_get(self.dg) if self.dg is not None else ob

    def build(self, base):
        """CSGSolid for `base` (an object with enabled Boolean modifiers, or a tagged
        primitive). Raises CSGFallback when it cannot be exact."""
        base = base.original or base
        world = _mat4(self._evaluated(base).matrix_world)
        if abs(np.linalg.det(world[:3, :3])) <= 1e-12 * max(np.abs(world[:3, :3]).max(), 1e-300) ** 3:
            raise CSGFallback(f"object '{base.name}': zero scale")
        self._inv_base = np.linalg.inv(world)
        self._operands = []
        self._leaves = 0
        root = self._solid(base, ())
        return CSGSolid(root, self._operands, self._leaves)

    # -- tree -------------------------------------------------------------------------------
    def _solid(self, ob, stack):
        bools = boolean_modifiers(ob)
        if not bools:
            return self._leaf(ob)
        others = other_modifiers(ob)
        if others:
            names = ", ".join(f"'{m.name}' ({m.type.lower()})" for m in others)
            if not stack:
                raise CSGFallback(f"object '{ob.name}' has modifiers besides Booleans ({names}), which "
                                  "exact CSG cannot express")
            # An operand's result is what Blender cuts with: its evaluated mesh, as a mesh leaf.
            self.report("WARNING", f"object '{ob.name}' has modifiers besides Booleans ({names}); as an "
                                   "operand its evaluated mesh is used instead of an exact subtree")
            return self._mesh(ob, self._evaluated(ob).data, self._relative(ob))
        node = self._own_geometry(ob)
        for mod in bools:
            obs, problem = modifier_operands(ob, mod)
            if problem:
                self.report("WARNING", problem)
                continue
            subs = []
            for o in obs:
                if o in stack or o == ob:
                    self.report("WARNING", f"object '{ob.name}': Boolean modifier '{mod.name}': operand "
                                           f"'{o.name}' depends on '{ob.name}' (a cycle); it is skipped")
                    continue
                try:
                    subs.append(self._solid(o, stack + (ob,)))
                except _SkipOperand:
                    continue
                self._operands.append(o)
            if not subs:
                continue
            op = OPS[mod.operation]
            name = f"{ob.name}/{mod.name}"
            if op == "intersection":
                for s in subs:
                    node = CSGNode(op, node, s, name=name)
            else:
                node = CSGNode(op, node, _balanced_union(subs, f"{name}/collection"), name=name)
        return node

    def _relative(self, ob):
        rel = self._inv_base @ _mat4(self._evaluated(ob).matrix_world)
        a = rel[:3, :3]
        if abs(np.linalg.det(a)) <= 1e-12 * max(np.abs(a).max(), 1e-300) ** 3:
            self.report("WARNING", f"object '{ob.name}': zero scale; this Boolean operand is skipped")
            raise _SkipOperand(ob.name)
        return rel

    def _leaf(self, ob):
        """An object without Boolean modifiers: its evaluated geometry (what Blender uses)."""
        rel, tag = self._relative(ob), _checked_tag(ob)
        if tag is not None and not other_modifiers(ob):
            return self._primitive(ob, tag, rel)
        if tag is not None:
            names = ", ".join(f"'{m.name}'" for m in other_modifiers(ob))
            self.report("WARNING", f"object '{ob.name}': modifiers {names} change the CSG primitive's "
                                   "display mesh, so its evaluated mesh is used instead of the exact surface")
        return self._mesh(ob, self._evaluated(ob).data, rel)

    def _own_geometry(self, ob):
        """An object with Boolean modifiers: its geometry before the stack (the original data)."""
        rel, tag = self._relative(ob), _checked_tag(ob)
        if tag is not None:
            return self._primitive(ob, tag, rel)
        return self._mesh(ob, ob.data, rel)

    def _primitive(self, ob, tag, rel):
        self._leaves += 1
        return Primitive(tag[0], rel[:3].copy(), material=self.material_of(ob), params=tag[1], name=ob.name)

    def _mesh(self, ob, mesh, rel):
        tm = self.triangle_mesh(mesh, ob)
        if tm is None:
            raise CSGFallback(f"Boolean operand '{ob.name}' has no triangles; exact CSG needs closed solids")
        problem = closed_mesh_problem(tm.vertices, tm.triangles)
        if problem:
            raise CSGFallback(f"Boolean operand '{ob.name}' {problem}; exact CSG needs closed solids")
        v = np.asarray(tm.vertices, np.float64)
        tm.vertices = v @ rel[:3, :3].T + rel[:3, 3]
        if np.linalg.det(rel[:3, :3]) < 0.0:
            # A mirroring transform turns the winding inside out; keep normals outward.
            tm.triangles = np.ascontiguousarray(tm.triangles[:, ::-1])
            if tm.uvs is not None:
                tm.uvs = np.ascontiguousarray(tm.uvs[:, ::-1])
        tm.material = self.material_of(ob)
        tm.material_ids = None
        tm.name = ob.name
        self._leaves += 1
        return tm


def tree_leaves(node):
    """Leaves of a CSG tree, left to right (for tests and reports)."""
    if isinstance(node, CSGNode):
        return tree_leaves(node.left) + tree_leaves(node.right)
    return [node]


def _balanced_union(items, name):
    """Union of a collection's solids as a balanced tree: depth log2(n), so a
    collection of hundreds of rivets stays within the ray-CSG work stack and
    its subtree boxes cull whole halves."""
    if len(items) == 1:
        return items[0]
    mid = (len(items) + 1) // 2
    return CSGNode("union", _balanced_union(items[:mid], name), _balanced_union(items[mid:], name),
                   name=name)


def find_operands(depsgraph):
    """{original operand object: name of the solid it cuts} for every solid an export of
    `depsgraph` may meet (the one finder: the export and the bake's target choice use it)."""
    viewport = depsgraph.mode == "VIEWPORT"
    out = {}
    for ob in depsgraph.objects:
        original = ob.original if ob.original is not None else ob
        if viewport and original.hide_render:
            continue
        cands = [original]
        if original.instance_type == "COLLECTION" and original.instance_collection is not None:
            cands += list(original.instance_collection.all_objects)
        for c in cands:
            if c.type == "MESH" and boolean_modifiers(c):
                collect_operands(c, out)
    return out


def csg_prototype(ctx, ob):
    """Prototype index of an object's exact CSG solid or tagged primitive; None: export its mesh."""
    original = ob.original if ob.original is not None else ob
    key = original.as_pointer()
    if key in ctx.csg_index:
        return ctx.csg_index[key]
    name = original.name
    ctx.csg_index[key] = None
    if name in ctx.mesh_results:
        ctx.map.csg_solids[name] = "mesh result"
        return None
    try:
        tag = primitive_tag(original)
    except ValueError as exc:
        ctx.report("WARNING", f"{exc}; its display mesh is exported instead")
        tag = None
        if not boolean_modifiers(original):
            return None
    if not boolean_modifiers(original):
        if tag is None:
            return None
        others = other_modifiers(original)
        if others:
            ctx.report("WARNING", f"object '{name}': modifiers {', '.join(repr(m.name) for m in others)} "
                                   "change the CSG primitive's display mesh, so that mesh is exported "
                                   "instead of the exact surface")
            return None
    try:
        solid = ctx.csg.build(original)
    except CSGFallback as exc:
        ctx.report("WARNING", f"{exc}; object '{name}' is exported as its evaluated Boolean result "
                               "mesh instead of exact CSG")
        ctx.map.csg_solids[name] = "fallback"
        return None
    root = solid.root
    if isinstance(root, CSGNode):
        proto, kind = Prototype(name=name, csg=[root]), "csg"
    elif isinstance(root, Primitive):
        proto, kind = Prototype(name=name, primitives=[root]), "primitive"
    else:
        return None   # every Boolean modifier was skipped: the plain mesh is the result
    ctx.scene.prototypes.append(proto)
    # A lone primitive's display mesh carries the engine's chart atlas as its Lightmap layer.
    ctx.map.prototypes.append(PrototypeRecord(name, 0, LIGHTMAP_UV if kind == "primitive" else "csg"))
    ctx.map.csg_solids[name] = kind
    idx = len(ctx.scene.prototypes) - 1
    ctx.csg_index[key] = idx
    return idx

