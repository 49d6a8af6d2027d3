"""Photon-tracing core of Photon Lightmaps. Imports without Blender (no bpy here)."""
import os
import pathlib

# numba reads NUMBA_CACHE_DIR when it is first imported: give it a writable
# per-user folder so kernels compile once (Blender's install dir may be read-only).
os.environ.setdefault("NUMBA_CACHE_DIR",
                      str(pathlib.Path.home() / ".cache" / "photon_lightmaps" / "numba"))
