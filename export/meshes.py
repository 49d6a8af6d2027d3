"""Blender meshes -> engine TriangleMesh prototypes (one per mesh datablock and material assignment).

Lightmap UVs: the mesh UV layer named "Lightmap" when present and inside [0,1]²,
otherwise none (the core unwraps with xatlas); uv_layers.py makes that layer
for bakes.
"""
import numpy as np

from ..engine.scene import Prototype, TriangleMesh
from .context import LIGHTMAP_UV, PrototypeRecord
from .materials import material


def _slot_materials(ctx, ob, mesh):
    slots = [s.material for s in ob.material_slots]
    if not slots:
        slots = list(mesh.materials)
    return tuple(material(ctx, m) for m in slots) or (material(ctx, None),)


def prototype(ctx, ob, mesh):
    slot_ids = _slot_materials(ctx, ob, mesh)
    key = (mesh.as_pointer(), slot_ids)
    idx = ctx.prototype_index.get(key)
    if idx is not None:
        return idx
    tm = triangle_mesh(ctx, mesh, slot_ids, ob)
    if tm is None:
        ctx.prototype_index[key] = -1
        return -1
    ctx.scene.prototypes.append(Prototype(name=mesh.name, meshes=[tm]))
    ctx.map.prototypes.append(PrototypeRecord(mesh.name, int(tm.triangles.shape[0]),
                                               "xatlas" if tm.uvs is None else LIGHTMAP_UV))
    idx = len(ctx.scene.prototypes) - 1
    ctx.prototype_index[key] = idx
    return idx


def triangle_mesh(ctx, mesh, slot_ids, ob):
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
    layer = mesh.uv_layers.get(LIGHTMAP_UV)
    if layer is not None:
        loops = np.empty(nt * 3, np.int32)
        tris.foreach_get("loops", loops)
        uv = np.empty(len(mesh.loops) * 2, np.float32)
        layer.uv.foreach_get("vector", uv)
        uvs = uv.reshape(-1, 2)[loops].reshape(nt, 3, 2).astype(np.float64)
        if not np.all(np.isfinite(uvs)) or uvs.min() < 0.0 or uvs.max() > 1.0:
            ctx.report("WARNING", f"mesh '{mesh.name}' (object '{ob.name}'): UV layer "
                                   f"'{LIGHTMAP_UV}' leaves [0,1]²; it is unwrapped automatically instead")
            uvs = None
    return TriangleMesh(pos.reshape(nv, 3).astype(np.float64), vi.reshape(nt, 3).astype(np.int64),
                        material=int(mat_ids[0]), material_ids=mat_ids, uvs=uvs, name=mesh.name)


def first_material(ctx, ob):
    slots = [sl.material for sl in ob.material_slots]
    if not slots and ob.type == "MESH":
        slots = list(ob.data.materials)
    return material(ctx, slots[0] if slots else None)


def leaf_mesh(ctx, mesh, ob):
    return triangle_mesh(ctx, mesh, (first_material(ctx, ob),), ob)

