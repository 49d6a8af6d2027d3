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
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from ..core.errors import Cancelled
from ..core.jit import CORE
from ..lightmaps import lightmap
from ..core import memory_budget
from ..core import parallel
from ..shading import photon_aim
from ..lightmaps import orientation_lightmap
from ..lightmaps.lightmap import lightmap_slot  # noqa: F401  (hosts import it from here)
from ..shading.lights import emit_photon, photon_tint
from ..shading import bsdf
from ..shading import materials
from ..geometry.raycast import STACK_WORDS, intersect_closest
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


@njit(cache=True)
def ray_epsilon(px, py, pz):
    """Offset that moves a ray origin off its surface, relative to the coordinates' size."""
    return 1e-7 * (1.0 + max(abs(px), abs(py), abs(pz)))


@njit(cache=True, nogil=True)
def _trace_chunk(g, ms, bt, ts, ls, lm, lmc, use_caustics, caustic_alpha, ol, seed, first, n_total,
                 max_bounces, record_from, main_last,
                 rec_texel, rec_power, rec_point, ledger, rays, start, stop):
    """Rows start..stop-1 of the chunk (parallel.run spreads the rows over
    threads): the block's scratch, then the core."""
    nb = ledger.shape[2]
    _trace_chunk_core(g, ms, bt, ts, ls, lm, lmc, use_caustics, caustic_alpha, ol, seed, first, n_total,
                      max_bounces, record_from, main_last, rec_texel, rec_power, rec_point, ledger, rays, start,
                      stop, np.empty(STACK_WORDS, np.int32), np.empty(nb), np.empty(nb), np.empty(nb), np.empty(nb),
                      np.empty(nb), np.empty(bsdf.P_SIZE))


