"""CSG solids in the photon pass and CSG-aware lightmaps (thesis ch. 5)."""
import math

import numpy as np
import pytest

from photon_lightmaps.engine.geometry import csg
from photon_lightmaps.engine.geometry import primitives
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.geometry.raycast import (
    intersect_closest, new_stack, trace_closest_batch)
from photon_lightmaps.engine.core.scene import (
    CSGNode, Instance, Light, Material, Primitive, Prototype, Scene, SceneError, compose, scale,
    translate)


def _csg_scene(root, lights, rho=0.5, density=16.0):
    s = Scene(n_bands=1, texel_density=density)
    s.add_material(Material("grey", diffuse=rho))
    s.prototypes.append(Prototype(name="solid", csg=[root]))
    s.instances.append(Instance(0, name="solid"))
    s.lights.extend(lights)
    return s


def _leaf_lightmaps(cs, inst=0):
    """Lightmap id of each CSG leaf of the instance (leaves follow the plain slots)."""
    return cs.instance_lightmaps[inst]


def _texel_centres(kind, xf, R, nf):
    """Prototype-space centre of every texel of a primitive lightmap, row layout."""
    W = nf * R
    out = np.zeros((R * W, 3))
    for f in range(nf):
        for y in range(R):
            for x in range(R):
                p = primitives.prim_point(kind, np.zeros(4), f, (x + 0.5) / R, (y + 0.5) / R)[:3]
                out[y * W + f * R + x] = xf[:, :3] @ np.array(p) + xf[:, 3]
    return out


def _hollow_box_with_slot(slot_w, y0):
    outer = Primitive("box", name="outer")
    inner = Primitive("box", transform=scale(0.9), name="inner")
    slot = Primitive("box", transform=compose(translate(1.0, y0, 0.0),
                                              scale(0.2, 0.5 * slot_w, 0.5)), name="slot")
    return CSGNode("difference", CSGNode("difference", outer, inner, name="shell"), slot,
                   name="slotted")


def test_light_enters_cavity_only_through_the_slot():
    # the slot (0.04 m) sits inside one outer texel (1/16 m, 32 per face): that
    # texel is split into the two strips of wall beside the slot
    slot_w, y0 = 0.04, 1.0 / 32.0
    light_pos = np.array([3.0, 0.0, 0.0])
    scene = _csg_scene(_hollow_box_with_slot(slot_w, y0),
                       [Light("point", power=100.0, transform=translate(*light_pos))])
    cs = compile_scene(scene)
    stats = trace_photons(cs, 300_000, seed=3, max_bounces=0, record_direct=True)
    lm = cs.lightmaps
    outer_id, inner_id, slot_id = _leaf_lightmaps(cs)
    # inner box (the cavity walls): only texels that see the light through the slot
    R = int(lm.height[inner_id])
    sl = slice(int(lm.offset[inner_id]), int(lm.offset[inner_id]) + 6 * R * R)
    hits = lm.hits[sl]
    centres = _texel_centres(primitives.BOX, scale(0.9), R, 6)
    # where the segment light -> texel centre crosses the outer wall plane x = 1
    s = (light_pos[0] - 1.0) / (light_pos[0] - centres[:, 0])
    cross = light_pos + s[:, None] * (centres - light_pos)
    margin = 2 * 1.8 / R
    in_view = (np.abs(cross[:, 1] - y0) < 0.5 * slot_w + margin) & (np.abs(cross[:, 2]) < 0.5 + margin)
    assert hits.sum() > 20, "light must reach the cavity through the slot"
    assert hits[~in_view].sum() == 0, "a cavity texel outside the slot's view got light"
    # the cavity side of the lit wall (inner +x face) is never lit: no light through material
    face0 = np.zeros((R, 6 * R), bool)
    face0[:, 0:R] = True
    assert hits[face0.reshape(-1)].sum() == 0
    # outer faces turned away from the light get nothing
    Ro = int(lm.height[outer_id])
    ho = lm.hits[int(lm.offset[outer_id]):int(lm.offset[outer_id]) + 6 * Ro * Ro].reshape(Ro, 6, Ro)
    assert ho[:, 1].sum() == 0
    assert ho[:, 0].sum() > 0
    # the slot is thinner than a texel: wall texels along it hold two regions
    info = cs.info
    assert info["csg_split_texels"] > 0
    assert info["csg_sub_texels"] >= info["csg_split_texels"]
    sub_rows = slice(int(lm.offset[-1]), int(lm.offset[-1]) + int(lm.width[-1]))
    assert lm.hits[sub_rows].sum() > 0, "photons on the far side of a cut go to a sub-texel"
    assert stats.audit_error() < 1e-12


