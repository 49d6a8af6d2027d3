"""Scenes built with bpy: the Cornell-like room (engine/demo_scenes.cornell_box in
Blender form) and small one-light scenes for comparing light units with Cycles.

Both start from an empty file, so what they build does not depend on the
user's startup file. Materials are Principled BSDFs with Specular IOR Level 0:
pure Lambertian surfaces, which this engine and Cycles shade identically, so
comparisons measure light transport rather than the glossy-layer approximation
(see export/materials.py).
"""
import math

import bmesh
import bpy
import numpy as np

from .engine.demo_scenes import CORNELL_WALLS  # noqa: E402
from .operators.render_engine import ENGINE_ID  # noqa: E402
LIGHTMAP_UV = "Lightmap"
# Texel inset of the unit-square lightmap UVs, so bilinear lookups never clamp at borders.
UV_INSET = 0.002


def _reset():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def principled(name, base, *, roughness=0.5, metallic=0.0, transmission=0.0, ior=1.5,
               emission=None, specular_level=0.0):
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # files from before node-only materials
        mat.use_nodes = True
    tree = mat.node_tree
    p = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    p.inputs["Base Color"].default_value = (*base, 1.0)
    p.inputs["Roughness"].default_value = roughness
    p.inputs["Metallic"].default_value = metallic
    p.inputs["Transmission Weight"].default_value = transmission
    p.inputs["IOR"].default_value = ior
    p.inputs["Specular IOR Level"].default_value = specular_level
    if emission is not None:
        p.inputs["Emission Color"].default_value = (*emission[:3], 1.0)
        p.inputs["Emission Strength"].default_value = emission[3] if len(emission) > 3 else 1.0
    mat.diffuse_color = (*base, 1.0)
    return mat


