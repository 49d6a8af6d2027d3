"""Compiles a plain-data `Scene` into the flat arrays the kernels traverse.

Every mesh triangle and every analytic primitive becomes a *shape* in
prototype space. Each prototype gets its own BVH (BLAS) over its shapes; all
BLAS nodes share one set of arrays with absolute indices. A second BVH (TLAS)
sits over the instances, each of which places a prototype in the world.

Within a prototype, shapes are renumbered into BVH leaf order, so the shapes
(and their triangle/primitive rows) a leaf touches are contiguous in memory
and `blas_items` is the identity, which the traversal relies on: a leaf's
item positions are its shape ids.

Besides the layout of docs/architecture.md the namedtuple carries `trace`,
one 64-byte aligned byte buffer with everything the traversal reads
(engine/geometry/trace_layout.py). The traversal core takes this one array
instead of the whole namedtuple: passing ~40 arrays through a call costs
about 100 ns per ray, the single buffer almost nothing. Input is checked
first (engine/geometry/validation.py).
"""
import time
from collections import namedtuple

import numpy as np

from .bvh import build_bvh, pack_bvh
from .dcsg import DCSG as SceneGraph, DCSGUnsupported
from . import dcsg_areas
from .dcsg_blob import H_DCSG, NO_VSHAPE, pack_blob as pack_dcsg_blob
from ..core import features
from .csg import CSG, MESH, flatten_csg, pack_blob
from .primitives import TRIANGLE, check_primitive, prim_local_bounds
from ..core.scene import SceneError, as_affine
from .trace_layout import DCSG, H_F64, pack_blas, pack_trace, trace_arrays_raw, trace_buf
from .validation import MAX_COORDINATE, check_graph, check_mesh, check_organs, fail

Geometry = namedtuple("Geometry", [
    # shapes (prototype space)
    "shape_kind", "shape_index", "shape_material", "shape_surface",
    "shape_proto",                   # owning prototype of each shape
    "tri_p", "tri_uv",
    "tri_tex_uv",                    # material (texture) UVs per corner, any range; 0 without
    "prim_kind", "prim_params", "prim_xf", "prim_inv",
    # bottom level: all prototypes' nodes in one array set
    "blas_min", "blas_max", "blas_a", "blas_count", "blas_items",
    "blas_pf", "blas_pi",            # packed 4-wide records (float32 / int32 views into trace)
    "proto_root", "proto_slot",      # root node (blas_*) and root record (blas_pf) of prototype p
    "proto_n_surfaces",
    "proto_shape_start", "proto_shape_count",   # shapes of prototype p are contiguous
    # instances and top level
    "inst_proto", "inst_xf", "inst_inv", "inst_lm_base",
    "tlas_min", "tlas_max", "tlas_a", "tlas_count", "tlas_items",
    "tlas_pf", "tlas_pi",            # packed records (views into trace); the root is record 0
    "trace",                         # uint8 buffer read by engine/geometry/raycast.py (layout: TRACE_*)
    "trace_i64", "trace_f32", "trace_i32", "trace_f64",   # typed views of the same bytes
    "trace_features",                # features.marker: which traversal cores the scene needs
])


def _box_corners_through(lo, hi, xf):
    """World bounds of the 8 corners of [lo, hi] under affine xf (3x4)."""
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                  for z in (lo[2], hi[2])], dtype=np.float64)
    w = c @ xf[:, :3].T + xf[:, 3]
    return w.min(axis=0), w.max(axis=0)


def _pad(lo, hi):
    """Widen boxes computed through transforms by a few ulps of their extent:
    the traversal maps rays with the inverse transform, whose rounding
    differs from the forward map used for these bounds."""
    mag = np.maximum(np.abs(lo), np.abs(hi)).max(axis=-1, keepdims=True)
    eps = 1e-12 * mag + 1e-300
    return lo - eps, hi + eps


