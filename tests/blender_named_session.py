"""Helper of test_cluster.py, run as a script: a session that names the add-on as Blender
does (bl_ext.user_default.photon_lightmaps), with `photon_lightmaps` itself not importable,
runs a multi-block photon pass and a bake's gathers on a local cluster -> arrays in argv[2]."""
import importlib.abc
import pathlib
import sys
import types

import numpy as np


class NoTopLevel(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "photon_lightmaps" or name.startswith("photon_lightmaps."):
            raise ModuleNotFoundError(f"no module named {name!r} (blocked: Blender names it otherwise)")
        return None


def main(root, out):
    import importlib.util
    sys.meta_path.insert(0, NoTopLevel())
    bl_ext = types.ModuleType("bl_ext")
    bl_ext.__path__ = []
    repo = types.ModuleType("bl_ext.user_default")
    repo.__path__ = []
    sys.modules.update({"bl_ext": bl_ext, "bl_ext.user_default": repo})
    # the package from this checkout's own files (their numba caches), under Blender's name
    name = "bl_ext.user_default.photon_lightmaps"
    spec = importlib.util.spec_from_file_location(name, pathlib.Path(root) / "__init__.py",
                                                  submodule_search_locations=[root])
    package = importlib.util.module_from_spec(spec)
    sys.modules[name] = package
    spec.loader.exec_module(package)
    from bl_ext.user_default.photon_lightmaps.engine import cluster, demo_scenes, session
    from bl_ext.user_default.photon_lightmaps.engine.transport import photon_tracer
    with cluster.Cluster.local(workers=2) as c:
        cs = session.compile(demo_scenes.cornell_box(n_bands=3, width=16, height=16))
        photon_tracer.trace_photons(cs, 50_000, seed=5, record_direct=True, caustics=True, gather=True,
                                    block=8192, cluster=c)
        flux = cs.lightmaps.flux.copy()
        settings = session.Settings(photons=50_000, bake_photons=50_000, seed=3, bake_gather_rays=4,
                                    bake_target_error=0.05)
        cs, _ = session.compile_and_trace_bake(demo_scenes.cornell_box(n_bands=3, width=16, height=16), settings)
        ids = sorted(int(lid) for lids in cs.instance_lightmaps for lid in lids)
        before = c.tasks
        with c.kernels():
            session.bake_texels(cs, ids, [], settings)
        assert c.tasks > before
        np.savez(out, flux=flux, baked=cs.lightmaps.irradiance, tasks=c.tasks)


if __name__ == "__main__":
    main(*sys.argv[1:])
