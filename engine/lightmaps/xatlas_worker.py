"""Runs xatlas jobs in a child process, so that a crash in native code we do not own
(xatlas segfaults on some dense meshes) ends this process, not Blender.

Run by engine/lightmaps/uv_atlas.py as ``python xatlas_worker.py FOLDER START`` (or through
``blender -b --python xatlas_worker.py -- FOLDER START``). It reads the batch from
FOLDER/jobs.npz, runs jobs START, START+1, ... in order, writes job i's result to
FOLDER/result_i.npz as soon as it is done and then prints ``TAG done i``; it
prints ``TAG start i`` before running job i, so when the process dies the parent
knows which job killed it. A Python exception in a job is written to its result
file as ``error`` and the worker goes on with the next job.

Imports only numpy (and xatlas when run): it must work with a bare interpreter,
without the package, bpy or numba. uv_atlas imports it as a module for the
constants and the pure-numpy helpers; xatlas itself is only imported in main().
"""
import math
import os
import sys

if __name__ == "__main__":
    # Run as a script, Python puts engine/ first on sys.path: keep the package's
    # modules from shadowing anything numpy or xatlas import.
    _here = os.path.dirname(os.path.abspath(__file__))
    if sys.path and os.path.abspath(sys.path[0] or os.getcwd()) == _here:
        del sys.path[0]

import numpy as np

TAG = "photon_lightmaps.xatlas_worker:"
JOBS_FILE = "jobs.npz"
UNWRAP = "unwrap"
PACK = "pack"

# Charts must stay this many lightmap texels apart at the requested resolution:
# a bilinear lookup reads texels up to 1.5 texels from its chart, and one ring of
# dilation reaches one texel further.
MIN_GAP_TEXELS = 3.0
_MAX_ATTEMPTS = 4


def result_path(folder, i):
    return os.path.join(folder, f"result_{i}.npz")


# --------------------------------------------------------------------------------------
# xatlas calls
# --------------------------------------------------------------------------------------

def _generate(xatlas, add_mesh, chart_options, resolution, texels_per_unit, padding):
    """xatlas atlas of one mesh, packed again with a lower texel density while its
    charts would come closer than MIN_GAP_TEXELS on a `resolution` lightmap."""
    gap = 2 * padding + 1  # xatlas leaves 2·padding (+1 bilinear) texels between charts
    tpu = texels_per_unit
    for attempt in range(_MAX_ATTEMPTS):
        atlas = xatlas.Atlas()
        add_mesh(atlas)
        po = xatlas.PackOptions()
        po.padding = padding
        po.bilinear = True
        if tpu:
            po.texels_per_unit = float(tpu)
        elif resolution:
            po.resolution = int(resolution)
        atlas.generate(chart_options=chart_options(), pack_options=po)
        side = max(int(atlas.width), int(atlas.height), 1)
        if not resolution or gap * resolution / side >= MIN_GAP_TEXELS or attempt == _MAX_ATTEMPTS - 1:
            return atlas
        # The packed atlas came out too large for the requested lightmap: shrink
        # the texel density in proportion and pack again (rare: xatlas' own
        # estimate usually overshoots the requested size by < 1.6x).
        tpu = float(atlas.texels_per_unit) * (gap * resolution / (MIN_GAP_TEXELS * side)) * 0.97


def to_original_order(t, vmap, idx, uv_px, vchart):
    """Per-corner UVs (texel units) and chart ids in the input triangle order."""
    T = t.shape[0]
    chart = np.full(T, -1, np.int64)
    out = np.zeros((T, 3, 2))
    orig = vmap[idx] if idx.size else np.zeros((0, 3), np.int64)
    if idx.shape[0] == T and np.array_equal(orig, t):
        # xatlas keeps faces in input order with the same corner order (the usual case).
        out[:] = uv_px[idx]
        chart[:] = vchart[idx[:, 0]]
    else:
        # Reordered or dropped faces: match by vertex triple, corner by corner.
        rows = {}
        for k in range(T):
            rows.setdefault(tuple(sorted(t[k])), []).append(k)
        for j in range(idx.shape[0]):
            cand = rows.get(tuple(sorted(orig[j])))
            if not cand:
                continue
            k = cand.pop(0)
            for c in range(3):
                pos = np.nonzero(orig[j] == t[k, c])[0]
                out[k, c] = uv_px[idx[j, pos[0] if pos.size else c]]
            chart[k] = vchart[idx[j, 0]]
    # xatlas marks ignored (degenerate) faces with chart 0xFFFFFFFF.
    chart[(chart < 0) | (chart >= 2 ** 31 - 1)] = -1
    return out, chart.astype(np.int32)


