"""Baked arrays -> Blender images and OpenEXR files: the image policy and the one save-or-pack.

Image policy. An image we made carries the custom property ``photon_lightmaps_object``
and is updated in place by the next bake. An image of the same name that we did
not make belongs to the user: with ``overwrite`` it is replaced (its users are
remapped to the new image); otherwise the bake writes a new image with a unique
name (".001", ...) and says so in the warnings.

Files. `save_dir` saves "<dir>/<name>.exr"; otherwise an image is saved to
"//lightmaps/<name>.exr" next to a saved .blend, or packed with `pack`.
OpenEXR, 32-bit float, ZIP, RGBA, alpha stored as is (images use the
"Channel Packed" alpha mode: coverage is data, not transparency).
"""
import math
import os
import re
import tempfile
from dataclasses import dataclass

import numpy as np

from ..engine.lightmaps import lightmap
from ..engine.transport import open_area
from ..engine.shading import spectrum
from ..engine.shading.texture import srgb_to_linear
from ..messages import InputError

IMAGE_SUFFIX = "_Lightmap"
OWNER_PROP = "photon_lightmaps_object"
# the bake's error image: its own name and owner tag, so it never takes the lightmap's place
ERROR = "error"
ERROR_FILE_SUFFIX = "_error"
# texel validity's image (R: the share of rays meeting back faces; invalid texels red, valid green)
VALIDITY = "validity"
VALIDITY_FILE_SUFFIX = "_validity"
# a directional bake's image (RGB: the light's share k times its direction s, world space)
DIRECTION = "direction"
DIRECTION_FILE_SUFFIX = "_direction"
# an L1 SH bake's images, one per axis (RGB: that axis's first-order coefficient per colour)
L1 = {a: "l1" + a for a in "xyz"}
L1_FILE_SUFFIX = {a: "_l1" + a for a in "xyz"}
_KINDS = {"": (IMAGE_SUFFIX, OWNER_PROP), ERROR: ("_LightmapError", "photon_lightmaps_error_of"),
          VALIDITY: ("_LightmapValidity", "photon_lightmaps_validity_of"),
          DIRECTION: ("_LightmapDirection", "photon_lightmaps_direction_of"),
          **{L1[a]: ("_LightmapL1" + a, "photon_lightmaps_l1" + a + "_of") for a in "xyz"}}
LIGHTMAP_DIR = "lightmaps"


@dataclass
class BakedMap:
    """One object's lightmap as an image: rgba float32 (height, width, 4), rows bottom-up."""
    object_name: str
    rgba: np.ndarray
    lightmap_id: int
    # CSG solids: leaf object name -> (x, y, width, height) of its block in texels
    tiles: dict = None

    @property
    def width(self):
        return int(self.rgba.shape[1])

    @property
    def height(self):
        return int(self.rgba.shape[0])

    def mean(self):
        """Coverage-weighted mean RGB over the texels a UV triangle touches."""
        a = self.rgba[..., 3].astype(np.float64)
        if a.sum() <= 0:
            return [0.0, 0.0, 0.0]
        return [float((self.rgba[..., c] * a).sum() / a.sum()) for c in range(3)]


def _baked(lm, lm_id):
    """(E per texel and band, width, height, texel slice) of lightmap `lm_id`."""
    sl = lightmap.texel_slice(lm, lm_id)
    return open_area.baked(lm, np.arange(sl.start, sl.stop)), int(lm.width[lm_id]), int(lm.height[lm_id]), sl


def lightmap_rgba(lm, lm_id, bands=None):
    """Lightmap `lm_id` as float32 (height, width, 4): RGB = E/pi, A = coverage.
    bands: the spectrum.Bands of a spectral scene, whose band values go to Rec.709."""
    e, w, h, sl = _baked(lm, lm_id)
    rgba = np.zeros((h * w, 4), np.float32)
    rgba[:, :3] = spectrum.as_rgb(e, bands) / math.pi
    rgba[:, 3] = lm.coverage[sl]
    return rgba.reshape(h, w, 4)


def texel_rgba(lm, lm_id, channels):
    """Lightmap `lm_id`'s rows of `channels` (every lightmap row's four values, as
    shadowmask.mask_channels gives) as float32 (height, width, 4)."""
    sl = lightmap.texel_slice(lm, lm_id)
    return channels[sl].astype(np.float32).reshape(int(lm.height[lm_id]), int(lm.width[lm_id]), 4)


def lightmap_bands(lm, lm_id):
    """Lightmap `lm_id` as float32 (height, width, n_bands): E/pi per band, as traced
    (a spectral scene's wavelength bands: bake/spectral_exr.py)."""
    e, w, h, _ = _baked(lm, lm_id)
    return (e / math.pi).astype(np.float32).reshape(h, w, -1)


def file_name(name):
    # Object names may hold path separators or characters file systems refuse.
    return re.sub(r'[\\/:*?"<>|\x00-\x1f]', "_", name).strip() or "object"


def our_image(ob, kind=""):
    import bpy
    suffix, owner = _KINDS[kind]
    base = ob.name + suffix
    ours = [im for im in bpy.data.images if im.library is None and im.get(owner) == ob.name]
    ours.sort(key=lambda im: (im.name != base, im.name))
    return ours[0] if ours else None


def _new_image(name, w, h):
    import bpy
    img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    img.use_half_precision = False
    img.alpha_mode = "CHANNEL_PACKED"
    img.colorspace_settings.name = "Linear Rec.709"
    return img


