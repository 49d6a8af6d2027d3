"""Node-driven material inputs -> engine Textures, baked by Cycles itself.

A material input the exporter cannot reduce to a constant (an Image Texture, a
procedural, a mix, vertex colours, attributes... anywhere upstream) is baked
to an image on the mesh's material UV map (its active render UV map, which
Image Texture nodes without a UV Map node read), so its meaning is exactly
Blender's:

* colour and scalar inputs: a copy of the material has the input's upstream
  output wired into an Emission shader (colours into Color, scalars into
  Strength, so Blender's own colour -> float conversion applies), and Cycles'
  Emit bake writes it to a float Non-Color image: scene-linear colours, raw
  data values;
* normals: Cycles' Normal bake in tangent space (+X +Y +Z) of the material as it
  is, so Normal Map, Bump and any other node the Normal input sees are
  Blender's; engine/shading/materials.py `shading_normal` applies the baked vector in
  the frame Blender's tangent-space bake uses (MikkTSpace's, for a flat
  triangle: the per-triangle UV tangent).

Nothing of the user's is touched: the bake runs in a scene of its own (engine
Cycles, never the user's scene, render engine or selection), on a mesh made
from the exported triangles and their layers, with copies of the materials;
everything made for it is removed afterwards. Bakes run after the depsgraph
walk (export_scene calls `bake_queued` last), so no evaluated datablock is
used after the main database changed. Results are cached across exports,
keyed on the material's node tree (images by name, file time, and pixel hash
when packed, generated or edited), the mesh data and UV map, the input and
the resolution, so a re-render bakes nothing and an image edit invalidates.

Resolution: TEXEL_DENSITY texels per metre of the object's surface with that
material (from its world area and the UV area it covers), a power of two in
[MIN_SIDE, MAX_SIDE], at most the render's larger side, and, when only image
textures drive the input, at most what their largest image needs.

Approximations (reported where they apply): UVs outside [0,1]² read the
texture wrapped, which is exact for repeating images only; CSG operand meshes
keep the inputs' unlinked values; Generated coordinates follow the exported
(deformed) mesh rather than Blender's pre-modifier coordinates.
"""
from __future__ import annotations

import hashlib
import math
import os
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, replace

import numpy as np

from ..engine.core.scene import Texture
from ..engine.shading.texture import linear_to_srgb

# engine input -> socket name, per shader node type (engine/shading/materials.py TEXTURE_INPUTS)
TEXTURE_SOCKETS = {
    "ShaderNodeBsdfPrincipled": {"base_color": "Base Color", "roughness": "Roughness",
                                 "metallic": "Metallic", "transmission": "Transmission Weight",
                                 "normal": "Normal"},
    "ShaderNodeBsdfDiffuse": {"base_color": "Color", "normal": "Normal"},
    "ShaderNodeBsdfGlossy": {"base_color": "Color", "roughness": "Roughness", "normal": "Normal"},
    "ShaderNodeBsdfAnisotropic": {"base_color": "Color", "roughness": "Roughness", "normal": "Normal"},
    "ShaderNodeBsdfGlass": {"base_color": "Color", "roughness": "Roughness", "normal": "Normal"},
}
COLOUR_INPUTS = ("base_color",)
# Nodes whose output is a constant node_input already reads (no bake needed).
CONSTANT_NODES = ("ShaderNodeRGB", "ShaderNodeValue")

TEXEL_DENSITY = 256.0          # texels per metre of surface
MIN_SIDE, MAX_SIDE = 64, 2048
MARGIN = 4                     # texels of Extend margin around UV islands (bilinear, mips)
CACHE_BYTES = 1 << 30          # baked arrays kept across exports (least recently used go first)
MAIN_THREAD_TIMEOUT = 600.0    # seconds a render thread waits for the main thread's bake

_cache: "OrderedDict[str, np.ndarray]" = OrderedDict()


def clear_cache():
    _cache.clear()


def _cycles_bake(**kw):
    """bpy.ops.object.bake under the caller's context override (one place, so tests count it)."""
    import bpy
    return bpy.ops.object.bake(**kw)


# ------------------------------------------------------------------- which inputs

