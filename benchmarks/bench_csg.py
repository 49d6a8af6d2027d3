"""Exact CSG against Blender's tessellated Exact-Boolean mesh, and CSG-aware
(split) lightmaps against plain ones (thesis 4.1, 5, 8; fig. 4.2, 5.5).

Usage (from the repository root):
    .venv/bin/python -m benchmarks.bench_csg            # full: fig. 5.5 x 3 and the machine
    .venv/bin/python -m benchmarks.bench_csg --quick    # fig. 5.5 difference and a small machine
Options: --out DIR  --charts DIR  --no-charts  --no-machine

For every scene (csg_scenes.py) and model:
  * exact: this engine on the exported CSG tree (analytic primitives);
  * tess<N>: Blender's Exact Boolean of N-segment display meshes, applied and
    exported as triangle meshes (xatlas lightmap UVs);
  * exact_plain: the exact model with plain primitive lightmaps (csg_split=False);
it records primitives/triangles, memory (trace buffer the ray kernels read +
lightmap arrays), setup time (Blender Boolean, export, compile), the photon
pass (best of `repeats`), a 16-spp render and its error against a Cycles
reference render of the finest tessellation (run_all's relative RMSE with the
reference noise removed). Writes DIR/csg_results.json and csg_*.png charts.
"""
import argparse
import json
import os
import pathlib
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", str(ROOT / ".numba_cache"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import photon_lightmaps  # noqa: E402
from photon_lightmaps import registration  # noqa: E402
from photon_lightmaps.engine.lightmaps import lightmap  # noqa: E402
from photon_lightmaps.engine.compile import compile_scene  # noqa: E402
from photon_lightmaps.engine.transport.photon_tracer import trace_photons  # noqa: E402
from photon_lightmaps.engine.transport.renderer import render as render_image  # noqa: E402
from photon_lightmaps.export import export_scene  # noqa: E402

from benchmarks import csg_scenes  # noqa: E402
from benchmarks import methods  # noqa: E402
from benchmarks.quiet import quiet  # noqa: E402
from benchmarks.run_all import Scorer  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
CACHE = HERE / "cache"
# Bump when a builder changes: the Cycles references are cached under it.
BUILD_VERSION = 2

FULL = dict(ops=["union", "intersection", "difference"], fig_size=(96, 96), fig_tess=[16, 64],
            fig_ref_segments=256, machine=True, machine_size=(128, 96), machine_tess=[16],
            machine_ref_segments=32, machine_pitch=0.009, photons=1_000_000, samples=16,
            ref_spp=128, repeats=3)
QUICK = dict(ops=["difference"], fig_size=(48, 48), fig_tess=[16], fig_ref_segments=64, machine=True,
             machine_size=(64, 48), machine_tess=[16], machine_ref_segments=16, machine_pitch=0.06,
             photons=200_000, samples=8, ref_spp=32, repeats=1)


def _builder(name, cfg):
    if name.startswith("fig55_"):
        op = name.split("_", 1)[1]
        return lambda seg: csg_scenes.build_fig55(op, *cfg["fig_size"], segments=seg)
    return lambda seg: csg_scenes.build_machine(*cfg["machine_size"], segments=seg,
                                        rivet_pitch=cfg["machine_pitch"])


def reference(name, cfg, log):
    """Cycles render (two halves) of the finest tessellation, cached by its settings."""
    ref_seg = cfg["fig_ref_segments"] if name.startswith("fig55") else cfg["machine_ref_segments"]
    size = cfg["fig_size"] if name.startswith("fig55") else cfg["machine_size"]
    key = (f"csg_{name}_v{BUILD_VERSION}_s{ref_seg}_{size[0]}x{size[1]}_spp{cfg['ref_spp']}"
           f"_p{cfg['machine_pitch'] if name == 'machine' else 0}_{bpy.app.version_string}_b{methods.MAX_BOUNCES}")
    path = CACHE / f"{key.replace(' ', '')}.npz"
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}, f"cache:{path.name}"
    log(f"  [{name}] Cycles reference: {ref_seg} segments, 2 x {cfg['ref_spp']} spp")
    _builder(name, cfg)(ref_seg)
    # Cycles renders the applied Boolean meshes, creases marked sharp (csg_scenes.tessellate)
    t_bool = csg_scenes.tessellate(unwrap=False)["boolean_seconds"]
    out = {}
    for half, seed in (("A", 1001), ("B", 2002)):
        with quiet():
            img, t = methods.cycles_render(cfg["ref_spp"], seed)
        out[f"render_{half}"] = img
        log(f"    half {half}: {t:.1f} s (Boolean {t_bool:.1f} s)")
    CACHE.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **out)
    return out, "regenerated"


