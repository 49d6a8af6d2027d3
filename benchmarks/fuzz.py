"""Fuzz harness for the engine: generated broken scenes must
either run cleanly or be refused with a SceneError, never crash, hang, produce
NaN/inf or create energy.

Case i is generated from seed i alone (reproducible). Cases run in a small pool
of long-lived worker processes, so a segfault only kills a worker: the parent
records the case id and starts a new worker. Kernels are compiled/loaded once
per worker (a warm-up scene before the first case), not per case.

Usage (from the repository root):
    .venv/bin/python -m benchmarks.fuzz --cases 10000 [--start K] [--workers W] [--timeout S] [--json F]
    .venv/bin/python -m benchmarks.fuzz --case 123        # one case in-process, with traceback
    .venv/bin/python -m benchmarks.fuzz --blender 20      # also N random scenes through bpy
Under NUMBA_BOUNDSCHECK=1 (own NUMBA_CACHE_DIR!) an out-of-bounds index raises
IndexError in the kernel, which is counted as a failure like any other exception.
"""
import argparse
import json
import math
import multiprocessing as mp
import os
import pathlib
import sys
import time
import traceback
from collections import Counter, defaultdict

ROOT = pathlib.Path(__file__).resolve().parents[1]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT.parent))
    __package__ = "photon_lightmaps.benchmarks" if (ROOT / "__init__.py").exists() else "benchmarks"
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import numpy as np  # noqa: E402

PHOTONS = 2000
REL_TOL = 1e-9
# A texel whose flux share exceeds its area share this many times: light from
# geometry much larger than the texel was recorded there (zero-UV-area slivers).
ABSURD_RATIO = 1e9

FAILURE_CLASSES = ("crash", "timeout", "exception", "nonfinite_lightmap", "nonfinite_render",
                   "nonfinite_gather", "negative", "energy_audit", "flux_above_emitted",
                   "absurd_irradiance")


def _engine():
    from photon_lightmaps.engine.core import scene as scene_model
    return scene_model


# --------------------------------------------------------------------------------------
# Case generator
# --------------------------------------------------------------------------------------