# The photon loop compiles without NRT: with it, every read of a field of the
# scene tuples is an atomic incref and decref that the threads contend for.
@njit(**CORE)
def _trace_chunk_core(g, ms, bt, ts, ls, lm, lmc, use_caustics, caustic_alpha, ol, seed, first, n_total,
                      max_bounces, record_from, main_last, rec_texel, rec_power, rec_point, ledger, rays, start,
                      stop, stack, power, wt, kd, ks, kt, pc):
    n_rec = rec_texel.shape[1]
    nb = ledger.shape[2]
    scale = ls.total_power / n_total
    n_main = lm.area.shape[0]
    for i in range(start, stop):
        for r in range(n_rec):
            rec_texel[i, r] = -1
        for k in range(4):
            for b in range(nb):
                ledger[i, k, b] = 0.0
        state = stream_state(seed, first + i)
        state, li, ox, oy, oz, dx, dy, dz, w = emit_photon(ls, g, state)
        p_light = ls.flux[li].mean()
        photon_tint(ls, li, dx, dy, dz, wt)     # an environment map's colour along d
        for b in range(nb):
            power[b] = w * wt[b] * ls.flux[li, b] * scale / p_light if p_light > 0.0 else 0.0
            ledger[i, 0, b] = power[b]
        n_rays = 0
        caustic = use_caustics
        rec = 0
        depth = 0
        tmin = 0.0
        while True:
            hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
                g, stack, ox, oy, oz, dx, dy, dz, tmin, math.inf)
            n_rays += 1
            if not hit:
                for b in range(nb):
                    ledger[i, 2, b] += power[b]
                break
            px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
            if depth >= record_from:
                lid = -1
                if caustic and depth >= 1:
                    # only sharp mirrors and glass since the light: the finer caustic lightmap
                    lid, f, s, tt = lightmap.record_slot(g, lmc, inst, shape, face, u, v)
                    if lid >= 0 and rec < n_rec:
                        rec_texel[i, rec] = n_main + lightmap.record_index(lmc, lid, f, s, tt)
                        if record_from == 0 and depth <= main_last and rec + 1 < n_rec:
                            # total irradiance for the final gather: in the main lightmap too
                            for b in range(nb):
                                rec_power[i, rec, b] = power[b]
                            rec += 1
                            lid = -1
                if lid < 0 and depth <= main_last:
                    lid, f, s, tt = lightmap.record_slot(g, lm, inst, shape, face, u, v)
                    if lid >= 0 and rec < n_rec:
                        rec_texel[i, rec] = lightmap.record_index(lm, lid, f, s, tt)
                if lid >= 0 and rec < n_rec:
                    for b in range(nb):
                        rec_power[i, rec, b] = power[b]
                    if rec_point.shape[0] > 0:
                        # Photon-map baselines keep the hit itself: position and normal.
                        rec_point[i, rec, 0] = px
                        rec_point[i, rec, 1] = py
                        rec_point[i, rec, 2] = pz
                        rec_point[i, rec, 3] = nx
                        rec_point[i, rec, 4] = ny
                        rec_point[i, rec, 5] = nz
                    rec += 1
                # the hit's normal bin in its OL and every level above (thesis 6.2)
                k = orientation_lightmap.hit_ol(g, ol, inst, shape, face) if depth <= main_last else -1
                while k >= 0 and rec < n_rec:
                    rec_texel[i, rec] = orientation_lightmap.bin_index(lm, ol, k, nx, ny, nz)
                    for b in range(nb):
                        rec_power[i, rec, b] = power[b]
                    rec += 1
                    k = ol.parent[k]
            if depth >= max_bounces or (depth >= main_last and not caustic):
                for b in range(nb):
                    ledger[i, 3, b] += power[b]
                break
            m = g.shape_material[shape]
            # photons read textures at their finest level: the albedo at the hit itself
            rough, ior, _ = materials.surface_inputs(ms, ts, g, inst, m, shape, face, u, v, 0.0, kd, ks, kt)
            snx, sny, snz = materials.shading_normal(ms, ts, g, inst, m, shape, face, u, v, 0.0, nx, ny, nz)
            # the local frame faces where the photon came from; entering by the outward normal
            cos_dn = dx * nx + dy * ny + dz * nz
            if cos_dn > 0.0:
                fx, fy, fz, sx, sy, sz = -nx, -ny, -nz, -snx, -sny, -snz
            else:
                fx, fy, fz, sx, sy, sz = nx, ny, nz, snx, sny, snz
            cos_o = -(dx * sx + dy * sy + dz * sz)
            if cos_o <= 1e-6:
                sx, sy, sz = fx, fy, fz
                cos_o = abs(cos_dn)
            bsdf.closure_scalars(bt, m, rough, ior, cos_dn < 0.0, cos_o, pc)
            pd, ps, pm, pg = bsdf.lobe_probabilities(pc, kd, ks, kt, cos_o)
            state, ur = next_float(state)
            state, u1 = next_float(state)
            state, u2 = next_float(state)
            state, u3 = next_float(state)
            ok = True
            # a diffuse or rough bounce spreads the focus: the rest of the path is no caustic
            caustic = caustic and ur >= pd and pc[bsdf.P_ALPHA] <= caustic_alpha
            if ur < pd:
                # Russian roulette on the lobe (thesis 3.4.3): a survivor keeps
                # power k/p <= power per band, the rest is absorbed here
                ix, iy, iz = bsdf.sample_diffuse(u1, u2)
                ds = bsdf.diffuse_scale(pc)
                for b in range(nb):
                    wt[b] = kd[b] * ds / pd
            elif ur < pd + ps + pm + pg:
                q = ps + pm + pg
                lox, loy, loz = bsdf.to_local(-dx, -dy, -dz, sx, sy, sz)
                ok, ix, iy, iz, _, _ = bsdf.sample_glossy(pc, ks, kt, ps, pm, pg, lox, loy, loz,
                                                        (ur - pd) / q, u1, u2, u3, wt)
                for b in range(nb):
                    wt[b] /= q
            else:
                for b in range(nb):
                    ledger[i, 1, b] += power[b]
                break
            if not ok:
                for b in range(nb):
                    ledger[i, 1, b] += power[b]
                break
            for b in range(nb):
                kept = power[b] * wt[b]
                ledger[i, 1, b] += power[b] - kept
                power[b] = kept
            dx, dy, dz = bsdf.from_local(ix, iy, iz, sx, sy, sz)
            if (dx * fx + dy * fy + dz * fz) * iz <= 0.0:
                # the shading frame's side and the face's disagree: absorbed, so a
                # normal map never leaks light through the surface
                for b in range(nb):
                    ledger[i, 1, b] += power[b]
                break
            # Leave the surface on the side the new direction points to.
            eps = ray_epsilon(px, py, pz)
            side = eps if (dx * nx + dy * ny + dz * nz) > 0.0 else -eps
            ox, oy, oz = px + side * nx, py + side * ny, pz + side * nz
            depth += 1
        rays[i] = n_rays


