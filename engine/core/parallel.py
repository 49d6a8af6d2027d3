"""Parallel loops over an index range, on threads of our own.

The scene kernels (photon pass, render tiles, bake gathers) take the compiled
scene: about 150 arrays in named tuples. numba's `prange` lowering of such a
kernel costs 35-50 s of LLVM time per kernel on a first run, because the
parallel launcher handles every array of every tuple; the same loop compiled
serial with `nogil=True` takes about 5 s. So those kernels are serial over a
sub-range `[start, stop)`, and `run` hands sub-ranges to a thread pool: the
kernels release the GIL, so the threads run side by side.

Each index writes only its own outputs, so the result does not depend on the
number of threads or their scheduling. The thread count is numba's
(`numba.set_num_threads`, NUMBA_NUM_THREADS), read in the calling thread.
"""
import contextlib
import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numba

# blocks per thread: enough that a slow block (a texel behind glass, a pixel
# on a caustic) does not leave the other threads idle, few enough that the
# per-call cost (numba types every argument) stays negligible
BLOCKS_PER_THREAD = 8

_PREFIX = "photon_lightmaps"
_pool = None
_pool_lock = threading.Lock()


def _forget_pool():
    # a forked child (multiprocessing's fork start, e.g. the fuzz workers)
    # inherits the pool object but none of its threads: it must make its own
    global _pool, _pool_lock
    _pool = None
    _pool_lock = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool)


def threads():
    """Threads a parallel loop started from this thread uses."""
    return max(1, int(numba.get_num_threads()))


def _executor():
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=max(1, int(numba.config.NUMBA_NUM_THREADS)),
                                       thread_name_prefix=_PREFIX)
        return _pool


def blocks(n, n_threads=None, min_block=1):
    """[start, stop) blocks covering range(n), in order."""
    n = int(n)
    if n <= 0:
        return []
    t = threads() if n_threads is None else max(1, int(n_threads))
    k = 1 if t == 1 else min(t * BLOCKS_PER_THREAD, max(1, n // max(1, int(min_block))))
    edges = [n * j // k for j in range(k + 1)]
    return [(edges[j], edges[j + 1]) for j in range(k) if edges[j + 1] > edges[j]]


def run(kernel, n, *args, min_block=1, remote=False):
    """kernel(*args, start, stop) over blocks of range(n), on the pool.

    `kernel` is a serial, nogil numba kernel that handles indices start..stop-1.
    Returns once every block is done; an exception in a block is raised here.
    remote: the call may go to the machines of an active `remote` context
    (a Dask cluster, engine/cluster.py); the kernel's outputs must be its
    array arguments (or arrays in plain tuples of them), which holds for the
    bake gathers that pass it."""
    runner = getattr(_remote, "runner", None)
    if remote and runner is not None and runner(kernel, int(n), args):
        return
    run_range(kernel, 0, n, *args, min_block=min_block)


def run_range(kernel, first, last, *args, min_block=1):
    """run() over indices first..last-1 only."""
    parts = [(first + a, first + b) for a, b in blocks(int(last) - int(first), min_block=min_block)]
    if len(parts) <= 1 or threading.current_thread().name.startswith(_PREFIX):
        # one block, or called from a pool thread (waiting on the pool there could deadlock)
        for start, stop in parts:
            kernel(*args, start, stop)
        return
    # as many lanes as this thread's thread count, each taking the next block:
    # numba.set_num_threads(k) holds, whatever the pool's size
    todo = iter(parts)
    lock = threading.Lock()

    def lane():
        while True:
            with lock:
                part = next(todo, None)
            if part is None:
                return
            kernel(*args, *part)
    futures = [_executor().submit(lane) for _ in range(min(threads(), len(parts)))]
    for f in futures:
        f.result()


# the runner of this thread's `remote` context: runner(kernel, n, args) -> True
# when it ran the call (False: too small to be worth sending; run here)
_remote = threading.local()


@contextlib.contextmanager
def remote(runner):
    """Within: run(..., remote=True) calls made from this thread go to runner."""
    before = getattr(_remote, "runner", None)
    _remote.runner = runner
    try:
        yield
    finally:
        _remote.runner = before