def _upstream(socket):
    """The node and output feeding `socket` through reroutes (None, None: unlinked)."""
    seen = 0
    while socket.is_linked and seen < 64:
        seen += 1
        link = socket.links[0]
        if link.is_muted:
            return None, None
        node = link.from_node
        if node.bl_idname == "NodeReroute":
            socket = node.inputs[0]
            continue
        return node, link.from_socket
    return None, None


def _upstream_nodes(node, out=None, depth=0):
    """Every node feeding `node` (itself included), inside node groups too."""
    out = {} if out is None else out
    if node is None or node.as_pointer() in out or depth > 64:
        return out
    out[node.as_pointer()] = node
    tree = getattr(node, "node_tree", None)
    if node.bl_idname == "ShaderNodeGroup" and tree is not None:
        for n in tree.nodes:
            _upstream_nodes(n, out, depth + 1)
    for s in node.inputs:
        for link in s.links:
            _upstream_nodes(link.from_node, out, depth + 1)
    return out


def image_missing(image):
    """True for an image Blender has no pixels for (a file that is not there)."""
    if image is None or image.source not in ("FILE", "SEQUENCE", "MOVIE", "TILED"):
        return False
    if image.packed_file is not None:
        return False
    try:
        w, h = image.size
        if w and h:
            return False
        return not image.has_data and len(image.pixels) == 0
    except (RuntimeError, ReferenceError):
        return True


def driven_inputs(ctx, node, owner):
    """{engine input: socket name} of the shader's inputs that need a bake.

    An input whose upstream holds an image without pixels keeps its unlinked
    value, with one warning naming the material and the image."""
    names = TEXTURE_SOCKETS.get(node.bl_idname, {})
    out = {}
    for key, sname in names.items():
        sock = node.inputs.get(sname)
        if sock is None or not sock.enabled:
            continue
        up, _ = _upstream(sock)
        if up is None or up.bl_idname in CONSTANT_NODES:
            continue
        missing = [n.image for n in _upstream_nodes(up).values()
                   if n.bl_idname in ("ShaderNodeTexImage", "ShaderNodeTexEnvironment")
                   and image_missing(n.image)]
        if missing:
            im = missing[0]
            ctx.report("WARNING", f"{owner}: image '{im.name}' has no pixels (file "
                                  f"'{im.filepath}' not found); the inputs it drives use their "
                                  f"unlinked values")
            continue
        out[key] = sname
    return out


# ------------------------------------------------------------------- capture (during the walk)

@dataclass
class MeshJob:
    """One exported mesh whose materials have driven inputs, as plain arrays, so the
    bake after the depsgraph walk needs no evaluated datablock."""
    name: str
    object_name: str
    tm: object                       # the engine TriangleMesh (its material ids are remapped)
    positions: np.ndarray            # (V, 3)
    tri_verts: np.ndarray            # (T, 3)
    tri_slot: np.ndarray             # (T,) slot index into `materials`
    materials: list                  # per slot: (engine material id, Blender material original)
    uv_name: str
    uv_layers: dict                  # name -> (T, 3, 2), render layer first
    colors: dict                     # name -> (T, 3, 4) linear float
    smooth: np.ndarray               # (T,) bool
    matrix: np.ndarray               # (4, 4) object -> world
    render_side: int
    digest: str = ""


def render_uv_name(mesh):
    layers = mesh.uv_layers
    for layer in layers:
        if layer.active_render:
            return layer.name
    return layers.active.name if layers.active is not None else (layers[0].name if len(layers) else None)


def corner_uvs(layer, loops, nt):
    uv = np.empty(len(layer.uv) * 2, np.float32)
    layer.uv.foreach_get("vector", uv)
    return uv.reshape(-1, 2)[loops].reshape(nt, 3, 2).astype(np.float64)


