"""Scenes built in Python (no Blender): the demo, tests and benchmarks share them."""
import math

import numpy as np

from .core.scene import (
    Camera, Instance, Light, Material, Primitive, Prototype, Scene, TriangleMesh, compose, rotate,
    scale, translate)


def quad_mesh(p0, p1, p2, p3, material=0, name="quad"):
    """Two triangles p0-p1-p2, p0-p2-p3 with UVs covering the unit square."""
    v = np.array([p0, p1, p2, p3], dtype=np.float64)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], dtype=np.float64)
    # Shrink into the unit square by half a texel's worth so borders never clamp.
    uv = 0.002 + 0.996 * uv
    return TriangleMesh(v, tris, material=material, uvs=uv, name=name)


def prism_mesh(base=1.0, depth=1.0, apex_deg=60.0, material=0, name="prism"):
    """A closed triangular prism, normals out: its base (width `base`) on z = 0 across x,
    its apex angle `apex_deg` on top at x = 0, extruded over y in [-depth/2, depth/2]."""
    h = 0.5 * base / math.tan(math.radians(apex_deg) / 2.0)
    y0, y1 = -0.5 * depth, 0.5 * depth
    a, b, c = (-0.5 * base, 0.0), (0.5 * base, 0.0), (0.0, h)
    v = np.array([(p[0], y, p[1]) for y in (y0, y1) for p in (a, b, c)], np.float64)
    tris = np.array([[0, 1, 2], [3, 5, 4],            # the ends, facing -y and +y
                     [0, 4, 1], [0, 3, 4],            # base, facing -z
                     [1, 5, 2], [1, 4, 5],            # right face
                     [2, 3, 0], [2, 5, 3]], np.int64)  # left face
    return TriangleMesh(v, tris, material=material, name=name)


def uv_sphere_mesh(radius=1.0, n_theta=32, n_phi=64, inward=False, material=0, uvs=None):
    """Closed triangulated sphere (poles fanned); normals outward unless `inward`."""
    verts = [(0.0, 0.0, radius)]
    for i in range(1, n_theta):
        th = math.pi * i / n_theta
        for j in range(n_phi):
            ph = 2 * math.pi * j / n_phi
            verts.append((radius * math.sin(th) * math.cos(ph), radius * math.sin(th) * math.sin(ph),
                          radius * math.cos(th)))
    verts.append((0.0, 0.0, -radius))
    verts = np.array(verts)
    ring = lambda i, j: 1 + (i - 1) * n_phi + (j % n_phi)
    tris = []
    for j in range(n_phi):
        tris.append((0, ring(1, j), ring(1, j + 1)))
    for i in range(1, n_theta - 1):
        for j in range(n_phi):
            a, b, c, d = ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)
            tris += [(a, b, c), (a, c, d)]
    last = len(verts) - 1
    for j in range(n_phi):
        tris.append((last, ring(n_theta - 1, j + 1), ring(n_theta - 1, j)))
    tris = np.array(tris, dtype=np.int64)
    if inward:
        tris = tris[:, ::-1].copy()
    return TriangleMesh(verts, tris, material=material, uvs=uvs, name="uv_sphere")


# The Cornell room's walls: name, corners (counter-clockwise seen from inside,
# so normals point in), colour. Shared with the Blender demo (demo_blend.py).
_A, _B = -1.0, 1.0
CORNELL_WALLS = (
    ("floor", [(_A, _A, 0), (_B, _A, 0), (_B, _B, 0), (_A, _B, 0)], "white"),
    ("ceiling", [(_A, _A, 2), (_A, _B, 2), (_B, _B, 2), (_B, _A, 2)], "white"),
    ("back", [(_A, _B, 0), (_B, _B, 0), (_B, _B, 2), (_A, _B, 2)], "white"),
    ("left", [(_A, _A, 0), (_A, _B, 0), (_A, _B, 2), (_A, _A, 2)], "red"),
    ("right", [(_B, _A, 0), (_B, _A, 2), (_B, _B, 2), (_B, _B, 0)], "green"),
)


