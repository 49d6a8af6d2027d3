"""Plain-data scene description: what the exporter fills and the tracer compiles.

Nothing here knows Blender. Units follow Blender/Cycles: metres, watts, W/m²
for sun strength, and colours are band arrays of shape (n_bands,).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


from .errors import SceneError  # noqa: F401  (the scene's own error, importable from here)


# Primitive kinds (mirrors engine.geometry.primitives; kept here so the scene stays import-light).
PRIMITIVE_KINDS = ("sphere", "box", "cylinder", "cone", "torus", "paraboloid", "disk", "quad",
                   "frustum")
LIGHT_KINDS = ("point", "spot", "sun", "area")
AREA_SHAPES = ("square", "rectangle", "disk", "ellipse")


def as_bands(value, n_bands, what):
    a = np.asarray(value, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.full(n_bands, float(a[0]))
    if a.size != n_bands:
        raise SceneError(f"{what}: expected {n_bands} bands, got {a.size}")
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{what}: non-finite colour {a}")
    return a


def as_affine(m, what):
    """Accepts a 4x4 or 3x4 matrix; returns a finite, invertible 3x4 float64 array."""
    a = np.asarray(m, dtype=np.float64)
    if a.shape == (4, 4):
        a = a[:3]
    if a.shape != (3, 4):
        raise SceneError(f"{what}: transform must be 4x4 or 3x4, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise SceneError(f"{what}: transform contains NaN or infinity")
    det = np.linalg.det(a[:, :3])
    scale = max(np.abs(a[:, :3]).max(), 1e-300)
    if not abs(det) > 1e-12 * scale ** 3:
        raise SceneError(f"{what}: transform is singular (det={det:.3g})")
    return np.ascontiguousarray(a)


def identity():
    return np.eye(4)[:3].copy()


def translate(x, y, z):
    m = identity()
    m[:, 3] = (x, y, z)
    return m


def scale(sx, sy=None, sz=None):
    sy = sx if sy is None else sy
    sz = sx if sz is None else sz
    return np.array([[sx, 0, 0, 0], [0, sy, 0, 0], [0, 0, sz, 0]], dtype=np.float64)


def rotate(axis, angle_deg):
    """Rotation about a coordinate axis ('x', 'y' or 'z')."""
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    i = "xyz".index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    m = identity()
    m[j, j], m[j, k], m[k, j], m[k, k] = c, -s, s, c
    return m


def compose(*ms):
    """compose(a, b, c) applies c first, then b, then a (like a @ b @ c)."""
    out = np.eye(4)
    for m in ms:
        m4 = np.eye(4)
        m4[:3] = np.asarray(m, dtype=np.float64)[:3]
        out = out @ m4
    return out[:3].copy()


@dataclass
class Material:
    """A layered surface: diffuse + specular (roughness) + transmission + emission.

    Weights are per band; diffuse + specular + transmission must not exceed 1
    in any band, otherwise the material would create energy.
    """
    name: str = "material"
    diffuse: object = 0.8
    specular: object = 0.0
    roughness: float = 0.0          # 0 = perfect mirror/refraction; >0 glossy lobe
    transmission: object = 0.0
    ior: float = 1.5
    emission: object = 0.0          # radiance W/(m² sr) per band, Lambertian, front side
    # Dielectric specular layer over the diffuse lobe (Principled 'Specular IOR Level'):
    # 0.5 gives F0 from `ior`, 0 no layer (a plain Lambertian, the default here).
    specular_level: float = 0.0
    # The specular lobe's colour is a Schlick F0 (Principled metal, F82 tint white);
    # False: a constant reflectance, as Blender's Glossy BSDF.
    metal_fresnel: bool = False
    # Principled inputs textures may drive; with `textures` set, the lobe weights are
    # recomputed per hit as diffuse = B(1-M)(1-T), specular = B M, transmission = B(1-M)T.
    base_color: object = 0.8
    metallic: float = 0.0
    transmission_weight: float = 0.0
    # input name ('base_color', 'roughness', 'metallic', 'transmission', 'normal')
    # -> index into Scene.textures, sampled at the mesh's `tex_uvs`
    textures: dict = field(default_factory=dict)
    # Dispersion (thesis A.1), seen in spectral mode: `glass` names a catalogue glass
    # (engine/shading/dispersion.PRESETS), whose index replaces `ior`; otherwise an
    # Abbe number > 0 spreads `ior` (taken as n_d) by Cauchy's fit. RGB traces n_d.
    glass: str = ""
    abbe: float = 0.0
    # Fluorescence (thesis A.3, engine/shading/fluorescence.Fluorescence), seen in spectral
    # mode: its diffuse light re-emits absorbed light at longer wavelengths.
    fluorescence: object = None
    # > 0: the emission is a blackbody's at this many kelvin (Blender's Blackbody node);
    # `emission` holds its RGB times the tint, and spectral mode emits Planck's spectrum
    emission_temperature: float = 0.0
    # A metal at a complex index (engine/shading/conductor.py): a preset name ('Ag', 'Al',
    # 'Au', 'Cu') or an (n, k) pair (scalars or per RGB channel). The specular lobe's
    # Fresnel is then the conductor's times `metallic`, whatever its colour.
    conductor: object = ""


@dataclass
class Texture:
    """An image a material samples at its UV map: (H, W, C) float32 scene-linear
    values (C = 1, 3 or 4; colour textures are linear RGB, data textures raw).
    Texel (0, 0) is the bottom-left corner, as Blender stores images; UVs wrap.

    encoding "srgb": the RGB values are sRGB-encoded and decoded after
    interpolation, which is what Cycles does with 8-bit sRGB images (it
    interpolates the bytes); interpolating decoded values instead makes a noisy
    image up to 20 % brighter between its texels."""
    pixels: np.ndarray
    name: str = "texture"
    encoding: str = "linear"        # "linear" or "srgb"
    bake_seconds: float = 0.0       # what baking it in Blender took (0: given, or cached)


@dataclass
class EnvironmentMap:
    """World radiance as an equirectangular map (H, W, n_bands), W/(m² sr).

    The direction <-> pixel mapping is Blender's equirectangular one (see
    engine/shading/environment.py); row 0 is the bottom (d.z = -1)."""
    pixels: np.ndarray
    name: str = "world"
    bake_seconds: float = 0.0       # time the host spent making it (0: cached), for the report


@dataclass
class TriangleMesh:
    vertices: np.ndarray            # (V, 3)
    triangles: np.ndarray           # (T, 3) int
    material: int = 0
    material_ids: np.ndarray | None = None  # (T,) per-triangle override
    uvs: np.ndarray | None = None   # (T, 3, 2) lightmap UVs in [0,1]²; None -> xatlas
    name: str = "mesh"
    tex_uvs: np.ndarray | None = None  # (T, 3, 2) the materials' UV map (textures); any range


@dataclass
class Primitive:
    kind: str                       # one of PRIMITIVE_KINDS
    transform: np.ndarray = field(default_factory=identity)  # primitive -> prototype
    material: int = 0
    params: tuple = ()              # torus: (minor_radius,); frustum: (top_radius,)
    name: str = "primitive"


@dataclass
class LSystem:
    """A rule-defined object (thesis ch. 7): a grammar text (engine/lsystem/grammar.py) the
    tracer expands lazily through its cyclic scene graph (engine/geometry/dcsg.py), or, for
    a context-sensitive grammar, derives and instances. Its turtle frame is the
    prototype's frame. `materials[i]` is the scene material that module ;(i)
    selects (the last one for larger i). Its photons go into orientation
    lightmaps: one over the whole object, or the grammar's `ol stub:` ones."""
    grammar: str
    name: str = "lsystem"
    steps: int | None = None        # None: the grammar's derivation length
    seed: int | None = None         # None: the grammar's seed
    materials: tuple = (0,)
    cache_mb: float = 64.0          # the expansion cache's size (engine/geometry/dcsg.py CACHE_MB)
    # `~(name)` organs: name -> TriangleMesh in the organ's own frame (x -> L, y -> U,
    # z -> H of the turtle, scaled by ~'s scale), its `material` a scene material
    organs: dict = field(default_factory=dict)