def capture(ctx, ob, mesh, tm, loops, slot_mats):
    """Queues a bake of `tm`'s driven materials (slot_mats: per slot (engine id,
    Blender material or None)); returns nothing, bake_queued does the work."""
    if not any(mid in ctx.textured for mid, _ in slot_mats):
        return
    uv_name = render_uv_name(mesh)
    if uv_name is None:
        for mid, mat in slot_mats:
            if mid in ctx.textured:
                ctx.report("WARNING", f"material '{mat.original.name}' on mesh '{mesh.name}': node-driven "
                                      "inputs need a UV map; the mesh has none, so their unlinked "
                                      "values are used")
        return
    nt = tm.triangles.shape[0]
    layers = {uv_name: tm.tex_uvs}
    for layer in mesh.uv_layers:
        if layer.name not in layers:
            layers[layer.name] = corner_uvs(layer, loops, nt)
    colors = {}
    for attr in mesh.color_attributes:
        try:
            n = len(attr.data)
            c = np.empty(n * 4, np.float32)
            attr.data.foreach_get("color", c)
        except (RuntimeError, TypeError):
            continue
        c = c.reshape(n, 4)
        if attr.domain == "POINT":
            colors[attr.name] = c[tm.triangles.reshape(-1)].reshape(nt, 3, 4)
        elif attr.domain == "CORNER":
            colors[attr.name] = c[loops].reshape(nt, 3, 4)
    poly = np.empty(nt, np.int32)
    mesh.loop_triangles.foreach_get("polygon_index", poly)
    smooth = np.zeros(len(mesh.polygons), bool)
    mesh.polygons.foreach_get("use_smooth", smooth)
    mi = np.empty(nt, np.int32)
    mesh.loop_triangles.foreach_get("material_index", mi)
    r = ctx.dg.scene.render
    side = max(r.resolution_x, r.resolution_y) * r.resolution_percentage // 100
    ctx.texture_jobs.append(MeshJob(
        mesh.name, ob.name, tm, np.asarray(tm.vertices, np.float32), tm.triangles.astype(np.int32),
        np.clip(mi, 0, len(slot_mats) - 1), list(slot_mats), uv_name, layers, colors,
        smooth[poly], np.array(ob.matrix_world, np.float64), int(side)))


# ------------------------------------------------------------------- cache keys

_SKIP_PROPS = {"rna_type", "name", "label", "location", "width", "height", "select", "show_options",
               "show_preview", "show_texture", "hide", "mute", "color", "use_custom_color",
               "parent", "dimensions", "width_hidden", "bl_idname", "bl_label", "bl_description",
               "bl_icon", "bl_static_type", "bl_width_default", "bl_width_min", "bl_width_max",
               "bl_height_default", "bl_height_min", "bl_height_max", "type", "internal_links",
               "inputs", "outputs", "location_absolute", "warning_propagation", "color_tag",
               "is_active_output"}


def _image_digest(h, image):
    if image is None:
        h.update(b"<no image>")
        return
    h.update(repr((image.name, image.source, image.filepath, image.colorspace_settings.name,
                   image.alpha_mode, tuple(image.size), image.is_dirty,
                   image.packed_file is not None)).encode())
    path = None
    if image.source == "FILE" and image.packed_file is None:
        import bpy
        path = bpy.path.abspath(image.filepath, library=image.library)
        try:
            st = os.stat(path)
            h.update(repr((st.st_mtime_ns, st.st_size)).encode())
        except OSError:
            h.update(b"<missing>")
    if image.packed_file is not None or image.source == "GENERATED" or image.is_dirty or path is None:
        w, hh = image.size
        if w * hh:
            px = np.empty(w * hh * image.channels, np.float32)
            image.pixels.foreach_get(px)
            h.update(hashlib.sha256(px.tobytes()).digest())


def _value(v):
    if hasattr(v, "__len__") and not isinstance(v, str):
        try:
            return tuple(_value(x) for x in v)
        except TypeError:
            return repr(v)
    return v


