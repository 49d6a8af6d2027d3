"""Final gather for bakes: a texel's indirect light from gather rays over the photon lightmaps.

The thesis's bake is the photon lightmap itself: direct light gathered per
texel (texel_gather.py), indirect light = the texel's own photons, so every
texel shows its photons' noise. Here the indirect part moves one bounce away,
as final_gather.py does for renders: from points spread over the texel's
surface (by world area, as the direct part's), cosine rays sample the
hemisphere and read kd(q)·E(q) where they land (the photon pass recorded
total irradiance, record_direct). The texel's value is then

    E = E_direct (light samples) + E_gather (photon lightmaps one bounce away)
        + E_caustic (the texel's caustic photons: light focused by sharp
          mirrors and glass, which gather rays cannot find)

A texel gets `points` points, each `rays` gather rays per lit side, so its
indirect noise falls as 1/sqrt(points·rays). Sides: an open mesh, disk or quad
is lit from both sides (photons of both meet in its texel), a closed solid from
outside only unless a light lies inside it (texel_gather.lit_sides). Point
streams are keyed like the direct part's, xored with STREAM_XOR, so the direct
part of a bake is bit-identical with and without the gather, and results do
not depend on the thread count.
"""
import time
from collections import namedtuple

import numpy as np
from numba import njit

from ..geometry import csg
from ..geometry import csg_trace
from ..lightmaps import lightmap
from . import texel_gather
from .csg_bake import csg_texel_items, csg_texel_sample
from .directional_lightmap import AMBIENT_MOMENT
from .final_gather import gather_irradiance
from .kernel_scene import kernel_scene
from .path_vertex import new_path_scratch
from ..core.jit import CORE, typed
from ..core.sampling import next_float
from ..core import parallel

STREAM_XOR = np.uint64(0x5BD1E9955BD1E995)
STREAM_XOR_2 = np.uint64(0x2545F4914F6CDD1D)  # the adaptive pass

GatherPass = namedtuple("GatherPass", [
    "mode",       # lightmap lookup where gather rays land (lightmap.MODE_*)
    "points",     # points per texel
    "rays",       # int64[K] gather rays per point and lit side of each item (0: skipped)
    "order",      # int64[K] the order items are handed out in (_order)
    "stream",     # uint64 xored into the texels' stream keys (STREAM_XOR, STREAM_XOR_2)
    "bands",      # the bands of a row; rows wider than this are a directional bake's (moments after)
])


@njit(**CORE)
def point_indirect(scene, w, mode, n_rays, p, n, side, state, out):
    """Gathered indirect irradiance at a bake point into out (added): along n
    (side >= 0) and against it (side <= 0); w.count[0] gains the rays traced.
    A directional bake's row takes the back side's moments as if mirrored to
    the front, as its direct light's (texel_gather._add_unshadowed)."""
    nb = w.tp.shape[0]
    for sgn in (1.0, -1.0):
        if side * sgn < 0.0:
            continue
        f = (sgn * n[0], sgn * n[1], sgn * n[2])
        if sgn < 0.0:
            mirror_moments(out, nb, n)
        state = gather_irradiance(scene, w, p, f, f, n_rays, mode, state, out, (typed(0), w.bands, w.tp))
        if sgn < 0.0:
            mirror_moments(out, nb, n)
    return state


@njit(cache=True, inline="always")
def mirror_moments(out, nb, n):
    """A directional row's moments reflected in the plane of normal n (nothing for
    a plain row). Twice is none: around a call, it mirrors what the call adds."""
    if out.shape[0] <= nb:
        return
    for b in range(nb):
        j = nb + 3 * b
        d = 2.0 * (out[j] * n[0] + out[j + 1] * n[1] + out[j + 2] * n[2])
        out[j] -= d * n[0]
        out[j + 1] -= d * n[1]
        out[j + 2] -= d * n[2]


@njit(cache=True)
def add_caustic(lmc, lid, face, s, t, n, tmp, out):
    """The caustic lightmap's irradiance at (s, t) into out (tmp: scratch of the
    bands). A directional row takes it as uniform over the hemisphere about n:
    the caustic map keeps no direction."""
    lightmap.lookup(lmc, lid, face, s, t, lightmap.MODE_CONSTANT, tmp)
    nb = tmp.shape[0]
    for b in range(nb):
        out[b] += tmp[b]
    if out.shape[0] > nb:
        texel_gather.add_moment(out, nb, tmp, AMBIENT_MOMENT, n[0], n[1], n[2])


