"""Exact ray–CSG intersection by hit-list interval classification (thesis 4.1, Roth 1982).

A CSG solid is a binary tree of Boolean operators over closed solids: analytic
primitives (sphere, box, cylinder, cone, torus, paraboloid) and closed triangle
meshes. Along a ray every leaf occupies a sorted list of parameter intervals
(entry, exit); a node combines its children's lists with union, intersection or
difference, so the 3D problem becomes a 1D merge of sorted lists.

Flattened layout (`flatten_csg` -> `CSGFlat`, packed by `pack_blob` into one
byte blob that lives inside the geometry's trace buffer, see below):

* nodes ``n``: ``node_op`` (UNION, INTER, DIFF or LEAF), ``node_l``/``node_r``
  (child node ids; for a leaf ``node_l`` is the leaf id), ``node_rfirst``
  (evaluate the right child first, Sethi–Ullman order: the number of interval
  lists alive at once stays at log2(leaves) + 1 for any tree shape) and
  ``node_box`` (prototype space, padded) for subtree culling. Intersection and
  difference boxes are left ∩ right and left.
* leaves ``k``: ``leaf_kind`` (primitive kind id, 0 = closed triangle mesh),
  ``leaf_flip`` (1 if the leaf sits under an odd number of subtracted operands:
  the solid is monotone in every leaf, so its outward normal on that leaf's
  boundary is the leaf's normal flipped, a static property), the leaf's
  inverse transform and parameters, its mesh triangles and mesh BVH, and its
  *virtual shape* ids (one per primitive leaf, one per mesh triangle): the
  shape a hit reports, which carries the leaf's material and lightmap slot.

The kernels (geometry/csg_trace.py) read the blob through the trace buffer (``buf``, byte offset from
header word ``H_CSG``) and use caller-provided scratch (``CSG_SCRATCH_WORDS``
int32 words), so they allocate nothing per ray.

Coincident boundaries (thesis 4.1.2: coplanar faces make hit lists "not
properly resolvable"): two boundaries of the operands closer than
``TIE_REL`` × (the ray's extent through the root box) are one event. Both
operands switch together and the result is re-evaluated once, so

* union: touching intervals merge (exit of A = entry of B emits nothing);
* difference: a face shared by A and B belongs to B (the cut): A minus a box
  that shares A's face removes that face, and a hit on a shared boundary
  reports B's leaf with its flipped normal;
* union and intersection: a boundary both operands own reports A's leaf.

Every such event is counted (``ties``); interval lists have room for
``MAX_INTERVALS`` intervals; further intervals (the farthest) are dropped and
counted (``overflow``) instead of writing out of bounds.
"""
from collections import namedtuple

import numpy as np

from ..core import features
from .primitives import (
    BOX, CONE, CYLINDER, FRUSTUM, N_FACES, PARABOLOID, SPHERE, TORUS, check_primitive,
    prim_local_bounds)
from ..core.scene import CSGNode, Primitive, SceneError, TriangleMesh

CSG = int(N_FACES.shape[0])   # shape kind of a CSG solid (after the primitive ids)
UNION, INTER, DIFF, LEAF = 0, 1, 2, 3
OP_IDS = {"union": UNION, "intersection": INTER, "difference": DIFF}
MESH = 0                      # leaf kind of a closed triangle mesh
SOLID_KINDS = (SPHERE, BOX, CYLINDER, CONE, TORUS, PARABOLOID, FRUSTUM)

MAX_INTERVALS = 32            # per interval list
MAX_LISTS = 16                # lists alive at once (Sethi–Ullman need of the tree)
MAX_WORK = 128                # pending nodes (tree depth)
MESH_STACK = 64               # mesh BVH traversal stack
TIE_REL = 1e-9

# trace-buffer header words (engine/geometry/trace_layout.py): the float64 section's
# byte offset, and the CSG blob's element offset inside it
H_F64 = 4
H_CSG = 19

