"""The `Lightmap` UV layer of a Blender mesh: honoured when the user made it, else xatlas.

Photon lightmaps need a UV layout in which no two surface points share a
texel (engine/lightmaps/uv_atlas.py). A mesh that already has a UV layer named
``Lightmap`` is used exactly as it is: we never write to a user's layer. A
mesh without one gets a new layer from an xatlas unwrap of its loop
triangles; the user's layers, and which of them is active and used for
rendering, are left as they were.

An unwrap costs up to seconds, so the layer we made remembers what it was made
from in custom properties of the mesh: a hash of the vertex positions and the
topology, a digest of the UVs we wrote (so a layer the user has since edited
counts as theirs), and the smallest lightmap resolution at which its charts
stay apart. It is made again only when one of these says it is stale.
"""
import hashlib

import numpy as np

from .context import LIGHTMAP_UV as LAYER_NAME  # noqa: E402  (one name for the layer)
HASH_PROP = "photon_lightmaps_uv_hash"
DIGEST_PROP = "photon_lightmaps_uv_digest"
MIN_RES_PROP = "photon_lightmaps_uv_min_res"
# "fast" where xatlas failed on the mesh and the fast box-projection layout
# stands in: it is kept while the geometry is unchanged (xatlas would fail
# again), and its MIN_RES_PROP is the lightmap side it needs.
LAYOUT_PROP = "photon_lightmaps_uv_layout"
FAST = "fast"

# Result of ensure_lightmap_uv: what happened to the mesh's layer.
USER = "user"          # the user's own layer, untouched
CACHED = "cached"      # our layer, still up to date, untouched
CREATED = "created"    # a new layer was added
UPDATED = "updated"    # our stale layer was unwrapped again

# Bump when the layout of our layers changes meaning, so old ones are redone.
_VERSION = b"photon-lightmaps-uv-1"
# Corners of one loop farther apart than this (UV units) belong to different charts.
_UV_TOL = 1e-6


def _mesh_of(obj_or_mesh):
    import bpy
    data = getattr(obj_or_mesh, "original", obj_or_mesh)
    if isinstance(data, bpy.types.Object):
        if data.type != "MESH":
            raise TypeError(f"object {data.name!r} is a {data.type}, not a mesh")
        data = data.data
    if not isinstance(data, bpy.types.Mesh):
        raise TypeError(f"expected a mesh or mesh object, got {type(obj_or_mesh).__name__}")
    return data