def mesh_object(name, verts, faces, material=None, *, uvs=None, collection=None):
    """A mesh object; uvs (one (u, v) per face corner, in face order) become the 'Lightmap' layer."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    me.update()
    if uvs is not None:
        layer = me.uv_layers.new(name=LIGHTMAP_UV)
        layer.uv.foreach_set("vector", np.asarray(uvs, dtype=np.float32).reshape(-1))
    if material is not None:
        me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def quad_uvs():
    return UV_INSET + (1.0 - 2.0 * UV_INSET) * np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)


def box_mesh_data():
    """Unit cube [-1,1]³ with outward faces (no lightmap UVs: the engine unwraps it)."""
    v = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    return v, faces


def add_light(scene, light_type, name="light", *, power=None, location=(0, 0, 1.98), rotation=(0, 0, 0),
              shape="SQUARE", size=0.5, size_y=0.25, radius=0.0, spot_size=math.radians(60),
              spot_blend=0.3, angle=0.0, visible_camera=False, soft_falloff=True, normalize=True):
    lt = bpy.data.lights.new(name, light_type)
    lt.normalize = normalize
    defaults = {"AREA": 25.0, "POINT": 25.0, "SPOT": 25.0, "SUN": 3.0}
    lt.energy = defaults[light_type] if power is None else power
    if light_type == "AREA":
        lt.shape = shape
        lt.size = size
        lt.size_y = size_y
    elif light_type in ("POINT", "SPOT"):
        lt.shadow_soft_size = radius
        lt.use_soft_falloff = soft_falloff
        if light_type == "SPOT":
            lt.spot_size = spot_size
            lt.spot_blend = spot_blend
    else:
        lt.angle = angle
    ob = bpy.data.objects.new(name, lt)
    ob.location = location
    ob.rotation_euler = rotation
    # Lights are not geometry in this engine; keep them out of Cycles' camera rays too.
    ob.visible_camera = visible_camera
    scene.collection.objects.link(ob)
    return ob


def add_camera(scene, location, rotation, *, lens=50.0, sensor=36.0, ortho_scale=None):
    cam = bpy.data.cameras.new("camera")
    cam.lens = lens
    cam.sensor_width = sensor
    if ortho_scale is not None:
        cam.type = 'ORTHO'
        cam.ortho_scale = ortho_scale
    ob = bpy.data.objects.new("camera", cam)
    ob.location = location
    ob.rotation_euler = rotation
    scene.collection.objects.link(ob)
    scene.camera = ob
    return ob


def set_world(scene, color=(0.0, 0.0, 0.0), strength=1.0):
    world = bpy.data.worlds.new("world")
    world.color = color
    scene.world = world
    tree = world.node_tree
    if tree is not None:
        bg = next((n for n in tree.nodes if n.bl_idname == "ShaderNodeBackground"), None)
        if bg is not None:
            bg.inputs["Color"].default_value = (*color, 1.0)
            bg.inputs["Strength"].default_value = strength
    return world


def _finish(scene, path, width, height, engine, photons, samples):
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    if engine is not None:
        r.engine = engine
    settings = getattr(scene, "photon_lightmaps", None)
    if settings is not None:
        if photons is not None:
            settings.photons = photons
        if samples is not None:
            settings.samples = samples
    if path is not None:
        bpy.ops.wm.save_as_mainfile(filepath=str(path), check_existing=False)
    return scene


def add_csg_solid(scene, material=None, *, location=(0.5, 0.55, 0.25), radius=0.25, segments=64):
    """A bowl: an exact CSG cylinder minus a sphere through a Boolean modifier (thesis 4.1).

    Both are tagged CSG primitives (operators/csg_primitives.py); the sphere is
    the usual cutter, hidden from render. The exporter turns the stack into one
    CSG tree; Cycles and EEVEE show Blender's Exact Boolean of the display meshes.
    Returns the solid (the cylinder object).
    """
    from .operators.csg_primitives import new_primitive_object
    x, y, z = location
    solid = new_primitive_object("cylinder", "csg_bowl", location=location, size=radius,
                                 segments=segments, material=material, collection=scene.collection)
    cutter = new_primitive_object("sphere", "csg_bowl_cutter", location=(x, y, z + 1.4 * radius),
                                  size=1.2 * radius, segments=segments, collection=scene.collection)
    cutter.hide_render = True
    cutter.display_type = "WIRE"
    mod = solid.modifiers.new("bowl", "BOOLEAN")
    mod.operation = "DIFFERENCE"
    mod.solver = "EXACT"
    mod.object = cutter
    return solid


def smooth_sphere(name, radius, location, material=None, *, collection=None, subdivisions=2):
    """A smooth-shaded icosphere mesh object (no lightmap UVs)."""
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    bmesh.ops.create_icosphere(bm, subdivisions=subdivisions, radius=radius)
    bm.to_mesh(me)
    bm.free()
    for poly in me.polygons:
        poly.use_smooth = True
    if material is not None:
        me.materials.append(material)
    ob = bpy.data.objects.new(name, me)
    ob.location = location
    (collection or bpy.context.scene.collection).objects.link(ob)
    return ob


def add_ol_cluster(scene, material=None, *, location=(0.62, -0.75, 0.0), radius=0.055, name="ol_cluster",
                   subdivisions=3):
    """A pyramid of 14 small spheres in collection `name` with an orientation lightmap (thesis ch. 6).

    Many small objects are where per-object lightmaps get few photons per texel;
    the OL stores one irradiance per normal for the whole group. The spheres
    get their own material, so the EEVEE hook of the OL bake shows on them only.
    Returns (collection, OL empty)."""
    from .operators.orientation_lightmaps import add_orientation_lightmap
    coll = bpy.data.collections.new(name)
    scene.collection.children.link(coll)
    mat = material or principled("cluster", (0.8, 0.7, 0.3))
    x0, y0, z0 = location
    d = 2.0 * radius
    k = 0
    for level, n in enumerate((3, 2, 1)):
        off = 0.5 * (3 - n) * d
        for i in range(n):
            for j in range(n):
                smooth_sphere(f"{name}_{k:02d}", radius,
                              (x0 + off + (i - 1) * d, y0 + off + (j - 1) * d, z0 + radius * (1 + 1.6 * level)),
                              mat, collection=coll, subdivisions=subdivisions)
                k += 1
    return coll, add_orientation_lightmap(scene, coll)


def build_cornell_blend(path=None, *, light_type="AREA", power=None, width=128, height=128, box=True,
                        spheres=False, csg=False, ol=False, engine=ENGINE_ID, photons=None, samples=None):
    """The Cornell-like room of engine/demo_scenes.cornell_box, built in bpy.

    A 2 m room (Z up, open towards the camera at -Y), red left and green right
    walls, each wall a quad with a 'Lightmap' UV layer, a tall white box (left
    without lightmap UVs, so the engine unwraps it), a 0.5 m square area light
    of 25 W under the ceiling, a 50 mm camera at (0, -3.9, 1). `spheres` adds
    the mirror and glass balls, `csg` the exact-CSG bowl of add_csg_solid, `ol`
    the sphere cluster with an orientation lightmap of add_ol_cluster. Saves
    to `path` when given; returns the scene.
    """
    scene = _reset()
    white = principled("white", (0.73, 0.73, 0.73))
    red = principled("red", (0.65, 0.05, 0.05))
    green = principled("green", (0.12, 0.45, 0.15))
    mats = {"white": white, "red": red, "green": green}
    for name, corners, colour in CORNELL_WALLS:
        mesh_object(name, corners, [(0, 1, 2, 3)], mats[colour], uvs=quad_uvs())
    if box:
        v, f = box_mesh_data()
        ob = mesh_object("tall_box", v, f, white)
        ob.location = (-0.35, 0.3, 0.6)
        ob.rotation_euler = (0.0, 0.0, math.radians(18.0))
        ob.scale = (0.3, 0.3, 0.6)
    if spheres:
        mirror = principled("mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
        glass = principled("glass", (0.98, 0.98, 0.98), transmission=1.0, roughness=0.0, specular_level=0.5)
        for name, mat, loc, rad in (("mirror_ball", mirror, (0.4, -0.2, 0.35), 0.35),
                                    ("glass_ball", glass, (-0.2, -0.55, 0.22), 0.22)):
            me = bpy.data.meshes.new(name)
            bm = bmesh.new()
            bmesh.ops.create_uvsphere(bm, u_segments=48, v_segments=24, radius=rad)
            bm.to_mesh(me)
            bm.free()
            me.materials.append(mat)
            for poly in me.polygons:
                poly.use_smooth = True
            ob = bpy.data.objects.new(name, me)
            ob.location = loc
            scene.collection.objects.link(ob)
    if csg:
        add_csg_solid(scene, white)
    if ol:
        add_ol_cluster(scene)
    if light_type == "AREA":
        add_light(scene, "AREA", "ceiling_light", power=power, location=(0, 0, 1.98))
    elif light_type in ("POINT", "SPOT"):
        add_light(scene, light_type, "ceiling_light", power=power, location=(0, 0, 1.8), radius=0.05,
                  spot_size=math.radians(120.0))
    else:
        raise ValueError(f"light_type must be AREA, POINT or SPOT for the closed room, got {light_type}")
    add_camera(scene, (0.0, -3.9, 1.0), (math.radians(90.0), 0.0, 0.0))
    set_world(scene)
    return _finish(scene, path, width, height, engine, photons, samples)


# Per-light-type test scenes: light placement chosen so the lit pattern (cone edge,
# penumbra, falloff) lies inside the camera's view of the floor.
LIGHT_TESTS = {
    # Radius 0.3 at 1 m: Cycles' soft falloff changes the floor by up to 9 % here.
    "POINT": dict(light_type="POINT", power=100.0, location=(0.3, 0.2, 1.0), radius=0.3),
    "POINT_SPHERE": dict(light_type="POINT", power=100.0, location=(0.3, 0.2, 1.0), radius=0.3,
                         soft_falloff=False),
    "POINT_UNNORMALIZED": dict(light_type="POINT", power=20.0, location=(0.3, 0.2, 1.0), radius=0.3,
                               normalize=False),
    "POINT_HARD": dict(light_type="POINT", power=100.0, location=(0.3, 0.2, 1.0), radius=0.0),
    "SPOT": dict(light_type="SPOT", power=200.0, location=(0.2, 0.0, 1.2),
                 rotation=(math.radians(20.0), 0.0, 0.0), spot_size=math.radians(70.0), spot_blend=0.4,
                 radius=0.05),
    "SUN": dict(light_type="SUN", power=3.0, rotation=(math.radians(35.0), math.radians(10.0), 0.0),
                angle=math.radians(5.0), location=(0.0, 0.0, 3.0)),
    "AREA_SQUARE": dict(light_type="AREA", power=60.0, shape="SQUARE", size=1.0, location=(0.0, 0.0, 0.8)),
    "AREA_RECTANGLE": dict(light_type="AREA", power=60.0, shape="RECTANGLE", size=1.5, size_y=0.5,
                           location=(0.2, 0.0, 0.7), rotation=(math.radians(25.0), 0.0, 0.0)),
    "AREA_DISK": dict(light_type="AREA", power=60.0, shape="DISK", size=1.0, location=(0.0, 0.2, 0.6)),
    "AREA_ELLIPSE": dict(light_type="AREA", power=60.0, shape="ELLIPSE", size=1.2, size_y=0.6,
                         location=(-0.2, 0.0, 0.6), rotation=(0.0, math.radians(20.0), 0.0)),
}


def build_spectral_blend(path=None, *, width=128, height=96, engine=ENGINE_ID, photons=None, samples=None):
    """Spectral light (thesis Appendix A), rendered with Spectral on.

    A 60° N-SF11 prism (dispersion from the glass catalogue) on a dark
    pedestal, a narrow spot beam entering it at the d line's minimum deviation,
    and the rainbow it throws onto the white floor; beside it, two white spheres
    under a 395 nm UV lamp, one with an optical brightener, which glows blue,
    and one without, which the eye hardly sees lit. Saves to `path` when given;
    returns the scene.
    """
    from .engine import demo_scenes
    from .engine.shading import dispersion
    scene = _reset()
    white = principled("white", (0.8, 0.8, 0.8))
    dark = principled("dark", (0.05, 0.05, 0.05))
    glass = principled("flint glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.78)
    glass.photon_lightmaps.dispersion = "N_SF11"
    brightened = principled("brightened paper", (0.85, 0.85, 0.85))
    brightened.photon_lightmaps.fluorescence = "OPTICAL_BRIGHTENER"
    mesh_object("floor", [(-1.5, -1.5, 0), (1.5, -1.5, 0), (1.5, 1.5, 0), (-1.5, 1.5, 0)], [(0, 1, 2, 3)], white,
                uvs=quad_uvs())
    mesh_object("wall", [(-1.5, 1.5, 0), (1.5, 1.5, 0), (1.5, 1.5, 1.5), (-1.5, 1.5, 1.5)], [(0, 1, 2, 3)], white,
                uvs=quad_uvs())
    v, f = box_mesh_data()
    stand = mesh_object("pedestal", v, f, dark)
    stand.location, stand.scale = (0.0, 0.0, 0.25), (0.15, 0.15, 0.25)
    base, top = 0.3, 0.5
    prism = demo_scenes.prism_mesh(base=base, depth=0.3)
    ob = mesh_object("prism", prism.vertices, prism.triangles.tolist(), glass)
    ob.location = (0.0, 0.0, top)
    # the beam: into the left face's middle at the d line's minimum-deviation incidence
    n_d = float(dispersion.sellmeier_index(dispersion.PRESETS["N-SF11"], dispersion.LINE_D))
    phi = math.asin(0.5 * n_d) - math.radians(30.0)
    mid = np.array([-0.25 * base, 0.0, top + 0.25 * base * math.sqrt(3.0)])
    lamp = mid - 0.6 * np.array([math.cos(phi), 0.0, math.sin(phi)])
    add_light(scene, "SPOT", "beam", power=400.0, location=tuple(lamp), rotation=(0.0, -(math.pi / 2 + phi), 0.0),
              spot_size=math.radians(3.0), spot_blend=0.0, soft_falloff=False)
    smooth_sphere("brightened_sphere", 0.15, (-0.75, 0.7, 0.15), brightened)
    smooth_sphere("plain_sphere", 0.15, (-0.35, 0.7, 0.15), white)
    uv = add_light(scene, "POINT", "uv_lamp", power=4.0, location=(-0.55, 0.45, 0.45), radius=0.02)
    uv.data.photon_lightmaps.spectrum = "LINE"
    uv.data.photon_lightmaps.line_nm, uv.data.photon_lightmaps.line_width = 395.0, 15.0
    add_camera(scene, (0.3, -2.2, 1.2), (math.radians(63.0), 0.0, math.radians(8.0)), lens=35.0)
    set_world(scene, (0.08, 0.08, 0.08))
    settings = getattr(scene, "photon_lightmaps", None)
    if settings is not None:
        settings.spectral = True
    return _finish(scene, path, width, height, engine, photons, samples)


def build_polarization_blend(path=None, *, width=128, height=96, engine=ENGINE_ID, photons=None, samples=None):
    """A polarizing filter over water (thesis Appendix A.2): a pool of clear water under a
    bright sky, seen near Brewster's angle (53° from the vertical for an index of 1.33).
    The sky's reflection off the water is polarized across the plane of incidence, which
    is the image's horizontal: the camera's filter at 0° passes it, at 90° it takes the
    glare off and shows the tiled floor under the water. The filter starts at 90°; render
    with `--polarizer 0` for the glare. Saves to `path` when given; returns the scene."""
    scene = _reset()
    water = principled("water", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.33)
    tiles = (principled("tile light", (0.5, 0.55, 0.55)), principled("tile blue", (0.05, 0.15, 0.35)))
    wall = principled("pool wall", (0.4, 0.5, 0.55))
    stone = principled("stone", (0.45, 0.42, 0.38))
    depth, half, n = 0.6, 2.0, 8
    step = 2.0 * half / n
    for i in range(n):
        for j in range(n):
            x0, y0 = -half + i * step, -half + j * step
            mesh_object(f"tile_{i}_{j}", [(x0, y0, -depth), (x0 + step, y0, -depth), (x0 + step, y0 + step, -depth),
                                          (x0, y0 + step, -depth)], [(0, 1, 2, 3)], tiles[(i + j) % 2],
                        uvs=quad_uvs())
    for name, (a, b) in {"wall_n": ((-half, half), (half, half)), "wall_s": ((half, -half), (-half, -half)),
                         "wall_e": ((half, half), (half, -half)), "wall_w": ((-half, -half), (-half, half))}.items():
        mesh_object(name, [(*a, -depth), (*b, -depth), (*b, 0.0), (*a, 0.0)], [(0, 1, 2, 3)], wall, uvs=quad_uvs())
    mesh_object("water", [(-half, -half, 0), (half, -half, 0), (half, half, 0), (-half, half, 0)], [(0, 1, 2, 3)],
                water, uvs=quad_uvs())
    v, f = box_mesh_data()
    block = mesh_object("stone", v, f, stone)
    block.location, block.scale = (0.0, half + 0.6, 0.3), (1.2, 0.4, 0.3)
    add_light(scene, "SUN", "sun", power=1.0, rotation=(math.radians(25.0), 0.0, math.radians(30.0)),
              angle=math.radians(1.0), location=(0.0, 0.0, 4.0))
    cam = add_camera(scene, (0.0, -3.2, 2.4), (math.radians(53.0), 0.0, 0.0), lens=30.0)
    cam.data.photon_lightmaps.use_polarizer = True
    cam.data.photon_lightmaps.polarizer_angle = math.radians(90.0)
    set_world(scene, (0.6, 0.7, 0.9), strength=3.0)
    return _finish(scene, path, width, height, engine, photons, samples)


def build_light_test_blend(light_type, path=None, *, width=32, height=32, albedo=0.8, engine=ENGINE_ID,
                           photons=None, samples=None):
    """A white Lambertian floor (6 x 6 m, 'Lightmap' UVs), one light from LIGHT_TESTS
    (e.g. 'POINT', 'SPOT', 'SUN', 'AREA_DISK'; plain 'AREA' means 'AREA_SQUARE'),
    a black world and a camera 3 m above looking straight down at a 4 x 4 m patch."""
    key = "AREA_SQUARE" if light_type == "AREA" else light_type
    spec = dict(LIGHT_TESTS[key])
    scene = _reset()
    floor = principled("floor", (albedo, albedo, albedo))
    s = 3.0
    mesh_object("floor", [(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [(0, 1, 2, 3)], floor, uvs=quad_uvs())
    kind = spec.pop("light_type")
    add_light(scene, kind, "light", **spec)
    add_camera(scene, (0.0, 0.0, 3.0), (0.0, 0.0, 0.0), lens=18.0, sensor=24.0)
    set_world(scene)
    return _finish(scene, path, width, height, engine, photons, samples)


# The material scene: rough gold, glossy blue plastic and clear glass
# over a floor and a back wall, under one area light, in a dim grey world.
SPHERES = (("gold_ball", (-0.75, 0.0, 0.3), 0.3), ("plastic_ball", (0.0, 0.0, 0.3), 0.3),
           ("glass_ball", (0.75, 0.0, 0.3), 0.3))


def checker_image(name, size=64, squares=8, colours=((0.8, 0.8, 0.8), (0.2, 0.25, 0.6))):
    """A generated float checker image (linear values), packed into the file."""
    img = bpy.data.images.new(name, size, size, alpha=False, float_buffer=True)
    y, x = np.mgrid[0:size, 0:size] * squares // size
    odd = ((x + y) % 2).astype(bool)
    px = np.ones((size, size, 4), np.float32)
    px[~odd, :3] = colours[0]
    px[odd, :3] = colours[1]
    img.pixels.foreach_set(px.ravel())
    img.pack()
    return img


def textured(mat, image=None, procedural=False, scale=4.0):
    """Drives the Principled Base Color by an Image Texture or a Checker Texture."""
    tree = mat.node_tree
    p = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    if procedural:
        tex = tree.nodes.new("ShaderNodeTexChecker")
        tex.inputs["Scale"].default_value = scale
        tex.inputs["Color1"].default_value = (0.8, 0.8, 0.8, 1.0)
        tex.inputs["Color2"].default_value = (0.6, 0.2, 0.1, 1.0)
        uv = tree.nodes.new("ShaderNodeTexCoord")
        tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
    else:
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image = image
    tree.links.new(tex.outputs["Color"], p.inputs["Base Color"])
    return tex


def build_spheres_blend(path=None, *, width=96, height=48, textures=False, world=0.05, light_power=80.0,
                        engine=ENGINE_ID, photons=None, samples=None):
    """Gold (metallic 1, roughness 0.3), blue plastic (roughness 0.2, Specular IOR
    Level 0.5) and glass (transmission 1, roughness 0, IOR 1.5) spheres of radius
    0.3 m, exact analytic spheres here (tagged CSG primitives) and their 96-segment
    display meshes in Cycles, on a 0.8 grey floor before a back wall, lit by a 1 m
    area light and a constant world of `world` radiance. `textures` puts an image
    checker on the floor and a procedural Checker on the wall."""
    from .operators.csg_primitives import new_primitive_object
    scene = _reset()
    floor = principled("floor", (0.8, 0.8, 0.8), roughness=0.5)
    wall = principled("wall", (0.7, 0.7, 0.7), roughness=0.5)
    if textures:
        textured(floor, checker_image("floor_checker"))
        textured(wall, procedural=True)
    s = 3.0
    mesh_object("floor", [(-s, -1.0, 0), (s, -1.0, 0), (s, 2.0, 0), (-s, 2.0, 0)], [(0, 1, 2, 3)], floor,
                uvs=quad_uvs())
    mesh_object("wall", [(-s, 1.0, 0), (s, 1.0, 0), (s, 1.0, 2.0), (-s, 1.0, 2.0)], [(0, 1, 2, 3)], wall,
                uvs=quad_uvs())
    for me in (bpy.data.meshes["floor"], bpy.data.meshes["wall"]):
        # the materials' UV map (textures) besides the lightmap layer
        uv = me.uv_layers.new(name="UVMap")
        uv.uv.foreach_set("vector", np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32).ravel())
        me.uv_layers.active = uv
        uv.active_render = True
    mats = {"gold_ball": principled("gold", (1.0, 0.766, 0.336), metallic=1.0, roughness=0.3),
            "plastic_ball": principled("plastic", (0.05, 0.12, 0.6), roughness=0.2, specular_level=0.5),
            "glass_ball": principled("glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0,
                                     specular_level=0.5)}
    for name, loc, rad in SPHERES:
        new_primitive_object("sphere", name, location=loc, size=rad, segments=96, material=mats[name],
                             collection=scene.collection)
    add_light(scene, "AREA", "key_light", power=light_power, location=(0.4, -0.6, 1.6),
              rotation=(math.radians(25.0), 0.0, 0.0), size=1.0)
    add_camera(scene, (0.0, -3.2, 1.1), (math.radians(78.0), 0.0, 0.0), lens=35.0)
    set_world(scene, (world, world, world))
    return _finish(scene, path, width, height, engine, photons, samples)
