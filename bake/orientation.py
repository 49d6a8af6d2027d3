"""Baking orientation lightmaps (thesis ch. 6) to images, and showing them in EEVEE.

One photon pass with direct light recorded (like Cycles' Diffuse bake,
Direct + Indirect, no Color) fills every OL's bins; each OL empty then owns
an R×R float RGBA image, and so does each L-system object for its automatic
OL (engine/compile._lsystem_orientation; thesis 7.3) unless a collection OL
covers it (that empty's image and hook then hold it):

* RGB = E/pi per direction bin, E the irradiance of the bin, after the
  hierarchy rule of the renderer (engine/orientation_lightmap.lookup): a bin
  with too few photons (relative error above 1/sqrt(min_hits)) shows the
  enclosing OL's value, so the image is what the renderer reads.
* A = 1 where the bin has surface (estimated area > 0), 0 elsewhere.

Pixel (x, y) is bin (x, y), rows bottom-up, at the octahedral coordinates of
the world normal (engine/primitives._octa_encode). Images are named
"<owner>_Lightmap" (owner: the empty, or the L-system object) and follow the
image policy of images.py exactly (ours are updated in place, a user's image
of that name is kept unless `overwrite`), and are saved by the same
images.store.

Material hook: hooks.add_ol_hook, owned (OL_HOOK_PROP) by the empty or the
L-system object; remove_orientation_lightmap deletes either's image and nodes.
An L-system's OL stubs (`ol stub:`, one OL each) are not baked apart: the
object's image is its whole OL (every level holds its subtree), because the
hook looks bins up by normal only and cannot tell which stub a pixel of the
realized preview belongs to.

REPORTS keeps the last render's or bake's per-OL numbers for the panel.
"""
import json
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..engine.lightmaps import lightmap
from ..engine.lightmaps import orientation_lightmap
from ..engine import session
from ..engine.core.scene import SceneError
from ..export import export_scene, is_orientation_lightmap
from ..export.lsystems import is_lsystem
from . import hooks, images
from .hooks import OL_HOOK_PROP  # noqa: F401  (re-exported: tests and the panel read it here)

OL_IMAGE_PROP = "photon_lightmaps_ol"        # on images we baked for an OL (value: empty name)
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
    rows = orientation_lightmap.report(cs)
    names = [r["name"] for r in rows]
    out = [summarize(r, names, source) for r in rows]
    for s in out:
        REPORTS[(scene_name, s["name"])] = s
        if report is not None:
            for w in s["warnings"]:
                report("WARNING", w)
    return out


def last_report(scene_name, ob):
    """The last render's or bake's summary for OL empty `ob`, or for an L-system object's
    automatic OL once baked (None if never run)."""
    s = REPORTS.get((scene_name, ob.name))
    if s is None:
        s = _stored_report(ob)
        if s is not None:
            # an L-system's OL is named after its object: a later render keeps it under that name
            s = REPORTS.get((scene_name, s.get("name")), s)
    return s


def _stored_report(ob):
    """The summary the last bake stored on `ob` (None if none or unreadable)."""
    try:
        s = json.loads(ob[REPORT_PROP]) if ob.get(REPORT_PROP) else None
    except (TypeError, ValueError):
        s = None
    return s if isinstance(s, dict) else None


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
    sl0 = lightmap.texel_slice(lm, int(ol.lid[k]))
    n = sl0.stop - sl0.start
    r = int(lm.width[int(ol.lid[k])])
    idx = np.arange(n)
    level = np.full(n, k, np.int64)
    # Walk up per bin exactly like orientation_lightmap.lookup: stop where the bin is good enough or at the top.
    for _ in range(orientation_lightmap.MAX_LEVELS + 1):
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
    empty = lm.state[ti] == lightmap.STATE_EMPTY
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
    """Unit normals (N, 3) at octahedral coordinates (s, t): inverse of the engine's octahedral map."""
    x, y = 2.0 * np.asarray(s, np.float64) - 1.0, 2.0 * np.asarray(t, np.float64) - 1.0
    z = 1.0 - np.abs(x) - np.abs(y)
    low = z < 0
    sx, sy = np.where(x >= 0, 1.0, -1.0), np.where(y >= 0, 1.0, -1.0)
    x, y = np.where(low, (1 - np.abs(y)) * sx, x), np.where(low, (1 - np.abs(x)) * sy, y)
    n = np.stack([x, y, z], axis=1)
    return n / np.linalg.norm(n, axis=1, keepdims=True)


# --------------------------------------------------------------------------------------
# Bake
# --------------------------------------------------------------------------------------

@dataclass
class OLBakeResult:
    # keyed by owner: the OL empty's name, or an L-system object's (its automatic OL)
    maps: dict = field(default_factory=dict)       # owner name -> rgba (R, R, 4)
    images: dict = field(default_factory=dict)     # owner name -> image name
    paths: dict = field(default_factory=dict)      # owner name -> saved file (None: unsaved/packed)
    covered: dict = field(default_factory=dict)    # owner name -> covered object names (innermost, hooked)
    lsystems: dict = field(default_factory=dict)   # L-system object name -> engine OL name it bakes
    rows: list = field(default_factory=list)       # summaries (see summarize)
    hooked: list = field(default_factory=list)     # materials given an OL hook
    warnings: list = field(default_factory=list)
    stats: object = None
    seconds: dict = field(default_factory=dict)


