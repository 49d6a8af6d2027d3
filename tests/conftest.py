import os
import pathlib
import sys

import pytest

# Compile numba kernels once per checkout and engine version, not once per run
# (the engine package keys the folder by a hash of its sources).
os.environ.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE",
                      str(pathlib.Path(__file__).resolve().parents[1] / ".numba_cache"))
import photon_lightmaps.engine  # noqa: E402,F401  (sets NUMBA_CACHE_DIR before numba loads)


def pytest_configure(config):
    # `pytest -m fuzz` selects the generated-scene fuzz sample (tests/test_fuzz.py)
    config.addinivalue_line("markers", "fuzz: generated broken scenes (benchmarks/fuzz.py)")


@pytest.fixture(autouse=True)
def _no_kept_bake_light():
    """Each test starts as a fresh Blender does: without a photon pass kept by an
    earlier bake (Keep Bake Light), which a test's own scene could otherwise reuse."""
    pipeline = sys.modules.get("photon_lightmaps.bake.pipeline")
    if pipeline is not None:
        pipeline.BAKE_LIGHT.clear()
    yield
