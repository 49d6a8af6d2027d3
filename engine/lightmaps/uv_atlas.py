"""Lightmap UVs for meshes that have none: an xatlas unwrap, cached.

Photon lightmaps need a UV layout in which charts never share texels, also
under bilinear reconstruction and dilation (engine/lightmaps/lightmap.py). xatlas packs
charts with ``padding`` texels around each of them (plus one texel for
bilinear filtering), so two charts are at least 2·padding + 1 atlas texels
apart. UVs are normalised *uniformly* by the larger atlas side, which keeps
texels square and the atlas grid aligned with a lightmap of that many texels
per side.

Unwrapping takes seconds to minutes for large meshes, so every result is
stored on disk (keyed by a hash of the vertices, triangles and options) and in
a small in-memory LRU: a mesh is never unwrapped twice.

xatlas is native code we do not own, and it crashes on some meshes (a dense UV
sphere of ~260k triangles segfaults inside ``Atlas.generate``). A crash in the
host process would take Blender and the user's unsaved work down, so xatlas
only ever runs in a child process (engine/lightmaps/xatlas_worker.py): when the child
dies, the job it was running fails with an UnwrapError and a fresh child runs
the rest of the batch.
"""
import hashlib
import math
import os
import pathlib
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import OrderedDict, namedtuple

import numpy as np

from . import xatlas_worker as _W
from ..core.scene import SceneError

# Bump when the stored result's meaning changes, so stale cache files are ignored.
_CACHE_VERSION = "uv-atlas-1"
_LRU_SIZE = 16
MIN_GAP_TEXELS = _W.MIN_GAP_TEXELS  # lightmap texels between charts (see the worker)
# Used when neither a resolution nor a texel density is given (xatlas' own
# default packs a unit sphere into ~1300² texels). Low on purpose: the chart
# gaps are fixed in UV space, so a layout made for 64 texels stays leak-free
# on every lightmap of at least ~50 texels per side, at some cost in UV space.
DEFAULT_RESOLUTION = 64
_to_original_order = _W.to_original_order  # re-exported: the tests call it directly

_WORKER = os.path.join(os.path.dirname(os.path.abspath(__file__)), "xatlas_worker.py")
# How often a waiting parent asks should_stop(): cheap, and Esc still feels immediate.
_POLL_S = 0.05
# A job (or a worker's start) that runs past this is taken as stuck: xatlas can
# hang as well as crash. About 30x the time xatlas takes here on 2 loaded cores
# (0.3 ms per triangle at 10^5 triangles), so a slow machine never meets it.
_STALL_BASE_S = 120.0
_STALL_S_PER_TRIANGLE = 0.01
_ADVICE = "add a UV layer named 'Lightmap' to the mesh, or simplify it (e.g. a Decimate modifier)"
_START_ADVICE = ("check that the add-on's xatlas package is installed (reinstall Photon Lightmaps), "
                 "or add a UV layer named 'Lightmap' to the mesh")
# Child processes started so far (the tests check that cache hits start none).
worker_launches = 0


class UnwrapError(SceneError):
    """A mesh could not get lightmap UVs: bad input, or xatlas failed or crashed
    (in its child process). ``reason``: what went wrong, e.g. "xatlas crashed
    (SIGSEGV)"; ``triangles``: the mesh's triangle count (None if unknown). The
    message adds what to do, then the last line of ``detail`` (the child's
    stderr tail) if any; callers prefix the object's name."""

    def __init__(self, reason, triangles=None, action="unwrapping", advice=_ADVICE, detail=""):
        self.reason = reason
        self.triangles = triangles
        self.detail = detail
        msg = reason
        if action and triangles is not None:
            msg += f" {action} {triangles:,} triangle{'' if triangles == 1 else 's'}"
        msg += f"; {advice}" if advice else ""
        # One line (CLI and Blender reports): only the child's last stderr line.
        last = next((ln.strip() for ln in reversed(detail.splitlines()) if ln.strip()), "")
        super().__init__(msg + (f" ({last[:200]})" if last else ""))


# Why a worker job failed (what _run_jobs gives instead of a result).
_Failure = namedtuple("_Failure", ["reason", "advice", "detail"], defaults=[_ADVICE, ""])


AtlasResult = namedtuple("AtlasResult", [
    "uv",              # float64[T, 3, 2] per-triangle-corner UVs in [0,1]², original order
    "chart",           # int32[T] chart id per triangle (-1: xatlas ignored a degenerate face)
    "width",           # atlas size in xatlas texels
    "height",
    "resolution",      # max(width, height): lightmap side on which the xatlas grid lies exactly
    "min_resolution",  # smallest lightmap side keeping charts MIN_GAP_TEXELS apart
])

