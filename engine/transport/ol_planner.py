"""Where orientation lightmaps pay off: a pilot photon pass predicts, per group
of instances, how many photons each per-object lightmap texel would get at
the full photon budget and what the lightmaps cost, against one OL instead.

A group of many small objects spreads the photons that reach it over many
texels: at a fixed budget its texels stay noisy (thesis 6.1), and its
lightmaps cost memory in proportion to the texel count, not to the detail the
illumination has. One OL of R×R bins collects the same photons in far fewer
bins. A group is proposed when its expected photons per texel fall below
`min_photons_per_texel`, or its lightmaps cost more than `max_bytes`, and the
OL is smaller than what it replaces; the saving is reported so that a scene
stores no more illumination detail than it needs.

Photons per texel alone cannot tell a cluster of pebbles from a big wall (at
one texel density both get the same photons per texel), but an OL of a wall
would give the whole wall one irradiance. So a group must also face many
directions: its surface area, estimated per normal bin exactly as the OL
would (area_estimation.py), must spread over more than FEW_DIRECTIONS bins
(99 % of the area), the criterion of the OL's own strong-averaging warning.

The pilot pass runs on a copy of the lightmaps (the caller's compiled scene
is left as it was) with far fewer photons than the budget; hit counts scale
linearly with the photon count, so the expected count per texel at the budget
is pilot hits × budget / pilot photons.
"""
from dataclasses import dataclass, replace

import numpy as np

from ..lightmaps import lightmap
from ..lightmaps.area_estimation import estimate_areas
from ..lightmaps.orientation_lightmap import FEW_DIRECTIONS
from .photon_tracer import trace_photons

PILOT_PHOTONS = 30_000
MIN_PHOTONS_PER_TEXEL = 4.0
MAX_BYTES = 4 << 20
OL_RESOLUTION = 16
AREA_SAMPLES = 4000


@dataclass
class Proposal:
    group: str
    instances: int
    texels: int                    # per-object lightmap texels with surface area
    lightmap_bytes: int            # what those lightmaps cost
    ol_bytes: int                  # one OL of resolution² bins instead
    pilot_hits: int
    expected_hits: float           # at the full budget, over the group
    photons_per_texel: float       # expected, per-object lightmaps
    photons_per_bin: float         # expected, per OL bin with surface
    directions: int                # normal bins holding 99 % of the group's area
    openness: float                # share of hemisphere rays leaving the group
    proposed: bool
    reason: str

    @property
    def saving_bytes(self):
        return self.lightmap_bytes - self.ol_bytes

    def as_dict(self):
        d = dict(self.__dict__)
        d["saving_bytes"] = self.saving_bytes
        return d


def bytes_per_texel(lm):
    """Memory of one texel in the flat lightmap arrays (areas, flux, hits, irradiance, ...)."""
    n = max(lightmap.n_texels(lm), 1)
    return sum(a.nbytes for a in (lm.area, lm.coverage, lm.open, lm.flux, lm.flux_sq, lm.hits,
                                  lm.irradiance, lm.state, lm.split)) / n


def _copy(cs):
    lm = lightmap.Lightmaps(*(a.copy() for a in cs.lightmaps))
    out = replace(cs, lightmaps=lm, info=dict(cs.info), timings=dict(cs.timings))
    out.reset_lightmaps()
    return out


def pilot_hits(cs, pilot_photons=PILOT_PHOTONS, seed=0, max_bounces=8):
    """Photon hits per texel of a pilot pass on a copy of cs (direct hits included,
    since a bake records them too) -> (hits int64[N], photons traced)."""
    work = _copy(cs)
    stats = trace_photons(work, int(pilot_photons), seed=seed, max_bounces=max_bounces, record_direct=True)
    return work.lightmaps.hits.copy(), stats.photons


def plan(cs, budget, groups, *, pilot_photons=PILOT_PHOTONS, seed=0, max_bounces=8,
         min_photons_per_texel=MIN_PHOTONS_PER_TEXEL, max_bytes=MAX_BYTES, resolution=OL_RESOLUTION,
         hits=None, area_samples=AREA_SAMPLES):
    """Proposals for `groups` ({name: instance ids}) at a budget of `budget` photons.

    cs: a compiled scene whose candidate instances have their own lightmaps
    (compile it without OLs). hits: a pilot_hits() result to reuse. Returns a
    list of Proposal, best saving first."""
    if int(budget) <= 0:
        raise ValueError(f"the photon budget must be positive, got {budget}")
    if not 2 <= int(resolution) <= 512:
        raise ValueError(f"OL resolution must be in [2, 512], got {resolution}")
    lm = cs.lightmaps
    if hits is None:
        hits, traced = pilot_hits(cs, pilot_photons, seed, max_bounces)
    else:
        hits, traced = hits
    scale = float(budget) / max(int(traced), 1)
    bpt = bytes_per_texel(lm)
    ol_bytes = int(round(bpt * int(resolution) ** 2))
    out = []
    for name, ids in groups.items():
        lids = sorted({int(l) for i in ids for l in cs.instance_lightmaps[int(i)]})
        if not lids:
            continue
        sl = [lightmap.texel_slice(lm, l) for l in lids]
        n_all = sum(s.stop - s.start for s in sl)
        texels = int(sum(int(np.count_nonzero(lm.area[s] > 0.0)) for s in sl))
        h = int(sum(int(hits[s].sum()) for s in sl))
        expected = h * scale
        per_texel = expected / max(texels, 1)
        est = estimate_areas(cs.geometry, np.asarray(ids, np.int64), int(resolution), int(area_samples),
                             seed, openness_samples=256)
        a = np.sort(est.area)[::-1]
        tot = float(a.sum())
        directions = int(np.searchsorted(np.cumsum(a), 0.99 * tot) + 1) if tot > 0 else 0
        per_bin = expected / max(int(np.count_nonzero(est.area > 0)), 1)
        lm_bytes = int(round(bpt * n_all))
        if lm_bytes <= ol_bytes:
            proposed, reason = False, "its lightmaps are already smaller than an orientation lightmap"
        elif directions <= FEW_DIRECTIONS:
            proposed, reason = False, (f"its surface faces only {directions} normal directions: an OL "
                                       "would give it one irradiance per direction (keep its lightmaps)")
        elif per_texel < float(min_photons_per_texel):
            proposed, reason = True, (f"{per_texel:.2g} photons per texel expected (< "
                                      f"{min_photons_per_texel:g}); an OL bin gets {per_bin:.3g}")
        elif lm_bytes > int(max_bytes):
            proposed, reason = True, (f"its lightmaps cost {lm_bytes / 2**20:.2f} MiB (> "
                                      f"{int(max_bytes) / 2**20:.2f} MiB)")
        else:
            proposed, reason = False, f"{per_texel:.3g} photons per texel expected: its own lightmaps are fine"
        out.append(Proposal(name, len(ids), texels, lm_bytes, ol_bytes, h, expected, per_texel, per_bin,
                            directions, float(est.openness), proposed, reason))
    out.sort(key=lambda p: (not p.proposed, -p.saving_bytes, p.group))
    return out
