"""Baking orientation lightmaps (thesis ch. 6) to images, and showing them in EEVEE.

One photon pass with direct light recorded (like Cycles' Diffuse bake,
Direct + Indirect, no Color) fills every OL's bins; each OL empty then owns
an R×R float RGBA image:

* RGB = E/pi per direction bin, E the irradiance of the bin, after the
  hierarchy rule of the renderer (engine/orientation_lightmap.lookup): a bin
  with too few photons (relative error above 1/sqrt(min_hits)) shows the
  enclosing OL's value, so the image is what the renderer reads.
* A = 1 where the bin has surface (estimated area > 0), 0 elsewhere.

Pixel (x, y) is bin (x, y), rows bottom-up, at the octahedral coordinates of
the world normal (engine/primitives._octa_encode). Images are named
"<empty>_Lightmap" and follow bake.py's policy exactly (bake._target_image:
ours are updated in place, a user's image of that name is kept unless
`overwrite`), and are saved like bake.py's (EXR via bake.write_exr).

Material hook: every material of the objects an OL covers (innermost OL,
non-backup) gets a frame of nodes: the shared group "Photon Orientation
Lightmap" turns the Geometry node's world normal into the octahedral (s, t)
with math nodes, an Image Texture (Linear, Extend) reads the OL image there,
and bake.py's "Photon Lightmap" group multiplies by the base colour into an
EEVEE-only Material Output. No UV layer is needed. Our nodes carry bake.py's
hook tag (so bake.py's output search and Remove Lightmap Hook treat them as
ours) plus OL_HOOK_PROP = the empty's name, which `remove_ol_hook` uses to
delete exactly them.

REPORTS keeps the last render's or bake's per-OL numbers for the panel.
"""
import json
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from . import bake as B
from .engine import lightmap as LM
from .engine import orientation_lightmap as OL
from .engine.scene import SceneError

OL_IMAGE_PROP = "photon_lightmaps_ol"        # on images we baked for an OL (value: empty name)
OL_HOOK_PROP = "photon_lightmaps_ol_hook"    # on our nodes (value: empty name) and on the group (1)
OL_GROUP = "Photon Orientation Lightmap"
OL_PREFIX = "Photon Orientation Lightmap"
REPORT_PROP = "photon_lightmaps_ol_report"   # JSON of the last bake's row, on the empty

# (scene name, empty name) -> summary dict of the last render or bake
REPORTS = {}


# --------------------------------------------------------------------------------------
# Reports
# --------------------------------------------------------------------------------------

def summarize(row, names, source):
    """The JSON-safe part of an orientation_lightmap.report() row."""
    p = int(row["parent"])
    return {"name": row["name"], "parent": names[p] if p >= 0 else None, "backup": bool(row["backup"]),
            "resolution": int(row["resolution"]), "bins": int(row["bins"]),
            "bins_with_area": int(row["bins_with_area"]), "instances": int(row["instances"]),
            "photons": int(row["photons"]), "memory_bytes": int(row["memory_bytes"]),
            "area": float(row["area"]),
            "area_rel_error": float(row["area_rel_error"]) if math.isfinite(row["area_rel_error"]) else None,
            "openness": float(row["openness"]), "samples": int(row["samples"]),
            "area_seconds": float(row["area_seconds"]), "warnings": list(row["warnings"]),
            "source": source}


def record_report(cs, scene_name, source, report=None):
    """Summaries of every OL of a traced compiled scene; kept in REPORTS, warnings reported."""
    rows = OL.report(cs)
    names = [r["name"] for r in rows]
    out = [summarize(r, names, source) for r in rows]
    for s in out:
        REPORTS[(scene_name, s["name"])] = s
        if report is not None:
            for w in s["warnings"]:
                report("WARNING", w)
    return out


def last_report(scene_name, ob):
    """The last render's or bake's summary for OL empty `ob` (None if never run)."""
    s = REPORTS.get((scene_name, ob.name))
    if s is None and ob.get(REPORT_PROP):
        try:
            s = json.loads(ob[REPORT_PROP])
        except (TypeError, ValueError):
            s = None
    return s


