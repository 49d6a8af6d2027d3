"""The Blender camera -> engine Camera (the field of view spans the larger image side)."""
import math

from ..engine.core.scene import Camera
from .context import matrix


def camera(ctx, cam_ob, width, height):
    cam = Camera(width=width, height=height)
    if cam_ob is None:
        ctx.report("WARNING", "the scene has no camera; a default view is used")
        return cam
    cam.transform = matrix(cam_ob.matrix_world)
    data = cam_ob.data
    settings = getattr(getattr(data, "original", None) or data, "photon_lightmaps", None)
    if settings is not None and settings.use_polarizer:
        cam.polarizer = float(settings.polarizer_angle)
    scene_settings = getattr(ctx.dg.scene, "photon_lightmaps", None)
    cam.polarized = bool(getattr(scene_settings, "polarization", False))
    r = ctx.dg.scene.render
    if abs(r.pixel_aspect_x - r.pixel_aspect_y) > 1e-6:
        ctx.report("WARNING", "non-square pixel aspect is ignored")
    if abs(data.shift_x) > 1e-9 or abs(data.shift_y) > 1e-9:
        ctx.report("WARNING", f"camera '{cam_ob.name}': lens shift is ignored")
    if data.dof.use_dof:
        ctx.report("WARNING", f"camera '{cam_ob.name}': depth of field is ignored")
    wide = width >= height
    ratio = max(width, height) / min(width, height)
    fit = data.sensor_fit
    # The engine's field of view spans the larger image side; Blender's sensor fit
    # says which side the sensor size (or ortho scale) spans.
    fit_larger = fit == "AUTO" or (fit == "HORIZONTAL") == wide
    if data.type == "ORTHO":
        cam.kind = "orthographic"
        cam.ortho_scale = float(data.ortho_scale) * (1.0 if fit_larger else ratio)
        return cam
    if data.type != "PERSP":
        ctx.report("WARNING", f"camera '{cam_ob.name}': {data.type} cameras are rendered as perspective")
    sensor = data.sensor_height if fit == "VERTICAL" else data.sensor_width
    half = 0.5 * float(sensor) / float(data.lens)
    cam.fov = 2.0 * math.atan(half * (1.0 if fit_larger else ratio))
    return cam

