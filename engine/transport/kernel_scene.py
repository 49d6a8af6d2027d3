"""The compiled scene as one record, as the transport kernels take it.

pbrt's integrator owns its aggregate and its lights; here `KernelScene` is
that owner: the photon pass, the render tiles and the gathers take it as one
argument instead of the ten arrays-of-arrays it holds, and read what they need
by name (`scene.geometry`, `scene.lights`, ...). It is a plain named tuple, so
numba passes it by reference and a kernel compiled without the NRT reads its
fields at no cost; a field's type is part of the kernel's signature, so a
scene without caustic lightmaps or orientation lightmaps compiles the same
kernels as one with them (the empty stand-ins have the same types).
"""
from collections import namedtuple

import numpy as np

from ..lightmaps import orientation_lightmap
from ..shading.lights import light_subset

KernelScene = namedtuple("KernelScene", [
    "geometry",       # geometry.assembly.Geometry
    "materials",      # shading.materials.MaterialSet
    "bsdf",           # shading.bsdf.BsdfTables
    "textures",       # shading.texture.TextureSet
    "lights",         # shading.lights.LightSet (aimed for a photon pass, shading/photon_aim.py)
    "lightmaps",      # the photon lightmaps (lightmaps/lightmap.py)
    "caustic_maps",   # the caustic lightmaps, or the photon lightmaps again when they are not read
    "caustics",       # bool: caustic_maps are the caustic lightmaps
    "orientation",    # orientation lightmaps (empty maps in a scene without them)
    "environment",    # shading.environment.EnvMap
    "inst_side",      # int64 per instance: the side a gather ray must meet it from (empty: no test)
    "gather_lights",  # shading.lights.LightSet: the lights gather rays sample where they land (empty: none)
])


def kernel_scene(cs, lights=None, caustics=None, inst_side=None):
    """The record of compiled scene `cs`.

    lights: a light set to use instead of cs.lights (a photon pass aims them);
    caustics: read or write the caustic lightmaps (default: when the last photon
    pass stored its caustics there); inst_side: the lit side of each instance
    for gather rays (texel_gather.instance_sides; default: no test). Gather rays
    sample the lights whose first hits the last photon pass kept out of the
    lightmaps (trace_photons(gather_lights=True))."""
    if caustics is None:
        caustics = bool(getattr(cs, "caustics_traced", False))
    caustics = bool(caustics) and cs.caustics is not None
    ol = cs.orientation
    if ol is None:
        ol = orientation_lightmap.empty_maps(cs.geometry.inst_proto.shape[0])
    return KernelScene(cs.geometry, cs.materials, cs.bsdf, cs.textures, cs.lights if lights is None else lights,
                       cs.lightmaps, cs.caustics if caustics else cs.lightmaps, caustics, ol, cs.environment,
                       np.zeros(0, np.int64) if inst_side is None else np.ascontiguousarray(inst_side, np.int64),
                       _gather_lights(cs))


def _gather_lights(cs):
    ls = getattr(cs, "gather_light_set", None)
    return ls if ls is not None else light_subset(cs.lights, np.zeros(cs.lights.kind.shape[0], bool))
