"""Blender materials -> engine Materials: node inputs evaluated to constants, one converter per shader.

The Principled BSDF (plus Diffuse, Glossy, Metallic, Glass and Emission shaders) maps to
diffuse/specular/transmission/emission weights; a linked input is followed
through reroutes to an RGB/Value node. Base colour, roughness, metallic,
transmission and normal inputs driven by anything else are baked per mesh by
Cycles (textures.py) and sampled per hit; other driven inputs (emission) read
an image averaged, with a warning.
"""
from dataclasses import replace

import numpy as np

from ..engine.core.scene import Material
from ..engine.shading import conductor, dispersion, fluorescence, spectrum
from . import textures
from ..engine.shading.texture import srgb_to_linear
from .context import DEFAULT_DIFFUSE, output_priority


# The material panel's Dispersion choices (Material.photon_lightmaps.dispersion):
# none, an Abbe number that spreads the shader's IOR, or a catalogue glass
DISPERSION_NONE, DISPERSION_ABBE = "NONE", "ABBE"
GLASS_IDS = {name.upper().replace("-", "_").replace(" ", "_"): name for name in dispersion.PRESETS}
# ... and its Fluorescence choices: none, a preset, or custom spectra
FLUORESCENCE_NONE, FLUORESCENCE_CUSTOM = "NONE", "CUSTOM"
FLUORESCENCE_IDS = {name.upper().replace(" ", "_"): name for name in fluorescence.PRESETS}
# ... and its Conductor choices: none (the shader's own metal), or a measured metal
CONDUCTOR_NONE = "NONE"
CONDUCTOR_IDS = {name.upper(): name for name in conductor.PRESETS}


def image_mean(ctx, image):
    key = image.as_pointer()
    if key in ctx.image_average:
        return ctx.image_average[key]
    mean = None
    try:
        n = len(image.pixels)
    except RuntimeError:
        n = 0
    if n:
        px = np.empty(n, np.float32)
        image.pixels.foreach_get(px)
        px = px.reshape(-1, image.channels).astype(np.float64)
        rgba = np.ones((px.shape[0], 4))
        rgba[:, :min(4, px.shape[1])] = px[:, :4]
        if px.shape[1] < 3:
            rgba[:, 1:3] = rgba[:, :1]
        space = image.colorspace_settings.name
        # Byte images hold colour-space-encoded values; float buffers are already scene linear.
        if not image.is_float and space == "sRGB":
            rgba[:, :3] = srgb_to_linear(rgba[:, :3])
        elif not image.is_float and space not in ("Non-Color", "Raw") and not space.startswith("Linear"):
            ctx.report("WARNING", f"image '{image.name}': colour space '{space}' is read as linear")
        mean = rgba.mean(axis=0)
    ctx.image_average[key] = mean
    return mean


def node_input(ctx, socket, what, owner, baked=False):
    """Value of a shader input: its own value, or what a simple linked node provides.

    Returns a float for scalar sockets and an RGB(A) tuple for colour sockets.
    baked=True: an input textures.py bakes; anything but a constant node gives
    the unlinked value quietly (the bake, or its warning, covers the rest).
    """
    node_socket = socket
    seen = 0
    while node_socket.is_linked and seen < 32:
        seen += 1
        link = node_socket.links[0]
        node = link.from_node
        if node.bl_idname == "NodeReroute":
            node_socket = node.inputs[0]
            continue
        out = link.from_socket
        if node.bl_idname in ("ShaderNodeRGB", "ShaderNodeValue"):
            val = out.default_value
            return _shape_like(socket, val)
        if node.bl_idname == "ShaderNodeBlackbody" and not node.inputs["Temperature"].is_linked:
            return _shape_like(socket, tuple(blackbody_rgb(node.inputs["Temperature"].default_value)) + (1.0,))
        if baked:
            break
        if node.bl_idname in ("ShaderNodeTexImage", "ShaderNodeTexEnvironment") and node.image is not None:
            mean = image_mean(ctx, node.image)
            if mean is not None:
                ctx.report("WARNING", f"{owner}: image '{node.image.name}' on {what} is averaged "
                                       f"to one colour (per-texel textures are not supported yet)")
                if out.identifier == "Alpha":
                    return _shape_like(socket, float(mean[3]))
                return _shape_like(socket, tuple(mean[:3]) + (1.0,))
        ctx.report("WARNING", f"{owner}: {what} is driven by node '{node.name}' ({node.bl_idname}), "
                               f"which is not evaluated; its unlinked value is used")
        break
    return _shape_like(socket, socket.default_value)


def _shape_like(socket, val):
    colour = socket.type in ("RGBA", "VECTOR")
    if hasattr(val, "__len__"):
        seq = tuple(float(x) for x in val)
        return seq if colour else float(sum(seq[:3]) / min(len(seq), 3))
    return (float(val),) * 3 + (1.0,) if colour else float(val)


