import os
import pathlib

# Compile numba kernels once per checkout, not once per test run.
os.environ.setdefault("NUMBA_CACHE_DIR", str(pathlib.Path(__file__).resolve().parents[1] / ".numba_cache"))
