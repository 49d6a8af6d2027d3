"""Particle tracing (thesis 3.4.3, after Pattanaik & Mudur): the photon pass.

Photons leave the lights in proportion to power and travel unsplit; at every
hit they are recorded in the surface's photon lightmap (thesis 3.5.2), then
Russian roulette on the material picks one interaction (diffuse, specular,
transmission) or absorption. With direct light computed at render time only
hits after the first bounce are recorded.

Photons are traced in parallel chunks; each photon writes its hits into its
own slots, and the slots are added to the lightmaps in photon order, so a seed
gives bit-identical lightmaps however threads are scheduled. Every joule is
booked as absorbed, escaped or truncated (the path-length cap), which lets
tests audit energy against each light's exact emitted flux.
"""
import math
import time
from collections import namedtuple
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numba.extending import overload

from ..core.errors import Cancelled
from ..core.jit import CORE, INLINE
from ..lightmaps import lightmap
from ..core import memory_budget
from ..core import parallel
from ..shading import photon_aim
from ..lightmaps import orientation_lightmap
from ..shading import lights as lights_module
from ..shading.lights import emit_photon, photon_tint
from ..shading import bsdf
from ..shading import dispersion
from ..shading import fluorescence
from ..shading import polarization
from ..geometry.raycast import intersect_closest
from .kernel_scene import kernel_scene
from .path_vertex import leave_surface, new_path_scratch, smooth_mueller_terms, surface_closure
from ..core.sampling import next_float, stream_state

MAX_BOUNCES_LIMIT = 256
# GGX alpha (Blender roughness 0.1 squared, compile.CAUSTIC_ROUGHNESS) up to which a
# bounce keeps a photon's path a caustic
CAUSTIC_ALPHA = 0.01



@dataclass
class PhotonStats:
    photons: int = 0
    rays: int = 0
    records: int = 0
    seconds: float = 0.0
    emitted: np.ndarray = field(default_factory=lambda: np.zeros(0))
    absorbed: np.ndarray = field(default_factory=lambda: np.zeros(0))
    escaped: np.ndarray = field(default_factory=lambda: np.zeros(0))
    truncated: np.ndarray = field(default_factory=lambda: np.zeros(0))
    points: np.ndarray | None = None       # (K, 6) hit position + normal, with keep_points
    point_power: np.ndarray | None = None  # (K, B)
    aim: tuple | None = None               # (centre, radius) photons were aimed at, None: the scene

    def audit_error(self):
        """Relative imbalance of emitted vs absorbed + escaped + truncated (0 when exact)."""
        booked = self.absorbed + self.escaped + self.truncated
        return float(np.max(np.abs(self.emitted - booked)) / max(np.max(np.abs(self.emitted)), 1e-300))

    def as_dict(self):
        return {"photons": self.photons, "rays": self.rays, "records": self.records,
                "seconds": self.seconds, "photons_per_second": self.photons / max(self.seconds, 1e-9),
                "emitted": self.emitted.tolist(), "absorbed": self.absorbed.tolist(),
                "escaped": self.escaped.tolist(), "truncated": self.truncated.tolist(),
                "aimed_at": None if self.aim is None else {"centre": [float(c) for c in self.aim[0]],
                                                           "radius": float(self.aim[1])}}


PhotonPass = namedtuple("PhotonPass", [
    "seed", "first",          # the pass's random streams, and the chunk's first photon in them
    "n_total",                # photons in the whole pass (each carries 1/n_total of the lights' power)
    "max_bounces",
    "record_from",            # int64 per light: the first bounce its photons record (1: direct light is sampled)
    "main_last",              # the last bounce the main lightmaps and OLs keep (one less under a final gather)
    "caustics_twice",         # a caustic hit goes to the main lightmaps too: gather rays read them there
    "pol",                    # polarization as a type the kernel specialises on: (1, 1) traces Stokes
                              # vectors (polarization.py), an empty 1-D array compiles none of it
])