_WARM = set()


def measure(label, cfg, score, csg_split=True, log=print):
    """Export + compile + photon pass + render of the current Blender scene."""
    t0 = time.perf_counter()
    scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    t_export = time.perf_counter() - t0
    if csg_split not in _WARM:
        # first compile in the process: JIT of the split-texel kernels, not setup cost
        compile_scene(scene, csg_split=csg_split)
        _WARM.add(csg_split)
    cs = compile_scene(scene, csg_split=csg_split)
    g = cs.geometry
    # warm-up: JIT from the numba cache for this scene's kernels
    trace_photons(cs, 2000, seed=1, max_bounces=methods.MAX_BOUNCES, record_direct=False)
    times = []
    for r in range(cfg["repeats"]):
        cs.reset_lightmaps()
        t1 = time.perf_counter()
        trace_photons(cs, cfg["photons"], seed=7, max_bounces=methods.MAX_BOUNCES, record_direct=False)
        times.append(time.perf_counter() - t1)
    t1 = time.perf_counter()
    img = render_image(cs, samples=cfg["samples"], seed=7, mode=lightmap.MODE_BILINEAR,
                       max_depth=methods.MAX_BOUNCES)[..., :3]
    t_render = time.perf_counter() - t1
    info = cs.info
    n_leaves = int(info.get("csg_leaves", 0))
    p = dict(model=label, csg_split=csg_split,
             primitives=int(g.prim_kind.shape[0]), csg_leaves=n_leaves, csg_solids=int(info.get("csg_solids", 0)),
             triangles=int(g.tri_p.shape[0]),
             geometry_bytes=int(g.trace.nbytes), lightmap_bytes=int(cs.lightmap_bytes()),
             texels=int(info["texels"]), lightmaps=int(info["lightmaps"]),
             export_seconds=t_export, compile_seconds=float(cs.timings["setup"]),
             csg_setup_seconds=float(info.get("csg_setup_seconds", 0.0)),
             photon_seconds=min(times), photon_seconds_all=times, render_seconds=t_render,
             **score(img))
    p.update({k: v for k, v in info.items() if k.startswith("csg_") and isinstance(v, (int, float))
              and k not in p})
    p["memory_bytes"] = p["geometry_bytes"] + p["lightmap_bytes"]
    log(f"  {label:12s} prims {p['primitives']:6,} tris {p['triangles']:8,}  mem {p['memory_bytes'] / 2**20:7.2f} MiB"
        f"  setup {t_export + p['compile_seconds']:6.2f} s  photons {p['photon_seconds']:6.2f} s"
        f"  relRMSE {p['rel_rmse']:.4f} bias {p['mean_error']:+.4f}")
    return p, img, cs


def interleaved_photon_seconds(cs_a, cs_b, cfg):
    """Best photon-pass time of two compiled scenes, measured alternately so that
    load from other processes on the shared cores hits both alike."""
    ta, tb = [], []
    for _ in range(max(cfg["repeats"], 2)):
        for cs, out in ((cs_a, ta), (cs_b, tb)):
            cs.reset_lightmaps()
            t0 = time.perf_counter()
            trace_photons(cs, cfg["photons"], seed=7, max_bounces=methods.MAX_BOUNCES, record_direct=False)
            out.append(time.perf_counter() - t0)
    return min(ta), min(tb)


