"""The optional OIDN pass (engine/transport/denoise.py), inside the bpy process next to the numba kernels.

pyoidn ships its own TBB and numba may run on TBB too: every test here runs a
parallel numba kernel in the same process as OIDN, before and after it.
Measured bounds (run with -s to print the numbers):
* gathered render of the Cornell room, 20 k photons, 4 spp, 4 gather rays,
  against 400 k photons, 32 spp, 16 rays: relative RMSE falls (asserted: to
  < 0.75 of the noisy one) and the mean moves by < 2 %;
* bake: texels outside every UV chart are bit-identical with and without
  denoising, covered ones change, the covered mean moves by < 2 %.
"""
import sys

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake  # noqa: E402
from photon_lightmaps import demo_blend  # noqa: E402
from photon_lightmaps.engine.transport import denoise  # noqa: E402
from photon_lightmaps.engine import session  # noqa: E402
from photon_lightmaps.export import export_scene  # noqa: E402

from blender_session import addon, bake_uv_cache  # noqa: E402,F401  (session-wide registration)



def _rel_rmse(x, ref):
    return float(np.sqrt(np.mean((x - ref) ** 2)) / ref.mean())


def _traced(photons, **kw):
    scene, _ = export_scene(bpy.context.evaluated_depsgraph_get())
    cs = session.compile(scene)
    settings = session.Settings(photons=photons, seed=kw.pop("seed", 1), **kw)
    session.render_photon_pass(cs, settings)
    return cs, settings


def test_missing_pyoidn_is_one_user_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "pyoidn", None)     # import pyoidn -> ImportError
    with pytest.raises(denoise.DenoiseUnavailable, match=r"^denoise: the pyoidn package is not available.*pyoidn==2\.5\.1"):
        denoise.denoise_image(np.zeros((4, 4, 3), np.float32))
    from photon_lightmaps.messages import is_user_error
    assert is_user_error(denoise.DenoiseUnavailable("x"))
    assert not denoise.available()


def test_lightmap_tiles_and_uncovered_texels_do_not_bleed():
    rng = np.random.default_rng(0)
    r = 24
    img = np.empty((r, 2 * r, 3), np.float32)
    img[:, :r] = 50.0 * rng.random((r, r, 3))           # a bright noisy face tile ...
    img[:, r:] = 0.1 + 0.02 * rng.random((r, r, 3))     # ... beside a dim one
    covered = np.ones((r, 2 * r), bool)
    covered[:4, r:] = False                             # a strip no chart covers, holding a sentinel
    img[:4, r:] = 7.0
    out = denoise.denoise_lightmap(img, covered, tiles=2)
    alone = denoise.denoise_lightmap(img[:, r:], covered[:, r:])
    assert out.dtype == np.float32 and out.shape == img.shape
    assert np.array_equal(out[:, r:], alone), "light crossed the tile seam"
    assert np.all(out[:4, r:] == 7.0), "uncovered texels changed"
    assert out[4:, r:].max() < 1.0


def test_fill_empty_continues_the_chart():
    img = np.zeros((8, 8, 3), np.float32)
    known = np.zeros((8, 8), bool)
    known[2:5, 2:5] = True
    img[known] = 3.0
    filled = denoise._fill_empty(img, known)
    assert np.allclose(filled, 3.0)


def test_denoised_render_is_closer_to_the_reference_and_keeps_the_mean():
    demo_blend.build_cornell_blend(width=48, height=48)
    cs_ref, s_ref = _traced(400_000, seed=11, samples=32, gather_rays=16)
    ref = session.render(cs_ref, s_ref)[..., :3]
    cs, s = _traced(20_000, seed=1, samples=4, gather_rays=4)
    noisy = session.render(cs, s)[..., :3]
    den = session.denoise_render(cs, noisy, session.Settings(samples=4, seed=1))
    e0, e1 = _rel_rmse(noisy, ref), _rel_rmse(den, ref)
    shift = float(den.mean() / noisy.mean() - 1.0)
    bias = float(den.mean() / ref.mean() - 1.0)
    print(f"\nrender relRMSE noisy {e0:.4f} -> denoised {e1:.4f}; mean shift {100 * shift:+.2f} %, "
          f"vs reference {100 * bias:+.2f} %")
    assert e1 < 0.75 * e0
    assert abs(shift) < 0.02
    # the numba kernels still run (and agree) after OIDN's TBB has been loaded
    again = session.render(cs, s)[..., :3]
    assert np.array_equal(again, noisy)
    # the Settings switch runs the same pass
    s_on = session.Settings(photons=20_000, seed=1, samples=4, gather_rays=4, denoise=True)
    assert np.allclose(session.render(cs, s_on)[..., :3], den, atol=1e-6 * float(den.max()))
    assert cs.timings["denoise"] > 0.0


def test_bake_with_denoise_keeps_uncovered_texels(bake_uv_cache):
    demo_blend.build_cornell_blend(width=16, height=16)
    objs = [bpy.data.objects[n] for n in ("floor", "tall_box")]
    kw = dict(photons=30_000, seed=2, resolution=32)
    plain = bake.bake_objects(bpy.context, objs, **kw, denoise=False)
    den = bake.bake_objects(bpy.context, objs, **kw, denoise=True)
    assert den.seconds["denoise"] > 0.0
    for name in ("floor", "tall_box"):
        a, b = plain.maps[name].rgba, den.maps[name].rgba
        out = a[..., 3] == 0.0
        assert np.array_equal(a[..., 3], b[..., 3])
        assert np.array_equal(a[out], b[out]), f"{name}: uncovered texels changed"
        cov = ~out
        assert not np.array_equal(a[cov, :3], b[cov, :3])
        shift = float(b[cov, :3].mean() / a[cov, :3].mean() - 1.0)
        print(f"\n{name}: {int(out.sum())} uncovered texels untouched, covered mean shift {100 * shift:+.2f} %")
        assert abs(shift) < 0.02
    assert np.count_nonzero(plain.maps["tall_box"].rgba[..., 3] == 0.0) > 0   # the check above bit


def test_cli_flags_reach_the_render_engine_and_the_bake(tmp_path):
    import json

    from photon_lightmaps import cli
    from photon_lightmaps.bake import render as render_engine

    from blender_session import read_image
    blend = tmp_path / "room.blend"
    demo_blend.build_cornell_blend(str(blend), width=80, height=70, photons=10_000, samples=2)  # 2 x 2 tiles
    exr, report = tmp_path / "room.exr", tmp_path / "render.json"
    assert cli.main(["render", str(blend), "--out", str(exr), "--denoise", "--json", str(report)]) == 0
    rep = json.loads(report.read_text())
    run = render_engine.LAST_RUN
    assert rep["denoised"] and rep["settings"]["denoise"] and rep["seconds"]["denoise"] > 0.0
    # the saved frame is the denoised image, not the noisy tiles shown while rendering
    np.testing.assert_allclose(read_image(exr)[..., :3], run.image.astype(np.float32), rtol=1e-5, atol=1e-6)
    bake_report = tmp_path / "bake.json"
    assert cli.main(["bake", str(blend), "--out", str(tmp_path / "maps"), "--resolution", "16",
                     "--denoise", "--json", str(bake_report)]) == 0
    rep = json.loads(bake_report.read_text())
    assert rep["denoised"] and rep["seconds"]["denoise"] > 0.0 and rep["objects"]
