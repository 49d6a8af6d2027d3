"""Baked lightmaps out to glTF 2.0, for web and game engines (MOZ_lightmap).

Blender's own glTF exporter writes the scene; its meshes carry every UV layer
as TEXCOORD_n in the mesh's order, the `Lightmap` layer among them. This
module then adds each baked object's lightmap to the file: an image, a
texture, and Mozilla Hubs' `MOZ_lightmap` extension (read by Hubs and
three.js-based viewers; Khronos has no lightmap extension) on the object's
materials, naming the texture and the Lightmap layer's TEXCOORD index.
Lightmaps are per object and materials are shared, so a material gets one
copy per lightmapped object (and a mesh shared by several such objects, one
copy per object).

Encodings (the lightmap holds E/π, linear, unbounded):
- RGBM (default): 8-bit PNG inside the file, rgb = value / (a·M), the
  multiplier a in alpha, decoded as rgb·a·M with M = RGBM_RANGE; values above
  M clip. The texture's extras say so (`photon_lightmaps.encoding`, `range`).
- EXR: the float image beside the file (`<file stem>_<object>.exr`, by uri),
  for engines that read OpenEXR.

A directional bake's images (engine/transport/directional_lightmap.py) go along
as textures that the object's materials name in their extras,
`photon_lightmaps.directional`, with the same TEXCOORD (no extension carries
them): the dominant direction u (|u| <= 1) as an 8-bit PNG of 0.5 + 0.5 u, or
L1 SH's three images, as 8-bit PNGs of each coefficient over the lightmap,
0.5 + L1 / (4 E) (values beyond ±2 E clip). With EXR, all are floats as baked.
"""
import copy
import json
import os
import struct
import tempfile

import numpy as np

from ..engine.core.errors import SceneError
from . import images

EXTENSION = "MOZ_lightmap"
RGBM_RANGE = 8.0
ENCODINGS = ("RGBM", "EXR")
_GLB_MAGIC, _JSON, _BIN = b"glTF", 0x4E4F534A, 0x004E4942


def rgbm_encode(rgb, m_range=RGBM_RANGE):
    """Linear RGB (..., 3) -> RGBM bytes (..., 4) uint8 (alpha: the multiplier over range)."""
    rgb = np.clip(np.asarray(rgb, np.float64), 0.0, m_range)
    m = np.clip(rgb.max(axis=-1, keepdims=True) / m_range, 1.0 / 255.0, 1.0)
    m = np.ceil(m * 255.0) / 255.0
    enc = np.round(rgb / (m * m_range) * 255.0)
    return np.concatenate([enc, np.round(m * 255.0)], axis=-1).clip(0, 255).astype(np.uint8)


def rgbm_decode(rgbm, m_range=RGBM_RANGE):
    """RGBM bytes (..., 4) -> linear RGB (..., 3)."""
    q = np.asarray(rgbm, np.float64) / 255.0
    return q[..., :3] * q[..., 3:4] * m_range


def lightmapped_objects(scene):
    """{object name: (its baked lightmap image, Lightmap UV layer index)} of the scene's meshes."""
    out = {}
    for ob in scene.objects:
        if ob.type != "MESH":
            continue
        img = images.our_image(ob)
        uv = ob.data.uv_layers.find("Lightmap")
        if img is not None and uv >= 0 and img.size[0] > 0:
            out[ob.name] = (img, uv)
    return out


def directional_images(ob, size):
    """(mode, images) of `ob`'s directional bake whose images match its lightmap's size:
    ("dominant", [direction]), ("sh", [L1x, L1y, L1z]), or None."""
    sh = [images.our_image(ob, images.L1[a]) for a in "xyz"]
    if all(img is not None and tuple(img.size) == tuple(size) for img in sh):
        return "sh", sh
    img = images.our_image(ob, images.DIRECTION)
    if img is not None and tuple(img.size) == tuple(size):
        return "dominant", [img]
    return None


def signed_png(values, E=None):
    """A directional image's signed values (..., 3) as 8-bit RGBA: the dominant
    direction u as 0.5 + 0.5 u; L1, given the lightmap E, as 0.5 + L1 / (4 E)."""
    if E is None:
        c = 0.5 + 0.5 * np.clip(values, -1.0, 1.0)
    else:
        ratio = np.divide(values, E, out=np.zeros_like(values), where=E > 0.0)
        c = 0.5 + 0.25 * np.clip(ratio, -2.0, 2.0)
    rgb = np.round(c * 255.0)
    return np.concatenate([rgb, np.full(rgb.shape[:-1] + (1,), 255.0)], axis=-1).astype(np.uint8)


def signed_decode(rgba8, E=None):
    """signed_png's inverse (E: the decoded lightmap, for L1)."""
    c = np.asarray(rgba8, np.float64)[..., :3] / 255.0
    return 2.0 * c - 1.0 if E is None else (4.0 * c - 2.0) * E


