"""Add > Photon CSG Primitive: exact analytic solids with a display mesh.

The object is tagged (csg_export.PRIMITIVE_PROP / PARAMS_PROP) so the exporter
hands the tracer the exact surface; the mesh only serves the viewport and
Blender's own Boolean modifier. It lives in the primitive's canonical local
frame (engine/geometry/primitives.py), so the object's transform is the primitive's
transform: size, position and orientation are object transforms, never baked
into the vertices.

Display mesh = each face's (u, v) chart sampled on a grid through
engine.geometry.primitives.prim_point, so at every vertex the position and the
`Lightmap` UV agree exactly with the engine's chart. The UV atlas matches the
engine's primitive lightmap layout (engine/lightmaps/lightmap.py): F faces give F tiles
side by side, tile f covers U in [f/F, (f+1)/F] and V in [0, 1], so
(U, V) = ((f + u) / F, v) and a baked lightmap image maps straight onto the
mesh. Vertices shared by two charts (seams, rims, the sphere's octahedral
fold) are welded, so the mesh is a closed 2-manifold that Boolean modifiers
accept; UVs stay per face corner, so every face keeps its own chart.
"""
import math

import bmesh
import bpy
import numpy as np
from bpy.props import EnumProperty, FloatProperty, FloatVectorProperty, IntProperty

from .. import messages
from ..export.csg import PARAMS_PROP, PRIMITIVE_PROP, SOLID_KINDS
from ..engine.geometry.primitives import KIND_IDS, N_FACES, prim_point
from ..engine.core.scene import SceneError
from .common import select_only

LIGHTMAP_UV = "Lightmap"
# Welding distance in the unit-size local frame: seam duplicates differ by ~1e-16,
# distinct grid vertices by > 1e-3 even at 512 segments.
WELD_DIST = 1e-7
# Edges between charts that meet at more than this angle (rims) stay sharp.
SHARP_ANGLE = math.radians(40.0)


