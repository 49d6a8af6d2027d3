"""The Blender world -> the engine's environment: a constant radiance or an equirectangular map.

A world whose Surface is a Background or Emission with a constant colour and
strength (unlinked, or an RGB/Value node) stays one constant radiance, exactly
as before. Anything else (Sky Texture, an HDRI in an Environment Texture,
gradients, mixes, node groups) is evaluated by Blender itself: Cycles renders
the world's background through a panoramic equirectangular camera in a
temporary scene, so every node means exactly what it means in Blender. The
camera is turned (90, 0, -90) degrees so that the image is Blender's own
equirectangular world mapping (engine/shading/environment.py; checked in
tests/test_world.py): an Environment Texture's image comes back as itself.

As in Cycles, a Sky Texture's sun disc is part of the world (it lands in the
map) and a Sun lamp is a separate light: a scene with both has both. The map
is what *camera* rays see: a world that shows lighting a different colour
through the Light Path node (Is Camera Ray) is baked as the camera sees it.

Bakes are cached per world content (nodes, their settings and inputs, images
by file and date, node groups), so a render after a render does not bake again.
"""
import hashlib
import inspect
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import OrderedDict

import numpy as np

from ..engine.core.scene import EnvironmentMap
from .context import output_priority
from .materials import node_input

# Equirectangular map size and Cycles samples per pixel (box filter: each pixel is
# the mean over its own area). 1024 x 512 at 32 spp takes ~9 s on two cores, once.
ENV_RESOLUTION = (1024, 512)
ENV_SAMPLES = 32
_CACHE_SIZE = 4
_cache = OrderedDict()     # content key -> (H, W, 3) float32 linear RGB
# "inprocess" (a temporary scene, on Blender's main thread), "subprocess" (a background
# Blender, from other threads, e.g. a RenderEngine's render thread in the UI) or "auto".
BAKE_MODE = "auto"

_SHADERS = ("ShaderNodeBackground", "ShaderNodeEmission")


def world(ctx, world):
    """Scene.environment for the world: a band array (constant) or an EnvironmentMap."""
    if world is None:
        return 0.0
    owner = f"world '{world.name}'"
    tree = world.node_tree
    if tree is None:
        return ctx.bands(tuple(world.color))
    outs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputWorld"]
    outs.sort(key=output_priority)
    if not outs or not outs[0].inputs["Surface"].is_linked:
        return 0.0
    node = _through_reroutes(outs[0].inputs["Surface"])
    if node is not None and node.bl_idname in _SHADERS and all(
            _is_constant(node.inputs[k]) for k in ("Color", "Strength")):
        return _constant(ctx, node, owner)
    try:
        rgb, seconds = baked_map(world)
    except Exception as exc:     # Cycles missing, render failure, unreadable result
        ctx.report("WARNING", f"{owner}: could not be rendered with Cycles ({exc}); "
                              f"its colour is averaged instead")
        return _constant(_Quiet(ctx), node, owner) if node is not None and node.bl_idname in _SHADERS \
            else 0.0
    px = rgb.astype(np.float64)
    if ctx.n_bands == 1:
        px = px.mean(axis=2, keepdims=True)
    return EnvironmentMap(pixels=px, name=world.name, bake_seconds=seconds)


def _constant(ctx, node, owner):
    what = "the background colour" if node.bl_idname == "ShaderNodeBackground" else "the colour"
    rgb = np.asarray(node_input(ctx, node.inputs["Color"], what, owner)[:3])
    return ctx.bands(np.clip(rgb * node_input(ctx, node.inputs["Strength"], "the strength", owner), 0, None))


class _Quiet:
    """The export context without its reporter (the fallback warns once itself)."""

    def __init__(self, ctx):
        self._ctx = ctx

    def __getattr__(self, name):
        return getattr(self._ctx, name)

    def report(self, level, message):
        pass


def _through_reroutes(socket):
    seen = 0
    while socket.is_linked and seen < 64:
        seen += 1
        node = socket.links[0].from_node
        if node.bl_idname != "NodeReroute":
            return node
        socket = node.inputs[0]
    return None


def _is_constant(socket):
    if not socket.is_linked:
        return True
    node = _through_reroutes(socket)
    return node is not None and node.bl_idname in ("ShaderNodeRGB", "ShaderNodeValue")


# --------------------------------------------------------------------------------------
# Baking through Cycles, cached by content
# --------------------------------------------------------------------------------------

