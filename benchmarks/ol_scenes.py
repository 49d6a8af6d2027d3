"""Scenes of the orientation-lightmap benchmarks (thesis ch. 6 and 8), built by script.

One plain description per scene (`spec(name)`: object transforms, floor, light,
camera, albedos) is built twice from the same numbers:

* `engine_scene(spec, method)`: an engine `Scene` with exact analytic
  primitives (sphere, box, torus), one prototype shared by all instances, and
  the orientation lightmaps of `method` ("lightmaps": per-object lightmaps,
  "ol": one OL over the whole object, "ol9": the sphereflake's root OL plus
  one child OL per first-generation sphere). Needs no bpy.
* `blender_scene(spec)`: the same scene in Blender for the Cycles reference:
  a finely segmented smooth UV sphere mesh (or a cube, or a fine torus mesh)
  shared by linked-duplicate objects, so Cycles instances it.

Scenes (each object on a grey floor, lit by one square area light, black world):

* ``torus``: a tilted torus (fig. 6.2: normal lightmaps against one OL).
* ``sphereflake``: Haines' level-4 sphereflake, 7381 spheres (fig. 8.3):
  6 children around each sphere's equator and 3 on its upper hemisphere,
  each 1/3 of its parent's radius, tangent to it.
* ``menger``: Menger sponge level 3, 20^3 = 8000 cubes (a documented failure case).
* ``cube``: one cube (the other failure case: six normal directions).
"""
import math
from dataclasses import dataclass, field

import numpy as np

from photon_lightmaps.engine.core import scene as scene_model

SCENES = ("torus", "sphereflake", "menger", "cube")
METHODS = {"torus": ("lightmaps", "ol"), "sphereflake": ("lightmaps", "ol", "ol9"),
           "menger": ("lightmaps", "ol"), "cube": ("lightmaps", "ol")}
KIND = {"torus": "torus", "sphereflake": "sphere", "menger": "box", "cube": "box"}

SPHEREFLAKE_LEVEL = 4
MENGER_LEVEL = 3
OL_RESOLUTION = 16
OL_SAMPLES = 20000
TORUS_MINOR = 0.35          # minor / major radius
# Blender mesh tessellation of the shared prototypes (Cycles reference only).
SPHERE_SEGMENTS = (64, 32)
TORUS_SEGMENTS = (192, 96)

FLOOR_HALF = 3.0
FLOOR_ALBEDO = (0.6, 0.6, 0.6)
OBJECT_ALBEDO = (0.8, 0.7, 0.55)


@dataclass
class Spec:
    name: str
    kind: str                    # sphere | box | torus: the shared prototype
    transforms: np.ndarray       # (N, 3, 4) prototype -> world
    branch: np.ndarray           # (N,) sphereflake: first-generation ancestor 0..8, -1 root; else -1
    generation: np.ndarray       # (N,) sphereflake generation (0 root); else 0
    params: tuple = ()
    light: dict = field(default_factory=dict)
    camera: dict = field(default_factory=dict)
    width: int = 128
    height: int = 128


# --------------------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------------------

def _frame(up):
    """Orthonormal (x, y) perpendicular to unit `up`."""
    a = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(up, a)
    x /= np.linalg.norm(x)
    return x, np.cross(up, x)


def _flake_directions():
    """The 9 child directions in a frame whose z is the sphere's up: 6 at 60 degree
    intervals around the equator, 3 evenly around the upper hemisphere (Haines)."""
    d = [(math.cos(math.radians(60 * k)), math.sin(math.radians(60 * k)), 0.0) for k in range(6)]
    el = math.radians(55.0)
    d += [(math.cos(el) * math.cos(math.radians(30 + 120 * k)),
           math.cos(el) * math.sin(math.radians(30 + 120 * k)), math.sin(el)) for k in range(3)]
    return np.asarray(d)


