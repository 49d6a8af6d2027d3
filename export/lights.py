"""Blender lights -> engine Lights in Cycles' units (see engine/shading/lights.py)."""
import math

import numpy as np

from ..engine.core.scene import Light
from ..engine.shading import spectrum

# the light panel's Spectrum choices (Light.photon_lightmaps.spectrum): its colour, or a line
LIGHT_COLOUR, LIGHT_LINE = "COLOUR", "LINE"


def light(ctx, ob, xf):
    lt = ob.data
    name = ob.original.name if ob.original is not None else ob.name
    owner = f"light '{name}'"
    color = np.asarray(tuple(lt.color), dtype=np.float64)
    if lt.use_temperature:
        color = color * np.asarray(tuple(lt.temperature_color), dtype=np.float64)
    power = float(lt.energy) * 2.0 ** float(lt.exposure)
    if power < 0.0:
        ctx.report("WARNING", f"{owner}: negative power is not supported; the light is skipped")
        return
    if lt.use_nodes and lt.node_tree is not None:
        ctx.report("WARNING", f"{owner}: light shader nodes are ignored")
    kw = dict(name=name, color=ctx.bands(color), power=power, transform=xf,
              temperature=float(lt.temperature) if lt.use_temperature else 0.0)
    settings = getattr(lt, "photon_lightmaps", None)
    if getattr(settings, "spectrum", LIGHT_COLOUR) == LIGHT_LINE:
        # the line's colour where RGB shows it (clipped into Rec.709: pure spectral colours lie outside it)
        bands = spectrum.Bands()
        rgb = spectrum.to_rgb(spectrum.line_spectrum(settings.line_nm, settings.line_width, bands), bands)
        kw.update(color=ctx.bands(np.maximum(rgb, 0.0)), temperature=0.0, line_nm=float(settings.line_nm),
                  line_width=float(settings.line_width))
    if getattr(settings, "use_polarizer", False):
        kw["polarizer"] = float(settings.polarizer_angle)
    scale = np.linalg.norm(xf[:, :3], axis=0)
    # normalize=False (measured against Cycles 5.0): the power is per unit of the
    # light's area, 4 pi r² for point/spot (4 when r = 0), the shape's area for area
    # lights, and the sun's power is per steradian of its disc.
    if lt.type in ("POINT", "SPOT"):
        kw["radius"] = max(float(lt.shadow_soft_size), 0.0)
        if not lt.normalize:
            kw["power"] *= 4.0 * math.pi * kw["radius"] ** 2 if kw["radius"] > 0.0 else 4.0
        if lt.type == "POINT":
            light = Light("point", **kw)
        else:
            if lt.use_square:
                ctx.report("WARNING", f"{owner}: square spot lights are rendered as round cones")
            if np.ptp(scale[:2]) > 1e-6 * scale[:2].max():
                ctx.report("WARNING", f"{owner}: non-uniform scale (elliptic cone) is ignored")
            light = Light("spot", spot_size=float(lt.spot_size), spot_blend=float(lt.spot_blend), **kw)
    elif lt.type == "SUN":
        if not lt.normalize and lt.angle > 0.0:
            kw["power"] *= 2.0 * math.pi * (1.0 - math.cos(0.5 * float(lt.angle)))
        light = Light("sun", angle=float(lt.angle), **kw)
    elif lt.type == "AREA":
        shape = lt.shape.lower()
        sx = float(lt.size)
        sy = sx if shape in ("square", "disk") else float(lt.size_y)
        if not lt.normalize:
            area = sx * sy * scale[0] * scale[1] * (math.pi / 4.0 if shape in ("disk", "ellipse") else 1.0)
            kw["power"] *= area
        if lt.spread < math.pi - 1e-4:
            ctx.report("WARNING", f"{owner}: area light spread below 180° is ignored")
        light = Light("area", shape=shape, size=sx, size_y=sy, **kw)
    else:
        ctx.report("WARNING", f"{owner}: unsupported light type {lt.type}")
        return
    if lt.type in ("POINT", "SPOT"):
        # Extra attribute read by engine/shading/lights.py (Cycles' soft falloff near the light).
        light.soft_falloff = bool(lt.use_soft_falloff)
    ctx.scene.lights.append(light)
    ctx.map.lights.append(name)

