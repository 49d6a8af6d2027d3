"""The methods under test, each as "run at effort X -> (result arrays, seconds, bytes)".

* Cycles: Diffuse bake (Direct + Indirect, no Color) on the Lightmap UV layer,
  and camera renders, over samples.
* Photon lightmaps (this engine): bake_objects' compute path over photon count,
  and two-pass renders over photon count (constant or bilinear lookup, or the
  final gather over the bilinear lightmaps); optionally OIDN over either
  (engine/transport/denoise.py), timed on top.
* The photon-map baseline lives in photon_map.py.

Baked arrays are (res, res, 3) E/pi with rows bottom-up (image pixel = texel);
renders are (H, W, 3) linear radiance with rows top-down.
"""
import os
import tempfile
import time

import bpy
import numpy as np
from numba import njit, prange

from photon_lightmaps import bake
from photon_lightmaps.export import uv_layers
from photon_lightmaps.bake import pipeline
from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine import session
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.transport.renderer import render as render_image
from photon_lightmaps.export import export_scene

MAX_BOUNCES = 8


# --------------------------------------------------------------------------------------
# Cycles
# --------------------------------------------------------------------------------------

def setup_cycles(scene, samples, seed):
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = int(samples)
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.seed = int(seed)
    # Same path length as ours and no clamping (clamping biases Cycles low).
    cy.max_bounces = cy.diffuse_bounces = MAX_BOUNCES
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    # A one-pixel box filter, like this engine's pixel sampling.
    cy.pixel_filter_type = "BOX"
    cy.filter_width = 1.0
    cy.use_animated_seed = False


def _bake_targets(objs, res):
    """One float image per object in an active Image Texture node of its own material copy."""
    out = {}
    for ob in objs:
        img = bpy.data.images.new(f"bench_{ob.name}", res, res, float_buffer=True, alpha=True)
        tree = ob.material_slots[0].material.node_tree
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image = img
        tree.nodes.active = node
        out[ob.name] = (img, node, tree)
    return out


def cycles_bake(objs, res, samples, seed):
    """Cycles' Diffuse bake of all `objs` in one call -> ({name: (res, res, 3)}, seconds)."""
    scene = bpy.context.scene
    setup_cycles(scene, samples, seed)
    targets = _bake_targets(objs, res)
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    for ob in objs:
        ob.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]
    t0 = time.perf_counter()
    bpy.ops.object.bake(type="DIFFUSE", pass_filter={"DIRECT", "INDIRECT"}, uv_layer="Lightmap",
                        margin=0, use_clear=True, target="IMAGE_TEXTURES")
    seconds = time.perf_counter() - t0
    maps = {}
    for name, (img, node, tree) in targets.items():
        px = np.empty(res * res * 4, np.float32)
        img.pixels.foreach_get(px)
        maps[name] = px.reshape(res, res, 4)[..., :3].copy()
        tree.nodes.remove(node)
        bpy.data.images.remove(img)
    return maps, seconds


def cycles_bake_ss(objs, res, ss, samples, seed):
    """Cycles' Diffuse bake at ss times the resolution, each ss x ss block of pixels
    averaged into one texel: the texel means a lightmap holds -> ({name: (res, res, 3)}, seconds)."""
    maps, seconds = cycles_bake(objs, res * ss, samples, seed)
    return {n: a.reshape(res, ss, res, ss, 3).mean(axis=(1, 3)) for n, a in maps.items()}, seconds


def cycles_render(samples, seed):
    """Cycles camera render -> ((H, W, 3) rows top-down, seconds)."""
    scene = bpy.context.scene
    setup_cycles(scene, samples, seed)
    return render_still(scene)


def render_still(scene):
    """F12 render with the scene's engine -> ((H, W, 3) linear, rows top-down; wall
    seconds). Written to EXR and read back, because a background process cannot read
    the Render Result's pixels."""
    r = scene.render
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    r.image_settings.color_management = "OVERRIDE"
    scene.view_settings.view_transform = "Standard"
    r.use_file_extension = False
    with tempfile.TemporaryDirectory() as tmp:
        r.filepath = os.path.join(tmp, "render.exr")
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        seconds = time.perf_counter() - t0
        out = read_rgb(r.filepath)
    return out, seconds


