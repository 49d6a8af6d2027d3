"""Ambient occlusion per texel: a bake pass for game engines that mix it with their own light.

A texel's AO is the share of cosine-weighted rays from its surface, on the
side its normal faces, that leave without meeting geometry within `distance`
(Cycles' AO bake, with the world's AO distance). It is also the irradiance
that a sky of radiance 1 seen through that occlusion would give, over π: so
the pass is stored as that irradiance, E = π·AO, and the bake's usual E/π
writes AO into the image, dilation and texel areas as for light.

Points are spread over the texel's surface, `points` of them, each with `rays`
rays stratified over the hemisphere (texel_rays.py, its OCCLUSION query), from
the texel's own random stream (xored with AO_XOR). Every surface occludes,
whatever its material, as in Cycles.
"""
import math

import numpy as np

from . import texel_rays

AO_XOR = np.uint64(0x3C6EF372FE94F82B)
DEFAULT_POINTS = 16
DEFAULT_RAYS = 16


def texel_ao(cs, lightmap_ids, distance, points=DEFAULT_POINTS, rays=DEFAULT_RAYS, seed=0, csg_leaves=()):
    """AO of the measured texels of the given instance lightmaps and CSG leaves
    ((instance, csg_bake.solid_leaves entry) pairs: over the solid's boundary only)
    -> (texel ids, AO float64[K])."""
    if not float(distance) > 0.0:
        raise ValueError(f"AO distance must be positive, got {distance}")
    ids, ao = texel_rays.per_texel(cs, lightmap_ids, texel_rays.OCCLUSION, points=points, rays=rays, xor=AO_XOR,
                                   seed=seed, distance=distance, csg_leaves=csg_leaves)
    return ids, ao[:, 0]


def bake_ao(cs, lightmap_ids, distance, points=DEFAULT_POINTS, rays=DEFAULT_RAYS, seed=0, csg_leaves=()):
    """The AO pass into cs.lightmaps: E = π·AO on every measured texel (the photon
    flux replaced), then finalize (dilation) -> (texel ids, AO)."""
    from .bake_gather import set_gathered
    ids, ao = texel_ao(cs, lightmap_ids, distance, points, rays, seed, csg_leaves)
    nb = cs.lightmaps.flux.shape[1]
    cs.lightmaps.flux[:] = 0.0
    set_gathered(cs.lightmaps, (ids, np.repeat(math.pi * ao[:, None], nb, axis=1)),
                 (np.zeros(0, np.int64), np.zeros((0, nb))))
    return ids, ao