def run_scene(name, cfg, log):
    ref, src = reference(name, cfg, log)
    log(f"[{name}] reference {src}")
    score = Scorer(ref["render_A"], ref["render_B"])
    build = _builder(name, cfg)
    models, images = [], {"reference": 0.5 * (ref["render_A"] + ref["render_B"])}
    for i, seg in enumerate(cfg["fig_tess"] if name.startswith("fig55") else cfg["machine_tess"]):
        t0 = time.perf_counter()
        _, binfo = build(seg)
        t_build = time.perf_counter() - t0
        if i == 0:
            p, img, cs_split = measure("exact", cfg, score, True, log)
            p["build_seconds"] = t_build
            p["setup_seconds"] = p["export_seconds"] + p["compile_seconds"]
            models.append(p)
            images["exact"] = img
            q, img, cs_plain = measure("exact_plain", cfg, score, False, log)
            t_split, t_plain = interleaved_photon_seconds(cs_split, cs_plain, cfg)
            p["photon_seconds_interleaved"], q["photon_seconds_interleaved"] = t_split, t_plain
            del cs_split, cs_plain
            q["setup_seconds"] = q["export_seconds"] + q["compile_seconds"]
            models.append(q)
            images["exact_plain"] = img
        tess = csg_scenes.tessellate()
        p, img, _ = measure(f"tess{seg}", cfg, score, True, log)
        p.update(segments=seg, build_seconds=t_build, boolean_seconds=tess["boolean_seconds"],
                 unwrap_seconds=tess["unwrap_seconds"], model_triangles=tess["triangles"])
        # what a polygon pipeline pays before its first photon: Boolean + unwrap + export + compile
        p["setup_seconds"] = (tess["boolean_seconds"] + tess["unwrap_seconds"] + p["export_seconds"]
                              + p["compile_seconds"])
        log(f"    Blender Exact Boolean {tess['boolean_seconds']:.1f} s, xatlas {tess['unwrap_seconds']:.1f} s, "
            f"{tess['triangles']:,} triangles")
        models.append(p)
        images[f"tess{seg}"] = img
    ex = next(m for m in models if m["model"] == "exact")
    pl = next(m for m in models if m["model"] == "exact_plain")
    split = dict(photon_overhead=ex["photon_seconds_interleaved"] / pl["photon_seconds_interleaved"] - 1.0,
                 photon_seconds_split=ex["photon_seconds_interleaved"],
                 photon_seconds_plain=pl["photon_seconds_interleaved"],
                 lightmap_memory_overhead=ex["lightmap_bytes"] / pl["lightmap_bytes"] - 1.0,
                 split_table_bytes=ex.get("csg_split_bytes", 0),
                 sub_texels=ex.get("csg_sub_texels", 0), texels_plain=pl["texels"],
                 csg_setup_seconds=ex["csg_setup_seconds"], ties=ex.get("csg_ties", 0),
                 rel_rmse_split=ex["rel_rmse"], rel_rmse_plain=pl["rel_rmse"],
                 mean_error_split=ex["mean_error"], mean_error_plain=pl["mean_error"])
    log(f"  split vs plain: photon pass {split['photon_overhead']:+.1%}, lightmap memory "
        f"{split['lightmap_memory_overhead']:+.1%} (goal <= 10 % each), CSG setup "
        f"{split['csg_setup_seconds']:.2f} s, ties {split['ties']}")
    info = dict(scene=name, primitives_in_blender=binfo["primitives"], solids=len(binfo["solids"]),
                reference=src, noise_floor=score.noise_floor(), split=split)
    return models, info, images


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-machine", action="store_true")
    ap.add_argument("--out", default=str(HERE / "out"))
    ap.add_argument("--charts", default=None, help="chart folder (default: DIR/charts; the full run "
                                                   "also refreshes benchmarks/charts/csg_*.png)")
    ap.add_argument("--no-charts", action="store_true")
    a = ap.parse_args(argv)
    cfg = QUICK if a.quick else FULL
    if not registration.is_registered():
        photon_lightmaps.register()
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    log = lambda s: print(s, flush=True)  # noqa: E731
    names = [f"fig55_{op}" for op in cfg["ops"]] + (["machine"] if cfg["machine"] and not a.no_machine else [])
    result = dict(config={k: v for k, v in cfg.items()}, quick=a.quick, scenes=[], points=[])
    images = {}
    t0 = time.perf_counter()
    for name in names:
        models, info, imgs = run_scene(name, cfg, log)
        result["scenes"].append(info)
        result["points"] += [dict(scene=name, **m) for m in models]
        images[name] = imgs
    result["seconds"] = time.perf_counter() - t0
    path = out / ("csg_results_quick.json" if a.quick else "csg_results.json")
    path.write_text(json.dumps(result, indent=1, default=float))
    log(f"wrote {path} ({result['seconds']:.0f} s)")
    if not a.no_charts:
        from benchmarks import charts
        folders = [pathlib.Path(a.charts) if a.charts else out / "charts"]
        if not a.quick and a.charts is None:
            folders.append(HERE / "charts")
        for f in folders:
            log("charts: " + ", ".join(charts.csg_charts(result, images, f)))
    return result


if __name__ == "__main__":
    main()
