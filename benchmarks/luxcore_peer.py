"""LuxCore (pyluxcore) as a peer renderer: its path tracer, with and without the
PhotonGI indirect cache, on the benchmark scenes.

The parent (a bpy process) exports the evaluated scene to a folder: world-space
triangles in an .npz, the rest (materials, lights, camera, film, render settings)
as JSON. A worker process (`python benchmarks/luxcore_peer.py --worker DIR`)
builds the LuxCore scene from it, renders and writes `image.npy` + `stats.json`.
The worker is a separate process because pyluxcore crashes at interpreter exit
(and it keeps LuxCore's threads off the bpy process).

Units (Cycles' conventions, see engine/shading/lights.py; LuxCore's from its sources,
src/slg/lights/*.cpp, and checked numerically by tests/test_luxcore_peer.py):

* point, P W: LuxCore's point light radiates gain * color / (4 pi) W/sr, so gain = P;
* spot, P W: LuxCore's spot radiates gain * color * falloff W/sr (no 1 / (4 pi)),
  so gain = P / (4 pi);
  its falloff ((cos - cos_total) / (cos_start - cos_total))^4 is not Blender's
  smoothstep, so coneangle = spot_size / 2 and the ring is made 5/8 as wide in
  cos as Blender's: same cone edge and same power, a different profile;
* sun, S W/m^2 (irradiance on a surface facing it): a `distant` light of
  half-angle theta = angle / 2 has radiance gain * color over its cone, so
  gain = S / (2 pi (1 - cos theta)) (`sharpdistant`, gain = S, for angle 0);
* area, P W over area A: an emissive mesh (one-sided, facing the light's -Z) of
  radiance L = P / (pi A), invisible to the camera like Cycles' lights here and
  transparent to every other ray (Blender's lights are not geometry);
* the world's constant colour: a `constantinfinite` light of that radiance.

Materials are the benchmark scenes' Lambertian Principled BSDFs (Specular IOR
Level 0): matte with the Base Color. Metallic, transmission and specular are
not exported (a warning says so).
"""
import json
import math
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import numpy as np

MAX_BOUNCES = 8   # methods.MAX_BOUNCES; not imported so the worker needs no bpy
# Measured on cornell (image means within 0.2 %): LuxCore's path depth d gives
# Cycles' max_bounces = d - 2 (depths 1 and 2 both give direct light only).
LUX_DEPTH = MAX_BOUNCES + 2
MODES = ("path", "photongi")
SCREEN_SHIFT_Y = -1.0   # pixels; see _scene_props


def available():
    """pyluxcore importable (checked without importing it: the import itself is safe,
    but interpreter exit after using it is not)."""
    import importlib.util
    return importlib.util.find_spec("pyluxcore") is not None


# --------------------------------------------------------------------------------------
# Export (parent, bpy)
# --------------------------------------------------------------------------------------