def _grids(kind, segments):
    """Grid cells (nu, nv) per face for `segments` vertices around circular rims.

    Chosen so the charts' shared boundaries land on the same points (which the
    weld then merges): a concentric disk chart of m x m cells has 4m boundary
    points at angles k * 2pi / 4m, and the octahedral sphere chart of n x n cells
    has 2n points on its equator, so m = segments / 4 and n = segments / 2 meet
    the cylinder's segments side columns; m even puts the disk centre (cone
    apex) on a vertex.
    """
    s = max(8, int(math.ceil(segments / 8.0)) * 8)
    m = s // 4
    if kind == "sphere":
        return [(s // 2, s // 2)]
    if kind == "box":
        return [(1, 1)] * 6
    if kind == "cylinder":
        return [(s, 1), (m, m), (m, m)]
    if kind in ("cone", "paraboloid"):
        return [(m, m), (m, m)]
    if kind == "torus":
        return [(s, max(8, s // 2))]
    raise ValueError(f"unknown CSG primitive kind '{kind}'")


def _disk_chart(kind, face):
    # faces parameterised by the concentric map (engine/geometry/primitives.py)
    return (kind == "cylinder" and face > 0) or kind in ("cone", "paraboloid")


def display_mesh_data(kind, params=(), segments=64):
    """(vertices (V,3), polygons (list of vertex-index lists), corner UVs (C,2), face of each polygon).

    Corner UVs follow the polygons' corners in order. Vertices are not welded
    yet (each chart has its own grid).
    """
    kid = np.int32(KIND_IDS[kind])
    p4 = np.zeros(4)
    p4[:len(params)] = params
    n_faces = int(N_FACES[kid])
    verts, polys, uvs, face_of = [], [], [], []
    base = 0
    for f, (nu, nv) in enumerate(_grids(kind, segments)):
        u = np.arange(nu + 1) / nu
        v = np.arange(nv + 1) / nv
        uu, vv = np.meshgrid(u, v, indexing="ij")          # (nu+1, nv+1)
        pts = np.array([prim_point(kid, p4, np.int64(f), a, b)[:3]
                        for a, b in zip(uu.ravel(), vv.ravel())])
        verts.append(pts)
        uv = np.stack([(f + uu.ravel()) / n_faces, vv.ravel()], axis=-1)
        idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
        # The concentric map sends a square's corner onto the rim, so a corner cell has
        # three rim vertices; split it through the corner so no triangle lies flat in
        # the rim (on cone and paraboloid sides such a triangle would overlap the cap).
        corner_cells = {(0, 0): 0, (nu - 1, 0): 1, (nu - 1, nv - 1): 2, (0, nv - 1): 3} \
            if _disk_chart(kind, f) else {}
        for i in range(nu):
            for j in range(nv):
                # counter-clockwise in (u, v): dP/du x dP/dv is outward, so Blender's normals point out
                q = [idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]]
                k = corner_cells.get((i, j))
                cells = [q] if k is None else [[q[k], q[(k + 1) % 4], q[(k + 2) % 4]],
                                               [q[k], q[(k + 2) % 4], q[(k + 3) % 4]]]
                for c in cells:
                    polys.append([base + int(x) for x in c])
                    uvs.append(uv[c])
                    face_of.append(f)
        base += pts.shape[0]
    return np.concatenate(verts), polys, np.concatenate(uvs), np.asarray(face_of, np.int32)


def build_display_mesh(name, kind, params=(), segments=64):
    """A new closed mesh datablock for the primitive, with the `Lightmap` UV layer."""
    verts, polys, uvs, _ = display_mesh_data(kind, params, segments)
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts.tolist(), [], polys)
    layer = me.uv_layers.new(name=LIGHTMAP_UV)
    # from_pydata keeps the face and corner order, so corner UVs go in as given.
    layer.uv.foreach_set("vector", uvs.astype(np.float32).reshape(-1))
    bm = bmesh.new()
    bm.from_mesh(me)
    bmesh.ops.remove_doubles(bm, verts=bm.verts, dist=WELD_DIST)
    bm.to_mesh(me)
    bm.free()
    me.update()
    if kind != "box":
        me.shade_smooth()
        me.set_sharp_from_angle(angle=SHARP_ANGLE)
    return me


def tag_object(ob, kind, params=()):
    ob[PRIMITIVE_PROP] = kind
    ob[PARAMS_PROP] = [float(x) for x in params]


def new_primitive_object(kind, name=None, *, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0),
                         size=1.0, minor_radius=0.25, segments=64, collection=None, material=None):
    """Creates and links a tagged CSG primitive object; `size` is its uniform scale."""
    if kind not in SOLID_KINDS:
        raise SceneError(f"CSG primitive kind '{kind}': unknown (use one of {', '.join(SOLID_KINDS)})")
    params = (float(minor_radius),) if kind == "torus" else ()
    if kind == "torus" and not 0.0 < params[0] < 1.0:
        raise SceneError(f"torus minor radius {params[0]:g}: must lie in (0, 1), the major radius is 1")
    name = name or f"CSG {kind.capitalize()}"
    me = build_display_mesh(name, kind, params, segments)
    if material is not None:
        me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    tag_object(ob, kind, params)
    ob.location = location
    ob.rotation_euler = rotation
    ob.scale = (size, size, size)
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


class PHOTON_LIGHTMAPS_OT_csg_primitive_add(bpy.types.Operator):
    """Add an exact analytic solid for CSG (Boolean modifiers); the mesh is for display only"""
    bl_idname = "photon_lightmaps.csg_primitive_add"
    bl_label = "Photon CSG Primitive"
    bl_options = {"REGISTER", "UNDO"}

    kind: EnumProperty(
        name="Kind", default="sphere",
        items=[(k, k.capitalize(), f"Exact {k} (engine/geometry/primitives.py canonical {k})") for k in SOLID_KINDS])
    size: FloatProperty(
        name="Size", default=1.0, min=1e-4, soft_max=100.0, unit="LENGTH",
        description="Uniform object scale: the radius, or the half-extent of the box")
    minor_radius: FloatProperty(
        name="Minor Radius", default=0.25, min=0.01, max=0.99,
        description="Torus tube radius, relative to the major radius 1")
    segments: IntProperty(
        name="Segments", default=64, min=8, soft_max=512, step=8,
        description="Display-mesh vertices around each circular rim (rounded up to a multiple of 8); "
                    "the render uses the exact surface")
    location: FloatVectorProperty(name="Location", subtype="TRANSLATION", size=3)
    rotation: FloatVectorProperty(name="Rotation", subtype="EULER", size=3)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "kind")
        layout.prop(self, "size")
        if self.kind == "torus":
            layout.prop(self, "minor_radius")
        layout.prop(self, "segments")
        layout.prop(self, "location")
        layout.prop(self, "rotation")

    def invoke(self, context, event):
        self.location = context.scene.cursor.location
        return self.execute(context)

    def execute(self, context):
        try:
            ob = new_primitive_object(self.kind, location=tuple(self.location), rotation=tuple(self.rotation),
                                      size=self.size, minor_radius=self.minor_radius, segments=self.segments,
                                      collection=context.collection)
        except Exception as exc:  # noqa: BLE001  (reported to the user instead of a traceback)
            return messages.operator_failed(self, exc)
        select_only(context, ob)
        return {"FINISHED"}


classes = (PHOTON_LIGHTMAPS_OT_csg_primitive_add,)