def export_gltf(context, path, *, encoding="RGBM", m_range=RGBM_RANGE):
    """Writes the scene to `path` (.glb or .gltf) through Blender's glTF exporter with each
    baked object's lightmap (MOZ_lightmap) -> report {"objects": {name: {...}}, "skipped": [...]}."""
    import bpy
    encoding = str(encoding).upper()
    if encoding not in ENCODINGS:
        raise SceneError(f"lightmap encoding '{encoding}': use one of {', '.join(e.lower() for e in ENCODINGS)}")
    path = os.path.abspath(path)
    glb = path.lower().endswith(".glb")
    if not (glb or path.lower().endswith(".gltf")):
        raise SceneError(f"{path}: the file name must end in .glb or .gltf")
    maps = lightmapped_objects(context.scene)
    meshes = [ob.name for ob in context.scene.objects if ob.type == "MESH"]
    skipped = sorted(n for n in meshes if n not in maps)
    if not maps:
        raise SceneError("no baked lightmaps to export: bake first (Render > Bake Photon Lightmaps, "
                         "or the CLI's export-gltf --bake)")
    with tempfile.TemporaryDirectory() as tmp:
        raw = os.path.join(tmp, "scene.glb")
        bpy.ops.export_scene.gltf(filepath=raw, export_format="GLB", export_texcoords=True, use_selection=False)
        gltf, blob = read_glb(raw)
    blob = bytearray(blob)
    report = {}
    for name, (img, uv) in sorted(maps.items()):
        rgba = _pixels(img)
        if encoding == "RGBM":
            png = _png_bytes(rgbm_encode(rgba[::-1, :, :3], m_range))      # glTF images: top row first
            source = _add_image(gltf, blob, png, f"{name}_Lightmap")
            extras = {"photon_lightmaps": {"encoding": "RGBM", "range": m_range, "quantity": "E/pi"}}
            error = float(np.abs(rgbm_decode(rgbm_encode(rgba[..., :3], m_range), m_range)
                                 - np.clip(rgba[..., :3], 0.0, m_range)).max())
        else:
            source = _exr_image(gltf, path, rgba, name, "")
            extras = {"photon_lightmaps": {"encoding": "EXR", "quantity": "E/pi"}}
            error = 0.0
        texture = _add_texture(gltf, source, extras)
        directional = _add_directional(gltf, blob, path, context.scene.objects[name], rgba, encoding, uv)
        n_mat = _attach(gltf, name, texture, uv, directional)
        report[name] = {"texture": texture, "texcoord": uv, "materials": n_mat, "width": img.size[0],
                        "height": img.size[1], "encoding": encoding, "max_encoding_error": error,
                        "directional": directional}
    used = gltf.setdefault("extensionsUsed", [])
    if EXTENSION not in used:
        used.append(EXTENSION)
    if glb:
        write_glb(path, gltf, bytes(blob))
    else:
        base = os.path.splitext(path)[0] + ".bin"
        with open(base, "wb") as f:
            f.write(blob)
        gltf["buffers"][0]["uri"] = os.path.basename(base)
        with open(path, "w") as f:
            json.dump(gltf, f, indent=1)
    return {"path": path, "objects": report, "skipped": skipped}


def _add_directional(gltf, blob, path, ob, lightmap, encoding, uv):
    """The object's directional images as textures -> the materials' extras entry
    (None: it has none)."""
    found = directional_images(ob, lightmap.shape[1::-1])
    if found is None:
        return None
    mode, imgs = found
    textures = []
    for img, suffix in zip(imgs, ("_direction",) if mode == "dominant" else ("_l1x", "_l1y", "_l1z")):
        rgba = _pixels(img)
        if encoding == "RGBM":
            png = signed_png(rgba[::-1, :, :3], None if mode == "dominant" else lightmap[::-1, :, :3])
            source = _add_image(gltf, blob, _png_bytes(png), ob.name + suffix)
        else:
            source = _exr_image(gltf, path, rgba, ob.name, suffix)
        textures.append({"index": _add_texture(gltf, source), "texCoord": uv})
    if encoding == "RGBM":
        decode = "u = 2 c - 1" if mode == "dominant" else "L1 = (4 c - 2) * lightmap"
    else:
        decode = "as stored (world space; L1 in the lightmap's units, E/pi)"
    key = "direction" if mode == "dominant" else "l1"
    return {"mode": mode, key: textures[0] if mode == "dominant" else textures, "decode": decode}


