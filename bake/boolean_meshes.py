"""Booleans of plain meshes, baked as Blender's own Boolean result.

A solid whose operands are all plain meshes (no tagged Photon CSG primitive)
is a polyhedron, and Blender's Exact Boolean result is exactly its surface:
nothing is tessellated. So the bake exports that result as a mesh
(export_scene's `mesh_results`) and bakes it like any mesh; its texels lie
on the surface that remains, and texels cut by the Boolean keep only their
remaining area, as on any mesh.

Its UVs come from the operands: Blender carries each operand's `Lightmap`
layer onto the faces that operand contributes. When every operand's layer is
one block of one atlas, the result has a layout without overlaps, and the
image shows on the evaluated result in EEVEE through that same layer. So the
operands' generated layers (export/uv_layers.py) are moved into blocks of an
atlas, each block as many texels as the operand's own lightmap would have.
The block's rect is kept on the mesh (BLOCK_PROP), so the next bake maps the
layer back first and never shrinks it twice. A layer the user made is never
moved: when every operand has the user's layer, those layers are used as
they are (the user laid the atlas out); a mix is refused, naming the operand.
"""
import numpy as np

from ..engine.transport.csg_bake import pack_atlas
from ..engine.core.scene import SceneError
from ..export import csg as csg_export
from ..export import uv_layers

# [x0, y0, sx, sy] on an operand's mesh: its generated Lightmap layer is mapped
# to (x0 + sx U, y0 + sy V), its block in a Boolean result's atlas.
BLOCK_PROP = "photon_lightmaps_boolean_block"


def _original(ob):
    return getattr(ob, "original", None) or ob


def mesh_operands(ob):
    """The operands (original objects, the base first) of a Boolean of plain meshes,
    or None when `ob` has no Boolean modifier or one of its leaves is a tagged
    Photon CSG primitive (an exact CSG solid, baked by bake/csg_atlas.py)."""
    ob = _original(ob)
    if ob.type != "MESH" or not csg_export.boolean_modifiers(ob):
        return None
    operands = [ob] + sorted(csg_export.collect_operands(ob), key=lambda o: o.name)
    for o in operands:
        try:
            if csg_export.primitive_tag(o) is not None:
                return None
        except ValueError:          # a malformed tag: the export reports it
            return None
    return operands


def _layout_resolution(ob, density):
    from .pipeline import layout_resolution
    return layout_resolution(ob, density)


def release(mesh):
    """Maps a layer this add-on moved into a block back to its own layout (a mesh
    baked on its own that was a Boolean operand before). -> whether it changed."""
    if BLOCK_PROP not in mesh:
        return False
    x0, y0, sx, sy = (float(v) for v in mesh[BLOCK_PROP])   # read before the property goes
    del mesh[BLOCK_PROP]
    if not uv_layers.layer_is_ours(mesh) or not (sx > 0.0 and sy > 0.0):
        return False                # edited since: the user's now, as it is
    _write_ours(mesh, (_layer_uvs(mesh) - (x0, y0)) / (sx, sy))
    return True


def _move(mesh, rect):
    _write_ours(mesh, _layer_uvs(mesh) * rect[2:] + rect[:2])
    mesh[BLOCK_PROP] = [float(v) for v in rect]


def _layer_uvs(mesh):
    return uv_layers.read_uvs(mesh.uv_layers[uv_layers.LAYER_NAME]).astype(np.float64)


def _write_ours(mesh, uv):
    """Writes our layer's UVs and records them as ours (uv_layers.layer_is_ours)."""
    layer = mesh.uv_layers[uv_layers.LAYER_NAME]
    layer.uv.foreach_set("vector", uv.astype(np.float32).reshape(-1))
    mesh[uv_layers.DIGEST_PROP] = uv_layers.uv_digest(uv_layers.read_uvs(layer))
    mesh.update()


def _check_own_mesh(solid, o):
    import bpy
    users = [x.name for x in bpy.data.objects if x.data == o.data and x != o]
    if users:
        raise SceneError(f"Boolean '{solid}': operand '{o.name}' shares its mesh '{o.data.name}' with "
                         f"{', '.join(repr(u) for u in users[:3])}; its Lightmap UV layer would move for "
                         "all of them (Object > Relations > Make Single User to bake it)")
    if o.library is not None or o.data.library is not None:
        raise SceneError(f"Boolean '{solid}': operand '{o.name}' is linked from a library; its Lightmap "
                         "UV layer cannot be laid out (make it local to bake it)")


def prepare(ob, operands, density, resolution=None):
    """Lays the operands' Lightmap layers out as one atlas -> (lightmap texels per side
    of the result, {operand mesh name: uv_layers status}). Raises SceneError
    naming the object when the layers cannot be laid out."""
    solid = ob.name
    layers = {}
    for o in operands:
        _check_own_mesh(solid, o)
        if o.data.is_editmode:
            raise SceneError(f"Boolean '{solid}': operand '{o.name}' is in Edit Mode; leave it to bake")
        release(o.data)
        has = o.data.uv_layers.get(uv_layers.LAYER_NAME) is not None
        layers[o.name] = "user" if has and not uv_layers.layer_is_ours(o.data) else "ours"
    users = [n for n, k in layers.items() if k == "user"]
    if users and len(users) < len(operands):
        ours = [n for n, k in layers.items() if k == "ours"]
        raise SceneError(f"Boolean '{solid}': operand '{users[0]}' has a '{uv_layers.LAYER_NAME}' UV layer "
                         f"of its own and '{ours[0]}' has none (or the add-on's); the operands' layers "
                         "must form one atlas, so give them all your own layout side by side in [0,1]², "
                         f"or remove '{users[0]}'s layer to let the bake lay them all out")
    if users:                       # the user's atlas, used as it is
        return int(resolution) if resolution else None, {o.data.name: uv_layers.USER for o in operands}
    sizes = [max(4, _layout_resolution(o, density)) for o in operands]
    status = {o.data.name: uv_layers.ensure_lightmap_uv(o, resolution=r) for o, r in zip(operands, sizes)}
    W, H, origins = pack_atlas([(r, r) for r in sizes])
    side = max(W, H)
    for o, r, (x, y) in zip(operands, sizes, origins):
        _move(o.data, np.array([x / side, y / side, r / side, r / side], np.float64))
    return int(resolution) if resolution else side, status