@njit(cache=True, inline="always")
def add_mesh_caustic(scene, tx, it, t, b1, b2, n, tmp, out):
    """The caustic lightmap of mesh texel it at barycentrics (b1, b2) of triangle t, added to out."""
    uv = scene.geometry.tri_uv[t]
    b0 = 1.0 - b1 - b2
    add_caustic(scene.caustic_maps, tx.lid[it], 0, b0 * uv[0, 0] + b1 * uv[1, 0] + b2 * uv[2, 0],
                b0 * uv[0, 1] + b1 * uv[1, 1] + b2 * uv[2, 1], n, tmp, out)


@njit(cache=True)
def _accumulate(w, ep, e, q, nb):
    """e += w·ep (the whole row); q += (w², w²·x, w²·x²) of the point's band mean
    x over its nb bands (for the error estimate)."""
    x = 0.0
    for b in range(nb):
        x += ep[b]
    for b in range(ep.shape[0]):
        e[b] += w * ep[b]
    x /= nb
    w2 = w * w
    q[0] += w2
    q[1] += w2 * x
    q[2] += w2 * x * x


@njit(cache=True)
def _variance(q, wsum, e, nb):
    """Variance of the weighted mean of the point values (band mean of e's first
    nb), treating the texel's points as independent: conservative, as they are
    stratified."""
    if wsum <= 0.0:
        return 0.0
    m = 0.0
    for b in range(nb):
        m += e[b]
    m /= nb * wsum
    return max(q[2] - 2.0 * m * q[1] + m * m * q[0], 0.0) / (wsum * wsum)


@njit(cache=True, nogil=True)
def _indirect_mesh(scene, tx, job, out, var, start, stop):
    """The gather of mesh texels start..stop: the block's scratch, then the core.
    out: (texels, job.bands), or a directional bake's wider rows."""
    _indirect_mesh_core(scene, tx, job, out, var, start, stop, new_path_scratch(job.bands),
                        np.empty((2, out.shape[1])), np.empty(3))


# Per-point loops compile without NRT, as texel_gather's kernels do (a read of a
# scene tuple's field would otherwise be a contended atomic incref and decref).
@njit(**CORE)
def _indirect_mesh_core(scene, tx, job, out, var, start, stop, w, bands, q):
    nb = job.bands
    e, ep = bands[0], bands[1]
    n_points = job.points
    k = texel_gather.grid_side(n_points)
    for i in range(start, stop):
        it = job.order[i]     # a shuffled order: the blocks get equal work
        n_rays = job.rays[it]
        if n_rays <= 0:
            continue
        for b in range(e.shape[0]):
            e[b] = 0.0
        q[0] = q[1] = q[2] = 0.0
        pieces = texel_gather.mesh_texel_pieces(scene.geometry, tx, it)
        if pieces[2] > 0.0:
            state = texel_gather.texel_stream(tx, it, job.stream)
            for s in range(n_points):
                state, j1 = next_float(state)
                state, j2 = next_float(state)
                u1, u2 = texel_gather.jitter(s, k, j1, j2)
                ok, px, py, pz, nx, ny, nz, t, b1, b2 = texel_gather.mesh_texel_sample(
                    scene.geometry, tx, pieces, u1, u2)
                for b in range(ep.shape[0]):
                    ep[b] = 0.0
                if ok:
                    texel_gather.add_normal(ep, nb, nx, ny, nz)
                    state = point_indirect(scene, w, job.mode, n_rays, (px, py, pz), (nx, ny, nz), tx.side[it],
                                           state, ep)
                    if scene.caustics:
                        add_mesh_caustic(scene, tx, it, t, b1, b2, (nx, ny, nz), w.ind, ep)
                _accumulate(1.0, ep, e, q, nb)
        var[it] = _variance(q, float(n_points), e, nb)
        for b in range(e.shape[0]):
            out[it, b] = e[b] / n_points


@njit(cache=True, nogil=True)
def _indirect_prim(scene, tx, job, out, var, start, stop):
    """The gather of primitive texels start..stop: the block's scratch, then the core
    (out as _indirect_mesh's)."""
    _indirect_prim_core(scene, tx, job, out, var, start, stop, new_path_scratch(job.bands),
                        np.empty((2, out.shape[1])), np.empty(3))