def _principled(mat):
    if mat is None or mat.node_tree is None:
        return None
    return next((n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled"), None)


def _material(mat, warn):
    """Lambertian Base Color (+ emission) of a Blender material, as the scenes use them."""
    p = _principled(mat)
    if p is None:
        kd = list(mat.diffuse_color[:3]) if mat is not None else [0.8, 0.8, 0.8]
        return dict(kd=kd, emission=[0.0, 0.0, 0.0])
    kd = list(p.inputs["Base Color"].default_value[:3])
    for socket in ("Metallic", "Transmission Weight", "Specular IOR Level"):
        if p.inputs[socket].default_value > 0.0:
            warn(f"material '{mat.name}': {socket} > 0 is not exported (matte only)")
    s = float(p.inputs["Emission Strength"].default_value)
    em = [s * c for c in p.inputs["Emission Color"].default_value[:3]]
    return dict(kd=kd, emission=em)


def _area_polygon(lt):
    """Corners (local, z = 0) of an area light's shape, ordered so that the triangle
    fan's normal is local -Z, the side Blender's area lights emit on."""
    sx = float(lt.size)
    sy = sx if lt.shape in ("SQUARE", "DISK") else float(lt.size_y)
    if lt.shape in ("DISK", "ELLIPSE"):
        a = np.linspace(0.0, 2.0 * math.pi, 64, endpoint=False)
        pts = np.stack([0.5 * sx * np.cos(a), 0.5 * sy * np.sin(a), np.zeros_like(a)], 1)
    else:
        pts = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float) * [0.5 * sx, 0.5 * sy, 0]
    return pts[::-1]   # clockwise seen from +Z: the fan's normal points to -Z


def export_scene(depsgraph, warn=lambda m: print("luxcore_peer:", m, file=sys.stderr)):
    """The evaluated bpy scene -> (spec dict, arrays dict) for the worker."""
    scene = depsgraph.scene
    spec = dict(materials={}, meshes=[], lights=[], world=[0.0, 0.0, 0.0])
    arrays = {}

    def add_mesh(verts, tris, mat_name, camera_invisible=False):
        i = len(spec["meshes"])
        arrays[f"v{i}"] = np.ascontiguousarray(verts, np.float32)
        arrays[f"f{i}"] = np.ascontiguousarray(tris, np.int32)
        spec["meshes"].append(dict(name=f"mesh{i}", material=mat_name, camera_invisible=camera_invisible))

    for inst in depsgraph.object_instances:
        ob = inst.object
        M = np.array(inst.matrix_world, np.float64)
        if ob.type == "MESH":
            me = ob.to_mesh()
            me.calc_loop_triangles()
            nv, nt = len(me.vertices), len(me.loop_triangles)
            co = np.empty(nv * 3, np.float32)
            me.vertices.foreach_get("co", co)
            tv = np.empty(nt * 3, np.int32)
            me.loop_triangles.foreach_get("vertices", tv)
            mi = np.empty(nt, np.int32)
            me.loop_triangles.foreach_get("material_index", mi)
            wv = co.reshape(-1, 3).astype(np.float64) @ M[:3, :3].T + M[:3, 3]
            tv = tv.reshape(-1, 3)
            slots = [s.material for s in ob.material_slots] or [None]
            for k in np.unique(mi):
                mat = slots[min(int(k), len(slots) - 1)]
                name = mat.name if mat is not None else "__default"
                if name not in spec["materials"]:
                    spec["materials"][name] = _material(mat, warn)
                add_mesh(wv, tv[mi == k], name)
            ob.to_mesh_clear()
        elif ob.type == "LIGHT":
            lt = ob.data
            color = np.asarray(lt.color, float)
            if lt.use_temperature:
                color = color * np.asarray(lt.temperature_color, float)
            power = float(lt.energy) * 2.0 ** float(lt.exposure)
            if not lt.normalize:
                warn(f"light '{ob.name}': normalize=False is exported as normalized")
            pos = M[:3, 3].tolist()
            down = -M[:3, 2] / np.linalg.norm(M[:3, 2])
            if lt.type == "POINT":
                spec["lights"].append(dict(type="point", position=pos, color=color.tolist(), gain=power))
            elif lt.type == "SPOT":
                half = 0.5 * float(lt.spot_size)
                cos_half = math.cos(half)
                # Blender's ring, cos_half .. cos_half + smooth with smooth = (1 - cos_half)
                # * blend, averages 1/2 (smoothstep); LuxCore's delta^4 averages 1/5 over
                # its ring. A ring 5/8 as wide in cos keeps the cone edge and the power.
                smooth = (1.0 - cos_half) * min(max(float(lt.spot_blend), 0.0), 1.0)
                cos_in = min(cos_half + 0.625 * smooth, 1.0)
                spec["lights"].append(dict(
                    type="spot", position=pos, target=(M[:3, 3] + down).tolist(), color=color.tolist(),
                    gain=power / (4.0 * math.pi), coneangle=math.degrees(half),
                    conedeltaangle=math.degrees(half - math.acos(cos_in))))
            elif lt.type == "SUN":
                half = 0.5 * float(lt.angle)
                if half > 1e-6:
                    # `distant` has radiance gain * color over its cone: divide by the cone's solid angle.
                    spec["lights"].append(dict(type="distant", direction=down.tolist(), color=color.tolist(),
                                               gain=power / (2.0 * math.pi * (1.0 - math.cos(half))),
                                               theta=math.degrees(half)))
                else:
                    spec["lights"].append(dict(type="sharpdistant", direction=down.tolist(),
                                               color=color.tolist(), gain=power))
            elif lt.type == "AREA":
                local = _area_polygon(lt)
                wv = local @ M[:3, :3].T + M[:3, 3]
                n = len(wv)
                tris = np.stack([np.zeros(n - 2, int), np.arange(1, n - 1), np.arange(2, n)], 1)
                e = np.cross(wv[tris[:, 1]] - wv[tris[:, 0]], wv[tris[:, 2]] - wv[tris[:, 0]])
                area = 0.5 * float(np.linalg.norm(e, axis=1).sum())
                name = f"__light_{ob.name}"
                spec["materials"][name] = dict(kd=[0.0, 0.0, 0.0],
                                               emission=(color * power / (math.pi * area)).tolist(),
                                               light=True)
                add_mesh(wv, tris, name, camera_invisible=not ob.visible_camera)
            else:
                warn(f"light '{ob.name}': type {lt.type} not exported")
    w = scene.world
    if w is not None:
        col = np.asarray(w.color, float)
        bg = None
        if w.node_tree is not None:
            bg = next((n for n in w.node_tree.nodes if n.bl_idname == "ShaderNodeBackground"), None)
        if bg is not None:
            col = np.asarray(bg.inputs["Color"].default_value[:3], float) * float(bg.inputs["Strength"].default_value)
        spec["world"] = col.tolist()
    spec["camera"] = _camera(scene)
    r = scene.render
    spec["width"] = int(r.resolution_x * r.resolution_percentage / 100)
    spec["height"] = int(r.resolution_y * r.resolution_percentage / 100)
    return spec, arrays


def _camera(scene):
    cam_ob = scene.camera
    cam = cam_ob.data
    M = np.array(cam_ob.matrix_world, np.float64)
    r = scene.render
    w, h = r.resolution_x, r.resolution_y
    fwd = -M[:3, 2] / np.linalg.norm(M[:3, 2])
    up = M[:3, 1] / np.linalg.norm(M[:3, 1])
    # Blender's AUTO sensor fit puts cam.angle on the longer side; LuxCore's
    # fieldofview is the shorter side's.
    fit_long = cam.sensor_fit == "AUTO" or (cam.sensor_fit == "HORIZONTAL") == (w >= h)
    t = math.tan(0.5 * cam.angle) * (min(w, h) / max(w, h) if fit_long else 1.0)
    if cam.type != "PERSP":
        raise ValueError("luxcore_peer: only perspective cameras are exported")
    return dict(orig=M[:3, 3].tolist(), target=(M[:3, 3] + fwd).tolist(), up=up.tolist(),
                fov=math.degrees(2.0 * math.atan(t)))


# --------------------------------------------------------------------------------------
# Render (parent): write, run the worker, read back
# --------------------------------------------------------------------------------------

def render_spec(spec, arrays, mode="photongi", spp=None, halttime=None, seed=11, threads=0,
                photongi=None, timeout=900):
    """Renders an exported scene in a worker process.

    Returns (image (H, W, 3) linear, rows top-down; stats dict with seconds (LuxCore
    scene build + cache + render, measured in the worker), seconds_render (LuxCore's
    own render time), seconds_cache, seconds_wall (whole subprocess), spp)."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}")
    job = dict(spec, render=dict(mode=mode, spp=spp, halttime=halttime, seed=int(seed), threads=int(threads),
                                 photongi=photongi or {}))
    with tempfile.TemporaryDirectory(prefix="luxcore_") as d:
        d = pathlib.Path(d)
        np.savez(d / "meshes.npz", **arrays)
        (d / "spec.json").write_text(json.dumps(job))
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, str(pathlib.Path(__file__).resolve()), "--worker", str(d)],
                              capture_output=True, text=True, timeout=timeout)
        wall = time.perf_counter() - t0
        if not (d / "image.npy").exists():
            raise RuntimeError(f"LuxCore worker failed (rc {proc.returncode}):\n{proc.stderr[-3000:]}")
        img = np.load(d / "image.npy")
        stats = json.loads((d / "stats.json").read_text())
    stats["seconds_wall"] = wall
    return img, stats


def render_current(mode="photongi", spp=None, halttime=None, seed=11, **kw):
    """Exports bpy's current scene and renders it -> (image, seconds, stats)."""
    import bpy
    spec, arrays = export_scene(bpy.context.evaluated_depsgraph_get())
    img, stats = render_spec(spec, arrays, mode, spp=spp, halttime=halttime, seed=seed, **kw)
    return img, stats["seconds"], stats


# --------------------------------------------------------------------------------------
# Worker (pyluxcore)
# --------------------------------------------------------------------------------------

def _props(lx, items):
    p = lx.Properties()
    for k, v in items.items():
        p.Set(lx.Property(k, v))
    return p


def _scene_props(spec):
    P = {}
    # Blender names may hold dots, LuxCore's property separator: number them instead.
    ids = {name: f"mat{i}" for i, name in enumerate(spec["materials"])}
    for name, m in spec["materials"].items():
        pre = f"scene.materials.{ids[name]}"
        P[pre + ".type"] = "matte"
        P[pre + ".kd"] = [float(x) for x in m["kd"]]
        if any(e > 0 for e in m["emission"]):
            P[pre + ".emission"] = [float(x) for x in m["emission"]]
            # Radiance = emission * gain: no power/efficacy normalisation.
            P[pre + ".emission.gain"] = [1.0, 1.0, 1.0]
            P[pre + ".emission.power"] = 0.0
            P[pre + ".emission.efficency"] = 0.0
        if m.get("light"):
            # Blender's lights are not geometry: other rays pass through the emitter
            # (transparency 0 = fully transparent; without it the ceiling above
            # cornell's light is shadowed, -2 % in the image mean).
            P[pre + ".transparency.front"] = 0.0
            P[pre + ".transparency.back"] = 0.0
    for m in spec["meshes"]:
        pre = f"scene.objects.{m['name']}"
        P[pre + ".shape"] = m["name"]
        P[pre + ".material"] = ids[m["material"]]
        if m["camera_invisible"]:
            P[pre + ".camerainvisible"] = 1
    for i, lt in enumerate(spec["lights"]):
        pre = f"scene.lights.l{i}"
        P[pre + ".type"] = lt["type"]
        P[pre + ".color"] = [float(x) for x in lt["color"]]
        P[pre + ".gain"] = [float(lt["gain"])] * 3
        P[pre + ".power"] = 0.0
        P[pre + ".efficency"] = 0.0
        for k in ("position", "target", "direction", "coneangle", "conedeltaangle", "theta"):
            if k in lt:
                P[pre + "." + k] = lt[k]
    if any(c > 0 for c in spec["world"]):
        P["scene.lights.world.type"] = "constantinfinite"
        P["scene.lights.world.color"] = [float(x) for x in spec["world"]]
        P["scene.lights.world.gain"] = [1.0, 1.0, 1.0]
    c = spec["camera"]
    P.update({"scene.camera.type": "perspective", "scene.camera.lookat.orig": c["orig"],
              "scene.camera.lookat.target": c["target"], "scene.camera.up": c["up"],
              "scene.camera.fieldofview": float(c["fov"])})
    # Measured on cornell against Cycles: with the default screen window LuxCore's
    # image sits one pixel row low (every horizontal edge, none of the vertical ones).
    sy = 2.0 * float(spec.get("screen_shift_y", SCREEN_SHIFT_Y)) / float(min(spec["width"], spec["height"]))
    if sy:
        ax = spec["width"] / spec["height"]
        bx, by = (ax, 1.0) if ax >= 1.0 else (1.0, 1.0 / ax)
        P["scene.camera.screenwindow"] = [-bx, bx, -by + sy, by + sy]
    # Raw LuxCore scene properties for experiments (e.g. the transparency checks).
    for k, v in spec.get("extra", {}).items():
        P[k] = v
    return P


def _config_props(spec):
    r = spec["render"]
    P = {"renderengine.type": "PATHCPU", "sampler.type": "SOBOL", "renderengine.seed": int(r["seed"]),
         "film.width": int(spec["width"]), "film.height": int(spec["height"]),
         # A one-pixel box (LuxCore's width is the half-width), like Cycles here.
         "film.filter.type": "BOX", "film.filter.width": 0.5,
         "path.pathdepth.total": LUX_DEPTH, "path.pathdepth.diffuse": LUX_DEPTH,
         "path.pathdepth.glossy": LUX_DEPTH, "path.pathdepth.specular": LUX_DEPTH,
         "path.clamping.variance.maxvalue": 0.0, "path.forceblackbackground.enable": 0,
         # The film's OpenCL probe costs 1.5-2.5 s per render on a machine without OpenCL.
         "film.opencl.enable": 0,
         }
    if r["threads"]:
        P["native.threads.count"] = int(r["threads"])
    if r["spp"]:
        P["batch.haltspp"] = int(r["spp"])
    if r["halttime"]:
        P["batch.halttime"] = float(r["halttime"])
    if r["mode"] == "photongi":
        P.update({"path.photongi.indirect.enabled": 1, "path.photongi.caustic.enabled": 0,
                  "path.photongi.photon.maxdepth": LUX_DEPTH})
        for k, v in r["photongi"].items():
            P["path.photongi." + k] = v
    return P


def worker(d):
    import pyluxcore as lx
    d = pathlib.Path(d)
    spec = json.loads((d / "spec.json").read_text())
    log = []
    lx.Init(lambda s: log.append(s))
    t0 = time.perf_counter()
    scene = lx.Scene()
    with np.load(d / "meshes.npz") as z:
        for i, m in enumerate(spec["meshes"]):
            v, f = z[f"v{i}"].astype(float), z[f"f{i}"].astype(int)
            # DefineMesh takes Python sequences, not arrays (pyluxcore 2.11).
            scene.DefineMesh(m["name"], list(map(tuple, v.tolist())), list(map(tuple, f.tolist())),
                             None, None, None, None)
    scene.Parse(_props(lx, _scene_props(spec)))
    cfg = lx.RenderConfig(_props(lx, _config_props(spec)), scene)
    session = lx.RenderSession(cfg)
    t1 = time.perf_counter()
    session.Start()   # blocks while the PhotonGI cache is built
    t2 = time.perf_counter()
    while not session.HasDone():
        time.sleep(0.01)
        session.UpdateStats()
    t3 = time.perf_counter()
    session.UpdateStats()
    st = session.GetStats()
    w, h = int(spec["width"]), int(spec["height"])
    buf = np.zeros(w * h * 3, np.float32)
    session.GetFilm().GetOutputFloat(lx.FilmOutputType.RGB, buf)
    spp = st.Get("stats.renderengine.pass").GetInt()
    lux_time = st.Get("stats.renderengine.time").GetFloat()
    session.Stop()
    # LuxCore's film rows run bottom-up.
    np.save(d / "image.npy", buf.reshape(h, w, 3)[::-1].copy())
    (d / "stats.json").write_text(json.dumps(dict(
        seconds=t3 - t0, seconds_setup=t1 - t0, seconds_cache=t2 - t1, seconds_render=lux_time,
        spp=int(spp), log_tail=log[-20:])))


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        rc = 0
        try:
            worker(sys.argv[2])
        except BaseException:
            import traceback
            traceback.print_exc()
            rc = 1
        sys.stdout.flush()
        sys.stderr.flush()
        # pyluxcore crashes in interpreter shutdown: leave without it.
        os._exit(rc)
    print(__doc__)
