"""Blender meshes -> engine TriangleMesh prototypes (one per mesh datablock and material assignment).

Lightmap UVs: the mesh UV layer named "Lightmap" when present and inside [0,1]²,
otherwise none (the core unwraps with xatlas); uv_layers.py makes that layer
for bakes. Texture UVs (`tex_uvs`): the active render UV map, which Image
Texture nodes read by default, unclamped.
"""
import numpy as np

from ..engine.core.scene import Prototype, TriangleMesh
from . import textures
from .context import LIGHTMAP_UV, PrototypeRecord
from .materials import material


def _slots(ob, mesh):
    slots = [s.material for s in ob.material_slots]
    return slots or list(mesh.materials) or [None]


def _slot_materials(ctx, ob, mesh):
    return tuple(material(ctx, m) for m in _slots(ob, mesh))


def prototype(ctx, ob, mesh):
    slot_ids = _slot_materials(ctx, ob, mesh)
    key = (mesh.as_pointer(), slot_ids)
    idx = ctx.prototype_index.get(key)
    if idx is not None:
        return idx
    tm = triangle_mesh(ctx, mesh, slot_ids, ob, slot_mats=_slots(ob, mesh))
    if tm is None:
        ctx.prototype_index[key] = -1
        return -1
    ctx.scene.prototypes.append(Prototype(name=mesh.name, meshes=[tm]))
    ctx.map.prototypes.append(PrototypeRecord(mesh.name, int(tm.triangles.shape[0]),
                                               "xatlas" if tm.uvs is None else LIGHTMAP_UV))
    idx = len(ctx.scene.prototypes) - 1
    ctx.prototype_index[key] = idx
    return idx


def triangle_mesh(ctx, mesh, slot_ids, ob, slot_mats=None):
    """The mesh as a TriangleMesh; slot_mats (Blender material per slot) queues the
    bakes of its node-driven material inputs (textures.py)."""
    mesh.calc_loop_triangles()
    tris = mesh.loop_triangles
    nt = len(tris)
    nv = len(mesh.vertices)
    if nt == 0 or nv == 0:
        return None
    pos = np.empty(nv * 3, np.float32)
    mesh.attributes["position"].data.foreach_get("vector", pos)
    vi = np.empty(nt * 3, np.int32)
    tris.foreach_get("vertices", vi)
    mi = np.empty(nt, np.int32)
    tris.foreach_get("material_index", mi)
    # Out-of-range indices render with the last slot in Blender.
    lut = np.asarray(slot_ids, dtype=np.int64)
    mat_ids = lut[np.clip(mi, 0, len(lut) - 1)]
    uvs = None
    loops = np.empty(nt * 3, np.int32)
    tris.foreach_get("loops", loops)
    layer = mesh.uv_layers.get(LIGHTMAP_UV)
    if layer is not None:
        uvs = textures.corner_uvs(layer, loops, nt)
        if not np.all(np.isfinite(uvs)) or uvs.min() < 0.0 or uvs.max() > 1.0:
            ctx.report("WARNING", f"mesh '{mesh.name}' (object '{ob.name}'): UV layer "
                                   f"'{LIGHTMAP_UV}' leaves [0,1]²; it is unwrapped automatically instead")
            uvs = None
    tex_name = textures.render_uv_name(mesh)
    tex_uvs = textures.corner_uvs(mesh.uv_layers[tex_name], loops, nt) if tex_name else None
    if tex_uvs is not None and not np.all(np.isfinite(tex_uvs)):
        tex_uvs = np.nan_to_num(tex_uvs, nan=0.0, posinf=0.0, neginf=0.0)
    tm = TriangleMesh(pos.reshape(nv, 3).astype(np.float64), vi.reshape(nt, 3).astype(np.int64),
                      material=int(mat_ids[0]), material_ids=mat_ids, uvs=uvs, name=mesh.name,
                      tex_uvs=tex_uvs)
    if slot_mats is not None:
        textures.capture(ctx, ob, mesh, tm, loops, list(zip(slot_ids, slot_mats)))
    return tm


def first_material(ctx, ob):
    slots = [sl.material for sl in ob.material_slots]
    if not slots and ob.type == "MESH":
        slots = list(ob.data.materials)
    return material(ctx, slots[0] if slots else None)


def leaf_mesh(ctx, mesh, ob):
    return triangle_mesh(ctx, mesh, (first_material(ctx, ob),), ob)