@njit(**CORE)
def _indirect_prim_core(scene, tx, job, out, var, start, stop, w, bands, q):
    nb = job.bands
    e, ew = bands[0], bands[1]
    n_points = job.points
    k = texel_gather.grid_side(n_points)
    for i in range(start, stop):
        it = job.order[i]     # a shuffled order: the blocks get equal work
        n_rays = job.rays[it]
        if n_rays <= 0:
            continue
        for b in range(ew.shape[0]):
            ew[b] = 0.0
        q[0] = q[1] = q[2] = 0.0
        side = 0 if tx.sides[tx.lm[it]] == 2 else 1
        state = texel_gather.texel_stream(tx, it, job.stream)
        wsum = 0.0
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, jac, px, py, pz, nx, ny, nz, cs_, ct = texel_gather.prim_texel_sample(tx, it, u1, u2)
            if not ok:
                continue
            for b in range(e.shape[0]):
                e[b] = 0.0
            texel_gather.add_normal(e, nb, nx, ny, nz)
            state = point_indirect(scene, w, job.mode, n_rays, (px, py, pz), (nx, ny, nz), side, state, e)
            if scene.caustics:
                add_caustic(scene.caustic_maps, tx.lid[it], tx.face[it], cs_, ct, (nx, ny, nz), w.ind, e)
            _accumulate(jac, e, ew, q, nb)
            wsum += jac
        var[it] = _variance(q, wsum, ew, nb)
        for b in range(ew.shape[0]):
            out[it, b] = ew[b] / wsum if wsum > 0.0 else 0.0


@njit(cache=True, nogil=True)
def _indirect_csg(scene, tx, job, acc, wsum, q, start, stop):
    """acc[row] += J·E_indirect, wsum[row] += J, q[row] += the error sums, like
    csg_bake._gather_csg (outside only). An item's rows are its own (its texel and
    that texel's split regions), so parallel items never write the same row. acc's
    rows: job.bands wide, or a directional bake's."""
    cb = csg_trace.csg_base(tx.buf)
    nb = job.bands
    n_points = job.points
    k = texel_gather.grid_side(n_points)
    for i in range(start, stop):
        it = job.order[i]     # a shuffled order: the blocks get equal work
        n_rays = job.rays[it]
        if n_rays <= 0:
            continue
        w = new_path_scratch(nb)
        bits = np.empty(3 * csg.MAX_WORK + 8, np.int32)
        e = np.zeros(acc.shape[1])
        state = texel_gather.texel_stream(tx, it, job.stream)
        for s in range(n_points):
            state, j1 = next_float(state)
            state, j2 = next_float(state)
            u1, u2 = texel_gather.jitter(s, k, j1, j2)
            ok, row, jac, px, py, pz, nx, ny, nz, cs_, ct = csg_texel_sample(tx, it, cb, bits, u1, u2)
            if not ok:
                continue
            for b in range(e.shape[0]):
                e[b] = 0.0
            texel_gather.add_normal(e, nb, nx, ny, nz)
            state = point_indirect(scene, w, job.mode, n_rays, (px, py, pz), (nx, ny, nz), 1, state, e)
            if scene.caustics:
                add_caustic(scene.caustic_maps, tx.lid[it], tx.face[it], cs_, ct, (nx, ny, nz), w.ind, e)
            _accumulate(jac, e, acc[row], q[row], nb)
            wsum[row] += jac


Gathered = namedtuple("Gathered", [
    "ids",    # int64[K]  texel rows (the direct part's)
    "E",      # float64[K, B] indirect irradiance (W/m²)
    "se",     # float64[K] its standard error (band mean), from the spread over the texel's points
    "rays",   # int64[K]  gather rays per point and lit side that the texel got
    "moments",  # float64[K, W - B] a directional bake's moments after the bands (texel_gather.moment_width), or None
], defaults=(None,))


