"""The one pipeline every entry point runs: compile -> photon pass -> direct gather -> render | bake.

The render engine, the lightmap bake, the orientation-lightmap bake and the OL
suggestion all go through here, so a change of order or of a default (which
pass records direct light, how many light samples a texel gets) is made once.
No bpy: the Blender layer reads its PropertyGroup into a `Settings` and hands
over a plain engine Scene.
"""
import contextlib
import time
from dataclasses import dataclass, fields, replace

from .lightmaps import lightmap
from . import spectral
from .core.errors import Cancelled

# Light-sampled points per texel for the direct part of a bake; one unstratified
# light sample per point, so this sets the direct term's noise (~1/sqrt(n)).
DIRECT_SAMPLES = 64


@dataclass
class Settings:
    """The scene's Photon Lightmaps settings; the defaults are the PropertyGroup's (ui/properties.py)."""
    photons: int = 1_000_000
    max_bounces: int = 8
    seed: int = 0
    texel_density: float = 16.0
    caustic_resolution: float = 4.0
    unwrap_limit: int = 20_000      # renders: larger meshes without lightmap UVs get an automatic OL
    samples: int = 16
    reconstruction: str = "BILINEAR"
    indirect: str = "GATHER"        # renders and bakes: "GATHER" (final gather) or "LOOKUP" (the thesis's)
    gather_rays: int = 8            # final-gather rays per camera sample
    bake_gather_rays: int = 256     # final-gather rays per baked texel and lit side
    # light samples per baked texel for its direct light (stratified points, one light
    # sample each); its noise falls about as one over the square root
    bake_direct_samples: int = DIRECT_SAMPLES
    # Photons a gathered bake traces. Its gather rays average the photon lightmaps'
    # noise, so its error stops falling at a few hundred thousand photons (a lookup
    # bake, which reads each texel's own photons, traces `photons`).
    bake_photons: int = 300_000
    bake_target_error: float = 0.0  # > 0: texels above this relative error get more gather rays
    bake_max_rays: int = 4096       # the most gather rays per texel and lit side, adaptive included
    bake_time: float = 0.0          # > 0: seconds a bake should take; the gather spends what is left
    # final gather through a sparse irradiance cache (engine/transport/irradiance_cache.py): a bake's
    # mesh texels read interpolated records (about 4x the per-texel gather's speed against
    # Cycles at equal error, benchmarks/README.md); a render's diffuse hits too, where it is
    # off by default: its error stops near a texel's scale, above the per-pixel gather's
    bake_irradiance_cache: bool = True
    # a gathered bake's rays sample point, spot and sun lights where they land, whose
    # first hits then stay out of the lightmaps: a sun patch one bounce away is as
    # sharp as the sun, not as coarse as the texels it falls on
    bake_gather_lights: bool = True
    irradiance_cache: bool = False
    # keep a bake's photon pass in memory: baking other objects of the unchanged
    # scene reuses it (engine/light_reuse.py BakeLight), at the cost of a copy of its lightmaps
    bake_keep_light: bool = True
    denoise: bool = False           # OIDN pass over renders and baked lightmaps (engine/transport/denoise.py)
    # trace 16 wavelength bands instead of RGB (engine/spectral.py); results come back as Rec.709
    spectral: bool = False
    # camera paths trace polarization through smooth glass and coats even without the
    # camera's polarizing filter (engine/shading/polarization.py)
    polarization: bool = False
    # photon passes on a Dask cluster (engine/cluster.py): a scheduler's address
    # ("tcp://host:8786"), "local:N" for N worker processes here, "" for none
    cluster: str = ""

    @classmethod
    def read(cls, props, **overrides):
        """From anything with these attributes (Scene.photon_lightmaps; None: the defaults).

        overrides: values that replace the stored ones unless they are None
        (a CLI flag or operator option left unset)."""
        kw = {}
        for f in fields(cls):
            value = overrides.get(f.name)
            if value is None and props is not None:
                value = getattr(props, f.name, None)
            if value is not None:
                kw[f.name] = type(f.default)(value)
        return cls(**kw)

    @property
    def gathers(self):
        """Renders use the final gather."""
        return self.indirect == "GATHER" and self.gather_rays > 0

    @property
    def bake_gathers(self):
        """Bakes use the final gather (engine/transport/bake_gather.py)."""
        return self.indirect == "GATHER" and self.bake_gather_rays > 0

    @property
    def bake_photon_count(self):
        """Photons a bake traces: bake_photons when it gathers, else photons."""
        return self.bake_photons if self.bake_gathers else self.photons

    @property
    def bake_rays_per_point(self):
        """Gather rays per texel point: bake_gather_rays spread over the DIRECT_SAMPLES points."""
        return max(1, round(self.bake_gather_rays / DIRECT_SAMPLES))

    @property
    def mode(self):
        """Lightmap reconstruction mode of the renderer."""
        return lightmap.MODE_CONSTANT if self.reconstruction == "CONSTANT" else lightmap.MODE_BILINEAR


