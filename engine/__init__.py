"""Photon-tracing core of Photon Lightmaps. Imports without Blender (no bpy here).

Packages, lowest rank first; each imports only from its own rank or below
(tests/test_architecture.py): `core` (scene description, errors, kernel
compilation, sampling), `lsystem` (grammars, turtle, presets), `geometry` (what
rays meet, and ray casting), `lightmaps` (where light is stored), `shading`
(materials, BSDFs, lights, environment), `transport` (photon pass, camera pass,
gathers). The modules here are the pipeline: `compile` turns a `Scene` into
kernel arrays and `session` runs compile -> photons -> gathers -> render or bake.
"""
import hashlib
import os
import pathlib
import sys


def _source_digest(root=None):
    """Hash of the engine's sources, sub-packages included. numba's cache only
    tracks the file a kernel is defined in, not the kernels it inlines from other
    modules, so after an upgrade a stale cache entry can run old traversal code:
    keying the cache folder by all sources makes every version compile into its
    own folder."""
    h = hashlib.sha1()
    root = pathlib.Path(root or pathlib.Path(__file__).parent)
    for p in sorted(root.rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:12]


# numba reads NUMBA_CACHE_DIR when it is first imported: give it a writable
# per-user folder (Blender's install dir may be read-only).
_base = os.environ.get("PHOTON_LIGHTMAPS_NUMBA_CACHE") or str(
    pathlib.Path.home() / ".cache" / "photon_lightmaps" / "numba")
# Bounds-checked kernels (NUMBA_BOUNDSCHECK=1, `make test-boundscheck`) are
# different machine code under the same cache key (numba's key ignores the
# flag): keep them in their own folder, also below a NUMBA_CACHE_DIR set by hand,
# so a checked run can never load unchecked code.
_flavour = "-boundscheck" if os.environ.get("NUMBA_BOUNDSCHECK", "0") not in ("", "0") else ""
if os.environ.get("NUMBA_CACHE_DIR"):
    if _flavour and os.path.basename(os.environ["NUMBA_CACHE_DIR"]) != "boundscheck":
        os.environ["NUMBA_CACHE_DIR"] = os.path.join(os.environ["NUMBA_CACHE_DIR"], "boundscheck")
else:
    os.environ["NUMBA_CACHE_DIR"] = os.path.join(_base, _source_digest() + _flavour)
if _flavour and "numba" in sys.modules:      # numba read the variable when it was imported
    sys.modules["numba"].config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]

# Helper processes compile into the same cache folder (engine/warmup.py).
from .core import kernel_cache  # noqa: E402

kernel_cache.install()