def material(ctx, mat):
    key = 0 if mat is None else mat.original.as_pointer()
    idx = ctx.material_index.get(key)
    if idx is None:
        driven = {}
        m = Material(name="default", diffuse=ctx.bands(DEFAULT_DIFFUSE)) if mat is None else \
            _convert(ctx, mat, driven)
        idx = ctx.scene.add_material(m)
        ctx.map.materials.append(None if mat is None else mat.original.name)
        ctx.material_index[key] = idx
        if driven.get("inputs"):
            ctx.textured[idx] = (driven["inputs"], driven["node"])
    return idx


def surface_node(mat):
    tree = mat.node_tree
    if tree is None:
        return None
    outs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
    outs.sort(key=output_priority)
    if not outs:
        return None
    sock = outs[0].inputs["Surface"]
    node = None
    while sock.is_linked:
        node = sock.links[0].from_node
        if node.bl_idname != "NodeReroute":
            break
        sock = node.inputs[0]
        node = None
    return node


# Surface shader node type -> converter(inp, name, ctx, owner) -> engine Material, where
# inp(socket name) is that input's value (node_input). A new shader is one entry here.
CONVERTERS = {}


def converter(*node_types):
    def register(fn):
        for t in node_types:
            CONVERTERS[t] = fn
        return fn
    return register


@converter("ShaderNodeBsdfPrincipled")
def _principled(inp, name, ctx, owner):
    base = np.asarray(inp("Base Color")[:3])
    metallic = min(max(inp("Metallic"), 0.0), 1.0)
    transmission = min(max(inp("Transmission Weight"), 0.0), 1.0)
    emission = np.asarray(inp("Emission Color")[:3]) * inp("Emission Strength")
    if inp("Alpha") < 1.0:
        ctx.report("WARNING", f"{owner}: alpha below 1 is ignored (treated as opaque)")
    diffuse = base * (1.0 - metallic) * (1.0 - transmission)
    specular = base * metallic
    trans = base * (1.0 - metallic) * transmission
    return Material(name, diffuse=diffuse, specular=specular, transmission=trans,
                    roughness=inp("Roughness"), ior=max(inp("IOR"), 1e-3), emission=emission,
                    base_color=base, metallic=metallic, transmission_weight=transmission,
                    specular_level=max(inp("Specular IOR Level"), 0.0), metal_fresnel=True)


# The converters below set base_color/metallic/transmission_weight so that the
# engine's textured mix B(1-M)(1-T), B M, B(1-M)T gives their own lobe.

@converter("ShaderNodeBsdfDiffuse")
def _diffuse(inp, name, ctx, owner):
    c = np.asarray(inp("Color")[:3])
    return Material(name, diffuse=c, base_color=c)


@converter("ShaderNodeEmission")
def _emission(inp, name, ctx, owner):
    return Material(name, diffuse=0.0, emission=np.asarray(inp("Color")[:3]) * inp("Strength"))


@converter("ShaderNodeBsdfGlossy", "ShaderNodeBsdfAnisotropic")
def _glossy(inp, name, ctx, owner):
    c = np.asarray(inp("Color")[:3])
    return Material(name, diffuse=0.0, specular=c, roughness=inp("Roughness"), base_color=c, metallic=1.0)


@converter("ShaderNodeBsdfMetallic")
def _metallic(inp, name, ctx, owner):
    """Blender's Metallic BSDF: Physical Conductor is a conductor at the node's index per
    RGB channel; F82 Tint is Schlick's colour of its base colour (the tint taken as white)."""
    node = inp.node
    if getattr(node, "fresnel_type", "F82") == "PHYSICAL_CONDUCTOR":
        n = np.maximum(np.asarray(inp("IOR")[:3], float), 1e-3)
        k = np.maximum(np.asarray(inp("Extinction")[:3], float), 0.0)
        c = conductor.normal_reflectance(n, k)
        return Material(name, diffuse=0.0, specular=c, roughness=inp("Roughness"), base_color=c, metallic=1.0,
                        metal_fresnel=True, conductor=(n, k))
    c = np.asarray(inp("Base Color")[:3])
    if np.any(np.abs(np.asarray(inp("Edge Tint")[:3]) - 1.0) > 1e-3):
        ctx.report("INFO", f"{owner}: the Metallic BSDF's Edge Tint is taken as white")
    return Material(name, diffuse=0.0, specular=c, roughness=inp("Roughness"), base_color=c, metallic=1.0,
                    metal_fresnel=True)


@converter("ShaderNodeBsdfGlass")
def _glass(inp, name, ctx, owner):
    c = np.asarray(inp("Color")[:3])
    return Material(name, diffuse=0.0, transmission=c, roughness=inp("Roughness"),
                    ior=max(inp("IOR"), 1e-3), base_color=c, transmission_weight=1.0)