def _tree_digest(h, tree, seen):
    if tree is None or tree.as_pointer() in seen:
        return
    seen.add(tree.as_pointer())
    for node in sorted(tree.nodes, key=lambda n: n.name):
        h.update(repr((node.bl_idname, node.name, node.mute)).encode())
        for prop in node.bl_rna.properties:
            pid = prop.identifier
            if pid in _SKIP_PROPS:
                continue
            val = getattr(node, pid, None)
            if prop.type == "POINTER":
                if pid == "image":
                    _image_digest(h, val)
                elif pid == "node_tree":
                    _tree_digest(h, val, seen)
                elif pid == "color_ramp" and val is not None:
                    h.update(repr((val.interpolation, val.color_mode,
                                   [(e.position, tuple(e.color)) for e in val.elements])).encode())
                elif pid == "mapping" and val is not None:
                    h.update(repr([[(p.location[0], p.location[1], p.handle_type) for p in c.points]
                                   for c in val.curves]).encode())
                elif hasattr(val, "name"):
                    h.update(repr((pid, val.name)).encode())
                elif hasattr(val, "bl_rna"):
                    # nested settings (image_user, texture_mapping...): their simple values
                    h.update(repr((pid, [(p.identifier, _value(getattr(val, p.identifier, None)))
                                         for p in val.bl_rna.properties
                                         if p.type in ("BOOLEAN", "INT", "FLOAT", "STRING", "ENUM")
                                         and p.identifier != "rna_type"])).encode())
            elif prop.type in ("BOOLEAN", "INT", "FLOAT", "STRING", "ENUM"):
                h.update(repr((pid, _value(val))).encode())
        for s in node.inputs:
            if not s.is_linked and hasattr(s, "default_value"):
                h.update(repr((s.identifier, _value(s.default_value))).encode())
    for link in tree.links:
        h.update(repr((link.from_node.name, link.from_socket.identifier, link.to_node.name,
                       link.to_socket.identifier, link.is_muted)).encode())


def material_digest(mat):
    h = hashlib.sha256()
    _tree_digest(h, mat.node_tree, set())
    return h.hexdigest()


def mesh_digest(job):
    h = hashlib.sha256()
    for a in (job.positions, job.tri_verts, job.smooth, job.matrix):
        h.update(np.ascontiguousarray(a).tobytes())
    for d in (job.uv_layers, job.colors):
        for k in sorted(d):
            h.update(k.encode())
            h.update(np.ascontiguousarray(d[k], np.float32).tobytes())
    h.update(job.uv_name.encode())
    return h.hexdigest()


def _cache_get(key):
    a = _cache.get(key)
    if a is not None:
        _cache.move_to_end(key)
    return a


def _cache_put(key, a):
    _cache[key] = a
    total = sum(x.nbytes for x in _cache.values())
    while total > CACHE_BYTES and len(_cache) > 1:
        _, old = _cache.popitem(last=False)
        total -= old.nbytes


# ------------------------------------------------------------------- resolution

def _pow2(n):
    return 1 << max(int(math.ceil(math.log2(max(n, 1)))), 0)


def bake_side(job, slot, driving_images):
    """Texels per side for the triangles of slot `slot` (module docstring)."""
    sel = job.tri_slot == slot
    p = job.positions.astype(np.float64)[job.tri_verts[sel]]
    p = p @ job.matrix[:3, :3].T
    world = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    uv = job.uv_layers[job.uv_name][sel]
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
    want = TEXEL_DENSITY * math.sqrt(world / uv_area) if uv_area > 0 else MIN_SIDE
    side = min(max(_pow2(want), MIN_SIDE), MAX_SIDE, max(_pow2(job.render_side), MIN_SIDE))
    if driving_images is not None:
        side = min(side, _pow2(max(driving_images)))
    return int(side)


def _driving_images(mat, node, sname):
    """Largest sides of the images feeding the input, or None when anything else
    (a procedural, an attribute) does too."""
    up, _ = _upstream(node.inputs[sname])
    sides = []
    for n in _upstream_nodes(up).values():
        if n.bl_idname == "ShaderNodeTexImage" and n.image is not None:
            sides.append(max(n.image.size))
        elif n.bl_idname.startswith("ShaderNodeTex") or n.bl_idname in (
                "ShaderNodeAttribute", "ShaderNodeVertexColor", "ShaderNodeAmbientOcclusion",
                "ShaderNodeBevel", "ShaderNodeNewGeometry", "ShaderNodeLayerWeight",
                "ShaderNodeFresnel", "ShaderNodeObjectInfo", "ShaderNodeWireframe"):
            return None
    return sides or None