def compile(scene, ahead=(), unwrap_progress=None, should_stop=None):
    """Plain engine Scene -> compiled scene (flat arrays, BVHs, empty lightmaps).

    ahead: the passes that will follow the photon pass ("render", "bake"); on a
    first run a helper process compiles their kernels meanwhile (engine/warmup.py).
    unwrap_progress(done, total), should_stop(): the xatlas unwraps of meshes
    without lightmap UVs (compile.unwrap_meshes)."""
    from .compile import compile_scene
    if ahead:
        from . import warmup
        warmup.ahead(scene, ahead)
    return compile_scene(scene, unwrap_progress=unwrap_progress, should_stop=should_stop)


def _kernels_for(cs, pass_, poll=None):
    """Before `pass_` runs: waits for its kernels if a helper is compiling them (engine/warmup.py)."""
    from .core import features
    from . import warmup
    warmup.join(features.mask_of(cs.geometry.trace_features), pass_, poll)


def _kernels_done(cs, pass_):
    from .core import features
    from . import warmup
    warmup.done(features.mask_of(cs.geometry.trace_features), pass_)


def photon_pass(cs, settings, *, record_direct=False, progress=None, photons=None, caustics=False,
                gather=False, aim=None, gather_lights=False):
    """Traces the photons into cs.lightmaps -> PhotonStats. Raises Cancelled.

    record_direct=False keeps first hits out (the direct part is gathered per
    texel instead, see gather_direct); orientation-lightmap bakes record them.
    caustics=True (renders): caustic photons go to the finer cs.caustics.
    gather=True: final-gather rays read the lightmaps, so they keep one bounce
    less (trace_photons). aim: the sphere photons are aimed at (photon_aim.py).
    gather_lights=True: gather rays sample the point, spot and sun lights where
    they land, and those lights' first hits stay out of the lightmaps.
    The texels' open areas are estimated first, once per compiled scene
    (open_area.py): finalize() divides by them.
    """
    from .transport import open_area
    from .transport.photon_tracer import trace_photons
    open_area.estimate(cs, seed=int(settings.seed))
    n = settings.photons if photons is None else photons
    with _on_cluster(cs, settings, "photon_pass") as cluster:
        return trace_photons(cs, int(n), seed=int(settings.seed), max_bounces=int(settings.max_bounces),
                             record_direct=record_direct, progress=progress, caustics=caustics, gather=gather,
                             aim=aim, gather_lights=gather_lights, cluster=cluster)


@contextlib.contextmanager
def _on_cluster(cs, settings, phase):
    """The Dask cluster of settings.cluster (engine/cluster.py), or None; the tasks the
    phase gave it are counted in cs.info["cluster"] (a pass too small to be worth
    sending runs here, and counts none)."""
    if not settings.cluster:
        yield None
        return
    from .cluster import open_cluster
    cluster = open_cluster(settings.cluster)
    before = cluster.tasks
    try:
        yield cluster
    finally:
        info = cs.info.setdefault("cluster", {"address": settings.cluster, "workers": cluster.workers, "tasks": {}})
        info["tasks"][phase] = info["tasks"].get(phase, 0) + cluster.tasks - before


def render_photon_pass(cs, settings, *, progress=None):
    """The photon pass a render needs: caustics apart, and direct hits recorded
    when the render gathers (the gather reads total irradiance one bounce away)."""
    return photon_pass(cs, settings, record_direct=settings.gathers, progress=progress, caustics=True,
                       gather=settings.gathers)