def _loguniform(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    a, b, c, d = q
    return np.array([[a*a+b*b-c*c-d*d, 2*(b*c-a*d), 2*(b*d+a*c)],
                     [2*(b*c+a*d), a*a-b*b+c*c-d*d, 2*(c*d-a*b)],
                     [2*(b*d-a*c), 2*(c*d+a*b), a*a-b*b-c*c+d*d]])


def random_transform(rng, tags, spread=2.0):
    """Affine 3x4: mostly ordinary, sometimes mirrored, near-singular, sheared,
    or scaled by 1e-6 … 1e7."""
    R = _rotation(rng) if rng.random() < 0.7 else np.eye(3)
    s = np.ones(3) * (rng.uniform(0.3, 1.5) if rng.random() < 0.6 else 1.0)
    r = rng.random()
    if r < 0.12:
        s *= _loguniform(rng, 1e-6, 1e7)
        tags.append("scale_extreme")
    elif r < 0.22:
        s = np.array([_loguniform(rng, 1e-6, 1e7) for _ in range(3)])
        tags.append("scale_aniso")
    elif r < 0.3:
        s[rng.integers(3)] *= 10.0 ** -rng.uniform(3, 12.5)
        tags.append("near_singular")
    if rng.random() < 0.2:
        s[rng.integers(3)] *= -1
        tags.append("mirrored")
    M = R @ np.diag(s)
    if rng.random() < 0.1:
        Sh = np.eye(3)
        Sh[0, 1] = rng.uniform(-5, 5)
        M = M @ Sh
        tags.append("shear")
    t = rng.uniform(-spread, spread, 3)
    if "scale_extreme" in tags and rng.random() < 0.3:
        t *= s[0]
    return np.hstack([M, t[:, None]])


def _near_degenerate(rng, a, b):
    """A third vertex just above the engine's collinearity threshold
    (|e1 x e2| > 1e-14 |e|²) or just below it."""
    d = b - a
    L = np.linalg.norm(d) + 1e-300
    perp = np.cross(d, rng.normal(size=3))
    perp /= np.linalg.norm(perp) + 1e-300
    h = L * 10.0 ** -rng.uniform(11, 14.5)
    return a + rng.uniform(-0.5, 1.5) * d + h * perp


def random_mesh(rng, tags, n_max=60):
    """Triangle soup / grid with degenerate, duplicate, non-manifold and inverted faces."""
    scene_model = _engine()
    kind = rng.choice(["soup", "grid", "box", "fan"])
    if kind == "grid":
        n = int(rng.integers(1, 5))
        xs = np.linspace(-1, 1, n + 1)
        X, Y = np.meshgrid(xs, xs)
        Z = rng.normal(scale=0.2, size=X.shape) if rng.random() < 0.5 else np.zeros_like(X)
        v = np.stack([X.ravel(), Y.ravel(), Z.ravel()], 1)
        idx = lambda i, j: i * (n + 1) + j
        t = []
        for i in range(n):
            for j in range(n):
                t += [(idx(i, j), idx(i, j + 1), idx(i + 1, j + 1)), (idx(i, j), idx(i + 1, j + 1), idx(i + 1, j))]
        v, t = list(v), list(t)
    elif kind == "box":
        v, t = (list(x) for x in box_mesh_arrays())
    elif kind == "fan":
        k = int(rng.integers(3, 12))
        v = [np.zeros(3)] + [np.array([math.cos(2 * math.pi * i / k), math.sin(2 * math.pi * i / k), 0.0])
                             for i in range(k)]
        t = [(0, 1 + i, 1 + (i + 1) % k) for i in range(k)]
    else:
        n = int(rng.integers(1, 20))
        v = list(rng.uniform(-1, 1, (3 * n, 3)))
        t = [(3 * i, 3 * i + 1, 3 * i + 2) for i in range(n)]
    v = [np.asarray(x, float) for x in v]
    # Inject broken faces.
    for _ in range(int(rng.integers(0, 6))):
        r = rng.random()
        V = len(v)
        a, b = v[rng.integers(V)], v[rng.integers(V)]
        if r < 0.2:      # collinear
            v.append(a + rng.uniform(-1, 2) * (b - a))
            t.append((int(rng.integers(V)), int(rng.integers(V)), V))
            tags.append("collinear")
        elif r < 0.35:   # repeated vertex
            i = int(rng.integers(V))
            t.append((i, i, int(rng.integers(V))))
            tags.append("repeated_vertex")
        elif r < 0.55:   # near-degenerate sliver
            ia, ib = int(rng.integers(V)), int(rng.integers(V))
            v.append(_near_degenerate(rng, v[ia], v[ib]))
            t.append((ia, ib, V))
            tags.append("sliver")
        elif r < 0.7 and t:   # duplicate / inverted duplicate
            f = t[int(rng.integers(len(t)))]
            t.append(f if rng.random() < 0.5 else f[::-1])
            tags.append("duplicate")
        elif r < 0.85 and t:  # non-manifold: a third face on an existing edge
            f = t[int(rng.integers(len(t)))]
            v.append(rng.uniform(-1, 1, 3))
            t.append((f[0], f[1], V))
            tags.append("non_manifold")
        elif t:          # same place, other vertex ids (coincident geometry)
            f = t[int(rng.integers(len(t)))]
            v += [v[f[0]].copy(), v[f[1]].copy(), v[f[2]].copy()]
            t.append((V, V + 1, V + 2))
            tags.append("coincident")
    if rng.random() < 0.15:
        t = [f[::-1] for f in t]
        tags.append("inverted")
    t = t[:n_max]
    v = np.array(v, float)
    t = np.array(t, np.int64).reshape(-1, 3)
    if rng.random() < 0.05:
        v = v * 1e-200 if rng.random() < 0.5 else v * 1e150   # extreme coordinates
        tags.append("extreme_coords")
    uvs = random_uvs(rng, t.shape[0], tags, allow_none=t.shape[0] <= 24)
    return scene_model.TriangleMesh(v, t, uvs=uvs, name=f"mesh_{kind}")


def random_uvs(rng, T, tags, allow_none=True):
    r = rng.random()
    if r < 0.12 and allow_none:
        tags.append("uv_none")       # xatlas unwrap (slow: small meshes only)
        return None
    uv = rng.uniform(0, 1, (T, 3, 2))
    if r < 0.35:
        # a sensible layout: each triangle in its own cell
        k = max(1, int(math.ceil(math.sqrt(T))))
        for i in range(T):
            cx, cy = (i % k) / k, (i // k) / k
            uv[i] = np.array([[cx, cy], [cx + 0.9 / k, cy], [cx, cy + 0.9 / k]]) + 0.01 / k
        tags.append("uv_cells")
    elif r < 0.5:
        tags.append("uv_random")
    elif r < 0.65:
        uv = rng.uniform(-1, 2, (T, 3, 2))
        tags.append("uv_out_of_range")
    # some triangles with zero or tiny UV area
    if rng.random() < 0.35 and T:
        for i in rng.choice(T, size=int(rng.integers(1, T + 1)), replace=False):
            m = rng.random()
            if m < 0.4:
                uv[i] = uv[i, 0]                          # one UV point
            elif m < 0.7:
                uv[i, 2] = uv[i, 0] + rng.uniform(0, 1) * (uv[i, 1] - uv[i, 0])   # collinear
            else:
                uv[i, 1:] = uv[i, 0] + rng.uniform(-1, 1, (2, 2)) * 10.0 ** -rng.uniform(6, 15)
        tags.append("uv_zero_area")
    return uv


def box_mesh_arrays(inward=False):
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    t = []
    for a, b, c, d in quads:
        t += [(a, b, c), (a, c, d)]
    t = np.array(t, np.int64)
    if inward:
        t = t[:, ::-1].copy()
    return v, t


def random_primitive(rng, tags, solid=False):
    scene_model = _engine()
    kinds = scene_model.PRIMITIVE_KINDS[:6] + ("frustum",) if solid else scene_model.PRIMITIVE_KINDS
    kind = str(rng.choice(kinds))
    params = ()
    if kind == "torus":
        params = (float(rng.choice([0.5, 0.25, 1e-6, 0.999999, 1 - 1e-12])),)
        if rng.random() < 0.05:
            params = (float(rng.choice([0.0, 1.0, 1.5, -0.2])),)   # invalid: SceneError
            tags.append("bad_params")
    elif kind == "frustum":
        params = (float(rng.choice([0.0, 1e-9, 0.4, 1 - 1e-12, 1.0])),)
        if rng.random() < 0.05:
            params = (float(rng.choice([-0.1, 1.5])),)              # invalid: SceneError
            tags.append("bad_params")
    elif rng.random() < 0.05:
        params = tuple(rng.normal(size=int(rng.integers(1, 6))))
        tags.append("odd_params")
    xf = random_transform(rng, tags, spread=0.5) if rng.random() < 0.5 else scene_model.identity()
    return scene_model.Primitive(kind, transform=xf, params=params, name=f"prim_{kind}")


def random_csg(rng, tags, depth):
    scene_model = _engine()
    ops = scene_model.CSG_OPS
    if depth <= 0 or rng.random() < 0.25:
        if rng.random() < 0.2:
            v, t = box_mesh_arrays()
            v = v * rng.uniform(0.3, 1.0) + rng.uniform(-0.5, 0.5, 3)
            tags.append("csg_mesh")
            return scene_model.TriangleMesh(v, t, uvs=random_uvs(rng, 12, tags, allow_none=rng.random() < 0.3),
                                            name="csg_box_mesh")
        if rng.random() < 0.02:
            tags.append("csg_open_leaf")
            return scene_model.Primitive("quad", name="open_leaf")
        return random_primitive(rng, tags, solid=True)
    op = str(rng.choice(ops))
    r = rng.random()
    left = random_csg(rng, tags, depth - 1)
    if r < 0.12:
        right = left                                     # self-union / self-intersection
        tags.append("csg_self")
    elif r < 0.22 and isinstance(left, scene_model.Primitive):
        # coincident: same kind, same or touching placement
        xf = np.array(left.transform, float).copy()
        if rng.random() < 0.5:
            xf[:, 3] += xf[:, 0] * 2.0   # shares a face
        right = scene_model.Primitive(left.kind, transform=xf, params=left.params, name="coincident")
        tags.append("csg_coincident")
    elif r < 0.3:
        right = random_primitive(rng, tags, solid=True)
        right.transform = np.array(right.transform, float).copy()
        right.transform[:, 3] += 100.0                  # disjoint
        tags.append("csg_disjoint")
    else:
        right = random_csg(rng, tags, depth - 1)
    if rng.random() < 0.01:
        right = None
        tags.append("csg_missing_operand")
    return scene_model.CSGNode(op, left, right, name=f"csg_{op}")


def random_material(rng, tags, i):
    scene_model = _engine()
    nb = 3
    d = rng.uniform(0, 1, nb) * rng.uniform(0, 1)
    sp = rng.uniform(0, 1, nb) * rng.uniform(0, 1) if rng.random() < 0.4 else 0.0
    tr = rng.uniform(0, 1, nb) * rng.uniform(0, 1) if rng.random() < 0.3 else 0.0
    tot = d + sp + tr
    if np.max(tot) > 1 and rng.random() < 0.85:
        f = 0.999999 / np.max(tot) if rng.random() < 0.5 else 1.0 / np.max(tot)
        d, sp, tr = d * f, sp * f if np.ndim(sp) else sp, tr * f if np.ndim(tr) else tr
    elif np.max(tot) > 1:
        tags.append("albedo_above_1")
    if rng.random() < 0.05:
        d = 1.0
    em = 0.0
    if rng.random() < 0.1:
        em = rng.uniform(0, 1, nb) * _loguniform(rng, 1e-30, 1e30)
        tags.append("emissive")
    return scene_model.Material(f"mat{i}", diffuse=d, specular=sp,
                                roughness=float(rng.choice([0.0, rng.uniform(0, 1), 1.0])), transmission=tr,
                                ior=float(rng.choice([1.5, 1.0, 1.0001, rng.uniform(1, 3)])), emission=em)


def random_light(rng, tags, centers):
    scene_model = _engine()
    kind = str(rng.choice(scene_model.LIGHT_KINDS))
    r = rng.random()
    if r < 0.08:
        power = 0.0
        tags.append("power_zero")
    elif r < 0.3:
        power = _loguniform(rng, 1e-30, 1e30)
        tags.append("power_extreme")
    else:
        power = _loguniform(rng, 1.0, 1000.0)
    if kind == "sun":
        power = min(power, 1e30)
    pos = rng.uniform(-3, 3, 3)
    if centers and rng.random() < 0.3:
        pos = centers[int(rng.integers(len(centers)))] + rng.normal(scale=0.05, size=3)
        tags.append("light_inside")
    xf = np.hstack([_rotation(rng), pos[:, None]])
    col = rng.uniform(0, 1, 3) if rng.random() < 0.5 else 1.0
    kw = {}
    if kind in ("point", "spot"):
        kw["radius"] = float(rng.choice([0.0, 0.0, rng.uniform(0, 0.5), 1e-9]))
        kw["soft_falloff"] = bool(rng.random() < 0.3)
    if kind == "spot":
        kw["spot_size"] = float(rng.choice([math.radians(45), 1e-6, math.pi, rng.uniform(0, math.pi)]))
        kw["spot_blend"] = float(rng.choice([0.0, 0.15, 1.0]))
    if kind == "area":
        kw["shape"] = str(rng.choice(scene_model.AREA_SHAPES))
        kw["size"] = float(rng.choice([1.0, rng.uniform(0, 2), 1e-9]))
        kw["size_y"] = float(rng.choice([1.0, rng.uniform(0, 2), 1e-9]))
    if kind == "sun":
        kw["angle"] = float(rng.choice([0.0, 0.01, rng.uniform(0, math.pi)]))
    return scene_model.Light(kind, color=col, power=power, transform=xf, name=f"light_{kind}", **kw)


def make_case(i):
    """(scene, tags, run settings) of case i, from seed i only."""
    scene_model = _engine()
    rng = np.random.default_rng([0xF0220, int(i)])
    tags = []
    scene = scene_model.Scene(n_bands=3, name=f"fuzz{i}")
    n_mat = int(rng.integers(1, 4))
    for m in range(n_mat):
        scene.materials.append(random_material(rng, tags, m))
    centers = []
    n_obj = int(rng.integers(1, 5)) if rng.random() > 0.05 else 0
    if n_obj == 0:
        tags.append("no_geometry")
    for k in range(n_obj):
        proto = scene_model.Prototype(name=f"proto{k}")
        r = rng.random()
        if r < 0.4:
            proto.meshes.append(random_mesh(rng, tags))
        elif r < 0.7:
            proto.primitives.append(random_primitive(rng, tags))
        elif r < 0.9:
            depth = int(rng.integers(1, 5)) if rng.random() < 0.9 else int(rng.integers(8, 40))
            proto.csg.append(random_csg(rng, tags, depth))
            tags.append("csg")
        else:   # a mix
            proto.meshes.append(random_mesh(rng, tags, n_max=20))
            proto.primitives.append(random_primitive(rng, tags))
        for g in proto.meshes + proto.primitives:
            g.material = int(rng.integers(n_mat))
        if rng.random() < 0.1 and proto.meshes:
            T = proto.meshes[0].triangles.shape[0]
            proto.meshes[0].material_ids = rng.integers(n_mat, size=T)
        _set_csg_materials(proto.csg, rng, n_mat)
        scene.prototypes.append(proto)
        for _ in range(1 if rng.random() < 0.8 else int(rng.integers(2, 4))):
            xf = random_transform(rng, tags)
            res = int(rng.choice([0, 2, 3, 4, 8, 16]))
            scene.instances.append(scene_model.Instance(len(scene.prototypes) - 1, xf,
                                                        name=f"inst{len(scene.instances)}",
                                                        lightmap=bool(rng.random() < 0.9), lightmap_resolution=res))
            centers.append(xf[:, 3].copy())
    if rng.random() < 0.15:
        # orientation lightmaps: random members (possibly none), maybe a parent
        n_inst = len(scene.instances)
        res = int(rng.choice([2, 4, 8]))
        taken = set()
        for k in range(int(rng.integers(1, 3))):
            members = [j for j in range(n_inst) if rng.random() < 0.5 and j not in taken]
            taken.update(members)
            scene.orientation_lightmaps.append(scene_model.OrientationLightmap(
                name=f"ol{k}", instances=members, parent=k - 1 if (k and rng.random() < 0.5) else -1,
                resolution=res, samples=int(rng.integers(20, 400)), min_hits=int(rng.integers(1, 20)),
                backup=bool(rng.random() < 0.3), seed=k))
        tags.append("ol")
        if not any(ol.instances for ol in scene.orientation_lightmaps):
            tags.append("ol_empty")
    n_lights = int(rng.integers(1, 4)) if rng.random() > 0.1 else 0
    if n_lights == 0:
        tags.append("no_lights")
    scene.lights = [random_light(rng, tags, centers) for _ in range(n_lights)]
    if rng.random() < 0.15:
        scene.environment = rng.uniform(0, 2, 3)
    w, h = int(rng.integers(8, 17)), int(rng.integers(8, 17))
    eye = rng.normal(size=3)
    eye = eye / (np.linalg.norm(eye) + 1e-12) * rng.uniform(3, 10)
    if rng.random() < 0.1:
        fwd = eye / np.linalg.norm(eye)          # looking away from everything
        tags.append("camera_away")
    else:
        fwd = -eye / np.linalg.norm(eye)
    up = np.array([0, 0, 1.0]) if abs(fwd[2]) < 0.99 else np.array([0, 1.0, 0])
    x = np.cross(fwd, up)
    x /= np.linalg.norm(x)
    y = np.cross(x, fwd)
    cam_xf = np.hstack([np.stack([x, y, -fwd], 1), eye[:, None]])
    kind = "orthographic" if rng.random() < 0.2 else "perspective"
    fov = float(rng.choice([math.radians(39.6), 1e-3, math.pi - 1e-3, rng.uniform(0.1, 2.5)]))
    scene.camera = scene_model.Camera(transform=cam_xf, kind=kind, fov=fov, ortho_scale=float(rng.uniform(0.1, 20)),
                                      width=w, height=h)
    scene.texel_density = float(rng.choice([1.0, 4.0, 16.0]))
    settings = dict(max_bounces=int(rng.integers(0, 9)), record_direct=bool(rng.random() < 0.5),
                    photons=PHOTONS, mode=int(rng.integers(0, 2)), gather=bool(rng.random() < 0.7),
                    csg_split=bool(rng.random() < 0.9))
    return scene, sorted(set(tags)), settings


def _set_csg_materials(nodes, rng, n_mat):
    scene_model = _engine()
    seen = set()
    stack = list(nodes)
    while stack:
        n = stack.pop()
        if n is None or id(n) in seen:
            continue
        seen.add(id(n))
        if isinstance(n, scene_model.CSGNode):
            stack += [n.left, n.right]
        else:
            n.material = int(rng.integers(n_mat))


# --------------------------------------------------------------------------------------
# Running and checking one case
# --------------------------------------------------------------------------------------

def _finite(a):
    return bool(np.all(np.isfinite(a)))


def run_case(i):
    """Runs case i in this process; returns a result dict (exceptions inside the
    engine become 'exception' failures, SceneError an accepted refusal)."""
    scene_model = _engine()
    t0 = time.perf_counter()
    scene, tags, st = make_case(i)
    res = dict(id=int(i), tags=tags, outcome="ok", failures=[], message="")
    try:
        _check_case(scene, st, res)
    except scene_model.SceneError as e:
        res["outcome"] = "scene_error"
        res["message"] = str(e)[:300]
    except Exception as e:  # noqa: BLE001  any other exception is a bug
        res["failures"].append("exception")
        # numba wraps a kernel's exception in SystemError: report the cause
        c = e.__cause__ or e.__context__ or e
        res["message"] = f"{type(c).__name__}: {str(c)[:200]} (in {type(e).__name__}: {str(e)[:120]})"
        res["traceback"] = traceback.format_exc()[-2000:]
    if res["failures"]:
        res["outcome"] = "fail"
    res["seconds"] = time.perf_counter() - t0
    return res


def _weights_bounded(ms, bt=None):
    """True when no band of any material can weigh a surviving photon above 1
    (bsdf.lobe_probabilities): then absorbed energy is never negative. A
    material whose lobes peak in different bands (diffuse [.9, .1], specular
    [.1, .9]) is unbiased but its bands' weights exceed 1, so a finite run may
    book a slightly negative absorption in one band. A rough metal's multiscatter
    compensation raises its lobe by up to 1/E (E its single-scatter albedo), so
    its specular counts that much."""
    spec = ms.specular.max(axis=1)
    if bt is not None:
        rough = ms.roughness > 0.0
        spec = np.where(rough, spec / max(float(bt.e_metal.min()), 1e-3), spec)
    peak = ms.diffuse.max(axis=1) + spec + ms.transmission.max(axis=1)
    return peak.size == 0 or float(peak.max()) <= 1.0 + 1e-12


def _check_case(scene, st, res):
    from photon_lightmaps.engine.lightmaps import lightmap
    from photon_lightmaps.engine.lightmaps import orientation_lightmap
    from photon_lightmaps.engine.transport import texel_gather
    from photon_lightmaps.engine.compile import compile_scene
    from photon_lightmaps.engine.transport.photon_tracer import trace_photons
    from photon_lightmaps.engine.transport.renderer import render

    fail = res["failures"]
    notes = []
    cs = compile_scene(scene, max_resolution=32, csg_split=st["csg_split"])
    lm = cs.lightmaps
    if not (_finite(lm.area) and np.all(lm.area >= 0)):
        fail.append("nonfinite_lightmap")
        notes.append("texel areas not finite/non-negative")
    B = st["max_bounces"]
    stats = trace_photons(cs, st["photons"], seed=int(res["id"]), max_bounces=B,
                          record_direct=st["record_direct"], keep_points=True)
    led = (stats.emitted, stats.absorbed, stats.escaped, stats.truncated)
    if not all(_finite(a) for a in led):
        fail.append("energy_audit")
        notes.append("ledger not finite")
    elif (_weights_bounded(cs.materials, cs.bsdf) and min(float(a.min(initial=0.0)) for a in led)
          < -REL_TOL * float(stats.emitted.max(initial=0.0))):
        # (a band of albedo ~1 books rounding-sized negatives: -1e-18 of 10 W is fine)
        fail.append("negative")
        notes.append(f"negative ledger entry {min(float(a.min()) for a in led):.3g}")
    elif stats.photons and stats.audit_error() > REL_TOL:
        fail.append("energy_audit")
        notes.append(f"audit error {stats.audit_error():.3g}")
    for name in ("flux", "irradiance", "flux_sq"):
        if not _finite(getattr(lm, name)):
            fail.append("nonfinite_lightmap")
            notes.append(f"lightmap {name} not finite")
            break
    emitted = stats.emitted
    if lm.flux.size and _finite(lm.flux):
        if lm.flux.min() < 0 or lm.irradiance.min() < 0:
            fail.append("negative")
            notes.append("negative flux/irradiance")
        ol = cs.orientation
        levels = orientation_lightmap.levels(ol) if ol is not None and ol.lid.size else 0
        # A photon never gains power and records at most once per bounce on its
        # own lightmap and once per OL level above it.
        per_texel = emitted * (B + 1) * (1 + REL_TOL) + 1e-300
        total = emitted * (B + 1) * (1 + levels) * (1 + REL_TOL) + 1e-300
        if np.any(lm.flux > per_texel[None, :]) or np.any(lm.flux.sum(axis=0) > total):
            fail.append("flux_above_emitted")
            notes.append(f"flux max {lm.flux.max():.3g} sum {lm.flux.sum(0).max():.3g} "
                         f"vs emitted {emitted.max():.3g}")
        _check_absurd(lm, fail, notes)
    img = render(cs, samples=1, seed=1, mode=st["mode"], max_depth=4, tile=8)
    if not _finite(img):
        fail.append("nonfinite_render")
        notes.append(f"{int((~np.isfinite(img)).sum())} non-finite pixel values")
    elif img.size and img.min() < 0:
        fail.append("negative")
        notes.append("negative pixel")
    if st["gather"]:
        ids, E = texel_gather.direct_texel_irradiance(cs, samples_per_texel=4, seed=2)
        if not _finite(E):
            fail.append("nonfinite_gather")
            notes.append(f"{int((~np.isfinite(E)).sum())} non-finite gathered values")
        elif E.size and E.min() < 0:
            fail.append("negative")
            notes.append("negative gathered E")
        else:
            texel_gather.add_direct(lm, ids, E)
            if not (_finite(lm.irradiance) and _finite(lm.flux)):
                fail.append("nonfinite_gather")
                notes.append("lightmap not finite after add_direct")
            img2 = render(cs, samples=1, seed=3, mode=st["mode"], max_depth=2, tile=16)
            if not _finite(img2):
                fail.append("nonfinite_render")
                notes.append("baked render not finite")
    res["info"] = dict(texels=int(lm.area.shape[0]), records=int(stats.records),
                       degenerate=int(cs.info.get("n_degenerate", 0)))
    if notes:
        res["message"] = "; ".join(notes)[:500]


def _check_absurd(lm, fail, notes):
    """Per lightmap: a measured texel's share of the flux against its share of
    the area. Photons land in proportion to area times irradiance; a share ratio
    of 1e9 means light of much larger geometry was recorded into a sliver."""
    off = lm.offset
    n = lm.area.shape[0]
    worst = 0.0
    for l in range(off.shape[0]):
        a0 = int(off[l])
        a1 = int(off[l + 1]) if l + 1 < off.shape[0] else n
        A = lm.area[a0:a1]
        F = lm.flux[a0:a1].mean(axis=1)
        At, Ft = float(A.sum()), float(F.sum())
        if not (At > 0 and Ft > 0):
            continue
        meas = (A > 0) & (lm.state[a0:a1] == LM_STATE_MEASURED())
        if not meas.any():
            continue
        r = (F[meas] / Ft) / (A[meas] / At)
        worst = max(worst, float(r.max()))
    if worst > ABSURD_RATIO:
        fail.append("absurd_irradiance")
        notes.append(f"texel flux share / area share = {worst:.3g}")


def LM_STATE_MEASURED():
    from photon_lightmaps.engine.lightmaps.lightmap import STATE_MEASURED
    return STATE_MEASURED


# --------------------------------------------------------------------------------------
# Worker pool (forkserver): a crash kills one worker, the parent records the case
# --------------------------------------------------------------------------------------

def _warm_up():
    """Compiles/loads every kernel family once: meshes, primitives, CSG, OLs,
    all light kinds, render and gather."""
    from photon_lightmaps.engine import demo_scenes
    from photon_lightmaps.engine.transport import texel_gather
    from photon_lightmaps.engine.compile import compile_scene
    from photon_lightmaps.engine.transport.photon_tracer import trace_photons
    from photon_lightmaps.engine.transport.renderer import render
    scene_model = _engine()
    s = demo_scenes.cornell_box(width=8, height=8)
    s.lights += [scene_model.Light("point", power=5.0, transform=scene_model.translate(0, 0, 1)),
                 scene_model.Light("spot", power=5.0, transform=scene_model.translate(0, 0, 1.5)),
                 scene_model.Light("sun", power=1.0)]
    em = s.add_material(scene_model.Material("em", diffuse=0.0, emission=1.0))
    s.add_object(scene_model.Primitive("disk", material=em), scene_model.translate(0, 0.5, 1.9))
    solid = scene_model.CSGNode("difference", scene_model.Primitive("box"),
                                scene_model.Primitive("sphere", transform=scene_model.scale(1.2)))
    s.prototypes.append(scene_model.Prototype("csg", csg=[solid]))
    s.instances.append(scene_model.Instance(len(s.prototypes) - 1, scene_model.compose(
        scene_model.translate(0.5, 0.5, 0.3), scene_model.scale(0.2))))
    s.orientation_lightmaps.append(scene_model.OrientationLightmap("ol", instances=[len(s.instances) - 1],
                                                                   samples=50, resolution=4))
    # a CSG solid with its own, split texels (most cases have one: 76 s of kernels otherwise)
    s.instances.append(scene_model.Instance(len(s.prototypes) - 1, scene_model.compose(
        scene_model.translate(-0.5, 0.5, 0.3), scene_model.scale(0.2))))
    cs = compile_scene(s, max_resolution=32, csg_split=True)
    trace_photons(cs, 500, max_bounces=3, keep_points=True)
    for mode in (0, 1):
        render(cs, samples=1, mode=mode, max_depth=2, tile=8)
    ids, E = texel_gather.direct_texel_irradiance(cs, samples_per_texel=4)
    texel_gather.add_direct(cs.lightmaps, ids, E)


def _worker(conn, threads):
    try:
        import numba
        if threads:
            numba.set_num_threads(threads)
        _warm_up()
        conn.send(("ready", None))
    except BaseException as e:  # noqa: BLE001
        conn.send(("warmup_failed", f"{type(e).__name__}: {e}\n{traceback.format_exc()[-2000:]}"))
        return
    while True:
        try:
            i = conn.recv()
        except EOFError:
            return
        if i is None:
            return
        try:
            r = run_case(i)
        except BaseException as e:  # noqa: BLE001  generator bugs too
            r = dict(id=int(i), tags=[], outcome="fail", failures=["exception"],
                     message=f"{type(e).__name__}: {e}", traceback=traceback.format_exc()[-2000:])
        conn.send(("result", r))


class _Slot:
    def __init__(self, ctx, threads):
        self.ctx, self.threads = ctx, threads
        self.start()

    def start(self):
        self.conn, child = self.ctx.Pipe()
        self.proc = self.ctx.Process(target=_worker, args=(child, self.threads), daemon=True)
        self.proc.start()
        child.close()
        self.ready = False
        self.case = None
        self.since = time.monotonic()

    def kill(self):
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)
        self.conn.close()


def run_cases(ids, workers=2, timeout=60.0, warmup_timeout=1800.0, threads=1, log=None):
    """Runs the case ids in worker processes; returns (results list, seconds)."""
    # forkserver: a child forked from a process that ran numba's OpenMP threads
    # is terminated by numba (GNU OpenMP is not fork-safe), and pytest runs
    # this after other kernels; the server process has run none
    ctx = mp.get_context("forkserver")
    todo = list(ids)[::-1]
    results = {}
    n_slots = max(1, min(workers, len(todo) or 1))
    slots = [_Slot(ctx, threads)]
    t0 = time.monotonic()
    restarts = 0
    try:
        while len(results) < len(ids):
            if len(slots) < n_slots and slots[0].ready:
                # the first worker compiled and cached every kernel: the others only load them
                slots += [_Slot(ctx, threads) for _ in range(n_slots - len(slots))]
            for s in slots:
                if s.case is None and s.ready and todo:
                    s.case = todo.pop()
                    s.since = time.monotonic()
                    s.conn.send(s.case)
            progressed = False
            for s in slots:
                if s.conn.poll(0.02):
                    progressed = True
                    try:
                        kind, payload = s.conn.recv()
                    except (EOFError, OSError):
                        kind, payload = "died", None
                    if kind == "ready":
                        s.ready = True
                    elif kind == "result":
                        results[payload["id"]] = payload
                        s.case = None
                        if log:
                            log(payload)
                    elif kind == "warmup_failed":
                        raise RuntimeError(f"worker warm-up failed: {payload}")
                    if kind == "died":
                        _died(s, results, log)
                        restarts += 1
                elif not s.proc.is_alive() and not s.conn.poll(0):
                    _died(s, results, log)
                    restarts += 1
                    progressed = True
                else:
                    limit = timeout if s.ready else warmup_timeout
                    if time.monotonic() - s.since > limit:
                        if s.case is not None:
                            results[s.case] = dict(id=s.case, tags=[], outcome="fail", failures=["timeout"],
                                                   message=f"no result after {limit:.0f} s")
                            if log:
                                log(results[s.case])
                        s.kill()
                        s.start()
                        restarts += 1
            if not progressed:
                time.sleep(0.005)
    finally:
        for s in slots:
            try:
                s.conn.send(None)
            except (OSError, BrokenPipeError):
                pass
            s.proc.join(2)
            s.kill()
    return [results[i] for i in ids], time.monotonic() - t0


def _died(s, results, log):
    code = s.proc.exitcode if not s.proc.is_alive() else None
    s.proc.join(5)
    code = s.proc.exitcode
    if s.case is not None:
        sig = f"signal {-code}" if code is not None and code < 0 else f"exit code {code}"
        results[s.case] = dict(id=s.case, tags=[], outcome="fail", failures=["crash"],
                               message=f"worker died ({sig})")
        if log:
            log(results[s.case])
    elif not s.ready:
        raise RuntimeError(f"worker died during warm-up (exit code {code})")
    s.kill()
    s.start()


def summarize(results, seconds, start):
    counts = Counter()
    ids = defaultdict(list)
    outcomes = Counter(r["outcome"] for r in results)
    for r in results:
        for f in dict.fromkeys(r["failures"]):
            counts[f] += 1
            ids[f].append(r["id"])
    tag_counts = Counter(t for r in results for t in r.get("tags", []))
    return dict(cases=len(results), start=start, seconds=round(seconds, 2),
                outcomes=dict(outcomes),
                failures={k: counts.get(k, 0) for k in FAILURE_CLASSES},
                failure_ids={k: v for k, v in ids.items()},
                messages={r["id"]: r["message"] for r in results if r["failures"]},
                scene_errors=Counter(r["message"].split(":")[-1].strip()[:60] for r in results
                                     if r["outcome"] == "scene_error").most_common(15),
                tags=dict(tag_counts))


# --------------------------------------------------------------------------------------
# Blender path sample
# --------------------------------------------------------------------------------------

BLENDER_SCRIPT = r'''
import sys, math, random, traceback, json
import numpy as np
import bpy
sys.path.insert(0, {parent!r})
import photon_lightmaps
from photon_lightmaps import registration
registration.register()
out = []
for case in {cases!r}:
    rnd = random.Random(case)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    try:
        mesh = bpy.data.meshes.new("m")
        verts = [(rnd.uniform(-1, 1), rnd.uniform(-1, 1), rnd.uniform(-1, 1)) for _ in range(8)]
        verts += [verts[0], ((verts[0][0]+verts[1][0])/2, (verts[0][1]+verts[1][1])/2, (verts[0][2]+verts[1][2])/2)]
        faces = [(0, 1, 2), (0, 1, 9), (0, 8, 3), (3, 4, 5, 6), (4, 5, 7), (4, 5, 7)]
        mesh.from_pydata(verts, [], faces)
        ob = bpy.data.objects.new("fuzz_mesh", mesh)
        sc.collection.objects.link(ob)
        ob.scale = (rnd.choice([1.0, 1e-6, 1e6, -1.0]),) * 3
        if rnd.random() < 0.6:
            bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0, 0, 0))
            cube = bpy.context.active_object
            mod = cube.modifiers.new("bool", "BOOLEAN")
            mod.operation = rnd.choice(["UNION", "DIFFERENCE", "INTERSECT"])
            r = rnd.random()
            if r < 0.3:
                mod.object = None
            elif r < 0.6:
                mod.operand_type = "COLLECTION"
                mod.collection = bpy.data.collections.new("empty_operands")
            else:
                mod.object = ob
        if rnd.random() < 0.4:
            e = bpy.data.objects.new("ol_empty", None)
            sc.collection.objects.link(e)
        if rnd.random() < 0.8:
            ld = bpy.data.lights.new("L", rnd.choice(["POINT", "SUN", "SPOT", "AREA"]))
            ld.energy = rnd.choice([0.0, 100.0, 1e30, 1e-30])
            lo = bpy.data.objects.new("L", ld)
            lo.location = (rnd.uniform(-2, 2), rnd.uniform(-2, 2), rnd.uniform(0, 3))
            sc.collection.objects.link(lo)
        if rnd.random() < 0.8:
            cd = bpy.data.cameras.new("C")
            co = bpy.data.objects.new("C", cd)
            co.location = (0, -6, 1)
            co.rotation_euler = (math.radians(85), 0, 0)
            sc.collection.objects.link(co)
            sc.camera = co
        sc.render.resolution_x = 16
        sc.render.resolution_y = 16
        sc.render.resolution_percentage = 100
        sc.render.engine = "PHOTON_LIGHTMAPS"
        props = getattr(sc, "photon_lightmaps", None)
        if props is not None:
            for k, v in (("photons", 2000), ("samples", 1)):
                if hasattr(props, k):
                    setattr(props, k, v)
        bpy.ops.render.render(write_still=False)
        out.append(dict(case=case, ok=True))
    except Exception as ex:
        out.append(dict(case=case, ok=False, error=type(ex).__name__ + ": " + str(ex)[:200],
                        tb=traceback.format_exc()[-1500:]))
print("FUZZ_RESULT " + json.dumps(out))
'''


def run_blender(n, start=0, timeout=600.0):
    """N random bpy scenes rendered in a subprocess (a crash there is recorded, not fatal)."""
    import subprocess
    cases = list(range(start, start + n))
    code = BLENDER_SCRIPT.format(parent=str(ROOT.parent), cases=cases)
    t0 = time.monotonic()
    try:
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return dict(cases=n, crash=0, timeout=1, tracebacks=0, seconds=time.monotonic() - t0, results=[])
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("FUZZ_RESULT ")]
    results = json.loads(line[-1][12:]) if line else []
    crashed = not line
    tb_in_log = "Traceback (most recent call last)" in p.stderr
    return dict(cases=n, crash=int(crashed), returncode=p.returncode,
                exceptions=sum(1 for r in results if not r["ok"]),
                stderr_tracebacks=int(tb_in_log), seconds=round(time.monotonic() - t0, 1),
                results=[r for r in results if not r["ok"]],
                stderr_tail=p.stderr[-3000:] if (crashed or tb_in_log) else "")