def compute(depsgraph, settings, progress=None):
    """Export + photon pass with direct light recorded -> (compiled scene, export map, stats, warnings)."""
    warnings = []
    scene, emap = export_scene(depsgraph, report=lambda level, msg: None)
    warnings.extend(emap.warnings)
    if not scene.orientation_lightmaps and not lsystem_instances(emap):
        raise SceneError(f"scene '{depsgraph.scene.name}': no usable orientation lightmap (add one with "
                         "Object > Add Orientation Lightmap to Collection) and no L-system object")
    # Only the OL bins are baked: per-object lightmaps would cost memory and time for
    # nothing, and recording never changes where photons go.
    for inst in scene.instances:
        inst.lightmap = False
    cs, stats = session.compile_and_trace(scene, settings, record_direct=True, progress=progress)
    if cs.lights.total_power <= 0.0:
        warnings.append("no photons were traced (no lights): the orientation lightmaps are black")
    return cs, emap, stats, warnings


def bake_orientation_lightmaps(context_or_depsgraph, *, photons=None, seed=None, overwrite=False,
                               save_dir=None, pack=False, hook_materials=True, progress=None):
    """Bakes every OL of the scene to "<empty>_Lightmap" images (and files, and material hooks)."""
    import bpy
    t0 = time.perf_counter()
    from .pipeline import BakeSettings, evaluated_depsgraph
    depsgraph = evaluated_depsgraph(context_or_depsgraph)
    bscene = depsgraph.scene
    settings = BakeSettings.read(getattr(bscene, "photon_lightmaps", None), photons=photons, seed=seed)
    if settings.photons < 0:
        raise SceneError(f"photons: must be 0 or more, got {settings.photons}")
    res = OLBakeResult()
    cs, emap, stats, warns = compute(depsgraph, settings, progress=progress)
    res.stats = stats
    res.warnings.extend(warns)
    res.seconds["photon_pass"] = stats.seconds
    scene_name = bscene.name
    res.rows = record_report(cs, scene_name, "bake")
    for row in res.rows:
        res.warnings.extend(row["warnings"])
    # Everything is computed: only now touch images and materials.
    images.check_output(save_dir, pack)
    store = dict(overwrite=overwrite, save_dir=save_dir, pack=pack)
    names = [row["empty"] for row in emap.orientation_lightmaps]   # engine OL order
    for k, name in enumerate(names):
        empty = bpy.data.objects.get(name)
        if empty is None:
            continue
        img = _bake_ol(cs, k, empty, res, **store)
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
                res.hooked += hooks.add_ol_hook(empty, img, objs, res.warnings)
    # L-system objects no collection OL covers: their automatic OL (the OLs after the
    # empties' are the compiler's), baked to an image the object owns.
    for i in lsystem_instances(emap):
        k = int(cs.orientation.inst_ol[i])
        ob = bpy.data.objects.get(emap.instances[i].object_name)
        if k < len(names) or ob is None:
            continue
        img = _bake_ol(cs, k, ob, res, **store)
        res.covered[ob.name] = [ob.name]
        res.lsystems[ob.name] = res.rows[k]["name"]
        if int(cs.orientation.inst_stub0[i]) >= 0:
            res.warnings.append(f"L-system object '{ob.name}': its OL stubs are baked into its one "
                                "orientation lightmap image (EEVEE shows the whole object's light by "
                                "normal; renders with this engine use each stub's own)")
        if hook_materials:
            res.hooked += hooks.add_ol_hook(ob, img, [ob], res.warnings)
    if res.maps and images.in_memory_only(save_dir, pack):
        res.warnings.append("the .blend is not saved yet: the orientation lightmap images live only "
                            "in memory (save the .blend and bake again, or pack them)")
    res.seconds["total"] = time.perf_counter() - t0
    return res


def _bake_ol(cs, k, owner, res, *, overwrite, save_dir, pack):
    """OL k of a traced compiled scene -> the image `owner` (an OL empty or an L-system
    object) owns, written, saved or packed, and recorded in `res`; the OL's report row
    goes onto the owner. -> the image."""
    name = owner.name
    rgba = ol_rgba(cs, k)
    r = rgba.shape[0]
    img = images.target_image(owner, r, r, overwrite, res.warnings)
    img[OL_IMAGE_PROP] = name
    images.write_pixels(img, rgba)
    path = images.store(img, name, save_dir=save_dir, pack=pack)
    res.maps[name], res.images[name], res.paths[name] = rgba, img.name, path
    owner[REPORT_PROP] = json.dumps(res.rows[k])
    return img


def lsystem_instances(emap):
    """Engine instance ids of L-system objects (their own geometry, not duplis)."""
    return [i for i, r in enumerate(emap.instances)
            if not r.is_instance and emap.prototypes[r.prototype].uv_source == "lsystem"]


def remove_orientation_lightmap(ob):
    """Deletes OL empty `ob`, its baked images and its material hook nodes; nothing else.

    Objects, UV layers and materials are left as they were before the OL was
    added, so their own lightmaps are used again. For an L-system object, removes
    what the bake added for its automatic OL (image, hook nodes, report) and keeps
    the object. -> summary dict ("removed_object": whether `ob` was deleted)."""
    import bpy
    empty = is_orientation_lightmap(ob)
    if not empty and not is_lsystem(ob):
        raise ValueError(f"object '{ob.name}' is not an orientation lightmap")
    name = ob.name
    nodes = hooks.remove_ol_hook(name)
    owned = [im for im in bpy.data.images
             if im.library is None and im.get(OL_IMAGE_PROP) == name and im.get(images.OWNER_PROP) == name]
    image_names = [im.name for im in owned]
    for im in owned:
        bpy.data.images.remove(im)
    ol_name = name
    if not empty and ob.get(REPORT_PROP) is not None:
        ol_name = (_stored_report(ob) or {}).get("name", name)
        del ob[REPORT_PROP]
    for sc in bpy.data.scenes:
        REPORTS.pop((sc.name, ol_name), None)
    if empty:
        bpy.data.objects.remove(ob)
    return {"empty": name, "nodes": nodes, "images": image_names, "removed_object": bool(empty)}

