"""Blender's Bake button (Render Properties > Bake): RenderEngine.bake, delegated here.

`bake(engine, ...)` is what PhotonLightmapsRenderEngine.bake calls; one photon
pass (engine/session.py) serves every object and image of a bake, cached by a
digest of the exported scene and the settings.
"""
import hashlib
import math

import numpy as np

from ..engine.lightmaps import lightmap  # first: the engine package picks numba's cache folder
from numba import njit, prange  # noqa: E402
from ..engine.transport import open_area  # noqa: E402
from ..engine import session  # noqa: E402
from ..engine.core.errors import Cancelled  # noqa: E402
from ..engine.core.scene import SceneError  # noqa: E402
from ..engine.session import Settings  # noqa: E402
from ..export import export_scene  # noqa: E402
from ..messages import bug_text  # noqa: E402
from . import images  # noqa: E402

# RenderEngine.bake pass_filter bits (BakeSettings.pass_filter enum values, read from bpy).
FILTER_EMIT = 2
FILTER_DIFFUSE = 4
FILTER_GLOSSY = 8
FILTER_TRANSMISSION = 16
FILTER_DIRECT = 64
FILTER_INDIRECT = 128
FILTER_COLOR = 256


@njit(cache=True, parallel=True)
def _sample_bilinear(lm, lm_id, s, t, out):
    for i in prange(s.shape[0]):
        lightmap.lookup_bilinear(lm, lm_id, 0, s[i], t[i], out[i])


# One photon pass serves every object (and image) of a bake: keyed by a digest of
# the exported scene and the settings, so an edited scene is never served stale maps.
_cache = {"key": None, "value": None}


def clear_cache(*_args):
    """Frees the photon pass kept for Blender's bake (also a bake-complete/cancel handler)."""
    _cache["key"] = None
    _cache["value"] = None


def _digest_scene(scene, extra):
    h = hashlib.sha256(repr(extra).encode())

    def add(x):
        if isinstance(x, np.ndarray):
            h.update(str((x.dtype, x.shape)).encode())
            h.update(np.ascontiguousarray(x).tobytes())
        elif isinstance(x, (list, tuple)):
            h.update(b"[")
            for y in x:
                add(y)
            h.update(b"]")
        elif hasattr(x, "__dataclass_fields__"):
            h.update(type(x).__name__.encode())
            for k in x.__dataclass_fields__:
                add(getattr(x, k))
        else:
            h.update(repr(x).encode())

    add(scene)
    return h.hexdigest()


def _patch_missing_uvs(scene):
    """Gives meshes without a Lightmap layer the core's own xatlas UVs, per loop triangle.

    The core would unwrap them anyway; doing it here keeps the UVs in Blender's
    loop-triangle order, which is what the bake API's primitive ids index.
    """
    from ..engine.lightmaps.uv_atlas import unwrap
    for proto in scene.prototypes:
        for tm in proto.meshes:
            if tm.uvs is None:
                try:
                    tm.uvs = unwrap(tm.vertices, tm.triangles)
                except ValueError as exc:   # NaN vertices, xatlas refusals: name the mesh
                    raise SceneError(f"mesh '{tm.name}' in prototype '{proto.name}': cannot unwrap its "
                                     f"lightmap UVs: {exc}") from exc


def _bake_lightmaps(depsgraph, modes, progress, report, stats=lambda text: None):
    """(scene, export map, {mode: (compiled scene, lightmaps)}) for the bake API, cached.

    Modes: "indirect" (the photon pass: hits after the first bounce), "direct"
    (the gathered direct light alone) and "total" (both). One photon pass serves
    all three; "direct" and "total" are copies of its lightmaps with the direct
    light added. stats(text) names each phase as it starts.
    """
    scene, emap = export_scene(depsgraph, report=None)
    _patch_missing_uvs(scene)
    settings = Settings.read(getattr(depsgraph.scene, "photon_lightmaps", None))
    key = _digest_scene(scene, sorted(vars(settings).items()))
    if _cache["key"] != key:
        clear_cache()
        for w in emap.warnings:
            report("WARNING", w)
        _cache["key"], _cache["value"] = key, (scene, emap, {})
    scene, emap, passes = _cache["value"]
    for mode in modes:
        if mode in passes:
            continue
        if "indirect" not in passes:
            stats("Compiling scene")
            cs, _ = session.compile_and_trace(scene, settings, progress=progress)
            passes["indirect"] = (cs, cs.lightmaps)
        cs, ind = passes["indirect"]
        if mode == "indirect":
            continue
        if "gathered" not in passes:
            # Blender's bake API addresses mesh triangles only (exact primitives and
            # CSG solids are refused below), so only mesh lightmaps need direct light.
            mesh_lms = [l for i, lids in enumerate(cs.instance_lightmaps)
                        if scene.prototypes[scene.instances[i].prototype].meshes for l in lids]
            texels = sum(int(cs.lightmaps.width[l]) * int(cs.lightmaps.height[l]) for l in mesh_lms)
            stats(f"Direct light | {texels:,} texels")
            passes["gathered"] = session.gather_direct(cs, mesh_lms, settings)
        ids, E = passes["gathered"]
        lm = lightmap.Lightmaps(*(a.copy() for a in ind))
        if mode == "direct":
            lm.flux[...] = 0.0
        session.add_direct(lm, (ids, E))
        passes[mode] = (cs, lm)
    return scene, emap, passes