CSG_OPS = ("union", "intersection", "difference")


@dataclass
class CSGNode:
    """A Boolean of two solids (thesis 4.1): children are CSGNode, Primitive or a
    closed TriangleMesh. Transforms live on the leaves (pushed down by the
    exporter), so a ray is mapped into each primitive's space once."""
    op: str                         # one of CSG_OPS
    left: object
    right: object
    name: str = "csg"


@dataclass
class Prototype:
    """Object-space geometry stored once and shared by all its instances."""
    name: str = "prototype"
    meshes: list = field(default_factory=list)
    primitives: list = field(default_factory=list)
    csg: list = field(default_factory=list)   # CSGNode roots, each one solid
    lsystems: list = field(default_factory=list)   # LSystem objects


@dataclass
class Instance:
    prototype: int
    transform: np.ndarray = field(default_factory=identity)  # object -> world
    name: str = "instance"
    lightmap: bool = True           # record photon hits on own lightmaps
    lightmap_resolution: int = 0    # per-surface texels per side; 0 = from texel density


@dataclass
class OrientationLightmap:
    """A normal-indexed lightmap shared by a group of instances (thesis ch. 6).

    `instances` are the instances whose innermost OL this is; `parent` (an
    index into Scene.orientation_lightmaps, -1 for none) also receives their
    hits, so each level of a hierarchy holds its whole subtree (fig. 6.3).
    backup=True: the instances keep their own lightmaps and this OL stands in
    where a texel has too few photons (6.2.1)."""
    name: str = "orientation lightmap"
    instances: list = field(default_factory=list)
    parent: int = -1
    resolution: int = 16            # octahedral bins per side
    samples: int = 20000            # area-estimation samples (6.3)
    min_hits: int = 16              # a bin with fewer hits defers to the parent level
    backup: bool = False
    seed: int = 0


