"""Photon passes on a Dask cluster (`dask.distributed`): more machines, the same result.

A photon pass is blocks of photons traced from their own random streams
(photon_tracer.trace_photons): each block's tally starts from zero, and the
tallies are added over a fixed binary tree of block indices. Here the compiled
scene goes to every worker once per pass (a broadcast scatter), each block is
a task, and each node of the tree is a task that adds its two children, so
only the root comes back. The tree's shape depends on the number of blocks
alone, so a pass gives the same lightmaps, bit for bit, as the same pass run
locally, on any number of workers, and a task the scheduler reruns after its
worker died gives what the lost one would have.

Workers need the core (numpy, numba; not Blender) at the same version: the
hash of the engine's source (`engine_version`) is compared with every
worker's when a cluster is opened, and again by each task, and a worker that
differs is refused by name. Dask is optional: nothing else imports this
module.
"""
import atexit
import contextlib
import functools
import hashlib
import importlib
import importlib.abc
import pathlib
import re
import time

import numpy as np

from .core.errors import Cancelled, SceneError

ENGINE = pathlib.Path(__file__).resolve().parent
WORKER_SETUP = str(ENGINE / "worker_setup.py")     # the workers' Dask preload


class ClusterError(SceneError):
    """A cluster that cannot run the pass: unreachable, or a worker at another version."""