def mesh_triangles(mesh):
    """(vertices (V,3) f64, triangle vertices (T,3), triangle loops (T,3), polygon (T,)) of a mesh."""
    mesh.calc_loop_triangles()
    n_v, n_t = len(mesh.vertices), len(mesh.loop_triangles)
    co = np.empty(n_v * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    tv = np.empty(n_t * 3, np.int32)
    tl = np.empty(n_t * 3, np.int32)
    tp = np.empty(n_t, np.int32)
    mesh.loop_triangles.foreach_get("vertices", tv)
    mesh.loop_triangles.foreach_get("loops", tl)
    mesh.loop_triangles.foreach_get("polygon_index", tp)
    return (co.reshape(-1, 3).astype(np.float64), tv.reshape(-1, 3).astype(np.int64),
            tl.reshape(-1, 3).astype(np.int64), tp.astype(np.int64))


def _mesh_raw(mesh):
    """Vertex positions (float32, flat), loop vertices, polygon loop starts and sizes."""
    co = np.empty(len(mesh.vertices) * 3, np.float32)
    mesh.vertices.foreach_get("co", co)
    lv = np.empty(len(mesh.loops), np.int32)
    mesh.loops.foreach_get("vertex_index", lv)
    ps = np.empty(len(mesh.polygons), np.int32)
    pt = np.empty(len(mesh.polygons), np.int32)
    mesh.polygons.foreach_get("loop_start", ps)
    mesh.polygons.foreach_get("loop_total", pt)
    return co, lv, ps, pt


def geometry_hash(mesh):
    """Hash of vertex positions and topology: what an unwrap depends on."""
    co, lv, ps, pt = _mesh_raw(mesh)
    h = hashlib.sha256(_VERSION)
    for a in (co, lv, ps, pt):
        h.update(np.int64(a.size).tobytes())
        h.update(a.tobytes())
    return h.hexdigest()


def read_uvs(layer):
    """Per-loop UVs (L, 2) float32 of a UV layer."""
    uv = np.empty(len(layer.uv) * 2, np.float32)
    layer.uv.foreach_get("vector", uv)
    return uv.reshape(-1, 2)


def uv_digest(uv):
    return hashlib.sha256(np.ascontiguousarray(uv, np.float32).tobytes()).hexdigest()


def layer_is_ours(mesh):
    """True when the mesh's Lightmap layer is one we made and nobody has edited since."""
    layer = mesh.uv_layers.get(LAYER_NAME)
    if layer is None or HASH_PROP not in mesh or DIGEST_PROP not in mesh:
        return False
    return mesh[DIGEST_PROP] == uv_digest(read_uvs(layer))


def _forget(mesh):
    for k in (HASH_PROP, DIGEST_PROP, MIN_RES_PROP, LAYOUT_PROP):
        if k in mesh:
            del mesh[k]


# --------------------------------------------------------------------------------------
# Unwrap: per-triangle-corner xatlas UVs -> one UV per loop
# --------------------------------------------------------------------------------------

def _inconsistent_polygons(uv, chart, loops, poly, n_loops):
    """Polygons whose triangles xatlas put in different charts (one UV per loop cannot say that)."""
    flat_loops = loops.reshape(-1)
    flat_uv = uv.reshape(-1, 2)
    per_loop = np.zeros((n_loops, 2))
    per_loop[flat_loops] = flat_uv
    dev = np.abs(per_loop[flat_loops] - flat_uv).max(axis=1).reshape(-1, 3).max(axis=1)
    bad = dev > _UV_TOL
    # Chart ids must agree within a polygon too (two charts may touch at a corner).
    first = np.full(int(poly.max()) + 1 if poly.size else 0, -2, np.int64)
    first[poly[::-1]] = chart[::-1]
    bad |= chart != first[poly]
    return np.unique(poly[bad])


def _planar_uvs(v, tri_v, rows):
    """Flattened corner coordinates (object units) of one polygon's triangles `rows`."""
    p = v[tri_v[rows]]                                   # (k, 3, 3)
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]).sum(axis=0)
    nl = np.linalg.norm(n)
    if not nl > 0.0:
        return np.zeros((len(rows), 3, 2))
    n /= nl
    # Any tangent works; the longest edge keeps the basis well conditioned.
    edges = (p[:, [1, 2, 0]] - p).reshape(-1, 3)
    e = edges[np.argmax(np.linalg.norm(edges, axis=1))]
    a = e - n * (e @ n)
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    return np.stack([p @ a, p @ b], axis=-1)