def trace_photons(cs, n_photons, seed=0, max_bounces=8, record_direct=False,
                  progress=None, chunk=None, keep_points=False, caustics=False, gather=False, aim=None):
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
    """
    if not 0 <= int(max_bounces) <= MAX_BOUNCES_LIMIT:
        raise ValueError(f"max_bounces must be in [0, {MAX_BOUNCES_LIMIT}], got {max_bounces}")
    n_photons = int(n_photons)
    if n_photons < 0:
        raise ValueError(f"photon count must be non-negative, got {n_photons}")
    nb = cs.n_bands
    if hasattr(cs, "render_records"):
        cs.render_records = None      # made over the light this pass adds to
    stats = PhotonStats(emitted=np.zeros(nb), absorbed=np.zeros(nb), escaped=np.zeros(nb),
                        truncated=np.zeros(nb))
    if n_photons == 0 or cs.lights.total_power <= 0.0:
        return stats
    t0 = time.perf_counter()
    ol = cs.orientation if cs.orientation is not None else orientation_lightmap.empty_maps(cs.geometry.inst_proto.shape[0])
    # one record per hit on an own lightmap, plus one per OL level above the instance
    n_rec = (int(max_bounces) + 1) * (1 + orientation_lightmap.levels(ol))
    lmc = getattr(cs, "caustics", None)
    use_caustics = bool(caustics) and lmc is not None
    if use_caustics and record_direct:
        n_rec += int(max_bounces)          # a caustic hit is recorded twice
    chunk = chunk or max(4096, min(1 << 16, (1 << 21) // n_rec))
    if keep_points:   # a photon map keeps every hit: refuse what cannot fit before tracing
        memory_budget.check(f"photon map ({n_photons:,} photons kept, up to {n_rec} hits each)",
                            n_photons * min(n_rec, 4) * (6 + nb) * 8 * 2, "lower the photon count")
    rec_texel = np.empty((chunk, n_rec), np.int64)
    rec_power = np.empty((chunk, n_rec, nb))
    ledger = np.empty((chunk, 4, nb))
    rays = np.empty(chunk, np.int64)
    rec_point = np.empty((chunk if keep_points else 0, n_rec, 6))
    points, point_power = [], []
    lm = cs.lightmaps
    # bakes keep every photon in the one lightmap they write out; renders split caustics off
    lmc = lmc if use_caustics else lm
    cs.caustics_traced = use_caustics
    cs.lightmaps_hold_direct = bool(record_direct)
    n_main = lm.area.shape[0]
    lights = photon_aim.aimed(cs.lights, aim)
    if lights.aim_radius < cs.lights.aim_radius:
        stats.aim = (lights.aim_center.copy(), float(lights.aim_radius))
    done = 0
    while done < n_photons:
        c = min(chunk, n_photons - done)
        parallel.run(_trace_chunk, c, cs.geometry, cs.materials, cs.bsdf, cs.textures, lights, lm, lmc,
                     use_caustics, CAUSTIC_ALPHA, ol, np.uint64(seed), done, n_photons, int(max_bounces),
                     0 if record_direct else 1, int(max_bounces) - 1 if gather else int(max_bounces),
                     rec_texel, rec_power, rec_point, ledger, rays, min_block=64)
        # the threads wait for this serial step: one pass, no masked copies
        stats.records += lightmap.accumulate_records(lm, lmc, rec_texel, rec_power, c, n_main)
        if keep_points:
            keep = rec_texel[:c].reshape(-1) >= 0
            points.append(rec_point[:c].reshape(-1, 6)[keep])
            point_power.append(rec_power[:c].reshape(-1, nb)[keep])
        sums = ledger[:c].sum(axis=0)
        stats.emitted += sums[0]
        stats.absorbed += sums[1]
        stats.escaped += sums[2]
        stats.truncated += sums[3]
        stats.rays += int(rays[:c].sum())
        done += c
        if progress is not None and progress(done, n_photons) is False:
            raise Cancelled("photon pass cancelled")
    stats.photons = n_photons
    if keep_points:
        stats.points = np.concatenate(points)
        stats.point_power = np.concatenate(point_power)
    lightmap.finalize(lm)
    if use_caustics:
        lightmap.finalize(lmc)
    stats.seconds = time.perf_counter() - t0
    return stats