def _instance_transforms(instances, n_protos, inst_proto, inst_xf, inst_inv):
    """Validates and inverts all instance transforms at once (10^6 instances
    must not cost a Python-level matrix inverse each); a bad one is re-checked
    alone so the error names the instance."""
    for i, inst in enumerate(instances):
        p = inst.prototype
        if isinstance(p, (bool, np.bool_)) or not isinstance(p, (int, np.integer)) or not 0 <= p < n_protos:
            fail(f"instance '{inst.name}'",
                  f"refers to prototype {p!r}, which does not exist (scene has {n_protos})")
        inst_proto[i] = p
        m = np.asarray(inst.transform, dtype=np.float64)
        inst_xf[i] = m[:3] if m.shape in ((4, 4), (3, 4)) else np.nan
    if not len(instances):
        return
    lin = inst_xf[:, :, :3]
    with np.errstate(all="ignore"):
        det = np.linalg.det(lin)
        scale = np.maximum(np.abs(lin).max(axis=(1, 2)), 1e-300)
        ok = np.all(np.isfinite(inst_xf), axis=(1, 2)) & (np.abs(det) > 1e-12 * scale ** 3)
    for i in np.nonzero(~ok)[0]:
        as_affine(instances[i].transform, f"instance '{instances[i].name}'")  # raises with a reason
    r = np.linalg.inv(lin)
    inst_inv[:, :, :3] = r
    inst_inv[:, :, 3] = -np.einsum("ijk,ik->ij", r, inst_xf[:, :, 3])
    bad = ~np.all(np.isfinite(inst_inv), axis=(1, 2))
    if bad.any():
        fail(f"instance '{instances[int(np.argmax(bad))].name}'", "transform cannot be inverted")


def box_corners(lo, hi, xf):
    """The 8 corners (I, 8, 3) of boxes lo..hi (I, 3) through affine maps xf (I, 3, 4)."""
    sel = np.arange(8)
    corners = np.stack([np.where(((sel >> k) & 1)[None, :], hi[:, None, k], lo[:, None, k])
                        for k in range(3)], axis=-1)
    return np.einsum("ijk,ilk->ilj", xf[:, :, :3], corners) + xf[:, None, :, 3]


def prototype_surfaces(geom):
    """For each prototype: list over surface slots of ('mesh', triangle rows) or ('prim', row)."""
    # shapes by prototype, including CSG leaves (which sit outside the BVH ranges);
    # grouped with stable sorts, as a Python loop over 100k shapes costs 0.15 s
    n_p = len(geom.proto_shape_start)
    slot = np.asarray(geom.shape_surface, np.int64)
    keep = np.flatnonzero(slot >= 0)
    proto = np.asarray(geom.shape_proto, np.int64)[keep]
    order = keep[np.lexsort((slot[keep], proto))]       # by prototype, then slot, then shape
    out = [[] for _ in range(n_p)]
    if order.size == 0:
        return out
    proto, slot = np.asarray(geom.shape_proto, np.int64)[order], slot[order]
    is_tri = np.asarray(geom.shape_kind)[order] == TRIANGLE
    index = np.asarray(geom.shape_index, np.int64)[order]
    starts = np.flatnonzero(np.r_[True, (proto[1:] != proto[:-1]) | (slot[1:] != slot[:-1])])
    ends = np.r_[starts[1:], len(order)]
    for a, b in zip(starts.tolist(), ends.tolist()):
        if is_tri[a]:
            out[proto[a]].append(("mesh", index[a:b]))
        else:
            out[proto[a]].append(("prim", int(index[b - 1])))
    return out


def instance_boxes(g):
    """Each instance's world box (lo (I, 3), hi (I, 3)): its prototype's root box through its transform."""
    roots = np.asarray(g.proto_root, np.int64)[np.asarray(g.inst_proto, np.int64)]
    world = box_corners(np.asarray(g.blas_min, np.float64)[roots], np.asarray(g.blas_max, np.float64)[roots],
                        np.asarray(g.inst_xf, np.float64))
    return world.min(axis=1), world.max(axis=1)


def _place_instances(scene, proto_root, proto_n_surfaces, blas_min, blas_max):
    """Validated instance transforms, lightmap bases (running sum of surfaces)
    and padded world boxes; refuses an instance beyond MAX_COORDINATE by name."""
    n_inst = len(scene.instances)
    inst_proto = np.zeros(n_inst, np.int32)
    inst_xf = np.zeros((n_inst, 3, 4))
    inst_inv = np.zeros((n_inst, 3, 4))
    inst_lm_base = np.full(n_inst, -1, np.int32)
    n_lightmaps = 0
    t_lo = np.zeros((n_inst, 3))
    t_hi = np.zeros((n_inst, 3))
    n_protos = len(scene.prototypes)
    _instance_transforms(scene.instances, n_protos, inst_proto, inst_xf, inst_inv)
    for i, inst in enumerate(scene.instances):
        if inst.lightmap:
            inst_lm_base[i] = n_lightmaps
            n_lightmaps += int(proto_n_surfaces[inst_proto[i]])
    roots = np.asarray(proto_root, np.int64)[inst_proto] if n_inst else np.zeros(0, np.int64)
    lo = blas_min[roots].astype(np.float64)
    hi = blas_max[roots].astype(np.float64)
    live = np.all(lo <= hi, axis=1)
    world = box_corners(lo, hi, inst_xf)
    if n_inst:
        t_lo[live], t_hi[live] = _pad(world.min(axis=1)[live], world.max(axis=1)[live])
        far = live & (np.maximum(np.abs(t_lo), np.abs(t_hi)).max(axis=1) > MAX_COORDINATE)
        if far.any():
            i = int(np.argmax(far))
            fail(f"instance '{scene.instances[i].name}'",
                  f"its transform puts it {np.abs(world[i]).max():.3g} m from the origin, beyond "
                  f"the tracer's range of {MAX_COORDINATE:.0e} m; scale or move it closer")
    return inst_proto, inst_xf, inst_inv, inst_lm_base, n_lightmaps, t_lo, t_hi, live