def sphereflake(level=SPHEREFLAKE_LEVEL, radius=0.55):
    """Centres (N, 3), radii (N,), generation (N,), branch (N,): the first-generation
    ancestor (0..8) of each sphere, -1 for the root. N = sum_{g<=level} 9^g."""
    dirs = _flake_directions()
    centres, radii, gen, branch = [np.zeros(3)], [radius], [0], [-1]
    frontier = [(np.zeros(3), radius, np.array([0.0, 0.0, 1.0]), -1)]
    for g in range(1, level + 1):
        nxt = []
        for c, r, up, br in frontier:
            x, y = _frame(up)
            for j, d in enumerate(dirs):
                w = d[0] * x + d[1] * y + d[2] * up
                rc = r / 3.0
                cc = c + (r + rc) * w
                b = j if g == 1 else br
                centres.append(cc)
                radii.append(rc)
                gen.append(g)
                branch.append(b)
                nxt.append((cc, rc, w, b))
        frontier = nxt
    return np.asarray(centres), np.asarray(radii), np.asarray(gen), np.asarray(branch)


def menger(level=MENGER_LEVEL, size=1.2):
    """Centres (N, 3) and the common half side of the 20^level cubes of a Menger
    sponge of side `size`, centred at the origin."""
    keep = [(i, j, k) for i in range(3) for j in range(3) for k in range(3)
            if (i == 1) + (j == 1) + (k == 1) < 2]
    pts = np.zeros((1, 3))
    side = size
    for _ in range(level):
        side /= 3.0
        off = (np.asarray(keep, float) - 1.0) * side
        pts = (pts[:, None, :] + off[None, :, :]).reshape(-1, 3)
    return pts, 0.5 * side


def _xf(R, t):
    m = np.zeros((3, 4))
    m[:, :3] = R
    m[:, 3] = t
    return m


def _euler(rx, ry, rz):
    """Blender's XYZ Euler (degrees): R = Rz @ Ry @ Rx."""
    rot = scene_model.rotate
    return scene_model.compose(rot("z", rz), rot("y", ry), rot("x", rx))[:, :3]


def spec(name, width=128, height=128):
    n = None
    branch = gen = None
    params = ()
    light = dict(power=900.0, size=1.5, location=(1.6, -1.4, 4.2), rotation=(0.0, 0.0, 0.0))
    camera = dict(location=(0.0, -6.2, 2.9), rotation=(67.0, 0.0, 0.0), lens=50.0)
    if name == "sphereflake":
        c, r, gen, branch = sphereflake()
        c = c + np.array([0.0, 0.0, -(c[:, 2] - r).min()])      # lowest sphere on the floor
        xfs = np.stack([_xf(np.eye(3) * ri, ci) for ci, ri in zip(c, r)])
        kind = "sphere"
        camera = dict(location=(0.0, -5.6, 3.3), rotation=(63.0, 0.0, 0.0), lens=50.0)
    elif name == "menger":
        c, h = menger()
        R = _euler(0.0, 0.0, 25.0)
        c = c @ R.T + np.array([0.0, 0.0, 0.6])
        xfs = np.stack([_xf(R * h, ci) for ci in c])
        kind = "box"
        camera = dict(location=(0.0, -3.4, 2.2), rotation=(62.0, 0.0, 0.0), lens=50.0)
    elif name == "cube":
        R = _euler(0.0, 0.0, 25.0)
        xfs = np.stack([_xf(R * 0.5, (0.0, 0.0, 0.5))])
        kind = "box"
        camera = dict(location=(0.0, -3.4, 2.2), rotation=(62.0, 0.0, 0.0), lens=50.0)
    elif name == "torus":
        tilt, major = 60.0, 0.8
        R = _euler(tilt, 0.0, 20.0)
        z = major * math.sin(math.radians(tilt)) + TORUS_MINOR * major
        xfs = np.stack([_xf(R * major, (0.0, 0.0, z))])
        kind = "torus"
        params = (TORUS_MINOR,)
        camera = dict(location=(0.0, -4.6, 2.6), rotation=(66.0, 0.0, 0.0), lens=50.0)
    else:
        raise KeyError(f"unknown OL scene '{name}' (one of {', '.join(SCENES)})")
    n = xfs.shape[0]
    branch = np.full(n, -1) if branch is None else branch
    gen = np.zeros(n, int) if gen is None else gen
    return Spec(name, kind, np.ascontiguousarray(xfs), branch, gen, params, light, camera, width, height)