def _attach(gltf, name, texture, uv, directional=None):
    """MOZ_lightmap on the materials of node `name`'s primitives (copies per object), and
    a directional bake's textures in their extras -> count."""
    nodes = [n for n in gltf.get("nodes", []) if n.get("name") == name and "mesh" in n]
    if not nodes:
        raise SceneError(f"object '{name}': not in the exported glTF (hidden, or not exported)")
    node = nodes[0]
    users = sum(1 for n in gltf["nodes"] if n.get("mesh") == node["mesh"])
    if users > 1:                              # its own mesh, so its materials can differ
        gltf["meshes"].append(copy.deepcopy(gltf["meshes"][node["mesh"]]))
        node["mesh"] = len(gltf["meshes"]) - 1
    materials = gltf.setdefault("materials", [])
    count = 0
    for prim in gltf["meshes"][node["mesh"]]["primitives"]:
        if f"TEXCOORD_{uv}" not in prim["attributes"]:
            raise SceneError(f"object '{name}': its Lightmap UV layer (TEXCOORD_{uv}) was not exported")
        base = copy.deepcopy(materials[prim["material"]]) if "material" in prim else {}
        base["name"] = f"{base.get('name', 'material')}_{name}"
        base.setdefault("extensions", {})[EXTENSION] = {"index": texture, "texCoord": uv, "intensity": 1.0}
        if directional is not None:
            base.setdefault("extras", {}).setdefault("photon_lightmaps", {})["directional"] = directional
        materials.append(base)
        prim["material"] = len(materials) - 1
        count += 1
    return count


def _pixels(img):
    w, h = img.size
    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    return px.reshape(h, w, 4)


def _png_bytes(rgba8):
    """8-bit RGBA (rows top first) as PNG file bytes, written raw (no colour transform) by Blender."""
    import bpy
    h, w = rgba8.shape[:2]
    img = bpy.data.images.new("photon_lightmaps_png", w, h, alpha=True, float_buffer=False)
    try:
        img.colorspace_settings.name = "Non-Color"
        img.pixels.foreach_set((rgba8[::-1].astype(np.float32) / 255.0).reshape(-1))
        with tempfile.TemporaryDirectory() as tmp:
            file = os.path.join(tmp, "map.png")
            img.filepath_raw = file
            img.file_format = "PNG"
            img.save()
            with open(file, "rb") as f:
                return f.read()
    finally:
        bpy.data.images.remove(img)


def _save_exr(rgba, file):
    import bpy
    h, w = rgba.shape[:2]
    img = bpy.data.images.new("photon_lightmaps_exr", w, h, alpha=True, float_buffer=True)
    try:
        img.pixels.foreach_set(rgba.astype(np.float32).reshape(-1))
        img.filepath_raw = file
        img.file_format = "OPEN_EXR"
        img.save()
    finally:
        bpy.data.images.remove(img)


def _exr_image(gltf, path, rgba, name, suffix):
    """Object `name`'s image (suffix: which of its images; "": the lightmap) as an
    OpenEXR file beside the glTF file, named by uri -> its image index."""
    stem = os.path.splitext(os.path.basename(path))[0]
    file = f"{stem}_{images.file_name(name)}{suffix}.exr"
    _save_exr(rgba, os.path.join(os.path.dirname(path), file))
    gltf.setdefault("images", []).append({"name": name + (suffix or "_Lightmap"), "uri": file})
    return len(gltf["images"]) - 1


def _add_texture(gltf, source, extras=None):
    """A texture of image `source`, filtered linearly -> its index."""
    gltf.setdefault("samplers", []).append({"magFilter": 9729, "minFilter": 9729})
    texture = {"source": source, "sampler": len(gltf["samplers"]) - 1}
    if extras is not None:
        texture["extras"] = extras
    gltf.setdefault("textures", []).append(texture)
    return len(gltf["textures"]) - 1


def _add_image(gltf, blob, data, name):
    """An image embedded in the binary chunk -> its index."""
    blob.extend(b"\0" * (-len(blob) % 4))
    gltf.setdefault("bufferViews", []).append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
    blob.extend(data)
    gltf["buffers"][0]["byteLength"] = len(blob)
    gltf.setdefault("images", []).append({"name": name, "mimeType": "image/png",
                                          "bufferView": len(gltf["bufferViews"]) - 1})
    return len(gltf["images"]) - 1


def read_glb(path):
    """(JSON dict, binary chunk bytes) of a GLB file."""
    with open(path, "rb") as f:
        data = f.read()
    magic, _version, length = struct.unpack_from("<4sII", data, 0)
    if magic != _GLB_MAGIC or length != len(data):
        raise SceneError(f"{path}: not a GLB file")
    n, kind = struct.unpack_from("<II", data, 12)
    gltf = json.loads(data[20:20 + n])
    blob = b""
    if 20 + n < len(data):
        m, kind = struct.unpack_from("<II", data, 20 + n)
        blob = data[28 + n:28 + n + m]
    return gltf, blob


def write_glb(path, gltf, blob):
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    total = 12 + 8 + len(text) + (8 + len(blob) if blob else 0)
    with open(path, "wb") as f:
        f.write(struct.pack("<4sII", _GLB_MAGIC, 2, total))
        f.write(struct.pack("<II", len(text), _JSON) + text)
        if blob:
            f.write(struct.pack("<II", len(blob), _BIN) + blob)