def _prototype_shapes(proto, pi_, csg, n_csg, n_materials, degenerate, uv_clamped, leaf_slot,
                      leaf_proto, leaf_root, graphs=()):
    """A prototype's shapes in input order: mesh triangles, primitives, then one
    shape per CSG solid (its roots start at csg.roots[n_csg]), with their surface
    slots; records dropped and clamped triangles, and each CSG leaf's slot.
    -> (kinds, materials, slots, lo, hi, triangles, uvs, texture uvs, primitive rows, CSG
    roots, surfaces)."""
    pname = f"prototype '{proto.name}'"
    # collect the prototype's shapes in input order
    k_kind, k_mat, k_surf, k_lo, k_hi = [], [], [], [], []
    k_tri, k_uv, k_tex, k_prim = [], [], [], []
    surf = []
    for mi, mesh in enumerate(proto.meshes):
        what = f"mesh '{mesh.name}' in {pname}"
        p, uv, mats, dropped, tex_uv = check_mesh(mesh, what, n_materials, uv_clamped)
        if dropped:
            degenerate[what] = dropped
        T = p.shape[0]
        if T == 0:
            # nothing left to hit: no surface slot either, or every lightmap id after
            # it would point one past its lightmap (slots count surfaces with shapes)
            continue
        slot = len(surf)
        surf.append(("mesh", mesh.name))
        k_kind.append(np.zeros(T, np.int32))
        k_mat.append(mats.astype(np.int32))
        k_surf.append(np.full(T, slot, np.int32))
        k_lo.append(p.min(axis=1))
        k_hi.append(p.max(axis=1))
        k_tri.append(p)
        k_uv.append(uv)
        k_tex.append(tex_uv)
    for prim in proto.primitives:
        what = f"primitive '{prim.name}' in {pname}"
        kid, params, xf, inv, mat = check_primitive(prim, what, n_materials)
        lb = prim_local_bounds(np.int32(kid), params)
        lo, hi = _box_corners_through(np.array(lb[:3]), np.array(lb[3:]), xf)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            fail(what, "bounds are not finite (check its parameters)")
        lo, hi = _pad(lo, hi)
        slot = len(surf)
        surf.append((prim.kind, prim.name))
        k_kind.append(np.array([kid], np.int32))
        k_mat.append(np.array([mat], np.int32))
        k_surf.append(np.array([slot], np.int32))
        k_lo.append(lo[None])
        k_hi.append(hi[None])
        k_prim.append((kid, params, xf, inv))
    # a CSG solid is one shape over its root box (after the primitives, so
    # their rows are unchanged); its leaves get surface slots of their own
    csg_roots = []
    for j in range(len(proto.csg)):
        root = int(csg.roots[n_csg + j])
        leaves = csg.root_leaves[n_csg + j]
        lo, hi = csg.node_box[root, :3], csg.node_box[root, 3:]
        if np.any(lo > hi):                  # provably empty (disjoint intersection)
            lo = hi = 0.5 * (lo + hi)
        k_kind.append(np.array([CSG], np.int32))
        k_mat.append(np.array([csg.leaf_material[leaves[0]]], np.int32))
        k_surf.append(np.array([-1], np.int32))
        k_lo.append(lo[None])
        k_hi.append(hi[None])
        csg_roots.append(root)
        for k in leaves:
            leaf_slot[k] = len(surf)
            leaf_proto[k] = pi_
            leaf_root[k] = root
            surf.append(("mesh" if csg.leaf_kind[k] == MESH else "csg", csg.leaf_name[k]))

    # an L-system is one shape over its graph's box (after the CSG solids); it has
    # no surface slot: its photons go into orientation lightmaps (thesis 7.2)
    for gi, graph, ls in graphs:
        lo, hi = _pad(*graph.bounds())
        k_kind.append(np.array([DCSG], np.int32))
        k_mat.append(np.array([ls.materials[0]], np.int32))
        k_surf.append(np.array([-1], np.int32))
        k_lo.append(lo[None])
        k_hi.append(hi[None])
        csg_roots.append(gi)
    kinds = np.concatenate(k_kind) if k_kind else np.zeros(0, np.int32)
    mats = np.concatenate(k_mat) if k_mat else np.zeros(0, np.int32)
    surfs = np.concatenate(k_surf) if k_surf else np.zeros(0, np.int32)
    lo = np.concatenate(k_lo) if k_lo else np.zeros((0, 3))
    hi = np.concatenate(k_hi) if k_hi else np.zeros((0, 3))
    tris = np.concatenate(k_tri) if k_tri else np.zeros((0, 3, 3))
    uvs = np.concatenate(k_uv) if k_uv else np.zeros((0, 3, 2))
    tex = np.concatenate(k_tex) if k_tex else np.zeros((0, 3, 2))
    return kinds, mats, surfs, lo, hi, tris, uvs, tex, k_prim, csg_roots, surf


