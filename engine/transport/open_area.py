"""Open texel area: the part of a texel's surface that lies outside every closed solid.

Objects in contact bury some of each other's surface: a wall box standing on a
floor covers a strip of the floor's top face, a cupboard on the floor the floor
under it. No light reaches a buried patch, so a texel that is partly buried
collects its photons on its open part only, and B = Φ/A over the texel's whole
area (thesis eq. 3.7) reads that open part too dark: a ray that lands next to
the wall, a gather ray or a camera ray, sees flux / A where the surface it hit
holds flux / A_open. In a room of box walls a third of the floor's texels touch
a wall, and the final gather's indirect light came out 1-2 % low.

The thesis answers the same question exactly for CSG solids (the visible region
of each texel, ch. 5, engine/lightmaps/split_texels.py). Here, for mesh texels, the open
fraction is estimated the way chapter 6 estimates OL areas: stratified points
over the texel (by world area), each tested with rays in random directions on
its lit side: a point outside every solid first meets nothing, an open
surface or the outside of a closed one, along any ray; a buried point first
meets the inside of the solid that buries it, except along a ray that leaves
through a face that another solid's face touches (a wall's top under the
ceiling), where either may come first. So a point is buried when any of its
rays meets an inside first; tilted rays mostly leave through a free face.
Each texel first gets SAMPLES points of one ray; where they disagree, it is
counted again with MORE_SAMPLES points of RAYS rays: the fraction must be fine
there, since a noisy f reads high (the mean of 1 / f exceeds 1 / f).

Each texel keeps f = open points / points in Lightmaps.open, and finalize()
then stores E = flux / (A·f), what a ray landing on the open surface reads; a
texel buried whole (f = 0) is empty there, and dilation fills it from its
neighbours for bilinear lookups, as at a chart's border. A bake's own texels
stay the mean over the whole texel (Cycles' Diffuse bake averages over it too,
buried part included): their extraction multiplies f back (`baked`).

Only instances whose world box meets a closed solid's box other than their own
are tested; the others keep f = 1 without a ray.
"""
import time

import numpy as np
from numba import njit

from ..core import parallel
from . import texel_gather
from ..geometry.assembly import instance_boxes
from ..core.jit import CORE
from .path_vertex import ray_epsilon
from ..geometry.raycast import STACK_WORDS, intersect_closest
from ..core.sampling import next_float, uniform_sphere

SAMPLES = 16          # points per texel, a 4 x 4 jittered grid, one ray each...
MORE_SAMPLES = 64     # ...then 8 x 8 where some are open and some buried,
RAYS = 3              # with up to this many rays each
STREAM_XOR = np.uint64(0x94D049BB133111EB)


@njit(cache=True, nogil=True)
def _open_mesh(g, inst_side, tx, counts, out, start, stop):
    """Open fraction of mesh texels start..stop: the block's scratch, then the core.
    counts = (points, rays per point, points, rays per point) of the first count
    and of the finer one; arguments, not constants: one signature of _count_open."""
    _open_mesh_core(g, inst_side, tx, counts, out, start, stop, np.empty(STACK_WORDS, np.int32))


@njit(**CORE)
def _open_mesh_core(g, inst_side, tx, counts, out, start, stop, stack):
    n_samples, n_rays, n_more, n_more_rays = counts
    for it in range(start, stop):
        pieces = texel_gather.mesh_texel_pieces(g, tx, it)
        out[it] = 1.0
        if not (pieces[2] > 0.0):
            continue
        side = tx.side[it]
        state = texel_gather.texel_stream(tx, it, STREAM_XOR)
        state, n_ok, n_open = _count_open(g, inst_side, stack, tx, pieces, side, n_samples, n_rays, state)
        if 0 < n_open < n_ok:
            # a mixed texel (or a buried one that a ray left through a touching face):
            # counted again, finer and with RAYS rays per point
            state, n_ok, n_open = _count_open(g, inst_side, stack, tx, pieces, side, n_more, n_more_rays, state)
        if n_ok > 0:
            out[it] = n_open / n_ok