def _whole_texels(lm):
    """The lightmaps as means over whole texels, buried parts included (open_area.baked):
    what Blender's bake pixels average, as the texels of a bake's images do."""
    if np.all(lm.open == 1.0):
        return lm
    out = lightmap.Lightmaps(*(a.copy() for a in lm))
    out.irradiance[...] = open_area.baked(lm, slice(None))
    out.open[:] = 1.0
    return out


def _band3(x, nb):
    a = np.broadcast_to(np.asarray(x, np.float64).reshape(-1), (nb,))
    return a if nb == 3 else np.repeat(a.mean(), 3)


def _target_images(ob):
    """Images Blender bakes `ob` into, in its order: first active image node per material slot."""
    images = []
    for slot in (getattr(ob, "original", None) or ob).material_slots:
        mat = slot.material
        if mat is None or mat.node_tree is None:
            continue
        node = mat.node_tree.nodes.active
        if node is not None and node.bl_idname == "ShaderNodeTexImage" and node.image is not None \
                and node.image not in images:
            images.append(node.image)
    return images


def bake(self, depsgraph, obj, pass_type, pass_filter, width, height):
    """RenderEngine.bake for Blender's Bake button (Render Properties > Bake).

    What Blender 5.0 passes (found by introspection): bake(depsgraph, object,
    pass_type, pass_filter, width, height) is called once per object and target
    image, on a fresh engine instance each time. `begin_result(0, 0, width,
    height, layer=...)` returns one layer with the passes "BakePrimitive" (3
    channels: barycentric u, barycentric v, loop-triangle index as int32 bits,
    -1 where no triangle covers the pixel), "BakeDifferential" and "Combined"
    (RGBA, rows bottom-up like the image); what we write to Combined is what
    Blender stores in the image after end_result. The barycentrics weigh the
    triangle's corners as (u, v, 1 - u - v). Blender writes the image even when
    a bake is cancelled or fails, so those paths write the image's current
    pixels back instead of black. (With "Clear Image" on, Blender blanks the
    image before any engine is called; what it blanked cannot come back.)

    Passes: DIFFUSE with DIRECT / INDIRECT / COLOR (no COLOR: E/pi, Cycles'
    convention), EMIT, and COMBINED (emission + diffuse; glossy and
    transmission are view-dependent and not in a lightmap). Others: an error.
    """
    index = getattr(self, "_photon_bake_calls", 0)
    self._photon_bake_calls = index + 1
    result = self.begin_result(0, 0, width, height, layer="Bake", view="")
    try:
        passes = result.layers[0].passes
        rgba = None
        try:
            prim = passes["BakePrimitive"]
            raw = np.empty(width * height * prim.channels, np.float32)
            prim.rect.foreach_get(raw)
            rgba = _bake_pixels(self, depsgraph, obj, pass_type, int(pass_filter),
                                            raw.reshape(-1, prim.channels))
        except Cancelled:
            self.report({"WARNING"}, "Photon Lightmaps bake cancelled; the image was left as it was")
        except Exception as e:  # noqa: BLE001  (any failure must still end the result)
            self.report({"ERROR"}, bug_text(e))
        if rgba is None:
            # Blender writes the image whatever happens: give it back what it holds.
            imgs = _target_images(obj)
            old = images.current_pixels(imgs[index] if index < len(imgs) else None, width, height)
            rgba = old if old is not None else np.zeros((height, width, 4), np.float32)
        passes["Combined"].rect.foreach_set(np.ascontiguousarray(rgba, np.float32).reshape(-1))
    finally:
        self.end_result(result)