class _Parts:
    """The shape, triangle, primitive and BLAS rows of compile_geometry, appended
    phase by phase in their final order, with running counts (absolute ids)."""

    def __init__(self, n_leaves):
        self.sh_kind, self.sh_index, self.sh_mat, self.sh_surf, self.sh_proto = [], [], [], [], []
        self.tri_p, self.tri_uv, self.tri_tex_uv = [], [], []
        self.pr_kind, self.pr_params, self.pr_xf, self.pr_inv = [], [], [], []
        self.b_min, self.b_max, self.b_a, self.b_cnt = [], [], [], []
        self.proto_root, self.proto_n_surf, self.proto_depth = [], [], []
        self.proto_start, self.proto_count = [], []
        # n_shapes counts BVH shapes only: the CSG virtual shapes follow them
        self.n_shapes = self.n_tris = self.n_prims = self.n_nodes = 0
        self.n_csg = 0                        # CSG solids placed so far (index into csg.roots)
        self.degenerate, self.uv_clamped, self.surfaces = {}, {}, []
        # per CSG leaf: its surface slot, owning prototype and root node
        self.leaf_slot = np.zeros(n_leaves, np.int64)
        self.leaf_proto = np.zeros(n_leaves, np.int64)
        self.leaf_root = np.zeros(n_leaves, np.int64)
        self.vs0 = 0                          # first virtual shape
        self.dcsg_vs0 = 0                     # first virtual shape of an L-system terminal
        self.dcsg_prims = 0
        self.prim_row_leaf = {}               # primitive row of a CSG primitive leaf -> leaf

    def add_shapes(self, kind, index, material, surface, proto):
        self.sh_kind.append(kind)
        self.sh_index.append(index)
        self.sh_mat.append(material)
        self.sh_surf.append(surface)
        self.sh_proto.append(proto)

    def add_triangles(self, p, uv, tex_uv=None):
        self.tri_p.append(p)
        self.tri_uv.append(uv)
        # CSG-generated triangles have no material UVs (textures read their mean there)
        self.tri_tex_uv.append(np.zeros_like(uv) if tex_uv is None else tex_uv)
        self.n_tris += p.shape[0]

    def add_primitive(self, kid, params, xf, inv):
        self.pr_kind.append(kid)
        self.pr_params.append(params)
        self.pr_xf.append(xf)
        self.pr_inv.append(inv)
        self.n_prims += 1


# Phase results of compile_geometry (the tuples pack_blas and _place_instances return)
_ShapeArrays = namedtuple("_ShapeArrays", [
    "shape_kind", "shape_index", "shape_material", "shape_surface", "shape_proto",
    "tri_p", "tri_uv", "tri_tex_uv", "prim_kind", "prim_params", "prim_xf", "prim_inv",
    "blas_min", "blas_max", "blas_a", "blas_count", "blas_items",
    "proto_root", "proto_n_surfaces", "proto_shape_start", "proto_shape_count"])
_BlasPack = namedtuple("_BlasPack", ["rec_parts", "proto_slot", "need", "tri4", "lane_shape",
                                     "shape_ref", "n_packets"])