def cornell_box(n_bands=3, light_power=25.0, width=128, height=128, with_primitives=True):
    """A Cornell-like room: 2 m cube, red/green side walls, area light under the ceiling.

    Z is up (Blender), the camera looks along +Y into the open front.
    """
    def col(r, g, b):
        return np.array([r, g, b]) if n_bands == 3 else np.full(n_bands, (r + g + b) / 3)

    s = Scene(n_bands=n_bands, name="cornell")
    white = s.add_material(Material("white", diffuse=col(0.73, 0.73, 0.73)))
    red = s.add_material(Material("red", diffuse=col(0.65, 0.05, 0.05)))
    green = s.add_material(Material("green", diffuse=col(0.12, 0.45, 0.15)))
    mirror = s.add_material(Material("mirror", diffuse=0.0, specular=col(0.9, 0.9, 0.9)))
    glass = s.add_material(Material("glass", diffuse=0.0, transmission=col(0.98, 0.98, 0.98), ior=1.5))
    mats = {"white": white, "red": red, "green": green}
    for name, corners, colour in CORNELL_WALLS:
        s.add_object(quad_mesh(*corners, material=mats[colour], name=name), name=name)
    if with_primitives:
        s.add_object(Primitive("box", material=white, name="tall_box"),
                     compose(translate(-0.35, 0.3, 0.6), rotate("z", 18), scale(0.3, 0.3, 0.6)),
                     name="tall_box")
        s.add_object(Primitive("sphere", material=mirror, name="mirror_ball"),
                     compose(translate(0.4, -0.2, 0.35), scale(0.35)), name="mirror_ball")
        s.add_object(Primitive("sphere", material=glass, name="glass_ball"),
                     compose(translate(-0.2, -0.55, 0.22), scale(0.22)), name="glass_ball")
    s.lights.append(Light("area", power=light_power, shape="square", size=0.5,
                          transform=translate(0.0, 0.0, 1.98), name="ceiling_light"))
    s.camera = Camera(transform=compose(translate(0.0, -3.9, 1.0), rotate("x", 90)),
                      fov=math.radians(39.6), width=width, height=height)
    s.texel_density = 16.0
    return s


def furnace_sphere(rho=0.5, flux=100.0, radius=1.0, source=(0.0, 0.0, 0.0), mesh=False,
                   n_bands=3, resolution=16):
    """A closed diffuse sphere of albedo rho with a point light of power `flux` inside."""
    s = Scene(n_bands=n_bands, name="furnace")
    m = s.add_material(Material("grey", diffuse=rho))
    if mesh:
        geo = uv_sphere_mesh(radius, 24, 48, inward=True, material=m)
        s.add_object(geo, name="furnace_mesh", lightmap_resolution=resolution)
    else:
        s.add_object(Primitive("sphere", material=m), scale(radius), name="furnace",
                     lightmap_resolution=resolution)
    s.lights.append(Light("point", power=flux, transform=translate(*source), name="source"))
    return s


def lsystem_studio(grammar_text, name="lsystem", steps=None, width=320, height=320, bounds=None):
    """An L-system lit in a default studio: a ground plane under its bounds, a sun
    from the upper left and a camera framing the bounds (turtle frame: up is +Z).
    bounds: (lo, hi) of the object (default: its scene graph's box)."""
    from .geometry.dcsg import DCSG
    from .lsystem.grammar import parse
    from .core.scene import LSystem
    if bounds is None:
        lo, hi = DCSG(parse(grammar_text, name=name), steps).bounds()
    else:
        lo, hi = (np.asarray(b, np.float64) for b in bounds)
    size = float(np.max(hi - lo)) or 1.0
    centre = 0.5 * (lo + hi)
    sc = Scene(n_bands=3)
    ground = sc.add_material(Material(diffuse=0.6))
    bark = sc.add_material(Material(diffuse=(0.45, 0.32, 0.2)))
    leaf = sc.add_material(Material(diffuse=(0.25, 0.55, 0.2)))
    sc.add_object(Primitive("quad", material=ground), name="ground", lightmap_resolution=64,
                  transform=compose(translate(centre[0], centre[1], lo[2]), scale(2.0 * size)))
    sc.prototypes.append(Prototype(name=name, lsystems=[LSystem(grammar_text, name=name, steps=steps,
                                                                materials=(bark, leaf))]))
    sc.instances.append(Instance(len(sc.prototypes) - 1, name=name))
    sc.lights.append(Light("sun", power=3.0, transform=compose(rotate("z", -35), rotate("x", 40))))
    sc.environment = 0.05
    fov = math.radians(39.6)
    dist = 0.5 * size / math.tan(0.5 * fov) * 1.35
    sc.camera = Camera(transform=compose(translate(centre[0], centre[1] - dist, centre[2]),
                                         rotate("x", 90)),
                       fov=fov, width=int(width), height=int(height))
    return sc