# blob header: int64 words; int32 arrays are offsets in int32 units, float64
# arrays in float64 units, both from the blob start
(B_NNODE, B_NLEAF, B_VS0, B_NODE_OP, B_NODE_L, B_NODE_R, B_NODE_RFIRST, B_NODE_BOX,
 B_LEAF_KIND, B_LEAF_FLIP, B_LEAF_INV, B_LEAF_PARAMS, B_LEAF_TRI0, B_LEAF_NODE0,
 B_LEAF_VSHAPE, B_VSHAPE_LEAF, B_MTRI, B_MNODE_BOX, B_MNODE_A, B_MNODE_CNT,
 B_NVSHAPE) = range(21)
BLOB_HEADER = 24

# scratch layout (int32 words)
SC_TIES, SC_OVER = 0, 1
SC_WORK = 4
SC_MSTACK = SC_WORK + MAX_WORK
SC_LEN = SC_MSTACK + MESH_STACK
SC_LISTS = SC_LEN + 2 * ((MAX_LISTS + 2) // 2) + 2
LIST_WORDS = 8 * MAX_INTERVALS            # t: 2*MI float64, owner: 2*MI, sub: 2*MI
CSG_SCRATCH_WORDS = SC_LISTS + (MAX_LISTS + 1) * LIST_WORDS


CSGFlat = namedtuple("CSGFlat", [
    "node_op", "node_l", "node_r", "node_rfirst", "node_box",
    "leaf_kind", "leaf_flip", "leaf_xf", "leaf_inv", "leaf_params", "leaf_material",
    "leaf_tri0", "leaf_ntri", "leaf_node0", "leaf_name", "leaf_src",
    "mtri", "mtri_uv", "mtri_material", "mnode_box", "mnode_a", "mnode_cnt",
    "roots", "root_names", "root_leaves", "info",
])

# what the kernels see of a stand-alone table (a Geometry has the same fields)
CSGTrace = namedtuple("CSGTrace", ["trace_i64", "trace_f32", "trace_i32", "trace_f64", "trace_features"])


def trace_views(buf):
    """The typed views (i64, f32, i32, f64) of a trace byte buffer and a features
    marker (every core: a stand-alone table), as the kernels take them."""
    return (buf.view(np.int64), buf.view(np.float32), buf.view(np.int32), buf.view(np.float64),
            features.marker(features.ALL))


class CSGTable:
    """Stand-alone CSG solids: `g` goes to the kernels, `flat` is the layout."""

    def __init__(self, trace, flat):
        self.trace = trace_views(trace)
        self.flat = flat
        self.g = CSGTrace(*self.trace)
        self.roots = flat.roots


# --------------------------------------------------------------------------------------
# Flattening (Python, compile time)
# --------------------------------------------------------------------------------------

def _pad_box(lo, hi):
    mag = max(float(np.max(np.abs(lo))), float(np.max(np.abs(hi))), 1e-300)
    eps = 1e-9 * mag
    return lo - eps, hi + eps


def _weld(v):
    """(distinct positions, index of each vertex's position): rows sorted by
    lexsort and compared to their neighbour, which is several times faster than
    np.unique(axis=0) on a mesh's worth of vertices."""
    order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))
    sv = v[order]
    new = np.ones(len(v), bool)
    new[1:] = np.any(sv[1:] != sv[:-1], axis=1)
    inverse = np.empty(len(v), np.int64)
    inverse[order] = np.cumsum(new) - 1
    return sv[new], inverse


def check_closed_mesh(vertices, triangles, what):
    """Raises SceneError unless the mesh is closed, edge-manifold and consistently
    oriented (every edge in exactly two triangles, once in each direction).
    Vertices are welded by position first, so split-UV meshes pass. Returns
    +1 for outward (positive volume), -1 for inward orientation."""
    v = np.asarray(vertices, np.float64).reshape(-1, 3)
    t = np.asarray(triangles, np.int64).reshape(-1, 3)
    if t.shape[0] < 4:
        raise SceneError(f"{what}: a CSG operand mesh must be closed (it has only {t.shape[0]} triangles)")
    welded, weld = _weld(v)
    t = weld[t]
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e = e[e[:, 0] != e[:, 1]]
    # edges as one int64 key each: a 1-D unique sorts far faster than rows
    n = np.int64(max(len(welded), 1))
    _, cnt = np.unique(np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1]),
                       return_counts=True)
    bad = int(np.sum(cnt != 2))
    if bad:
        raise SceneError(f"{what}: a CSG operand mesh must be closed and manifold: {bad} edges "
                         f"are not shared by exactly two triangles")
    _, dcnt = np.unique(e[:, 0] * n + e[:, 1], return_counts=True)
    if np.any(dcnt != 1):
        raise SceneError(f"{what}: a CSG operand mesh must be consistently oriented "
                         f"({int(np.sum(dcnt != 1))} edges run the same way in both triangles)")
    # t now indexes the welded vertices. Taken about their centroid, so a mesh far
    # from the origin keeps the signed volume's precision.
    p = welded[t] - welded.mean(axis=0)
    vol = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() / 6.0
    return 1 if vol >= 0.0 else -1


