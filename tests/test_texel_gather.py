"""Direct light gathered per texel (engine/transport/texel_gather.py): texel averages of
analytic irradiance fields, both sides of open surfaces, the inside of a closed
solid, occlusion, and determinism; plus the piece lists it samples from.
"""
import math

import numpy as np
import pytest

from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine.lightmaps import texel_areas
from photon_lightmaps.engine.transport import texel_gather
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.demo_scenes import furnace_sphere
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.core.scene import (
    Light, Material, Primitive, Scene, TriangleMesh, compose, scale, translate)

HALF = 1.0   # floor half size: the floor is [-HALF, HALF]² at z = 0
RES = 8


def floor_scene(kind, lights, res=RES, half=HALF):
    """A floor whose lightmap texel (x, y) covers world [x, x+1] × [y, y+1] · 2·half/res - half."""
    s = Scene(n_bands=3)
    m = s.add_material(Material("white", diffuse=0.5))
    if kind == "mesh":
        v = np.array([(-half, -half, 0), (half, -half, 0), (half, half, 0), (-half, half, 0)], float)
        uv = (v[:, :2] + half) / (2 * half)
        tris = np.array([[0, 1, 2], [0, 2, 3]])
        s.add_object(TriangleMesh(v, tris, material=m, uvs=uv[tris]), name="floor",
                     lightmap_resolution=res)
    else:
        s.add_object(Primitive("quad", material=m), scale(half), name="floor", lightmap_resolution=res)
    s.lights.extend(lights)
    return s


def texel_average(f, res=RES, half=HALF, n=48):
    """(res, res) averages of f(x, y) over each texel of the floor (midpoint rule, n² points)."""
    size = 2 * half / res
    g = (np.arange(n) + 0.5) / n * size
    out = np.empty((res, res))
    for ty in range(res):
        for tx in range(res):
            X, Y = np.meshgrid(-half + tx * size + g, -half + ty * size + g)
            out[ty, tx] = f(X, Y).mean()
    return out


def point_E(P, c, h_sign=1):
    """Irradiance on z = 0 from a point light of power P at c (on the side of sign(c.z))."""
    def f(X, Y):
        h = abs(c[2])
        return P / (4 * math.pi) * h / ((X - c[0]) ** 2 + (Y - c[1]) ** 2 + h * h) ** 1.5
    return f


def disk_E(P, a, h):
    """Irradiance on a plane parallel to a Lambertian disk (radius a, height h) of power P."""
    L = P / (math.pi * math.pi * a * a)

    def f(X, Y):
        r2 = X * X + Y * Y
        q = h * h + r2 + a * a
        return 0.5 * math.pi * L * (1.0 - (h * h + r2 - a * a) / np.sqrt(q * q - 4.0 * r2 * a * a))
    return f


def gathered(cs, n=64, seed=0, lm_id=0):
    ids, E = texel_gather.direct_texel_irradiance(cs, [lm_id], samples_per_texel=n, seed=seed)
    lm = cs.lightmaps
    out = np.zeros((lm.area[lightmap.texel_slice(lm, lm_id)].size, cs.n_bands))
    out[ids - lm.offset[lm_id]] = E
    w, h = int(lm.width[lm_id]), int(lm.height[lm_id])
    return out.reshape(h, w, -1)


@pytest.mark.parametrize("kind", ["mesh", "quad"])
def test_point_light_texel_average(kind):
    P, c = 50.0, (0.3, -0.2, 0.5)     # low light: E varies by up to ~2x across a texel
    cs = compile_scene(floor_scene(kind, [Light("point", power=P, transform=translate(*c))]))
    got = gathered(cs)
    ref = texel_average(point_E(P, c), n=96)
    # Bands are equal (white light); 64 jittered samples: ~0.5 % rms per texel.
    assert np.allclose(got[..., 0], got[..., 2])
    rel = got[..., 0] / ref - 1
    assert np.sqrt(np.mean(rel ** 2)) < 0.008 and np.abs(rel).max() < 0.025
    assert abs(np.mean(rel)) < 0.003
    # The texel *average*, not the centre value: that one is off by 1.5 % rms, 5 % max.
    centre = point_E(P, c)(*np.meshgrid(*(2 * [-HALF + (np.arange(RES) + 0.5) * 2 * HALF / RES])))
    assert np.sqrt(np.mean((centre / ref - 1) ** 2)) > 0.012