def _bake_pixels(self, depsgraph, obj, pass_type, pass_filter, raw):
    if pass_type not in ("DIFFUSE", "EMIT", "COMBINED"):
        raise SceneError(f"bake type {pass_type}: not supported by Photon Lightmaps "
                         "(use Diffuse, Emit or Combined, or bake it with Cycles)")
    direct = bool(pass_filter & FILTER_DIRECT)
    indirect = bool(pass_filter & FILTER_INDIRECT)
    if pass_type == "EMIT":
        want_light, want_color, want_emit = False, False, True
    elif pass_type == "DIFFUSE":
        want_light = direct or indirect
        want_color = bool(pass_filter & FILTER_COLOR)
        want_emit = False
        if not (want_light or want_color):
            raise SceneError("bake contributions: the Diffuse bake needs Direct, Indirect or Color")
    else:
        want_light = (direct or indirect) and bool(pass_filter & FILTER_DIFFUSE)
        want_color = True
        want_emit = bool(pass_filter & FILTER_EMIT)
    modes = []
    if want_light:
        modes = ["total"] if direct and indirect else ["indirect"] if indirect else ["direct"]

    def progress(done, total):
        self.update_progress(done / max(total, 1))
        self.update_stats("", f"Photons {done:,}/{total:,}")
        return not self._photon_should_stop()

    def report(level, msg):
        self.report({level}, msg)

    if self._photon_should_stop():
        raise Cancelled("bake cancelled before the photon pass")
    scene, emap, passes = _bake_lightmaps(depsgraph, modes, progress, report,
                                          lambda text: self.update_stats("", text))
    name = (getattr(obj, "original", None) or obj).name
    ids = emap.object_instances(name)
    if not ids:
        raise SceneError(f"object '{name}' is not part of the exported scene")
    lit = [i for i in ids if emap.instances[i].lightmap]
    if want_light and not lit:
        raise SceneError(f"object '{name}' is excluded from lightmaps (Object > Photon Lightmaps)")
    inst = lit[0] if lit else ids[0]
    proto = scene.prototypes[emap.instances[inst].prototype]
    if not proto.meshes:
        # Exact primitives and CSG solids have analytic charts, not the bake
        # mesh's triangles: Blender's per-triangle bake cannot address them.
        raise SceneError(f"object '{name}' is an exact primitive or CSG solid; use "
                         "Render > Bake Photon Lightmaps, which bakes its analytic charts")
    tm = proto.meshes[0]

    prim_id = raw[:, 2].view(np.int32)
    ok = prim_id >= 0
    if ok.any() and prim_id[ok].max() >= tm.triangles.shape[0]:
        raise SceneError(f"object '{name}': Blender's bake mesh has more triangles than the "
                         "exported one (is the mesh being edited?)")
    k = prim_id[ok].astype(np.int64)
    u = raw[ok, 0].astype(np.float64)[:, None]
    v = raw[ok, 1].astype(np.float64)[:, None]
    uv = tm.uvs[k]
    st = u * uv[:, 0] + v * uv[:, 1] + (1.0 - u - v) * uv[:, 2]
    nb = scene.n_bands
    light = None
    if want_light:
        cs, lm = passes[modes[0]]
        if ("whole", modes[0]) not in passes:     # once per bake, not per object
            passes["whole", modes[0]] = _whole_texels(lm)
        lm = passes["whole", modes[0]]
        light = np.zeros((k.shape[0], nb))
        _sample_bilinear(lm, cs.instance_lightmaps[inst][0], st[:, 0].copy(),
                         st[:, 1].copy(), light)
        light = (light if nb == 3 else np.repeat(light.mean(axis=1, keepdims=True), 3, axis=1)) / math.pi
    mids = np.asarray(tm.material_ids if tm.material_ids is not None else
                      np.full(tm.triangles.shape[0], tm.material))[k]
    albedo = np.array([_band3(m.diffuse, nb) for m in scene.materials])[mids]
    emission = np.array([_band3(m.emission, nb) for m in scene.materials])[mids]
    if pass_type == "DIFFUSE":
        val = light if want_light else np.ones((k.shape[0], 3))
        if want_color:
            val = val * albedo
    elif pass_type == "EMIT":
        val = emission
    else:
        val = np.zeros((k.shape[0], 3))
        if want_light:
            val += albedo * light
        if want_emit:
            val += emission
    if pass_type == "COMBINED" and (pass_filter & (FILTER_GLOSSY | FILTER_TRANSMISSION)):
        spec = [m.name for m in scene.materials if np.any(np.asarray(m.specular) > 0)
                or np.any(np.asarray(m.transmission) > 0)]
        if spec:
            self.report({"WARNING"}, "glossy and transmitted light are not in photon lightmaps "
                                     f"(materials: {', '.join(spec[:5])})")
    out = np.zeros((raw.shape[0], 4), np.float32)
    out[ok, :3] = val
    out[ok, 3] = 1.0
    return out

