"""Kernel compiles, observed.

numba compiles a kernel the first time a process meets one of its signatures
that the on-disk cache lacks, so a first run on a new machine or a new
version spends minutes in the compiler before anything shows. A KernelWatch
counts those compiles and their seconds (numba's "numba:compile" events; a
kernel loaded from the cache raises none), so the CLI and Blender can say
that the wait is compiling, and reports and tests can count it.
"""
import time
from contextlib import contextmanager

from numba.core import event


def _name(ev):
    d = (ev.data or {}).get("dispatcher")
    f = getattr(d, "py_func", None)
    return f"{f.__module__.rsplit('.', 1)[-1]}.{f.__qualname__}" if f is not None else "kernel"


class KernelWatch(event.Listener):
    """Counts kernel compiles. `on_compile(watch, name)` is called as each one
    starts; nested compiles (a kernel's callees) count once each, and their
    seconds count once, under the outermost."""

    def __init__(self, on_compile=None):
        self.started = 0
        self.compiled = 0
        self.seconds = 0.0
        self.by_kernel = {}         # name -> seconds, outermost compiles only
        self.on_compile = on_compile
        self._stack = []

    def on_start(self, ev):
        name = _name(ev)
        self.started += 1
        self._stack.append((name, time.perf_counter()))
        if self.on_compile is not None:
            self.on_compile(self, name)

    def on_end(self, ev):
        name, t0 = self._stack.pop()
        self.compiled += 1
        if not self._stack:
            dt = time.perf_counter() - t0
            self.seconds += dt
            self.by_kernel[name] = self.by_kernel.get(name, 0.0) + dt

    def summary(self):
        return {"compiled": self.compiled, "seconds": round(self.seconds, 2)}


@contextmanager
def watching(on_compile=None):
    """A KernelWatch listening for the duration of the block."""
    watch = KernelWatch(on_compile)
    with event.install_listener("numba:compile", watch):
        yield watch
