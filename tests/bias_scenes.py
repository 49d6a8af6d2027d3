"""Rooms where a biased bake shows: the tests in test_bake_bias.py bake them with
our gathered default and a many-photon lookup, and compare each object's mean
with Cycles' Diffuse bake (Direct + Indirect, no Color) stored in tests/data/.

Every surface has an explicit 'Lightmap' UV layer, so both renderers bake the
same texels and no reference depends on our unwrapper. The room is closed and
made of single-sided planes (open planes meeting at edges, inside corners); its
ceiling is lit only indirectly (the area light and the spot face down). In it:
a UV sphere resting on the floor, a rotated box, and two thin boxes, a shelf
against the back wall and a free-standing panel.

scripts/make_test_references.py regenerates the references; SCENE_HASH (this
file's source and Blender's version) tells the test when they are stale.
"""
import hashlib
import math
import pathlib

import bmesh
import bpy
import numpy as np

from photon_lightmaps import demo_blend as D

RES = 32                  # texels per side of every object's lightmap
MAX_BOUNCES = 8           # ours and Cycles' (max and diffuse bounces)
SCENES = ("room", "shelves")
DATA = pathlib.Path(__file__).resolve().parent / "data"
REFERENCE = DATA / "bias_scenes_cycles.npz"
PROVENANCE = DATA / "bias_scenes_cycles.json"

W, L, H = 4.0, 3.0, 2.6   # room extent in x, y, z (floor at z = 0)


def scene_hash():
    h = hashlib.sha1(pathlib.Path(__file__).read_bytes())
    h.update(bpy.app.version_string.encode())
    return h.hexdigest()[:16]


def _grid_uvs(n_faces, cols):
    """One cell of a cols-wide grid per quad face, inset by a texel and a half."""
    rows = math.ceil(n_faces / cols)
    inset = 1.5 / RES
    out = []
    for f in range(n_faces):
        c, r = f % cols, f // cols
        x0, y0 = c / cols + inset, r / rows + inset
        x1, y1 = (c + 1) / cols - inset, (r + 1) / rows - inset
        out += [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    return out


def _box(name, size, location, material, rotation_z=0.0):
    """A closed box mesh (outward faces), each face its own cell of the Lightmap UVs."""
    sx, sy, sz = (0.5 * s for s in size)
    v = [(x, y, z) for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    ob = D.mesh_object(name, v, faces, material, uvs=_grid_uvs(6, 3))
    ob.location = location
    ob.rotation_euler = (0.0, 0.0, math.radians(rotation_z))
    return ob


def _sphere(name, radius, location, material):
    """Blender's 48 x 24 UV sphere; its own UV map (equirectangular) is the Lightmap layer."""
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bm.loops.layers.uv.new(D.LIGHTMAP_UV)
    bmesh.ops.create_uvsphere(bm, u_segments=48, v_segments=24, radius=radius, calc_uvs=True)
    bm.to_mesh(me)
    bm.free()
    uv = me.uv_layers[D.LIGHTMAP_UV].uv
    a = np.empty(2 * len(uv), np.float32)
    uv.foreach_get("vector", a)
    uv.foreach_set("vector", (1.5 / RES + (1.0 - 3.0 / RES) * a).astype(np.float32))  # off the borders
    me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    bpy.context.scene.collection.objects.link(ob)
    return ob


def _room(scene, colours):
    """Six single-sided planes facing in, each with unit-square Lightmap UVs."""
    x, y = 0.5 * W, 0.5 * L
    walls = {
        "floor": [(-x, -y, 0), (x, -y, 0), (x, y, 0), (-x, y, 0)],
        "ceiling": [(-x, -y, H), (-x, y, H), (x, y, H), (x, -y, H)],
        "back": [(-x, y, 0), (x, y, 0), (x, y, H), (-x, y, H)],
        "front": [(-x, -y, 0), (-x, -y, H), (x, -y, H), (x, -y, 0)],
        "left": [(-x, -y, 0), (-x, y, 0), (-x, y, H), (-x, -y, H)],
        "right": [(x, -y, 0), (x, -y, H), (x, y, H), (x, y, 0)],
    }
    for name, corners in walls.items():
        D.mesh_object(name, corners, [(0, 1, 2, 3)], colours.get(name, colours["white"]),
                      uvs=D.quad_uvs())


def build(name):
    """Builds scene `name` (one of SCENES) from an empty file; returns the bpy scene."""
    scene = D._reset()
    white = D.principled("white", (0.75, 0.75, 0.75))
    colours = {"white": white, "left": D.principled("red", (0.7, 0.15, 0.1)),
               "right": D.principled("green", (0.15, 0.55, 0.2))}
    _room(scene, colours)
    if name == "room":
        _sphere("sphere", 0.45, (0.6, 0.3, 0.45), white)
        _box("box", (0.7, 0.7, 1.1), (-1.0, 0.2, 0.55), white, rotation_z=25.0)
        D.add_light(scene, "AREA", "ceiling_light", power=300.0, location=(0.0, 0.0, H - 0.02),
                    size=1.0, size_y=1.0)
        D.add_light(scene, "SPOT", "spot", power=400.0, location=(-1.6, -1.2, 2.2),
                    rotation=(math.radians(50.0), 0.0, math.radians(-50.0)),
                    spot_size=math.radians(50.0), spot_blend=0.3, radius=0.05)
    elif name == "shelves":
        _box("shelf", (1.4, 0.4, 0.03), (0.3, 0.5 * L - 0.2, 1.4), white)         # touches the back wall
        _box("panel", (0.04, 1.2, 0.9), (1.2, -0.3, 0.45), white, rotation_z=10.0)  # stands on the floor
        D.add_light(scene, "AREA", "ceiling_light", power=300.0, location=(-0.8, 0.0, H - 0.02),
                    size=1.0, size_y=1.0)
    else:
        raise ValueError(f"unknown bias scene '{name}'")
    D.set_world(scene)
    scene.photon_lightmaps.max_bounces = MAX_BOUNCES
    return scene


def bake_objects():
    """The scene's mesh objects in a stable order."""
    return sorted((ob for ob in bpy.context.scene.objects if ob.type == "MESH"), key=lambda o: o.name)


def cycles_bake(samples, seed=0):
    """Cycles' Diffuse bake (Direct + Indirect, no Color) of every mesh -> {name: (RES, RES, 3)}."""
    from blender_session import cycles_diffuse_bake
    return {ob.name: cycles_diffuse_bake(ob, RES, samples, seed=seed, bounces=MAX_BOUNCES, margin=2,
                                         uv_layer=D.LIGHTMAP_UV)[..., :3].copy()
            for ob in bake_objects()}
