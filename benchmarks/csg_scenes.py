"""Exact-CSG benchmark scenes, built by script with bpy (thesis 4.1, 5; fig. 4.2, 5.5).

* ``fig55_<op>``: the thesis's fig. 5.5 case, a cylinder and a sphere under
  union, intersection or difference, on the floor of demo_blend's Cornell room
  (no tall box).
* ``machine``: a generated locomotive after the thesis's 3744-primitive type
  310 model (fig. 4.2): wheels (a disc minus spoke and axle holes, plus hub,
  crank pin and bolts), a riveted boiler in courses, domes, chimney, riveted
  frames, running boards, cab, buffers and a tender, about 3000 primitives,
  more than a third of them paraboloid rivets as in the original.

Every solid is a tagged Photon CSG primitive (operators/csg_primitives.py)
with Boolean modifiers (Exact solver) whose operands are other tagged
primitives, so one .blend serves both sides: this engine exports the exact
CSG tree, Cycles renders Blender's Exact Boolean of the display meshes.
``tessellate()`` turns the scene into the polygon model instead: modifiers
applied, tags removed, a fresh xatlas Lightmap layer per mesh, so this
engine sees the same Boolean meshes Cycles does.

Display meshes are shared between objects of the same kind, segments and
material (a 3000-object scene builds in seconds).
"""
import math
import time

import bpy
import bmesh  # noqa: E402  (after bpy)
import numpy as np
from mathutils import Vector

from photon_lightmaps import demo_blend
from photon_lightmaps.export import csg as csg_export
from photon_lightmaps.export import uv_layers
from photon_lightmaps.operators import csg_primitives

OPS = {"union": "UNION", "intersection": "INTERSECT", "difference": "DIFFERENCE"}
# Lightmap layout resolution of the tessellated meshes' xatlas unwrap (chart gaps).
UV_LAYOUT_RES = 16


class _Builder:
    """Tagged CSG primitives with shared display meshes, and Boolean stacks."""

    def __init__(self, scene, segments, rivet_segments):
        self.scene = scene
        self.segments = int(segments)
        self.rivet_segments = int(rivet_segments)
        self.meshes = {}
        self.n_prims = 0

    def prim(self, kind, name, loc, scale, rot=(0.0, 0.0, 0.0), mat=None, collection=None,
             segments=None, minor=0.25):
        seg = int(segments or self.segments)
        params = (float(minor),) if kind == "torus" else ()
        key = (kind, seg, params, mat.name if mat else None)
        me = self.meshes.get(key)
        if me is None:
            me = csg_primitives.build_display_mesh(f"{kind}_{seg}", kind, params, seg)
            if mat is not None:
                me.materials.append(mat)
            self.meshes[key] = me
        ob = bpy.data.objects.new(name, me)
        csg_primitives.tag_object(ob, kind, params)
        ob.location = loc
        ob.rotation_euler = rot
        ob.scale = scale if isinstance(scale, (tuple, list)) else (scale,) * 3
        (collection or self.scene.collection).objects.link(ob)
        self.n_prims += 1
        return ob

    def operands(self, name):
        """A render-hidden collection: a Boolean operand, the union of its objects."""
        col = bpy.data.collections.new(name)
        self.scene.collection.children.link(col)
        col.hide_render = True
        col.hide_viewport = False
        return col

    def boolean(self, ob, operand, operation, chunk=32):
        """Boolean modifier(s); a collection of more than `chunk` objects is split into
        several modifiers, so the exported union chains stay shallow (the CSG tree's
        depth limit, engine/geometry/csg.py MAX_WORK, and a short interval walk per ray)."""
        if isinstance(operand, bpy.types.Collection) and len(operand.objects) > chunk:
            objs = sorted(operand.objects, key=lambda o: o.name)
            for c in range(0, len(objs), chunk):
                sub = self.operands(f"{operand.name}_{c // chunk}")
                for o in objs[c:c + chunk]:
                    operand.objects.unlink(o)
                    sub.objects.link(o)
                self._boolean(ob, sub, operation)
            bpy.data.collections.remove(operand)
            return
        self._boolean(ob, operand, operation)

    @staticmethod
    def _boolean(ob, operand, operation):
        m = ob.modifiers.new(f"{operation.lower()}_{operand.name}", "BOOLEAN")
        m.operation = operation
        m.solver = "EXACT"
        # Not evaluated in the viewport depsgraph until evaluate_booleans(): this
        # engine exports the CSG tree (show_render) and never needs Blender's mesh.
        m.show_viewport = False
        if isinstance(operand, bpy.types.Collection):
            m.operand_type = "COLLECTION"
            m.collection = operand
        else:
            m.object = operand
            operand.hide_render = True
            operand.display_type = "WIRE"
        return m


