"""Compiles a plain-data `Scene` into the flat arrays the kernels traverse.

Every mesh triangle and every analytic primitive becomes a *shape* in
prototype space. Each prototype gets its own BVH (BLAS) over its shapes; all
BLAS nodes share one set of arrays with absolute indices. A second BVH (TLAS)
sits over the instances, each of which places a prototype in the world.

Within a prototype, shapes are renumbered into BVH leaf order, so the shapes
(and their triangle/primitive rows) a leaf touches are contiguous in memory
and `blas_items` is the identity, which the traversal relies on: a leaf's
item positions are its shape ids.

Besides the layout of docs/architecture.md the namedtuple carries the packed
traversal records of both BVHs (see engine/bvh.py `pack_bvh`).
"""
import time
from collections import namedtuple

import numpy as np

from .bvh import STACK_BUDGET, aligned_empty, build_bvh, pack_bvh
from .primitives import KIND_IDS, prim_local_bounds
from .scene import SceneError, _affine

Geometry = namedtuple("Geometry", [
    # shapes (prototype space)
    "shape_kind", "shape_index", "shape_material", "shape_surface",
    "shape_proto",                   # owning prototype of each shape
    "shape_ref",                     # traversal: triangle row, or -1 - primitive row
    "tri_p", "tri_uv",
    "prim_kind", "prim_params", "prim_xf", "prim_inv",
    # bottom level: all prototypes' nodes in one array set
    "blas_min", "blas_max", "blas_a", "blas_count", "blas_items",
    "blas_pf", "blas_pi",            # packed 4-wide records (float32 / int32 views of one buffer)
    "proto_root", "proto_slot",      # root node (blas_*) and root record (blas_pf) of prototype p
    "proto_n_surfaces",
    "proto_shape_start", "proto_shape_count",   # shapes of prototype p are contiguous
    # instances and top level
    "inst_proto", "inst_xf", "inst_inv", "inst_lm_base",
    "tlas_min", "tlas_max", "tlas_a", "tlas_count", "tlas_items",
    "tlas_pf", "tlas_pi",            # packed records; the root is record 0
])

# Stack words a two-level traversal may need: two int32 words per entry,
# at most STACK_BUDGET entries per level (guaranteed by bvh.pack_bvh).
STACK_WORDS = 2 * 2 * STACK_BUDGET


def _fail(what, msg):
    raise SceneError(f"{what}: {msg}")


def _inverse(a):
    inv = np.empty((3, 4))
    r = np.linalg.inv(a[:, :3])
    inv[:, :3] = r
    inv[:, 3] = -r @ a[:, 3]
    return inv


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


def _unwrap_uvs(vertices, triangles, what):
    # TODO(lightmap): the uv_atlas module is being written; until it exists
    # meshes without a lightmap UV layer get zero UVs here.
    try:
        from .uv_atlas import unwrap
    except ImportError:
        return np.zeros((triangles.shape[0], 3, 2))
    uv = np.asarray(unwrap(vertices, triangles), dtype=np.float64)
    if uv.shape != (triangles.shape[0], 3, 2):
        _fail(what, f"UV unwrap returned shape {uv.shape}")
    return uv


def _check_mesh(mesh, what, n_materials):
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        _fail(what, f"vertices must have shape (V, 3), got {v.shape}")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        _fail(what, f"vertex {int(np.argmax(bad))} is NaN or infinite ({int(bad.sum())} such vertices)")
    tri = np.asarray(mesh.triangles)
    if tri.size == 0:
        tri = tri.reshape(0, 3)
    if tri.ndim != 2 or tri.shape[1] != 3:
        _fail(what, f"triangles must have shape (T, 3), got {tri.shape}")
    if tri.dtype.kind not in "iu":
        if tri.dtype.kind != "f" or not np.all(np.isfinite(tri)) or np.any(tri != np.round(tri)):
            _fail(what, "triangle indices must be integers")
    tri = tri.astype(np.int64)
    if tri.size and (tri.min() < 0 or tri.max() >= v.shape[0]):
        k = int(np.argmax(((tri < 0) | (tri >= v.shape[0])).any(axis=1)))
        _fail(what, f"triangle {k} has vertex index out of range {tri[k].tolist()} "
                    f"(mesh has {v.shape[0]} vertices)")
    T = tri.shape[0]
    if mesh.material_ids is not None:
        mats = np.asarray(mesh.material_ids).reshape(-1)
        if mats.shape[0] != T:
            _fail(what, f"material_ids has {mats.shape[0]} entries for {T} triangles")
        mats = mats.astype(np.int64)
    else:
        mats = np.full(T, int(mesh.material), np.int64)
    if n_materials and T and (mats.min() < 0 or mats.max() >= n_materials):
        _fail(what, f"material index out of range (scene has {n_materials} materials)")
    uvs = None
    if mesh.uvs is not None:
        uvs = np.asarray(mesh.uvs, dtype=np.float64)
        if uvs.shape != (T, 3, 2):
            _fail(what, f"uvs must have shape ({T}, 3, 2), got {uvs.shape}")
        if not np.all(np.isfinite(uvs)):
            _fail(what, "uvs contain NaN or infinity")
    p = v[tri]                                   # (T, 3, 3)
    e1 = p[:, 1] - p[:, 0]
    e2 = p[:, 2] - p[:, 0]
    e3 = p[:, 2] - p[:, 1]
    cr = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest2 = np.maximum(np.maximum((e1 * e1).sum(1), (e2 * e2).sum(1)), (e3 * e3).sum(1))
    # zero area, or collinear within float64 rounding (|e1 x e2| ~ eps·|e|²)
    keep = cr > 1e-14 * longest2
    if uvs is None:
        uvs = _unwrap_uvs(v, tri[keep], what)
    else:
        uvs = uvs[keep]
    return p[keep], uvs, mats[keep], int(T - keep.sum())


