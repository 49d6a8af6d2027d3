"""A spectral lightmap as a multi-band OpenEXR file, in the spectral OpenEXR layout
(Fichet, Pacanowski and Wilkie 2021, "An OpenEXR Layout for Spectral Images").

Each band is one channel named by its central wavelength, "S0.<nm>nm" with a
decimal comma, as the layout names an emissive image's channels (S0: the first
Stokes component, unpolarized light). The values are what the RGB lightmap
holds, E/π per band: the radiance a white Lambertian surface sends back, in
W m⁻² sr⁻¹ per band (a band's irradiance, not per nm). Written with the OpenEXR
package (PyPI `OpenEXR`), 32-bit float, ZIP.
"""
import numpy as np

LAYOUT_VERSION = "1.0"


def channel_name(nm):
    """The layout's channel name of a band centred at nm: 'S0.392,500000nm'."""
    return f"S0.{float(nm):.6f}nm".replace(".", ",").replace("S0,", "S0.", 1)


def write(path, values, bands):
    """Writes values (height, width, bands.n), row 0 at the bottom as Blender stores
    images, to path as a multi-band OpenEXR (rows flipped to the file's top-down order)."""
    try:
        import OpenEXR
    except ImportError:
        raise RuntimeError("spectral EXR files need the OpenEXR package (pip install OpenEXR)") from None
    values = np.asarray(values, np.float32)
    if values.ndim != 3 or values.shape[2] != int(bands.n):
        raise ValueError(f"spectral EXR: need (height, width, {bands.n}) values, got {values.shape}")
    centres = bands.lo + (np.arange(bands.n) + 0.5) * (bands.hi - bands.lo) / bands.n
    channels = {channel_name(nm): np.ascontiguousarray(values[::-1, :, k]) for k, nm in enumerate(centres)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "spectralLayoutVersion": LAYOUT_VERSION, "emissiveUnits": "W.m^-2.sr^-1"}
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def read(path):
    """(values (height, width, n) bottom row first, band centres nm (n,)) of a file `write` wrote."""
    import OpenEXR
    with OpenEXR.File(str(path)) as f:
        chans = {name: c.pixels for name, c in f.channels().items() if name.startswith("S0.")}
    nm = {name: float(name[3:-2].replace(",", ".")) for name in chans}
    order = sorted(chans, key=nm.get)
    return np.stack([chans[k][::-1] for k in order], axis=2), np.array([nm[k] for k in order])