def test_cut_sphere_visible_area_and_unbiased_irradiance():
    # cavity = sphere ∩ {z < 0.3}, carved out of a big box; point light at the centre
    cavity = CSGNode("intersection", Primitive("sphere", name="ball"),
                     Primitive("box", transform=compose(translate(0, 0, -0.85), scale(1.2, 1.2, 1.15)),
                               name="below"), name="bowl")
    solid = CSGNode("difference", Primitive("box", transform=scale(2.0), name="block"), cavity,
                    name="carved")
    scene = _csg_scene(solid, [Light("point", power=100.0, transform=translate(0.0, 0.0, 0.0))],
                       density=8.0)
    cs = compile_scene(scene)
    lm = cs.lightmaps
    block_id, ball_id, below_id = _leaf_lightmaps(cs)
    R = int(lm.height[ball_id])
    sl = slice(int(lm.offset[ball_id]), int(lm.offset[ball_id]) + R * R)
    # the sphere's visible part is the cap z < 0.3 of a unit sphere: area 2 pi (1 + 0.3)
    cap = 2 * math.pi * 1.3
    assert lm.area[sl].sum() == pytest.approx(cap, rel=5e-3)
    # the lid: disk of radius sqrt(1 - 0.09) on the box's top face
    Rb = int(lm.height[below_id])
    lid = lm.area[int(lm.offset[below_id]):int(lm.offset[below_id]) + 6 * Rb * Rb].sum()
    assert lid == pytest.approx(math.pi * 0.91, rel=5e-3)
    assert cs.info["csg_boundary_texels"] > 0
    # the block keeps its whole outside (6 faces of 4 x 4 m)
    Rk = int(lm.height[block_id])
    block = lm.area[int(lm.offset[block_id]):int(lm.offset[block_id]) + 6 * Rk * Rk].sum()
    assert block == pytest.approx(96.0, rel=1e-9)
    stats = trace_photons(cs, 400_000, seed=5, max_bounces=0, record_direct=True)
    # direct irradiance on the sphere is Phi / (4 pi) everywhere, split texels included
    E = float(stats.emitted[0]) / (4 * math.pi)
    ball_full = np.zeros(lm.area.shape[0], bool)
    ball_full[sl] = True
    split = ball_full & (lm.area > 0)
    # boundary texels: visible area below the full texel area
    from photon_lightmaps.engine.lightmaps import lightmap
    from photon_lightmaps.engine.lightmaps import texel_areas
    full = lightmap.faces_to_rows(texel_areas.primitive_texel_areas(primitives.SPHERE, np.zeros(4), np.eye(3), R), 1, R)
    partial = np.zeros_like(split)
    partial[sl] = (lm.area[sl] > 0) & (lm.area[sl] < 0.999 * full)
    assert partial.sum() > 5
    e_part = lm.flux[partial, 0].sum() / lm.area[partial].sum()
    e_all = lm.flux[split, 0].sum() / lm.area[split].sum()
    assert e_all == pytest.approx(E, rel=0.01)
    # the partially visible texels: unbiased only because B = flux / visible area
    assert e_part == pytest.approx(E, rel=0.05)
    e_wrong = lm.flux[partial, 0].sum() / full[partial[sl]].sum()
    assert abs(e_wrong / E - 1) > 0.1
    assert stats.escaped.max() == 0.0
    assert stats.audit_error() < 1e-12


