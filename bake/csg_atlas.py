"""CSG solids and exact primitives in a bake: which leaves share the solid's atlas, the atlas
itself, and moving each baked leaf's `Lightmap` layer into its block (see bake/__init__.py)."""
import numpy as np

from ..engine.transport import csg_bake
from ..engine.lightmaps import lightmap
from ..export import csg as csg_export
from ..export import uv_layers
from .images import BakedMap


def original(ob):
    return getattr(ob, "original", None) or ob


def leaf_plan(proto, solid, others, warnings):
    """{leaf object name: None (baked into the solid's atlas) or why not} for one exported solid.

    A leaf is baked when it is a tagged Photon CSG primitive whose `Lightmap` layer is
    still the generated chart layout: only then can that layer be moved into the
    leaf's atlas block without touching anything of the user's.
    """
    import bpy

    from ..engine.core.scene import Primitive
    plan = {}
    taken = {leaf for p in others.values() for leaf, why in p.items() if why is None}
    for leaf in csg_export.tree_leaves(proto.csg[0]):
        name = leaf.name
        ob = bpy.data.objects.get(name)
        why = None
        if name in plan or name in taken:
            warnings.append(f"CSG solid '{solid}': operand '{name}' is used more than once as a Boolean "
                            f"operand; its '{uv_layers.LAYER_NAME}' layer can point at one atlas block "
                            "only, so only its first use is baked")
            plan.setdefault(name, "used more than once")
            continue
        elif ob is None or not isinstance(leaf, Primitive):
            why = (f"'{name}' is a mesh operand, not a Photon CSG primitive: its own "
                   f"'{uv_layers.LAYER_NAME}' UVs cannot share the solid's atlas without being rewritten")
        elif sum(1 for o in bpy.data.objects if o.data == ob.data) > 1:
            why = (f"'{name}' shares its mesh '{ob.data.name}' with other objects "
                   "(Object > Relations > Make Single User to bake it)")
        elif ob.library is not None or ob.data.library is not None:
            why = f"'{name}' is linked from a library"
        else:
            why = uv_layers.primitive_chart_uvs(ob)[2]
        if why is not None:
            warnings.append(f"CSG solid '{solid}': operand {why}; its surface is left out of the "
                            "solid's lightmap")
        plan[name] = why
    return plan


def solid_leaves(cs, job, name):
    """The leaves of CSG solid `name` that get a block in its atlas (engine/csg_bake.solid_leaves entries)."""
    plan = job.csg[name]
    out, seen = [], set()
    for d in csg_bake.solid_leaves(cs, job.targets[name]):
        # a leaf used twice gets two engine lightmaps, but one UV layer: the first one
        if d["kind"] == "prim" and plan.get(d["name"], "unknown") is None and d["name"] not in seen:
            seen.add(d["name"])
            out.append(d)
    return out


def atlas(cs, job, name, leaves, lightmaps=None):
    """One image for CSG solid `name`: its leaves' lightmaps packed into one atlas (or None).

    lightmaps: other per-texel values in cs.lightmaps' layout (the error image) to lay out
    the same way; job.result is then left alone."""
    if lightmaps is not None:
        if not leaves:
            return None
        return _packed(name, leaves, [b for b, _ in _leaf_blocks(cs, job.targets[name], leaves, lightmaps)])
    lm = cs.lightmaps
    inst = job.targets[name]
    skipped = {k: v for k, v in job.csg[name].items() if v is not None}
    info = dict(leaves=[d["name"] for d in leaves], skipped=skipped, split_texels=0,
                boundary_texels=0, atlas=None)
    job.result.csg[name] = info
    if not leaves:
        job.result.skipped[name] = ("a CSG solid none of whose operands can be baked "
                                    "(see the warnings)")
        return None
    pairs = _leaf_blocks(cs, inst, leaves, lm)
    for d, (_, full) in zip(leaves, pairs):
        sl = lightmap.texel_slice(lm, d["lightmap"])
        info["split_texels"] += int(np.count_nonzero(lm.split[sl] >= 0))
        info["boundary_texels"] += int(np.count_nonzero((lm.area[sl] < full.reshape(-1) * (1 - 1e-9))
                                                        & (lm.area[sl] > 0)))
    bm = _packed(name, leaves, [b for b, _ in pairs])
    info["atlas"] = (bm.width, bm.height)
    return bm


def _leaf_blocks(cs, inst, leaves, values):
    """Per leaf: (its image block from per-texel `values` in cs.lightmaps' layout,
    its texels' areas before CSG)."""
    out = []
    for d in leaves:
        full = csg_bake.full_primitive_areas(cs, inst, d["row"], int(values.height[d["lightmap"]]))
        bands = getattr(cs, "spectral", None) if values is cs.lightmaps else None   # error maps stay grey
        out.append((csg_bake.leaf_rgba(values, d["lightmap"], full, bands), full))
    return out


def _packed(name, leaves, blocks):
    # pack_atlas is deterministic in the block sizes: the error image gets the same tiles
    W, H, origins = csg_bake.pack_atlas([(b.shape[1], b.shape[0]) for b in blocks])
    img = np.zeros((H, W, 4), np.float32)
    tiles = {}
    for d, b, o in zip(leaves, blocks, origins):
        csg_bake.blit(img, b, o)
        tiles[d["name"]] = (o[0], o[1], b.shape[1], b.shape[0])
    return BakedMap(name, img, leaves[0]["lightmap"], tiles)


def place_leaf_uvs(solid, bm, warnings):
    """Moves each baked leaf's generated `Lightmap` layer into its block of the solid's atlas.

    bm.tiles: leaf name -> (x, y, w, h) texels, or None for the plain chart layout
    (a stand-alone primitive whose layer an earlier CSG bake had moved).
    The layer is checked again here (the user may have edited it during the bake).
    """
    import bpy
    for leaf, tile in bm.tiles.items():
        ob = bpy.data.objects.get(leaf)
        if ob is None:
            continue
        unit, applied, why = uv_layers.primitive_chart_uvs(ob)
        if why is not None:
            if tile is not None:
                warnings.append(f"CSG solid '{solid}': {why}; that operand's part of the image is "
                                "not shown on the solid")
            continue
        if tile is None:
            rect = (0.0, 0.0, 1.0, 1.0)
        else:
            x, y, w, h = tile
            rect = (x / bm.width, y / bm.height, w / bm.width, h / bm.height)
        uv_layers.set_primitive_tile(ob, unit, applied, rect)


def solid_materials(ob, parts):
    """Materials the evaluated object shows: its own slots, then (CSG solids) those the
    Boolean result carries over from its baked operands (Exact solver, Transfer)."""
    import bpy
    mats = []

    def add(m):
        if m is not None and m not in mats:
            mats.append(m)
    for slot in ob.material_slots:
        add(slot.material)
    if parts:
        try:
            ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
            for m in ev.data.materials:
                add(getattr(m, "original", None) or m)
        except Exception:  # noqa: BLE001  (no depsgraph in this context: the slots below suffice)
            pass
        for leaf in parts:
            op = bpy.data.objects.get(leaf)
            if op is not None and op is not ob:
                for slot in op.material_slots:
                    add(slot.material)
    return mats