def _arr(lst, shape, dt):
    """lst as a contiguous array of `shape` (-1: any length); empty lists give
    a zero-length array of that shape."""
    if len(lst):
        return np.ascontiguousarray(np.array(lst, dt).reshape(shape))
    shape = (shape,) if isinstance(shape, int) else shape
    return np.zeros(tuple(0 if s < 0 else s for s in shape), dt)


def _cat(lst, shape, dt):
    return np.ascontiguousarray(np.concatenate(lst).astype(dt)) if lst else np.zeros(shape, dt)


class _Flattener:
    """The node, leaf and mesh-BVH lists flatten_csg fills, root after root
    (ids are global over all roots), and their running counts."""

    def __init__(self, n_materials, mesh_uvs):
        self.n_materials = n_materials
        self.mesh_uvs = mesh_uvs
        self.node_op, self.node_l, self.node_r, self.node_rf, self.node_box = [], [], [], [], []
        self.leaf_kind, self.leaf_flip, self.leaf_xf, self.leaf_inv = [], [], [], []
        self.leaf_params, self.leaf_mat, self.leaf_tri0, self.leaf_ntri = [], [], [], []
        self.leaf_node0, self.leaf_name, self.leaf_src = [], [], []
        self.mtri, self.mtri_uv, self.mtri_mat = [], [], []
        self.mnode_box, self.mnode_a, self.mnode_cnt = [], [], []
        self.roots, self.root_names, self.root_leaves = [], [], []
        self.n_tri = 0
        self.n_mnode = 0
        self.max_need = 0
        self.max_depth = 0

    def add_root(self, root, where):
        """Flattens one solid; checks its tree fits the kernel's interval lists."""
        name = getattr(root, "name", "csg")
        what = f"CSG solid {name!r} in {where}"
        k0 = len(self.leaf_kind)
        if not isinstance(root, (CSGNode, Primitive, TriangleMesh)):
            raise SceneError(f"{what}: expected a CSGNode, got {type(root).__name__}")
        n, lo, hi, need, depth = self._visit(root, 0, 0, what)
        if need > MAX_LISTS:
            raise SceneError(f"{what}: tree needs {need} interval lists at once, "
                             f"the kernel has {MAX_LISTS}")
        self.max_need = max(self.max_need, need)
        self.max_depth = max(self.max_depth, depth)
        self.roots.append(n)
        self.root_names.append(name)
        self.root_leaves.append(list(range(k0, len(self.leaf_kind))))

    def _visit(self, obj, flip, depth, what):
        """Returns (node id, box lo, hi, Sethi–Ullman need, max depth)."""
        if depth > MAX_WORK - 8:
            raise SceneError(f"{what}: CSG tree deeper than {MAX_WORK - 8} levels")
        if obj is None:
            raise SceneError(f"{what}: missing CSG operand")
        if isinstance(obj, CSGNode):
            return self._operator(obj, flip, depth, what)
        if isinstance(obj, (Primitive, TriangleMesh)):
            k, lo, hi = self._leaf(obj, flip, f"{what} > {type(obj).__name__.lower()} "
                                              f"{getattr(obj, 'name', '')!r}")
            return self._add_node(LEAF, k, -1, 0, lo, hi), lo, hi, 1, 1
        raise SceneError(f"{what}: CSG operand must be a CSGNode, Primitive or closed "
                         f"TriangleMesh, got {type(obj).__name__}")

    def _operator(self, obj, flip, depth, what):
        """_visit of a CSGNode: both operands, then the node over them."""
        op = obj.op.lower() if isinstance(obj.op, str) else obj.op
        if op not in OP_IDS:
            raise SceneError(f"{what}: unknown CSG operation {obj.op!r} "
                             f"(expected one of {', '.join(OP_IDS)})")
        name = f"{what} > {obj.name!r}"
        if obj.left is None or obj.right is None:
            raise SceneError(f"CSG node {name}: missing "
                             f"{'left' if obj.left is None else 'right'} operand")
        l, llo, lhi, ln, ld = self._visit(obj.left, flip, depth + 1, name)
        r, rlo, rhi, rn, rd = self._visit(obj.right, flip ^ (1 if op == "difference" else 0),
                                          depth + 1, name)
        if op == "union":
            lo, hi = np.minimum(llo, rlo), np.maximum(lhi, rhi)
        elif op == "intersection":
            lo, hi = np.maximum(llo, rlo), np.minimum(lhi, rhi)
        else:
            lo, hi = llo, lhi
        need = max(ln, rn) if ln != rn else ln + 1
        n = self._add_node(OP_IDS[op], l, r, 1 if rn > ln else 0, lo, hi)
        return n, lo, hi, need, max(ld, rd) + 1

    def _add_node(self, op, left, right, rfirst, lo, hi):
        self.node_op.append(op)
        self.node_l.append(left)
        self.node_r.append(right)
        self.node_rf.append(rfirst)
        self.node_box.append(np.concatenate([lo, hi]))
        return len(self.node_op) - 1

    def _leaf(self, obj, flip, what):
        """Adds a primitive or mesh leaf; returns (leaf id, box lo, hi)."""
        k = len(self.leaf_kind)
        if isinstance(obj, Primitive):
            lo, hi = self._solid_primitive(obj, flip, what)
        else:
            lo, hi = self._closed_mesh(obj, flip, what)
        self.leaf_name.append(getattr(obj, "name", "leaf"))
        self.leaf_src.append(obj)
        return k, lo, hi

    def _add_leaf(self, kind, flip, xf, inv, params, material, n_triangles):
        self.leaf_kind.append(kind)
        self.leaf_flip.append(flip)
        self.leaf_xf.append(xf)
        self.leaf_inv.append(inv)
        self.leaf_params.append(params)
        self.leaf_mat.append(material)
        self.leaf_tri0.append(self.n_tri)
        self.leaf_ntri.append(n_triangles)
        self.leaf_node0.append(self.n_mnode)

    def _solid_primitive(self, obj, flip, what):
        kid, p4, xf, inv, mat = check_primitive(obj, what, self.n_materials)
        if kid not in SOLID_KINDS:
            raise SceneError(f"{what}: a {obj.kind} is an open surface and cannot be a CSG "
                             "operand (use a closed solid)")
        lb = prim_local_bounds(np.int32(kid), p4)
        c = np.array([[x, y, z] for x in (lb[0], lb[3]) for y in (lb[1], lb[4])
                      for z in (lb[2], lb[5])])
        w = c @ xf[:, :3].T + xf[:, 3]
        lo, hi = _pad_box(w.min(0), w.max(0))
        self._add_leaf(kid, flip, xf, inv, p4, mat, 0)
        return lo, hi

    def _mesh_triangles(self, obj, what):
        """(p (T,3,3), uv (T,3,2), materials (T,)) of a mesh leaf (see flatten_csg)."""
        if self.mesh_uvs is not None:
            return self.mesh_uvs(obj, what)
        v = np.asarray(obj.vertices, np.float64)
        p = v[np.asarray(obj.triangles, np.int64)]
        uv = np.zeros((p.shape[0], 3, 2))
        mats = np.full(p.shape[0], int(obj.material), np.int64)
        return p, uv, mats

    def _closed_mesh(self, obj, flip, what):
        """A closed mesh leaf: its triangles in the order of its own BVH, whose
        nodes join the shared mesh-node arrays (absolute ids)."""
        from .bvh import build_bvh
        sign = check_closed_mesh(obj.vertices, obj.triangles, what)
        p, uv, mats = self._mesh_triangles(obj, what)
        if p.shape[0] == 0:
            raise SceneError(f"{what}: mesh has no triangles")
        tlo = p.min(axis=1)
        thi = p.max(axis=1)
        bvh = build_bvh(tlo, thi)
        order = bvh.items.astype(np.int64)
        p, uv, mats = p[order], uv[order], np.asarray(mats)[order]
        a = bvh.node_a.astype(np.int64).copy()
        cnt = bvh.node_count.astype(np.int64)
        a[cnt == 0] += self.n_mnode
        a[cnt > 0] += self.n_tri
        self.mnode_box.append(np.concatenate([bvh.node_min.astype(np.float64),
                                              bvh.node_max.astype(np.float64)], axis=1))
        self.mnode_a.append(a)
        self.mnode_cnt.append(cnt)
        lo, hi = _pad_box(p.reshape(-1, 3).min(0), p.reshape(-1, 3).max(0))
        # an inward-oriented mesh flips like a subtracted operand
        self._add_leaf(MESH, flip ^ (1 if sign < 0 else 0), np.eye(4)[:3].copy(),
                       np.eye(4)[:3].copy(), np.array([float(sign), 0.0, 0.0, 0.0]),
                       int(mats[0]), p.shape[0])
        self.mtri.append(p.reshape(-1, 9))
        self.mtri_uv.append(uv)
        self.mtri_mat.append(mats.astype(np.int64))
        self.n_tri += p.shape[0]
        self.n_mnode += bvh.n_nodes
        return lo, hi

    def flat(self):
        """The lists as a CSGFlat of contiguous arrays."""
        L = len(self.leaf_kind)
        return CSGFlat(
            node_op=_arr(self.node_op, -1, np.int32), node_l=_arr(self.node_l, -1, np.int32),
            node_r=_arr(self.node_r, -1, np.int32), node_rfirst=_arr(self.node_rf, -1, np.int32),
            node_box=_arr(self.node_box, (-1, 6), np.float64),
            leaf_kind=_arr(self.leaf_kind, -1, np.int32),
            leaf_flip=_arr(self.leaf_flip, -1, np.int32),
            leaf_xf=_arr(self.leaf_xf, (L, 3, 4), np.float64),
            leaf_inv=_arr(self.leaf_inv, (L, 3, 4), np.float64),
            leaf_params=_arr(self.leaf_params, (L, 4), np.float64),
            leaf_material=_arr(self.leaf_mat, -1, np.int32),
            leaf_tri0=_arr(self.leaf_tri0, -1, np.int32),
            leaf_ntri=_arr(self.leaf_ntri, -1, np.int32),
            leaf_node0=_arr(self.leaf_node0, -1, np.int32),
            leaf_name=self.leaf_name, leaf_src=self.leaf_src,
            mtri=_cat(self.mtri, (0, 9), np.float64),
            mtri_uv=_cat(self.mtri_uv, (0, 3, 2), np.float64),
            mtri_material=_cat(self.mtri_mat, 0, np.int64),
            mnode_box=_cat(self.mnode_box, (0, 6), np.float64),
            mnode_a=_cat(self.mnode_a, 0, np.int32), mnode_cnt=_cat(self.mnode_cnt, 0, np.int32),
            roots=_arr(self.roots, -1, np.int32), root_names=self.root_names,
            root_leaves=self.root_leaves,
            info={"csg_solids": len(self.roots), "csg_nodes": len(self.node_op),
                  "csg_leaves": L, "csg_mesh_triangles": self.n_tri,
                  "csg_max_lists": self.max_need, "csg_max_depth": self.max_depth},
        )