def input_encoding(node, sname):
    """"srgb" when the input reads an 8-bit sRGB Image Texture's Color directly:
    Cycles interpolates such images in sRGB and decodes afterwards, so the baked
    texel-centre values are re-encoded and interpolated the same way; "linear"
    otherwise (float images, data, anything computed from the image)."""
    up, out = _upstream(node.inputs[sname])
    img = getattr(up, "image", None)
    if (up is None or up.bl_idname != "ShaderNodeTexImage" or img is None or out.name != "Color"
            or up.interpolation == "Closest"):
        return "linear"
    try:
        byte = not img.is_float
    except (AttributeError, ReferenceError):
        return "linear"
    return "srgb" if byte and img.colorspace_settings.name == "sRGB" else "linear"


# ------------------------------------------------------------------- the bake

def _on_main_thread(fn):
    """Runs fn on Blender's main thread (the operator cannot run elsewhere): directly
    when called there, else through a timer while this thread waits."""
    if threading.current_thread() is threading.main_thread():
        return fn()
    import bpy
    done = threading.Event()
    box = {}

    def run():
        try:
            box["value"] = fn()
        except Exception as exc:  # noqa: BLE001 - re-raised in the waiting thread
            box["error"] = exc
        done.set()
        return None

    bpy.app.timers.register(run, first_interval=0.0)
    if not done.wait(MAIN_THREAD_TIMEOUT):
        raise RuntimeError("the main thread did not run the texture bake in time")
    if "error" in box:
        raise box["error"]
    return box["value"]


def _build_mesh(bpy, job, mats):
    me = bpy.data.meshes.new("PL texture bake")
    V, T = job.positions.shape[0], job.tri_verts.shape[0]
    me.vertices.add(V)
    me.vertices.foreach_set("co", job.positions.reshape(-1))
    me.loops.add(3 * T)
    me.loops.foreach_set("vertex_index", job.tri_verts.reshape(-1))
    me.polygons.add(T)
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * T, 3, dtype=np.int32))
    me.polygons.foreach_set("material_index", job.tri_slot.astype(np.int32))
    me.polygons.foreach_set("use_smooth", job.smooth.astype(bool))
    me.update()
    for name, uv in job.uv_layers.items():
        layer = me.uv_layers.new(name=name)
        layer.uv.foreach_set("vector", uv.astype(np.float32).reshape(-1))
    layer = me.uv_layers[job.uv_name]
    me.uv_layers.active = layer
    layer.active_render = True
    for name, c in job.colors.items():
        attr = me.color_attributes.new(name, "FLOAT_COLOR", "CORNER")
        attr.data.foreach_set("color", c.astype(np.float32).reshape(-1))
    for m in mats:
        me.materials.append(m)
    return me


def _output_node(tree):
    from .context import output_priority
    outs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
    outs.sort(key=output_priority)
    return outs[0] if outs else None