@dataclass
class Light:
    kind: str                       # point | spot | sun | area
    color: object = 1.0
    power: float = 100.0            # W (point/spot/area); W/m² (sun: 'strength')
    transform: np.ndarray = field(default_factory=identity)  # emits along local -Z
    radius: float = 0.0             # point/spot soft radius (0 = delta light)
    soft_falloff: bool = False      # Blender's 'Soft Falloff': direct E ~ I cos / (d^2 + r^2)
    spot_size: float = math.radians(45.0)  # full cone angle
    spot_blend: float = 0.15
    shape: str = "square"           # area shape
    size: float = 1.0               # area size x (diameter for disk/ellipse)
    size_y: float = 1.0
    angle: float = 0.0              # sun angular diameter (radians)
    # > 0: a blackbody at this many kelvin (Blender's light temperature); `color` then
    # holds its RGB times the tint, and spectral mode emits Planck's spectrum instead
    temperature: float = 0.0
    # > 0: in spectral mode the light emits a line at this wavelength (nm; an LED, a UV
    # lamp, a laser) of FWHM `line_width` nm, with a white light's power; `color` is
    # then what RGB mode uses
    line_nm: float = 0.0
    line_width: float = 10.0
    # a linear polarizer in front of the light, its axis at this angle (radians, from the
    # light's x axis toward its y); None: none. It passes half of the power, polarized
    # (engine/shading/polarization.py)
    polarizer: object = None
    name: str = "light"


@dataclass
class Camera:
    transform: np.ndarray = field(default_factory=identity)  # camera -> world, looks along -Z
    kind: str = "perspective"       # perspective | orthographic
    fov: float = math.radians(39.6)  # horizontal field of view (sensor fit: larger side)
    ortho_scale: float = 6.0
    width: int = 256
    height: int = 256
    # a linear polarizing filter at this angle (radians, from the camera's x axis toward
    # its y) in front of the lens; None: none. With one, camera paths carry Stokes
    # vectors through smooth glass and coats (engine/shading/polarization.py)
    polarizer: object = None
    # camera paths trace polarization without a filter too (the scene's Polarization):
    # what long chains of glass pass changes with it
    polarized: bool = False


@dataclass
class Scene:
    n_bands: int = 3
    materials: list = field(default_factory=list)
    prototypes: list = field(default_factory=list)
    instances: list = field(default_factory=list)
    lights: list = field(default_factory=list)
    camera: Camera = field(default_factory=Camera)
    environment: object = 0.0       # constant world radiance per band, or an EnvironmentMap
    texel_density: float = 16.0     # lightmap texels per metre
    # Caustic lightmaps (renders): photons that reached a surface only through sharp
    # mirrors and glass are stored at this many times the texel density (1: off).
    caustic_resolution: float = 4.0
    # Renders: a mesh without lightmap UVs and above this many triangles is lit through
    # an automatic orientation lightmap instead of waiting on an xatlas unwrap
    # (~0.6 ms per triangle on 2 cores; 0: always unwrap). Cached unwraps are still used.
    unwrap_limit: int = 20_000
    name: str = "scene"
    orientation_lightmaps: list = field(default_factory=list)  # OrientationLightmap
    textures: list = field(default_factory=list)   # Texture, indexed by Material.textures
    # spectral mode (engine/spectral.py): the bands' spectrum.Bands, whose
    # wavelengths the n_bands colours are; None: colours are RGB (or grey)
    spectral: object = None

    # convenience builders -------------------------------------------------
    def add_material(self, material):
        self.materials.append(material)
        return len(self.materials) - 1

    def add_object(self, geometry, transform=None, name=None, **kw):
        """Adds a one-instance prototype from a TriangleMesh, Primitive or a list of them."""
        items = geometry if isinstance(geometry, (list, tuple)) else [geometry]
        proto = Prototype(name=name or getattr(items[0], "name", "object"))
        for g in items:
            (proto.meshes if isinstance(g, TriangleMesh) else proto.primitives).append(g)
        self.prototypes.append(proto)
        inst = Instance(len(self.prototypes) - 1, identity() if transform is None else transform,
                        name=proto.name, **kw)
        self.instances.append(inst)
        return len(self.instances) - 1