def _convert(ctx, mat, driven):
    """The engine Material; driven["inputs"], driven["node"]: what textures.py bakes."""
    owner = f"material '{mat.original.name}'"
    node = surface_node(mat)
    name = mat.original.name
    convert = CONVERTERS.get(node.bl_idname) if node is not None else None
    if convert is not None:
        baked = set(textures.TEXTURE_SOCKETS.get(node.bl_idname, {}).values())
        driven["inputs"] = textures.driven_inputs(ctx, node, owner)
        driven["node"] = node.name

        def inp(key, what=None):
            return node_input(ctx, node.inputs[key], what or key, owner, baked=key in baked)
        inp.node = node
        m = convert(inp, name, ctx, owner)
    else:
        why = "has no shader nodes" if mat.node_tree is None else \
            "has no surface shader" if node is None else f"uses an unsupported shader ({node.bl_idname})"
        ctx.report("WARNING", f"{owner} {why}; rendered as diffuse with its viewport colour")
        m = Material(name, diffuse=np.asarray(tuple(mat.diffuse_color)[:3], dtype=np.float64))
    _dispersion(mat, m)
    _emission_temperature(node, m)
    return _physical(ctx, m, owner)


def blackbody_rgb(kelvin):
    """Blender's Blackbody node: Planck's colour at kelvin in Rec.709, luminance 1, through
    the spectral bands (within 1.5 % of Blender's own from 1500 to 10 000 K), negative
    channels clipped."""
    bands = spectrum.Bands()
    return np.maximum(spectrum.to_rgb(spectrum.blackbody_spectrum(float(kelvin), bands), bands), 0.0)


# where each converted shader takes its emitted colour
EMISSION_COLOUR = {"ShaderNodeBsdfPrincipled": "Emission Color", "ShaderNodeEmission": "Color"}


def _emission_temperature(node, m):
    """A Blackbody node on the shader's emission colour: its temperature on Material m
    (spectral mode emits Planck's spectrum; RGB its colour, as node_input gave it)."""
    key = EMISSION_COLOUR.get(getattr(node, "bl_idname", None))
    if key is None:
        return
    sock = node.inputs[key]
    for _ in range(32):
        if not sock.is_linked:
            return
        src = sock.links[0].from_node
        if src.bl_idname != "NodeReroute":
            break
        sock = src.inputs[0]
    if src.bl_idname == "ShaderNodeBlackbody" and not src.inputs["Temperature"].is_linked:
        m.emission_temperature = float(src.inputs["Temperature"].default_value)


def _dispersion(mat, m):
    """The panel's Dispersion, Fluorescence and Conductor settings onto engine Material m (the
    compiler checks the values)."""
    settings = getattr(mat.original, "photon_lightmaps", None)
    choice = getattr(settings, "dispersion", DISPERSION_NONE)
    if choice == DISPERSION_ABBE:
        m.abbe = float(settings.abbe)
    elif choice in GLASS_IDS:
        m.glass = GLASS_IDS[choice]
    m.fluorescence = material_fluorescence(settings)
    metal = getattr(settings, "conductor", CONDUCTOR_NONE)
    if metal in CONDUCTOR_IDS:
        m.conductor = CONDUCTOR_IDS[metal]


def material_fluorescence(settings):
    """The panel's Fluorescence as a fluorescence.Fluorescence (None: off); Strength scales
    the absorption of a preset or of custom spectra."""
    choice = getattr(settings, "fluorescence", FLUORESCENCE_NONE)
    if choice in FLUORESCENCE_IDS:
        fl = fluorescence.PRESETS[FLUORESCENCE_IDS[choice]]
    elif choice == FLUORESCENCE_CUSTOM:
        fl = fluorescence.Fluorescence("custom", settings.fl_excitation_nm, settings.fl_excitation_width,
                                       settings.fl_emission_nm, settings.fl_emission_width, settings.fl_absorption,
                                       settings.fl_quantum_yield)
    else:
        return None
    return replace(fl, peak=fl.peak * float(settings.fl_strength))


def _physical(ctx, m, owner):
    """Clamps to a material that conserves energy (weights in [0,1], sum <= 1 per band)."""
    ks = {}
    for key in ("diffuse", "specular", "transmission"):
        ks[key] = np.clip(ctx.bands(np.broadcast_to(np.asarray(getattr(m, key), float), (3,))), 0.0, None)
    total = ks["diffuse"] + ks["specular"] + ks["transmission"]
    over = total.max()
    if over > 1.0:
        ctx.report("WARNING", f"{owner}: reflectance {over:.3f} > 1 is scaled down to 1 (energy conservation)")
        for key in ks:
            ks[key] = ks[key] / over
    for key, val in ks.items():
        setattr(m, key, val)
    le = ctx.bands(np.broadcast_to(np.asarray(m.emission, float), (3,)))
    m.emission = np.clip(np.nan_to_num(le), 0.0, None)
    m.base_color = np.clip(ctx.bands(np.broadcast_to(np.asarray(m.base_color, float), (3,))), 0.0, 1.0)
    m.metallic = float(min(max(m.metallic, 0.0), 1.0))
    m.transmission_weight = float(min(max(m.transmission_weight, 0.0), 1.0))
    m.roughness = float(min(max(m.roughness, 0.0), 1.0))
    return m

