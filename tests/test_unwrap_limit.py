"""Renders never wait minutes on an unwrap: a mesh without lightmap UVs
above the scene's unwrap limit is lit through an automatic orientation lightmap,
no xatlas worker starts, the choice is reported, and the image agrees with the
xatlas-laid-out render."""
from dataclasses import replace

import numpy as np

from photon_lightmaps.engine import demo_scenes, session
from photon_lightmaps.engine import uv_atlas as UA
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.scene import translate


def _scene(n_theta, n_phi, limit, size=32):
    s = demo_scenes.cornell_box(width=size, height=size, with_primitives=False)
    s.add_object(demo_scenes.uv_sphere_mesh(0.3, n_theta, n_phi), translate(0.1, 0.1, -0.6), name="ball")
    s.prototypes[-1].meshes[0].name = "ball"
    return replace(s, unwrap_limit=limit)


def _render(scene, photons=200_000):
    st = session.Settings(photons=photons, samples=8, gather_rays=8, seed=3)
    cs = session.compile(scene)
    session.render_photon_pass(cs, st)
    return cs, session.render(cs, st)


def test_mesh_above_the_limit_gets_an_automatic_ol_and_no_xatlas_worker():
    UA.clear_memory_cache()
    before = UA.worker_launches
    cs = compile_scene(_scene(256, 512, limit=20_000))       # 261,632 triangles, the default limit
    assert UA.worker_launches == before
    rows = [r for r in cs.info["layouts"] if r["mesh"] == "ball"]
    assert len(rows) == 1 and rows[0]["layout"] == "orientation lightmap"
    assert rows[0]["triangles"] > 200_000 and "unwrap limit of 20,000" in rows[0]["reason"]
    assert [r["name"] for r in cs.info["orientation_lightmaps"]] == ["ball (automatic)"]
    assert not [w for w in cs.info["warnings"] if "ball" in w]   # a choice, not a failure
    assert cs.geometry.inst_lm_base[-1] == -1 and cs.orientation.inst_ol[-1] >= 0


def test_limit_zero_unwraps_and_a_cached_unwrap_is_used_above_the_limit():
    sc = _scene(16, 32, limit=0)
    cs = compile_scene(sc)
    assert [r["layout"] for r in cs.info["layouts"] if r["mesh"] == "ball"] == ["xatlas"]
    before = UA.worker_launches
    cs = compile_scene(replace(sc, unwrap_limit=100))       # cached now: no reason to skip it
    assert UA.worker_launches == before
    assert [r["layout"] for r in cs.info["layouts"] if r["mesh"] == "ball"] == ["xatlas"]
    assert cs.geometry.inst_lm_base[-1] >= 0


def test_automatic_ol_render_agrees_with_the_xatlas_render(monkeypatch, tmp_path):
    """Same ball (960 triangles), once unwrapped and once above a lowered limit:
    with the final gather the ball's own lightmap is read one bounce away, so
    the images differ by little. Bounds: the image mean within 2 %, and the
    ball's 4x4-pixel blocks within 6 % RMS."""
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path / "a"))
    _, a = _render(_scene(16, 32, limit=0))
    UA.clear_memory_cache()         # the unwrap just made must not count as cached
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path / "b"))
    cs, b = _render(_scene(16, 32, limit=100))
    assert [r["layout"] for r in cs.info["layouts"] if r["mesh"] == "ball"] == ["orientation lightmap"]
    ya, yb = a.mean(axis=2), b.mean(axis=2)
    rel_mean = abs(yb.mean() / ya.mean() - 1.0)
    H, W = ya.shape
    ba = ya.reshape(H // 4, 4, W // 4, 4).mean(axis=(1, 3))
    bb = yb.reshape(H // 4, 4, W // 4, 4).mean(axis=(1, 3))
    lit = ba > 0.05 * ba.max()
    rms = float(np.sqrt(np.mean(((bb[lit] - ba[lit]) / ba[lit]) ** 2)))
    print(f"mean {rel_mean:.4f}  block rms {rms:.4f}")
    assert rel_mean < 0.02 and rms < 0.06