_Instances = namedtuple("_Instances", ["proto", "xf", "inv", "lm_base", "n_lightmaps",
                                       "lo", "hi", "live"])
_Tlas = namedtuple("_Tlas", ["bvh", "items", "pi", "n_rec", "need"])


def _flatten_scene_csg(scene, n_materials):
    """All CSG solids at once: node ids are global, one blob for the trace."""
    return flatten_csg([(r, f"prototype '{p.name}'") for p in scene.prototypes for r in p.csg],
                       n_materials, mesh_uvs=lambda m, w: check_mesh(m, w, n_materials)[:3])


def _leaf_order_rows(kinds, order, csg_roots, n_tris, n_prims):
    """Renumbers a prototype's shapes into BVH leaf order `order`: -> (shape index
    in that order, its triangle rows, its primitive rows, both as input-order rows
    of the prototype's tables). Triangles and primitives get consecutive absolute
    rows from n_tris / n_prims."""
    S = kinds.shape[0]
    # input-order row of each shape inside its kind's table
    is_tri = kinds == 0
    row = np.where(is_tri, np.cumsum(is_tri) - 1, np.cumsum(~is_tri) - 1)
    kinds_o = kinds[order]
    is_csg = kinds_o >= CSG            # CSG solids and L-systems
    tri_rows = row[order][kinds_o == 0]
    prim_rows = row[order][(kinds_o != 0) & ~is_csg]
    new_index = np.empty(S, np.int32)
    new_index[kinds_o == 0] = n_tris + np.arange(tri_rows.size)
    new_index[(kinds_o != 0) & ~is_csg] = n_prims + np.arange(prim_rows.size)
    # CSG solids, then L-systems, are the last shapes of the input order; their
    # index is the root node or the graph (csg_roots holds both, in that order)
    csg_root_in = np.full(S, -1, np.int64)
    if csg_roots:
        csg_root_in[S - len(csg_roots):] = csg_roots
    new_index[is_csg] = csg_root_in[order][is_csg]
    return new_index, tri_rows, prim_rows


def _add_blas(parts, bvh, n_shapes, n_surfaces):
    """Appends a prototype's BVH to the shared BLAS arrays, with absolute node
    and blas_items ids."""
    a = bvh.node_a.copy()
    interior = bvh.node_count == 0
    if n_shapes > 0:
        a[interior] += parts.n_nodes              # child node index
        a[~interior] += parts.n_shapes            # position in blas_items
    parts.b_min.append(bvh.node_min)
    parts.b_max.append(bvh.node_max)
    parts.b_a.append(a)
    parts.b_cnt.append(bvh.node_count)
    parts.proto_root.append(parts.n_nodes)
    parts.proto_n_surf.append(n_surfaces)
    parts.proto_depth.append(bvh.depth)
    parts.proto_start.append(parts.n_shapes)
    parts.proto_count.append(n_shapes)
    parts.n_nodes += bvh.n_nodes
    parts.n_shapes += n_shapes


def _add_prototype(parts, pi_, proto, csg, n_materials, graphs=()):
    """Prototype pi_'s shapes, triangles and primitives in BVH leaf order, and its BLAS."""
    kinds, mats, surfs, lo, hi, tris, uvs, tex_uvs, k_prim, csg_roots, surf = _prototype_shapes(
        proto, pi_, csg, parts.n_csg, n_materials, parts.degenerate, parts.uv_clamped,
        parts.leaf_slot, parts.leaf_proto, parts.leaf_root, graphs)
    parts.n_csg += len(proto.csg)
    parts.surfaces.append(surf)
    S = kinds.shape[0]
    bvh = build_bvh(lo, hi)
    order = bvh.items.astype(np.int64)           # BVH leaf order of the shapes
    new_index, tri_rows, prim_rows = _leaf_order_rows(kinds, order, csg_roots,
                                                      parts.n_tris, parts.n_prims)
    parts.add_shapes(kinds[order], new_index, mats[order], surfs[order],
                     np.full(S, pi_, np.int32))
    parts.add_triangles(tris[tri_rows], uvs[tri_rows], tex_uvs[tri_rows])
    for r in prim_rows:
        parts.add_primitive(*k_prim[r])
    _add_blas(parts, bvh, S, len(surf))


