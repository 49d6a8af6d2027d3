"""Memory refused up front: big allocations are checked against what the machine has.

numpy's zeros() of a few hundred GiB succeeds on Linux (pages are mapped
lazily) and the process is killed later by the OOM killer, Blender and the
user's unsaved work with it. So every allocation that grows with a user
setting (texel density, resolution, samples, photons kept) is estimated
first and refused with the estimate and what to lower, before anything is
allocated.
"""
import os
import sys

from .scene import SceneError

# Share of the memory available now that one render may take: Blender, the
# scene and the kernels' own buffers need the rest.
USABLE_FRACTION = 0.7


class BudgetError(SceneError):
    """A setting would need more memory than the machine has (names the setting)."""


def available_bytes():
    """Memory available to this process now (physical memory where the OS will not say)."""
    override = os.environ.get("PHOTON_LIGHTMAPS_MEMORY_LIMIT")
    if override:                        # tests and shared machines
        return int(float(override))
    if sys.platform.startswith("linux"):
        try:
            with open("/proc/meminfo") as f:
                for line in f:
                    if line.startswith("MemAvailable:"):
                        return int(line.split()[1]) * 1024
        except OSError:
            pass
    if sys.platform == "win32":
        import ctypes

        class Status(ctypes.Structure):
            _fields_ = [("dwLength", ctypes.c_ulong), ("dwMemoryLoad", ctypes.c_ulong)] + [
                (n, ctypes.c_ulonglong) for n in ("ullTotalPhys", "ullAvailPhys", "ullTotalPageFile",
                                                  "ullAvailPageFile", "ullTotalVirtual",
                                                  "ullAvailVirtual", "ullAvailExtendedVirtual")]
        st = Status()
        st.dwLength = ctypes.sizeof(st)
        if ctypes.windll.kernel32.GlobalMemoryStatusEx(ctypes.byref(st)):
            return int(st.ullAvailPhys)
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):
        return 1 << 62                  # unknown: do not refuse


def gib(n):
    return f"{n / 2 ** 30:.1f} GiB" if n >= 2 ** 30 else f"{n / 2 ** 20:.1f} MiB"


def check(what, need_bytes, fix):
    """Raises BudgetError "<what>: needs X, Y available; <fix>" when need_bytes is too much.

    fix: what to lower, or a callable (budget_bytes) -> that text, so the
    message can say how far."""
    budget = int(available_bytes() * USABLE_FRACTION)
    need = int(need_bytes)
    if need <= budget:
        return
    text = fix(budget) if callable(fix) else fix
    raise BudgetError(f"{what}: needs about {gib(need)}, but only {gib(budget)} of memory can be "
                      f"used; {text}")
