"""Two-pass renderer (thesis 8.2): direct light by sampling the lights, indirect
light from the photon lightmaps, glossy, specular and refractive paths traced on.

At every hit the closure (bsdf.py, with textured inputs from materials.py) is split:
its diffuse part takes direct light from shadow rays and everything else from the
lightmap irradiance E, plus the caustic lightmaps' (radiance kd·E/π); its glossy
lobes take direct light too, weighted by multiple importance sampling against the
glossy sample that continues the path, which also sees lights and the world
(light_hits.py). Rendering proceeds tile by tile so a host can show progress and cancel.

With `gather` > 0 the diffuse part's indirect light comes from a final gather
(final_gather.py) instead of the hit's own texel: the lightmaps then hold total
irradiance (the photon pass recorded direct hits), and only the caustic
lightmaps are still read at the hit. Each later diffuse hit along a glossy
continuation gathers with a quarter of the rays of the one before.
"""
import math
import time
from collections import namedtuple

import numpy as np
from numba import njit
from numba.extending import overload

from ..core.jit import CORE, INLINE, typed
from ..lightmaps import lightmap
from ..lightmaps import orientation_lightmap
from ..shading import bsdf
from ..shading import dispersion
from ..shading import fluorescence
from ..shading import light_hits
from ..shading import materials
from ..shading import environment
from ..shading import polarization
from . import final_gather
from . import irradiance_cache
from ..core import parallel
from ..shading.lights import EMISSIVE, light_sample_count, pick_light, sample_light_radiance
from ..core.errors import Cancelled
from .kernel_scene import kernel_scene
from .path_vertex import (leave_surface, new_path_scratch, path_scratch, ray_epsilon, smooth_mueller_terms,
                          surface_closure)
from ..geometry.raycast import STACK_WORDS, intersect_closest, occluded
from ..core.sampling import next_float, stream_state
from .texel_gather import grid_side, jitter, light_stratum, texel_shift

# pol: polarization as a type the render kernel specialises on: a (1, 2) array (the
# filter's angle, 1 with a filter / 0 without) when camera paths trace it, or an
# empty 1-D array when they do not (no polarization code is compiled)
CameraData = namedtuple("CameraData", "xf kind sx sy width height pol")


def compile_camera(camera):
    """Camera basis and image-plane half extents, Blender conventions (looks along -Z, sensor fit auto)."""
    from ..core.scene import SceneError, as_affine
    w, h = int(camera.width), int(camera.height)
    if w <= 0 or h <= 0:
        raise SceneError(f"camera resolution must be positive, got {w}x{h}")
    xf = as_affine(camera.transform, "camera")
    # Remove scale so rays stay unit length.
    lin = xf[:, :3] / np.linalg.norm(xf[:, :3], axis=0)
    xf = np.concatenate([lin, xf[:, 3:]], axis=1)
    aspect = w / h
    if camera.kind == "orthographic":
        half = 0.5 * float(camera.ortho_scale)
        if not (math.isfinite(half) and half > 0.0):
            raise SceneError(f"camera: orthographic scale must be positive, got {camera.ortho_scale}")
        kind = 1
    elif camera.kind == "perspective":
        if not 0 < camera.fov < math.pi:
            raise SceneError(f"camera field of view must be in (0, pi), got {camera.fov}")
        half = math.tan(0.5 * float(camera.fov))
        kind = 0
    else:
        raise SceneError(f"unknown camera kind '{camera.kind}'")
    sx, sy = (half, half / aspect) if w >= h else (half * aspect, half)
    angle = getattr(camera, "polarizer", None)
    if angle is None and not getattr(camera, "polarized", False):
        pol = np.zeros(0)
    elif angle is None:
        pol = np.array([[0.0, 0.0]])
    else:
        if not math.isfinite(float(angle)):
            raise SceneError(f"camera: the polarizing filter's angle must be finite, got {angle}")
        pol = np.array([[float(angle), 1.0]])
    return CameraData(xf, kind, sx, sy, w, h, pol)


def _polarizer_start(pol, w, tp, cam, d):
    """Camera paths that trace polarization: the Stokes row starts as the filter's, or S0."""


def _polarizer_vertex(pol, w, tp, d_cam, d_next, fn, lobes, delta):
    """A camera path that traces polarization meets a glossy interaction: a smooth one
    (glass, a coat, a metal: its Mueller matrix, bsdf.mueller_terms) polarizes, a rough
    one depolarizes."""