def _add_csg_virtual_shapes(csg, parts):
    """Virtual shapes: one per CSG primitive leaf, one per CSG mesh triangle,
    after all BVH shapes (outside every BVH). A CSG hit reports one, so the
    owning leaf's material and lightmap slot apply (thesis 5.2.1)."""
    parts.vs0 = parts.n_shapes
    for k in range(csg.leaf_kind.shape[0]):
        kid = int(csg.leaf_kind[k])
        if kid == MESH:
            t0, nt = int(csg.leaf_tri0[k]), int(csg.leaf_ntri[k])
            kind = np.zeros(nt, np.int32)
            index = parts.n_tris + np.arange(nt, dtype=np.int32)
            material = csg.mtri_material[t0:t0 + nt].astype(np.int32)
            parts.add_triangles(csg.mtri[t0:t0 + nt].reshape(-1, 3, 3), csg.mtri_uv[t0:t0 + nt])
        else:
            nt = 1
            kind = np.array([kid], np.int32)
            index = np.array([parts.n_prims], np.int32)
            material = csg.leaf_material[k:k + 1].astype(np.int32)
            parts.prim_row_leaf[parts.n_prims] = k
            parts.add_primitive(kid, csg.leaf_params[k], csg.leaf_xf[k], csg.leaf_inv[k])
        parts.add_shapes(kind, index, material, np.full(nt, parts.leaf_slot[k], np.int32),
                         np.full(nt, parts.leaf_proto[k], np.int32))


def _lsystem_graphs(scene, n_materials, notes):
    """Each prototype's L-systems as scene graphs [(global graph id, DCSG, LSystem)],
    in prototype order; a grammar that cannot be one (context-sensitive, or choices
    that move what follows) is derived and its primitives instanced instead,
    with a note. -> (per prototype list, the scene with those primitives added)."""
    from dataclasses import replace
    from ..lsystem.grammar import parse
    from ..lsystem import derivation
    from ..lsystem.turtle import interpret, to_primitives
    from ..core.scene import LSystem
    per_proto, graphs, prototypes = [], [], list(scene.prototypes)
    for pi_, proto in enumerate(scene.prototypes):
        mine, extra = [], []
        for ls in proto.lsystems:
            what = f"L-system '{ls.name}' in prototype '{proto.name}'"
            if not isinstance(ls, LSystem) or not isinstance(ls.grammar, str):
                fail(what, "needs a grammar text")
            mats = tuple(int(m) for m in ls.materials) or (0,)
            if any(not 0 <= m < max(n_materials, 1) for m in mats):
                fail(what, f"material slots {mats} are not all scene materials (0..{n_materials - 1})")
            ls = replace(ls, materials=mats)
            grammar = parse(ls.grammar, name=ls.name)
            if ls.seed is not None:
                grammar = replace(grammar, seed=int(ls.seed))
            organs = check_organs(ls, what, n_materials)
            try:
                graph = SceneGraph(grammar, ls.steps, cache_mb=ls.cache_mb, organs=organs)
            except DCSGUnsupported as exc:
                der = derivation.derive(grammar, ls.steps)
                prims = to_primitives(interpret(der.modules, grammar.angle, grammar.width), name=ls.name)
                extra += [replace(p, material=mats[min(int(p.material), len(mats) - 1)]) for p in prims]
                notes.append(f"{what}: {exc}; {len(prims):,} primitives instanced")
                continue
            check_graph(graph, what)
            mine.append((len(graphs), graph, ls))
            graphs.append(graph)
        if extra:
            prototypes[pi_] = replace(proto, primitives=list(proto.primitives) + extra)
        per_proto.append(mine)
    if any(p is not q for p, q in zip(prototypes, scene.prototypes)):
        scene = replace(scene, prototypes=prototypes)
    return per_proto, graphs, scene


def _add_dcsg_virtual_shapes(per_proto, graphs, parts):
    """Virtual shapes: one per terminal primitive of every graph, after the CSG ones.
    A DCSG hit reports one, so the material its `;(i)` selected applies."""
    parts.dcsg_vs0 = int(sum(len(k) for k in parts.sh_kind))
    for pi_, mine in enumerate(per_proto):
        for gi, graph, ls in mine:
            a = graph.arrays()
            n = a.prim_kind.shape[0]
            first = parts.dcsg_prims
            # ;(i) slots, or (negative: -1 - organ) the organ's own material
            slot = np.clip(a.prim_material, 0, len(ls.materials) - 1)
            organ_mats = np.asarray(graph.organs.material + [0], np.int32)
            organ = np.clip(-1 - a.prim_material, 0, organ_mats.shape[0] - 1)
            mats = np.where(a.prim_material >= 0, np.asarray(ls.materials, np.int32)[slot],
                            organ_mats[organ])
            parts.add_shapes(np.full(n, DCSG, np.int32), first + np.arange(n, dtype=np.int32),
                             mats, np.full(n, -1, np.int32), np.full(n, pi_, np.int32))
            parts.dcsg_prims += n