class _Baker:
    """The temporary scene, object and material copies of one mesh's bakes."""

    def __init__(self, bpy, job, shaders):
        self.bpy = bpy
        self.made_images = []
        self.scene = bpy.data.scenes.new("PL texture bake")
        sc = self.scene
        sc.render.engine = "CYCLES"
        sc.cycles.device = "CPU"
        sc.cycles.samples = 1
        sc.render.bake.use_clear = True
        self.mats = []
        self.slots = []              # per slot: (copy, shader node in the copy, emission, target, output)
        for mid, mat in job.materials:
            copy = (mat.original.copy() if mat is not None and mat.node_tree is not None
                    else bpy.data.materials.new("PL texture bake"))
            if copy.node_tree is None:
                copy.use_nodes = True
            self.mats.append(copy)
            tree = copy.node_tree
            name = shaders.get(mid)
            node = tree.nodes.get(name) if name else None
            em = tree.nodes.new("ShaderNodeEmission")
            target = tree.nodes.new("ShaderNodeTexImage")
            out = _output_node(tree) or tree.nodes.new("ShaderNodeOutputMaterial")
            surf = out.inputs["Surface"]
            self.slots.append((copy, node, em, target, out, surf.links[0].from_socket if surf.is_linked
                               else None))
        self.dummy = self._image(1)
        self.mesh = _build_mesh(bpy, job, self.mats)
        self.ob = bpy.data.objects.new("PL texture bake", self.mesh)
        from mathutils import Matrix
        # object-space nodes (Object coordinates, Position) see the object where it is
        self.ob.matrix_world = Matrix(job.matrix.tolist())
        sc.collection.objects.link(self.ob)

    def _image(self, side):
        img = self.bpy.data.images.new("PL texture bake", side, side, alpha=True, float_buffer=True)
        img.colorspace_settings.name = "Non-Color"
        self.made_images.append(img)
        return img

    def bake(self, key, sides, uv_name):
        """Bakes input `key` of the slots in `sides` (slot -> (socket name, side)) -> {slot: pixels}."""
        normal = key == "normal"
        targets = {}
        for i, (copy, node, em, target, out, surface) in enumerate(self.slots):
            tree = copy.node_tree
            if i in sides and node is not None:
                sname, side = sides[i]
                targets[i] = img = self._image(side)
                target.image = img
                if not normal:
                    up = node.inputs[sname].links[0].from_socket
                    for s in em.inputs:
                        for link in list(s.links):
                            tree.links.remove(link)
                    if key in COLOUR_INPUTS:
                        tree.links.new(up, em.inputs["Color"])
                        em.inputs["Strength"].default_value = 1.0
                    else:
                        # scalar: through Strength, so a colour converts to float as Blender does
                        em.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
                        tree.links.new(up, em.inputs["Strength"])
            else:
                target.image = self.dummy
                em.inputs["Strength"].default_value = 0.0
                for s in em.inputs:
                    for link in list(s.links):
                        tree.links.remove(link)
            if normal and surface is not None:
                tree.links.new(surface, out.inputs["Surface"])
            else:
                tree.links.new(em.outputs[0], out.inputs["Surface"])
            tree.nodes.active = target
        bpy = self.bpy
        vl = self.scene.view_layers[0]
        self.ob.select_set(True, view_layer=vl)
        vl.objects.active = self.ob
        kw = dict(type="NORMAL" if normal else "EMIT", uv_layer=uv_name, margin=MARGIN,
                  margin_type="EXTEND", use_clear=True, target="IMAGE_TEXTURES",
                  use_selected_to_active=False)
        if normal:
            kw.update(normal_space="TANGENT", normal_r="POS_X", normal_g="POS_Y", normal_b="POS_Z")
        with bpy.context.temp_override(scene=self.scene, view_layer=vl, active_object=self.ob,
                                       object=self.ob, selected_objects=[self.ob],
                                       selected_editable_objects=[self.ob]):
            _cycles_bake(**kw)
        out = {}
        for i, img in targets.items():
            w, h = img.size
            px = np.empty(w * h * 4, np.float32)
            img.pixels.foreach_get(px)
            px = px.reshape(h, w, 4)
            out[i] = np.ascontiguousarray(px[..., :3] if normal or key in COLOUR_INPUTS else px[..., :1])
        return out

    def close(self):
        bpy = self.bpy
        for ob in (self.ob,):
            bpy.data.objects.remove(ob, do_unlink=True)
        bpy.data.meshes.remove(self.mesh)
        for m in self.mats:
            bpy.data.materials.remove(m)
        for img in self.made_images:
            bpy.data.images.remove(img)
        bpy.data.scenes.remove(self.scene)


def _bake_job(ctx, job, todo):
    """Runs the missing bakes of one mesh: todo {key: {slot: (socket, side, cache key)}}."""
    import bpy
    shaders = {mid: ctx.textured[mid][1] for mid, _ in job.materials if mid in ctx.textured}
    baker = _Baker(bpy, job, shaders)
    try:
        for key, slots in todo.items():
            t0 = time.perf_counter()
            got = baker.bake(key, {i: (s, side) for i, (s, side, _) in slots.items()}, job.uv_name)
            secs = (time.perf_counter() - t0) / max(len(got), 1)
            for i, px in got.items():
                _cache_put(slots[i][2], px)
                ctx.texture_seconds[slots[i][2]] = secs
                ctx.texture_stats["baked"] += 1
    finally:
        baker.close()


