"""Partial rebakes: a bake of some objects of an unchanged scene reuses the last
bake's photon pass (Keep Bake Light, engine/light_reuse.py BakeLight), or one saved
in a folder (--light-cache), gives those objects the very maps a bake of the whole
scene gave them, and leaves every other object's images and UVs alone."""
import json

import numpy as np
import pytest

import bpy  # noqa: F401  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake, demo_blend
from photon_lightmaps.bake import pipeline

from blender_session import addon  # noqa: F401  (session-wide registration)

PHOTONS = 50_000


@pytest.fixture
def room():
    demo_blend.build_cornell_blend(spheres=True)
    scene = bpy.context.scene
    scene.photon_lightmaps.texel_density = 8.0     # small maps; no forced resolution (see below)
    return scene


def meshes(scene):
    return [ob for ob in scene.objects if ob.type == "MESH"]


def baked(objects, **kw):
    # per-texel gathers, so that a texel's value does not depend on what else is baked
    # with it (the irradiance cache's records are shared by every object baked together)
    kw.setdefault("irradiance_cache", False)
    return bake.bake_objects(bpy.context, objects, photons=PHOTONS, seed=1, overwrite=True, **kw)


def pixels(name):
    return np.array(bpy.data.images[name].pixels[:], np.float32)


def uvs(ob):
    layer = ob.data.uv_layers["Lightmap"]
    return np.array([d.uv[:] for d in layer.data], np.float32)


def test_rebaking_one_object_reuses_the_pass_and_keeps_the_others(room):
    """Bake every mesh, then the floor alone: the photon pass is reused from memory
    (nothing traced), the floor's map is the full bake's bit for bit (twice: the kept
    pass is not worn by the bake that reads it), and the other objects' images and
    Lightmap UVs are untouched."""
    full = baked(meshes(room))
    assert full.light_reuse["reused"] is None and full.light_reuse["kept_bytes"] > 0
    others = {n: pixels(full.images[n]) for n in full.images if n != "floor"}
    others_uv = {n: uvs(bpy.data.objects[n]) for n in others}
    for _ in range(2):
        again = baked([bpy.data.objects["floor"]])
        assert again.light_reuse["reused"] == "memory", again.light_reuse
        assert again.light_reuse["photons"] == PHOTONS and again.stats.photons == PHOTONS
        assert set(again.maps) == {"floor"}
        assert np.array_equal(again.maps["floor"].rgba, full.maps["floor"].rgba)
    for name, px in others.items():
        assert np.array_equal(pixels(full.images[name]), px), name
        assert np.array_equal(uvs(bpy.data.objects[name]), others_uv[name]), name


def test_a_rebake_through_the_irradiance_cache_agrees_within_its_noise(room):
    """With the irradiance cache, records depend on every object baked together: the
    back wall rebaked alone reuses the pass and agrees with the full bake within the
    cache's error (measured: mean -0.39 %, the worst texel 8.4 % of the mean, where
    the texels' estimated error averages 2 %)."""
    full = baked(meshes(room), irradiance_cache=True)
    again = baked([bpy.data.objects["back"]], irradiance_cache=True)
    assert again.light_reuse["reused"] == "memory"
    a, b = full.maps["back"].rgba, again.maps["back"].rgba
    inside = a[..., 3] >= 1.0 - 1e-6
    mean = float(b[..., :3][inside].mean() / a[..., :3][inside].mean() - 1.0)
    worst = float((np.abs(b[..., :3] - a[..., :3])[inside] / a[..., :3][inside].mean()).max())
    print(f"\nmean {mean:+.4f}, worst texel {worst:.4f}")
    assert not np.array_equal(a, b)           # the records did differ
    assert abs(mean) < 0.01 and worst < 0.15


def test_a_changed_scene_or_photon_count_traces_again(room):
    """Moving a light or asking for other photons is a new pass, and the report says why;
    putting the light back finds the kept pass gone (one pass is kept, never two)."""
    baked(meshes(room))
    light = next(ob for ob in room.objects if ob.type == "LIGHT")
    light.location.z -= 0.1
    moved = baked([bpy.data.objects["floor"]])
    assert moved.light_reuse["reused"] is None
    assert moved.light_reuse["why_not"] == "the scene or the photon settings changed"
    more = bake.bake_objects(bpy.context, [bpy.data.objects["floor"]], photons=2 * PHOTONS, seed=1,
                             overwrite=True)
    assert more.light_reuse["reused"] is None and more.stats.photons == 2 * PHOTONS
    light.location.z += 0.1
    assert baked([bpy.data.objects["floor"]]).light_reuse["reused"] is None


def test_a_pass_aimed_at_a_small_object_serves_only_what_it_aimed_at(room):
    """Photons aimed at a 10 cm cube (importance emission) do not serve the floor; a
    pass aimed at the whole room serves the cube."""
    bpy.ops.mesh.primitive_cube_add(size=0.1, location=(0.3, 0.3, 0.05))
    cube = bpy.context.active_object
    small = baked([cube])
    assert small.stats.aim is not None                    # small enough to aim at
    floor = baked([bpy.data.objects["floor"]])
    assert floor.light_reuse["why_not"] == "its photons were aimed at other objects"
    assert floor.stats.aim is None
    assert baked([cube]).light_reuse["reused"] == "memory"


