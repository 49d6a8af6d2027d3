"""Which kinds of geometry a compiled scene holds, as a type the kernels specialise on.

numba compiles a kernel once per combination of argument types, and compile
time is most of a first render's wait. The traversal reaches CSG solids and
L-system graphs through their own cores, about 30 s of compiling; a scene of
meshes and primitives never needs them. So the trace buffer carries a marker
whose *type* says what the scene holds (an empty array whose rank is the
feature mask plus one: a type numba and its on-disk cache already know), and
the traversal calls those cores through gates (`@overload`) that compile to
nothing for a scene without them.
"""
import numpy as np

CSG = 1          # exact CSG solids (engine/geometry/csg.py)
DCSG = 2         # L-systems as cyclic scene graphs (engine/geometry/dcsg.py)
ALL = CSG | DCSG


def marker(mask):
    """The value that stands for feature `mask` in a trace buffer."""
    mask = int(mask)
    if not 0 <= mask <= ALL:
        raise ValueError(f"feature mask must be in [0, {ALL}], got {mask}")
    return np.zeros((0,) * (mask + 1), np.uint8)


def mask_of(marker_type):
    """The feature mask of a marker's numba type (at typing time)."""
    return marker_type.ndim - 1


def has(marker_type, feature):
    """True if a marker's numba type includes `feature` (CSG or DCSG)."""
    return bool(mask_of(marker_type) & feature)
