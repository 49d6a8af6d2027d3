"""numba's on-disk kernel cache, shared safely by several processes.

The warm-up compiles kernel families in helper processes while the host
renders (engine/warmup.py), all into one cache folder. numba updates a
kernel's index file by reading it, picking the first free data-file number
and writing both back; two processes that save different signatures of one
kernel at the same moment can both pick number 1, and the index then pairs
one signature with the other's machine code. Loading that would call a
kernel with the wrong argument types. `install` puts every save under an
exclusive lock on a file beside the index, so the read-pick-write is atomic
across processes. Reads need no lock: numba writes each file whole and
renames it into place, and a data file not written yet reads as a miss.
"""
import contextlib
import os

# marks numba's save once it is ours: the package can be imported under two
# names (an add-on folder and its symlink), each with its own copy of this module
_MARK = "_photon_lightmaps_locked"


@contextlib.contextmanager
def _exclusive(path):
    try:
        f = open(path, "a+b")
    except OSError:             # a read-only cache: numba's own save fails the same way
        yield
        return
    try:
        if os.name == "nt":
            import msvcrt
            f.seek(0)
            try:
                msvcrt.locking(f.fileno(), msvcrt.LK_LOCK, 1)
            except OSError:     # gave up after its ten tries: save as numba would
                pass
        else:
            import fcntl
            fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        yield
    finally:
        f.close()               # closing releases the lock


def install():
    """Makes numba's cache saves exclusive across processes (once per process)."""
    from numba.core import caching
    save = caching.IndexDataCacheFile.save
    if getattr(save, _MARK, False):
        return

    def locked_save(self, key, data):
        with _exclusive(self._index_path + ".lock"):
            return save(self, key, data)
    locked_save.__wrapped__ = save
    setattr(locked_save, _MARK, True)
    caching.IndexDataCacheFile.save = locked_save