# A chunk's output, one row per photon: the texel rows it recorded into (-1: none)
# with the power of each and (photon-map baselines) the hit itself; its energy
# ledger (emitted, absorbed, escaped, truncated per band) and the rays it traced.
PhotonRecords = namedtuple("PhotonRecords", "texel power point ledger rays")


@njit(cache=True, nogil=True)
def _trace_chunk(scene, job, out, start, stop):
    """Photons start..stop-1 of the chunk (parallel.run spreads them over
    threads): the block's scratch, then the core."""
    _trace_chunk_core(scene, job, out, start, stop, new_path_scratch(out.ledger.shape[2]))


# The photon loop compiles without NRT: with it, every read of a field of the
# scene tuples is an atomic incref and decref that the threads contend for.
@njit(**CORE)
def _trace_chunk_core(scene, job, out, start, stop, w):
    g, ls, ms, ts, bt = scene.geometry, scene.lights, scene.materials, scene.textures, scene.bsdf
    maps = (scene.lightmaps, scene.caustic_maps, scene.orientation)
    power = w.tp            # the photon's power per band
    for i in range(start, stop):
        # emit_photon is inlined here, not in a helper: numba copies a helper's IR
        # at every inlining, with everything inlined into it (see docs/kernels.md)
        state, li, ox, oy, oz, dx, dy, dz, wl = emit_photon(ls, g, stream_state(job.seed, job.first + i))
        _start(ls, job, out, i, w, li, (dx, dy, dz), wl)
        _polarized_start(job.pol, ls, li, w, (dx, dy, dz))
        first = job.record_from[li]
        n_rays = 0
        caustic = scene.caustics
        rec = 0
        depth = 0
        while True:
            hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
                g, w.stack, ox, oy, oz, dx, dy, dz, 0.0, math.inf)
            n_rays += 1
            if not hit:
                _book(out, i, ESCAPED, power)
                break
            p = (ox + t * dx, oy + t * dy, oz + t * dz)
            surf = (inst, shape, face, u, v)
            if depth >= first:
                rec = _record_hit(g, maps, job, out, i, rec, depth, caustic, (surf, (nx, ny, nz), p), power)
            if depth >= job.max_bounces or (depth >= job.main_last and not caustic):
                _book(out, i, TRUNCATED, power)
                break
            m = g.shape_material[shape]
            if dispersion.splits_bands(ms.dispersion, m, w.wave):
                state = _keep_one_band(out, i, ms, w, state)
            # photons read textures at their finest level: the albedo at the hit itself
            fn, sn, _, _, lobes = surface_closure(ms, ts, bt, g, w, m, surf, (nx, ny, nz), (dx, dy, dz), 0.0)
            alive, o, d, caustic, state = _scatter(w, out, i, lobes, (fn, sn), ((nx, ny, nz), p), (dx, dy, dz),
                                                   caustic, state, ms, m, job.pol)
            if not alive:
                break
            ox, oy, oz = o
            dx, dy, dz = d
            depth += 1
        out.rays[i] = n_rays


# ledger columns
EMITTED, ABSORBED, ESCAPED, TRUNCATED = 0, 1, 2, 3


@njit(**INLINE)
def _book(out, i, column, power):
    """Photon i's power goes to ledger column `column` (absorbed, escaped, truncated)."""
    for b in range(power.shape[0]):
        out.ledger[i, column, b] += power[b]


@njit(**INLINE)
def _start(ls, job, out, i, w, li, d, wl):
    """Photon i has left light li along d with weight wl: its record row cleared,
    its power in w.tp and in the ledger."""
    power, wt = w.tp, w.f
    nb = power.shape[0]
    w.wave[dispersion.WAVE_BAND] = -1.0      # every band, until a dispersive surface
    for r in range(out.texel.shape[1]):
        out.texel[i, r] = -1
    for k in range(4):
        for b in range(nb):
            out.ledger[i, k, b] = 0.0
    p_light = ls.flux[li].mean()
    photon_tint(ls, li, d[0], d[1], d[2], wt)     # an environment map's colour along d
    scale = ls.total_power / job.n_total
    for b in range(nb):
        power[b] = wl * wt[b] * ls.flux[li, b] * scale / p_light if p_light > 0.0 else 0.0
        out.ledger[i, EMITTED, b] = power[b]


