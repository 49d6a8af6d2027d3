"""Two-pass renderer (thesis 8.2): direct light by sampling the lights, indirect
light from the photon lightmaps, specular and refraction by recursive tracing.

Camera paths stop at the first diffuse interaction: its direct part comes from
shadow rays to the lights, everything else from the lightmap irradiance E
(radiance kd·E/π). Specular, glossy and refractive lobes continue the path.
Rendering proceeds tile by tile so a host can display progress and cancel.
"""
import math
import time
from collections import namedtuple

import numpy as np
from numba import njit, prange

from . import lightmap as LM
from . import orientation_lightmap as OL
from .lights import sample_light
from .photon_tracer import Cancelled, ray_epsilon
from .raycast import STACK_WORDS, intersect_closest, occluded
from .sampling import next_float, stream_state
from .materials import SPECULAR, TRANSMIT, scatter

CameraData = namedtuple("CameraData", "xf kind sx sy width height")


def compile_camera(camera):
    """Camera basis and image-plane half extents, Blender conventions (looks along -Z, sensor fit auto)."""
    from .scene import SceneError, _affine
    w, h = int(camera.width), int(camera.height)
    if w <= 0 or h <= 0:
        raise SceneError(f"camera resolution must be positive, got {w}x{h}")
    xf = _affine(camera.transform, "camera")
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
    return CameraData(xf, kind, sx, sy, w, h)


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


@njit(cache=True)
def direct_irradiance(g, ls, stack, px, py, pz, nx, ny, nz, state, out):
    """Adds the direct irradiance at p (normal n facing the viewer) into out[bands].

    With few lights every light gets one sample; with many, four are drawn in
    proportion to power (unbiased either way).
    """
    n_lights = ls.kind.shape[0]
    if n_lights == 0:
        return state
    eps = ray_epsilon(px, py, pz)
    ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
    all_lights = n_lights <= 8
    n_samples = n_lights if all_lights else 4
    total = ls.power_cdf[n_lights - 1]
    for j in range(n_samples):
        if all_lights:
            li = j
            w_sel = 1.0
        else:
            state, us = next_float(state)
            target = us * total
            li = 0
            while li < n_lights - 1 and ls.power_cdf[li] <= target:
                li += 1
            p_li = (ls.power_cdf[li] - (ls.power_cdf[li - 1] if li > 0 else 0.0)) / total
            w_sel = 1.0 / (n_samples * p_li)
        state, u1 = next_float(state)
        state, u2 = next_float(state)
        state, u3 = next_float(state)
        wx, wy, wz, dist, scale, ok = sample_light(ls, g, li, px, py, pz, u1, u2, u3)
        if not ok:
            continue
        cos_r = wx * nx + wy * ny + wz * nz
        if cos_r <= 0.0:
            continue
        tmax = dist * (1.0 - 1e-6) - eps if dist < math.inf else math.inf
        if tmax <= 0.0 or occluded(g, stack, ox, oy, oz, wx, wy, wz, 0.0, tmax):
            continue
        c = cos_r * scale * w_sel
        for b in range(out.shape[0]):
            out[b] += ls.radiance[li, b] * c
    return state


