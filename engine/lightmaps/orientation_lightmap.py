"""Orientation lightmaps (thesis ch. 6): irradiance indexed by surface normal.

An OL is shared by a group of instances. A photon that hits any of them is
recorded in the bin of the hit's world-space normal, and at render time a
point reads the OL at its own normal. The OL needs no UVs and no exact area
per primitive; each bin's area is estimated stochastically (area_estimation.py),
and it gathers the hits of the whole group, so its variance is low. Photon
paths still use the real geometry: an OL changes storage only (6.2.3).

Bins. The sphere of directions is mapped to an R×R octahedral square, the
same map the analytic sphere uses for its chart (primitives.octa_encode):
bins are nearly equal in solid angle, there is no pole singularity, and an
OL on a sphere is texel-for-texel the sphere's own lightmap, the thesis's
limit case. An OL is therefore stored as one more lightmap (one tile of R×R
texels) in the scene's flat texel arrays: accumulate, finalize, statistics and
memory accounting all apply unchanged, and E = flux / area per bin.

Hierarchy (fig. 6.3). A hit is recorded in its instance's innermost OL and in
every ancestor, so each level holds its whole subtree and knows its own hit
count. A lookup starts at the innermost level and moves up while the bin has
too few photons (relative error above 1/sqrt(min_hits)).

Backup (6.2.1). Instances under a backup OL keep their own lightmaps and
record into both; a texel whose relative error is too high reads the OL.

Bins with zero estimated area hold no measurement: lookups never blend them
in (finalize() dilates them only so that a constant lookup at a normal the
area samples missed still returns a neighbour's value).
"""
import math
from collections import namedtuple

import numpy as np
from numba import njit

from . import lightmap
from ..geometry.dcsg_trace import dcsg_vs0
from ..core.jit import CORE, typed
from ..geometry.primitives import octa_encode
from ..core.scene import SceneError

OrientationMaps = namedtuple("OrientationMaps", [
    "inst_ol",        # int32[I]  innermost OL of instance i, -1 if none
    "inst_keep",      # int8[I]   1: the instance keeps its own lightmaps (backup OL)
    "lid",            # int32[K]  lightmap id of OL k in the scene's lightmaps
    "parent",         # int32[K]  enclosing OL, -1 at the top
    "max_rel_error",  # float64[K] a bin above this relative error defers upwards
    "inst_stub0",     # int64[I]  L-system OL stubs (thesis 7.4): a DCSG hit with stub index j
                      #           records into OL inst_stub0[i] + j; -1: the instance has none
])

MAX_LEVELS = 16


def empty_maps(n_instances):
    """Routing for a scene without OLs (the kernels always take one)."""
    return OrientationMaps(np.full(n_instances, -1, np.int32), np.zeros(n_instances, np.int8),
                           np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0),
                           np.full(n_instances, -1, np.int64))


def levels(maps):
    """Longest chain of OLs above one instance (0 without OLs): extra records per hit."""
    depth = 0
    for k in range(maps.parent.shape[0]):
        d, j = 0, k
        while j >= 0:
            d += 1
            j = int(maps.parent[j])
        depth = max(depth, d)
    return depth