def unwrap(xatlas, v, t, resolution, texels_per_unit, padding):
    """xatlas unwrap -> the fields of uv_atlas.AtlasResult as a dict."""
    T = t.shape[0]
    if T == 0:
        return dict(uv=np.zeros((0, 3, 2)), chart=np.zeros(0, np.int32), width=1, height=1,
                    resolution=1, min_resolution=1)
    pos, ind = v.astype(np.float32), t.astype(np.uint32)
    atlas = _generate(xatlas, lambda a: a.add_mesh(pos, ind), xatlas.ChartOptions,
                      resolution, texels_per_unit, padding)
    vmap, idx, uv = atlas[0]
    _, vchart = atlas.get_mesh_vertex_assignment(0)
    w, h = int(atlas.width), int(atlas.height)
    side = max(w, h, 1)
    uv_px = uv.astype(np.float64) * np.array([w, h], np.float64)
    out, chart = to_original_order(t, vmap.astype(np.int64), idx.astype(np.int64), uv_px,
                                   vchart.astype(np.int64))
    return dict(uv=np.clip(out / side, 0.0, 1.0), chart=chart, width=w, height=h, resolution=side,
                min_resolution=int(math.ceil(MIN_GAP_TEXELS * side / (2 * padding + 1))))


def pack_islands(xatlas, v, tri_v, corner_uv, island, resolution, padding):
    """Packs given UV islands (corner_uv in object units, island id per triangle)
    -> dict(uv=(T, 3, 2) in [0,1]², min_resolution).

    Corners are welded by (vertex, island, uv), so xatlas sees each island as one
    connected chart and only scales and places it.
    """
    T = tri_v.shape[0]
    q = np.round(corner_uv.reshape(-1, 2) / max(np.abs(corner_uv).max(), 1e-30) * 2 ** 30)
    key = np.column_stack([tri_v.reshape(-1), np.repeat(island, 3), q]).astype(np.int64)
    uniq, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    pos = v[uniq[:, 0]].astype(np.float32)
    in_uv = np.zeros((uniq.shape[0], 2))
    in_uv[inverse] = corner_uv.reshape(-1, 2)
    in_uv = in_uv.astype(np.float32)
    idx = inverse.reshape(T, 3).astype(np.uint32)

    def chart_options():
        co = xatlas.ChartOptions()
        co.use_input_mesh_uvs = True
        return co

    atlas = _generate(xatlas, lambda a: a.add_mesh(pos, idx, None, in_uv), chart_options,
                      resolution, None, padding)
    w, h = int(atlas.width), int(atlas.height)
    side = max(w, h, 1)
    vmap, out_idx, out_uv = atlas[0]
    if out_idx.shape[0] != T or not np.array_equal(vmap[out_idx], idx):
        raise RuntimeError("xatlas reordered faces while repacking lightmap UV islands")
    uv = np.clip(out_uv[out_idx].astype(np.float64) * np.array([w, h]) / side, 0.0, 1.0)
    return dict(uv=uv, min_resolution=int(math.ceil(MIN_GAP_TEXELS * side / (2 * padding + 1))))


# --------------------------------------------------------------------------------------
# The batch: jobs.npz holds n and, for job i, kind_i, v_i, t_i, opt_i
# (resolution, texels per unit, padding; 0 = none) and for PACK jobs uv_i, island_i.
# --------------------------------------------------------------------------------------

def job_arrays(i, kind, v, t, resolution=None, texels_per_unit=None, padding=2,
               corner_uv=None, island=None):
    """The jobs.npz entries of job i (the parent's side of the format)."""
    d = {f"kind_{i}": np.array(kind), f"v_{i}": v, f"t_{i}": t,
         f"opt_{i}": np.array([resolution or 0, texels_per_unit or 0, padding], np.float64)}
    if kind == PACK:
        d[f"uv_{i}"] = corner_uv
        d[f"island_{i}"] = island
    return d


def _run_job(xatlas, z, i):
    kind = str(z[f"kind_{i}"])
    v, t = z[f"v_{i}"], z[f"t_{i}"]
    res, tpu, pad = (float(x) for x in z[f"opt_{i}"])
    res = int(res) or None
    tpu = tpu or None
    if kind == UNWRAP:
        return unwrap(xatlas, v, t, res, tpu, int(pad))
    if kind == PACK:
        return pack_islands(xatlas, v, t, z[f"uv_{i}"], z[f"island_{i}"], res, int(pad))
    raise ValueError(f"unknown job kind {kind!r}")


def _save(folder, i, out):
    path = result_path(folder, i)
    tmp = path + ".tmp"
    with open(tmp, "wb") as fh:
        np.savez(fh, **out)
    os.replace(tmp, path)  # the parent never sees half a file


def main(argv):
    folder, start = argv[0], int(argv[1])
    import xatlas  # here, not at the top: uv_atlas imports this module in the host process
    with np.load(os.path.join(folder, JOBS_FILE), allow_pickle=False) as z:
        n = int(z["n"])
        for i in range(start, n):
            print(TAG, "start", i, flush=True)
            try:
                out = _run_job(xatlas, z, i)
            except Exception as e:  # noqa: BLE001  (reported for this job; the rest still run)
                out = {"error": np.array(f"{type(e).__name__}: {e}")}
            _save(folder, i, out)
            print(TAG, "done", i, flush=True)


if __name__ == "__main__":
    # Blender passes the script's own arguments after "--".
    main(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
