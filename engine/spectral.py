"""Spectral mode: an RGB scene made spectral before it is compiled.

The tracer carries colour as (..., n_bands) arrays whatever the bands mean, so
spectral mode is a change of scene, not of kernels: every colour of the scene
becomes a band spectrum (engine/shading/spectrum.py) and the compiled scene
remembers its bands, so renders and bakes can be turned back into Rec.709 at
the end (`to_rgb`). No kernel is compiled for it: the kernels' types do not
depend on the number of bands.

* Reflectances (diffuse, specular, transmission and base colours) become Jakob &
  Hanika spectra. Each lobe is fitted on its own; where the lobes of a material
  would then sum above 1 in some band, they are scaled down there, so no
  surface makes light.
* A blackbody light (Blender's light temperature) or glowing surface (a
  Blackbody node on its emission colour) emits Planck's spectrum times its
  tint, at its colour's luminance.
* A line light (an LED, a UV lamp) emits a Gaussian line with a white light's
  power, whatever its colour (which RGB mode uses); a line outside the bands
  would emit nothing there, and is refused.
* Emitted colours (lights, glowing surfaces, a constant world) become their
  brightest channel times a reflectance times the white light.
* A grey (a scalar, or equal channels) stays flat: a grey is a grey in every band.

* A base-colour texture keeps its RGB; each hit turns the colour it reads into
  a spectrum through the spectra of an RGB grid (spectrum.rgb_table).

* A world image map's pixels become emission spectra through the same grid, so
  each keeps its RGB.
"""
import math
from dataclasses import replace

import numpy as np

from .core.scene import EnvironmentMap, SceneError
from .shading import spectrum

def spectral_scene(scene, bands=None):
    """A copy of RGB `scene` (n_bands 3) with every colour a spectrum over `bands`
    (spectrum.Bands; None: the default 16) -> Scene with n_bands = bands.n."""
    bands = bands or spectrum.Bands()
    if int(scene.n_bands) != 3:
        raise SceneError(f"spectral mode: the scene must be RGB (3 bands), it has {scene.n_bands}")
    mats = []
    for m in scene.materials:
        d, s, t = (_reflectance(getattr(m, k), bands) for k in ("diffuse", "specular", "transmission"))
        total = _as_array(d, bands) + _as_array(s, bands) + _as_array(t, bands)
        over = np.maximum(total, 1.0)
        if np.any(over > 1.0):
            d, s, t = (_as_array(x, bands) / over for x in (d, s, t))
        kelvin = float(getattr(m, "emission_temperature", 0.0) or 0.0)
        glow = _blackbody(m.emission, kelvin, bands, f"material '{m.name}'") \
            if kelvin > 0.0 or not math.isfinite(kelvin) else _emission(m.emission, bands)
        mats.append(replace(m, diffuse=d, specular=s, transmission=t, base_color=_reflectance(m.base_color, bands),
                            emission=glow))
    lights = [replace(lt, color=_light(lt, bands)) for lt in scene.lights]
    env = scene.environment
    env = _world_map(env, bands) if isinstance(env, EnvironmentMap) else _emission(env, bands)
    return replace(scene, n_bands=int(bands.n), materials=mats, lights=lights, environment=env, spectral=bands)


def to_rgb(cs, image):
    """An (..., n_bands) result of compiled scene `cs` in Rec.709: converted when
    `cs` is spectral, as it is otherwise."""
    bands = getattr(cs, "spectral", None)
    return image if bands is None else spectrum.to_rgb(image, bands)


def _rgb(value):
    """value as an RGB triple, or None when it is a grey (stays a scalar)."""
    a = np.asarray(value, np.float64).reshape(-1)
    if a.size == 1 or np.all(a == a[0]):
        return None
    if a.size != 3:
        raise SceneError(f"spectral mode: a colour must have 3 channels, got {a.size}")
    return a


def _reflectance(value, bands):
    rgb = _rgb(value)
    if rgb is None:
        return float(np.asarray(value, np.float64).reshape(-1)[0])
    return spectrum.reflectance_spectrum(np.clip(rgb, 0.0, 1.0), bands)


def _emission(value, bands):
    rgb = _rgb(value)
    if rgb is None:
        grey = float(np.asarray(value, np.float64).reshape(-1)[0])
        # a grey light is white light of that brightness (D65), not a flat spectrum
        return grey * bands.white if grey else 0.0
    return spectrum.emission_spectrum(np.maximum(rgb, 0.0), bands)


def _light(light, bands):
    """A light's spectrum: its colour's, or for a blackbody light Planck's spectrum
    times its tint (the colour over the blackbody's own RGB), at the colour's luminance."""
    line = float(getattr(light, "line_nm", 0.0) or 0.0)
    if line > 0.0:
        width = float(light.line_width)
        if not (math.isfinite(line) and math.isfinite(width) and width > 0.0):
            raise SceneError(f"light '{light.name}': a line spectrum needs a finite wavelength and a width "
                             f"above 0 nm, got {line} and {width}")
        s = spectrum.line_spectrum(line, width, bands)
        if not s.sum() > 1e-3 * bands.white.sum():
            raise SceneError(f"light '{light.name}': its line at {line:g} nm lies outside the spectral bands "
                             f"({bands.lo:g}-{bands.hi:g} nm); move it inside them")
        return s
    kelvin = float(getattr(light, "temperature", 0.0) or 0.0)
    if kelvin <= 0.0:
        return _emission(light.color, bands)
    return _blackbody(light.color, kelvin, bands, f"light '{light.name}'")


def _blackbody(colour, kelvin, bands, what):
    """Planck's spectrum at kelvin times the tint (colour over the blackbody's own RGB),
    at the colour's luminance: a blackbody light's or glowing surface's spectrum."""
    if not (math.isfinite(kelvin) and 1.0 <= kelvin <= 1e6):
        raise SceneError(f"{what}: a blackbody temperature must lie between 1 and 1e6 K, got {kelvin}")
    rgb = np.broadcast_to(np.asarray(colour, np.float64), (3,))
    planck = spectrum.blackbody_spectrum(kelvin, bands)
    tint = rgb / np.maximum(spectrum.to_rgb(planck, bands), 1e-12)
    peak = tint.max()
    if not peak > 0.0:
        return 0.0
    s = planck * spectrum.reflectance_spectrum(np.clip(tint / peak, 0.0, 1.0), bands)
    y = float(np.linalg.inv(bands.xyz_to_rgb)[1] @ rgb)      # the colour's luminance
    return s * (y / max(float(spectrum.luminance(s, bands)), 1e-300))


def _world_map(env, bands):
    """A world image map's pixels as emission spectra (each its brightest channel times a
    reflectance times the white light, as a constant world's), through the RGB grid's
    spectra (spectrum.table_spectrum: no fit per pixel), so each pixel keeps its RGB."""
    rgb = np.asarray(env.pixels, np.float64)
    if rgb.ndim != 3 or rgb.shape[2] not in (1, 3):
        raise SceneError(f"world '{env.name}': spectral mode needs an RGB or grey map, got {rgb.shape}")
    if rgb.shape[2] == 1:
        return replace(env, pixels=rgb * bands.white)
    peak = rgb.max(axis=2, keepdims=True)
    safe = np.where(peak > 0.0, peak, 1.0)
    spectra = np.maximum(peak, 0.0) * spectrum.table_spectrum(rgb / safe, bands) * bands.white
    return replace(env, pixels=spectra)


def _as_array(x, bands):
    return np.broadcast_to(np.asarray(x, np.float64), (int(bands.n),)).astype(np.float64)
