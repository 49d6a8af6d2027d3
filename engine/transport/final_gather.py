"""Final gather over the photon lightmaps (Jensen 1996; what Lightmass and PhotonGI do).

The thesis's renderer (8.2) reads a diffuse hit's indirect light from its own
texel: the texel's photon noise and its size show directly in the image. The
gather moves that reading one bounce away. From the camera's diffuse hit p,
cosine-distributed rays sample the hemisphere; where one lands (q), the cached
outgoing radiance of q is kd(q)·E(q)/π with E(q) the *total* irradiance the
lightmap or OL stores there (the photon pass records direct hits too for this,
photon_tracer record_direct). Then

    E_ind(p) ≈ (1/N) Σ kd(q_i) · E(q_i)          (cosine pdf cancels π and cos)

Rays that reach a light or the world add nothing: that light is p's direct
light, which the renderer samples itself. Where a gather ray meets glossy,
mirror or glass lobes it follows them (up to CHAIN vertices), so p still sees
lit walls in a mirror; lights met along such a chain count only if some lobe on
it was rough, because light focused onto p by sharp glass and mirrors alone
(L S+ D) is what the caustic lightmaps hold, read at p as before (those photons
are stored in both maps, so q still sees them). The gather is a consistent
estimator of the integral the lookup estimates, so both agree in the mean
(tests/test_final_gather.py).

Sampled lights (scene.gather_lights, a bake's *Gather Lights*): a lightmap holds
q's direct light averaged over q's texel, so a sun patch or a shadow's edge one
bounce away reaches p smeared over a texel, a bias no number of rays removes
(the window room's thin walls: relRMSE 0.036 at 300 k photons, 0.030 at 3 M
photons and 4096 rays). For the lights named there (small sources:
lights.gather_sampled) the photon pass leaves first hits out, and q takes their
direct light by a light sample and a shadow ray instead, as sharp as the light.

Approximations: glossy lobes met by gather rays see lights only by hitting them
(no light sampling there), and the gather uses q's face normal (no normal map).
"""
import math

from numba import njit

from ..shading import bsdf
from ..shading import dispersion
from ..shading import fluorescence
from ..shading import environment
from ..shading import light_hits
from ..shading import materials
from ..lightmaps import orientation_lightmap
from .photon_tracer import CAUSTIC_ALPHA
from .path_vertex import leave_surface
from ..core.jit import CORE, typed
from ..geometry.raycast import intersect_closest
from ..core.sampling import cosine_hemisphere, next_float, to_world
from .texel_gather import add_moment, direct_irradiance_at

GOLDEN = 0.6180339887498949
CHAIN = 3          # vertices a gather ray follows through glossy lobes