def baked_map(world, resolution=None, samples=None):
    """((H, W, 3) float32 radiance, seconds spent baking: 0 when cached) for a world."""
    w, h = resolution or ENV_RESOLUTION
    samples = int(samples or ENV_SAMPLES)
    world = getattr(world, "original", world)
    key = (content_key(world), int(w), int(h), samples)
    hit = _cache.get(key)
    if hit is not None:
        _cache.move_to_end(key)
        return hit, 0.0
    t0 = time.perf_counter()
    mode = BAKE_MODE
    if mode == "auto":
        mode = "inprocess" if threading.current_thread() is threading.main_thread() else "subprocess"
    with tempfile.TemporaryDirectory(prefix="plm_world_") as tmp:
        if mode == "inprocess":
            rgb = _bake_in_process(world, int(w), int(h), samples, tmp)
        else:
            rgb = _bake_in_subprocess(world, int(w), int(h), samples, tmp)
    rgb = np.nan_to_num(np.asarray(rgb, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    rgb = np.ascontiguousarray(np.clip(rgb, 0.0, None))
    _cache[key] = rgb
    while len(_cache) > _CACHE_SIZE:
        _cache.popitem(last=False)
    return rgb, time.perf_counter() - t0


def clear_cache():
    _cache.clear()


def content_key(world):
    """Hash of everything the world's background depends on: its node tree (nodes,
    their settings, input values, links), node groups, and images by file and date."""
    h = hashlib.sha256()
    seen = set()

    def put(*items):
        h.update(repr(items).encode())

    def image(img):
        if img is None:
            return put("image", None)
        path = img.filepath_raw
        try:
            import bpy
            abspath = bpy.path.abspath(path, library=img.library)
            stat = os.stat(abspath)
            file_id = (abspath, stat.st_mtime_ns, stat.st_size)
        except (OSError, ValueError, ImportError):
            file_id = (path, None)
        put("image", img.name, img.source, file_id, tuple(img.size), img.colorspace_settings.name,
            img.alpha_mode, bool(img.packed_file), img.is_dirty)
        if img.packed_file is not None or img.is_dirty or img.source == "GENERATED":
            # content that lives only in memory: its pixels
            n = img.size[0] * img.size[1] * img.channels
            if n:
                a = np.empty(n, np.float32)
                img.pixels.foreach_get(a)
                h.update(a.tobytes())

    def value(v):
        if hasattr(v, "__len__") and not isinstance(v, str):
            return tuple(value(x) for x in v)
        if hasattr(v, "as_pointer"):
            return None
        return v

    def tree(nt):
        if nt is None or nt.as_pointer() in seen:
            return put("tree", None if nt is None else nt.name)
        seen.add(nt.as_pointer())
        put("tree", nt.name, nt.bl_idname)
        for node in sorted(nt.nodes, key=lambda n: n.name):
            put("node", node.name, node.bl_idname, node.mute)
            for prop in node.bl_rna.properties:
                pid = prop.identifier
                if prop.is_readonly and prop.type != "POINTER" or pid in _SKIP_PROPS:
                    continue
                v = getattr(node, pid, None)
                if prop.type == "POINTER":
                    if pid == "image":
                        image(v)
                    elif pid == "node_tree":
                        tree(v)
                    elif v is not None and hasattr(v, "name") and hasattr(v, "as_pointer") \
                            and hasattr(v, "matrix_world"):
                        put(pid, v.name, tuple(tuple(r) for r in v.matrix_world))   # texture coordinate object
                    continue
                put(pid, value(v))
            for sock in node.inputs:
                put("in", sock.identifier, value(getattr(sock, "default_value", None)), sock.is_linked)
        for link in nt.links:
            put("link", link.from_node.name, link.from_socket.identifier, link.to_node.name,
                link.to_socket.identifier, link.is_muted)

    put("world", tuple(world.color))
    tree(world.node_tree)
    return h.hexdigest()


# layout and selection state: no effect on the result
_SKIP_PROPS = {"location", "location_absolute", "width", "height", "select", "show_options",
               "show_preview", "hide", "show_texture", "color", "use_custom_color", "label", "parent",
               "warning_propagation", "rna_type", "dimensions", "internal_links"}


def render_world(bpy, world, path, width, height, samples):
    """Renders `world`'s background to a float EXR at `path` with Cycles (a temporary
    scene with a panoramic camera) and returns its (H, W, 3) float32 pixels, row 0 at
    the bottom. Everything it creates is removed again. Self-contained (bpy passed
    in): a background Blender runs this very source for the subprocess bake."""
    import math

    import numpy as np

    images_before = set(bpy.data.images)
    sc = bpy.data.scenes.new("photon_lightmaps_world_bake")
    cam = ob = None
    vis = getattr(world, "cycles_visibility", None)
    cam_vis = vis.camera if vis is not None else None
    try:
        sc.world = world
        if vis is not None:
            vis.camera = True      # the bake looks at the world with a camera ray
        r = sc.render
        r.engine = "CYCLES"
        r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
        r.film_transparent = False
        r.use_compositing = r.use_sequencer = False
        c = sc.cycles
        c.device = "CPU"
        c.samples = samples
        c.use_adaptive_sampling = False
        c.use_denoising = False
        c.pixel_filter_type = "BOX"       # a pixel is the mean over its own area
        c.filter_width = 1.0
        c.seed = 0
        c.film_exposure = 1.0
        sc.view_settings.view_transform = "Standard"
        sc.view_settings.look = "None"
        sc.view_settings.exposure = 0.0
        sc.view_settings.gamma = 1.0
        cam = bpy.data.cameras.new("photon_lightmaps_world_bake")
        cam.type = "PANO"
        cam.panorama_type = "EQUIRECTANGULAR"
        cam.clip_start = 1e-3
        ob = bpy.data.objects.new("photon_lightmaps_world_bake", cam)
        sc.collection.objects.link(ob)
        # Looking along +x with +z up: the image is then Blender's world mapping
        # (u = -atan2(y, x) / 2pi + 0.5, v = atan2(z, hypot(x, y)) / pi + 0.5).
        ob.rotation_euler = (math.pi / 2.0, 0.0, -math.pi / 2.0)
        sc.camera = ob
        r.filepath = path
        r.use_file_extension = False
        im = r.image_settings
        im.file_format, im.color_depth, im.color_mode = "OPEN_EXR", "32", "RGB"
        res = bpy.ops.render.render(write_still=True, scene=sc.name)
        if "FINISHED" not in res:
            raise RuntimeError(f"Cycles did not finish ({', '.join(res)})")
        img = bpy.data.images.load(path, check_existing=False)
        try:
            px = np.empty(width * height * 4, np.float32)
            img.pixels.foreach_get(px)
        finally:
            bpy.data.images.remove(img)
        return px.reshape(height, width, 4)[..., :3].copy()
    finally:
        if vis is not None:
            vis.camera = cam_vis
        if ob is not None:
            bpy.data.objects.remove(ob)
        if cam is not None:
            bpy.data.cameras.remove(cam)
        bpy.data.scenes.remove(sc)
        for img in set(bpy.data.images) - images_before:   # the Render Result, if new
            bpy.data.images.remove(img)


def _bake_in_process(world, width, height, samples, tmp):
    import bpy
    return render_world(bpy, world, os.path.join(tmp, "world.exr"), width, height, samples)


_CHILD = """
import sys, numpy as np, bpy
blend, name, out, w, h, s = sys.argv[sys.argv.index("--") + 1:]
with bpy.data.libraries.load(blend) as (src, dst):
    dst.worlds = [name]
np.save(out, render_world(bpy, dst.worlds[0], out + ".exr", int(w), int(h), int(s)))
"""


def _bake_in_subprocess(world, width, height, samples, tmp):
    """The same render in a background Blender (or Python with the bpy module): Blender's
    operators must not run on a render thread. The world travels in a .blend of its own."""
    import bpy
    blend = os.path.join(tmp, "world.blend")
    out = os.path.join(tmp, "world.npy")
    bpy.data.libraries.write(blend, {world}, path_remap="ABSOLUTE", fake_user=True)
    script = inspect.getsource(render_world) + _CHILD
    args = ["--", blend, world.name, out, str(width), str(height), str(samples)]
    if bpy.app.binary_path:
        cmd = [bpy.app.binary_path, "-b", "--factory-startup", "--python-expr", script] + args
    else:                     # the bpy module: its Python imports bpy itself
        cmd = [sys.executable, "-c", "import sys\n" + script] + args
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    if proc.returncode != 0 or not os.path.exists(out):
        tail = (proc.stderr or proc.stdout or "").strip().splitlines()[-1:]
        raise RuntimeError(f"the background Blender failed: {tail[0] if tail else proc.returncode}")
    return np.load(out)