def compile_and_trace(scene, settings, *, record_direct=False, progress=None, aim_at=None):
    """compile + photon_pass -> (compiled scene, PhotonStats); aim_at: see
    compile_and_trace_bake."""
    cs = compile(scene)
    return cs, photon_pass(cs, settings, record_direct=record_direct, progress=progress,
                           aim=_aim(cs, aim_at))


def _aim(cs, instances):
    from .shading import photon_aim
    return None if instances is None else photon_aim.sphere_around(cs.geometry, instances)


def compile_and_trace_bake(scene, settings, *, progress=None, aim_at=None, kept=None, cache_dir=""):
    """compile + the photon pass a bake needs -> (compiled scene, PhotonStats).

    A lookup bake keeps first hits out (its direct part is gathered per texel);
    a gathering bake records them, since gather rays read total irradiance one
    bounce away, and keeps caustics apart (gather rays cannot find them). Its
    caustic lightmaps need no finer texels than the bake's own: they are
    averaged over each baked texel.

    aim_at: the instance ids baked; photons are aimed at the space around them
    (importance emission, photon_aim.py). None aims at the whole scene.

    kept: a light_reuse.BakeLight. A pass it holds that serves this bake (the
    same scene and photon settings, every baked object recorded, photons aimed
    around them) is reused instead of traced; with cache_dir, so is one saved
    there. The pass this bake ends up with is kept (and saved to cache_dir).
    cs.info["light_reuse"] says what was reused, or why nothing was."""
    if kept is None or int(settings.photons) <= 0:
        cs = _bake_compile(scene, settings)
        return cs, _bake_trace(cs, settings, progress, aim_at)
    from . import light_reuse
    key, needs = light_reuse.bake_key(scene, settings), light_reuse.recording(scene)
    found, why = kept.take(key, needs, aim_at)
    source = "memory"
    if found is None and cache_dir:
        found, why_disk = _saved_pass(scene, settings, key, needs, aim_at, cache_dir)
        source, why = "disk", why_disk or why
        kept.kept = found                   # a loaded pass is kept as a traced one would be
    if found is not None:
        # a pass from memory is copied; one just loaded is this bake's own scene already
        cs = found.fresh_scene() if source == "memory" else found.cs
        cs.info["light_reuse"] = {"reused": source, "key": key[:16], "kept_bytes": found.nbytes(),
                                  "photons": int(found.stats.photons)}
        return cs, found.stats
    kept.clear()                # the old pass goes before this one is traced: never two in memory
    cs = _bake_compile(scene, settings)
    stats = _bake_trace(cs, settings, progress, aim_at)
    new = kept.keep(key, needs, light_reuse.aim_sphere(cs, aim_at), cs, stats)
    info = {"reused": None, "why_not": why, "key": key[:16], "kept_bytes": new.nbytes()}
    if cache_dir:
        info["saved"] = light_reuse.save_pass(cache_dir, new)
    cs.info["light_reuse"] = info
    return cs, stats


def _saved_pass(scene, settings, key, needs, aim_at, cache_dir):
    """A pass saved in cache_dir for this bake, loaded into a compiled scene
    -> (KeptPass or None, why not)."""
    from . import light_reuse
    from .transport.photon_tracer import PhotonStats
    recorded = light_reuse.saved_recording(cache_dir, key)
    if recorded is None:
        return None, ""
    if not light_reuse.covers(recorded, needs):
        return None, "the saved pass did not record every object baked now"
    # compiled as the saved pass was, so that its lightmaps fit
    scene = replace(scene, instances=[replace(i, lightmap=bool(r)) for i, r in zip(scene.instances, recorded)])
    cs = _bake_compile(scene, settings)
    cs.__dict__["_open_area_done"] = True          # the saved lightmaps hold the open areas
    _bake_trace(cs, replace(settings, photons=0), None, None)   # the pass's light set, no photons
    return light_reuse.load_pass(cache_dir, key, cs, light_reuse.aim_sphere(cs, aim_at), PhotonStats)


def _bake_compile(scene, settings):
    if not settings.bake_gathers:
        return compile(scene)
    return compile(replace(scene, caustic_resolution=1.0), ahead=("bake",))