class Texels:
    """The packed texel items of one bake (mesh, primitive and CSG) and the
    kernel inputs they share; run() is one gather pass over them."""

    def __init__(self, cs, lightmap_ids, csg_leaves, points, mode, seed, moments=False):
        if not getattr(cs, "lightmaps_hold_direct", False) and np.any(cs.lightmaps.flux):
            raise ValueError("a bake's final gather needs a photon pass that recorded direct light")
        self.cs, self.points, self.mode = cs, int(points), int(mode)
        # a directional bake's rows carry moments
        self.width = texel_gather.moment_width(cs.n_bands) if moments else cs.n_bands
        self.scene = kernel_scene(cs, inst_side=texel_gather.instance_sides(cs))
        self.mesh = self.prim = self.csg = None
        ids = sorted({int(l) for l in lightmap_ids})
        if ids:
            mesh, prim = texel_gather.collect_texels(cs, texel_gather.lightmap_owners(cs), ids, seed, with_sides=True)
            self.mesh, self.prim = mesh.packed(), prim.packed()
        if csg_leaves:
            self.csg = csg_texel_items(cs, list(csg_leaves), seed)

    def item_rows(self):
        """Per part, the texel row that each item's error is judged by (for a
        CSG texel cut into regions: the region rows too, see csg_rows)."""
        return [tx.texel if i < 2 else tx.row for i, tx in enumerate((self.mesh, self.prim, self.csg))
                if tx is not None]

    def job(self, item_rays, stream):
        """The GatherPass of one part's items."""
        return GatherPass(self.mode, self.points, item_rays, _order(item_rays), stream, self.cs.n_bands)

    def run(self, item_rays, stream, cached=False):
        """One pass, item_rays[part][item] rays per point -> (ids, E, var, rays) per texel row
        (E: rows self.width wide).
        cached: mesh texels interpolate an irradiance cache whose records get
        rays-per-point × points rays each (engine/transport/irradiance_cache.py); those no
        record reaches are gathered per texel. Also sets self.seconds, the time
        its kernels took."""
        nb = self.cs.n_bands
        parts, i = [], 0
        t0 = time.perf_counter()
        if self.mesh is not None:
            tx, r = self.mesh, item_rays[i]
            out, var = np.zeros((tx.texel.size, self.width)), np.zeros(tx.texel.size)
            todo = r
            if cached and r.size:
                from .irradiance_cache import cached_mesh_gather
                out, var, fallback, self.cache_info = cached_mesh_gather(
                    self.cs, self.scene, self.mode, tx, self.points, int(r.max()) * self.points, stream,
                    self.width)
                todo = np.zeros_like(r)
                todo[fallback] = r[fallback]
            if todo.any():
                o2, v2 = np.zeros_like(out), np.zeros_like(var)
                parallel.run(_indirect_mesh, out.shape[0], self.scene, tx, self.job(todo, stream), o2, v2,
                             remote=True)
                out[todo > 0], var[todo > 0] = o2[todo > 0], v2[todo > 0]
            parts.append((tx.texel, out, var, r))
            i += 1
        if self.prim is not None:
            tx, r = self.prim, item_rays[i]
            out, var = np.zeros((tx.texel.size, self.width)), np.zeros(tx.texel.size)
            parallel.run(_indirect_prim, out.shape[0], self.scene, tx, self.job(r, stream), out, var, remote=True)
            parts.append((tx.texel, out, var, r))
            i += 1
        if self.csg is not None:
            tx, r = self.csg, item_rays[i]
            n_rows = self.cs.lightmaps.area.shape[0]
            acc, wsum, q = np.zeros((n_rows, self.width)), np.zeros(n_rows), np.zeros((n_rows, 3))
            parallel.run(_indirect_csg, tx.lm.shape[0], self.scene, tx, self.job(r, stream), acc, wsum, q,
                         remote=True)
            rows = np.flatnonzero(wsum > 0.0).astype(np.int64)
            var = np.array([_variance(q[j], wsum[j], acc[j], nb) for j in rows])
            # a row's rays: those of the item (texel) it belongs to
            row_rays = np.zeros(n_rows, np.int64)
            for it_row, k in zip(*csg_rows(self.cs.lightmaps, tx.row)):
                row_rays[it_row] = r[k]
            parts.append((rows, acc[rows] / wsum[rows][:, None], var, row_rays[rows]))
        self.seconds = time.perf_counter() - t0
        return parts


def _order(item_rays):
    """A fixed shuffle of the items: a texel's rays differ in an adaptive pass, and
    neighbours (one object's texels) differ in cost, so contiguous chunks would not."""
    return np.random.default_rng(0x5EED).permutation(item_rays.size).astype(np.int64)