def compute_lightmap_uvs(mesh, resolution=None, padding=2, notes=None):
    """xatlas layout of a mesh as one UV per loop -> (uv (L, 2) float64, min_resolution,
    layout: "xatlas" or FAST).

    xatlas charts triangles, but a UV layer holds one UV per polygon corner, so
    a polygon whose triangles land in different charts cannot be written as
    they are. Such polygons (a few percent on organic meshes) become islands of
    their own, flattened onto their plane, and all islands are packed again.
    xatlas runs in a child process. Where it fails or crashes, the mesh gets the
    fast box-projection layout (engine/lightmaps/fast_layout.py), made for `resolution`
    or, where its charts and gaps need more, the min_resolution it returns; and
    `notes` (a list) gets a line saying so. Only where that cannot fit either is
    engine.lightmaps.uv_atlas.UnwrapError (a SceneError) raised, for the caller to report.
    """
    from ..engine.lightmaps import uv_atlas

    resolution = int(resolution) if resolution else uv_atlas.DEFAULT_RESOLUTION
    v, tri_v, tri_l, poly = mesh_triangles(mesh)
    n_loops = len(mesh.loops)
    if tri_v.shape[0] == 0:
        return np.zeros((n_loops, 2)), 1, "xatlas"
    try:
        res = uv_atlas.unwrap_atlas(v, tri_v, resolution=resolution, padding=padding)
    except uv_atlas.UnwrapError as exc:
        if not np.isfinite(v).all():
            raise                  # bad input, not xatlas: the user's to fix
        uv, side = _fast_layout(v, tri_v, poly, resolution, exc)
        if notes is not None:
            notes.append(f"{exc.reason} unwrapping {tri_v.shape[0]:,} triangles; its '{LAYER_NAME}' "
                         f"layer is a fast box-projection layout instead"
                         + (f", baked at {side}×{side} texels so its charts stay apart"
                            if side > resolution else ""))
        per_loop = np.zeros((n_loops, 2))
        per_loop[tri_l.reshape(-1)] = uv.reshape(-1, 2)
        return per_loop, side, FAST
    uv, min_res = res.uv, res.min_resolution
    bad = _inconsistent_polygons(uv, res.chart, tri_l, poly, n_loops)
    if bad.size:
        # Back to object units (charts keep their relative scale), detach the bad polygons.
        a3 = 0.5 * np.linalg.norm(np.cross(v[tri_v[:, 1]] - v[tri_v[:, 0]],
                                           v[tri_v[:, 2]] - v[tri_v[:, 0]]), axis=1)
        d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        a2 = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
        ok = (a3 > 0) & (a2 > 0)
        scale = np.sqrt(a2[ok].sum() / a3[ok].sum()) if ok.any() else 1.0
        corner = uv / scale
        island = res.chart.astype(np.int64).copy()
        next_id = int(island.max()) + 1
        order = np.argsort(poly, kind="stable")
        starts = np.searchsorted(poly[order], bad)
        ends = np.searchsorted(poly[order], bad, side="right")
        for s, e in zip(starts, ends):
            rows = order[s:e]
            corner[rows] = _planar_uvs(v, tri_v, rows)
            island[rows] = next_id
            next_id += 1
        uv, min_res = uv_atlas.pack_islands(v, tri_v, corner, island, resolution, padding)
    per_loop = np.zeros((n_loops, 2))
    per_loop[tri_l.reshape(-1)] = uv.reshape(-1, 2)
    return per_loop, int(min_res), "xatlas"


def _fast_layout(v, tri_v, poly, resolution, xatlas_error):
    """The fast layout of a mesh's triangles, polygons kept whole -> (per-triangle
    UVs (T, 3, 2), the lightmap side it is made for, >= resolution)."""
    from ..engine.lightmaps import fast_layout
    from ..engine.geometry.validation import nondegenerate
    keep = nondegenerate(v[tri_v])
    uv = np.zeros((tri_v.shape[0], 3, 2))
    try:
        lay = fast_layout.layout(v, tri_v[keep], resolution, groups=poly[keep])
    except fast_layout.LayoutError as e:
        from ..engine.lightmaps.uv_atlas import UnwrapError
        raise UnwrapError(f"{xatlas_error.reason}, and the fast layout does not fit either "
                          f"({e.reason})", tri_v.shape[0], detail=xatlas_error.detail) from None
    uv[keep] = lay.uv
    return uv, int(lay.resolution)


# --------------------------------------------------------------------------------------
# The public entry point
# --------------------------------------------------------------------------------------

