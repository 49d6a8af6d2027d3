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