# --------------------------------------------------------------------------------------
# Bins -> pixels
# --------------------------------------------------------------------------------------

def _rel_error(lm):
    f = lm.flux.mean(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(f > 0.0, np.sqrt(lm.flux_sq) / np.where(f > 0.0, f, 1.0), np.inf)


def ol_rgba(cs, k):
    """OL k of a traced compiled scene as float32 (R, R, 4): RGB = E/pi after the
    hierarchy rule (noisy bins read the enclosing level), A = bin has area."""
    lm, ol = cs.lightmaps, cs.orientation
    rel = _rel_error(lm)
    sl0 = LM.texel_slice(lm, int(ol.lid[k]))
    n = sl0.stop - sl0.start
    r = int(lm.width[int(ol.lid[k])])
    idx = np.arange(n)
    level = np.full(n, k, np.int64)
    # Walk up per bin exactly like OL.lookup: stop where the bin is good enough or at the top.
    for _ in range(OL.MAX_LEVELS + 1):
        start = ol.lid[level]
        ti = lm.offset[start] + idx
        up = (ol.parent[level] >= 0) & (rel[ti] > ol.max_rel_error[level])
        if not up.any():
            break
        level = np.where(up, ol.parent[level], level)
    ti = lm.offset[ol.lid[level]] + idx
    e = lm.irradiance[ti].copy()
    # EEVEE looks bins up by smooth shading normals, which reach bins that no
    # flat face normal has: those take the value of the nearest bin in angle.
    empty = lm.state[ti] == LM.STATE_EMPTY
    full = ~empty
    if empty.any() and full.any():
        c = (np.arange(r) + 0.5) / r
        d = octa_decode(np.tile(c, r), np.repeat(c, r))
        for chunk in np.array_split(np.flatnonzero(empty), max(1, int(empty.sum()) // 4096)):
            near = np.flatnonzero(full)[np.argmax(d[chunk] @ d[full].T, axis=1)]
            e[chunk] = e[near]
    rgba = np.zeros((n, 4), np.float32)
    rgba[:, :3] = (e if e.shape[1] == 3 else np.repeat(e.mean(axis=1, keepdims=True), 3, axis=1)) / math.pi
    rgba[:, 3] = lm.area[sl0] > 0.0
    return rgba.reshape(r, r, 4)


def octa_decode(s, t):
    """Unit normals (N, 3) at octahedral coordinates (s, t): inverse of octa_st."""
    x, y = 2.0 * np.asarray(s, np.float64) - 1.0, 2.0 * np.asarray(t, np.float64) - 1.0
    z = 1.0 - np.abs(x) - np.abs(y)
    low = z < 0
    sx, sy = np.where(x >= 0, 1.0, -1.0), np.where(y >= 0, 1.0, -1.0)
    x, y = np.where(low, (1 - np.abs(y)) * sx, x), np.where(low, (1 - np.abs(x)) * sy, y)
    n = np.stack([x, y, z], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def octa_st(normals):
    """numpy octahedral (s, t) of unit normals (N, 3): the engine's map (sgn(0) = +1)."""
    n = np.asarray(normals, np.float64)
    l1 = np.abs(n).sum(axis=1)
    x, y = n[:, 0] / l1, n[:, 1] / l1
    sx, sy = np.where(x >= 0, 1.0, -1.0), np.where(y >= 0, 1.0, -1.0)
    low = n[:, 2] < 0
    fx, fy = (1 - np.abs(y)) * sx, (1 - np.abs(x)) * sy
    x, y = np.where(low, fx, x), np.where(low, fy, y)
    return np.clip(0.5 * (x + 1), 0, 1), np.clip(0.5 * (y + 1), 0, 1)


def sample_bilinear(rgba, s, t):
    """What an Image Texture node (Linear, Extend) returns at (s, t): texel centres at (i+0.5)/R."""
    h, w = rgba.shape[:2]
    fx, fy = np.asarray(s) * w - 0.5, np.asarray(t) * h - 0.5
    x0, y0 = np.floor(fx).astype(int), np.floor(fy).astype(int)
    wx, wy = (fx - x0)[:, None], (fy - y0)[:, None]
    cx = lambda x: np.clip(x, 0, w - 1)  # noqa: E731
    cy = lambda y: np.clip(y, 0, h - 1)  # noqa: E731
    a, b = rgba[cy(y0), cx(x0)], rgba[cy(y0), cx(x0 + 1)]
    c, d = rgba[cy(y0 + 1), cx(x0)], rgba[cy(y0 + 1), cx(x0 + 1)]
    return (a * (1 - wx) + b * wx) * (1 - wy) + (c * (1 - wx) + d * wx) * wy


# --------------------------------------------------------------------------------------
# Bake
# --------------------------------------------------------------------------------------

@dataclass
class OLBakeResult:
    maps: dict = field(default_factory=dict)       # empty name -> rgba (R, R, 4)
    images: dict = field(default_factory=dict)     # empty name -> image name
    paths: dict = field(default_factory=dict)      # empty name -> saved file (None: unsaved/packed)
    covered: dict = field(default_factory=dict)    # empty name -> covered object names (innermost, hooked)
    rows: list = field(default_factory=list)       # summaries (see summarize)
    hooked: list = field(default_factory=list)     # materials given an OL hook
    warnings: list = field(default_factory=list)
    stats: object = None
    seconds: dict = field(default_factory=dict)


def orientation_lightmap_empties(scene):
    from .export import is_orientation_lightmap
    return sorted((ob for ob in scene.objects if is_orientation_lightmap(ob)), key=lambda o: o.name)


def compute(depsgraph, *, photons, seed, max_bounces=8, progress=None):
    """Export + photon pass with direct light recorded -> (compiled scene, export map, stats, warnings)."""
    from .engine.compile import compile_scene
    from .engine.photon_tracer import trace_photons
    from .export import export_scene
    warnings = []
    scene, emap = export_scene(depsgraph, report=lambda level, msg: None)
    warnings.extend(emap.warnings)
    if not scene.orientation_lightmaps:
        raise SceneError(f"scene '{depsgraph.scene.name}': no usable orientation lightmap (add one with "
                         "Object > Add Orientation Lightmap to Collection)")
    # Only the OL bins are baked: per-object lightmaps would cost memory and time for
    # nothing, and recording never changes where photons go.
    for inst in scene.instances:
        inst.lightmap = False
    cs = compile_scene(scene)
    stats = trace_photons(cs, int(photons), seed=int(seed), max_bounces=int(max_bounces),
                          record_direct=True, progress=progress)
    if cs.lights.total_power <= 0.0:
        warnings.append("no photons were traced (no lights): the orientation lightmaps are black")
    return cs, emap, stats, warnings


def bake_orientation_lightmaps(context_or_depsgraph, *, photons=None, seed=None, overwrite=False,
                               save_dir=None, pack=False, hook_materials=True, progress=None):
    """Bakes every OL of the scene to "<empty>_Lightmap" images (and files, and material hooks)."""
    import bpy
    t0 = time.perf_counter()
    depsgraph = B._depsgraph(context_or_depsgraph)
    bscene = depsgraph.scene
    settings = B._settings(bscene)
    photons = settings["photons"] if photons is None else int(photons)
    seed = settings["seed"] if seed is None else int(seed)
    if photons < 0:
        raise SceneError(f"photons: must be 0 or more, got {photons}")
    res = OLBakeResult()
    cs, emap, stats, warns = compute(depsgraph, photons=photons, seed=seed,
                                     max_bounces=settings["max_bounces"], progress=progress)
    res.stats = stats
    res.warnings.extend(warns)
    res.seconds["photon_pass"] = stats.seconds
    scene_name = bscene.name
    res.rows = record_report(cs, scene_name, "bake")
    for row in res.rows:
        res.warnings.extend(row["warnings"])
    # Everything is computed: only now touch images and materials.
    blend_saved = bool(bpy.data.filepath)
    B.check_writable(save_dir or (None if pack or not blend_saved else f"//{B.LIGHTMAP_DIR}"))
    names = [row["empty"] for row in emap.orientation_lightmaps]   # engine OL order
    for k, name in enumerate(names):
        empty = bpy.data.objects.get(name)
        if empty is None:
            continue
        rgba = ol_rgba(cs, k)
        r = rgba.shape[0]
        img = B._target_image(empty, r, r, overwrite, res.warnings)
        img[OL_IMAGE_PROP] = name
        img.pixels.foreach_set(rgba.reshape(-1))
        img.update()
        path = None
        fname = B._file_name(name)
        if save_dir:
            path = os.path.join(os.path.abspath(bpy.path.abspath(save_dir)), fname + ".exr")
            B._save_exr(img, path, relative=False)
        elif pack:
            B._pack_exr(img, f"//{B.LIGHTMAP_DIR}/{fname}.exr")
        elif blend_saved:
            path = bpy.path.abspath(f"//{B.LIGHTMAP_DIR}/{fname}.exr")
            B._save_exr(img, path, relative=True)
        res.maps[name], res.images[name], res.paths[name] = rgba, img.name, path
        summary = next((s for s in res.rows if s["name"] == name), None)
        if summary is not None:
            empty[REPORT_PROP] = json.dumps(summary)
        row = emap.orientation_lightmaps[k]
        covered = sorted({emap.instances[i].object_name for i in row["instances"]
                          if not emap.instances[i].is_instance})
        res.covered[name] = covered
        if hook_materials:
            if empty.photon_lightmaps.ol_backup:
                res.warnings.append(f"orientation lightmap '{name}' is a backup: its objects keep "
                                    "their own lightmaps, so no material hook is added for it")
            else:
                objs = [bpy.data.objects[n] for n in covered if n in bpy.data.objects]
                res.hooked += add_ol_hook(empty, img, objs, res.warnings)
    if res.maps and not (save_dir or pack or blend_saved):
        res.warnings.append("the .blend is not saved yet: the orientation lightmap images live only "
                            "in memory (save the .blend and bake again, or pack them)")
    res.seconds["total"] = time.perf_counter() - t0
    return res


# --------------------------------------------------------------------------------------
# Material hook
# --------------------------------------------------------------------------------------

def _tag(node, role, owner):
    node[B.HOOK_PROP] = role
    node[OL_HOOK_PROP] = owner
    node.name = f"{OL_PREFIX} {role}"
    node.label = node.name
    return node


def ol_group():
    """The shared group: world normal (Geometry node) -> octahedral (s, t, 0), with math nodes."""
    import bpy
    for ng in bpy.data.node_groups:
        if ng.get(OL_HOOK_PROP) and ng.library is None and ng.bl_idname == "ShaderNodeTree":
            return ng
    ng = bpy.data.node_groups.new(OL_GROUP, "ShaderNodeTree")
    ng[OL_HOOK_PROP] = 1
    ng.description = ("Photon Lightmaps: octahedral coordinates of the world-space normal, "
                      "for looking up an orientation lightmap image")
    ng.interface.new_socket("Vector", in_out="OUTPUT", socket_type="NodeSocketVector")
    n, links = ng.nodes, ng.links
    geo = n.new("ShaderNodeNewGeometry")
    sep = n.new("ShaderNodeSeparateXYZ")
    links.new(geo.outputs["Normal"], sep.inputs[0])
    col = [0]

    def math_node(op, a, b=None, c=None):
        m = n.new("ShaderNodeMath")
        m.operation = op
        col[0] += 1
        m.location = (200 + 180 * (col[0] // 6), -120 * (col[0] % 6))
        for sock, v in zip(m.inputs, (a, b, c)):
            if v is None:
                continue
            if isinstance(v, (int, float)):
                sock.default_value = float(v)
            else:
                links.new(v, sock)
        return m.outputs[0]

    nx, ny, nz = sep.outputs[0], sep.outputs[1], sep.outputs[2]
    ax, ay, az = (math_node("ABSOLUTE", c) for c in (nx, ny, nz))
    l1 = math_node("ADD", math_node("ADD", ax, ay), az)
    x, y = math_node("DIVIDE", nx, l1), math_node("DIVIDE", ny, l1)
    # sgn with sgn(0) = +1 (the engine's fold): 1 - 2 * (v < 0)
    sx = math_node("MULTIPLY_ADD", math_node("LESS_THAN", x, 0.0), -2.0, 1.0)
    sy = math_node("MULTIPLY_ADD", math_node("LESS_THAN", y, 0.0), -2.0, 1.0)
    fx = math_node("MULTIPLY", math_node("SUBTRACT", 1.0, math_node("ABSOLUTE", y)), sx)
    fy = math_node("MULTIPLY", math_node("SUBTRACT", 1.0, math_node("ABSOLUTE", x)), sy)
    low = math_node("LESS_THAN", nz, 0.0)
    X = math_node("MULTIPLY_ADD", low, math_node("SUBTRACT", fx, x), x)
    Y = math_node("MULTIPLY_ADD", low, math_node("SUBTRACT", fy, y), y)
    s = math_node("MULTIPLY_ADD", X, 0.5, 0.5)
    t = math_node("MULTIPLY_ADD", Y, 0.5, 0.5)
    comb = n.new("ShaderNodeCombineXYZ")
    links.new(s, comb.inputs[0])
    links.new(t, comb.inputs[1])
    go = n.new("NodeGroupOutput")
    links.new(comb.outputs[0], go.inputs["Vector"])
    geo.location, sep.location = (-300, 0), (-100, 0)
    comb.location, go.location = (1400, 0), (1600, 0)
    return ng


def remove_ol_nodes(mat, owner=None):
    """Deletes our OL nodes (of OL `owner`, or all) from one material -> how many."""
    tree = mat.node_tree
    if tree is None or mat.library is not None:
        return 0
    ours = [nd for nd in tree.nodes if nd.get(OL_HOOK_PROP) and (owner is None or nd[OL_HOOK_PROP] == owner)]
    for nd in ours:
        tree.nodes.remove(nd)
    return len(ours)


def add_ol_hook(empty, image, objects, warnings=None):
    """Adds (or refreshes) the OL lookup in every material of `objects`; returns the material names."""
    import bpy
    warnings = warnings if warnings is not None else []
    coords = ol_group()
    shade = B.hook_group()
    covered = {o.name for o in objects}
    mats = []
    for ob in objects:
        slots = [s.material for s in ob.material_slots]
        if not any(slots):
            warnings.append(f"object '{ob.name}' has no material: no orientation lightmap hook added")
        for m in slots:
            if m is not None and m not in mats:
                mats.append(m)
    done = []
    for mat in mats:
        if mat.library is not None or mat.node_tree is None:
            why = "is linked from a library" if mat.library is not None else "uses no nodes"
            warnings.append(f"material '{mat.name}' {why}: no orientation lightmap hook added")
            continue
        users = sorted({o.name for o in bpy.data.objects
                        if any(s.material == mat for s in o.material_slots)} - covered)
        if users:
            warnings.append(f"material '{mat.name}' is shared with objects outside orientation lightmap "
                            f"'{empty.name}' ({', '.join(users)}): in EEVEE they show its light too; "
                            "give the covered objects their own material")
        tree = mat.node_tree
        other = [nd for nd in tree.nodes if nd.get(B.HOOK_PROP) and nd.get(OL_HOOK_PROP) != empty.name]
        if other:
            warnings.append(f"material '{mat.name}': its earlier Photon Lightmap hook was replaced by "
                            f"orientation lightmap '{empty.name}' (one material shows one baked light)")
        B.remove_hook_nodes(mat)
        out = B._user_output(tree)
        surface = B._source(out.inputs["Surface"]) if out is not None else None
        x0, y0 = (out.location.x, out.location.y - 400) if out is not None else (300, -400)
        frame = _tag(tree.nodes.new("NodeFrame"), "Frame", empty.name)
        frame.label = (f"Orientation lightmap '{empty.name}' (baked light by normal, EEVEE only; "
                       "removed with Remove Orientation Lightmap)")
        grp_c = _tag(tree.nodes.new("ShaderNodeGroup"), "Coordinates", empty.name)
        grp_c.node_tree = coords
        grp = B.hook_nodes(tree, frame, (x0, y0), grp_c, grp_c.outputs["Vector"], image, shade, out,
                           surface, lambda nd, role: _tag(nd, role, empty.name))
        B._link_base_color(tree, surface, grp, mat, warnings)
        done.append(mat.name)
    return done


def remove_ol_hook(owner=None, materials=None):
    """Removes OL hook nodes (of OL `owner`, or all) from `materials` (default: all);
    drops our node groups when nothing uses them. -> nodes removed."""
    import bpy
    mats = bpy.data.materials if materials is None else materials
    removed = sum(remove_ol_nodes(m, owner) for m in mats)
    for ng in list(bpy.data.node_groups):
        if ng.get(OL_HOOK_PROP) and ng.library is None and ng.users == 0:
            bpy.data.node_groups.remove(ng)
    B.remove_lightmap_hook([])   # drops bake.py's shading group if it is now unused
    return removed


def remove_orientation_lightmap(empty):
    """Deletes OL empty `empty`, its baked images and its material hook nodes; nothing else.

    Objects, UV layers and materials are left as they were before the OL was
    added, so their own lightmaps are used again. -> summary dict."""
    import bpy
    from .export import is_orientation_lightmap
    if not is_orientation_lightmap(empty):
        raise ValueError(f"object '{empty.name}' is not an orientation lightmap")
    name = empty.name
    nodes = remove_ol_hook(name)
    images = [im for im in bpy.data.images
              if im.library is None and im.get(OL_IMAGE_PROP) == name and im.get(B.OWNER_PROP) == name]
    image_names = [im.name for im in images]
    for im in images:
        bpy.data.images.remove(im)
    for sc in bpy.data.scenes:
        REPORTS.pop((sc.name, name), None)
    bpy.data.objects.remove(empty)
    return {"empty": name, "nodes": nodes, "images": image_names}


# --------------------------------------------------------------------------------------
# Command line: python -m photon_lightmaps bake-ol FILE.blend --out DIR
# --------------------------------------------------------------------------------------

def ol_bake_main(args):
    """CLI: bakes every orientation lightmap of a .blend to DIR/<empty>.exr (+ JSON report)."""
    import bpy

    from .headless import open_blend
    t0 = time.perf_counter()
    B._ensure_registered()
    blend = open_blend(args.blend)
    B._ensure_registered()
    out_dir = os.path.abspath(args.out)
    B.check_writable(out_dir)
    res = bake_orientation_lightmaps(bpy.context, photons=args.photons, seed=args.seed,
                                     save_dir=out_dir, overwrite=True, hook_materials=False)
    report = {"blend": str(blend),
              "photons": int(res.stats.photons) if res.stats else 0,
              "orientation_lightmaps": {
                  name: {"path": res.paths[name], "resolution": int(rgba.shape[0]),
                         "objects": res.covered.get(name, []),
                         **next((r for r in res.rows if r["name"] == name), {})}
                  for name, rgba in res.maps.items()},
              "warnings": res.warnings,
              "seconds": {"photon_pass": res.seconds.get("photon_pass", 0.0),
                          "total": time.perf_counter() - t0}}
    text = json.dumps(report, indent=2)
    print(text)
    if getattr(args, "json", None):
        with open(args.json, "w") as f:
            f.write(text)
    return 0
