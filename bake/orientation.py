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
"<empty>_Lightmap" and follow the image policy of images.py exactly (ours are
updated in place, a user's image of that name is kept unless `overwrite`), and
are saved by the same images.store.

Material hook: hooks.add_ol_hook.

REPORTS keeps the last render's or bake's per-OL numbers for the panel.
"""
import json
import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..engine import lightmap as LM
from ..engine import orientation_lightmap as OL
from ..engine import session
from ..engine.scene import SceneError
from ..export import export_scene, is_orientation_lightmap
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
    maps: dict = field(default_factory=dict)       # empty name -> rgba (R, R, 4)
    images: dict = field(default_factory=dict)     # empty name -> image name
    paths: dict = field(default_factory=dict)      # empty name -> saved file (None: unsaved/packed)
    covered: dict = field(default_factory=dict)    # empty name -> covered object names (innermost, hooked)
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
    if not scene.orientation_lightmaps:
        raise SceneError(f"scene '{depsgraph.scene.name}': no usable orientation lightmap (add one with "
                         "Object > Add Orientation Lightmap to Collection)")
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
    from .pipeline import BakeSettings, _depsgraph
    depsgraph = _depsgraph(context_or_depsgraph)
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
    names = [row["empty"] for row in emap.orientation_lightmaps]   # engine OL order
    for k, name in enumerate(names):
        empty = bpy.data.objects.get(name)
        if empty is None:
            continue
        rgba = ol_rgba(cs, k)
        r = rgba.shape[0]
        img = images.target_image(empty, r, r, overwrite, res.warnings)
        img[OL_IMAGE_PROP] = name
        images.write_pixels(img, rgba)
        path = images.store(img, name, save_dir=save_dir, pack=pack)
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
                res.hooked += hooks.add_ol_hook(empty, img, objs, res.warnings)
    if res.maps and images.in_memory_only(save_dir, pack):
        res.warnings.append("the .blend is not saved yet: the orientation lightmap images live only "
                            "in memory (save the .blend and bake again, or pack them)")
    res.seconds["total"] = time.perf_counter() - t0
    return res


def remove_orientation_lightmap(empty):
    """Deletes OL empty `empty`, its baked images and its material hook nodes; nothing else.

    Objects, UV layers and materials are left as they were before the OL was
    added, so their own lightmaps are used again. -> summary dict."""
    import bpy
    if not is_orientation_lightmap(empty):
        raise ValueError(f"object '{empty.name}' is not an orientation lightmap")
    name = empty.name
    nodes = hooks.remove_ol_hook(name)
    owned = [im for im in bpy.data.images
             if im.library is None and im.get(OL_IMAGE_PROP) == name and im.get(images.OWNER_PROP) == name]
    image_names = [im.name for im in owned]
    for im in owned:
        bpy.data.images.remove(im)
    for sc in bpy.data.scenes:
        REPORTS.pop((sc.name, name), None)
    bpy.data.objects.remove(empty)
    return {"empty": name, "nodes": nodes, "images": image_names}

