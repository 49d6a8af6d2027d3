"""A closed mesh's orientation (outward +1, inward -1) decides which side the
final gather reads and which side of a CSG mesh operand is solid. It must not
depend on vertex or triangle order, on split vertices, or on where the mesh
sits: every case here shuffles both, splits every vertex per triangle, and
moves the mesh far from the origin, through each caller of the check."""
import numpy as np
import pytest

from photon_lightmaps.engine.geometry import csg

from photon_lightmaps.engine.geometry import csg_trace
from photon_lightmaps.engine.transport import texel_gather
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.demo_scenes import uv_sphere_mesh
from photon_lightmaps.engine.core.scene import (
    CSGNode, Light, Material, Primitive, Scene, TriangleMesh, compose, scale, translate)

FAR = np.array([123.25, -456.5, 78.75])


def _box(half=0.3):
    """An axis-aligned closed box mesh centred on the origin, wound outward."""
    v = np.array([[x, y, z] for z in (-half, half) for y in (-half, half) for x in (-half, half)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return v, np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])


def _sphere(radius=0.3):
    m = uv_sphere_mesh(radius, 24, 48)
    return np.asarray(m.vertices, float), np.asarray(m.triangles, np.int64)


SHAPES = {"box": _box, "uv_sphere": _sphere}


def _scrambled(shape, inward, seed, split=False, offset=FAR):
    """The shape moved by `offset`, its vertices and triangles permuted, each
    triangle's corners rotated, optionally every corner its own vertex (as
    split UV seams or a triangle soup give), optionally wound inward."""
    v, t = SHAPES[shape]()
    rng = np.random.default_rng(seed)
    if inward:
        t = t[:, ::-1]
    t = np.roll(t, rng.integers(3), axis=1)          # same winding, another first corner
    t = t[rng.permutation(len(t))]
    if split:
        v, t = v[t].reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3)
    perm = rng.permutation(len(v))
    inv = np.empty_like(perm)
    inv[perm] = np.arange(len(v))
    return v[perm] + offset, inv[t]


@pytest.mark.parametrize("shape", sorted(SHAPES))
@pytest.mark.parametrize("split", [False, True], ids=["shared", "split"])
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_check_closed_mesh_sign(shape, split, seed):
    for inward in (False, True):
        v, t = _scrambled(shape, inward, seed, split)
        assert csg.check_closed_mesh(v, t, shape) == (-1 if inward else 1)


def _intervals(mesh_v, mesh_t):
    """Intervals of (cube minus the mesh) along a ray through both centres."""
    cube = Primitive("box", transform=compose(translate(*FAR), scale(0.6)), name="cube")
    tree = CSGNode("difference", cube, TriangleMesh(mesh_v, mesh_t, name="hole"))
    table = csg.csg_table([tree])
    o, d = FAR + (-3.0, 0.011, 0.017), (1.0, 0.0, 0.0)     # t = x + 3 about the centre
    return csg_trace.csg_all_intervals(table, int(table.roots[0]), o, d)["intervals"].reshape(-1, 2)


@pytest.mark.parametrize("shape", sorted(SHAPES))
@pytest.mark.parametrize("inward", [False, True], ids=["outward", "inward"])
def test_csg_mesh_operand_is_solid_inside_whatever_its_order(shape, inward):
    """A cube (half-size 0.6) minus a centred mesh (half-size 0.3) is hollow:
    a ray through both crosses two intervals of solid. Read inside-out, the
    mesh would remove everything but its own inside: one interval."""
    for seed in range(5, 10):
        v, t = _scrambled(shape, inward, seed)
        iv = _intervals(v, t) - 3.0      # ray parameter -> x about the centre
        assert iv.shape == (2, 2), (seed, iv)
        np.testing.assert_allclose(iv[:, 0], [-0.6, 0.3], atol=0.02)
        np.testing.assert_allclose(iv[:, 1], [-0.3, 0.6], atol=0.02)


def _scene(shape, inward):
    v, t = _scrambled(shape, inward, seed=9, offset=np.zeros(3))
    s = Scene(n_bands=1)
    m = s.add_material(Material("grey", diffuse=0.6))
    uv = np.tile(np.array([[0.1, 0.1], [0.9, 0.1], [0.1, 0.9]]), (len(t), 1, 1))
    s.add_object(TriangleMesh(v, t, material=m, uvs=uv, name=shape), translate(*FAR), name=shape,
                 lightmap_resolution=4)
    s.lights.append(Light("point", power=50.0, transform=translate(*(FAR + (1.0, -0.5, 1.5)))))
    return s


@pytest.mark.parametrize("shape", sorted(SHAPES))
@pytest.mark.parametrize("inward", [False, True], ids=["outward", "inward"])
def test_gather_reads_the_outside_whatever_the_order(shape, inward):
    cs = compile_scene(_scene(shape, inward))
    expected = -1 if inward else 1
    assert texel_gather.lit_sides(cs, 0) == expected
    assert list(texel_gather.instance_sides(cs)) == [expected]