def _dcsg_layout(per_proto, graphs, stubs, vs0):
    """What compile.py needs of the graphs (OL stubs, area estimation); not plain data."""
    stub_first, n = [], 0
    for recs in stubs:
        stub_first.append(n)
        n += len(recs)
    roots, node_area, n0 = [], [], 0
    for g in graphs:
        roots.append(g.arrays().root + n0)
        node_area.append(dcsg_areas.node_areas(g))
        n0 += len(g.nodes)
    return {"graphs": graphs, "proto_graphs": [[gi for gi, _, _ in mine] for mine in per_proto],
            "stubs": stubs, "stub_first": stub_first, "roots": roots, "vs0": vs0,
            "node_area": np.concatenate(node_area) if node_area else np.zeros(0)}


def _cat(lst, shape, dt):
    return np.ascontiguousarray(np.concatenate(lst).astype(dt)) if lst else np.zeros(shape, dt)


def _shape_arrays(parts):
    """The appended rows as the contiguous arrays of the Geometry."""
    return _ShapeArrays(
        shape_kind=_cat(parts.sh_kind, 0, np.int32),
        shape_index=_cat(parts.sh_index, 0, np.int32),
        shape_material=_cat(parts.sh_mat, 0, np.int32),
        shape_surface=_cat(parts.sh_surf, 0, np.int32),
        shape_proto=_cat(parts.sh_proto, 0, np.int32),
        tri_p=_cat(parts.tri_p, (0, 3, 3), np.float64),
        tri_uv=_cat(parts.tri_uv, (0, 3, 2), np.float64),
        tri_tex_uv=_cat(parts.tri_tex_uv, (0, 3, 2), np.float64),
        prim_kind=np.array(parts.pr_kind, np.int32).reshape(-1),
        prim_params=np.array(parts.pr_params, np.float64).reshape(-1, 4),
        prim_xf=np.array(parts.pr_xf, np.float64).reshape(-1, 3, 4),
        prim_inv=np.array(parts.pr_inv, np.float64).reshape(-1, 3, 4),
        blas_min=_cat(parts.b_min, (0, 3), np.float32),
        blas_max=_cat(parts.b_max, (0, 3), np.float32),
        blas_a=_cat(parts.b_a, 0, np.int32),
        blas_count=_cat(parts.b_cnt, 0, np.int32),
        blas_items=np.arange(parts.n_shapes, dtype=np.int32),
        proto_root=np.array(parts.proto_root, np.int32).reshape(-1),
        proto_n_surfaces=np.array(parts.proto_n_surf, np.int32).reshape(-1),
        proto_shape_start=np.array(parts.proto_start, np.int32).reshape(-1),
        proto_shape_count=np.array(parts.proto_count, np.int32).reshape(-1))


def _build_tlas(inst):
    """TLAS over the instances whose prototype has a box, packed into records."""
    live_ids = np.nonzero(inst.live)[0].astype(np.int32)
    tl = build_bvh(inst.lo[live_ids], inst.hi[live_ids])
    items = live_ids[tl.items] if live_ids.size else np.zeros(0, np.int32)
    _, pi, n_rec, need = pack_bvh(tl.node_min, tl.node_max, tl.node_a, tl.node_count)
    return _Tlas(tl, items, pi, n_rec, need)


def _geometry_tuple(sa, blas, inst, tlas, trace, feature_mask):
    """The Geometry: the phases' arrays and the record views into the trace."""
    t_arr = trace_arrays_raw(trace)
    tl = tlas.bvh
    return Geometry(
        **sa._asdict(), blas_pf=t_arr[1], blas_pi=t_arr[3], proto_slot=blas.proto_slot,
        inst_proto=inst.proto, inst_xf=inst.xf, inst_inv=inst.inv, inst_lm_base=inst.lm_base,
        tlas_min=tl.node_min, tlas_max=tl.node_max, tlas_a=tl.node_a, tlas_count=tl.node_count,
        tlas_items=np.ascontiguousarray(tlas.items, dtype=np.int32),
        tlas_pf=t_arr[0], tlas_pi=t_arr[2], trace=trace,
        # views made here, once: numba repeats its size and alignment checks
        # for a view made inside a kernel on every call
        trace_i64=trace.view(np.int64), trace_f32=trace.view(np.float32),
        trace_i32=trace.view(np.int32), trace_f64=trace.view(np.float64),
        trace_features=features.marker(feature_mask),
    )