def bake_queued(ctx):
    """Bakes (or takes from the cache) every queued mesh's driven inputs, adds the
    Textures to the scene and gives each such mesh textured material variants."""
    jobs, ctx.texture_jobs = ctx.texture_jobs, []
    if not jobs:
        return
    t0 = time.perf_counter()
    st = ctx.texture_stats
    tex_index = {}
    digests = {}
    for job in jobs:
        job.digest = mesh_digest(job)
        plan = {}                  # slot -> {key: (cache key, encoding)}
        todo = {}
        for slot, (mid, mat) in enumerate(job.materials):
            rec = ctx.textured.get(mid)
            if rec is None or mat is None or not np.any(job.tri_slot == slot):
                continue
            inputs, shader = rec
            node = mat.original.node_tree.nodes.get(shader)
            if node is None:
                continue
            if mid not in digests:
                digests[mid] = material_digest(mat.original)
            for key, sname in inputs.items():
                imgs = _driving_images(mat, node, sname) if key != "normal" else None
                side = bake_side(job, slot, imgs)
                ck = f"{digests[mid]}|{job.digest}|{job.uv_name}|{key}|{side}"
                enc = input_encoding(node, sname) if key in COLOUR_INPUTS else "linear"
                plan.setdefault(slot, {})[key] = (ck, enc)
                if _cache_get(ck) is None:
                    todo.setdefault(key, {})[slot] = (sname, side, ck)
                else:
                    st["cached"] += 1
        if todo:
            try:
                _on_main_thread(lambda: _bake_job(ctx, job, todo))
            except Exception as exc:  # noqa: BLE001 - the render goes on with unlinked values
                ctx.report("WARNING", f"mesh '{job.name}': node-driven material inputs could not be "
                                      f"baked with Cycles ({exc}); their unlinked values are used")
        _bind(ctx, job, plan, tex_index)
    st["seconds"] += time.perf_counter() - t0
    n = len(ctx.scene.textures)
    nbytes = sum(int(t.pixels.nbytes) for t in ctx.scene.textures)
    st["textures"], st["bytes"] = n, nbytes
    if n:
        ctx.report("INFO", f"Photon Lightmaps: {n} material texture(s), {nbytes / 2 ** 20:.1f} MiB "
                           f"({st['baked']} baked by Cycles in {st['seconds']:.2f} s, "
                           f"{st['cached']} from the cache)")


def _bind(ctx, job, plan, tex_index):
    """Material variants of this mesh with its textures; remaps the mesh's material ids."""
    tm = job.tm
    ids = np.asarray(tm.material_ids).copy()
    scene = ctx.scene
    for slot, keys in plan.items():
        textures = {}
        for key, (ck, enc) in keys.items():
            px = _cache_get(ck)
            if px is None:
                continue
            if ck not in tex_index:
                if enc == "srgb":
                    px = px.copy()
                    px[..., :3] = linear_to_srgb(px[..., :3])
                scene.textures.append(Texture(px, name=f"{job.materials[slot][1].original.name}:{key}",
                                              bake_seconds=ctx.texture_seconds.get(ck, 0.0),
                                              encoding=enc))
                tex_index[ck] = len(scene.textures) - 1
            textures[key] = tex_index[ck]
        if not textures:
            continue
        mid = job.materials[slot][0]
        vkey = (mid, tuple(sorted(textures.items())))
        idx = ctx.texture_variants.get(vkey)
        if idx is None:
            idx = scene.add_material(replace(scene.materials[mid], textures=textures))
            ctx.map.materials.append(ctx.map.materials[mid])
            ctx.texture_variants[vkey] = idx
        ids[(job.tri_slot == slot)] = idx
    tm.material_ids = ids
    tm.material = int(ids[0])
    uv = job.uv_layers[job.uv_name]
    if uv.size and (uv.min() < 0.0 or uv.max() > 1.0) and plan:
        ctx.report("INFO", f"mesh '{job.name}': its UV map '{job.uv_name}' leaves [0,1]²; textures "
                           "baked on it are read wrapped there")