def test_a_lookup_pass_serves_only_the_objects_it_recorded(room):
    """A lookup bake records its targets alone: its pass cannot serve another object."""
    baked([bpy.data.objects["floor"]], indirect="LOOKUP")
    back = baked([bpy.data.objects["back"]], indirect="LOOKUP")
    assert back.light_reuse["why_not"] == "it did not record every object baked now"
    full = baked(meshes(room), indirect="LOOKUP")
    again = baked([bpy.data.objects["back"]], indirect="LOOKUP")
    assert again.light_reuse["reused"] == "memory"
    assert np.array_equal(again.maps["back"].rgba, full.maps["back"].rgba)


def test_keep_bake_light_off_keeps_nothing(room):
    baked([bpy.data.objects["floor"]], keep_light=False)
    assert pipeline.BAKE_LIGHT.kept is None
    assert baked([bpy.data.objects["floor"]]).light_reuse["why_not"] == "no photon pass was kept"


def test_a_saved_pass_is_reused_from_its_folder(room, tmp_path):
    """--light-cache in-process: the pass saved by the full bake is loaded (nothing kept
    in memory), with its photon statistics, and gives the floor's map bit for bit."""
    full = baked(meshes(room), light_cache=str(tmp_path), keep_light=False)
    assert full.light_reuse["saved"].startswith(str(tmp_path))
    assert pipeline.BAKE_LIGHT.kept is None
    again = baked([bpy.data.objects["floor"]], light_cache=str(tmp_path), keep_light=False)
    assert again.light_reuse["reused"] == "disk", again.light_reuse
    assert again.stats.rays == full.stats.rays and np.array_equal(again.stats.emitted, full.stats.emitted)
    assert np.array_equal(again.maps["floor"].rgba, full.maps["floor"].rgba)
    # a damaged file (a NaN in the saved flux) is not read: the pass is traced again
    path = full.light_reuse["saved"]
    with np.load(path) as f:
        arrays = dict(f)
    arrays["lm_flux"][0, 0] = np.nan
    np.savez(path, **arrays)
    damaged = baked([bpy.data.objects["floor"]], light_cache=str(tmp_path), keep_light=False)
    assert damaged.light_reuse["reused"] is None
    assert damaged.light_reuse["why_not"] == "the saved pass does not fit the scene (or is damaged)"
    assert np.array_equal(damaged.maps["floor"].rgba, full.maps["floor"].rgba)
    moved = bpy.data.objects["tall_box"]
    moved.location.x += 0.05
    assert baked([bpy.data.objects["floor"]], light_cache=str(tmp_path)).light_reuse["reused"] is None


def test_cli_rebakes_named_objects_from_a_light_cache(tmp_path):
    """bake --light-cache DIR, then bake --objects floor --light-cache DIR in a new
    process: the pass is read from DIR (no photons traced), the floor's file is the first
    run's values, and the other objects' files are not rewritten. An unknown name in
    --objects: exit 2 and one line."""
    from test_cli_commands import run
    from photon_lightmaps.registration import ensure_registered
    ensure_registered()
    blend = tmp_path / "room.blend"
    demo_blend.build_cornell_blend(str(blend), width=24, height=16)
    cache, out = tmp_path / "light", tmp_path / "maps"
    # per-texel gathers: the irradiance cache's records are shared by every object
    # baked together, so a rebake with it agrees within noise rather than bit for bit
    common = ("--photons", str(PHOTONS), "--light-cache", cache, "--bake-gather-rays", "64",
              "--no-irradiance-cache")
    run("bake", blend, "--out", out, *common, "--json", tmp_path / "a.json")
    first = json.loads((tmp_path / "a.json").read_text())
    assert first["light_reuse"]["reused"] is None and first["light_reuse"]["saved"].startswith(str(cache))
    floor_px = _exr(first["objects"]["floor"]["path"])
    stamps = {n: (out / f"{n}.exr").stat().st_mtime_ns for n in first["objects"] if n != "floor"}
    run("bake", blend, "--out", out, *common, "--objects", "floor", "--json", tmp_path / "b.json")
    second = json.loads((tmp_path / "b.json").read_text())
    assert second["light_reuse"]["reused"] == "disk", second["light_reuse"]
    assert list(second["objects"]) == ["floor"] and second["photons"] == PHOTONS
    assert second["seconds"]["photon_pass"] < first["seconds"]["photon_pass"]
    assert np.array_equal(_exr(second["objects"]["floor"]["path"]), floor_px)
    assert {n: (out / f"{n}.exr").stat().st_mtime_ns for n in stamps} == stamps
    bad = run("bake", blend, "--out", out, "--objects", "floor,nothing", check=False)
    assert bad.returncode == 2 and "--objects: no object named 'nothing'" in bad.stderr
    assert "Traceback" not in bad.stderr
    blocked = tmp_path / "file"
    blocked.write_text("")                       # a file where the folder should be
    bad = run("bake", blend, "--out", out, "--light-cache", blocked / "light", check=False)
    assert bad.returncode == 2 and "cannot write the photon pass (--light-cache) there" in bad.stderr


def _exr(path):
    img = bpy.data.images.load(str(path))
    try:
        return np.array(img.pixels[:], np.float32)
    finally:
        bpy.data.images.remove(img)


def test_loading_a_file_lets_the_kept_pass_go(room):
    """The kept pass belongs to the file it was traced in: loading another lets it go."""
    baked([bpy.data.objects["floor"]])
    assert pipeline.BAKE_LIGHT.kept is not None
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert pipeline.BAKE_LIGHT.kept is None
