"""A first run on an empty kernel cache, as a new user meets it: `warmup` compiles
every kernel family, and renders and bakes after it compile nothing.

It compiles everything into a cache of its own, so `make test` runs it in a
lane of its own (`make test-first-run`, with the extension install test),
beside the suite rather than inside it."""
import json
import os

from tests.test_cli_commands import TINY, run


def test_warmup_then_render_compiles_nothing(tmp_path):
    """On an empty kernel cache, `warmup` compiles every kernel family; renders after it
    compile nothing: the demo (meshes, spheres, a CSG solid, orientation lightmaps) and
    a textured scene of a kind the demo is not (no CSG)."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "kernels"))
    env.pop("PHOTON_LIGHTMAPS_NUMBA_CACHE", None)
    rep = tmp_path / "w.json"
    r = run("warmup", "--json", rep, env=env)
    report = json.loads(rep.read_text())
    from photon_lightmaps.engine import warmup
    n = len(warmup.FAMILIES)
    assert len(report["families"]) == n and all(f["seconds"] > 0 for f in report["families"])
    assert report["kernels"]["compiled"] > 50
    assert [ln for ln in r.stderr.splitlines() if ln.startswith(f"warmup {n}/{n}: done")]
    import bpy  # noqa: F401
    from photon_lightmaps import demo_blend, registration
    if not registration.is_registered():
        registration.register()
    demo = tmp_path / "demo.blend"
    demo_blend.build_cornell_blend(str(demo), width=12, height=8, spheres=True, csg=True, ol=True)
    blend = tmp_path / "textured.blend"
    demo_blend.build_spheres_blend(str(blend), width=12, height=8, textures=True)
    for name, path in (("demo", demo), ("textured", blend)):
        rr = tmp_path / f"{name}.json"
        run("render", path, "--out", tmp_path / f"{name}.png", "--json", rr, *TINY, "--samples", "2", env=env)
        assert json.loads(rr.read_text())["kernels"] == {"compiled": 0, "seconds": 0.0}, name
    rb = tmp_path / "bake.json"
    run("bake", demo, "--out", tmp_path / "maps", "--json", rb, *TINY, "--resolution", "8",
        "--bake-gather-rays", "2", env=env)
    assert json.loads(rb.read_text())["kernels"] == {"compiled": 0, "seconds": 0.0}


AHEAD = """
import json, sys
from photon_lightmaps.engine import demo_scenes, session, warmup
from photon_lightmaps.engine.core import kernel_watch
scene = demo_scenes.cornell_box(width=16, height=16, with_primitives=False)
settings = session.Settings(photons=5000, samples=1)
with kernel_watch.watching() as watch:
    cs = session.compile(scene, ahead=("render",))
    helper = warmup._ahead.get((0, "render"), (None,))[0]
    session.render_photon_pass(cs, settings)
    before = watch.compiled
    image = session.render(cs, settings)
json.dump({"helper": helper is not None and helper.error is None, "before": before,
           "during": watch.compiled - before, "mean": float(image.mean())}, sys.stdout)
"""


def test_a_first_render_compiles_its_render_pass_in_a_second_process(tmp_path):
    """On an empty cache, a render's compile starts a helper process on the render
    pass's kernels while the host compiles and runs its photon pass; the render
    then loads them and compiles nothing (engine/warmup.py, ahead)."""
    import subprocess
    import sys
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "kernels"))
    env.pop("PHOTON_LIGHTMAPS_NUMBA_CACHE", None)
    r = subprocess.run([sys.executable, "-c", AHEAD], env=env, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout)
    assert out["helper"] and out["before"] > 50 and out["during"] == 0, out
    assert out["mean"] > 0.0
    assert (tmp_path / "kernels" / "compiled-0-render").is_file()