def _room(width, height, samples=16, photons=1_000_000):
    scene = demo_blend.build_cornell_blend(width=width, height=height, box=False, photons=photons,
                                           samples=samples)
    # Own copies of the room's materials (like benchmarks/scenes.py).
    return scene


def build_fig55(op, width=96, height=96, segments=64):
    """Cylinder (base) and sphere (operand) under `op` (union, intersection,
    difference), 0.5 m across, on the Cornell room's floor. Returns (scene, info)."""
    scene = _room(width, height)
    b = _Builder(scene, segments, segments)
    white = demo_blend.principled("csg_white", (0.75, 0.75, 0.75))
    cyl = b.prim("cylinder", "cyl", (0.0, 0.1, 0.35), (0.3, 0.3, 0.35), mat=white)
    sph = b.prim("sphere", "sph", (0.12, -0.05, 0.62), 0.32, mat=white)
    b.boolean(cyl, sph, OPS[op])
    bpy.context.view_layer.update()
    return scene, dict(scene=f"fig55_{op}", primitives=b.n_prims, segments=segments, solids=["cyl"])


# --------------------------------------------------------------------------------------
# The machine
# --------------------------------------------------------------------------------------

def _ring_positions(n, radius, phase=0.0):
    a = phase + 2 * math.pi * np.arange(n) / n
    return radius * np.cos(a), radius * np.sin(a)


