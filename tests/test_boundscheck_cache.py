"""A bounds-checked run (NUMBA_BOUNDSCHECK=1, `make test-boundscheck`) never loads
a kernel compiled without bounds checking: numba's cache key ignores the flag, so
the engine gives checked kernels their own cache folder, also below a
NUMBA_CACHE_DIR the user set."""
import os
import subprocess
import sys
import textwrap

KERNEL = textwrap.dedent('''
    import numpy as np
    from numba import njit

    @njit(cache=True)
    def read(a, i):
        return a[i]
''')

RUN = textwrap.dedent('''
    import photon_lightmaps.engine        # sets the cache folder before numba compiles anything
    import numpy as np
    import oob_kernel
    try:
        oob_kernel.read(np.zeros(8)[:4], 5)    # past the view, inside its buffer: safe to read
        print("unchecked")
    except IndexError:
        print("checked")
''')


def run(tmp_path, env):
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")} | env
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), env.get("PYTHONPATH", "")])
    r = subprocess.run([sys.executable, "-c", RUN], env=env, capture_output=True, text=True,
                       timeout=300, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def test_checked_run_never_loads_an_unchecked_kernel(tmp_path):
    (tmp_path / "oob_kernel.py").write_text(KERNEL)
    cache = str(tmp_path / "cache")
    for preset in ({"NUMBA_CACHE_DIR": cache}, {"PHOTON_LIGHTMAPS_NUMBA_CACHE": cache}):
        assert run(tmp_path, preset) == "unchecked"        # compiles and caches the plain kernel
        assert any(os.scandir(cache))
        assert run(tmp_path, preset | {"NUMBA_BOUNDSCHECK": "1"}) == "checked"
        assert run(tmp_path, preset) == "unchecked"        # and the checked one did not replace it
