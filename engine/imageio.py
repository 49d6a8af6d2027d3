"""A minimal PNG writer, so the core can show images without Blender or PIL."""
import struct
import zlib

import numpy as np


def linear_to_srgb(x):
    x = np.clip(np.nan_to_num(x, nan=0.0, posinf=1.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def to_rgb(img):
    """(H, W, B) band image -> (H, W, 3); 3 bands are taken as linear Rec.709 RGB."""
    img = np.asarray(img, dtype=np.float64)
    if img.shape[2] == 3:
        return img
    if img.shape[2] == 1:
        return np.repeat(img, 3, axis=2)
    raise ValueError("spectral images need a colour conversion (engine.spectrum) before display")


def write_png(path, img, exposure=0.0):
    """Writes a linear (H, W, 3) image as 8-bit sRGB PNG (rows top to bottom)."""
    rgb = to_rgb(img) * (2.0 ** exposure)
    data = (linear_to_srgb(rgb) * 255.0 + 0.5).astype(np.uint8)
    h, w, _ = data.shape
    raw = b"".join(b"\x00" + data[y].tobytes() for y in range(h))

    def chunk(tag, payload):
        return (struct.pack(">I", len(payload)) + tag + payload
                + struct.pack(">I", zlib.crc32(tag + payload) & 0xFFFFFFFF))

    with open(path, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n")
        f.write(chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)))
        f.write(chunk(b"IDAT", zlib.compress(raw, 6)))
        f.write(chunk(b"IEND", b""))
