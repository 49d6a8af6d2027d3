"""Dask's preload for workers of photon passes and bakes (engine/cluster.py).

Dask loads this file by its path in each worker process before the worker
takes tasks, so it imports nothing of the add-on's by a relative name. It
makes the add-on importable as `photon_lightmaps` (an installed Blender
extension's folder has that name) and lets the worker read what a session
inside Blender pickles under bl_ext.<repository>.photon_lightmaps.
"""
import importlib
import pathlib
import sys

ADDON = pathlib.Path(__file__).resolve().parents[1]


def dask_setup(worker):
    try:
        cluster = importlib.import_module("photon_lightmaps.engine.cluster")
    except ImportError:
        sys.path.insert(0, str(ADDON.parent))
        cluster = importlib.import_module("photon_lightmaps.engine.cluster")
    cluster.install_aliases()