@njit(**INLINE)
def _keep_one_band(out, i, ms, w, state):
    """Photon i meets a dispersive surface carrying every band: it keeps one
    (dispersion.keep_one_band). Its total power is unchanged; what moves between
    bands is booked in the absorbed column, so each band's ledger still balances
    (that column's entries then sum to the absorbed power only in expectation)."""
    power = w.tp
    for b in range(power.shape[0]):
        out.ledger[i, ABSORBED, b] += power[b]
    state = dispersion.keep_one_band(ms.bands, power, w.wave, state)
    for b in range(power.shape[0]):
        out.ledger[i, ABSORBED, b] -= power[b]
    return state


@njit(**INLINE)
def _record_hit(g, maps, job, out, i, rec, depth, caustic, hit, power):
    """Photon i's hit = ((instance, shape, face, u, v), n, point) with `power`,
    recorded from row `rec` on into maps = (lightmaps, caustic lightmaps, OLs):
    in the texel of its lightmap, or of its caustic lightmap while only sharp
    mirrors and glass lie behind it, and in its normal's bin of its OL and every
    level above (thesis 6.2) -> the next free row."""
    lm, lmc, ol = maps
    (inst, shape, face, u, v), n, p = hit
    n_rec = out.texel.shape[1]
    n_main = lm.area.shape[0]
    lid = -1
    if caustic and depth >= 1:
        # only sharp mirrors and glass since the light: the finer caustic lightmap
        lid, f, s, tt = lightmap.record_slot(g, lmc, inst, shape, face, u, v)
        if lid >= 0 and rec < n_rec:
            out.texel[i, rec] = n_main + lightmap.record_index(lmc, lid, f, s, tt)
            if job.caustics_twice and depth <= job.main_last and rec + 1 < n_rec:
                # gather rays read the main lightmap and cannot find caustics: there too
                _set_power(out, i, rec, power)
                rec += 1
                lid = -1
    if lid < 0 and depth <= job.main_last:
        lid, f, s, tt = lightmap.record_slot(g, lm, inst, shape, face, u, v)
        if lid >= 0 and rec < n_rec:
            out.texel[i, rec] = lightmap.record_index(lm, lid, f, s, tt)
    if lid >= 0 and rec < n_rec:
        _set_power(out, i, rec, power)
        if out.point.shape[0] > 0:
            # Photon-map baselines keep the hit itself: position and normal.
            for c in range(3):
                out.point[i, rec, c] = p[c]
                out.point[i, rec, 3 + c] = n[c]
        rec += 1
    k = orientation_lightmap.hit_ol(g, ol, inst, shape, face) if depth <= job.main_last else -1
    while k >= 0 and rec < n_rec:
        out.texel[i, rec] = orientation_lightmap.bin_index(lm, ol, k, n[0], n[1], n[2])
        _set_power(out, i, rec, power)
        rec += 1
        k = ol.parent[k]
    return rec


@njit(**INLINE)
def _set_power(out, i, rec, power):
    """Record rec of photon i carries `power`."""
    for b in range(power.shape[0]):
        out.power[i, rec, b] = power[b]


def _polarized_start(pol, ls, li, w, d):
    """A photon that traces polarization leaves light li along d: unpolarized, or through its polarizer."""


def _polarized_vertex(pol, w, out, i, d_in, d_out, fn, lobes, delta):
    """A photon that traces polarization has scattered off a lobe: a smooth glossy one (glass,
    a coat, a metal: its Mueller matrix, bsdf.mueller_terms) polarizes it, a diffuse or rough
    one depolarizes it; what the Mueller matrix changes in its power is booked absorbed."""