def csg_rows(lm, cell_rows):
    """(rows, item index) pairs: each CSG item's texel row and its split regions' rows."""
    rows, owner = [cell_rows], [np.arange(cell_rows.size)]
    k = lm.split[cell_rows]
    for it in np.flatnonzero(k >= 0):
        n_reg = int(lm.split_cell[k[it]].max())
        if n_reg > 0:
            rows.append(lm.split_first[k[it]] + np.arange(n_reg))
            owner.append(np.full(n_reg, it))
    return np.concatenate(rows), np.concatenate(owner)


def _joined(parts, nb, width):
    """The parts' rows (width wide) sorted by texel row, bands and moments apart."""
    if not parts:
        parts = [(np.zeros(0, np.int64), np.zeros((0, width)), np.zeros(0), np.zeros(0, np.int64))]
    cat = [np.concatenate([p[j] for p in parts]) for j in range(4)]
    order = np.argsort(cat[0], kind="stable")
    E = cat[1][order]
    return Gathered(cat[0][order], np.ascontiguousarray(E[:, :nb]), np.sqrt(cat[2][order]), cat[3][order].astype(np.int64),
                    E[:, nb:] if width > nb else None)


def gathered_indirect(cs, lightmap_ids=(), csg_leaves=(), points=texel_gather.DEFAULT_SAMPLES, rays=4,
                      mode=lightmap.MODE_BILINEAR, seed=0, target_error=0.0, max_rays=None, direct=None,
                      time_budget=None, cached=False, info=None, moments=False):
    """Indirect irradiance (gather + caustics) of the measured texels of the given
    instance lightmaps and CSG leaves -> Gathered(ids, E, se, rays) over the same
    texels as texel_gather.direct_texel_irradiance / csg_bake.direct_csg_texels
    return. `rays` gather rays per point and lit side. Nothing in `cs` changes.

    Adaptive, after a first pass with `rays` everywhere (a second pass adds rays,
    at most max_rays per point in all, 16 x rays if None):
    - target_error > 0: a texel whose standard error exceeds target_error × its
      total irradiance (the direct part, a (ids, E) pair, plus the gathered one)
      gets as many rays as should bring it to the target;
    - time_budget (seconds for this call): the rays the first pass's speed allows
      in the time left go to the texels in proportion to their relative error
      (which minimises the summed squared relative error), capped by the target's
      need if both are given.
    A texel's error is judged against at least a tenth of the median texel's
    irradiance, so black texels do not take every ray.

    cached: the first pass reads mesh texels' indirect light from an irradiance
    cache (engine/transport/irradiance_cache.py: records with points × rays rays each at a
    sparse, adaptive set of places, interpolated at every texel's points); an
    adaptive second pass adds per-texel rays as before. info (a dict) gets the
    cache's counts. moments: Gathered.moments holds the texels' moments for a
    directional bake."""
    points, rays = int(points), int(rays)
    if points < 1 or rays < 1:
        raise ValueError(f"points and rays must be >= 1, got {points}, {rays}")
    t0 = time.perf_counter()
    tex = Texels(cs, lightmap_ids, csg_leaves, points, mode, seed, moments)
    item_rows = tex.item_rows()
    first = _joined(tex.run([np.full(r.size, rays, np.int64) for r in item_rows], STREAM_XOR, cached),
                    cs.n_bands, tex.width)
    if info is not None and getattr(tex, "cache_info", None):
        info.update(tex.cache_info)
    t_first = tex.seconds
    got = first
    adaptive = target_error > 0.0 or time_budget is not None
    if adaptive and first.ids.size:
        cap = max(rays, int(max_rays) if max_rays else 16 * rays)
        budget = None
        if time_budget is not None:
            # rays (per point, summed over texels) the time left allows at the first pass's
            # kernel speed (its texel collection is not repeated)
            left = float(time_budget) - (time.perf_counter() - t0)
            budget = int(max(left, 0.0) / max(t_first, 1e-9) * rays * first.ids.size)
        need = _extra_need(first, direct, float(target_error), rays, cap, budget)
        extra = _by_item(cs.lightmaps, tex, first.ids, need, item_rows)
        if any(e.any() for e in extra):
            second = _joined(tex.run(extra, STREAM_XOR_2), cs.n_bands, tex.width)
            got = _combined(first, second)
    cs.timings["bake_gather"] = time.perf_counter() - t0
    return got