# --------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------

def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=200)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per case")
    ap.add_argument("--threads", type=int, default=1, help="numba threads per worker")
    ap.add_argument("--json", help="write the summary here")
    ap.add_argument("--case", type=int, help="run one case in-process and show the traceback")
    ap.add_argument("--blender", type=int, default=0, help="also N random scenes through bpy")
    ap.add_argument("-v", "--verbose", action="store_true")
    a = ap.parse_args(argv)
    if a.case is not None:
        scene, tags, st = make_case(a.case)
        print("tags:", tags, "\nsettings:", st)
        if a.verbose:
            print(scene)
        from photon_lightmaps.engine.core.scene import SceneError
        res = dict(id=a.case, tags=tags, outcome="ok", failures=[], message="")
        try:
            _check_case(scene, st, res)
        except SceneError as e:
            print("SceneError (accepted):", e)
            return 0
        print("failures:", res["failures"], res["message"])
        return 1 if res["failures"] else 0
    ids = list(range(a.start, a.start + a.cases))
    done = [0]

    def log(r):
        done[0] += 1
        if r["failures"]:
            print(f"case {r['id']}: {','.join(r['failures'])}: {r['message'][:200]}", flush=True)
        if done[0] % 500 == 0:
            print(f"... {done[0]}/{len(ids)}", flush=True)

    results, secs = run_cases(ids, a.workers, a.timeout, threads=a.threads, log=log)
    summ = summarize(results, secs, a.start)
    if a.blender:
        summ["blender"] = run_blender(a.blender, a.start)
    print(json.dumps({k: summ[k] for k in ("cases", "seconds", "outcomes", "failures")}, indent=1))
    for k, v in summ["failure_ids"].items():
        print(f"{k}: {v[:50]}{' ...' if len(v) > 50 else ''}")
    if a.blender:
        b = summ["blender"]
        print("blender:", {k: b[k] for k in b if k not in ("results", "stderr_tail")})
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(summ, indent=1, default=str))
    return 1 if any(summ["failures"].values()) else 0


if __name__ == "__main__":
    sys.exit(main())