@overload(_polarized_start)
def _polarized_start_gate(pol, ls, li, w, d):
    if pol.ndim == 2:
        def start(pol, ls, li, w, d):
            polarization.start_stokes(w.pol, w.tp, ls.pol[li, 3] > 0.0, (ls.pol[li, 0], ls.pol[li, 1], ls.pol[li, 2]),
                                      d)
        return start
    return lambda pol, ls, li, w, d: None


@overload(_polarized_vertex)
def _polarized_vertex_gate(pol, w, out, i, d_in, d_out, fn, lobes, delta):
    if pol.ndim == 2:
        def vertex(pol, w, out, i, d_in, d_out, fn, lobes, delta):
            power = w.tp
            nb = power.shape[0]
            if not delta:
                polarization.depolarize(w.pol, nb)
                return
            smooth_mueller_terms(w, lobes, d_in, d_out, fn)
            for b in range(nb):
                out.ledger[i, ABSORBED, b] += power[b]
            polarization.photon_vertex(w.pol, power, d_in, d_out, fn)
            for b in range(nb):
                out.ledger[i, ABSORBED, b] -= power[b]
        return vertex
    return lambda pol, w, out, i, d_in, d_out, fn, lobes, delta: None


@njit(**INLINE)
def _scatter(w, out, i, lobes, frame, hit, d, caustic, state, ms, m, pol):
    """Russian roulette on the closure in w (lobe probabilities `lobes`) of material m
    at photon i's hit = (n, point), thesis 3.4.3: a lobe or absorption. frame: the
    face and shading normals facing where the photon came from. A survivor keeps
    power k/p <= its power per band, the rest is booked absorbed here; a
    fluorescent diffuse lobe moves power between bands (fluorescence.py), and
    the absorbed column books what each band lost or gained
    pol: PhotonPass.pol (a photon that traces polarization carries it through the
    lobe, _polarized_vertex)
    -> (alive, origin, direction, still a caustic path, state)."""
    n, p = hit
    fn, sn = frame
    power, wt = w.tp, w.f
    nb = power.shape[0]
    pd, ps, pm, pg = lobes
    state, ur = next_float(state)
    state, u1 = next_float(state)
    state, u2 = next_float(state)
    state, u3 = next_float(state)
    ok = True
    delta = False
    moved = False       # the new power is in w.rad (fluorescence), not power times wt
    # a diffuse or rough bounce spreads the focus: the rest of the path is no caustic
    caustic = caustic and ur >= pd and w.closure[bsdf.P_ALPHA] <= CAUSTIC_ALPHA
    if ur < pd:
        ix, iy, iz = bsdf.sample_diffuse(u1, u2)
        ds = bsdf.diffuse_scale(w.closure)
        if ms.fluorescent[m]:
            moved = True
            for b in range(nb):
                w.rad[b] = fluorescence.reflected(ms, m, w.kd, power, b) * ds / pd
        else:
            for b in range(nb):
                wt[b] = w.kd[b] * ds / pd
    elif ur < pd + ps + pm + pg:
        q = ps + pm + pg
        lox, loy, loz = bsdf.to_local(-d[0], -d[1], -d[2], sn[0], sn[1], sn[2])
        ok, ix, iy, iz, _, delta = bsdf.sample_glossy(w.closure, w.ks, w.kt, ps, pm, pg, lox, loy, loz,
                                                      (ur - pd) / q, u1, u2, u3, wt)
        for b in range(nb):
            wt[b] /= q
    else:
        _book(out, i, ABSORBED, power)
        return False, p, d, caustic, state
    if not ok:
        _book(out, i, ABSORBED, power)
        return False, p, d, caustic, state
    d_in = d
    for b in range(nb):
        kept = w.rad[b] if moved else power[b] * wt[b]
        out.ledger[i, ABSORBED, b] += power[b] - kept
        power[b] = kept
    d = bsdf.from_local(ix, iy, iz, sn[0], sn[1], sn[2])
    if (d[0] * fn[0] + d[1] * fn[1] + d[2] * fn[2]) * iz <= 0.0:
        # the shading frame's side and the face's disagree: absorbed, so a
        # normal map never leaks light through the surface
        _book(out, i, ABSORBED, power)
        return False, p, d, caustic, state
    _polarized_vertex(pol, w, out, i, d_in, d, fn, lobes, delta)
    # Leave the surface on the side the new direction points to.
    return True, leave_surface(p, n, d), d, caustic, state