# --------------------------------------------------------------------------------------
# Engine scene
# --------------------------------------------------------------------------------------

def _camera_xf(cam):
    return scene_model.compose(scene_model.translate(*cam["location"]), _euler4(*cam["rotation"]))


def _euler4(rx, ry, rz):
    return scene_model.compose(scene_model.rotate("z", rz), scene_model.rotate("y", ry), scene_model.rotate("x", rx))


def engine_scene(sp, method="lightmaps", ol_resolution=OL_RESOLUTION, ol_samples=OL_SAMPLES, seed=0):
    """The engine Scene of `sp`. Instance 0 is the floor, instances 1..N the objects.

    method: "lightmaps" (per-object lightmaps), "ol" (one OL over all objects),
    "ol9" (sphereflake: root OL holding the root sphere, and one OL per
    first-generation child holding its subtree, each with the root OL as parent)."""
    sc = scene_model.Scene(n_bands=3, name=f"{sp.name}_{method}")
    m_floor = sc.add_material(scene_model.Material("floor", diffuse=FLOOR_ALBEDO))
    m_obj = sc.add_material(scene_model.Material("object", diffuse=OBJECT_ALBEDO))
    sc.add_object(scene_model.Primitive("quad", transform=scene_model.scale(FLOOR_HALF, FLOOR_HALF, 1.0),
                                        material=m_floor), name="floor")
    sc.prototypes.append(scene_model.Prototype(name=sp.kind, primitives=[
        scene_model.Primitive(sp.kind, material=m_obj, params=tuple(sp.params))]))
    proto = len(sc.prototypes) - 1
    first = len(sc.instances)
    for i, xf in enumerate(sp.transforms):
        sc.instances.append(scene_model.Instance(proto, xf, name=f"{sp.kind}{i}"))
    ids = np.arange(first, first + sp.transforms.shape[0])
    L = sp.light
    sc.lights.append(scene_model.Light(
        "area", power=L["power"], shape="square", size=L["size"], size_y=L["size"],
        transform=scene_model.compose(scene_model.translate(*L["location"]), _euler4(*L["rotation"])), name="light"))
    C = sp.camera
    sc.camera = scene_model.Camera(transform=_camera_xf(C), fov=2.0 * math.atan(0.5 * 36.0 / C["lens"]),
                                   width=sp.width, height=sp.height)
    sc.environment = 0.0
    kw = dict(resolution=ol_resolution, samples=ol_samples, seed=seed)
    if method == "ol":
        sc.orientation_lightmaps.append(scene_model.OrientationLightmap(f"{sp.name} OL", instances=ids.tolist(), **kw))
    elif method == "ol9":
        if not (sp.branch >= 0).any():
            raise ValueError(f"'{sp.name}' has no first-generation branches")
        sc.orientation_lightmaps.append(scene_model.OrientationLightmap(
            f"{sp.name} root OL", instances=ids[sp.branch < 0].tolist(), **kw))
        for b in range(int(sp.branch.max()) + 1):
            sc.orientation_lightmaps.append(scene_model.OrientationLightmap(
                f"{sp.name} branch {b} OL", instances=ids[sp.branch == b].tolist(), parent=0,
                **dict(kw, seed=seed + 1 + b)))
    elif method != "lightmaps":
        raise ValueError(f"unknown method '{method}'")
    return sc, ids


def exact_area(sp):
    """Exact total surface area of the objects (spheres, boxes, torus: analytic)."""
    det = np.abs(np.linalg.det(sp.transforms[:, :, :3]))
    s2 = det ** (2.0 / 3.0)            # uniform scales
    unit = {"sphere": 4.0 * math.pi, "box": 24.0,
            "torus": 4.0 * math.pi ** 2 * (sp.params[0] if sp.params else TORUS_MINOR)}[sp.kind]
    return float(unit * s2.sum())


