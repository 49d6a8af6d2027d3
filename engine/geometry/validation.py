"""Checks of scene geometry before it enters a kernel: every mesh, organ and
L-system graph is refused by name, with what to do, where a kernel could not
trace it (NaN or out-of-range vertices, bad indices, shapes, materials,
coordinates beyond the tracer's range); degenerate triangles are dropped."""
import numpy as np

from ..core.scene import SceneError


# World coordinates beyond this lose the float32 BVH bounds and the relative ray
# offsets (1e-7 · |p|) their meaning; such input is refused by name.
MAX_COORDINATE = 1e12


def fail(what, msg):
    raise SceneError(f"{what}: {msg}")


def nondegenerate(p):
    """bool[T]: triangles (T, 3, 3) with area, i.e. not collinear within float64
    rounding (|e1 x e2| ~ eps·|e|² there). Degenerate ones are dropped from the
    BVH and the lightmaps: they have no normal and no texel area."""
    e1 = p[:, 1] - p[:, 0]
    e2 = p[:, 2] - p[:, 0]
    e3 = p[:, 2] - p[:, 1]
    cr = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest2 = np.maximum(np.maximum((e1 * e1).sum(1), (e2 * e2).sum(1)), (e3 * e3).sum(1))
    return cr > 1e-14 * longest2


def check_mesh_arrays(mesh, what, n_materials):
    """Validated (vertices float64[V,3], triangles int64[T,3], materials int64[T]) of a
    TriangleMesh; raises SceneError naming `what` for NaNs, bad shapes or indices."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3:
        fail(what, f"vertices must have shape (V, 3), got {v.shape}")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        n = int(bad.sum())
        fail(what, f"vertex {int(np.argmax(bad))} is NaN or infinite"
                    + (f" ({n:,} such vertices)" if n > 1 else "")
                    + "; move it to a finite position or delete it")
    if v.size and np.abs(v).max() > MAX_COORDINATE:
        fail(what, f"a vertex lies {np.abs(v).max():.3g} m from the origin, beyond the tracer's "
                    f"range of {MAX_COORDINATE:.0e} m; scale the object down")
    tri = np.asarray(mesh.triangles)
    if tri.size == 0:
        tri = tri.reshape(0, 3)
    if tri.ndim != 2 or tri.shape[1] != 3:
        fail(what, f"triangles must have shape (T, 3), got {tri.shape}")
    if tri.dtype.kind not in "iu":
        if tri.dtype.kind != "f" or not np.all(np.isfinite(tri)) or np.any(tri != np.round(tri)):
            fail(what, "triangle indices must be integers")
    tri = tri.astype(np.int64)
    if tri.size and (tri.min() < 0 or tri.max() >= v.shape[0]):
        k = int(np.argmax(((tri < 0) | (tri >= v.shape[0])).any(axis=1)))
        fail(what, f"triangle {k} has vertex index out of range {tri[k].tolist()} "
                    f"(mesh has {v.shape[0]} vertices)")
    T = tri.shape[0]
    if mesh.material_ids is not None:
        mats = np.asarray(mesh.material_ids).reshape(-1)
        if mats.shape[0] != T:
            fail(what, f"material_ids has {mats.shape[0]} entries for {T} triangles")
        mats = mats.astype(np.int64)
    else:
        mats = np.full(T, int(mesh.material), np.int64)
    if n_materials and T and (mats.min() < 0 or mats.max() >= n_materials):
        fail(what, f"material index out of range (scene has {n_materials} materials)")
    return v, tri, mats


def check_mesh(mesh, what, n_materials, notes=None):
    """(triangles (T',3,3), uvs (T',3,2), materials (T',), dropped, texture uvs
    (T',3,2)) of a mesh's non-degenerate triangles (texture UVs unclamped, zeros
    when the mesh has none). A mesh without UVs gets zero UVs here: compile.py
    unwraps the meshes whose lightmaps are used before geometry is built.
    notes[what] counts triangles whose given UVs left [0,1]² (clamped)."""
    v, tri, mats = check_mesh_arrays(mesh, what, n_materials)
    T = tri.shape[0]
    if mesh.uvs is None:
        uvs = np.zeros((T, 3, 2))
    else:
        uvs = np.asarray(mesh.uvs, dtype=np.float64)
        if uvs.shape != (T, 3, 2):
            fail(what, f"uvs must have shape ({T}, 3, 2), got {uvs.shape}")
        if not np.all(np.isfinite(uvs)):
            fail(what, "uvs contain NaN or infinity")
        # A lightmap atlas is [0,1]²: outside it texel lookups would clamp to
        # the border while the area went elsewhere; clamping keeps both together.
        out = ((uvs < 0.0) | (uvs > 1.0)).any(axis=(1, 2))
        if out.any():
            uvs = np.clip(uvs, 0.0, 1.0)
            if notes is not None:
                notes[what] = int(out.sum())
    tex_uvs = getattr(mesh, "tex_uvs", None)
    if tex_uvs is None:
        tex_uvs = np.zeros((T, 3, 2))
    else:
        tex_uvs = np.asarray(tex_uvs, dtype=np.float64)
        if tex_uvs.shape != (T, 3, 2):
            fail(what, f"tex_uvs must have shape ({T}, 3, 2), got {tex_uvs.shape}")
        if not np.all(np.isfinite(tex_uvs)):
            fail(what, "tex_uvs contain NaN or infinity")
    p = v[tri]                                   # (T, 3, 3)
    keep = nondegenerate(p)
    return p[keep], uvs[keep], mats[keep], int(T - keep.sum()), tex_uvs[keep]


def check_organs(ls, what, n_materials):
    """The L-system's organ meshes, validated: name -> mesh with finite vertices,
    triangles in range and some area (a mesh without any is left out, with the
    organ drawn as nothing, as for a name without a mesh)."""
    from types import SimpleNamespace
    out = {}
    for name, mesh in dict(ls.organs or {}).items():
        w = f"{what}, organ '{name}'"
        v, tri, mats = check_mesh_arrays(mesh, w, n_materials)
        if tri.shape[0] == 0:
            continue
        q = v[tri]
        area = 0.5 * np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1)
        keep = area > 0.0
        if not keep.any():
            fail(w, "has no triangle with area; give the organ a surface")
        out[str(name)] = SimpleNamespace(vertices=v, triangles=tri[keep], material=int(mats[0]))
    return out


def check_graph(graph, what):
    """A graph the kernels can trace: finite tables, and a box inside MAX_COORDINATE
    (1.24a at 60 steps is 1e41 m tall: float32 boxes and ray offsets lose all meaning)."""
    lo, hi = graph.bounds()
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        fail(what, "has no finite extent (nothing drawn, or lengths overflow); check its parameters")
    if max(np.abs(lo).max(), np.abs(hi).max()) > MAX_COORDINATE:
        fail(what, f"reaches {max(np.abs(lo).max(), np.abs(hi).max()):.3g} m from its origin (at most "
                    f"{MAX_COORDINATE:g}); use fewer steps or shorter segments")
    a = graph.arrays()
    # (node boxes may be empty, +-inf, for nodes that draw nothing: the rays skip them)
    for name in ("child_inv", "child_rot", "child_box", "prim_inv", "prim_params", "alt_cum",
                 "item_inv"):
        if not np.all(np.isfinite(getattr(a, name))):
            fail(what, f"its scene graph has non-finite {name.replace('_', ' ')}; check its parameters")