def _check_primitive(prim, what, kind_ids, n_materials):
    kind = prim.kind.lower() if isinstance(prim.kind, str) else prim.kind
    if kind not in kind_ids:
        _fail(what, f"unknown primitive kind {prim.kind!r} (expected one of {', '.join(kind_ids)})")
    params = np.asarray(prim.params if prim.params is not None else (), dtype=np.float64).reshape(-1)
    if params.size > 4:
        _fail(what, f"at most 4 parameters, got {params.size}")
    if not np.all(np.isfinite(params)):
        _fail(what, "parameters contain NaN or infinity")
    p4 = np.zeros(4)
    p4[:params.size] = params
    if kind == "torus" and not (params.size >= 1 and 0.0 < p4[0] < 1.0):
        _fail(what, "a torus needs params=(minor_radius,) with 0 < minor_radius < 1")
    mat = int(prim.material)
    if n_materials and not (0 <= mat < n_materials):
        _fail(what, f"material index {mat} out of range (scene has {n_materials} materials)")
    xf = _affine(prim.transform, what)
    return kind_ids[kind], p4, xf, _inverse(xf), mat


def compile_geometry(scene):
    """Flattens scene.prototypes / scene.instances; returns (Geometry, info)."""
    t0 = time.perf_counter()
    n_materials = len(scene.materials)

    # per prototype, in BVH leaf order
    sh_kind, sh_index, sh_mat, sh_surf = [], [], [], []
    tri_p, tri_uv = [], []
    pr_kind, pr_params, pr_xf, pr_inv = [], [], [], []
    b_min, b_max, b_a, b_cnt = [], [], [], []
    proto_root, proto_n_surf, proto_depth = [], [], []
    proto_start, proto_count, sh_proto = [], [], []
    n_shapes = n_tris = n_prims = n_nodes = 0
    degenerate = {}
    surfaces = []

    for pi_, proto in enumerate(scene.prototypes):
        pname = f"prototype '{proto.name}'"
        # collect the prototype's shapes in input order
        k_kind, k_mat, k_surf, k_lo, k_hi = [], [], [], [], []
        k_tri, k_uv, k_prim = [], [], []
        surf = []
        for mi, mesh in enumerate(proto.meshes):
            what = f"mesh '{mesh.name}' in {pname}"
            p, uv, mats, dropped = _check_mesh(mesh, what, n_materials)
            if dropped:
                degenerate[what] = dropped
            slot = len(surf)
            surf.append(("mesh", mesh.name))
            T = p.shape[0]
            k_kind.append(np.zeros(T, np.int32))
            k_mat.append(mats.astype(np.int32))
            k_surf.append(np.full(T, slot, np.int32))
            k_lo.append(p.min(axis=1))
            k_hi.append(p.max(axis=1))
            k_tri.append(p)
            k_uv.append(uv)
        for prim in proto.primitives:
            what = f"primitive '{prim.name}' in {pname}"
            kid, params, xf, inv, mat = _check_primitive(prim, what, KIND_IDS, n_materials)
            lb = prim_local_bounds(np.int32(kid), params)
            lo, hi = _box_corners_through(np.array(lb[:3]), np.array(lb[3:]), xf)
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
                _fail(what, "bounds are not finite (check its parameters)")
            lo, hi = _pad(lo, hi)
            slot = len(surf)
            surf.append((prim.kind, prim.name))
            k_kind.append(np.array([kid], np.int32))
            k_mat.append(np.array([mat], np.int32))
            k_surf.append(np.array([slot], np.int32))
            k_lo.append(lo[None])
            k_hi.append(hi[None])
            k_prim.append((kid, params, xf, inv))
        surfaces.append(surf)

        kinds = np.concatenate(k_kind) if k_kind else np.zeros(0, np.int32)
        mats = np.concatenate(k_mat) if k_mat else np.zeros(0, np.int32)
        surfs = np.concatenate(k_surf) if k_surf else np.zeros(0, np.int32)
        lo = np.concatenate(k_lo) if k_lo else np.zeros((0, 3))
        hi = np.concatenate(k_hi) if k_hi else np.zeros((0, 3))
        tris = np.concatenate(k_tri) if k_tri else np.zeros((0, 3, 3))
        uvs = np.concatenate(k_uv) if k_uv else np.zeros((0, 3, 2))
        S = kinds.shape[0]
        # input-order row of each shape inside its kind's table
        is_tri = kinds == 0
        row = np.where(is_tri, np.cumsum(is_tri) - 1, np.cumsum(~is_tri) - 1)

        bvh = build_bvh(lo, hi)
        order = bvh.items.astype(np.int64)           # BVH leaf order of the shapes
        kinds_o = kinds[order]
        tri_rows = row[order][kinds_o == 0]
        prim_rows = row[order][kinds_o != 0]
        new_index = np.empty(S, np.int32)
        new_index[kinds_o == 0] = n_tris + np.arange(tri_rows.size)
        new_index[kinds_o != 0] = n_prims + np.arange(prim_rows.size)
        sh_kind.append(kinds_o)
        sh_index.append(new_index)
        sh_mat.append(mats[order])
        sh_surf.append(surfs[order])
        tri_p.append(tris[tri_rows])
        tri_uv.append(uvs[tri_rows])
        for r in prim_rows:
            kid, params, xf, inv = k_prim[r]
            pr_kind.append(kid)
            pr_params.append(params)
            pr_xf.append(xf)
            pr_inv.append(inv)
        n_tris += tri_rows.size
        n_prims += prim_rows.size

        a = bvh.node_a.copy()
        interior = bvh.node_count == 0
        if S > 0:
            a[interior] += n_nodes                    # child node index
            a[~interior] += n_shapes                  # position in blas_items
        b_min.append(bvh.node_min)
        b_max.append(bvh.node_max)
        b_a.append(a)
        b_cnt.append(bvh.node_count)
        proto_root.append(n_nodes)
        proto_n_surf.append(len(surf))
        proto_depth.append(bvh.depth)
        proto_start.append(n_shapes)
        proto_count.append(S)
        sh_proto.append(np.full(S, pi_, np.int32))
        n_nodes += bvh.n_nodes
        n_shapes += S

    cat = lambda lst, shape, dt: (np.ascontiguousarray(np.concatenate(lst).astype(dt))
                                  if lst else np.zeros(shape, dt))
    shape_kind = cat(sh_kind, 0, np.int32)
    shape_index = cat(sh_index, 0, np.int32)
    shape_material = cat(sh_mat, 0, np.int32)
    shape_surface = cat(sh_surf, 0, np.int32)
    shape_proto = cat(sh_proto, 0, np.int32)
    # one load tells the traversal both kind and row of a shape
    shape_ref = np.where(shape_kind == 0, shape_index, -1 - shape_index).astype(np.int32)
    tri_p_a = cat(tri_p, (0, 3, 3), np.float64)
    tri_uv_a = cat(tri_uv, (0, 3, 2), np.float64)
    prim_kind = np.array(pr_kind, np.int32).reshape(-1)
    prim_params = np.array(pr_params, np.float64).reshape(-1, 4)
    prim_xf = np.array(pr_xf, np.float64).reshape(-1, 3, 4)
    prim_inv = np.array(pr_inv, np.float64).reshape(-1, 3, 4)
    blas_min = cat(b_min, (0, 3), np.float32)
    blas_max = cat(b_max, (0, 3), np.float32)
    blas_a = cat(b_a, 0, np.int32)
    blas_count = cat(b_cnt, 0, np.int32)
    blas_items = np.arange(n_shapes, dtype=np.int32)
    proto_root_a = np.array(proto_root, np.int32).reshape(-1)
    proto_n_surfaces = np.array(proto_n_surf, np.int32).reshape(-1)

    # 4-wide traversal records, packed per prototype then concatenated
    pf_parts = []
    proto_slot = np.zeros(len(scene.prototypes), np.int32)
    n_rec = 0
    blas_need = 0
    for p in range(len(scene.prototypes)):
        r0 = proto_root[p]
        r1 = proto_root[p + 1] if p + 1 < len(proto_root) else n_nodes
        cnt = blas_count[r0:r1]
        a_local = blas_a[r0:r1].copy()
        a_local[cnt == 0] -= r0               # interior children: local node index
        pf, pi, m, need = pack_bvh(blas_min[r0:r1], blas_max[r0:r1], a_local, cnt)
        pi = pi.reshape(m, 32).copy()
        refs = pi[:, 24:28]
        refs[pi[:, 28:32] == 0] += n_rec      # child records become absolute
        pf_parts.append(pi.view(np.float32).reshape(-1))
        proto_slot[p] = n_rec
        n_rec += m
        blas_need = max(blas_need, need)
    blas_pf = aligned_empty(max(n_rec, 1) * 32, np.float32)
    blas_pf[:] = 0.0
    if pf_parts:
        blas_pf[:n_rec * 32] = np.concatenate(pf_parts)
    blas_pi = blas_pf.view(np.int32)

    # instances
    n_inst = len(scene.instances)
    inst_proto = np.zeros(n_inst, np.int32)
    inst_xf = np.zeros((n_inst, 3, 4))
    inst_inv = np.zeros((n_inst, 3, 4))
    inst_lm_base = np.full(n_inst, -1, np.int32)
    n_lightmaps = 0
    t_lo = np.zeros((n_inst, 3))
    t_hi = np.zeros((n_inst, 3))
    live = np.zeros(n_inst, bool)
    n_protos = len(scene.prototypes)
    for i, inst in enumerate(scene.instances):
        what = f"instance '{inst.name}'"
        p = inst.prototype
        if isinstance(p, (bool, np.bool_)) or not isinstance(p, (int, np.integer)) or not 0 <= p < n_protos:
            _fail(what, f"refers to prototype {p!r}, which does not exist (scene has {n_protos})")
        xf = _affine(inst.transform, what)
        inst_proto[i] = p
        inst_xf[i] = xf
        inst_inv[i] = _inverse(xf)
        if not np.all(np.isfinite(inst_inv[i])):
            _fail(what, "transform cannot be inverted")
        if inst.lightmap:
            inst_lm_base[i] = n_lightmaps
            n_lightmaps += int(proto_n_surfaces[p])
        r = proto_root[p]
        lo = blas_min[r].astype(np.float64)
        hi = blas_max[r].astype(np.float64)
        if np.all(lo <= hi):
            wlo, whi = _box_corners_through(lo, hi, xf)
            t_lo[i], t_hi[i] = _pad(wlo, whi)
            live[i] = True
    live_ids = np.nonzero(live)[0].astype(np.int32)
    tl = build_bvh(t_lo[live_ids], t_hi[live_ids])
    tlas_items = live_ids[tl.items] if live_ids.size else np.zeros(0, np.int32)
    tlas_pf, tlas_pi, _, tlas_need = pack_bvh(tl.node_min, tl.node_max, tl.node_a, tl.node_count)

    g = Geometry(
        shape_kind=shape_kind, shape_index=shape_index, shape_material=shape_material,
        shape_surface=shape_surface, shape_proto=shape_proto, shape_ref=shape_ref, tri_p=tri_p_a, tri_uv=tri_uv_a,
        prim_kind=prim_kind, prim_params=prim_params, prim_xf=prim_xf, prim_inv=prim_inv,
        blas_min=blas_min, blas_max=blas_max, blas_a=blas_a, blas_count=blas_count,
        blas_items=blas_items, blas_pf=blas_pf, blas_pi=blas_pi,
        proto_root=proto_root_a, proto_slot=proto_slot, proto_n_surfaces=proto_n_surfaces,
        proto_shape_start=np.array(proto_start, np.int32).reshape(-1),
        proto_shape_count=np.array(proto_count, np.int32).reshape(-1),
        inst_proto=inst_proto, inst_xf=inst_xf, inst_inv=inst_inv, inst_lm_base=inst_lm_base,
        tlas_min=tl.node_min, tlas_max=tl.node_max, tlas_a=tl.node_a, tlas_count=tl.node_count,
        tlas_items=np.ascontiguousarray(tlas_items, dtype=np.int32),
        tlas_pf=tlas_pf, tlas_pi=tlas_pi,
    )
    info = {
        "n_shapes": n_shapes,
        "n_triangles": n_tris,
        "n_primitives": n_prims,
        "n_degenerate": int(sum(degenerate.values())),
        "degenerate": degenerate,                 # {"mesh 'x' in prototype 'y'": dropped}
        "n_instances": n_inst,
        "n_lightmaps": n_lightmaps,
        "surfaces": surfaces,                     # per prototype: [(kind, name)] by slot
        "blas_nodes": n_nodes,
        "tlas_nodes": tl.n_nodes,
        "blas_depth": max(proto_depth) if proto_depth else 0,
        "tlas_depth": tl.depth,
        "stack_entries": tlas_need + blas_need,   # worst case of one traversal
        "build_seconds": time.perf_counter() - t0,
    }
    return g, info


def new_stack():
    """Traversal stack for one thread: reuse it for every ray of that thread."""
    return np.empty(STACK_WORDS, np.int32)