def _bake_trace(cs, settings, progress, aim_at):
    if not settings.bake_gathers:
        return photon_pass(cs, settings, progress=progress, aim=_aim(cs, aim_at))
    return photon_pass(cs, settings, record_direct=True, progress=progress, caustics=True, gather=True,
                       aim=_aim(cs, aim_at), gather_lights=settings.bake_gather_lights)


def bake_texels(cs, lightmap_ids, csg_leaves, settings, *, direct=True, deadline=None, phase=None,
                should_stop=None, directional=False):
    """A bake's texel values into cs.lightmaps -> seconds per part.

    Direct light per texel (unless direct=False), plus either the photons' own
    indirect light (lookup) or the final gather over the photon lightmaps
    (engine/transport/bake_gather.py). lightmap_ids: instance lightmaps; csg_leaves:
    (instance, leaf) pairs of CSG solids (csg_bake.solid_leaves). deadline: the
    time.perf_counter() by which the bake should end (settings.bake_time); the
    gather gives the time left to the texels with the highest error.
    phase(name, n) is told as "direct" and "gather" start (n: texels), and
    while it waits on a helper compiling the bake kernels ("kernels", seconds).
    On a cluster (settings.cluster) the gathers' kernel calls are its tasks
    (Cluster.kernels), with the same result. should_stop() -> True cancels
    (Cancelled) between the parts, and on a cluster between its tasks.
    directional: the moments of the lightmaps' texels go to cs.bake_moments =
    (texel ids, moments (K, 3 per band + the normal's 3), E (K, bands) of the
    light they cover), for a directional bake (transport/directional_lightmap.py):
    the direct light's and the gather's (the photons' own light, in a bake
    without the gather, has no direction)."""
    with _on_cluster(cs, settings, "bake") as cluster:
        with cluster.kernels(should_stop) if cluster is not None else contextlib.nullcontext():
            return _bake_texels(cs, lightmap_ids, csg_leaves, settings, direct, deadline, phase,
                                should_stop or (lambda: False), directional)


