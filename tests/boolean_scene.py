"""The everyday Boolean: a mesh cube minus a mesh cylinder (Exact solver), standing
on a floor under an area light, with no Photon CSG primitive anywhere.

With `user_uvs` both operands carry a 'Lightmap' layer laid out side by side
(the cube's six faces in the left half, the cylinder's wall unrolled in the
right half): Blender carries those UVs onto the Boolean result, and both
renderers bake the same texels of it, so the reference does not depend on our
unwrapper. Without, the bake lays the operands out itself.

scripts/make_test_references.py bakes the applied result with Cycles into
tests/data/boolean_cycles.npz; SCENE_HASH (this file's source and Blender's
version) tells the test when that is stale.
"""
import hashlib
import math
import pathlib

import bpy
import numpy as np

from photon_lightmaps import demo_blend as D

RES = 64                  # texels per side of the result's lightmap
MAX_BOUNCES = 8
SEGMENTS = 24
DATA = pathlib.Path(__file__).resolve().parent / "data"
REFERENCE = DATA / "boolean_cycles.npz"
PROVENANCE = DATA / "boolean_cycles.json"
INSET = 1.5 / RES


def scene_hash():
    h = hashlib.sha1(pathlib.Path(__file__).read_bytes())
    h.update(bpy.app.version_string.encode())
    return h.hexdigest()[:16]


def _cube_uvs():
    """Each of the six faces one cell of a 2 x 3 grid in u < 0.5, inset 1.5 texels."""
    out = []
    for f in range(6):
        c, r = f % 2, f // 2
        x0, y0 = 0.25 * c + INSET, r / 3 + INSET
        x1, y1 = 0.25 * (c + 1) - INSET, (r + 1) / 3 - INSET
        out += [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    return out


def _cylinder(white, user_uvs):
    """Radius 0.5, from z = -0.5 to 2.5 (through the cube), SEGMENTS side quads; with
    user_uvs the wall unrolled over u in [0.5, 1] and the caps (cut away) at one corner point."""
    n = SEGMENTS
    verts = [(0.5 * math.cos(2 * math.pi * k / n), 0.5 * math.sin(2 * math.pi * k / n), z)
             for z in (-0.5, 2.5) for k in range(n)]
    faces = [(k, (k + 1) % n, n + (k + 1) % n, n + k) for k in range(n)]
    faces += [tuple(reversed(range(n))), tuple(range(n, 2 * n))]
    uvs = None
    if user_uvs:
        u = lambda k: 0.5 + INSET + (0.5 - 2 * INSET) * k / n  # noqa: E731
        uvs = [p for k in range(n) for p in ((u(k), INSET), (u(k + 1), INSET), (u(k + 1), 1 - INSET),
                                             (u(k), 1 - INSET))]
        uvs += [(1 - INSET, 1 - INSET)] * (2 * n)
    return D.mesh_object("cylinder", verts, faces, white, uvs=uvs)


def build(user_uvs=True):
    """Builds the scene from an empty file; returns the bpy scene."""
    scene = D._reset()
    white = D.principled("white", (0.75, 0.75, 0.75))
    D.mesh_object("floor", [(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], [(0, 1, 2, 3)], white,
                  uvs=D.quad_uvs())
    v = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (0, 2)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    cube = D.mesh_object("cube", v, faces, white, uvs=_cube_uvs() if user_uvs else None)
    cube.data.uv_layers.new(name="UVMap")      # a layer of the user's that nothing may touch
    cylinder = _cylinder(white, user_uvs)
    cylinder.hide_render = True
    cylinder.display_type = "WIRE"
    mod = cube.modifiers.new("Hole", "BOOLEAN")
    mod.operation, mod.solver, mod.object = "DIFFERENCE", "EXACT", cylinder
    D.add_light(scene, "AREA", "light", power=400.0, location=(0.6, -0.4, 4.0), size=1.0, size_y=1.0)
    # no world light: an open plane (the floor) lit from below by the world passes some of
    # that light to its top side in our engine (about +0.03 on the cube's sides against
    # Cycles, measured), which is not what this scene tests
    D.set_world(scene)
    scene.photon_lightmaps.max_bounces = MAX_BOUNCES
    return scene


def applied_result():
    """A new object holding the cube's evaluated Boolean result (its UVs carried over), the
    cube hidden from render: what Cycles bakes for the reference."""
    cube = bpy.data.objects["cube"]
    dg = bpy.context.evaluated_depsgraph_get()
    me = bpy.data.meshes.new_from_object(cube.evaluated_get(dg))
    ob = bpy.data.objects.new("cube_applied", me)
    ob.matrix_world = cube.matrix_world
    bpy.context.scene.collection.objects.link(ob)
    cube.hide_render = True
    return ob
