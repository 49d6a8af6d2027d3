"""Ray casting against brute force, instancing, watertightness and input validation."""
import math

import numba
import numpy as np
import pytest
from numba import njit

from photon_lightmaps.engine.geometry import raycast
from photon_lightmaps.engine.geometry.assembly import compile_geometry
from photon_lightmaps.engine.geometry.trace_layout import STACK_WORDS, new_stack, trace_arrays
from photon_lightmaps.engine.geometry.primitives import KIND_IDS, prim_hits, prim_surface
from photon_lightmaps.engine.core.scene import (Instance, Primitive, Prototype, Scene, SceneError, TriangleMesh,
                          compose, rotate, scale, translate)
from photon_lightmaps.engine.geometry.triangle import intersect_triangle


# ------------------------------------------------------------------ helpers

def icosphere(sub):
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t),
         (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    v = [np.array(x, float) / np.linalg.norm(x) for x in v]
    for _ in range(sub):
        cache, nf = {}, []

        def mid(a, b):
            k = (min(a, b), max(a, b))
            if k not in cache:
                m = v[a] + v[b]
                v.append(m / np.linalg.norm(m))
                cache[k] = len(v) - 1
            return cache[k]
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = nf
    return np.array(v), np.array(f)


def soup(n, seed, size=0.08, extent=1.0):
    """n random triangles (overlapping, all orientations) in a cube."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-extent, extent, (n, 1, 3))
    v = (c + rng.normal(0, size, (n, 3, 3))).reshape(-1, 3)
    return v, np.arange(3 * n).reshape(n, 3)


def random_rays(n, seed, extent=1.5):
    rng = np.random.default_rng(seed)
    o = rng.uniform(-extent, extent, (n, 3))
    d = rng.normal(size=(n, 3))
    d *= rng.uniform(0.2, 3.0, (n, 1)) / np.linalg.norm(d, axis=1, keepdims=True)  # not unit
    return o, d


def mesh_scene(v, f, **kw):
    sc = Scene()
    sc.add_object(TriangleMesh(v, f, uvs=np.zeros((len(f), 3, 2))), **kw)
    return sc


# not cached: numba does not notice when engine code they inline changes
@njit
def _shape_t(tri_p, shape_kind, shape_index, prim_kind, prim_params, prim_inv, inst_inv,
             i, s, ox, oy, oz, dx, dy, dz, tmin, tmax):
    """Nearest crossing of shape s of instance i in (tmin, tmax): same arithmetic
    as the traversal (rays mapped with the same affine formula)."""
    m = inst_inv[i]
    lox = m[0, 0] * ox + m[0, 1] * oy + m[0, 2] * oz + m[0, 3]
    loy = m[1, 0] * ox + m[1, 1] * oy + m[1, 2] * oz + m[1, 3]
    loz = m[2, 0] * ox + m[2, 1] * oy + m[2, 2] * oz + m[2, 3]
    ldx = m[0, 0] * dx + m[0, 1] * dy + m[0, 2] * dz
    ldy = m[1, 0] * dx + m[1, 1] * dy + m[1, 2] * dz
    ldz = m[2, 0] * dx + m[2, 1] * dy + m[2, 2] * dz
    j = shape_index[s]
    if shape_kind[s] == 0:
        p = tri_p[j]
        hit, t, b1, b2 = intersect_triangle(p[0, 0], p[0, 1], p[0, 2], p[1, 0], p[1, 1], p[1, 2],
                                            p[2, 0], p[2, 1], p[2, 2], lox, loy, loz,
                                            ldx, ldy, ldz, tmin, tmax)
        return t if hit else math.inf
    q = prim_inv[j]
    px = q[0, 0] * lox + q[0, 1] * loy + q[0, 2] * loz + q[0, 3]
    py = q[1, 0] * lox + q[1, 1] * loy + q[1, 2] * loz + q[1, 3]
    pz = q[2, 0] * lox + q[2, 1] * loy + q[2, 2] * loz + q[2, 3]
    qx = q[0, 0] * ldx + q[0, 1] * ldy + q[0, 2] * ldz
    qy = q[1, 0] * ldx + q[1, 1] * ldy + q[1, 2] * ldz
    qz = q[2, 0] * ldx + q[2, 1] * ldy + q[2, 2] * ldz
    n, t0, t1, t2, t3 = prim_hits(prim_kind[j], prim_params[j], px, py, pz, qx, qy, qz)
    for k, t in enumerate((t0, t1, t2, t3)):
        if k < n and t > tmin and t < tmax:
            return t
    return math.inf


@njit
def _brute(tri_p, shape_kind, shape_index, prim_kind, prim_params, prim_inv, inst_inv,
           inst_proto, proto_start, proto_count, o, d, tmin, tmax):
    n = o.shape[0]
    out = np.full(n, math.inf)
    for r in range(n):
        best = tmax[r]
        for i in range(inst_proto.shape[0]):
            p = inst_proto[i]
            for s in range(proto_start[p], proto_start[p] + proto_count[p]):
                t = _shape_t(tri_p, shape_kind, shape_index, prim_kind, prim_params, prim_inv,
                             inst_inv, i, s, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1],
                             d[r, 2], tmin, best)
                if t < best:
                    best = t
                    out[r] = t
    return out


def brute(g, o, d, tmax, tmin=0.0):
    tmax = np.broadcast_to(np.asarray(tmax, float), (o.shape[0],)).copy()
    return _brute(g.tri_p, g.shape_kind, g.shape_index, g.prim_kind, g.prim_params, g.prim_inv,
                  g.inst_inv, g.inst_proto, g.proto_shape_start, g.proto_shape_count, o, d,
                  tmin, tmax)


def shape_t(g, inst, shape, o, d, tmin=0.0, tmax=math.inf):
    return _shape_t(g.tri_p, g.shape_kind, g.shape_index, g.prim_kind, g.prim_params,
                    g.prim_inv, g.inst_inv, inst, shape, *o, *d, tmin, tmax)


@njit
def _closest_loop(g, o, d, tmin, tmax):
    """intersect_closest / occluded called from a kernel, one ray at a time."""
    n = o.shape[0]
    stack = np.empty(STACK_WORDS, np.int32)
    t = np.empty(n)
    ids = np.empty((n, 3), np.int32)
    surf = np.empty((n, 5))
    occ = np.empty(n, np.bool_)
    for r in range(n):
        hit, tt, inst, shape, face, u, v, nx, ny, nz = raycast.intersect_closest(
            g, stack, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2], tmin, tmax[r])
        t[r] = tt
        ids[r, 0] = inst
        ids[r, 1] = shape
        ids[r, 2] = face
        surf[r, 0] = u
        surf[r, 1] = v
        surf[r, 2] = nx
        surf[r, 3] = ny
        surf[r, 4] = nz
        occ[r] = raycast.occluded(g, stack, o[r, 0], o[r, 1], o[r, 2], d[r, 0], d[r, 1], d[r, 2],
                            tmin, tmax[r])
    return t, ids, surf, occ


def closest_loop(g, o, d, tmax=math.inf, tmin=0.0):
    tmax = np.broadcast_to(np.asarray(tmax, float), (o.shape[0],)).copy()
    return _closest_loop(g, o, d, tmin, tmax)


# -------------------------------------------------------------------- tests

@pytest.mark.parametrize("n_tri,n_rays", [(1_000, 4000), (10_000, 2000), (100_000, 600)])
def test_matches_brute_force(n_tri, n_rays):
    v, f = soup(n_tri, seed=n_tri, size=1.0 / n_tri ** (1 / 3))
    g, info = compile_geometry(mesh_scene(v, f))
    assert info["n_triangles"] == n_tri
    o, d = random_rays(n_rays, seed=1)
    rng = np.random.default_rng(2)
    tmax = np.where(rng.random(n_rays) < 0.3, rng.uniform(0.05, 1.0, n_rays), np.inf)
    ref = brute(g, o, d, tmax)
    t, ids, surf, occ = closest_loop(g, o, d, tmax)
    hit = ids[:, 1] >= 0
    assert hit.sum() > n_rays // 10                        # the test exercises hits
    assert np.array_equal(np.isfinite(ref), hit)
    assert np.array_equal(t[hit], ref[hit])                # same arithmetic: bit-identical
    for r in np.nonzero(hit)[0]:                           # reported shape gives that t
        assert shape_t(g, ids[r, 0], ids[r, 1], o[r], d[r]) == t[r]
    assert np.array_equal(occ, np.isfinite(ref))
    tb, ib, sb = raycast.trace_closest_batch(g, o, d, np.inf)
    ref_inf = brute(g, o, d, np.inf)
    assert np.array_equal(tb, ref_inf)
    assert np.array_equal(raycast.occluded_batch(g, o, d, 0.7), ref_inf < 0.7)


def _random_xf(rng, mirror=False):
    m = compose(translate(*rng.uniform(-4, 4, 3)), rotate("z", rng.uniform(0, 360)),
                rotate("x", rng.uniform(0, 360)), scale(*rng.uniform(0.3, 2.0, 3)))
    if mirror:
        m = compose(m, scale(-1, 1, 1))
    return m


def test_instances_match_flattened_mesh():
    rng = np.random.default_rng(7)
    v, f = icosphere(2)
    v = v * rng.uniform(0.8, 1.2, (len(v), 1))             # a closed, lumpy mesh
    xfs = [_random_xf(rng, mirror=(k % 5 == 0)) for k in range(40)]
    inst = Scene()
    inst.prototypes.append(Prototype("lump", meshes=[TriangleMesh(v, f, uvs=np.zeros((len(f), 3, 2)))]))
    inst.instances = [Instance(0, x, name=f"i{k}") for k, x in enumerate(xfs)]
    flat_v = np.concatenate([v @ x[:, :3].T + x[:, 3] for x in xfs])
    flat_f = np.concatenate([f + k * len(v) for k in range(len(xfs))])
    gi, _ = compile_geometry(inst)
    gf, _ = compile_geometry(mesh_scene(flat_v, flat_f))
    o, d = random_rays(3000, seed=3, extent=6.0)
    ti, ids, surf, occ = closest_loop(gi, o, d)
    tf, idf, surff, occf = closest_loop(gf, o, d)
    hit = ids[:, 1] >= 0
    assert hit.sum() > 500
    assert np.array_equal(hit, idf[:, 1] >= 0)
    assert np.allclose(ti[hit], tf[hit], rtol=1e-9, atol=0)
    assert np.array_equal(occ, occf)
    # the instance reported is the one whose copy was hit in the flat mesh
    # (flat shapes are in BVH order: find their instance through a vertex)
    vertex_id = {row.tobytes(): k for k, row in enumerate(flat_v)}
    first_vertex = gf.tri_p[gf.shape_index, 0]
    flat_shape_inst = np.array([vertex_id[row.tobytes()] // len(v) for row in first_vertex])
    assert np.array_equal(ids[hit, 0], flat_shape_inst[idf[hit, 1]])
    # normals follow the inverse-transpose: on mirrored copies the winding of
    # the flattened triangle is reversed, the normal is not
    det = np.array([np.linalg.det(x[:, :3]) for x in xfs])
    sgn = np.sign(det[ids[hit, 0]])
    assert np.allclose(surf[hit, 2:5], sgn[:, None] * surff[hit, 2:5], atol=1e-9)
    assert np.allclose(np.linalg.norm(surf[hit, 2:5], axis=1), 1.0)


def test_watertight_closed_mesh():
    v, f = icosphere(3)
    xf = compose(translate(0.3, -0.2, 0.1), rotate("y", 33.0), scale(1.7, 0.9, 1.3))
    sc = Scene()
    sc.add_object(TriangleMesh(v, f, uvs=np.zeros((len(f), 3, 2))), transform=xf)
    g, _ = compile_geometry(sc)
    world = v @ xf[:, :3].T + xf[:, 3]
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    rng = np.random.default_rng(5)
    fn = np.cross(world[f[:, 1]] - world[f[:, 0]], world[f[:, 2]] - world[f[:, 0]])
    vn = np.zeros_like(world)
    for k in range(3):
        np.add.at(vn, f[:, k], fn / np.linalg.norm(fn, axis=1, keepdims=True))
    vn /= np.linalg.norm(vn, axis=1, keepdims=True)
    targets = [(world, vn)]                                  # every vertex
    for s in [np.full((len(edges), 1), 0.5)] + [rng.random((len(edges), 1)) for _ in range(3)]:
        # the midpoint and random points of every edge
        n = (1 - s) * vn[edges[:, 0]] + s * vn[edges[:, 1]]
        targets.append(((1 - s) * world[edges[:, 0]] + s * world[edges[:, 1]], n))
    p = np.concatenate([a for a, _ in targets])
    n = np.concatenate([b for _, b in targets])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    centre = world.mean(axis=0)
    # from outside within ~30 degrees of the normal (a ray that only grazes a
    # silhouette edge at a rounded target point may legitimately miss), and
    # from the inside, where every direction must leave through the surface
    for k in range(3):
        w = n + rng.normal(0, 0.3, n.shape)
        o = p + rng.uniform(0.05, 4.0, (len(p), 1)) * w / np.linalg.norm(w, axis=1, keepdims=True)
        hit_dir = np.einsum("ij,ij->i", p - o, n) < -0.5 * np.linalg.norm(p - o, axis=1)
        o, q = o[hit_dir], p[hit_dir]
        assert len(o) > 0.8 * len(p)
        t, inst, shape = raycast.trace_closest_batch(g, o, (q - o) * 1.5)
        assert np.all(shape >= 0), f"{np.sum(shape < 0)} rays slipped through"
        assert np.all(raycast.occluded_batch(g, o, (q - o) * 1.5))
    o = np.tile(centre, (len(p), 1))
    t, inst, shape = raycast.trace_closest_batch(g, o, (p - o) * 1.5)
    assert np.all(shape >= 0), f"{np.sum(shape < 0)} rays slipped through"
    assert np.all(raycast.occluded_batch(g, o, (p - o) * 1.5))
    d = p - centre
    t, inst, shape = raycast.trace_closest_batch(g, np.tile(centre, (len(p), 1)), d)
    assert np.allclose(t, 1.0, atol=1e-9)                    # the target itself is the hit


def grid_box(n):
    """Closed mesh of the box [0, n]^3, each face an n x n grid of split
    squares (alternating diagonals), outward winding, integer vertices."""
    verts, tris, index = [], [], {}

    def vid(p):
        key = tuple(p)
        if key not in index:
            index[key] = len(verts)
            verts.append(key)
        return index[key]
    for axis in range(3):
        for side in (0, n):
            u, w = (axis + 1) % 3, (axis + 2) % 3
            for i in range(n):
                for j in range(n):
                    q = []
                    for a, b in ((i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)):
                        p = [0, 0, 0]
                        p[axis], p[u], p[w] = side, a, b
                        q.append(vid(p))
                    quad = [(q[0], q[1], q[2]), (q[0], q[2], q[3])] if (i + j) % 2 else \
                           [(q[0], q[1], q[3]), (q[1], q[2], q[3])]
                    for t in quad:
                        tris.append(t if side else t[::-1])
    return np.array(verts, float), np.array(tris)


def test_watertight_exact_edges():
    # axis-aligned rays through the vertices, edge midpoints and diagonal
    # midpoints of an integer grid: every edge function is exactly zero there,
    # so only a test that counts the boundary as inside keeps them all
    n = 4
    v, f = grid_box(n)
    g, _ = compile_geometry(mesh_scene(v, f))
    half = np.arange(0, 2 * n + 1) / 2.0
    a, b = np.meshgrid(half, half, indexing="ij")
    o, d = [], []
    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3
        for side, sign in ((-3.0, 1.0), (n + 3.0, -1.0)):
            p = np.zeros((a.size, 3))
            p[:, axis] = side
            p[:, u] = a.ravel()
            p[:, w] = b.ravel()
            dd = np.zeros(3)
            dd[axis] = sign
            o.append(p)
            d.append(np.tile(dd, (a.size, 1)))
    o, d = np.concatenate(o), np.concatenate(d)
    t, inst, shape = raycast.trace_closest_batch(g, o, d)
    assert np.all(shape >= 0), f"{np.sum(shape < 0)} rays slipped through"
    assert np.array_equal(t, np.full(len(o), 3.0))
    assert np.all(raycast.occluded_batch(g, o, d))
    # and from the inside through the same points
    c = np.full((len(o), 3), n / 2.0)
    q = o + 3.0 * d
    t, inst, shape = raycast.trace_closest_batch(g, c, q - c)
    assert np.all(shape >= 0) and np.allclose(t, 1.0, rtol=1e-15)


def test_degenerate_triangles_dropped_and_counted():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [1e-9, 0, 0]], float)
    f = np.array([[0, 1, 2],        # fine
                  [0, 1, 3],        # collinear
                  [0, 0, 2],        # repeated index
                  [1, 2, 1],        # repeated index
                  [0, 4, 1],        # collinear, tiny
                  [2, 1, 0]])       # fine (reversed)
    sc = Scene()
    sc.add_object(TriangleMesh(v, f, name="flaky"))
    g, info = compile_geometry(sc)
    assert info["n_degenerate"] == 4 and info["n_triangles"] == 2
    (key, n), = info["degenerate"].items()
    assert "flaky" in key and n == 4
    assert g.tri_p.shape == (2, 3, 3) and g.tri_uv.shape == (2, 3, 2)
    t, inst, shape = raycast.trace_closest_batch(g, [[0.2, 0.2, 1.0]], [[0, 0, -1.0]])
    assert t[0] == 1.0


def test_empty_scenes_miss():
    o, d = random_rays(100, seed=9)
    empty_proto = Scene()
    empty_proto.prototypes.append(Prototype("nothing"))
    empty_proto.prototypes.append(Prototype("hollow", meshes=[
        TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), int))]))
    empty_proto.instances = [Instance(0), Instance(1), Instance(1, translate(1, 2, 3))]
    for sc in (Scene(), empty_proto):
        g, info = compile_geometry(sc)
        assert info["n_shapes"] == 0
        t, inst, shape = raycast.trace_closest_batch(g, o, d)
        assert np.all(shape == -1) and np.all(inst == -1) and np.all(np.isinf(t))
        assert not raycast.occluded_batch(g, o, d).any()
        hit = raycast.intersect_closest(g, new_stack(), 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, math.inf)
        assert not hit[0] and hit[2] == -1 and hit[3] == -1
    # running sum of surfaces: a mesh without triangles has none (no lightmap id to skip)
    assert compile_geometry(empty_proto)[0].inst_lm_base.tolist() == [0, 0, 0]
    assert compile_geometry(empty_proto)[0].proto_n_surfaces.tolist() == [0, 0]


def _one(mesh=None, prim=None, xf=None, proto=0, n_protos=1):
    sc = Scene()
    for _ in range(n_protos):
        sc.prototypes.append(Prototype("p", meshes=[mesh] if mesh else [],
                                       primitives=[prim] if prim else []))
    sc.instances.append(Instance(proto, np.eye(4)[:3] if xf is None else xf, name="inst7"))
    return sc


@pytest.mark.parametrize("case,needle", [
    ("nan_vertex", "badmesh"), ("index", "badmesh"), ("float_index", "badmesh"),
    ("nan_instance", "inst7"), ("singular_instance", "inst7"), ("missing_proto", "inst7"),
    ("singular_primitive", "badprim"), ("nan_primitive", "badprim"),
    ("unknown_kind", "badprim"), ("torus_param", "badprim")])
def test_bad_input_raises(case, needle):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    f = np.array([[0, 1, 2]])
    sc = {
        "nan_vertex": lambda: _one(TriangleMesh(np.where(np.eye(3) > 0, np.nan, v), f, name="badmesh")),
        "index": lambda: _one(TriangleMesh(v, np.array([[0, 1, 3]]), name="badmesh")),
        "float_index": lambda: _one(TriangleMesh(v, np.array([[0, 1, 1.5]]), name="badmesh")),
        "nan_instance": lambda: _one(TriangleMesh(v, f), xf=np.full((3, 4), np.nan)),
        "singular_instance": lambda: _one(TriangleMesh(v, f), xf=scale(1, 0, 1)),
        "missing_proto": lambda: _one(TriangleMesh(v, f), proto=3),
        "singular_primitive": lambda: _one(prim=Primitive("sphere", scale(1, 1, 0), name="badprim")),
        "nan_primitive": lambda: _one(prim=Primitive("box", np.full((4, 4), np.nan), name="badprim")),
        "unknown_kind": lambda: _one(prim=Primitive("teapot", name="badprim")),
        "torus_param": lambda: _one(prim=Primitive("torus", params=(1.5,), name="badprim")),
    }[case]()
    with pytest.raises(SceneError, match=needle):
        compile_geometry(sc)


def _prim_scene(rng):
    prims = []
    for k, kind in enumerate(KIND_IDS):
        params = {"torus": (0.3,), "frustum": (0.4,)}.get(kind, ())
        xf = compose(translate(*rng.uniform(-2, 2, 3)), rotate("x", rng.uniform(0, 360)),
                     rotate("z", rng.uniform(0, 360)), scale(*rng.uniform(0.3, 0.9, 3)))
        prims.append(Primitive(kind, xf, params=params, name=f"{kind}{k}"))
    v, f = soup(40, seed=11, size=0.3, extent=2.0)
    mesh = TriangleMesh(v, f, uvs=np.zeros((len(f), 3, 2)), name="bits")
    sc = Scene()
    sc.prototypes.append(Prototype("mix", meshes=[mesh], primitives=prims))
    sc.prototypes.append(Prototype("solo", primitives=[Primitive("sphere", name="ball")]))
    for k in range(6):
        sc.instances.append(Instance(k % 2, _random_xf(rng, mirror=(k == 3)), name=f"m{k}"))
    return sc


def test_primitives_match_brute_force():
    rng = np.random.default_rng(12)
    g, info = compile_geometry(_prim_scene(rng))
    assert info["n_primitives"] == len(KIND_IDS) + 1 and info["n_triangles"] == 40
    o, d = random_rays(4000, seed=13, extent=6.0)
    tmax = np.full(len(o), np.inf)
    ref = brute(g, o, d, tmax)
    t, ids, surf, occ = closest_loop(g, o, d, tmax)
    hit = ids[:, 1] >= 0
    prim_hit = hit & (g.shape_kind[np.maximum(ids[:, 1], 0)] != 0)
    assert prim_hit.sum() > 200
    assert np.array_equal(np.isfinite(ref), hit)
    assert np.array_equal(t[hit], ref[hit])
    assert np.array_equal(occ, hit)
    for r in np.nonzero(prim_hit)[0]:
        i, s = ids[r, 0], ids[r, 1]
        assert shape_t(g, i, s, o[r], d[r]) == t[r]
        # chart and outward normal of the local hit point, carried to world
        j = g.shape_index[s]
        pi_ = np.vstack([g.inst_inv[i], [0, 0, 0, 1]])
        pp = np.vstack([g.prim_inv[j], [0, 0, 0, 1]])
        local = (pp @ pi_ @ np.append(o[r] + t[r] * d[r], 1.0))[:3]
        face, u, v, nx, ny, nz = prim_surface(g.prim_kind[j], g.prim_params[j], *local)
        assert ids[r, 2] == face
        assert np.allclose(surf[r, :2], (u, v), atol=1e-6)
        # inverse-transpose of M = (pp @ pi_)^-1 is (pp @ pi_)^T
        n_world = (pp @ pi_)[:3, :3].T @ np.array([nx, ny, nz])
        assert np.allclose(surf[r, 2:5], n_world / np.linalg.norm(n_world), atol=1e-6)


def test_interval_is_open():
    sc = Scene()
    sc.add_object(Primitive("sphere", name="ball"))
    g, _ = compile_geometry(sc)
    st = new_stack()
    hit = raycast.intersect_closest(g, st, 0.0, 0.0, -3.0, 0.0, 0.0, 2.0, 0.0, math.inf)
    assert hit[0] and hit[1] == 1.0 and np.allclose(hit[7:], (0, 0, -1))
    again = raycast.intersect_closest(g, st, 0.0, 0.0, -3.0, 0.0, 0.0, 2.0, 1.0, math.inf)
    assert again[0] and again[1] == 2.0 and np.allclose(again[7:], (0, 0, 1))   # exit point
    assert not raycast.intersect_closest(g, st, 0.0, 0.0, -3.0, 0.0, 0.0, 2.0, 0.0, 1.0)[0]
    assert not raycast.occluded(g, st, 0.0, 0.0, -3.0, 0.0, 0.0, 2.0, 0.0, 1.0)
    assert raycast.occluded(g, st, 0.0, 0.0, -3.0, 0.0, 0.0, 2.0, 0.0, 1.0 + 1e-12)


def test_threads_agree():
    v, f = soup(20_000, seed=4, size=0.02)
    g, _ = compile_geometry(mesh_scene(v, f))
    o, d = random_rays(20_000, seed=6)
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        a = raycast.trace_closest_batch(g, o, d)
        oa = raycast.occluded_batch(g, o, d, 0.5)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        b = raycast.trace_closest_batch(g, o, d)
        ob = raycast.occluded_batch(g, o, d, 0.5)
    finally:
        numba.set_num_threads(old)
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    assert np.array_equal(oa, ob)


def test_packets_cover_every_triangle_once():
    g, _ = compile_geometry(_prim_scene(np.random.default_rng(1)))
    ta = trace_arrays(g)
    lanes = ta["lane_shape"]
    tri_shapes = np.nonzero(g.shape_kind == 0)[0]
    assert np.array_equal(np.sort(lanes[lanes >= 0]), tri_shapes)
    codes = ta["shape_ref"][tri_shapes]
    assert np.array_equal(lanes[codes], tri_shapes)
    tri4 = ta["tri4"]
    for s in tri_shapes:                                    # packets hold the exact vertices
        pk, q = divmod(ta["shape_ref"][s], 4)
        assert np.array_equal(tri4[pk, :, :, q], g.tri_p[g.shape_index[s]])
    prims = np.nonzero(g.shape_kind != 0)[0]
    assert np.array_equal(-1 - ta["shape_ref"][prims], g.shape_index[prims])