def _bake_texels(cs, lightmap_ids, csg_leaves, settings, direct, deadline, phase, should_stop, directional=False):
    from .transport import texel_gather
    lightmap_ids, csg_leaves = list(lightmap_ids), list(csg_leaves)
    phase = phase or (lambda name, texels: None)
    lm = cs.lightmaps
    texels = sum(int(lm.width[i]) * int(lm.height[i]) for i in set(lightmap_ids))
    seconds = {}
    _kernels_for(cs, "bake", lambda waited: phase("kernels", waited))
    t0 = time.perf_counter()
    parts = []
    if direct:
        phase("direct", texels)
    cs.bake_moments = None
    nb = cs.n_bands
    if direct and lightmap_ids:
        ids, E = gather_direct(cs, lightmap_ids, settings, moments=directional)
        if directional:
            cs.bake_moments = (ids, E[:, nb:], E[:, :nb].copy())
            E = E[:, :nb]
        parts.append((ids, E))
    if direct and csg_leaves:
        ids, E = gather_direct_csg(cs, csg_leaves, settings, moments=directional)
        if directional:
            cs.bake_moments = _summed_moments(cs.bake_moments, (ids, E[:, nb:], E[:, :nb].copy()), nb)
            E = E[:, :nb]
        parts.append((ids, E))
    seconds["direct"] = time.perf_counter() - t0
    if should_stop():
        raise Cancelled("bake cancelled")
    if not settings.bake_gathers:
        for part in parts:
            add_direct(cs.lightmaps, part)
        return seconds
    from .transport import bake_gather
    phase("gather", texels)
    t1 = time.perf_counter()
    direct_E = texel_gather.by_texel(parts, cs.n_bands)
    cache_info = {}
    indirect = bake_gather.gathered_indirect(cs, lightmap_ids, csg_leaves, DIRECT_SAMPLES, settings.bake_rays_per_point,
                                    settings.mode, seed=int(settings.seed),
                                    target_error=float(settings.bake_target_error),
                                    max_rays=max(1, int(settings.bake_max_rays) // DIRECT_SAMPLES),
                                    direct=direct_E,
                                    time_budget=None if deadline is None else deadline - time.perf_counter(),
                                    cached=bool(settings.bake_irradiance_cache), info=cache_info,
                                    moments=directional)
    if directional:
        cs.bake_moments = _summed_moments(cs.bake_moments, (indirect.ids, indirect.moments, indirect.E), nb)
    if cache_info:
        cs.info["irradiance_cache"] = cache_info
    bake_gather.set_gathered(cs.lightmaps, direct_E, indirect)
    cs.bake_error = texel_error(cs.lightmaps, direct_E, indirect)
    seconds["gather"] = time.perf_counter() - t1
    _kernels_done(cs, "bake")
    return seconds


def _summed_moments(a, b, nb):
    """Two parts' (ids, moments, E) over the union of their texel rows (either may be None)."""
    import numpy as np
    parts = [p for p in (a, b) if p is not None and p[1] is not None]
    if not parts:
        return None
    ids = np.union1d(*[np.asarray(p[0], np.int64) for p in parts]) if len(parts) > 1 else np.asarray(parts[0][0])
    mom = np.zeros((ids.size, parts[0][1].shape[1]))
    E = np.zeros((ids.size, nb))
    for p_ids, p_mom, p_E in parts:
        at = np.searchsorted(ids, p_ids)
        mom[at] += p_mom
        E[at] += p_E
    return ids, mom, E


def bake_ao(cs, lightmap_ids, settings, distance, *, rays=16, should_stop=None, csg_leaves=()):
    """The ambient-occlusion pass of a bake into cs.lightmaps (E = π·AO, so the
    bake's E/π is AO; engine/transport/ambient_occlusion.py) -> seconds.
    csg_leaves: (instance, leaf) pairs of CSG solids (csg_bake.solid_leaves)."""
    from .transport import ambient_occlusion
    t0 = time.perf_counter()
    with _on_cluster(cs, settings, "bake") as cluster:
        with cluster.kernels(should_stop) if cluster is not None else contextlib.nullcontext():
            ambient_occlusion.bake_ao(cs, lightmap_ids, distance, rays=int(rays), seed=int(settings.seed),
                                      csg_leaves=list(csg_leaves))
    return {"ao": time.perf_counter() - t0}


def bake_shadowmask(cs, lightmap_ids, settings, lights, *, samples=16, should_stop=None, csg_leaves=()):
    """Shadowmask of the compiled lights `lights` (rows of cs.lights, up to four):
    every lightmap row's visibility per light, dilated (engine/transport/shadowmask.py)
    -> (float64 (rows, 4), seconds). csg_leaves: (instance, leaf) pairs of CSG solids."""
    from .transport import shadowmask
    t0 = time.perf_counter()
    with _on_cluster(cs, settings, "bake") as cluster:
        with cluster.kernels(should_stop) if cluster is not None else contextlib.nullcontext():
            ids, V = shadowmask.texel_visibility(cs, lightmap_ids, lights, samples=int(samples),
                                                 seed=int(settings.seed), csg_leaves=list(csg_leaves))
    channels = shadowmask.mask_channels(cs, ids, V)
    return channels, {"shadowmask": time.perf_counter() - t0}


def texel_error(lm, direct, indirect):
    """Per baked texel row: (ids, relative standard error of E, gather rays per texel)."""
    import numpy as np
    ids = np.asarray(indirect.ids, np.int64)
    E = lm.flux[ids].mean(axis=1) / np.maximum(lm.area[ids], 1e-300)
    rel = np.where(E > 0.0, indirect.se / np.maximum(E, 1e-300), 0.0)
    return ids, rel, indirect.rays * DIRECT_SAMPLES


def gather_direct(cs, lightmap_ids, settings, moments=False):
    """Direct irradiance per texel of the given lightmaps -> (texel ids, E); add with add_direct.
    moments: E's rows end with the direct light's moments (texel_gather.MOMENTS)."""
    from .transport import texel_gather
    return texel_gather.direct_texel_irradiance(cs, lightmap_ids, int(settings.bake_direct_samples),
                                                seed=int(settings.seed), moments=moments)


def gather_direct_csg(cs, leaves, settings, moments=False):
    """Direct irradiance of CSG leaf texels over their visible part -> (texel ids, E)
    (moments: as gather_direct's)."""
    from .transport import csg_bake
    return csg_bake.direct_csg_texels(cs, leaves, int(settings.bake_direct_samples), seed=int(settings.seed),
                                      moments=moments)


def add_direct(lightmaps, gathered):
    """Adds a gather_direct result to `lightmaps` (cs.lightmaps or a copy) and re-finalizes them."""
    from .transport import texel_gather
    texel_gather.add_direct(lightmaps, *gathered)


def render(cs, settings, *, tile=64, progress=None, passes=None, waiting=None):
    """The render pass over a traced compiled scene -> (H, W, n_bands) radiance,
    in Rec.709 (H, W, 3) when the scene is spectral (its tiles too, as progress sees them).

    passes: samples per progressive pass (renderer.render; None: one pass).
    waiting(seconds): called while the render waits for a helper process
    compiling its kernels (session.compile's ahead); False stops the wait."""
    from .transport.renderer import render as render_image
    _kernels_for(cs, "render", waiting)
    gather = int(settings.gather_rays) if settings.gathers else 0
    if settings.denoise:
        from .transport import denoise
        denoise.require()
    cs.timings.pop("records", None)
    records = render_records(cs, settings) if gather and settings.irradiance_cache else None
    if cs.spectral is not None and progress is not None:
        shown = progress

        def progress(x0, y0, tile_image, image):
            return shown(x0, y0, spectral.to_rgb(cs, tile_image), image)
    with _on_cluster(cs, settings, "render") as cluster:
        img = render_image(cs, samples=int(settings.samples), seed=int(settings.seed), mode=settings.mode,
                           max_depth=int(settings.max_bounces), tile=tile, gather=gather, progress=progress,
                           passes=passes, records=records, cluster=cluster)
    _kernels_done(cs, "render")
    img = spectral.to_rgb(cs, img)
    if settings.denoise:
        t0 = time.perf_counter()
        img = denoise_render(cs, img, settings)
        cs.timings["denoise"] = time.perf_counter() - t0
    return img


def render_records(cs, settings):
    """The irradiance-cache records a gathering render reads (engine/transport/irradiance_cache.py),
    made once per traced light and kept on cs: every frame of a camera animation
    that reuses the light reads the same records. Timed in cs.timings["records"]
    (0 when they were kept)."""
    from .transport.irradiance_cache import scene_records
    key = (int(settings.seed), int(settings.bake_gather_rays))
    kept = cs.render_records
    if kept is not None and kept[0] == key:
        cs.timings["records"] = 0.0
        return kept[1]
    t0 = time.perf_counter()
    records, info = scene_records(cs, settings.bake_gather_rays, seed=int(settings.seed))
    cs.render_records = (key, records, info)
    cs.timings["records"] = time.perf_counter() - t0
    return records


def denoise_render(cs, img, settings):
    """A rendered (H, W, n_bands) image -> its OIDN-denoised copy, guided by the
    first hits' albedo and normal (traced here with the render's own pixel jitter)."""
    import numpy as np

    from .transport import denoise
    from .transport.renderer import render_aux
    albedo, normal = render_aux(cs, samples=int(settings.samples), seed=int(settings.seed))
    if cs.spectral is not None:
        albedo = albedo @ cs.spectral.reflectance_matrix      # a reflectance's colour under white light
    nb = img.shape[2]
    if nb == 3:
        return denoise.denoise_image(img, albedo, normal).astype(img.dtype)
    # Other band counts: each band as a grey image, with a grey albedo to match.
    grey = np.repeat(albedo.mean(axis=2, keepdims=True), 3, axis=2)
    out = np.empty_like(img)
    for b in range(nb):
        out[..., b] = denoise.denoise_image(np.repeat(img[..., b:b + 1], 3, axis=2), grey, normal)[..., 0]
    return out


def denoise_baked(rgba, tiles=1):
    """A baked (H, W, 4) RGBA lightmap (A = coverage) -> the same with RGB denoised;
    texels no UV triangle covers keep their values (engine/denoise.denoise_lightmap)."""
    from .transport import denoise
    out = rgba.copy()
    out[..., :3] = denoise.denoise_lightmap(rgba[..., :3], covered=rgba[..., 3] > 0.0, tiles=tiles)
    return out