@functools.lru_cache(maxsize=1)
def engine_version():
    """sha256 of the engine's Python source (every engine/**/*.py, by relative path)."""
    h = hashlib.sha256()
    for path in sorted(ENGINE.rglob("*.py")):
        h.update(str(path.relative_to(ENGINE)).encode())
        h.update(b"\0")
        h.update(path.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def _require_dask():
    try:
        import distributed
    except ImportError:
        raise ClusterError("a cluster needs Dask: pip install 'distributed' (dask.distributed) "
                           "beside the add-on's other packages") from None
    return distributed


def _on_worker(version):
    """A task's start: refuses a worker of another engine version; numba gets the worker's threads."""
    import numba
    from distributed import get_worker
    ours = engine_version()
    if ours != version:
        raise ClusterError(f"worker {get_worker().address} runs engine {ours[:12]}, the session {version[:12]}")
    numba.set_num_threads(max(1, min(get_worker().state.nthreads, numba.config.NUMBA_NUM_THREADS)))


def _worker_block(cs, plan, start, stop, version):
    """A task: photons start..stop-1 of the pass."""
    from .transport import photon_tracer
    _on_worker(version)
    return photon_tracer.trace_block(cs, plan, start, stop)


def _worker_tile(cs, records, tile, version):
    """A task: one tile of a render."""
    from .transport import renderer
    _on_worker(version)
    return renderer.render_tile(cs, records, tile)


_ENGINE_PKG = __name__.rsplit(".", 1)[0]
_ADDON_PKG = _ENGINE_PKG.rsplit(".", 1)[0]      # photon_lightmaps, or bl_ext.<repository>.photon_lightmaps
ADDON_NAME = "photon_lightmaps"


class _PackageAlias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports of the add-on under another name, as the modules this process has.

    Inside Blender the add-on is the package bl_ext.<repository>.photon_lightmaps;
    on a worker it is photon_lightmaps. Dask pickles functions and classes by
    their module's name, so each side must find the other's names: they import
    as the same module objects (and bl_ext, bl_ext.<repository> as empty packages)."""

    def __init__(self, pattern, parents=()):
        self.pattern = re.compile(pattern)
        self.parents = [re.compile(p) for p in parents]

    def find_spec(self, name, path=None, target=None):
        import importlib.util
        m = self.pattern.fullmatch(name)
        if m is not None:
            module = importlib.import_module(_ADDON_PKG + (m.group(1) or ""))
            return importlib.util.spec_from_loader(name, self, is_package=hasattr(module, "__path__"))
        if any(p.fullmatch(name) for p in self.parents):
            return importlib.util.spec_from_loader(name, self, is_package=True)
        return None

    def create_module(self, spec):
        m = self.pattern.fullmatch(spec.name)
        return None if m is None else importlib.import_module(_ADDON_PKG + (m.group(1) or ""))

    def exec_module(self, module):
        pass


def install_aliases():
    """Lets this process read what a process that names the add-on otherwise has
    pickled (_PackageAlias); once per process."""
    import sys
    if any(isinstance(f, _PackageAlias) for f in sys.meta_path):
        return
    if _ADDON_PKG == ADDON_NAME:         # a worker (or a session outside Blender)
        alias = _PackageAlias(r"bl_ext\.[A-Za-z0-9_]+\." + ADDON_NAME + r"(\..+)?",
                              parents=[r"bl_ext", r"bl_ext\.[A-Za-z0-9_]+"])
    else:                                # a session inside Blender
        alias = _PackageAlias(ADDON_NAME + r"(\..+)?")
    sys.meta_path.insert(0, alias)


def dask_setup(worker):
    """Dask's preload hook (worker_setup.py): a worker reads the session's names."""
    install_aliases()


# A bake gather's call goes to the cluster in at most TASKS_PER_WORKER tasks per
# worker, each of at least MIN_TASK_ITEMS items (texels, records); smaller calls
# run here, where they cost less than a task's round trip.
TASKS_PER_WORKER = 2
MIN_TASK_ITEMS = 64


def _kernel_name(kernel):
    """A kernel's module (relative to the engine package) and name: inside Blender
    the package is bl_ext.<repository>.photon_lightmaps, on a worker photon_lightmaps."""
    f = getattr(kernel, "py_func", kernel)
    module = f.__module__
    if not module.startswith(_ENGINE_PKG + "."):
        raise ValueError(f"{module}.{f.__name__}: only engine kernels run on a cluster")
    return module[len(_ENGINE_PKG):], f.__name__


def _writable(args):
    """(slot, index in a plain tuple or None, array) of each array a kernel may write:
    the top-level array arguments and the arrays in plain tuples (parallel.run)."""
    for i, a in enumerate(args):
        if isinstance(a, np.ndarray) and a.ndim:
            yield i, None, a
        elif type(a) is tuple:
            for j, b in enumerate(a):
                if isinstance(b, np.ndarray) and b.ndim:
                    yield i, j, b


def _changed_rows(before, after):
    """Indices along the first axis where `after` differs from `before`, bit for bit."""
    if before.size == 0:
        return np.zeros(0, np.int64)
    a = np.ascontiguousarray(before).reshape(before.shape[0], -1).view(np.uint8)
    b = np.ascontiguousarray(after).reshape(after.shape[0], -1).view(np.uint8)
    return np.flatnonzero(np.any(a != b, axis=1))


def _worker_kernel(module, name, start, stop, version, *args):
    """A task: kernel indices start..stop-1 on copies of its writable arrays -> the
    rows each changed, [(slot, index, rows, values)] (the broadcast inputs are
    shared by this worker's tasks, so they are not written)."""
    from .core import parallel
    _on_worker(version)
    kernel = getattr(importlib.import_module(_ENGINE_PKG + module), name)
    args = list(args)
    copies = []
    for i, j, a in list(_writable(args)):
        c = a.copy()
        if j is None:
            args[i] = c
        else:
            args[i] = (*args[i][:j], c, *args[i][j + 1:])
        copies.append((i, j, a, c))
    parallel.run_range(kernel, start, stop, *args)
    out = []
    for i, j, a, c in copies:
        rows = _changed_rows(a, c)
        if rows.size:
            out.append((i, j, rows, c[rows]))
    return out


class Cluster:
    """A connection to a Dask cluster that photon passes run on (trace_photons(cluster=...)).

    Cluster.connect("tcp://host:8786") joins a running scheduler; Cluster.local(n)
    starts n worker processes on this machine (loopback only). Use it as a context
    manager, or close() it."""

    def __init__(self, client, cluster=None):
        install_aliases()               # results pickled by workers, read inside Blender
        self.client = client
        self._own = cluster
        self.tasks = 0          # tasks submitted (photon blocks, tiles, gather ranges; not tree nodes)
        self.check_versions()

    @classmethod
    def connect(cls, address, timeout=30):
        distributed = _require_dask()
        try:
            client = distributed.Client(address, timeout=timeout)
        except (OSError, TimeoutError) as e:
            raise ClusterError(f"cluster {address}: cannot connect ({e}); start a scheduler there "
                               "(dask-scheduler) and workers (python -m photon_lightmaps worker)") from None
        return cls(client)

    @classmethod
    def local(cls, workers=2, threads_per_worker=1):
        distributed = _require_dask()
        cluster = distributed.LocalCluster(n_workers=int(workers), threads_per_worker=int(threads_per_worker),
                                           processes=True, host="127.0.0.1", dashboard_address=":0",
                                           preload=[WORKER_SETUP])
        return cls(distributed.Client(cluster), cluster)

    def check_versions(self):
        """Refuses (ClusterError) a cluster whose workers run another engine, naming them."""
        ours = engine_version()
        theirs = self.client.run(engine_version)
        bad = sorted(addr for addr, v in theirs.items() if v != ours)
        if bad:
            raise ClusterError("; ".join(f"worker {addr} runs another version of the engine (source hash "
                                         f"{theirs[addr][:12]}, this session {ours[:12]})" for addr in bad)
                               + ": start workers from this version (python -m photon_lightmaps worker)")
        return theirs

    @property
    def workers(self):
        return len(self.client.scheduler_info().get("workers", {}))

    def close(self):
        # futures are released asynchronously: let those releases reach the scheduler
        # first, or it reports the scattered scene as lost when the workers stop
        deadline = time.monotonic() + 2.0
        while self.client.refcount and time.monotonic() < deadline:
            time.sleep(0.02)
        self.client.close()
        if self._own is not None:
            self._own.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def photon_pass(self, cs, plan, blocks, progress=None):
        """The blocks [(start, stop), ...] of pass `plan` on compiled scene cs, added over
        the fixed tree (photon_tracer.reduce_blocks) -> Partial. progress(done, total)
        after each block; False cancels the cluster's tasks (raises Cancelled)."""
        from distributed import as_completed
        from .transport import photon_tracer
        client = self.client
        [scene] = client.scatter([cs], broadcast=True, hash=False)
        version = engine_version()
        leaves = [client.submit(_worker_block, scene, plan, start, stop, version, pure=False)
                  for start, stop in blocks]
        self.tasks += len(leaves)
        root = photon_tracer.reduce_blocks(
            lambda k: leaves[k], len(leaves),
            add=lambda a, b: client.submit(photon_tracer.add_partials, a, b, pure=False))
        size = {f.key: stop - start for f, (start, stop) in zip(leaves, blocks)}
        total = sum(stop - start for start, stop in blocks)
        done = 0
        try:
            for f in as_completed(leaves):
                if f.status == "error":
                    f.result()                  # raises the task's error (a version refused)
                done += size[f.key]             # (the block's tally stays on its worker)
                if progress is not None and progress(done, total) is False:
                    raise Cancelled("photon pass cancelled")
            return root.result()
        except BaseException:
            client.cancel([*leaves, root])
            raise
        finally:
            scene.release()                 # the broadcast scene leaves the workers' memory

    @contextlib.contextmanager
    def kernels(self, should_stop=None):
        """Within: parallel.run(..., remote=True) calls made from this thread (a bake's
        direct and final gathers) run on the cluster, each split into index ranges
        that are tasks. A task changes rows of its outputs, and they come back
        alone; each index writes only its own outputs (parallel.run), so the result
        is the local run's, bit for bit. Objects other than the outputs (the scene,
        texel lists) go to every worker once per context, so they must not change
        while it is open. should_stop() -> True, asked as tasks finish, cancels the
        call's tasks and raises Cancelled, the outputs untouched."""
        from .core import parallel
        shared = {}                     # id(obj) -> (obj, its future on every worker)
        try:
            with parallel.remote(functools.partial(self._run_kernel, shared, should_stop)):
                yield self
        finally:
            for _obj, future in shared.values():
                future.release()

    def _run_kernel(self, shared, should_stop, kernel, n, args):
        client = self.client
        n_tasks = min(TASKS_PER_WORKER * self.workers, n // MIN_TASK_ITEMS)
        if n_tasks < 1:
            return False
        module, name = _kernel_name(kernel)
        fresh, sent = [], []
        for a in args:
            if isinstance(a, (bool, int, float, np.generic)) or (type(a) is tuple and not any(
                    isinstance(b, np.ndarray) for b in a)):
                sent.append(a)                  # numbers and small tuples of them
            elif isinstance(a, np.ndarray) or type(a) is tuple:
                [f] = client.scatter([a], broadcast=True, hash=False)      # outputs: their current contents
                fresh.append(f)
                sent.append(f)
            else:
                if id(a) not in shared:         # the scene, texel lists (named tuples)
                    [f] = client.scatter([a], broadcast=True, hash=False)
                    shared[id(a)] = (a, f)      # (held: its id is not reused while the context lasts)
                sent.append(shared[id(a)][1])
        edges = [n * k // n_tasks for k in range(n_tasks + 1)]
        version = engine_version()
        futures = [client.submit(_worker_kernel, module, name, edges[k], edges[k + 1], version, *sent, pure=False)
                   for k in range(n_tasks)]
        self.tasks += n_tasks
        try:
            from distributed import as_completed
            changes = []
            for f in as_completed(futures):
                changes.append(f.result())
                if should_stop is not None and should_stop():
                    raise Cancelled("bake cancelled")
            for change in changes:
                for i, j, rows, values in change:
                    (args[i] if j is None else args[i][j])[rows] = values
        except BaseException:
            client.cancel(futures)
            raise
        finally:
            for f in fresh:
                f.release()
        return True

    def render_tiles(self, cs, records, tiles):
        """The tiles (renderer.Tile) of a render of cs, each a task -> their (samples, rays) in
        tile order, as each arrives; closing the iterator early cancels what is left."""
        client = self.client
        scene, recs = client.scatter([cs, records], broadcast=True, hash=False)
        version = engine_version()
        futures = [client.submit(_worker_tile, scene, recs, t, version, pure=False) for t in tiles]
        self.tasks += len(futures)
        try:
            for f in futures:
                yield f.result()
        finally:
            client.cancel([f for f in futures if not f.done()])
            scene.release()
            recs.release()


def run_worker(scheduler, nthreads=None):
    """A worker (under a nanny, which restarts it if it dies) that joins `scheduler` and
    serves photon passes until the scheduler or a signal stops it."""
    import asyncio
    import os
    distributed = _require_dask()
    nthreads = int(nthreads or os.cpu_count() or 1)
    print(f"photon_lightmaps worker: engine {engine_version()[:12]}, {nthreads} threads, scheduler {scheduler}",
          flush=True)

    async def serve():
        async with distributed.Nanny(scheduler, nthreads=nthreads, preload=[WORKER_SETUP]) as nanny:
            await nanny.finished()
    asyncio.run(serve())


_open = {}


def open_cluster(spec):
    """The Cluster for `spec` (a scheduler's address, or "local:N"), opened once per
    process and closed at exit."""
    spec = str(spec).strip()
    if spec not in _open:
        m = re.fullmatch(r"local:(\d+)", spec)
        if m:
            if not 1 <= int(m.group(1)) <= 256:
                raise ClusterError(f"cluster '{spec}': a local cluster has 1 to 256 workers")
            _open[spec] = Cluster.local(int(m.group(1)))
        elif re.fullmatch(r"(tcp|tls|ucx|inproc)://\S+", spec):
            _open[spec] = Cluster.connect(spec)
        else:
            raise ClusterError(f"cluster '{spec}': give a scheduler's address (tcp://host:8786) or local:N")
        # registered after Dask's own exit handlers (atexit runs the last first), so
        # the clusters close while Dask can still release their data cleanly
        atexit.unregister(close_all)
        atexit.register(close_all)
    return _open[spec]


def close_all():
    while _open:
        _open.popitem()[1].close()