_lru = OrderedDict()
# Cache key -> the _Failure of an xatlas run that failed or crashed on it in this
# process: the same mesh would fail again, so a second ask (a bake's prepass,
# then the bake) does not start a worker to crash it twice.
_failures = OrderedDict()


def cache_dir():
    """Folder of the disk cache: $PHOTON_LIGHTMAPS_CACHE/uv or ~/.cache/photon_lightmaps/uv."""
    root = os.environ.get("PHOTON_LIGHTMAPS_CACHE")
    base = pathlib.Path(root) if root else pathlib.Path.home() / ".cache" / "photon_lightmaps"
    return base / "uv"


def clear_memory_cache():
    _lru.clear()
    _failures.clear()


def _bad_input(reason):
    return UnwrapError(reason, advice="fix the mesh data")


def _check_inputs(vertices, triangles):
    try:
        v = np.ascontiguousarray(vertices, dtype=np.float64)
        t = np.asarray(triangles)
    except (TypeError, ValueError) as e:
        raise _bad_input(f"vertices and triangles must be numeric arrays ({e})") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise _bad_input(f"vertices must have shape (V, 3), got {v.shape}")
    if t.size == 0:
        t = t.reshape(0, 3)
    if t.ndim != 2 or t.shape[1] != 3:
        raise _bad_input(f"triangles must have shape (T, 3), got {t.shape}")
    if t.size and not np.issubdtype(t.dtype, np.integer):
        raise _bad_input("triangles must be integer vertex indices")
    t = np.ascontiguousarray(t, dtype=np.int64)
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise UnwrapError(f"vertices contain NaN or infinity ({int(bad.sum()):,} of {v.shape[0]:,}, "
                          f"first: vertex {int(np.argmax(bad))})",
                          t.shape[0], action=None, advice="fix or delete those vertices")
    if t.size and (t.min() < 0 or t.max() >= v.shape[0]):
        k = int(np.argmax(((t < 0) | (t >= v.shape[0])).any(axis=1)))
        raise _bad_input(f"triangle {k} has a vertex index out of range [0, {v.shape[0]}): {t[k].tolist()}")
    return v, t


def _options(resolution, texels_per_unit, padding):
    padding = max(int(padding), 2)
    resolution = int(resolution) if resolution else None
    if resolution is not None and resolution < 1:
        raise _bad_input(f"resolution must be >= 1, got {resolution}")
    tpu = float(texels_per_unit) if texels_per_unit else None
    if tpu is not None and not (math.isfinite(tpu) and tpu > 0):
        raise _bad_input(f"texels_per_unit must be positive, got {texels_per_unit}")
    if resolution is None and tpu is None:
        resolution = DEFAULT_RESOLUTION
    return resolution, tpu, padding


_xatlas_version = None  # looked up once: metadata scans sys.path


def _key(v, t, resolution, texels_per_unit, padding):
    global _xatlas_version
    if _xatlas_version is None:
        # From the package metadata: loading xatlas here would put native code we do
        # not own into the host process (and fail there if xatlas is missing).
        from importlib import metadata
        try:
            _xatlas_version = metadata.version("xatlas")
        except Exception:  # noqa: BLE001  (no metadata: only a cache miss)
            _xatlas_version = "?"
    h = hashlib.sha256()
    opts = f"{_CACHE_VERSION}|xatlas {_xatlas_version}|" \
           f"{v.shape}|{t.shape}|{resolution}|{texels_per_unit}|{padding}"
    h.update(opts.encode())
    h.update(v.tobytes())
    h.update(t.tobytes())
    return h.hexdigest()


def _valid(res, n_tri):
    uv, chart = res.uv, res.chart
    return (uv.shape == (n_tri, 3, 2) and chart.shape == (n_tri,) and np.all(np.isfinite(uv))
            and (uv.size == 0 or (uv.min() >= 0.0 and uv.max() <= 1.0)))


def _load(path, n_tri):
    try:
        with np.load(path) as z:
            res = AtlasResult(z["uv"].astype(np.float64), z["chart"].astype(np.int32),
                              int(z["width"]), int(z["height"]), int(z["resolution"]),
                              int(z["min_resolution"]))
    except Exception:   # missing, truncated or foreign file: unwrap again
        return None
    return res if _valid(res, n_tri) else None


def _store(path, res):
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # Write then rename, so a concurrent reader never sees half a file.
        fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, uv=res.uv, chart=res.chart, width=res.width, height=res.height,
                     resolution=res.resolution, min_resolution=res.min_resolution)
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only cache only costs time


