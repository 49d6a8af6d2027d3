"""Fixtures and helpers shared by the Blender-side tests (import them into a test module)."""
import bpy
import numpy as np
import pytest

import photon_lightmaps
from photon_lightmaps import registration


@pytest.fixture(scope="session", autouse=True)
def addon():
    """Registers the add-on once per session, unless something already did."""
    owned = not registration.is_registered()
    if owned:
        photon_lightmaps.register()
    yield
    if owned:
        photon_lightmaps.unregister()


@pytest.fixture
def bake_uv_cache(tmp_path_factory, monkeypatch):
    """xatlas results go to a per-session folder, not the user's cache; the bake's
    kept photon pass is dropped before and after the test."""
    from photon_lightmaps import bake
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path_factory.getbasetemp() / "uvcache"))
    bake.clear_cache()
    yield
    bake.clear_cache()


def read_image(path):
    """(H, W, 4) float pixels, rows top to bottom (float EXR: linear; PNG: encoded bytes / 255)."""
    img = bpy.data.images.load(str(path), check_existing=False)
    try:
        w, h = img.size
        px = np.empty(w * h * 4, np.float32)
        img.pixels.foreach_get(px)
    finally:
        bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[::-1].astype(np.float64)


def cycles_diffuse_bake(ob, res, samples, *, seed=0, bounces=8, margin=4, uv_layer="Lightmap",
                        bake_type="DIFFUSE", pass_filter=("DIRECT", "INDIRECT"), **options):
    """Cycles' Diffuse bake of `ob` (Direct + Indirect, no Color) into a new res x res float
    image -> (res, res, 4) pixels, rows bottom-up. CPU, no clamping (it would bias Cycles
    low), no denoising, no adaptive sampling, `bounces` max and diffuse bounces. The image
    and its node are removed again, and the render engine is put back. bake_type and
    pass_filter: another of Cycles' bakes (AO; Diffuse with Direct or Indirect alone;
    NORMAL, with options normal_space="OBJECT"). options: more of object.bake's."""
    scene = bpy.context.scene
    engine = scene.render.engine
    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = samples
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.seed = seed
    cy.max_bounces = cy.diffuse_bounces = bounces
    cy.sample_clamp_direct = cy.sample_clamp_indirect = 0.0
    img = bpy.data.images.new(f"cycles_bake_{ob.name}", res, res, float_buffer=True, alpha=True)
    tree = ob.material_slots[0].material.node_tree
    node = tree.nodes.new("ShaderNodeTexImage")
    node.image = img
    tree.nodes.active = node
    try:
        for o in bpy.context.view_layer.objects:
            o.select_set(False)
        ob.select_set(True)
        bpy.context.view_layer.objects.active = ob
        bpy.ops.object.bake(type=bake_type, pass_filter=set(pass_filter), uv_layer=uv_layer,
                            margin=margin, use_clear=True, target="IMAGE_TEXTURES", **options)
        px = np.empty(res * res * 4, np.float32)
        img.pixels.foreach_get(px)
    finally:
        tree.nodes.remove(node)
        bpy.data.images.remove(img)
        scene.render.engine = engine
    return px.reshape(res, res, 4)


def render_exr(scene, engine, path, cycles_samples=128):
    scene.render.engine = engine
    if engine == "CYCLES":
        c = scene.cycles
        c.device = "CPU"
        c.samples = cycles_samples
        c.use_denoising = False
        c.use_adaptive_sampling = False
        c.light_sampling_threshold = 0.0
        c.max_bounces = c.diffuse_bounces = 16
        c.seed = 1
        # Cycles' defaults clamp indirect samples at 10 and blur glossy paths (Filter
        # Glossy): both bias light through glass and mirrors low; compare unbiased
        c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
        c.blur_glossy = 0.0
    scene.render.filepath = str(path)
    scene.render.use_file_extension = False
    im = scene.render.image_settings
    im.file_format, im.color_depth, im.color_mode = "OPEN_EXR", "32", "RGBA"
    bpy.ops.render.render(write_still=True)
    return read_image(path)


def empty_blender_file(tmp_path_factory, monkeypatch):
    """Generator body of an autouse fixture: a factory-empty file, a per-session UV cache
    and no orientation-bake reports left from an earlier test; yields the scene."""
    import bpy
    from photon_lightmaps.bake import orientation as ol_bake
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path_factory.getbasetemp() / "uvcache"))
    ol_bake.REPORTS.clear()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene
