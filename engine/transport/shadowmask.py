"""Shadowmasks: per texel, how much of each of up to four lights reaches it unoccluded.

Game engines that light a scene with dynamic lights but bake their shadows
(Unity's and Godot's shadowmask, Unreal's stationary lights) read one light's
visibility per channel. A texel's visibility of a light is the share of light
samples, from points spread over the texel's surface (as the direct-light
gather's, texel_gather.py), whose shadow ray reaches the light unoccluded: 1 in
full light, 0 in umbra, between in a penumbra. The light's falloff, colour and
the receiver's cosine stay out (the engine applies them); a sample that cannot
light the point at all (outside a spot's cone, behind an area light, below a
surface that a solid closes) counts as occluded. Samples are stratified over
the light (k x k cells of its two random numbers), and each texel follows its
own random stream (xored with MASK_XOR); texel_rays.py's VISIBILITY query.
"""
import math

import numpy as np

from . import texel_rays

MASK_XOR = np.uint64(0x510E527FADE682D1)
MAX_LIGHTS = 4
DEFAULT_POINTS = 16
DEFAULT_SAMPLES = 16


def light_rows(scene, names):
    """The compiled light rows (cs.lights) of the scene's lights named `names`, in that
    order: compile_lights keeps the scene's lights first, in order, less the dark ones."""
    from ..core.errors import SceneError
    rows, row = {}, 0
    for light in scene.lights:
        lit = float(light.power) > 0.0 and np.any(np.asarray(light.color, np.float64) > 0.0)
        if lit:
            rows[light.name] = row
            row += 1
    if not 1 <= len(names) <= MAX_LIGHTS:
        raise SceneError(f"shadowmask: give 1 to {MAX_LIGHTS} lights, got {len(names)}")
    out = []
    for name in names:
        if name not in rows:
            known = ", ".join(sorted(rows)) or "none"
            raise SceneError(f"shadowmask light '{name}': not a light that emits in this scene (lights: {known})")
        out.append(rows[name])
    return np.asarray(out, np.int64)


def texel_visibility(cs, lightmap_ids, lights, points=DEFAULT_POINTS, samples=DEFAULT_SAMPLES, seed=0,
                     csg_leaves=()):
    """Visibility of the compiled lights `lights` (rows of cs.lights) over the measured
    texels of the given instance lightmaps and CSG leaves ((instance, leaf) pairs: over
    the solid's boundary) -> (texel ids, V float64[K, len(lights)])."""
    return texel_rays.per_texel(cs, lightmap_ids, texel_rays.VISIBILITY, points=points, rays=samples,
                                xor=MASK_XOR, seed=seed, lights=lights, csg_leaves=csg_leaves)


def mask_channels(cs, ids, V):
    """The visibilities V (K, L <= 4) of texels `ids` as every lightmap row's four channels,
    each dilated into empty texels as light is (finalize), in the whole-texel means a bake
    writes (open_area.baked) -> float64 (rows, 4); channels past L are 0. cs.lightmaps is
    used for the dilation: afterwards it holds the last round's values."""
    from .bake_gather import set_gathered
    from .open_area import baked
    lm = cs.lightmaps
    nb = lm.flux.shape[1]
    rows = np.arange(lm.area.shape[0])
    out = np.zeros((rows.size, MAX_LIGHTS))
    for first in range(0, V.shape[1], nb):
        part = V[:, first:first + nb]
        E = np.zeros((ids.size, nb))
        E[:, :part.shape[1]] = math.pi * part
        lm.flux[:] = 0.0
        set_gathered(lm, (ids, E), (np.zeros(0, np.int64), np.zeros((0, nb))))
        out[:, first:first + part.shape[1]] = baked(lm, rows)[:, :part.shape[1]] / math.pi
    return out