@overload(_polarizer_start)
def _polarizer_start_gate(pol, w, tp, cam, d):
    if pol.ndim == 2:
        def start(pol, w, tp, cam, d):
            m = cam.xf
            polarization.start_row(w.pol, tp, pol[0, 0], pol[0, 1] > 0.0, (m[0, 0], m[1, 0], m[2, 0]), d)
        return start
    return lambda pol, w, tp, cam, d: None


@overload(_polarizer_vertex)
def _polarizer_vertex_gate(pol, w, tp, d_cam, d_next, fn, lobes, delta):
    if pol.ndim == 2:
        def vertex(pol, w, tp, d_cam, d_next, fn, lobes, delta):
            nb = tp.shape[0]
            if not delta:
                polarization.depolarize(w.pol, nb)
                return
            smooth_mueller_terms(w, lobes, d_cam, d_next, fn)
            polarization.camera_vertex(w.pol, tp, d_cam, d_next, fn)
        return vertex
    return lambda pol, w, tp, d_cam, d_next, fn, lobes, delta: None


@njit(cache=True)
def camera_ray(cam, fx, fy):
    """Ray through film position (fx, fy) in pixels (y down)."""
    ndc_x = 2.0 * fx / cam.width - 1.0
    ndc_y = 1.0 - 2.0 * fy / cam.height
    x = ndc_x * cam.sx
    y = ndc_y * cam.sy
    m = cam.xf
    if cam.kind == 1:
        ox = m[0, 3] + m[0, 0] * x + m[0, 1] * y
        oy = m[1, 3] + m[1, 0] * x + m[1, 1] * y
        oz = m[2, 3] + m[2, 0] * x + m[2, 1] * y
        return ox, oy, oz, -m[0, 2], -m[1, 2], -m[2, 2]
    dx = m[0, 0] * x + m[0, 1] * y - m[0, 2]
    dy = m[1, 0] * x + m[1, 1] * y - m[1, 2]
    dz = m[2, 0] * x + m[2, 1] * y - m[2, 2]
    ln = math.sqrt(dx * dx + dy * dy + dz * dz)
    return m[0, 3], m[1, 3], m[2, 3], dx / ln, dy / ln, dz / ln


@njit(cache=True, inline="always")
def _pixel_sample(seed, pixel, spp, s, k):
    """Sample s of a pixel -> (its stream, its jitter): the jitter is stratified on
    the k x k grid (k = grid_side(spp)); one sample takes the pixel's centre."""
    state = stream_state(seed, pixel * spp + s)
    state, jx = next_float(state)
    state, jy = next_float(state)
    if spp == 1:
        return state, 0.5, 0.5
    jx, jy = jitter(s, k, jx, jy)
    return state, jx, jy


# Keys a pixel's light-stratum shift apart from its samples' streams.
PIXEL_SHIFT_XOR = np.uint64(0x9E3779B97F4A7C15)