def _copy(res):
    return res._replace(uv=res.uv.copy(), chart=res.chart.copy())


def _lookup(key, n_tri):
    hit = _lru.get(key)
    if hit is not None:
        _lru.move_to_end(key)
        return hit
    res = _load(cache_dir() / f"{key}.npz", n_tri)
    if res is not None:
        _remember(key, res)
    return res


def _remember(key, res):
    _lru[key] = res
    while len(_lru) > _LRU_SIZE:
        _lru.popitem(last=False)


# --------------------------------------------------------------------------------------
# The child process
# --------------------------------------------------------------------------------------

def _worker_command(folder, start):
    exe = sys.executable
    if os.path.basename(exe).lower().startswith("blender"):
        # Blender < 2.92 reports itself as sys.executable: run the worker as its script.
        return [exe, "-b", "--factory-startup", "--python-exit-code", "1", "--python", _WORKER,
                "--", folder, str(start)]
    return [exe, _WORKER, folder, str(start)]


def _worker_env():
    env = dict(os.environ)
    # Blender's bundled numpy and the add-on's xatlas wheel are on our sys.path only.
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
    return env


def _exit_reason(rc):
    """Why the worker died, from its return code."""
    if rc < 0:
        try:
            name = signal.Signals(-rc).name
        except ValueError:
            name = f"signal {-rc}"
        if -rc == getattr(signal, "SIGKILL", None):
            return f"xatlas was killed ({name}; out of memory?)"
        return f"xatlas crashed ({name})"
    if rc >= 0xC0000000:  # Windows NTSTATUS, e.g. 0xC0000005 access violation
        return f"xatlas crashed (exception 0x{rc:08X})"
    return f"the xatlas worker exited with code {rc}"


def _tail(path, n_chars=1500):
    try:
        with open(path, "rb") as fh:
            fh.seek(0, os.SEEK_END)
            fh.seek(max(fh.tell() - n_chars, 0))
            text = fh.read().decode("utf-8", "replace").strip()
    except OSError:
        return ""
    return text


def _pump(stream, lines):
    for line in stream:
        lines.put(line.decode("utf-8", "replace"))
    stream.close()
    lines.put(None)


def _read_result(folder, i):
    try:
        with np.load(_W.result_path(folder, i), allow_pickle=False) as z:
            out = {k: z[k] for k in z.files}
    except Exception as e:  # noqa: BLE001
        return _Failure(f"the xatlas worker's result could not be read ({type(e).__name__}: {e})")
    return _Failure(f"xatlas failed ({out['error']})") if "error" in out else out


def stall_limit(triangles):
    """Seconds after which a job of this many triangles is taken as stuck."""
    return _STALL_BASE_S + _STALL_S_PER_TRIANGLE * triangles


def _watch_worker(folder, start, out, should_stop, on_done, limits):
    """One child running jobs start.. of the batch; fills `out` as jobs finish.
    limits[i]: seconds job i may run (the child's start counts toward its first job).
    -> (a job was started, the job running when it ended or None, return code,
    stderr tail, it was killed as stuck)."""
    global worker_launches
    err_path = os.path.join(folder, f"stderr_{start}.txt")
    try:
        with open(err_path, "wb") as err:
            proc = subprocess.Popen(
                _worker_command(folder, start), stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                stderr=err, env=_worker_env(),
                creationflags=getattr(subprocess, "CREATE_NO_WINDOW", 0))
    except OSError as e:
        return False, None, None, str(e), False
    worker_launches += 1
    lines = queue.Queue()
    # A thread reads the pipe so that the loop below can wake up for should_stop().
    threading.Thread(target=_pump, args=(proc.stdout, lines), daemon=True).start()
    started, running, stuck = False, None, False
    deadline = time.monotonic() + limits[start]
    try:
        while True:
            try:
                line = lines.get(timeout=_POLL_S)
            except queue.Empty:
                line = ""
            if should_stop is not None and should_stop():
                from ..core.errors import Cancelled
                raise Cancelled("UV unwrap cancelled")
            if line is None:
                break
            if time.monotonic() > deadline:
                stuck = True
                break
            parts = line.split()
            if len(parts) != 3 or parts[0] != _W.TAG or not parts[2].isdigit():
                continue  # anything else a host interpreter prints (Blender's banner)
            i = int(parts[2])
            if parts[1] == "start":
                if started:
                    deadline = time.monotonic() + limits[i]
                started, running = True, i
            elif parts[1] == "done":
                running = None
                out[i] = _read_result(folder, i)
                if on_done is not None:
                    on_done(i)
    finally:
        if proc.poll() is None:
            proc.kill()
        rc = proc.wait()
    return started, running, rc, _tail(err_path), stuck


