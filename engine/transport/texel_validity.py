"""Texel validity: texels that lie inside geometry, found by the back faces they see.

A texel under a box standing on the floor, or behind a wall that cuts through
it, holds a surface nothing can see; whatever light or occlusion it reads
there (light leaking in through the box's inside, a box's inner darkness)
bleeds into its visible neighbours through texture filtering. As Unity's
Texel Validity does, rays from points spread over the texel (as the direct
gather's, texel_gather.py) tell: a ray from a point inside a closed object
meets that object's back faces. A texel whose share of rays meeting back
faces is above INVALID_SHARE is invalid; the bake then fills it from its
valid neighbours, as it fills texels outside the charts (`dilate_over`).
Rays leave the side the surface's normal faces (texel_rays.py's BACKFACES
query); each texel follows its own random stream (xored with VALIDITY_XOR).
"""
import numpy as np

from ..lightmaps import lightmap
from . import texel_rays

VALIDITY_XOR = np.uint64(0x9B05688C2B3E6C1F)
INVALID_SHARE = 0.5
DEFAULT_POINTS = 8
DEFAULT_RAYS = 8


def backface_share(cs, lightmap_ids, points=DEFAULT_POINTS, rays=DEFAULT_RAYS, seed=0, csg_leaves=()):
    """Share of rays meeting back faces, per measured texel of the given instance
    lightmaps and CSG leaves ((instance, csg_bake.solid_leaves entry) pairs: over
    the solid's boundary) -> (texel ids, share float64[K])."""
    ids, share = texel_rays.per_texel(cs, lightmap_ids, texel_rays.BACKFACES, points=points, rays=rays,
                                      xor=VALIDITY_XOR, seed=seed, csg_leaves=csg_leaves)
    return ids, share[:, 0]


def dilate_over(lm, rows):
    """Makes texel rows empty (no surface) and fills them, with the texels outside the
    charts, from their valid neighbours (lightmap.finalize's dilation)."""
    rows = np.asarray(rows, np.int64)
    if rows.size:
        lm.area[rows] = 0.0
        lm.open[rows] = 1.0             # a bake writes irradiance x open: the filled value whole
        lightmap.finalize(lm)