def ensure_lightmap_uv(obj_or_mesh, *, resolution=None, force=False, notes=None):
    """Gives a mesh (or a mesh object's mesh) a `Lightmap` UV layer; returns what happened.

    resolution: lightmap texels per side the layout is for (charts stay apart
    at that size and above); None: engine.lightmaps.uv_atlas.DEFAULT_RESOLUTION.
    force: unwrap our own layer again even if it looks current. A layer named
    `Lightmap` that we did not make (or that was edited after we made it) is
    never modified, force or not. Returns USER, CACHED, CREATED or UPDATED.
    notes (a list) gets a line where xatlas failed and the fast layout stood in;
    required_resolution(mesh) then says the lightmap side that layout needs.
    Raises engine.lightmaps.uv_atlas.UnwrapError when no layout fits (the mesh is left as
    it was).
    """
    mesh = _mesh_of(obj_or_mesh)
    if mesh.is_editmode:
        raise RuntimeError(f"mesh {mesh.name!r} is in Edit Mode; leave it to make a lightmap UV layer")
    layer = mesh.uv_layers.get(LAYER_NAME)
    if layer is not None and not layer_is_ours(mesh):
        if HASH_PROP in mesh:
            _forget(mesh)  # the layer was edited or replaced: it is the user's now
        return USER
    if mesh.library is not None:
        raise RuntimeError(f"mesh {mesh.name!r} is linked from a library; cannot add a lightmap UV layer")
    ghash = geometry_hash(mesh)
    want_res = int(resolution) if resolution else None
    if not force and _current(mesh, ghash, want_res):
        return CACHED
    uv, min_res, how = compute_lightmap_uvs(mesh, want_res, notes=notes)

    status = UPDATED
    if layer is None:
        status = CREATED
        # Adding a layer must not change which UV map the user edits and renders with.
        active_index = mesh.uv_layers.active_index
        render = [l.name for l in mesh.uv_layers if l.active_render]
        had_layers = len(mesh.uv_layers) > 0
        layer = mesh.uv_layers.new(name=LAYER_NAME, do_init=False)
        if layer is None:
            raise RuntimeError(f"mesh {mesh.name!r}: cannot add a UV layer (limit reached?)")
        layer = mesh.uv_layers[LAYER_NAME]
        if had_layers:
            mesh.uv_layers.active_index = active_index
            for l in mesh.uv_layers:
                if l.name in render:
                    l.active_render = True
    layer.uv.foreach_set("vector", uv.astype(np.float32).reshape(-1))
    mesh.update()
    mesh[HASH_PROP] = ghash
    mesh[DIGEST_PROP] = uv_digest(read_uvs(mesh.uv_layers[LAYER_NAME]))
    mesh[MIN_RES_PROP] = int(min_res)
    if how == FAST:
        mesh[LAYOUT_PROP] = FAST
    elif LAYOUT_PROP in mesh:
        del mesh[LAYOUT_PROP]
    return status


def _current(mesh, ghash, want_res):
    """Our Lightmap layer is there, made from this geometry, and good for want_res texels."""
    return (mesh.uv_layers.get(LAYER_NAME) is not None and mesh.get(HASH_PROP) == ghash
            and (want_res is None or int(mesh.get(MIN_RES_PROP, 0)) <= want_res
                 or mesh.get(LAYOUT_PROP) == FAST))


def needs_unwrap(obj_or_mesh, resolution=None):
    """True when ensure_lightmap_uv would run xatlas on this mesh now (no layer, or
    our layer is stale); changes nothing. Meshes it cannot write (Edit Mode, a
    library) answer False: ensure_lightmap_uv refuses those by name."""
    mesh = _mesh_of(obj_or_mesh)
    if mesh.is_editmode or mesh.library is not None:
        return False
    if mesh.uv_layers.get(LAYER_NAME) is not None and not layer_is_ours(mesh):
        return False
    return not _current(mesh, geometry_hash(mesh), int(resolution) if resolution else None)