def plan(scene):
    """Validates scene.orientation_lightmaps and returns (maps without lids, chains).

    Raises SceneError naming the culprit: an instance claimed by two OLs, a
    parent cycle, a bad index or resolution."""
    ols = list(scene.orientation_lightmaps)
    n_inst = len(scene.instances)
    maps = empty_maps(n_inst)
    if not ols:
        return maps
    K = len(ols)
    parent = np.full(K, -1, np.int32)
    rel = np.zeros(K)
    for k, ol in enumerate(ols):
        if not 2 <= int(ol.resolution) <= 512:
            raise SceneError(f"orientation lightmap '{ol.name}': resolution must be in [2, 512], "
                             f"got {ol.resolution}")
        if int(ol.samples) < 1:
            raise SceneError(f"orientation lightmap '{ol.name}': needs at least one area sample")
        if int(ol.min_hits) < 1:
            raise SceneError(f"orientation lightmap '{ol.name}': min_hits must be >= 1")
        p = int(ol.parent)
        if not -1 <= p < K or p == k:
            raise SceneError(f"orientation lightmap '{ol.name}': bad parent index {p}")
        parent[k] = p
        rel[k] = 1.0 / math.sqrt(int(ol.min_hits))
        for i in ol.instances:
            i = int(i)
            if not 0 <= i < n_inst:
                raise SceneError(f"orientation lightmap '{ol.name}': no instance {i}")
            if maps.inst_ol[i] >= 0:
                other = ols[int(maps.inst_ol[i])].name
                raise SceneError(f"instance '{scene.instances[i].name}' is in two orientation "
                                 f"lightmaps ('{other}' and '{ol.name}'); nest them instead")
            maps.inst_ol[i] = k
            maps.inst_keep[i] = 1 if ol.backup else 0
    for k in range(K):
        p = int(parent[k])
        if p >= 0 and int(ols[p].resolution) != int(ols[k].resolution):
            # a parent's bin areas are the sum of its children's
            raise SceneError(f"orientation lightmap '{ols[k].name}' must have the resolution of "
                             f"its parent '{ols[p].name}' ({ols[p].resolution}), got {ols[k].resolution}")
        seen, j = set(), k
        while j >= 0:
            if j in seen or len(seen) > MAX_LEVELS:
                raise SceneError(f"orientation lightmap '{ols[k].name}': parent chain loops or "
                                 f"is deeper than {MAX_LEVELS}")
            seen.add(j)
            j = int(parent[j])
    return OrientationMaps(maps.inst_ol, maps.inst_keep, np.zeros(K, np.int32), parent, rel,
                           maps.inst_stub0)


def covered_instances(maps, k):
    """Instances whose hits OL k receives: its own and those of every descendant."""
    hit = np.zeros(maps.inst_ol.shape[0], np.bool_)
    j = maps.inst_ol.astype(np.int64)
    # walk all instances up their chains at once: one step per level, not per instance
    for _ in range(MAX_LEVELS + 1):
        hit |= j == k
        live = j >= 0
        if not live.any():
            break
        j[live] = maps.parent[j[live]]
    return np.flatnonzero(hit)


# --------------------------------------------------------------------------------------
# Kernels: recording and lookup
# --------------------------------------------------------------------------------------

@njit(cache=True, inline="always")
def bin_coords(nx, ny, nz):
    """Octahedral (s, t) in [0,1]² of a unit normal (the sphere chart's map)."""
    return octa_encode(nx, ny, nz)


@njit(cache=True, inline="always")
def bin_index(lm, ol, k, nx, ny, nz):
    s, t = octa_encode(nx, ny, nz)
    return lightmap.texel_index(lm, ol.lid[k], 0, s, t)


@njit(cache=True, inline="always")
def _rel_error(lm, i):
    """Relative standard error of a texel's flux: sqrt(Σp²)/Σp over its photons."""
    nb = lm.flux.shape[1]
    f = 0.0
    for b in range(nb):
        f += lm.flux[i, b]
    f /= nb
    if not f > 0.0:
        return math.inf
    return math.sqrt(lm.flux_sq[i]) / f


@njit(cache=True)
def _lookup_level(lm, lid, nx, ny, nz, mode, out):
    """E of one OL level at normal n: bilinear over measured bins only."""
    s, t = octa_encode(nx, ny, nz)
    if mode == lightmap.MODE_BILINEAR:
        lightmap.lookup_bilinear(lm, lid, typed(0), s, t, out)     # typed: the lightmaps' own signature
    else:
        lightmap.lookup_constant(lm, lid, typed(0), s, t, out)