def flatten_csg(roots, n_materials=0, owner="prototype", mesh_uvs=None):
    """Flattens CSGNode roots into a CSGFlat (node ids are global over all roots).

    An item of `roots` may be a (root, owner name) pair, for error messages.

    mesh_uvs(mesh, what) -> (p (T,3,3), uv (T,3,2), materials (T,)) prepares a
    mesh leaf's triangles (engine/geometry/assembly.py passes its mesh checker so CSG
    meshes get lightmap UVs like plain meshes); None: the raw triangles, zero UVs.
    """
    fl = _Flattener(n_materials, mesh_uvs)
    for root in roots:
        where = owner
        if isinstance(root, tuple):
            root, where = root
        fl.add_root(root, where)
    return fl.flat()


def leaf_vshapes(flat, vs0=0):
    """Virtual shape id of every leaf (mesh leaves: of their first triangle) and
    the total count, numbered from vs0 in leaf order."""
    n = np.where(flat.leaf_kind == MESH, flat.leaf_ntri, 1).astype(np.int64)
    first = vs0 + np.concatenate([[0], np.cumsum(n)[:-1]]).astype(np.int64)
    return first.astype(np.int32), int(n.sum())


def pack_blob(flat, vs0=0):
    """The flattened arrays as one float64 array (raw bits): blob header, int32
    section, float64 section. Virtual shapes are numbered from vs0."""
    vfirst, nv = leaf_vshapes(flat, vs0)
    vleaf = np.repeat(np.arange(flat.leaf_kind.shape[0], dtype=np.int32),
                      np.where(flat.leaf_kind == MESH, flat.leaf_ntri, 1))
    i32_parts = [(B_NODE_OP, flat.node_op), (B_NODE_L, flat.node_l), (B_NODE_R, flat.node_r),
                 (B_NODE_RFIRST, flat.node_rfirst), (B_LEAF_KIND, flat.leaf_kind),
                 (B_LEAF_FLIP, flat.leaf_flip), (B_LEAF_TRI0, flat.leaf_tri0),
                 (B_LEAF_NODE0, flat.leaf_node0), (B_LEAF_VSHAPE, vfirst),
                 (B_VSHAPE_LEAF, vleaf), (B_MNODE_A, flat.mnode_a), (B_MNODE_CNT, flat.mnode_cnt)]
    f64_parts = [(B_NODE_BOX, flat.node_box), (B_LEAF_INV, flat.leaf_inv),
                 (B_LEAF_PARAMS, flat.leaf_params), (B_MTRI, flat.mtri),
                 (B_MNODE_BOX, flat.mnode_box)]
    hdr = np.zeros(BLOB_HEADER, np.int64)
    hdr[B_NNODE] = flat.node_op.shape[0]
    hdr[B_NLEAF] = flat.leaf_kind.shape[0]
    hdr[B_VS0] = vs0
    hdr[B_NVSHAPE] = nv
    i32, n = [], 2 * BLOB_HEADER
    for key, a in i32_parts:
        hdr[key] = n
        i32.append(np.asarray(a, np.int32).reshape(-1))
        n += i32[-1].size
    if n % 2:
        i32.append(np.zeros(1, np.int32))
        n += 1
    f64, m = [], n // 2
    for key, a in f64_parts:
        hdr[key] = m
        f64.append(np.asarray(a, np.float64).reshape(-1))
        m += f64[-1].size
    blob = np.concatenate([hdr.view(np.float64), np.concatenate(i32).view(np.float64)]
                          + f64)
    return blob