@njit(**CORE)
def gather_irradiance(scene, w, p, fn, sn, n_rays, mode, state, out, cells):
    """Indirect irradiance at p from n_rays gather rays into out[bands] (added).

    scene.inst_side (one per instance, or empty: no test): the lit side of a
    closed surface, +1 along its hit normal, 0 for open ones. A ray that first
    meets a closed surface from inside reads nothing: p lies inside that solid
    (a bake point where a box touches the floor), where no light comes, while
    its texels hold the outside's.
    fn: the face normal on the viewer's side, sn: the shading normal (rays are
    cosine-distributed about sn; those that leave below fn count zero, as the
    direct light's do). w: the gather path's scratch (path_vertex.PathScratch);
    w.count[0] gains the rays traced (glossy chains included). A randomly
    shifted rank-1 lattice stratifies the rays; it stays unbiased.

    cells = (rings, cell_e, cell_t). rings > 0 (irradiance-cache records): the
    hemisphere about sn is cut into `rings` rings of equal cosine-weighted
    measure by n_rays // rings sectors of azimuth, one jittered ray per cell
    (Ward & Heckbert's split), and each ray's own estimate and the distance to
    what it met first (inf: nothing) also go to cell_e[i] and cell_t[i], for
    the record's gradients. Otherwise cell_e and cell_t are not touched (any
    arrays of their types do).

    An `out` longer than the bands (a directional bake's row,
    texel_gather.moment_width) also gets each ray's light times the direction
    it left p in (texel_gather.add_moment)."""
    rings, cell_e, cell_t = cells
    g, ms, ls, lm, ol = scene.geometry, scene.materials, scene.lights, scene.lightmaps, scene.orientation
    inst_side = scene.inst_side
    kd, ks, kt, pc, ind, tp, f, rad = w.kd, w.ks, w.kt, w.closure, w.ind, w.tp, w.f, w.rad
    px, py, pz = p
    fx, fy, fz = fn
    sx, sy, sz = sn
    nb = tp.shape[0]
    directional = out.shape[0] > nb
    ox0, oy0, oz0 = leave_surface(p, fn, fn)
    state, o1 = next_float(state)
    state, o2 = next_float(state)
    wr = 1.0 / n_rays
    # texture footprint at q: a gather ray stands for about 1/N of the hemisphere
    spread = 2.0 / math.sqrt(n_rays)
    env_li = light_hits.environment_light(ls)
    sectors = n_rays // rings if rings > 0 else 0
    # every ray starts at the wavelength state p's path has (all bands, or the one it keeps)
    band0, nm0 = w.wave[dispersion.WAVE_BAND], w.wave[dispersion.WAVE_NM]
    for i in range(n_rays):
        w.wave[dispersion.WAVE_BAND] = band0
        w.wave[dispersion.WAVE_NM] = nm0
        dst = out
        if rings > 0:
            state, u1 = next_float(state)
            state, u2 = next_float(state)
            s2 = ((i // sectors) + u1) / rings
            st = math.sqrt(s2)
            phi = 2.0 * math.pi * ((i % sectors) + u2) / sectors
            lx, ly, lz = st * math.cos(phi), st * math.sin(phi), math.sqrt(max(1.0 - s2, 0.0))
            dst = cell_e[i]
            for b in range(nb):
                dst[b] = 0.0
            cell_t[i] = math.inf
        else:
            u1 = (i + o1) * wr
            u2 = (o2 + i * GOLDEN) % 1.0
            lx, ly, lz = cosine_hemisphere(u1, u2)
            if directional:
                # the ray's own light first, for its moment
                dst = w.ray
                for b in range(nb):
                    dst[b] = 0.0
        dx, dy, dz = to_world(lx, ly, lz, sx, sy, sz)
        if dx * fx + dy * fy + dz * fz <= 0.0:
            continue
        d0x, d0y, d0z = dx, dy, dz
        ox, oy, oz = ox0, oy0, oz0
        for b in range(nb):
            tp[b] = wr if rings == 0 else 1.0
        sharp = True         # every lobe followed so far was sharp: lights seen are caustics
        for k in range(CHAIN):
            w.count[0] += 1
            hit, t, inst, shape, face, u, v, nx, ny, nz = intersect_closest(
                g, w.stack, ox, oy, oz, dx, dy, dz, 0.0, math.inf)
            if k > 0 and not sharp:
                # the "irradiance" here is radiance weighted by cos/pdf (tp): lights met count
                light_hits.add_seen_lights(ls, ox, oy, oz, dx, dy, dz, t if hit else math.inf, 0.0, typed(True), tp,
                                           dst, w.pol, False)
            if k == 0 and rings > 0 and hit:
                cell_t[i] = t
            if not hit:
                if k > 0 and not sharp and env_li >= 0:
                    environment.radiance(scene.environment, dx, dy, dz, rad)
                    for b in range(nb):
                        dst[b] += tp[b] * rad[b]
                break
            cos_dn = dx * nx + dy * ny + dz * nz
            if k == 0 and inst_side.shape[0] > 0 and inst_side[inst] * cos_dn > 0.0:
                break
            m = g.shape_material[shape]
            if k > 0 and not sharp:
                for b in range(nb):
                    dst[b] += tp[b] * ms.emission[m, b]
            qx, qy, qz = ox + t * dx, oy + t * dy, oz + t * dz
            rough, ior, _ = materials.surface_inputs(ms, scene.textures, g, inst, m, shape, face, u, v, spread * t,
                                                     kd, ks, kt)
            if dispersion.splits_bands(ms.dispersion, m, w.wave):
                state = dispersion.keep_one_band(ms.bands, tp, w.wave, state)
            ior = dispersion.path_ior(ms.dispersion, m, ior, w.wave)
            cos_o = min(abs(cos_dn), 1.0)
            bsdf.closure_scalars(scene.bsdf, m, rough, ior, cos_dn < 0.0, cos_o, pc)
            ds = bsdf.diffuse_scale(pc)
            pd, ps, pm, pg = fluorescence.diffuse_probability(ms, m, kd, ds,
                                                              bsdf.lobe_probabilities(pc, kd, ks, kt, cos_o))
            if pd > 0.0 and ds > 0.0 and orientation_lightmap.surface_irradiance(g, lm, ol, inst, shape, face, u, v,
                                                                                 nx, ny, nz, mode, ind):
                if scene.gather_lights.kind.shape[0] > 0:
                    # these lights' first hits are not in the lightmap: sampled here, as sharp as they are
                    sg = -1.0 if cos_dn > 0.0 else 1.0
                    for b in range(nb):
                        w.e[b] = 0.0
                    state = direct_irradiance_at(g, scene.gather_lights, w.stack, (qx, qy, qz),
                                                 (sg * nx, sg * ny, sg * nz), state, w.e, w.lg)
                    for b in range(nb):
                        ind[b] += w.e[b]
                if ms.fluorescent[m]:
                    for b in range(nb):
                        dst[b] += tp[b] * fluorescence.reflected(ms, m, kd, ind, b) * ds
                else:
                    for b in range(nb):
                        dst[b] += tp[b] * kd[b] * ds * ind[b]
            if ps + pm + pg <= 0.0 or k == CHAIN - 1:
                break
            # on through the glossy lobes, in the frame of the face towards the ray
            if cos_dn > 0.0:
                gx, gy, gz = -nx, -ny, -nz
            else:
                gx, gy, gz = nx, ny, nz
            lox, loy, loz = bsdf.to_local(-dx, -dy, -dz, gx, gy, gz)
            state, r0 = next_float(state)
            state, r1 = next_float(state)
            state, r2 = next_float(state)
            state, r3 = next_float(state)
            ok, ix, iy, iz, _, _ = bsdf.sample_glossy(pc, ks, kt, ps, pm, pg, lox, loy, loz, r0, r1, r2, r3, f)
            if not ok:
                break
            if pc[bsdf.P_ALPHA] > CAUSTIC_ALPHA:
                sharp = False
            dx, dy, dz = bsdf.from_local(ix, iy, iz, gx, gy, gz)
            for b in range(nb):
                tp[b] *= f[b]
            ox, oy, oz = leave_surface((qx, qy, qz), (nx, ny, nz), (dx, dy, dz))
        if rings > 0 or directional:
            scale = wr if rings > 0 else 1.0
            for b in range(nb):
                out[b] += scale * dst[b]
            if directional:
                add_moment(out, nb, dst, scale, d0x, d0y, d0z)
    w.wave[dispersion.WAVE_BAND] = band0
    w.wave[dispersion.WAVE_NM] = nm0
    return state