def _geometry_info(scene, parts, csg, blas, inst, tlas, g, t0, dcsg=None, notes=()):
    """compile_geometry's info dict (counts, notes, layout for compile.py)."""
    info = {
        "n_shapes": parts.n_shapes,
        "n_triangles": parts.n_tris,
        "n_primitives": parts.n_prims,
        "n_degenerate": int(sum(parts.degenerate.values())),
        "degenerate": parts.degenerate,           # {"mesh 'x' in prototype 'y'": dropped}
        "uv_clamped": parts.uv_clamped,           # {mesh: triangles whose UVs left [0,1]²}
        "n_instances": len(scene.instances),
        "n_lightmaps": inst.n_lightmaps,
        "surfaces": parts.surfaces,               # per prototype: [(kind, name)] by slot
        "blas_nodes": parts.n_nodes,
        "tlas_nodes": tlas.bvh.n_nodes,
        "blas_depth": max(parts.proto_depth) if parts.proto_depth else 0,
        "tlas_depth": tlas.bvh.depth,
        "stack_entries": tlas.need + blas.need,   # worst case of one traversal
        "n_packets": blas.n_packets,
        "trace_bytes": int(g.trace.nbytes),
        "build_seconds": time.perf_counter() - t0,
    }
    info.update(csg.info)
    if dcsg is not None and dcsg["graphs"]:
        info["dcsg_layout"] = dcsg
        info["lsystems"] = [dict(g.stats(), name=ls.name) for mine in parts.lsystems
                            for _, g, ls in mine]
    if notes:
        info["lsystem_notes"] = list(notes)
    if csg.leaf_kind.shape[0]:
        # for compile.py (lightmaps of the leaves); not plain data, popped there
        info["csg_layout"] = {"flat": csg, "prim_row_leaf": parts.prim_row_leaf,
                              "leaf_root": parts.leaf_root, "vs0": parts.vs0,
                              "trace": trace_buf(g)}
    return info


def compile_geometry(scene):
    """Flattens scene.prototypes / scene.instances; returns (Geometry, info)."""
    t0 = time.perf_counter()
    n_materials = len(scene.materials)
    notes = []
    per_proto, graphs, scene = _lsystem_graphs(scene, n_materials, notes)
    csg = _flatten_scene_csg(scene, n_materials)
    parts = _Parts(csg.leaf_kind.shape[0])
    parts.lsystems = per_proto
    for pi_, proto in enumerate(scene.prototypes):
        _add_prototype(parts, pi_, proto, csg, n_materials, per_proto[pi_])
    _add_csg_virtual_shapes(csg, parts)
    csg_blob = pack_blob(csg, parts.vs0)
    _add_dcsg_virtual_shapes(per_proto, graphs, parts)
    dcsg_blob, _, stubs = pack_dcsg_blob(graphs, parts.dcsg_vs0 if graphs else NO_VSHAPE,
                                      [ls.name for mine in per_proto for _, _, ls in mine])
    dcsg = _dcsg_layout(per_proto, graphs, stubs, parts.dcsg_vs0)
    sa = _shape_arrays(parts)
    blas = _BlasPack(*pack_blas(
        parts.proto_root, parts.n_nodes, sa.blas_min, sa.blas_max, sa.blas_a, sa.blas_count,
        sa.shape_kind, sa.shape_index, sa.tri_p, parts.n_shapes))
    inst = _Instances(*_place_instances(scene, parts.proto_root, sa.proto_n_surfaces,
                                        sa.blas_min, sa.blas_max))
    tlas = _build_tlas(inst)
    mask = (features.CSG if csg.leaf_kind.shape[0] else 0) | (features.DCSG if graphs else 0)
    g = _geometry_tuple(sa, blas, inst, tlas, pack_trace(sa, blas, inst, tlas, csg_blob, dcsg_blob), mask)
    if (g.trace.ctypes.data + int(g.trace_i64[H_F64]) + 8 * int(g.trace_i64[H_DCSG])) % 16:
        raise SceneError("internal: the L-system blob is not 16-byte aligned")   # the vector loads
    return g, _geometry_info(scene, parts, csg, blas, inst, tlas, g, t0, dcsg, notes)