def csg_table(roots, n_materials=0):
    """Stand-alone CSG table (for tests and tools): a minimal trace-style buffer
    holding only the blob, so the same kernels run on it as on a Geometry."""
    flat = flatten_csg(list(roots), n_materials)
    blob = pack_blob(flat, 0)
    hdr = np.zeros(32, np.int64)
    hdr[H_F64] = 32 * 8
    hdr[H_CSG] = 0
    buf = np.concatenate([hdr.view(np.uint8), blob.view(np.uint8)])
    return CSGTable(buf, flat)


def check_not_emissive(csg_info, materials):
    """Emitters are sampled over their whole surface, which would include the
    parts a CSG operation removed: emissive operands are refused by name."""
    flat = csg_info["flat"]
    em = np.asarray(materials.emission).max(axis=1) > 0.0
    for k in range(flat.leaf_kind.shape[0]):
        if flat.leaf_kind[k] == MESH:
            t0 = int(flat.leaf_tri0[k])
            mats = flat.mtri_material[t0:t0 + int(flat.leaf_ntri[k])]
        else:
            mats = flat.leaf_material[k:k + 1]
        if np.any(em[np.asarray(mats, np.int64)]):
            raise SceneError(f"CSG operand {flat.leaf_name[k]!r}: emissive CSG operands are not "
                             "supported (light would leave from the parts the solid removes)")