def required_resolution(obj_or_mesh):
    """The lightmap side our fast-layout `Lightmap` layer needs so that its charts
    stay apart, else 0 (xatlas layouts and user layers bake at any side)."""
    mesh = _mesh_of(obj_or_mesh)
    if mesh.get(LAYOUT_PROP) != FAST or not layer_is_ours(mesh):
        return 0
    return int(mesh.get(MIN_RES_PROP, 0))


# --------------------------------------------------------------------------------------
# Tagged CSG primitives: their Lightmap layer placed in a solid's atlas (bake.py)
# --------------------------------------------------------------------------------------

# [x0, y0, sx, sy] on the mesh: its Lightmap layer holds the chart layout mapped
# to (x0 + sx U, y0 + sy V), the block of its leaf in a CSG solid's atlas. With
# it a bake can always go back to the chart layout, so re-baking never shrinks
# the layer twice.
TILE_PROP = "photon_lightmaps_csg_tile"
# Largest distance (local units of the unit-size primitive) between a vertex and
# the chart point of its UV for the layer to count as the generated one: float32
# UVs in a small atlas block are off by ~1e-5, a user's edit by far more.
CHART_TOL = 1e-3
_UNIT = (0.0, 0.0, 1.0, 1.0)


def _mesh_arrays(mesh):
    co, lv, ps, pt = _mesh_raw(mesh)
    return co.reshape(-1, 3).astype(np.float64), lv, ps, pt


def primitive_chart_uvs(ob):
    """(chart-layout UVs (L, 2) float64, tile rect now applied, None) of a tagged CSG
    primitive's generated `Lightmap` layer, or (None, None, why not) for a layer that
    is not (or no longer) the generated chart layout, i.e. the user's.

    The test is geometric, so it needs no bookkeeping from when the mesh was made:
    every vertex must sit on the engine's chart point of its UV (after undoing
    the tile rect this add-on stored, if any).
    """
    from .csg import primitive_tag
    from ..engine.transport.csg_bake import chart_uv_error

    tag = primitive_tag(ob)
    if tag is None:
        return None, None, f"'{ob.name}' is not a tagged Photon CSG primitive"
    mesh = ob.data
    layer = mesh.uv_layers.get(LAYER_NAME)
    if layer is None:
        return None, None, f"'{ob.name}' has no '{LAYER_NAME}' UV layer"
    co, lv, ps, pt = _mesh_arrays(mesh)
    uv = read_uvs(layer).astype(np.float64)
    rects = []
    stored = mesh.get(TILE_PROP)
    if stored is not None and len(stored) == 4 and float(stored[2]) > 0 and float(stored[3]) > 0:
        rects.append(tuple(float(x) for x in stored))
    rects.append(_UNIT)
    for rect in rects:
        unit = (uv - np.array(rect[:2])) / np.array(rect[2:])
        if chart_uv_error(tag[0], tag[1], co, lv, unit, ps, pt) <= CHART_TOL:
            return unit, rect, None
    return None, None, (f"the '{LAYER_NAME}' UV layer of '{ob.name}' is not the generated chart "
                        "layout (edited or made by the user), so it is left as it is")


def set_primitive_tile(ob, unit_uv, applied, rect):
    """Writes chart-layout UVs mapped into `rect` (x0, y0, sx, sy) to the `Lightmap` layer
    and remembers the rect; the unit rect restores the plain chart layout.
    unit_uv, applied: what primitive_chart_uvs found. -> whether the layer changed."""
    mesh = ob.data
    rect = tuple(float(x) for x in rect)
    if tuple(applied) == rect:
        return False      # already there: leave the layer bit for bit as it is
    uv = np.asarray(unit_uv, np.float64) * np.array(rect[2:]) + np.array(rect[:2])
    mesh.uv_layers[LAYER_NAME].uv.foreach_set("vector", uv.astype(np.float32).reshape(-1))
    if rect == _UNIT:
        if TILE_PROP in mesh:
            del mesh[TILE_PROP]
    else:
        mesh[TILE_PROP] = list(rect)
    mesh.update()
    return True