@njit(cache=True, parallel=True)
def _render_tile(g, ms, ls, lm, ol, cam, env, x0, y0, tw, th, spp, seed, mode, max_depth, indirect,
                 out):
    nb = out.shape[2]
    for idx in prange(tw * th):
        stack = np.empty(STACK_WORDS, np.int32)
        acc = np.zeros(nb)
        tp = np.empty(nb)
        e = np.empty(nb)
        ind = np.empty(nb)
        px_i = x0 + idx % tw
        py_i = y0 + idx // tw
        pixel = py_i * cam.width + px_i
        for s in range(spp):
            state = stream_state(seed, pixel * spp + s)
            state, jx = next_float(state)
            state, jy = next_float(state)
            if spp == 1:
                jx, jy = 0.5, 0.5
            ox, oy, oz, dx, dy, dz = camera_ray(cam, px_i + jx, py_i + jy)
            for b in range(nb):
                tp[b] = 1.0 / spp
            tmin = 0.0
            for depth in range(max_depth + 1):
                hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
                    g, stack, ox, oy, oz, dx, dy, dz, tmin, math.inf)
                if not hit:
                    for b in range(nb):
                        acc[b] += tp[b] * env[b]
                    break
                px, py, pz = ox + t * dx, oy + t * dy, oz + t * dz
                m = g.shape_material[shape]
                cos_v = -(dx * nx + dy * ny + dz * nz)
                for b in range(nb):
                    acc[b] += tp[b] * ms.emission[m, b]
                fx, fy, fz = (nx, ny, nz) if cos_v >= 0.0 else (-nx, -ny, -nz)
                kd_max = 0.0
                for b in range(nb):
                    kd_max = max(kd_max, ms.diffuse[m, b])
                if kd_max > 0.0:
                    for b in range(nb):
                        e[b] = 0.0
                    state = direct_irradiance(g, ls, stack, px, py, pz, fx, fy, fz, state, e)
                    if indirect and OL.surface_irradiance(g, lm, ol, inst, shape, face, u, v,
                                                          nx, ny, nz, mode, ind):
                        for b in range(nb):
                            e[b] += ind[b]
                    for b in range(nb):
                        acc[b] += tp[b] * ms.diffuse[m, b] * e[b] / math.pi
                # Continue along a specular or transmitted lobe, chosen by probability.
                ps = 0.0
                pt = 0.0
                for b in range(nb):
                    ps = max(ps, ms.specular[m, b])
                    pt = max(pt, ms.transmission[m, b])
                if depth == max_depth or ps + pt <= 0.0:
                    break
                norm = max(1.0, ps + pt)
                ps /= norm
                pt /= norm
                state, ur = next_float(state)
                if ur < ps:
                    lobe, k, prob = SPECULAR, ms.specular, ps
                elif ur < ps + pt:
                    lobe, k, prob = TRANSMIT, ms.transmission, pt
                else:
                    break
                for b in range(nb):
                    tp[b] *= k[m, b] / prob
                state, u1 = next_float(state)
                state, u2 = next_float(state)
                state, u3 = next_float(state)
                ok, dx, dy, dz = scatter(ms, m, lobe, dx, dy, dz, nx, ny, nz, u1, u2, u3)
                if not ok:
                    break
                eps = ray_epsilon(px, py, pz)
                side = eps if (dx * nx + dy * ny + dz * nz) > 0.0 else -eps
                ox, oy, oz = px + side * nx, py + side * ny, pz + side * nz
        for b in range(nb):
            out[idx // tw, idx % tw, b] = acc[b]


def render(cs, samples=4, seed=0, mode=LM.MODE_BILINEAR, max_depth=8, tile=64,
           indirect=True, progress=None):
    """Renders cs.camera to a (height, width, n_bands) float array of radiance.

    progress(x0, y0, tile_image, image) is called after each tile; returning
    False cancels (raises Cancelled).
    """
    cam = cs.camera
    img = np.zeros((cam.height, cam.width, cs.n_bands))
    env = np.ascontiguousarray(cs.environment, dtype=np.float64)
    ol = cs.orientation if cs.orientation is not None else OL.empty_maps(cs.geometry.inst_proto.shape[0])
    t0 = time.perf_counter()
    for y0 in range(0, cam.height, tile):
        for x0 in range(0, cam.width, tile):
            tw, th = min(tile, cam.width - x0), min(tile, cam.height - y0)
            out = np.zeros((th, tw, cs.n_bands))
            _render_tile(cs.geometry, cs.materials, cs.lights, cs.lightmaps, ol, cam, env,
                         x0, y0, tw, th, int(samples), np.uint64(seed), int(mode), int(max_depth),
                         bool(indirect), out)
            img[y0:y0 + th, x0:x0 + tw] = out
            if progress is not None and progress(x0, y0, out, img) is False:
                raise Cancelled("render cancelled")
    cs.timings["render"] = time.perf_counter() - t0
    return img