@njit(cache=True)
def direct_light(g, ls, w, lobes, p, fn, sn, wo, state, strata):
    """Direct light at p, sampled as texel_gather.direct_irradiance samples it: the
    diffuse irradiance into w.e and the glossy lobes' radiance towards wo (local,
    in the frame of sn) into w.lg, both added, the glossy part weighted by the
    power heuristic against glossy sampling (light_hits); w.count[0] gains the
    shadow rays. lobes: (pd, ps, pm, pg) of the closure in w. fn is the face
    normal on the viewer's side, sn the (normal-mapped) shading normal: cosines
    are sn's, and a light must lie on the side of fn that the lobe scatters to
    (no light through a normal map's tilt).
    strata = (stratum, k); stratum >= 0: the cell of a k x k grid the light's two
    random numbers are jittered in (texel_gather.light_stratum: a pixel's samples
    cover each light evenly); -1: plain uniform. Takes the geometry and lights,
    not the whole scene: a call copies its arguments, and this one runs per hit."""
    stratum, k = strata
    n_lights = ls.kind.shape[0]
    if n_lights == 0:
        return state
    _, ps, pm, pg = lobes
    pc, ks, kt, e, lg, f, rad = w.closure, w.ks, w.kt, w.e, w.lg, w.f, w.rad
    px, py, pz = p
    fx, fy, fz = fn
    sx, sy, sz = sn
    ox, oy, oz = wo
    nb = e.shape[0]
    glossy = ps + pm + pg > 0.0 and pc[bsdf.P_ALPHA] > bsdf.DELTA_ALPHA
    eps = ray_epsilon(px, py, pz)
    n_samples = light_sample_count(n_lights)
    for j in range(n_samples):
        state, li, w_sel = pick_light(ls, j, n_samples, state)
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        state, u3 = next_float(state)
        if stratum >= 0:
            u1, u2 = jitter(stratum, k, u1, u2)
        wx, wy, wz, dist, scale, ok = sample_light_radiance(ls, g, li, px, py, pz, u1, u2, u3, rad)
        if not ok or scale <= 0.0:
            continue
        cos_g = wx * fx + wy * fy + wz * fz
        cos_r = wx * sx + wy * sy + wz * sz
        if cos_g * cos_r <= 0.0:
            continue
        # a glass lobe also sees lights behind the surface
        if cos_r <= 0.0 and not (glossy and pg > 0.0):
            continue
        gl = 0.0
        if glossy and ls.kind[li] != EMISSIVE:
            ix, iy, iz = bsdf.to_local(wx, wy, wz, sx, sy, sz)
            pdf_b = bsdf.eval_glossy(pc, ks, kt, ps, pm, pg, ox, oy, oz, ix, iy, iz, f)
            pdf_l = light_hits.light_pdf(ls, li, px, py, pz, wx, wy, wz, dist)
            gl = 1.0 if pdf_l == math.inf else light_hits.power_heuristic(light_hits.selection_factor(ls, li) * pdf_l,
                                                                          pdf_b)
        if cos_r <= 0.0 and gl == 0.0:
            continue
        side = eps if cos_r > 0.0 else -eps
        qx, qy, qz = px + side * fx, py + side * fy, pz + side * fz
        tmax = dist * (1.0 - 1e-6) - eps if dist < math.inf else math.inf
        if tmax <= 0.0:
            continue
        w.count[0] += 1
        if occluded(g, w.stack, qx, qy, qz, wx, wy, wz, 0.0, tmax):
            continue
        c = scale * w_sel
        for b in range(nb):
            if cos_r > 0.0:
                e[b] += rad[b] * cos_r * c
            if gl > 0.0:
                lg[b] += rad[b] * f[b] * c * gl
    return state


Tile = namedtuple("Tile", [
    "x0", "y0", "width", "height",   # the tile's pixels in the frame
    "spp", "s0", "s1",               # samples s0 <= s < s1 of the pixel's spp
    "seed", "mode",                  # random streams; lightmap lookup (lightmap.MODE_*)
    "max_depth",                     # glossy vertices a camera path follows
    "indirect",                      # bool: add the stored (or gathered) indirect light
    "gather",                        # final-gather rays at the first diffuse hit (0: the texel's own)
])

# A render tile's scratch: the camera path's and its gathers' (one stack and
# ray counter for both), and the pixel's sum.
RenderScratch = namedtuple("RenderScratch", "camera gather acc")


@njit(cache=True, nogil=True)
def _render_tile(scene, cam, tile, rec, out, rays, start, stop):
    """Pixels start..stop-1 of the tile (parallel.run spreads them over threads):
    the block's scratch, then the core. rays[y, x]: the rays a pixel traced.
    rec: irradiance-cache records (irradiance_cache.Records; none: gather rays
    everywhere) that a diffuse hit reads before it gathers."""
    nb = out.shape[2]
    w = new_path_scratch(nb)
    _render_tile_core(scene, cam, tile, rec, out, rays, start, stop,
                      RenderScratch(w, path_scratch(nb, w.stack, w.count), np.empty(nb)))


@njit(cache=True, inline="always")
def _ray_cone(cam):
    """(width at the camera, growth per metre travelled) of a pixel's ray cone (texture filtering)."""
    pixel = 2.0 * max(cam.sx, cam.sy) / max(cam.width, cam.height)
    return (pixel, 0.0) if cam.kind == 1 else (0.0, pixel)