def _run_jobs(arrays, n, should_stop=None, on_done=None):
    """Runs n worker jobs (the jobs.npz entries `arrays`, see xatlas_worker) in a
    child process -> per job a dict of result arrays or a _Failure.
    A job that kills the child fails; a new child runs the jobs after it. A job
    that runs past its stall_limit is tried once more in a new child (a hang
    need not repeat), then fails."""
    out = [None] * n
    limits = [stall_limit(len(arrays[f"t_{i}"])) for i in range(n)]
    retried = set()
    folder = tempfile.mkdtemp(prefix="photon_lightmaps_xatlas_")
    try:
        with open(os.path.join(folder, _W.JOBS_FILE), "wb") as fh:
            np.savez(fh, n=np.array(n), **arrays)
        start = 0
        while start < n:
            started, running, rc, err, stuck = _watch_worker(folder, start, out, should_stop,
                                                             on_done, limits)
            rest = [i for i in range(start, n) if out[i] is None]
            if not rest:
                break
            failed = []
            if stuck:
                job = rest[0] if running is None else running
                if job not in retried:
                    retried.add(job)
                    start = job
                    continue
                if started:
                    out[job] = _Failure(f"xatlas did not finish within {limits[job]:.0f} s, twice",
                                        _ADVICE, err)
                    failed, start = [job], job + 1
                else:
                    why = f"the xatlas worker did not start within {limits[job]:.0f} s, twice"
                    for i in rest:
                        out[i] = _Failure(why, _START_ADVICE, err)
                    failed, start = rest, n
            elif running is not None:
                why = _exit_reason(rc) if rc else "the xatlas worker stopped unexpectedly"
                out[running] = _Failure(why, _ADVICE, err)
                failed, start = [running], running + 1
            elif not started:
                # It died before its first job (no xatlas, unusable interpreter): a new
                # one would too.
                why = "the xatlas worker could not start"
                if rc:
                    why += f" (exit code {rc})" if 0 < rc < 0xC0000000 else f" ({_exit_reason(rc)})"
                for i in rest:
                    out[i] = _Failure(why, _START_ADVICE, err)
                failed, start = rest, n
            else:
                start = rest[0]  # ended between two jobs: go on where it stopped
            for i in failed:
                if on_done is not None:
                    on_done(i)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return out


# --------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------

def _prepare(vertices, triangles, resolution=None, texels_per_unit=None, padding=2, use_cache=True):
    v, t = _check_inputs(vertices, triangles)
    return (v, t) + _options(resolution, texels_per_unit, padding) + (bool(use_cache),)


def unwrap_many(jobs, progress=None, should_stop=None):
    """xatlas unwraps of many meshes -> list of AtlasResult or UnwrapError, in job order.

    jobs: each a dict of unwrap_atlas' keyword arguments (vertices, triangles,
    resolution, texels_per_unit, padding, use_cache) or a tuple of its positional
    ones. Cached meshes are answered here; all others go to one child process
    (a new one after a crash). progress(done, total) is called as jobs finish.
    should_stop() returning True kills the child and raises
    engine.core.errors.Cancelled.
    """
    jobs = list(jobs)
    n = len(jobs)
    results = [None] * n
    todo = {}   # cache key -> [v, t, options, store in cache, job indices]
    for i, job in enumerate(jobs):
        try:
            v, t, res, tpu, pad, use_cache = _prepare(**job) if isinstance(job, dict) else _prepare(*job)
        except UnwrapError as e:
            results[i] = e
            continue
        if t.shape[0] == 0:
            results[i] = AtlasResult(np.zeros((0, 3, 2)), np.zeros(0, np.int32), 1, 1, 1, 1)
            continue
        key = _key(v, t, res, tpu, pad)
        hit = _lookup(key, t.shape[0]) if use_cache else None
        if hit is not None:
            results[i] = _copy(hit)
            continue
        failed = _failures.get(key) if use_cache else None
        if failed is not None:
            results[i] = UnwrapError(failed.reason, t.shape[0], advice=failed.advice, detail=failed.detail)
            continue
        entry = todo.setdefault(key, [v, t, (res, tpu, pad), False, []])
        entry[3] |= use_cache
        entry[4].append(i)
    done = n - sum(len(e[4]) for e in todo.values())
    if progress is not None and done:
        progress(done, n)
    if not todo:
        return results
    entries = list(todo.items())
    arrays = {}
    for j, (_, (v, t, opts, _, _)) in enumerate(entries):
        arrays.update(_W.job_arrays(j, _W.UNWRAP, v, t, *opts))

    def on_done(j):
        nonlocal done
        done += len(entries[j][1][4])
        if progress is not None:
            progress(done, n)

    outs = _run_jobs(arrays, len(entries), should_stop, on_done)
    for (key, (v, t, _, store, idx)), out in zip(entries, outs):
        T = t.shape[0]
        if isinstance(out, _Failure):
            res = UnwrapError(out.reason, T, advice=out.advice, detail=out.detail)
            if out.advice == _ADVICE:         # xatlas itself failed, not a worker that cannot start
                _failures[key] = out
                while len(_failures) > _LRU_SIZE:
                    _failures.popitem(last=False)
        else:
            res = AtlasResult(out["uv"].astype(np.float64), out["chart"].astype(np.int32),
                              int(out["width"]), int(out["height"]), int(out["resolution"]),
                              int(out["min_resolution"]))
            if not _valid(res, T):
                res = UnwrapError("xatlas returned an invalid layout", T)
            elif store:
                _store(cache_dir() / f"{key}.npz", res)
                _remember(key, res)
        for i in idx:
            results[i] = res if isinstance(res, UnwrapError) else _copy(res)
    return results