def build_machine(width=128, height=96, segments=24, rivet_segments=8, rivet_pitch=0.009):
    """A locomotive and tender of about 3000 primitives in the Cornell room.

    rivet_pitch (m) sets the rivet spacing along every seam, hence the count.
    Returns (scene, info)."""
    scene = _room(width, height)
    scene.camera.location = (0.0, -3.6, 0.75)
    scene.camera.rotation_euler = (math.radians(86.0), 0.0, 0.0)
    b = _Builder(scene, segments, rivet_segments)
    steel = demo_blend.principled("steel", (0.35, 0.36, 0.4))
    red = demo_blend.principled("wheel_red", (0.6, 0.12, 0.08))
    black = demo_blend.principled("boiler", (0.12, 0.13, 0.14))
    green = demo_blend.principled("cab_green", (0.15, 0.35, 0.2))
    solids = []
    RV = 0.0045    # rivet head radius
    rx90 = (math.radians(90.0), 0.0, 0.0)
    ry90 = (0.0, math.radians(90.0), 0.0)

    def rivet(name, p, n, col, mat):
        # A paraboloid head (thesis fig. 4.2: rivets are paraboloids): vertex RV/2 out of
        # the surface at p along the outward normal n, the cap as deep inside.
        n = Vector(n).normalized()
        rot = (-n).to_track_quat("Z", "Y").to_euler()
        return b.prim("paraboloid", name, tuple(Vector(p) + 0.5 * RV * n), (RV, RV, RV), rot=tuple(rot),
                      mat=mat, collection=col, segments=b.rivet_segments)

    def solid(name):
        solids.append(name)
        return name

    # Wheels: 5 per side on the locomotive, 4 per side on the tender (smaller).
    wheels = [(x, 0.11) for x in (-0.62, -0.37, -0.12, 0.13, 0.38)]
    tender = [(x, 0.08) for x in (0.62, 0.8)]
    for side, y in (("L", -0.19), ("R", 0.19)):
        for i, (x, r) in enumerate(wheels + tender):
            n = solid(f"wheel_{side}{i}")
            w = b.prim("cylinder", n, (x, y, r), (r, r, 0.018), rot=rx90, mat=red)
            holes = b.operands(f"{n}_holes")
            hx, hz = _ring_positions(8, 0.62 * r)
            for k in range(8):
                b.prim("cylinder", f"{n}_hole{k}", (x + hx[k], y, r + hz[k]), (0.16 * r, 0.16 * r, 0.05),
                       rot=rx90, collection=holes)
            b.prim("cylinder", f"{n}_axle", (x, y, r), (0.012, 0.012, 0.05), rot=rx90, collection=holes)
            b.boolean(w, holes, "DIFFERENCE")
            adds = b.operands(f"{n}_adds")
            out = -1.0 if y < 0 else 1.0
            b.prim("cylinder", f"{n}_hub", (x, y + out * 0.01, r), (0.3 * r, 0.3 * r, 0.018), rot=rx90,
                   mat=red, collection=adds)
            b.prim("cylinder", f"{n}_crank", (x + 0.45 * r, y + out * 0.03, r), (0.012, 0.012, 0.02),
                   rot=rx90, mat=steel, collection=adds)
            b.prim("torus", f"{n}_tyre", (x, y, r), (0.97 * r, 0.97 * r, 0.97 * r), rot=rx90, mat=steel,
                   collection=adds, minor=0.03)
            bx, bz = _ring_positions(10, 0.2 * r)
            for k in range(10):
                rivet(f"{n}_bolt{k}", (x + bx[k], y + out * 0.028, r + bz[k]), (0, out, 0), adds, steel)
            b.boolean(w, adds, "UNION")

    # Boiler: courses along x, each a cylinder with rivet rings at both ends and a
    # rivet row along its top seam.
    R_B, ZB = 0.16, 0.42
    edges = np.linspace(-0.62, 0.38, 6)
    n_ring = max(8, int(round(2 * math.pi * R_B / rivet_pitch)))
    for c in range(5):
        n = solid(f"boiler{c}")
        x0, x1 = edges[c], edges[c + 1]
        body = b.prim("cylinder", n, (0.5 * (x0 + x1), 0.0, ZB), (R_B, R_B, 0.5 * (x1 - x0)), rot=ry90,
                      mat=black)
        adds = b.operands(f"{n}_rivets")
        for ring, xr in enumerate((x0 + 0.012, x1 - 0.012)):
            ys, zs = _ring_positions(n_ring // 2, R_B, phase=ring * math.pi / n_ring)
            for k in range(n_ring // 2):
                # rivet axis along the boiler's radius: rotate +z onto (0, y, z)
                rivet(f"{n}_r{ring}_{k}", (xr, ys[k], ZB + zs[k]), (0, ys[k], zs[k]), adds, black)
        for k in range(int((x1 - x0 - 0.04) / rivet_pitch)):
            rivet(f"{n}_seam{k}", (x0 + 0.02 + k * rivet_pitch, 0.0, ZB + R_B), (0, 0, 1), adds, black)
        b.boolean(body, adds, "UNION")
    # Smokebox door, domes and chimney.
    n = solid("smokebox")
    sb = b.prim("cylinder", n, (-0.655, 0.0, ZB), (R_B + 0.01, R_B + 0.01, 0.035), rot=ry90, mat=black)
    adds = b.operands(f"{n}_adds")
    b.prim("sphere", f"{n}_door", (-0.69, 0.0, ZB), (0.02, 0.13, 0.13), mat=steel, collection=adds)
    b.prim("torus", f"{n}_rim", (-0.69, 0.0, ZB), (0.135, 0.135, 0.135), rot=ry90, mat=steel, collection=adds,
           minor=0.08)
    hx, hz = _ring_positions(24, 0.155)
    for k in range(24):
        rivet(f"{n}_r{k}", (-0.69, hx[k], ZB + hz[k]), (-1, 0, 0), adds, steel)
    b.boolean(sb, adds, "UNION")
    for name, x, h, r in (("chimney", -0.56, 0.12, 0.045), ("sand_dome", -0.2, 0.07, 0.06),
                          ("steam_dome", 0.08, 0.08, 0.07)):
        n = solid(name)
        base = b.prim("cylinder", n, (x, 0.0, ZB + R_B + 0.5 * h - 0.02), (r, r, 0.5 * h + 0.02), mat=black)
        adds = b.operands(f"{n}_adds")
        if name == "chimney":
            b.prim("torus", f"{n}_lip", (x, 0.0, ZB + R_B + h), (1.05 * r, 1.05 * r, 1.05 * r), mat=black,
                   collection=adds, minor=0.2)
            bore = b.prim("cylinder", f"{n}_bore", (x, 0.0, ZB + R_B + h), (0.7 * r, 0.7 * r, 0.1))
            b.boolean(base, adds, "UNION")
            b.boolean(base, bore, "DIFFERENCE")
            continue
        b.prim("sphere", f"{n}_cap", (x, 0.0, ZB + R_B + h - 0.02), (r, r, 0.6 * r), mat=black, collection=adds)
        hx, hy = _ring_positions(16, r)
        for k in range(16):
            rivet(f"{n}_r{k}", (x + hx[k], hy[k], ZB + R_B + 0.01), (hx[k], hy[k], 0), adds, black)
        b.boolean(base, adds, "UNION")

    # Frames: two plates along x with lightening holes and rivet rows top and bottom.
    for side, y in (("L", -0.1), ("R", 0.1)):
        n = solid(f"frame_{side}")
        plate = b.prim("box", n, (0.05, y, 0.17), (0.8, 0.008, 0.06), mat=steel)
        holes = b.operands(f"{n}_holes")
        for k, x in enumerate(np.linspace(-0.6, 0.7, 9)):
            b.prim("cylinder", f"{n}_hole{k}", (x, y, 0.17), (0.025, 0.025, 0.05), rot=rx90, collection=holes)
        b.boolean(plate, holes, "DIFFERENCE")
        out = -1.0 if y < 0 else 1.0
        adds = b.operands(f"{n}_rivets")
        xs = np.arange(-0.74, 0.84, rivet_pitch)
        for row, z in enumerate((0.125, 0.215)):
            for k, x in enumerate(xs):
                rivet(f"{n}_r{row}_{k}", (x, y + out * 0.008, z), (0, out, 0), adds, steel)
        b.boolean(plate, adds, "UNION")
    # Running boards: plates over the wheels, riveted along the outer edge.
    for side, y in (("L", -0.23), ("R", 0.23)):
        n = solid(f"board_{side}")
        board = b.prim("box", n, (-0.12, y, 0.27), (0.55, 0.05, 0.006), mat=black)
        adds = b.operands(f"{n}_rivets")
        for row, dy in enumerate((-0.04, 0.04)):
            for k, x in enumerate(np.arange(-0.65, 0.42, rivet_pitch)):
                rivet(f"{n}_r{row}_{k}", (x, y + dy, 0.276), (0, 0, 1), adds, black)
        b.boolean(board, adds, "UNION")

    # Cab: a hollow box with windows, a curved roof and riveted corners.
    n = solid("cab")
    cab = b.prim("box", n, (0.46, 0.0, 0.5), (0.09, 0.2, 0.2), mat=green)
    cut = b.operands(f"{n}_cut")
    b.prim("box", f"{n}_inside", (0.48, 0.0, 0.54), (0.08, 0.19, 0.2), collection=cut)
    for k, y in enumerate((-0.2, 0.2)):
        b.prim("box", f"{n}_win{k}", (0.45, y, 0.6), (0.04, 0.03, 0.05), collection=cut)
    for k, y in enumerate((-0.1, 0.1)):
        b.prim("cylinder", f"{n}_front{k}", (0.37, y, 0.62), (0.035, 0.035, 0.05), rot=ry90, collection=cut)
    b.boolean(cab, cut, "DIFFERENCE")
    adds = b.operands(f"{n}_adds")
    b.prim("cylinder", f"{n}_roof", (0.46, 0.0, 0.62), (0.12, 0.24, 0.12), rot=ry90, mat=green,
                  collection=adds)
    for k, z in enumerate(np.arange(0.32, 0.68, rivet_pitch)):
        for j, (x, y) in enumerate(((0.37, -0.2), (0.37, 0.2), (0.55, -0.2), (0.55, 0.2))):
            rivet(f"{n}_c{j}_{k}", (x, y, z), (0, np.sign(y), 0), adds, green)
    b.boolean(cab, adds, "UNION")

    # Buffers and beam at the front.
    n = solid("beam")
    beam = b.prim("box", n, (-0.8, 0.0, 0.2), (0.02, 0.25, 0.05), mat=red)
    adds = b.operands(f"{n}_adds")
    for k, y in enumerate((-0.17, 0.17)):
        b.prim("cylinder", f"{n}_buf{k}", (-0.85, y, 0.2), (0.018, 0.018, 0.05), rot=ry90, mat=steel,
               collection=adds)
        b.prim("sphere", f"{n}_head{k}", (-0.9, y, 0.2), (0.01, 0.035, 0.035), mat=steel, collection=adds)
    for k, y in enumerate(np.arange(-0.23, 0.24, rivet_pitch)):
        for row, z in enumerate((0.165, 0.235)):
            rivet(f"{n}_r{row}_{k}", (-0.82, y, z), (-1, 0, 0), adds, steel)
    b.boolean(beam, adds, "UNION")

    # Tender: a tank with a coal hollow, riveted seams in a grid on both sides.
    n = solid("tender")
    tank = b.prim("box", n, (0.72, 0.0, 0.37), (0.14, 0.21, 0.15), mat=green)
    hollow = b.prim("box", f"{n}_coal", (0.72, 0.0, 0.5), (0.12, 0.19, 0.06))
    b.boolean(tank, hollow, "DIFFERENCE")
    for side, y in (("L", -0.21), ("R", 0.21)):
        adds = b.operands(f"{n}_rivets_{side}")
        for row, z in enumerate(np.arange(0.24, 0.52, 0.045)):
            for k, x in enumerate(np.arange(0.59, 0.86, rivet_pitch)):
                rivet(f"{n}_{side}{row}_{k}", (x, y, z), (0, np.sign(y), 0), adds, green)
        b.boolean(tank, adds, "UNION")
    bpy.context.view_layer.update()
    return scene, dict(scene="machine", primitives=b.n_prims, segments=segments,
                       rivet_segments=rivet_segments, solids=solids)


def evaluate_booleans(scene=None):
    """Switches the Boolean modifiers on in the viewport depsgraph and evaluates
    them (Blender's Exact solver on the display meshes). Returns seconds."""
    scene = scene or bpy.context.scene
    for ob in scene.objects:
        for m in ob.modifiers:
            if m.type == "BOOLEAN":
                m.show_viewport = True
    t0 = time.perf_counter()
    bpy.context.view_layer.update()
    return time.perf_counter() - t0


def count_leaves(scene=None):
    """Tagged primitives in the scene (CSG leaves and lone primitives)."""
    scene = scene or bpy.context.scene
    return sum(1 for ob in scene.objects if csg_export.PRIMITIVE_PROP in ob)


def tessellate(scene=None, unwrap=True):
    """The polygon model of the current scene: every Boolean stack applied
    (Blender's Exact solver), primitive tags removed, operand objects deleted,
    a fresh xatlas Lightmap layer on every resulting mesh.

    Returns timings: {'boolean': s, 'unwrap': s, 'triangles': n}."""
    scene = scene or bpy.context.scene
    t_eval = evaluate_booleans(scene)
    dg = bpy.context.evaluated_depsgraph_get()
    solids = [ob for ob in scene.objects if ob.type == "MESH" and any(
        m.type == "BOOLEAN" for m in ob.modifiers)]
    tagged = [ob for ob in scene.objects if csg_export.PRIMITIVE_PROP in ob]
    t0 = time.perf_counter()
    # Blender evaluates the Boolean modifiers lazily: force every solid here, timed.
    new = {}
    for ob in solids:
        ev = ob.evaluated_get(dg)
        new[ob.name] = bpy.data.meshes.new_from_object(ev)
    t_bool = t_eval + time.perf_counter() - t0
    for me in new.values():
        # The Boolean leaves zero-area slivers along its cut curves; photons landing on
        # them would find zero-area texels in the xatlas layout.
        bm = bmesh.new()
        bm.from_mesh(me)
        bmesh.ops.dissolve_degenerate(bm, dist=1e-6, edges=bm.edges)
        # n-gons of the cut caps: triangulated here so xatlas sees the triangles we trace
        bmesh.ops.triangulate(bm, faces=bm.faces, quad_method="BEAUTY", ngon_method="BEAUTY")
        bm.to_mesh(me)
        bm.free()
        # The Boolean's new creases are not marked sharp, so smooth vertex normals
        # would be interpolated across them over whole long faces (a cylinder's side
        # cut by a sphere shades ~20 % off in Cycles): mark them as the display
        # meshes' own rims are.
        me.set_sharp_from_angle(angle=csg_primitives.SHARP_ANGLE)
    keep = {ob.name for ob in solids}
    operands = [ob for ob in tagged if ob.name not in keep and ob.hide_render]
    for ob in solids:
        ob.modifiers.clear()
        ob.data = new[ob.name]
    for ob in operands:
        bpy.data.objects.remove(ob)
    for col in list(bpy.data.collections):
        if col.hide_render and not col.objects:
            bpy.data.collections.remove(col)
    tris = 0
    t1 = time.perf_counter()
    for ob in [o for o in scene.objects if csg_export.PRIMITIVE_PROP in o]:
        del ob[csg_export.PRIMITIVE_PROP]
        if csg_export.PARAMS_PROP in ob:
            del ob[csg_export.PARAMS_PROP]
        me = ob.data
        if me.users > 1:
            ob.data = me = me.copy()
        layer = me.uv_layers.get(uv_layers.LAYER_NAME)
        if layer is not None:
            # the Boolean interpolates every operand's chart atlas into one layer: overlapping
            me.uv_layers.remove(layer)
        if unwrap:
            uv_layers.ensure_lightmap_uv(ob, resolution=UV_LAYOUT_RES)
        me.calc_loop_triangles()
        tris += len(me.loop_triangles)
    bpy.context.view_layer.update()
    return {"boolean_seconds": t_bool, "unwrap_seconds": time.perf_counter() - t1, "triangles": tris}