@njit(cache=True)
def lookup(lm, ol, k, nx, ny, nz, mode, out):
    """Irradiance at world normal n from OL k, moving up the hierarchy while
    the bin is too noisy (thesis 6.2: the lowest level with enough hits)."""
    while True:
        i = bin_index(lm, ol, k, nx, ny, nz)
        p = ol.parent[k]
        if p < 0 or _rel_error(lm, i) <= ol.max_rel_error[k]:
            break
        k = p
    _lookup_level(lm, ol.lid[k], nx, ny, nz, mode, out)


@njit(cache=True, inline="always")
def hit_ol(g, ol, inst, shape, face):
    """Innermost OL a hit records into and reads from: an L-system hit's stub
    (its face is the stub index, engine/geometry/dcsg.py) or the instance's OL (-1: none)."""
    if face >= 0 and ol.inst_stub0[inst] >= 0 and \
            shape >= dcsg_vs0((g.trace_i64, g.trace_f32, g.trace_i32, g.trace_f64, g.trace_features)):
        return ol.inst_stub0[inst] + face
    return ol.inst_ol[inst]


@njit(**CORE)
def surface_irradiance(g, lm, ol, inst, shape, face, u, v, nx, ny, nz, mode, out):
    """Stored irradiance at a hit: the surface's own lightmap, or its OL where
    it has none or (backup OL) where the texel is too noisy. n: the world
    normal as the ray query returns it. False when nothing is stored there."""
    lid, f, s, t = lightmap.lightmap_slot(g, lm, inst, shape, face, u, v)
    k = hit_ol(g, ol, inst, shape, face)
    if lid >= 0 and (k < 0 or _rel_error(lm, lightmap.record_index(lm, lid, f, s, t))
                     <= ol.max_rel_error[k]):
        lightmap.lookup(lm, lid, f, s, t, mode, out)
        return True
    if k < 0:
        return False
    lookup(lm, ol, k, nx, ny, nz, mode, out)
    return True


# --------------------------------------------------------------------------------------
# Setup and reporting
# --------------------------------------------------------------------------------------

def with_lightmap_ids(maps, lids):
    return maps._replace(lid=np.asarray(lids, np.int32).reshape(-1))


# Strong averaging (thesis ch. 8 failure cases): few distinct normals, or a group
# that shades much of itself, so one irradiance per normal hides real variation.
FEW_DIRECTIONS = 8        # bins holding 99 % of the area
LOW_OPENNESS = 0.6        # share of hemisphere rays that leave the group


def averaging_warnings(row, area):
    out = []
    tot = float(area.sum())
    if tot <= 0.0:
        return [f"orientation lightmap '{row['name']}' covers no surface: its objects keep no "
                "stored light"]
    a = np.sort(area)[::-1]
    n99 = int(np.searchsorted(np.cumsum(a), 0.99 * tot) + 1)
    if n99 <= FEW_DIRECTIONS:
        out.append(f"orientation lightmap '{row['name']}': averaging is strong, the surface has "
                   f"only {n99} normal directions (a box has six), so every face direction gets one "
                   "irradiance over the whole group; use per-object lightmaps for shading detail")
    if row["openness"] < LOW_OPENNESS:
        out.append(f"orientation lightmap '{row['name']}': averaging is strong, "
                   f"{1 - row['openness']:.0%} of the rays leaving its surface hit the group itself: "
                   "cavities swallow light (more so when self-similar), yet they get the irradiance "
                   "of open faces with the same normal")
    return out


def report(cs):
    """Per OL: bins, photons received, memory, area estimate and warnings."""
    out = []
    ols = cs.info.get("orientation_lightmaps", [])
    lm = cs.lightmaps
    for k, entry in enumerate(ols):
        lid = int(cs.orientation.lid[k])
        sl = lightmap.texel_slice(lm, lid)
        row = dict(entry)
        row.update(photons=int(lm.hits[sl].sum()),
                   flux=lm.flux[sl].sum(axis=0).tolist(),
                   memory_bytes=int(sum(a[sl].nbytes for a in (lm.area, lm.coverage, lm.open, lm.flux,
                                                                lm.flux_sq, lm.hits, lm.irradiance,
                                                                lm.state, lm.split))))
        out.append(row)
    return out