def read_rgb(path):
    """An image file -> (H, W, 3) float32, rows top-down (EXR: linear)."""
    img = bpy.data.images.load(str(path), check_existing=False)
    try:
        w, h = img.size
        px = np.empty(w * h * img.channels, np.float32)
        img.pixels.foreach_get(px)
        return px.reshape(h, w, img.channels)[::-1, :, :3].copy()
    finally:
        bpy.data.images.remove(img)


# --------------------------------------------------------------------------------------
# Photon lightmaps (this engine)
# --------------------------------------------------------------------------------------

def ours_bake(objs, photons, seed, res, indirect="LOOKUP", irradiance_cache=False, gather_rays=None,
              gather_lights=None):
    """bake_objects without writing images -> (maps {name: (res, res, 4) E/pi + coverage},
    seconds (export + photon pass + texels + extract), lightmap bytes, photon stats, job).
    indirect: "LOOKUP" (each texel's own photons, the thesis's bake) or "GATHER"
    (final gather over the photon lightmaps, the add-on's default); irradiance_cache:
    the gather through the sparse cache; gather_rays: per texel side (None: 256);
    gather_lights: gather rays sample point, spot and sun lights where they land (None: the default)."""
    t0 = time.perf_counter()
    job = bake.prepare_bake(bpy.context, objs, photons=photons, seed=seed, resolution=res, indirect=indirect,
                         irradiance_cache=irradiance_cache, bake_gather_rays=gather_rays,
                         gather_lights=gather_lights)
    bake.compute_bake(job)
    seconds = time.perf_counter() - t0
    maps = {n: m.rgba for n, m in job.result.maps.items()}
    return maps, seconds, job.result.lightmap_bytes, job.result.stats, job


@njit(cache=True, parallel=True)
def _lookup_many(lm, lm_id, s, t, mode, out):
    for i in prange(s.shape[0]):
        lightmap.lookup(lm, lm_id, 0, s[i], t[i], mode, out[i])


def resample(job, name, res_out, mode):
    """Object `name`'s lightmap looked up at the texel centres of a res_out grid -> (res_out, res_out, 3) E/pi."""
    cs = job.cs
    lm_id = cs.instance_lightmaps[job.targets[name]][0]
    c = (np.arange(res_out) + 0.5) / res_out
    s, t = np.meshgrid(c, c)   # rows = t (bottom-up), like the baked image
    out = np.zeros((res_out * res_out, cs.n_bands))
    _lookup_many(cs.lightmaps, lm_id, s.reshape(-1).copy(), t.reshape(-1).copy(), int(mode), out)
    return (out / np.pi).reshape(res_out, res_out, -1)[..., :3]


def ours_render(photons, samples, seed, modes=(lightmap.MODE_CONSTANT, lightmap.MODE_BILINEAR)):
    """Two-pass renders, one photon pass shared by the modes -> {mode: (image, seconds)}.

    Each mode's time is export + compile + photon pass + its own render pass.
    """
    t0 = time.perf_counter()
    scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    cs = compile_scene(scene)
    if photons > 0:
        trace_photons(cs, photons, seed=seed, max_bounces=MAX_BOUNCES, record_direct=False)
    t_shared = time.perf_counter() - t0
    out = {}
    for mode in modes:
        t1 = time.perf_counter()
        img = render_image(cs, samples=samples, seed=seed, mode=mode, max_depth=MAX_BOUNCES)
        out[mode] = (img[..., :3], t_shared + time.perf_counter() - t1)
    return out


