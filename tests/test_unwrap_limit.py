"""Renders never wait minutes on an unwrap, and dense meshes keep their own
light: a mesh without lightmap UVs above the scene's unwrap limit gets the fast
box-projection layout (engine/lightmaps/fast_layout.py), no xatlas worker starts, the
choice is reported, and the image agrees with the xatlas-laid-out render."""
from dataclasses import replace

import numpy as np

from photon_lightmaps.engine import demo_scenes, session
from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine.lightmaps import uv_atlas
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.core.scene import translate


def _scene(n_theta, n_phi, limit, size=32):
    s = demo_scenes.cornell_box(width=size, height=size, with_primitives=False)
    # On the floor (z = 0), in view: the room is the cube [-1, 1]² × [0, 2].
    s.add_object(demo_scenes.uv_sphere_mesh(0.3, n_theta, n_phi), translate(0.1, 0.1, 0.32), name="ball")
    s.prototypes[-1].meshes[0].name = "ball"
    return replace(s, unwrap_limit=limit)


def _render(scene, photons=200_000):
    st = session.Settings(photons=photons, samples=8, gather_rays=8, seed=3)
    cs = session.compile(scene)
    session.render_photon_pass(cs, st)
    return cs, session.render(cs, st)


def _blocks(img, k=4):
    y = img.mean(axis=2)
    H, W = y.shape
    return y.reshape(H // k, k, W // k, k).mean(axis=(1, 3))


def _compare(a, b):
    """(relative difference of the image means, RMS relative difference of the
    lit 4x4-pixel blocks)."""
    ba, bb = _blocks(a), _blocks(b)
    lit = ba > 0.05 * ba.max()
    rms = float(np.sqrt(np.mean(((bb[lit] - ba[lit]) / ba[lit]) ** 2)))
    return abs(b.mean() / a.mean() - 1.0), rms


def test_dense_mesh_gets_the_fast_layout_its_own_lightmap_and_no_xatlas_worker():
    uv_atlas.clear_memory_cache()
    before = uv_atlas.worker_launches
    cs = compile_scene(_scene(256, 512, limit=20_000))       # 261,120 triangles, the default limit
    assert uv_atlas.worker_launches == before
    row, = [r for r in cs.info["layouts"] if r["mesh"] == "ball"]
    assert row["layout"] == "fast layout" and row["triangles"] > 200_000
    assert "unwrap limit of 20,000" in row["reason"] and row["charts"] == 6
    assert not cs.info.get("orientation_lightmaps")
    assert not [w for w in cs.info["warnings"] if "ball" in w]   # a choice, not a failure
    # The ball records on a lightmap of its own, at least as large as its
    # texel density asks (0.3 m radius at 16 texels/m: 17 texels per side) and
    # as large as the layout was made for.
    base = int(cs.geometry.inst_lm_base[-1])
    assert base >= 0 and cs.orientation is None or cs.orientation.inst_ol[-1] < 0
    lid = int(cs.instance_lightmaps[-1][0])
    assert int(cs.lightmaps.width[lid]) == row["resolution"] >= 17


def test_limit_zero_unwraps_and_a_cached_unwrap_is_used_above_the_limit():
    sc = _scene(16, 32, limit=0)
    cs = compile_scene(sc)
    assert [r["layout"] for r in cs.info["layouts"] if r["mesh"] == "ball"] == ["xatlas"]
    before = uv_atlas.worker_launches
    cs = compile_scene(replace(sc, unwrap_limit=100))       # cached now: no reason to skip it
    assert uv_atlas.worker_launches == before
    assert [r["layout"] for r in cs.info["layouts"] if r["mesh"] == "ball"] == ["xatlas"]
    assert cs.geometry.inst_lm_base[-1] >= 0


def test_fast_layout_render_agrees_with_the_xatlas_render(monkeypatch, tmp_path):
    """Same ball (960 triangles), once unwrapped by xatlas and once laid out
    fast above a lowered limit: the ball's own lightmap holds the same light,
    so the images differ by texel placement only (measured: 0.02 % in the
    mean, 0.11 % block RMS). Bounds: the mean within 0.05 %, the lit 4x4-pixel
    blocks within 0.2 % RMS."""
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path / "a"))
    _, a = _render(_scene(16, 32, limit=0))
    uv_atlas.clear_memory_cache()         # the unwrap just made must not count as cached
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path / "b"))
    cs, b = _render(_scene(16, 32, limit=100))
    assert [r["layout"] for r in cs.info["layouts"] if r["mesh"] == "ball"] == ["fast layout"]
    rel_mean, rms = _compare(a, b)
    print(f"mean {rel_mean:.5f}  block rms {rms:.5f}")
    assert rel_mean < 0.0005 and rms < 0.002, (rel_mean, rms)


def test_dense_ball_render_agrees_with_an_xatlas_ball(monkeypatch, tmp_path):
    """The 261k-triangle ball xatlas crashes on, laid out fast, against a
    4k-triangle ball of the same size that xatlas lays out: the same light up
    to the coarser ball's facets (measured: 0.02 % in the mean, 0.19 % block
    RMS; the 4k ball against a 960-triangle one differs as much). Bounds: the
    mean within 0.1 %, the lit 4x4-pixel blocks within 0.3 % RMS; the ball's
    flux per area within 1 %."""
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path))
    ca, a = _render(_scene(32, 64, limit=0))
    before = uv_atlas.worker_launches
    cb, b = _render(_scene(256, 512, limit=20_000))
    assert uv_atlas.worker_launches == before
    assert [r["layout"] for r in cb.info["layouts"] if r["mesh"] == "ball"] == ["fast layout"]
    e = []
    for cs in (ca, cb):
        sl = lightmap.texel_slice(cs.lightmaps, int(cs.instance_lightmaps[-1][0]))
        assert cs.lightmaps.hits[sl].sum() > 10_000
        e.append(cs.lightmaps.flux[sl].sum() / cs.lightmaps.area[sl].sum())
    rel_mean, rms = _compare(a, b)
    print(f"mean {rel_mean:.5f}  block rms {rms:.5f}  flux/area {e[1] / e[0] - 1:+.4f}")
    assert rel_mean < 0.001 and rms < 0.003 and abs(e[1] / e[0] - 1) < 0.01, (rel_mean, rms, e)


def test_unwraps_report_progress_and_can_be_cancelled(monkeypatch, tmp_path):
    """The render's stats line follows the xatlas batch from its start, and Esc
    kills the worker (the scene compile raises Cancelled, nothing is cached)."""
    import pytest
    from photon_lightmaps.engine.core.errors import Cancelled
    monkeypatch.setenv("PHOTON_LIGHTMAPS_CACHE", str(tmp_path))
    uv_atlas.clear_memory_cache()
    with pytest.raises(Cancelled):
        compile_scene(_scene(16, 32, limit=0), should_stop=lambda: True)
    assert not list(tmp_path.glob("uv/*.npz"))
    calls = []
    compile_scene(_scene(16, 32, limit=0), unwrap_progress=lambda done, total: calls.append((done, total)))
    assert calls[0] == (0, 1) and calls[-1] == (1, 1)
