"""numba's kernel cache shared by processes (engine/core/kernel_cache.py): a save waits
for another process's save of the same kernel, and processes that compile
different signatures of one kernel at once leave an index whose every entry
loads its own machine code."""
import os
import subprocess
import sys
import textwrap
import threading
import time

import pytest

pytest.importorskip("fcntl", reason="the lock is fcntl's on POSIX (msvcrt's on Windows)")

import photon_lightmaps.engine  # noqa: F401,E402  (installs the lock)
from numba.core import caching  # noqa: E402

KERNEL = textwrap.dedent('''
    from numba import njit

    @njit(cache=True)
    def twice(x):
        return x + x
''')

# (type name, argument, result): each a signature of its own
SIGNATURES = [("int64", "3", "6"), ("float64", "1.5", "3.0"), ("complex128", "1j", "2j"),
              ("bool", "True", "2"), ("float32", "np.float32(0.25)", "0.5"), ("uint8", "np.uint8(7)", "14")]


def test_a_save_waits_for_another_process_holding_the_index(tmp_path):
    index = caching.IndexDataCacheFile(str(tmp_path), "k", ("stamp", 1))
    saved = threading.Event()
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, time\n"
                               f"f = open({index._index_path + '.lock'!r}, 'a+b')\n"
                               "fcntl.flock(f.fileno(), fcntl.LOCK_EX)\n"
                               "print('held', flush=True)\ntime.sleep(1.0)\n"],
                              stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    t0 = time.perf_counter()
    worker = threading.Thread(target=lambda: (index.save("key", b"data"), saved.set()))
    worker.start()
    assert not saved.wait(0.4)                  # blocked while the other process holds it
    worker.join(5)
    assert holder.wait(5) == 0
    assert saved.is_set() and time.perf_counter() - t0 >= 0.5
    assert index.load("key") == b"data"


def test_processes_compiling_one_kernel_at_once_keep_each_signature(tmp_path):
    (tmp_path / "kernel_mod.py").write_text(KERNEL)
    cache = tmp_path / "cache"
    go = tmp_path / "go"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    env.pop("NUMBA_BOUNDSCHECK", None)
    compile_one = ("import os, time\nimport numpy as np\nimport photon_lightmaps.engine\n"
                   "from kernel_mod import twice\n"
                   f"while not os.path.exists({str(go)!r}): time.sleep(0.005)\n"
                   "twice({arg})\n")
    procs = [subprocess.Popen([sys.executable, "-c", compile_one.format(arg=arg)], env=env)
             for _, arg, _ in SIGNATURES]
    time.sleep(2.0)             # all of them imported and waiting
    go.touch()
    assert all(p.wait(120) == 0 for p in procs)
    check = ("import numpy as np\nimport photon_lightmaps.engine\nfrom kernel_mod import twice\n"
             + "".join(f"assert repr(twice({arg})) == repr({res}), ({arg!r}, twice({arg}))\n"
                       for _, arg, res in SIGNATURES)
             + f"assert twice.stats.cache_hits and not twice.stats.cache_misses, twice.stats\n"
             f"assert len(twice.signatures) == {len(SIGNATURES)}\n")
    r = subprocess.run([sys.executable, "-c", check], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]


def test_a_second_copy_of_the_module_does_not_lock_twice(tmp_path):
    """The package can be imported under two names (the add-on folder and a symlink):
    a second copy's install must not wrap the save again, which would wait for itself."""
    import importlib.util

    from photon_lightmaps.engine.core import kernel_cache
    spec = importlib.util.spec_from_file_location("second_copy_of_kernel_cache", kernel_cache.__file__)
    copy = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(copy)
    copy.install()
    assert not hasattr(caching.IndexDataCacheFile.save.__wrapped__, "__wrapped__")
    index = caching.IndexDataCacheFile(str(tmp_path), "k", ("stamp", 1))
    worker = threading.Thread(target=index.save, args=("key", b"data"), daemon=True)
    worker.start()
    worker.join(10)
    assert not worker.is_alive() and index.load("key") == b"data"


def test_the_cache_folder_key_covers_every_sub_package(tmp_path):
    """The kernel cache folder is keyed by a digest of the engine's sources: an edit
    in any sub-package (a kernel inlined from there) must change it, or a stale
    kernel would load."""
    import shutil
    from photon_lightmaps import engine
    src = os.path.dirname(engine.__file__)
    copy = tmp_path / "engine"
    shutil.copytree(src, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert engine._source_digest(copy) == engine._source_digest()
    seen = {engine._source_digest(copy)}
    for rel in ("geometry/raycast.py", "core/sampling.py", "transport/texel_gather.py", "session.py"):
        with open(copy / rel, "a") as f:
            f.write("\n# edited\n")
        seen.add(engine._source_digest(copy))
    assert len(seen) == 5
    # a new module moved into a sub-package counts as well
    (copy / "lightmaps" / "new_module.py").write_text("X = 1\n")
    assert engine._source_digest(copy) not in seen