# --------------------------------------------------------------------------------------
# Blender scene (Cycles reference)
# --------------------------------------------------------------------------------------

def _torus_mesh(minor, nu, nv):
    u = np.arange(nu) * 2 * math.pi / nu
    v = np.arange(nv) * 2 * math.pi / nv
    U, V = np.meshgrid(u, v, indexing="ij")
    verts = np.stack([(1 + minor * np.cos(V)) * np.cos(U), (1 + minor * np.cos(V)) * np.sin(U),
                      minor * np.sin(V)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j
    c = ((i + 1) % nu) * nv + (j + 1) % nv
    d = i * nv + (j + 1) % nv
    faces = np.stack([a, b, c, d], axis=-1).reshape(-1, 4)
    return verts, faces


def _sphere_mesh(nu, nv):
    """UV sphere of radius 1 (poles on z), quads with triangle fans at the poles."""
    th = np.arange(1, nv) * math.pi / nv
    ph = np.arange(nu) * 2 * math.pi / nu
    T, P = np.meshgrid(th, ph, indexing="ij")
    ring = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, 1]], ring, [[0, 0, -1]]])
    faces = []
    for j in range(nu):
        faces.append((0, 1 + j, 1 + (j + 1) % nu))
    for i in range(nv - 2):
        for j in range(nu):
            a = 1 + i * nu + j
            b = 1 + i * nu + (j + 1) % nu
            faces.append((a, a + nu, b + nu, b))
    last = verts.shape[0] - 1
    base = 1 + (nv - 2) * nu
    for j in range(nu):
        faces.append((base + j, last, base + (j + 1) % nu))
    return verts, faces


def blender_scene(sp):
    """Builds `sp` in a fresh Blender file (Cycles settings are the harness's)."""
    import bpy
    from mathutils import Matrix

    from photon_lightmaps import demo_blend

    scene = demo_blend._reset()
    floor_mat = demo_blend.principled("floor", FLOOR_ALBEDO)
    obj_mat = demo_blend.principled("object", OBJECT_ALBEDO)
    h = FLOOR_HALF
    demo_blend.mesh_object("floor", [(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], [(0, 1, 2, 3)], floor_mat)
    if sp.kind == "sphere":
        v, f = _sphere_mesh(*SPHERE_SEGMENTS)
        smooth = True
    elif sp.kind == "torus":
        v, f = _torus_mesh(sp.params[0], *TORUS_SEGMENTS)
        smooth = True
    else:
        v, f = demo_blend.box_mesh_data()
        smooth = False
    me = bpy.data.meshes.new(sp.kind)
    me.from_pydata([tuple(map(float, x)) for x in v], [], [tuple(map(int, x)) for x in f])
    me.update()
    me.materials.append(obj_mat)
    if smooth:
        me.polygons.foreach_set("use_smooth", np.ones(len(me.polygons), bool))
        me.update()
    coll = bpy.data.collections.new("objects")
    scene.collection.children.link(coll)
    for i, xf in enumerate(sp.transforms):
        ob = bpy.data.objects.new(f"{sp.kind}{i:05d}", me)
        m4 = np.eye(4)
        m4[:3] = xf
        ob.matrix_world = Matrix(m4.tolist())
        coll.objects.link(ob)
    L = sp.light
    demo_blend.add_light(scene, "AREA", "light", power=L["power"], location=L["location"],
                rotation=tuple(math.radians(a) for a in L["rotation"]), shape="SQUARE", size=L["size"])
    C = sp.camera
    demo_blend.add_camera(scene, C["location"], tuple(math.radians(a) for a in C["rotation"]), lens=C["lens"])
    demo_blend.set_world(scene)
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = sp.width, sp.height, 100
    bpy.context.view_layer.update()
    return scene