@njit(**CORE)
def _count_open(g, inst_side, stack, tx, pieces, side, n_samples, n_rays, state):
    """n_samples stratified points of a texel (its pieces: texel_gather.mesh_texel_pieces),
    n_rays rays each -> (state, points with area, open points)."""
    k = texel_gather.grid_side(n_samples)
    n_ok = 0
    n_open = 0
    for s in range(n_samples):
        state, j1 = next_float(state)
        state, j2 = next_float(state)
        u1, u2 = texel_gather.jitter(s, k, j1, j2)
        ok, px, py, pz, nx, ny, nz, _, _, _ = texel_gather.mesh_texel_sample(g, tx, pieces, u1, u2)
        if not ok:
            continue
        n_ok += 1
        eps = ray_epsilon(px, py, pz)
        for sgn in (1.0, -1.0):
            if side * sgn < 0.0:
                continue
            fx, fy, fz = sgn * nx, sgn * ny, sgn * nz
            buried = False
            for _ in range(n_rays):
                state, u1 = next_float(state)
                state, u2 = next_float(state)
                # uniform, not cosine: low rays leave a wall through its sides, not its top
                dx, dy, dz = uniform_sphere(u1, u2)
                if dx * fx + dy * fy + dz * fz < 0.0:
                    dx, dy, dz = -dx, -dy, -dz
                hit, _, inst, _, _, _, _, hx, hy, hz = intersect_closest(
                    g, stack, px + eps * fx, py + eps * fy, pz + eps * fz, dx, dy, dz, 0.0, np.inf)
                if hit and inst_side[inst] * (dx * hx + dy * hy + dz * hz) > 0.0:
                    buried = True
                    break
            if not buried:
                n_open += 1
                break
    return state, n_ok, n_open


def _touching(g, inst_side):
    """bool per instance: its world box meets the box of a closed solid other than itself."""
    n = g.inst_proto.shape[0]
    if n == 0:
        return np.zeros(0, bool)
    lo, hi = instance_boxes(g)
    pad = 1e-6 * (1.0 + np.abs(np.concatenate([lo, hi], axis=1)).max(axis=1))
    lo, hi = lo - pad[:, None], hi + pad[:, None]
    closed = np.flatnonzero(inst_side != 0)
    if closed.size == 0:
        return np.zeros(n, bool)
    meets = np.all((lo[:, None, :] <= hi[None, closed, :]) & (hi[:, None, :] >= lo[None, closed, :]), axis=2)
    meets[closed, np.arange(closed.size)] = False
    return meets.any(axis=1)


def estimate(cs, seed=0, samples=SAMPLES, more=MORE_SAMPLES):
    """Fills cs.lightmaps.open for the mesh texels of instances that touch a closed
    solid (the rest stay 1), once per compiled scene -> seconds taken (0 when kept).
    Call before the photon pass's finalize (session.photon_pass does)."""
    if cs.__dict__.get("_open_area_done"):
        return 0.0
    t0 = time.perf_counter()
    lm = cs.lightmaps
    lm.open[:] = 1.0
    g = cs.geometry
    inst_side = texel_gather.instance_sides(cs)
    touching = _touching(g, inst_side)
    owners = texel_gather.lightmap_owners(cs)
    ids = sorted(lid for lid, (inst, _, (kind, _)) in owners.items() if kind == "mesh" and touching[inst])
    if ids:
        mesh, _ = texel_gather.collect_texels(cs, owners, ids, seed, with_sides=True)
        tx = mesh.packed()
        if tx is not None:
            out = np.ones(tx.texel.size)
            parallel.run(_open_mesh, out.size, g, inst_side, tx, (int(samples), 1, int(more), RAYS), out)
            lm.open[tx.texel] = out
    cs.__dict__["_open_area_done"] = True
    seconds = time.perf_counter() - t0
    cs.timings["open_area"] = seconds
    return seconds


def baked(lm, rows):
    """The lightmap values a bake writes for texel rows: E·f, the mean over the
    whole texel (finalize() divided the open fraction out for rays that land)."""
    return lm.irradiance[rows] * lm.open[rows, None]
