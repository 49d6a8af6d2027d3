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
import functools
import hashlib
import pathlib
import re

from .core.errors import Cancelled, SceneError

ENGINE = pathlib.Path(__file__).resolve().parent


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


class Cluster:
    """A connection to a Dask cluster that photon passes run on (trace_photons(cluster=...)).

    Cluster.connect("tcp://host:8786") joins a running scheduler; Cluster.local(n)
    starts n worker processes on this machine (loopback only). Use it as a context
    manager, or close() it."""

    def __init__(self, client, cluster=None):
        self.client = client
        self._own = cluster
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
                                           processes=True, host="127.0.0.1", dashboard_address=":0")
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

    def render_tiles(self, cs, records, tiles):
        """The tiles (renderer.Tile) of a render of cs, each a task -> their (samples, rays) in
        tile order, as each arrives; closing the iterator early cancels what is left."""
        client = self.client
        scene, recs = client.scatter([cs, records], broadcast=True, hash=False)
        version = engine_version()
        futures = [client.submit(_worker_tile, scene, recs, t, version, pure=False) for t in tiles]
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
        async with distributed.Nanny(scheduler, nthreads=nthreads) as nanny:
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
    return _open[spec]


@atexit.register
def close_all():
    while _open:
        _open.popitem()[1].close()