def ours_render_gather(photons, samples, seed, gather_rays=16, denoise=False):
    """Render with the final gather (the photon pass records direct hits) -> (image, seconds).

    denoise=True -> ((image, seconds), (denoised image, seconds + denoise seconds)): the
    same render, then the OIDN pass (albedo and normal traced by session.denoise_render),
    so both curves share their photons and the denoised one pays for its pass."""
    t0 = time.perf_counter()
    scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    cs = compile_scene(scene)
    trace_photons(cs, max(int(photons), 1), seed=seed, max_bounces=MAX_BOUNCES, record_direct=True,
                  caustics=True, gather=gather_rays > 0)
    img = render_image(cs, samples=samples, seed=seed, mode=lightmap.MODE_BILINEAR, max_depth=MAX_BOUNCES,
                       gather=gather_rays)
    t = time.perf_counter() - t0
    if not denoise:
        return img[..., :3], t
    t1 = time.perf_counter()
    den = session.denoise_render(cs, img, session.Settings(samples=samples, seed=seed))
    return (img[..., :3], t), (den[..., :3], t + time.perf_counter() - t1)


def oidn_cycles_bake(maps, covered):
    """Cycles' baked maps through the same OIDN lightmap filter ours get
    (RTLightmap, empty texels filled first) -> (maps, denoise seconds)."""
    from photon_lightmaps.engine.transport import denoise
    t0 = time.perf_counter()
    out = {n: denoise.denoise_lightmap(m, covered=covered[n]) for n, m in maps.items()}
    return out, time.perf_counter() - t0


def oidn_bake(job):
    """ours_bake's maps denoised as a bake with Denoise on does it -> (maps, denoise seconds)."""
    t0 = time.perf_counter()
    maps = {}
    for n, m in job.result.maps.items():
        bm = bake.BakedMap(m.object_name, m.rgba.copy(), m.lightmap_id, m.tiles)
        pipeline._denoise_map(job.cs, bm)
        maps[n] = bm.rgba
    return maps, time.perf_counter() - t0


# --------------------------------------------------------------------------------------
# Texel centres in the world (for the photon map) and the texels every method is scored on
# --------------------------------------------------------------------------------------

def texel_points(ob, res):
    """World position and normal of each texel centre of `ob`'s Lightmap layout at res x res.

    Returns (pos (res, res, 3), normal (res, res, 3), inside (res, res) bool); rows are
    bottom-up like the baked image. A centre outside every UV triangle has inside False.
    """
    mesh = ob.data
    v, tri_v, tri_l, _ = uv_layers.mesh_triangles(mesh)
    uv = uv_layers.read_uvs(mesh.uv_layers[uv_layers.LAYER_NAME])[tri_l]  # (T, 3, 2)
    M = np.array(ob.matrix_world, np.float64)
    wv = v @ M[:3, :3].T + M[:3, 3]
    P = wv[tri_v]                                                         # (T, 3, 3)
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    pos = np.zeros((res, res, 3))
    nrm = np.zeros((res, res, 3))
    inside = np.zeros((res, res), bool)
    for k in range(P.shape[0]):
        a, b, c = uv[k] * res   # texel units; centre of texel (x, y) at (x + 0.5, y + 0.5)
        x0, x1 = int(np.floor(min(a[0], b[0], c[0]))), int(np.ceil(max(a[0], b[0], c[0])))
        y0, y1 = int(np.floor(min(a[1], b[1], c[1]))), int(np.ceil(max(a[1], b[1], c[1])))
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, res), min(y1, res)
        if x1 <= x0 or y1 <= y0:
            continue
        xs, ys = np.meshgrid(np.arange(x0, x1) + 0.5, np.arange(y0, y1) + 0.5)
        d = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
        if abs(d) < 1e-14:
            continue
        l1 = ((xs - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (ys - a[1])) / d
        l2 = ((b[0] - a[0]) * (ys - a[1]) - (xs - a[0]) * (b[1] - a[1])) / d
        l0 = 1.0 - l1 - l2
        hit = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        iy, ix = np.nonzero(hit)
        iy, ix = iy + y0, ix + x0
        w0, w1, w2 = l0[hit], l1[hit], l2[hit]
        pos[iy, ix] = w0[:, None] * P[k, 0] + w1[:, None] * P[k, 1] + w2[:, None] * P[k, 2]
        nrm[iy, ix] = n[k]
        inside[iy, ix] = True
    return pos, nrm, inside