# The pixel loop compiles without NRT: with it, every read of a field of the
# scene tuples is an atomic incref and decref that the threads contend for.
# Its helpers take the scene's parts they read, and the camera path is written
# out here rather than in a helper: numba copies an inlined helper's IR with all
# that was inlined into it, per call site (docs/kernels.md).
@njit(**CORE)
def _render_tile_core(scene, cam, tile, rec, out, rays, start, stop, work):
    # Samples s0 <= s < s1 of the pixel's spp, each weighted 1/spp: the passes of a
    # progressive render add up to the one-pass image (the same streams).
    g, ms, ls, ts, bt = scene.geometry, scene.materials, scene.lights, scene.textures, scene.bsdf
    w, acc = work.camera, work.acc
    tp = w.tp
    nb = out.shape[2]
    width0, spread = _ray_cone(cam)
    env_li = light_hits.environment_light(ls)
    # A pixel's samples are stratified on a k x k grid, and so are their first
    # hits' light samples (shifted per pixel, texel_gather.light_stratum).
    k = grid_side(tile.spp)
    for idx in range(start, stop):
        for b in range(nb):
            acc[b] = 0.0
        w.count[0] = 0
        px_i = tile.x0 + idx % tile.width
        py_i = tile.y0 + idx // tile.width
        pixel = py_i * cam.width + px_i
        _, shift = texel_shift(stream_state(tile.seed ^ PIXEL_SHIFT_XOR, pixel), k)
        for s in range(tile.s0, tile.s1):
            # a camera path through glossy lobes
            state, jx, jy = _pixel_sample(tile.seed, pixel, tile.spp, s, k)
            ox, oy, oz, dx, dy, dz = camera_ray(cam, px_i + jx, py_i + jy)
            for b in range(nb):
                tp[b] = 1.0 / tile.spp
            _polarizer_start(cam.pol, w, tp, cam, (dx, dy, dz))
            w.wave[dispersion.WAVE_BAND] = -1.0
            pdf_b = 0.0
            delta = True
            travelled = 0.0
            n_gather = tile.gather
            for depth in range(tile.max_depth + 1):
                w.count[0] += 1
                hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
                    g, w.stack, ox, oy, oz, dx, dy, dz, 0.0, math.inf)
                if depth > 0:      # lights are invisible to the camera, as in Cycles
                    light_hits.add_seen_lights(ls, ox, oy, oz, dx, dy, dz, t if hit else math.inf, pdf_b, delta,
                                               tp, acc, w.pol, cam.pol.ndim == 2)
                if not hit:
                    mis = 1.0
                    if not delta and env_li >= 0:
                        mis = light_hits.power_heuristic(pdf_b, light_hits.selection_factor(ls, env_li) *
                                                         light_hits.light_pdf(ls, env_li, ox, oy, oz, dx, dy, dz,
                                                                              math.inf))
                    environment.radiance(scene.environment, dx, dy, dz, w.rad)
                    for b in range(nb):
                        acc[b] += tp[b] * w.rad[b] * mis
                    break
                p = (ox + t * dx, oy + t * dy, oz + t * dz)
                m = g.shape_material[shape]
                for b in range(nb):
                    acc[b] += tp[b] * ms.emission[m, b]
                travelled += t
                surf = (inst, shape, face, u, v)
                if dispersion.splits_bands(ms.dispersion, m, w.wave):
                    state = dispersion.keep_one_band(ms.bands, tp, w.wave, state)
                fn, sn, _, _, lobes = surface_closure(ms, ts, bt, g, w, m, surf, (nx, ny, nz), (dx, dy, dz),
                                                      width0 + spread * travelled)
                wo = bsdf.to_local(-dx, -dy, -dz, sn[0], sn[1], sn[2])
                stratum = light_stratum(s, k, shift) if depth == 0 else -1
                state = _shade(scene, tile, rec, work, (surf, (nx, ny, nz), p), (fn, sn, wo), lobes,
                               (stratum, n_gather), state)
                if tile.gather > 0 and lobes[0] > 0.0:
                    n_gather = max(1, n_gather // 4)
                # Continue along the glossy lobes (the diffuse light came from the lightmaps).
                if depth == tile.max_depth or lobes[1] + lobes[2] + lobes[3] <= 0.0:
                    break
                ok, o, d, pdf_b, delta, state = _scatter_glossy(w, lobes, (fn, sn, wo), (nx, ny, nz), p, state)
                if not ok:
                    break
                _polarizer_vertex(cam.pol, w, tp, (dx, dy, dz), d, fn, lobes, delta)
                ox, oy, oz = o
                dx, dy, dz = d
        for b in range(nb):
            out[idx // tile.width, idx % tile.width, b] = acc[b]
        rays[idx // tile.width, idx % tile.width] = w.count[0]


@njit(**INLINE)
def _shade(scene, tile, rec, work, hit, frame, lobes, strata, state):
    """The light a camera-path vertex sends back along the path, times the
    throughput, added to work.acc: direct light from light samples (diffuse and
    glossy), and the diffuse part's indirect light from the irradiance-cache
    records, a final gather or the hit's own lightmap (or OL), plus its caustic
    lightmap. hit: (instance, shape, face, u, v), outward normal, point; frame:
    (face normal, shading normal, local direction back); strata: (this vertex's
    light stratum or -1, its gather rays)."""
    w, gw, acc = work.camera, work.gather, work.acc
    e, ind = w.e, w.ind
    nb = e.shape[0]
    fn, sn, wo = frame
    stratum, n_gather = strata
    pd, ps, pm, pg = lobes
    (inst, shape, face, u, v), (nx, ny, nz), p = hit
    for b in range(nb):
        e[b] = 0.0
        w.lg[b] = 0.0
    if pd > 0.0 or (ps + pm + pg > 0.0 and w.closure[bsdf.P_ALPHA] > bsdf.DELTA_ALPHA):
        state = direct_light(scene.geometry, scene.lights, w, lobes, p, fn, sn, wo, state,
                             (stratum, grid_side(tile.spp)))
    if pd > 0.0 and tile.indirect and n_gather > 0:
        reached = False
        if rec.pos.shape[0] > 0:
            wsum, _ = irradiance_cache.lookup(rec, p, fn, ind)
            if wsum > 0.0:
                reached = True
                for b in range(nb):
                    e[b] += ind[b]
        if not reached:
            # gather rays go on at the path's wavelength
            gw.wave[dispersion.WAVE_BAND] = w.wave[dispersion.WAVE_BAND]
            gw.wave[dispersion.WAVE_NM] = w.wave[dispersion.WAVE_NM]
            state = final_gather.gather_irradiance(scene, gw, p, fn, sn, n_gather, tile.mode, state, e,
                                                   (typed(0), rec.E, rec.R))
    elif pd > 0.0 and tile.indirect and orientation_lightmap.surface_irradiance(
            scene.geometry, scene.lightmaps, scene.orientation, inst, shape, face, u, v, nx, ny, nz, tile.mode, ind):
        for b in range(nb):
            e[b] += ind[b]
    if pd > 0.0 and tile.indirect and scene.caustics:
        lmc = scene.caustic_maps
        lid, cf, cs_, ct = lightmap.lightmap_slot(scene.geometry, lmc, inst, shape, face, u, v)
        if lid >= 0:
            lightmap.lookup(lmc, lid, cf, cs_, ct, tile.mode, ind)
            for b in range(nb):
                e[b] += ind[b]
    ds = bsdf.diffuse_scale(w.closure)
    m = scene.geometry.shape_material[shape]
    if m >= 0 and scene.materials.fluorescent[m]:
        for b in range(nb):
            acc[b] += w.tp[b] * (fluorescence.reflected(scene.materials, m, w.kd, e, b) * ds / math.pi + w.lg[b])
    else:
        for b in range(nb):
            acc[b] += w.tp[b] * (w.kd[b] * ds * e[b] / math.pi + w.lg[b])
    return state


@njit(**INLINE)
def _scatter_glossy(w, lobes, frame, n, p, state):
    """A glossy, mirror or glass direction from the closure in w, its weight
    multiplied into w.tp -> (ok, origin, direction, pdf, delta, state); ok False
    when the path ends here (no sample, or the shading frame's side and the
    face's disagree)."""
    _, ps, pm, pg = lobes
    fn, sn, wo = frame
    state, u0 = next_float(state)
    state, u1 = next_float(state)
    state, u2 = next_float(state)
    state, u3 = next_float(state)
    ok, ix, iy, iz, pdf_b, delta = bsdf.sample_glossy(w.closure, w.ks, w.kt, ps, pm, pg, wo[0], wo[1], wo[2],
                                                      u0, u1, u2, u3, w.f)
    d = bsdf.from_local(ix, iy, iz, sn[0], sn[1], sn[2])
    if not ok or (d[0] * fn[0] + d[1] * fn[1] + d[2] * fn[2]) * iz <= 0.0:
        return False, p, d, pdf_b, delta, state
    for b in range(w.tp.shape[0]):
        w.tp[b] *= w.f[b]
    return True, leave_surface(p, n, d), d, pdf_b, delta, state


def progressive_passes(samples):
    """Samples per pass of a progressive render: 1, 1, 2, 4, ... (the first image comes
    after one sample per pixel, then each pass doubles what is shown), the last pass what is left."""
    samples, out, done = int(samples), [], 0
    while done < samples:
        n = min(max(done, 1), samples - done)
        if samples - done - n < n / 2:
            n = samples - done           # no tiny last pass
        out.append(n)
        done += n
    return out


def render(cs, samples=4, seed=0, mode=lightmap.MODE_BILINEAR, max_depth=8, tile=64,
           indirect=True, gather=0, progress=None, passes=None, records=None, cluster=None):
    """Renders cs.camera to a (height, width, n_bands) float array of radiance.

    gather: final-gather rays per sample at the first diffuse hit (0: read the
    hit's own lightmap, the thesis's way). It needs lightmaps that hold direct
    light too (trace_photons(record_direct=True)); the lookup needs ones that do not.

    passes: samples per pass (summing to `samples`; None: one pass), e.g.
    progressive_passes(samples). Every pass covers the whole frame, and the image
    after the last equals the one-pass image (up to rounding): pass k adds the
    samples the one-pass render takes from the same random streams.

    progress(x0, y0, tile_image, image) is called after each tile, with both
    scaled to the samples done so far; returning False cancels (raises Cancelled).

    records (irradiance_cache.scene_records; with gather > 0): a diffuse hit that
    records reach reads their interpolated irradiance instead of gathering.

    cluster (engine/cluster.py): its workers render the tiles; every pixel depends
    only on its own random streams, so the image is the same, bit for bit.
    """
    gather = int(gather)
    samples = int(samples)
    passes = [samples] if passes is None else [int(n) for n in passes]
    if sum(passes) != samples or min(passes, default=0) < 1:
        raise ValueError(f"passes {passes} must be positive and add up to {samples} samples")
    holds_direct = getattr(cs, "lightmaps_hold_direct", False)
    # (lightmaps nothing was traced into are right for either: zero)
    if indirect and gather > 0 and not holds_direct and np.any(cs.lightmaps.flux):
        raise ValueError("final gather needs a photon pass that recorded direct light (record_direct=True)")
    cam = cs.camera
    img = np.zeros((cam.height, cam.width, cs.n_bands))
    t0 = time.perf_counter()
    s0 = 0
    rays = 0
    shown = img if len(passes) == 1 else np.zeros_like(img)
    for n in passes:
        scale = samples / (s0 + n)      # sums of 1/spp-weighted samples -> the mean so far

        def on_tile(x0, y0, th, tw):
            if shown is not img:
                shown[y0:y0 + th, x0:x0 + tw] = img[y0:y0 + th, x0:x0 + tw] * scale
            if progress is not None and progress(x0, y0, shown[y0:y0 + th, x0:x0 + tw], shown) is False:
                raise Cancelled("render cancelled")
        rays += add_samples(cs, img, samples, s0, s0 + n, seed=seed, mode=mode, max_depth=max_depth,
                            tile=tile, indirect=indirect, gather=gather, on_tile=on_tile, records=records,
                            cluster=cluster)
        s0 += n
    cs.timings["render"] = time.perf_counter() - t0
    cs.rays["render"] = rays
    return img


def add_samples(cs, img, samples, start, stop, seed=0, mode=lightmap.MODE_BILINEAR, max_depth=8, tile=64,
                indirect=True, gather=0, on_tile=None, records=None, cluster=None):
    """Adds samples start..stop-1 of a `samples`-sample render of cs.camera to `img`
    ((height, width, n_bands), each sample weighted 1/samples): after every sample
    has been added, img is render(cs, samples, seed, ...). A progressive host (the
    Rendered viewport) adds one sample at a time. on_tile(x0, y0, th, tw) after each tile.
    Returns the rays traced (camera, shadow, gather and glossy rays)."""
    cam = cs.camera
    rec = records if records is not None else irradiance_cache.no_records(cs.n_bands)
    tiles = [Tile(x0, y0, min(tile, cam.width - x0), min(tile, cam.height - y0), int(samples), int(start),
                  int(stop), np.uint64(seed), int(mode), int(max_depth), bool(indirect), max(int(gather), 0))
             for y0 in range(0, cam.height, tile) for x0 in range(0, cam.width, tile)]
    if cluster is not None:
        done = cluster.render_tiles(cs, rec, tiles)
    else:
        scene = kernel_scene(cs)
        done = (render_tile(cs, rec, t, scene) for t in tiles)
    traced = 0
    for params, (out, rays) in zip(tiles, done):
        x0, y0, tw, th = params.x0, params.y0, params.width, params.height
        img[y0:y0 + th, x0:x0 + tw] += out
        traced += int(rays)
        if on_tile is not None:
            on_tile(x0, y0, th, tw)
    return traced


def render_tile(cs, rec, params, scene=None):
    """One tile of a render -> (its (height, width, n_bands) samples, rays traced). What a
    cluster's worker runs (scene: cs's kernel scene, when the caller has it)."""
    scene = kernel_scene(cs) if scene is None else scene
    out = np.zeros((params.height, params.width, cs.n_bands))
    rays = np.zeros((params.height, params.width), np.int64)
    parallel.run(_render_tile, params.width * params.height, scene, cs.camera, params, rec, out, rays)
    return out, int(rays.sum())


@njit(cache=True, nogil=True)
def _aux_tile(scene, cam, tile, albedo, normal, start, stop):
    """First-hit albedo and shading normal of pixels start..stop-1 of the tile,
    averaged over the render's own anti-aliasing jitter (same stream as
    _render_tile), for the denoiser."""
    g, ms, ts = scene.geometry, scene.materials, scene.textures
    nb = ms.emission.shape[1]
    spp = tile.spp
    width0, spread = _ray_cone(cam)
    for idx in range(start, stop):
        stack = np.empty(STACK_WORDS, np.int32)
        kd = np.empty(nb)
        ks = np.empty(nb)
        kt = np.empty(nb)
        iy, ix = idx // tile.width, idx % tile.width
        px_i = tile.x0 + ix
        py_i = tile.y0 + iy
        pixel = py_i * cam.width + px_i
        k = grid_side(spp)
        for s in range(spp):
            _, jx, jy = _pixel_sample(tile.seed, pixel, spp, s, k)
            ox, oy, oz, dx, dy, dz = camera_ray(cam, px_i + jx, py_i + jy)
            hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
                g, stack, ox, oy, oz, dx, dy, dz, 0.0, math.inf)
            if not hit:
                continue        # the world: albedo 0, normal 0 (OIDN's convention for "nothing")
            m = g.shape_material[shape]
            if m < 0:
                continue
            materials.surface_inputs(ms, ts, g, inst, m, shape, face, u, v, width0 + spread * t, kd, ks, kt)
            sx, sy, sz = materials.shading_normal(ms, ts, g, inst, m, shape, face, u, v, width0 + spread * t,
                                                  nx, ny, nz)
            if dx * nx + dy * ny + dz * nz > 0.0:     # the side facing the camera, as the render shades it
                sx, sy, sz = -sx, -sy, -sz
            for c in range(3):
                b = c if nb >= 3 else 0
                # all lobes together: glass and mirrors are not black to the denoiser
                albedo[iy, ix, c] += min(kd[b] + ks[b] + kt[b], 1.0) / spp
            normal[iy, ix, 0] += sx / spp
            normal[iy, ix, 1] += sy / spp
            normal[iy, ix, 2] += sz / spp


def render_aux(cs, samples=4, seed=0, tile=64):
    """(albedo, normal), each (height, width, 3) float32, of cs.camera's first hits."""
    cam = cs.camera
    scene = kernel_scene(cs)
    albedo = np.zeros((cam.height, cam.width, 3))
    normal = np.zeros((cam.height, cam.width, 3))
    for y0 in range(0, cam.height, tile):
        for x0 in range(0, cam.width, tile):
            tw, th = min(tile, cam.width - x0), min(tile, cam.height - y0)
            a = np.zeros((th, tw, 3))
            n = np.zeros((th, tw, 3))
            params = Tile(x0, y0, tw, th, int(samples), 0, int(samples), np.uint64(seed), 0, 0, False, 0)
            parallel.run(_aux_tile, tw * th, scene, cam, params, a, n)
            albedo[y0:y0 + th, x0:x0 + tw] = a
            normal[y0:y0 + th, x0:x0 + tw] = n
    return albedo.astype(np.float32), normal.astype(np.float32)