def target_image(ob, w, h, overwrite, warnings, kind=""):
    """The image to write object `ob`'s lightmap (kind ERROR, VALIDITY: its error or validity image) into,
    following the module's policy."""
    import bpy
    suffix, owner = _KINDS[kind]
    base = ob.name + suffix
    img = our_image(ob, kind)
    if img is None:
        existing = bpy.data.images.get(base)
        if existing is None:
            img = _new_image(base, w, h)
        elif overwrite and existing.library is None:
            img = existing
            warnings.append(f"image '{base}' was replaced (overwrite)")
        else:
            img = _new_image(base, w, h)   # Blender appends .001, .002, ...
            warnings.append(f"image '{base}' already exists and is not a Photon Lightmaps bake: "
                            f"kept it, wrote '{img.name}' instead (bake with overwrite to replace it)")
    if (not img.is_float or img.channels != 4 or tuple(img.size) != (w, h)
            or img.source not in ("GENERATED", "FILE") or img.packed_file is not None):
        # Rebuild it as a fresh float image; its users (materials) follow via remap.
        name = img.name
        fresh = _new_image(name + ".photon_tmp", w, h)
        img.user_remap(fresh)
        bpy.data.images.remove(img)
        fresh.name = name
        img = fresh
    img.alpha_mode = "CHANNEL_PACKED"
    img.use_half_precision = False
    img[owner] = ob.name
    # a bake's image stays in the .blend when it is saved, before any material uses it
    # (Blender drops images without users)
    img.use_fake_user = True
    return img


def _exr_scene():
    import bpy
    sc = bpy.data.scenes.new("photon_lightmaps_exr_settings")
    s = sc.render.image_settings
    s.file_format = "OPEN_EXR"
    s.color_depth = "32"
    s.exr_codec = "ZIP"
    s.color_mode = "RGBA"
    return sc


def write_exr(img, path):
    """Writes a float image as OpenEXR 32-bit RGBA, ZIP, values as stored (linear, no view transform)."""
    import bpy
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    sc = _exr_scene()
    try:
        # save_render takes format and codec from a scene; a scratch one leaves the user's alone.
        img.save_render(path, scene=sc)
    finally:
        bpy.data.scenes.remove(sc)


def _save_exr(img, path, relative):
    import bpy
    # Write beside the target, then rename: a crash never leaves half a file.
    os.makedirs(os.path.dirname(path), exist_ok=True)
    tmp = f"{path}.{os.getpid()}.tmp.exr"
    try:
        write_exr(img, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    img.filepath_raw = bpy.path.relpath(path) if relative else path
    img.file_format = "OPEN_EXR"
    if img.source != "FILE":
        img.source = "FILE"
    else:
        img.reload()


def _pack_exr(img, filepath):
    with tempfile.TemporaryDirectory() as d:
        tmp = os.path.join(d, "lightmap.exr")
        write_exr(img, tmp)
        img.filepath_raw = tmp
        img.file_format = "OPEN_EXR"
        if img.source != "FILE":
            img.source = "FILE"
        else:
            img.reload()
        img.pack()
    img.filepath_raw = filepath   # where "Unpack" will put it


def check_output(save_dir=None, pack=False):
    """Checks the folder the next store() calls will write to, before any image is touched."""
    import bpy
    check_writable(save_dir or (None if pack or not bpy.data.filepath else f"//{LIGHTMAP_DIR}"))


def store(img, name, *, save_dir=None, pack=False):
    """Saves or packs a written image after the policy above -> saved path (None: packed or unsaved).

    The one copy for the lightmap bake and the orientation-lightmap bake."""
    import bpy
    fname = file_name(name) + ".exr"
    if save_dir:
        path = os.path.join(os.path.abspath(bpy.path.abspath(save_dir)), fname)
        _save_exr(img, path, relative=False)
        return path
    if pack:
        _pack_exr(img, f"//{LIGHTMAP_DIR}/{fname}")
        return None
    if bpy.data.filepath:
        path = bpy.path.abspath(f"//{LIGHTMAP_DIR}/{fname}")
        _save_exr(img, path, relative=True)
        return path
    return None


def in_memory_only(save_dir=None, pack=False):
    """True when store() keeps the images only in memory (an unsaved .blend)."""
    import bpy
    return not (save_dir or pack or bpy.data.filepath)


def write_pixels(img, rgba):
    img.pixels.foreach_set(np.ascontiguousarray(rgba, np.float32).reshape(-1))
    img.update()


def current_pixels(image, width, height):
    """An image's pixels as the linear RGBA Blender's bake would turn back into them."""
    if image is None or tuple(image.size) != (width, height):
        return None
    px = np.empty(width * height * image.channels, np.float32)
    image.pixels.foreach_get(px)
    px = px.reshape(height, width, image.channels)
    out = np.ones((height, width, 4), np.float32)
    out[..., :min(4, image.channels)] = px[..., :4]
    if not image.is_float and image.colorspace_settings.name == "sRGB":
        out[..., :3] = srgb_to_linear(out[..., :3])
    return out


def check_writable(folder, what="the lightmaps"):
    """Creates the output folder (a Blender "//" path is fine) -> raises an InputError if it cannot take files
    (`what`: what would be written there, for the message)."""
    import bpy
    if not folder:
        return
    path = os.path.abspath(bpy.path.abspath(folder))
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".photon_lightmaps_probe"):
            pass
    except OSError as exc:
        raise InputError(f"{path}: cannot write {what} there ({exc.strerror or exc}); "
                         "choose another folder") from exc