def test_energy_audit_and_raycast_report_owner():
    solid = CSGNode("union", CSGNode("difference", Primitive("box", name="b"),
                                     Primitive("sphere", transform=scale(1.3), name="s")),
                    Primitive("torus", params=(0.3,), transform=translate(0, 0, 0.2), name="t"),
                    name="mix")
    scene = _csg_scene(solid, [Light("point", power=50.0, transform=translate(0.2, 0.1, 3.0))],
                       rho=0.7)
    cs = compile_scene(scene)
    stats = trace_photons(cs, 50_000, seed=1, max_bounces=8, record_direct=False)
    assert stats.audit_error() < 1e-12
    assert stats.records > 0
    # a ray down the axis hits the torus' top at z = 0.5, owned by the torus leaf
    g = cs.geometry
    hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
        g, new_stack(), 0.0, 1.0, 5.0, 0.0, 0.0, -1.0, 0.0, math.inf)
    assert hit and t == pytest.approx(4.5) and nz == pytest.approx(1.0)
    assert g.shape_kind[shape] == primitives.TORUS
    # corner of the box survives the subtraction of the sphere
    hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
        g, new_stack(), 0.95, 0.95, 5.0, 0.0, 0.0, -1.0, 0.0, math.inf)
    assert hit and t == pytest.approx(4.0) and g.shape_kind[shape] == primitives.BOX
    # down the axis: the box is carved away there and the torus has its hole
    assert not intersect_closest(g, new_stack(), 0.0, 0.0, 5.0, 0.0, 0.0, -1.0, 0.0, math.inf)[0]
    # from the carved-out centre towards a corner: the sphere's inside, normal flipped
    d = np.ones(3) / math.sqrt(3.0)
    hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
        g, new_stack(), 0.0, 0.0, 0.0, *d, 0.0, math.inf)
    assert hit and t == pytest.approx(1.3) and g.shape_kind[shape] == primitives.SPHERE
    assert np.dot([nx, ny, nz], d) == pytest.approx(-1.0)


def test_emissive_operand_rejected():
    s = Scene(n_bands=1)
    s.add_material(Material("grey", diffuse=0.5))
    s.add_material(Material("glow", emission=1.0))
    s.prototypes.append(Prototype(name="p", csg=[CSGNode("difference", Primitive("box"),
                                                          Primitive("sphere", material=1,
                                                                    name="lamp"))]))
    s.instances.append(Instance(0))
    with pytest.raises(SceneError, match="lamp"):
        compile_scene(s)


def test_coplanar_faces_report_ties_and_stay_finite():
    # box minus a box sharing its +z face (thesis 4.1.2): the split-texel planning's
    # sampling rays meet the coincident faces, the tie rule resolves them and the
    # compile info counts them; a generic cut (no shared face) counts none
    light = [Light("point", power=50.0, transform=translate(0.3, 0.2, 3.0))]
    pocket = CSGNode("difference", Primitive("box", name="a"),
                     Primitive("box", transform=compose(translate(0, 0, 0.5), scale(0.5)), name="b"))
    cs = compile_scene(_csg_scene(pocket, light, density=8.0))
    assert cs.info["csg_ties"] > 0
    assert 0 < cs.info["csg_tie_texels"] <= cs.info["texels"]
    stats = trace_photons(cs, 50_000, seed=2, max_bounces=4, record_direct=True)
    lm = cs.lightmaps
    assert np.all(np.isfinite(lm.area)) and np.all(lm.area >= 0)
    assert np.all(np.isfinite(lm.flux)) and lm.flux.sum() > 0
    assert stats.audit_error() < 1e-12
    # the shared face belongs to the cut: a's +z face keeps only the ring around the pocket
    a_id = _leaf_lightmaps(cs)[0]
    R = int(lm.height[a_id])
    top = lm.area[int(lm.offset[a_id]):int(lm.offset[a_id]) + 6 * R * R].reshape(R, 6, R)[:, 4]
    assert top.sum() == pytest.approx(4.0 - 1.0, rel=1e-6)

    generic = CSGNode("difference", Primitive("box", name="a"),
                      Primitive("sphere", transform=compose(translate(0.2, 0.1, 0.9), scale(0.6)),
                                name="s"))
    cs = compile_scene(_csg_scene(generic, light, density=8.0))
    assert cs.info["csg_boundary_texels"] > 0 and cs.info["csg_ties"] == 0