def is_cached(vertices, triangles, resolution=None, texels_per_unit=None, padding=2):
    """True when unwrap_many would answer this mesh from the cache (no child process)."""
    try:
        v, t, res, tpu, pad, _ = _prepare(vertices, triangles, resolution, texels_per_unit, padding)
    except UnwrapError:
        return False
    return t.shape[0] == 0 or _lookup(_key(v, t, res, tpu, pad), t.shape[0]) is not None


def unwrap_atlas(vertices, triangles, resolution=None, texels_per_unit=None, padding=2,
                 use_cache=True):
    """xatlas unwrap of a mesh -> AtlasResult (see the namedtuple fields); raises UnwrapError.

    resolution: lightmap texels per side the atlas is meant for; charts are
    packed so that they stay at least MIN_GAP_TEXELS apart at that resolution
    (the atlas is repacked with a lower texel density if xatlas overshoots).
    texels_per_unit: fixes the texel density instead (object-space units);
    then use ``result.resolution`` as the lightmap size. Neither: DEFAULT_RESOLUTION.
    padding: xatlas padding in atlas texels (>= 2).
    """
    res = unwrap_many([dict(vertices=vertices, triangles=triangles, resolution=resolution,
                            texels_per_unit=texels_per_unit, padding=padding, use_cache=use_cache)])[0]
    if isinstance(res, UnwrapError):
        raise res
    return res


def unwrap(vertices, triangles, resolution=None, texels_per_unit=None, padding=2):
    """Per-triangle-corner lightmap UVs (T, 3, 2) in [0,1]², in the input triangle order.

    Faces xatlas ignores (zero area, repeated vertex) get UV (0, 0) at every
    corner; the lightmap gives such zero-UV-area triangles' world area to the
    texel under their UV centroid.
    """
    return unwrap_atlas(vertices, triangles, resolution, texels_per_unit, padding).uv


def pack_islands(vertices, triangles, corner_uv, island, resolution, padding=2, should_stop=None):
    """Packs given UV islands with xatlas (in the child process), scaling and placing
    each island whole -> (uv (T, 3, 2) in [0,1]², smallest lightmap side keeping
    the islands MIN_GAP_TEXELS apart). Raises UnwrapError.

    corner_uv: (T, 3, 2) corner coordinates in object units (islands keep their
    relative scale); island: (T,) island id per triangle; resolution: lightmap
    texels per side the packing is for. Not cached (callers cache the layer).
    """
    v, t = _check_inputs(vertices, triangles)
    T = t.shape[0]
    corner_uv = np.ascontiguousarray(corner_uv, np.float64)
    island = np.ascontiguousarray(island, np.int64).reshape(-1)
    if corner_uv.shape != (T, 3, 2) or island.shape != (T,):
        raise _bad_input(f"corner_uv must have shape ({T}, 3, 2) and island ({T},), "
                         f"got {corner_uv.shape} and {island.shape}")
    if not np.all(np.isfinite(corner_uv)):
        raise _bad_input("corner UVs contain NaN or infinity")
    resolution, _, padding = _options(resolution, None, padding)
    if T == 0:
        return np.zeros((0, 3, 2)), 1
    arrays = _W.job_arrays(0, _W.PACK, v, t, resolution, None, padding, corner_uv, island)
    out = _run_jobs(arrays, 1, should_stop)[0]
    if isinstance(out, _Failure):
        raise UnwrapError(out.reason, T, "packing the UV islands of", out.advice, out.detail)
    return out["uv"].astype(np.float64), int(out["min_resolution"])