def _extra_need(first, direct, target, rays, cap, budget):
    """Per texel of `first`, the rays per point to add (see gathered_indirect)."""
    total = _total_mean(first.ids, first.E, direct)
    median = float(np.median(total)) if total.size else 0.0
    rel = first.se / np.maximum(total, max(0.1 * median, 1e-300))
    room = cap - rays
    need = np.full(rel.size, room, np.int64)
    if target > 0.0:
        need = (np.ceil(rays * (rel / target) ** 2).clip(rays, cap) - rays).astype(np.int64)
    if budget is not None:
        # for the time budget, error relative to the median texel's light below it: the summed
        # squared error of the map (its RMSE) is what the rays should cut, not dark texels' ratios
        weight = first.se / np.maximum(total, max(median, 1e-300))
        need = np.minimum(need, _share(weight, rays, room, budget))
    return need


def _share(rel, rays, room, budget):
    """Extra rays per texel, at most `room` each and `budget` in all, so that every
    texel's rays in total are as near as possible to proportional to its relative
    error (water-filling by bisection on the proportionality constant)."""
    if budget <= 0 or not np.any(rel > 0):
        return np.zeros(rel.size, np.int64)

    def extra(lam):
        return np.clip(np.floor(lam * rel) - rays, 0, room)

    if extra(1e300).sum() <= budget:
        return np.full(rel.size, room, np.int64)
    lo, hi = 0.0, (rays + room) / rel[rel > 0].min()
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if extra(mid).sum() > budget:
            hi = mid
        else:
            lo = mid
    return extra(lo).astype(np.int64)


def _by_item(lm, tex, ids, need, item_rows):
    """Per-texel-row rays -> per part and item (a CSG texel: the most any of its regions needs)."""
    by_row = np.zeros(lm.area.shape[0], np.int64)
    by_row[ids] = need
    extra = []
    for k, rows in enumerate(item_rows):
        if tex.csg is not None and k == len(item_rows) - 1:
            all_rows, owner = csg_rows(lm, rows)
            e = np.zeros(rows.size, np.int64)
            np.maximum.at(e, owner, by_row[all_rows])
            extra.append(e)
        else:
            extra.append(by_row[rows])
    return extra


def _total_mean(ids, E, direct):
    """Band-mean total irradiance per texel row of `ids`: E plus the direct part."""
    total = E.mean(axis=1).copy()
    if direct is not None and len(direct[0]):
        d_ids = np.asarray(direct[0], np.int64)
        pos = np.searchsorted(d_ids, ids).clip(0, d_ids.size - 1)
        hit = d_ids[pos] == ids
        total[hit] += np.asarray(direct[1])[pos[hit]].mean(axis=1)
    return total


def _combined(a, b):
    """Two passes over the same texels, weighted by their rays: E (and moments), its error and the rays."""
    pos = np.searchsorted(a.ids, b.ids)
    var, n = a.se ** 2, a.rays.astype(np.float64)
    ra, rb = n[pos], b.rays.astype(np.float64)
    tot = np.maximum(ra + rb, 1.0)

    def mixed(xa, xb):
        if xa is None:
            return None
        x = xa.copy()
        x[pos] = (ra[:, None] * xa[pos] + rb[:, None] * xb) / tot[:, None]
        return x

    var[pos] = (ra ** 2 * var[pos] + rb ** 2 * b.se ** 2) / tot ** 2
    n[pos] = ra + rb
    return Gathered(a.ids, mixed(a.E, b.E), np.sqrt(var), n.astype(np.int64), mixed(a.moments, b.moments))


def set_gathered(lm, direct, indirect):
    """Writes E = direct + indirect (two (texel ids, E) results over the same texels)
    as the bake's lightmap: flux = E·area, the photon flux of those texels replaced,
    then finalize() (dilation into empty texels as usual)."""
    ids_d, E_d = direct
    ids_i, E_i = indirect[0], indirect[1]
    nb = lm.flux.shape[1]
    ids = np.union1d(np.asarray(ids_d, np.int64), np.asarray(ids_i, np.int64))
    E = np.zeros((ids.size, nb))
    E[np.searchsorted(ids, ids_d)] += np.asarray(E_d).reshape(-1, nb)
    E[np.searchsorted(ids, ids_i)] += np.asarray(E_i).reshape(-1, nb)
    if ids.size:
        lm.flux[ids] = E * lm.area[ids][:, None]
    lightmap.finalize(lm)