def trace_photons(cs, n_photons, seed=0, max_bounces=8, record_direct=False,
                  progress=None, chunk=None, keep_points=False, caustics=False, gather=False, aim=None,
                  gather_lights=False, block=None, cluster=None):
    """Runs the photon pass on a compiled scene `cs`, adding into cs.lightmaps.

    record_direct: True when the lightmaps must hold direct light too (baking,
    and renders with final gather, which read total irradiance one bounce
    away); False for the renderer's lookup, which samples direct light itself.
    progress(done, total) may return False to cancel (raises Cancelled).
    keep_points: also return every recorded hit as stats.points (K, 6)
    position+normal and stats.point_power (K, B), for photon-map baselines.
    caustics: store photons that came only through sharp mirrors and glass in
    cs.caustics (the renderer reads them there; bakes write cs.lightmaps alone).
    With record_direct too (final gather) they go to both maps: the caustic one
    is read at the hit, the main one is what gather rays see.
    gather: the main lightmaps (and OLs) are read by final-gather rays, which add
    a bounce of their own, so they keep light of at most max_bounces - 1 bounces;
    caustic lightmaps, read at the hit, keep max_bounces. Without this a gathered
    result carries one bounce more than a lookup and than Cycles at the same
    setting (+0.6 % per object in a closed white room at 8 bounces).
    aim: (centre, radius) of a sphere around what is baked: photons go toward it
    by importance emission (photon_aim.py); None aims at the scene's bounds.
    gather_lights (with gather and record_direct): the gather samples the point,
    spot and sun lights where its rays land (lights.gather_sampled; kept as
    cs.gather_light_set), so their photons' first hits stay out of the lightmaps.
    block: photons per block (default BLOCK). A pass of more than one block sums
    each block's tally from zero and adds the tallies over a fixed binary tree of
    block indices, so its result depends on the seed and the block size but not
    on where the blocks ran: `cluster` (engine/cluster.py) traces them on a Dask
    cluster with the same result, bit for bit. keep_points traces in one block.
    """
    if not 0 <= int(max_bounces) <= MAX_BOUNCES_LIMIT:
        raise ValueError(f"max_bounces must be in [0, {MAX_BOUNCES_LIMIT}], got {max_bounces}")
    n_photons = int(n_photons)
    if n_photons < 0:
        raise ValueError(f"photon count must be non-negative, got {n_photons}")
    block = BLOCK if block is None else int(block)
    if block < 1:
        raise ValueError(f"photons per block must be positive, got {block}")
    if keep_points and cluster is not None:
        raise ValueError("a photon map (keep_points) is traced locally, not on a cluster")
    nb = cs.n_bands
    if hasattr(cs, "render_records"):
        cs.render_records = None      # made over the light this pass adds to
    stats = PhotonStats(emitted=np.zeros(nb), absorbed=np.zeros(nb), escaped=np.zeros(nb),
                        truncated=np.zeros(nb))
    record_from = np.full(cs.lights.kind.shape[0], 0 if record_direct else 1, np.int64)
    cs.gather_light_set = None
    if gather and record_direct and gather_lights:
        sampled = lights_module.gather_sampled(cs.lights)
        record_from[sampled] = 1
        if sampled.any():
            cs.gather_light_set = lights_module.light_subset(cs.lights, sampled)
    if n_photons == 0 or cs.lights.total_power <= 0.0:
        return stats
    t0 = time.perf_counter()
    # bakes keep every photon in the one lightmap they write out; renders split caustics off
    use_caustics = bool(caustics) and getattr(cs, "caustics", None) is not None
    lights = photon_aim.aimed(cs.lights, aim)
    if lights.aim_radius < cs.lights.aim_radius:
        stats.aim = (lights.aim_center.copy(), float(lights.aim_radius))
    # one record per hit on an own lightmap, plus one per OL level above the instance
    levels = orientation_lightmap.levels(cs.orientation) if cs.orientation is not None else 0
    n_rec = (int(max_bounces) + 1) * (1 + levels)
    if use_caustics and record_direct:
        n_rec += int(max_bounces)          # a caustic hit is recorded twice
    chunk = chunk or max(4096, min(1 << 16, (1 << 21) // n_rec))
    if keep_points:   # a photon map keeps every hit: refuse what cannot fit before tracing
        memory_budget.check(f"photon map ({n_photons:,} photons kept, up to {n_rec} hits each)",
                            n_photons * min(n_rec, 4) * (6 + nb) * 8 * 2, "lower the photon count")
    plan = PassPlan(int(seed), n_photons, int(max_bounces), record_from,
                    int(max_bounces) - 1 if gather else int(max_bounces), bool(record_direct),
                    bool(getattr(cs, "polarization", False)), use_caustics, lights, n_rec, chunk)
    cs.caustics_traced = use_caustics
    cs.lightmaps_hold_direct = bool(record_direct)
    if cluster is None and (n_photons <= block or keep_points):
        # one block: straight into the lightmaps, in photon order
        main = Tally(cs.lightmaps.flux, cs.lightmaps.flux_sq, cs.lightmaps.hits)
        fine = Tally(cs.caustics.flux, cs.caustics.flux_sq, cs.caustics.hits) if use_caustics else main
        part = _trace_range(cs, plan, 0, n_photons, main, fine, progress, stats if keep_points else None)
    else:
        blocks = [(b, min(b + block, n_photons)) for b in range(0, n_photons, block)]
        if cluster is not None:
            part = cluster.photon_pass(cs, plan, blocks, progress)
        else:
            done = [0]

            def leaf(k):
                start, stop = blocks[k]

                def step(n, _total):
                    return progress is None or progress(done[0] + n, n_photons) is not False
                p = trace_block(cs, plan, start, stop, step)
                done[0] += stop - start
                return p
            part = reduce_blocks(leaf, len(blocks))
        _add_tally(cs.lightmaps, part.main)
        if use_caustics:
            _add_tally(cs.caustics, part.fine)
    stats.emitted += part.ledger[EMITTED]
    stats.absorbed += part.ledger[ABSORBED]
    stats.escaped += part.ledger[ESCAPED]
    stats.truncated += part.ledger[TRUNCATED]
    stats.rays += int(part.rays)
    stats.records += int(part.records)
    stats.photons = n_photons
    if keep_points:
        stats.points = np.concatenate(stats.points)
        stats.point_power = np.concatenate(stats.point_power)
    lightmap.finalize(cs.lightmaps)
    if use_caustics:
        lightmap.finalize(cs.caustics)
    stats.seconds = time.perf_counter() - t0
    return stats


# Photons per block of a pass (trace_photons): a pass within one block adds its
# records straight into the lightmaps, as it always has; a longer one sums
# block tallies over a fixed tree, whether its blocks run here or on a cluster.
BLOCK = 1 << 22

# What a pass needs besides the compiled scene: everything a block of it depends on.
PassPlan = namedtuple("PassPlan", "seed n_total max_bounces record_from main_last record_direct polarized "
                                  "caustics lights n_rec chunk")
# Where records are added: a lightmap set's flux, flux_sq and hits.
Tally = namedtuple("Tally", "flux flux_sq hits")
# A block's (or a subtree's) result: its main and caustic tallies (fine None
# without caustic maps), its ledger (4, n_bands), rays and records.
Partial = namedtuple("Partial", "main fine ledger rays records")


def _zero_tally(lm):
    return Tally(np.zeros_like(lm.flux), np.zeros_like(lm.flux_sq), np.zeros_like(lm.hits))


def _add_tally(lm, t):
    lm.flux[...] += t.flux
    lm.flux_sq[...] += t.flux_sq
    lm.hits[...] += t.hits


def trace_block(cs, plan, start, stop, progress=None):
    """Photons start..stop-1 of the pass `plan` on compiled scene cs, tallied from zero
    (cs's lightmaps are not touched) -> Partial. What a cluster's worker runs."""
    main = _zero_tally(cs.lightmaps)
    fine = _zero_tally(cs.caustics) if plan.caustics else None
    part = _trace_range(cs, plan, start, stop, main, main if fine is None else fine, progress, None)
    return part._replace(fine=fine)


def add_partials(a, b):
    """a + b, array by array (a before b: the tree's order)."""
    def add(x, y):
        return None if x is None else Tally(x.flux + y.flux, x.flux_sq + y.flux_sq, x.hits + y.hits)
    return Partial(add(a.main, b.main), add(a.fine, b.fine), a.ledger + b.ledger, a.rays + b.rays,
                   a.records + b.records)


def tree_split(lo, hi):
    """The fixed tree over block indices lo..hi-1: its left subtree is the largest power
    of two below hi - lo."""
    n = hi - lo
    half = 1 << ((n - 1).bit_length() - 1)
    return lo + half


def reduce_blocks(leaf, n, add=add_partials):
    """The sum of leaf(0) .. leaf(n-1) over the fixed tree (tree_split), leaves made in order."""
    def node(lo, hi):
        if hi - lo == 1:
            return leaf(lo)
        mid = tree_split(lo, hi)
        left = node(lo, mid)
        return add(left, node(mid, hi))
    return node(0, n)


def _trace_range(cs, plan, start, stop, main, fine, progress, points):
    """Photons start..stop-1 of `plan`, their records added in photon order into the tallies
    main (ids below the main lightmaps' size) and fine (the caustic lightmaps) -> Partial.
    progress(done, total) may return False (raises Cancelled). points: a PhotonStats whose
    points and point_power lists take every recorded hit (photon maps), or None."""
    nb = cs.n_bands
    scene = kernel_scene(cs, lights=plan.lights, caustics=plan.caustics)
    n_main = scene.lightmaps.area.shape[0]
    chunk, n_rec = plan.chunk, plan.n_rec
    out = PhotonRecords(np.empty((chunk, n_rec), np.int64), np.empty((chunk, n_rec, nb)),
                        np.empty((chunk if points is not None else 0, n_rec, 6)), np.empty((chunk, 4, nb)),
                        np.empty(chunk, np.int64))
    rec_texel, rec_power, rec_point, ledger, rays = out
    if points is not None:
        points.points, points.point_power = [], []
    pol = np.zeros((1, 1)) if plan.polarized else np.zeros(0)
    total = np.zeros((4, nb))
    n_rays = 0
    n_records = 0
    done = start
    while done < stop:
        c = min(chunk, stop - done)
        job = PhotonPass(np.uint64(plan.seed), done, plan.n_total, plan.max_bounces, plan.record_from,
                         plan.main_last, plan.record_direct, pol)
        parallel.run(_trace_chunk, c, scene, job, out, min_block=64)
        # the threads wait for this serial step: one pass, no masked copies
        n_records += lightmap.accumulate_records(main, fine, rec_texel, rec_power, c, n_main)
        if points is not None:
            keep = rec_texel[:c].reshape(-1) >= 0
            points.points.append(rec_point[:c].reshape(-1, 6)[keep])
            points.point_power.append(rec_power[:c].reshape(-1, nb)[keep])
        total += ledger[:c].sum(axis=0)
        n_rays += int(rays[:c].sum())
        done += c
        if progress is not None and progress(done - start, stop - start) is False:
            raise Cancelled("photon pass cancelled")
    return Partial(main, fine, total, n_rays, n_records)