@pytest.mark.parametrize("kind", ["mesh", "quad"])
def test_disk_light_on_axis(kind):
    P, a, h = 40.0, 0.4, 0.8
    light = Light("area", power=P, shape="disk", size=2 * a, transform=translate(0, 0, h))
    cs = compile_scene(floor_scene(kind, [light]))
    got = gathered(cs, n=1024)[..., 0]
    ref = texel_average(disk_E(P, a, h))
    # direct_irradiance draws one unstratified point on the light per surface point,
    # so per-texel noise falls as 1/sqrt(n): ~5 % rms at 64, ~1.5 % at 1024 (worst
    # far from the axis); the central 4x4 block (on axis) averages 16k samples.
    c = slice(RES // 2 - 2, RES // 2 + 2)
    assert got[c, c].mean() == pytest.approx(ref[c, c].mean(), rel=0.005)
    rel = got / ref - 1
    assert np.sqrt(np.mean(rel ** 2)) < 0.025 and abs(rel.mean()) < 0.005


@pytest.mark.parametrize("kind", ["mesh", "quad"])
def test_open_surface_sums_both_sides(kind):
    P1, c1 = 30.0, (0.2, 0.1, 0.6)       # above
    P2, c2 = 80.0, (-0.4, 0.3, -0.9)     # below
    lights = [Light("point", power=P1, transform=translate(*c1)),
              Light("point", power=P2, transform=translate(*c2))]
    cs = compile_scene(floor_scene(kind, lights))
    got = gathered(cs)[..., 0]
    up, down = texel_average(point_E(P1, c1)), texel_average(point_E(P2, c2))
    rel = got / (up + down) - 1
    assert np.sqrt(np.mean(rel ** 2)) < 0.01 and np.abs(rel).max() < 0.02
    # Each side alone would be far off somewhere.
    assert np.abs(got / up - 1).min() > 0.05 and np.abs(got / down - 1).min() > 0.05


def test_texel_behind_blocker_gets_no_direct_light():
    half, res = 2.0, 8
    s = floor_scene("mesh", [Light("point", power=100.0, transform=translate(0, 0, 2.0))],
                    res=res, half=half)
    # Box [-0.5, 0.5]² × [0.95, 1.05]: the umbra on the floor covers at least [-1, 1]².
    s.add_object(Primitive("box", material=0), compose(translate(0, 0, 1.0), scale(0.5, 0.5, 0.05)),
                 name="blocker")
    cs = compile_scene(s)
    got = gathered(cs, n=16, lm_id=cs.instance_lightmaps[0][0])[..., 0]
    inner = np.zeros((res, res), bool)
    inner[2:6, 2:6] = True                 # texels inside [-1, 1]²
    assert np.all(got[inner] == 0.0)
    assert np.all(got[~inner] > 0.0)


def test_furnace_direct_plus_indirect_photons():
    """Point light inside a closed analytic sphere: only the inner side is lit.

    Direct (gathered) + indirect (photons after the first bounce) must give the
    furnace value Φ / (4πR²(1-ρ)) on average; direct alone averages Φ / (4πR²).
    """
    rho, flux, R = 0.5, 100.0, 1.3
    cs = compile_scene(furnace_sphere(rho=rho, flux=flux, radius=R, source=(0.3, -0.2, 0.1),
                                      resolution=12))
    stats = trace_photons(cs, 200_000, seed=4, max_bounces=64, record_direct=False)
    lm = cs.lightmaps
    ids, E = texel_gather.direct_texel_irradiance(cs, samples_per_texel=16, seed=1)
    a = lm.area[ids]
    e_dir = flux / (4 * math.pi * R * R)
    assert (E[:, 0] * a).sum() / a.sum() == pytest.approx(e_dir, rel=0.01)
    assert E.min() > 0.0                    # every texel sees the source from inside
    texel_gather.add_direct(lm, ids, E)
    mean = (lm.irradiance[ids] * a[:, None]).sum(axis=0) / a.sum()
    # Indirect photon mean: relative error ~ 1/sqrt(photons) (RR on the path length).
    np.testing.assert_allclose(mean, e_dir / (1 - rho), rtol=0.01)
    assert stats.audit_error() < 1e-9


def test_sphere_outside_light_skips_inner_side():
    s = Scene(n_bands=1)
    m = s.add_material(Material("grey", diffuse=0.5))
    s.add_object(Primitive("sphere", material=m), scale(0.5), name="ball", lightmap_resolution=8)
    s.lights.append(Light("point", power=10.0, transform=translate(0, 0, 3)))
    cs = compile_scene(s)
    pk, params = 1, np.zeros(4)
    xf = cs.geometry.inst_xf[0] @ np.vstack([cs.geometry.prim_xf[0], [0, 0, 0, 1]])
    assert not texel_gather._needs_inner_side(cs, pk, params, xf)
    got = gathered(cs, n=16)[..., 0]
    assert got.max() > 0 and (got == 0).sum() > 0.3 * got.size   # the far half is dark


def test_deterministic_and_independent_of_allocation():
    lights = [Light("point", power=50.0, transform=translate(0.3, -0.2, 0.7)),
              Light("area", power=20.0, size=0.3, transform=translate(-0.4, 0.2, 1.0))]
    s = floor_scene("mesh", lights)
    s.add_object(Primitive("quad", material=0), translate(0, 0, -0.5), name="other",
                 lightmap_resolution=4)
    cs = compile_scene(s)
    a = texel_gather.direct_texel_irradiance(cs, seed=7)
    b = texel_gather.direct_texel_irradiance(cs, seed=7)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    c = texel_gather.direct_texel_irradiance(cs, seed=8)
    assert not np.array_equal(a[1], c[1])
    # Without the second object's lightmap the floor's texels get the same samples.
    s.instances[1].lightmap = False
    cs2 = compile_scene(s)
    f1 = gathered(cs, seed=7, n=16)
    f2 = gathered(cs2, seed=7, n=16)
    assert np.array_equal(f1, f2)


def test_texel_pieces_add_up_to_texel_areas():
    rng = np.random.default_rng(3)
    uv = rng.random((40, 3, 2)) * 1.1 - 0.05                       # some stick out of [0,1]²
    uv[5] = [[0.3, 0.3], [0.3, 0.3], [0.31, 0.3]]                  # degenerate UV triangle
    area3d = rng.random(40) + 0.1
    area, _ = texel_areas.triangle_texel_areas(uv, area3d, 9, 7)
    pcs = texel_areas.triangle_texel_pieces(uv, area3d, 9, 7)
    sums = np.array([pcs.area[pcs.start[j]:pcs.start[j + 1]].sum() for j in range(63)])
    np.testing.assert_allclose(sums, area, rtol=1e-12, atol=1e-15)
    assert pcs.nv.min() >= 3 and pcs.nv.max() <= texel_areas.MAX_PIECE_VERTICES
    # Every piece lies inside its triangle (barycentrics) and inside its texel (UV).
    for p in range(pcs.tri.size):
        b = pcs.bary[p, :pcs.nv[p]]
        assert b.min() >= -1e-9 and (b.sum(axis=1)).max() <= 1 + 1e-9
        t = uv[pcs.tri[p]]
        q = (1 - b.sum(axis=1))[:, None] * t[0] + b[:, :1] * t[1] + b[:, 1:] * t[2]
        j = int(np.searchsorted(pcs.start, p, side="right") - 1)
        if np.abs(np.cross(t[1] - t[0], t[2] - t[0])) > 1e-9:
            assert np.all(np.floor(q.mean(axis=0) * [9, 7]) == [j % 9, j // 9])


def test_dense_mesh_pieces_split_over_threads_match_one_call():
    """A mesh of more than 2 x PIECES_BLOCK triangles is clipped in blocks on the
    thread pool; joined in triangle order, the pieces are those of one call."""
    rng = np.random.default_rng(5)
    n = 2 * texel_areas.PIECES_BLOCK + 1234
    centre = rng.random((n, 1, 2))
    uv = centre + rng.normal(scale=0.004, size=(n, 3, 2))
    area3d = rng.random(n) + 0.1
    one = texel_areas._triangle_texel_pieces(*texel_areas._atlas_inputs(uv, area3d, 64, 64))
    pcs = texel_areas.triangle_texel_pieces(uv, area3d, 64, 64)
    order = np.argsort(one[1], kind="stable")
    np.testing.assert_array_equal(pcs.tri, one[0][order])
    np.testing.assert_array_equal(pcs.area, one[2][order])
    np.testing.assert_array_equal(pcs.nv, one[3][order])
    used = np.arange(texel_areas.MAX_PIECE_VERTICES)[None, :] < pcs.nv[:, None]
    np.testing.assert_array_equal(pcs.bary[used], one[4][order][used])
    assert pcs.tri.max() > 2 * texel_areas.PIECES_BLOCK      # the last block's rows are offset back
