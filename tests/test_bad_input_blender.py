"""Bad input on the Blender side: one clear line, exit code 2, nothing of the user's lost.

Each failure class of the CLI (a NaN vertex in render and bake, a missing file,
no camera, a bad option, a bug) prints exactly one line "error: ..." on stderr
(plus the traceback with --debug); the operators return CANCELLED with the same
text; a failed or cancelled bake leaves images, UV layers and materials as they
were. Scenes are tiny (8x8 texels, a few thousand photons) so the file runs in
well under a minute on a warm numba cache.
"""
import json
import math
import os
import re
import subprocess
import sys
import types

import numpy as np
import pytest

import bpy  # noqa: E402  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import bake  # noqa: E402
from photon_lightmaps import cli, messages  # noqa: E402
from photon_lightmaps.bake import images as B_images  # noqa: E402
from photon_lightmaps.bake import render as render_engine  # noqa: E402
from photon_lightmaps.engine import session  # noqa: E402
from photon_lightmaps.export import uv_layers  # noqa: E402
from photon_lightmaps.engine.core.scene import SceneError  # noqa: E402

from blender_session import addon, bake_uv_cache  # noqa: E402,F401  (session-wide registration)


@pytest.fixture(autouse=True)
def uv_cache(bake_uv_cache):
    yield


def _mesh_object(name, verts, faces, sc):
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    ob = bpy.data.objects.new(name, me)
    sc.collection.objects.link(ob)
    return ob


def build_scene(*, camera=True, nan=False):
    """A lit floor and a box (with a user UV layer, material and image); optionally a NaN mesh."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    sc = bpy.context.scene
    sc.render.engine = "PHOTON_LIGHTMAPS"
    sc.render.resolution_x, sc.render.resolution_y = 16, 12
    s = sc.photon_lightmaps
    s.photons, s.samples, s.texel_density = 2000, 1, 2.0
    if camera:
        cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
        sc.collection.objects.link(cam)
        cam.location, cam.rotation_euler = (0, -6, 2), (math.radians(75), 0, 0)
        sc.camera = cam
    light = bpy.data.objects.new("L", bpy.data.lights.new("L", "POINT"))
    light.data.energy = 500
    light.location = (0, 0, 4)
    sc.collection.objects.link(light)
    _mesh_object("floor", [(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], [(0, 1, 2, 3)], sc)
    box = _mesh_object("box", [(x, y, z) for x in (-.5, .5) for y in (-.5, .5) for z in (0, 1)],
                       [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)], sc)
    layer = box.data.uv_layers.new(name="UVMap")
    layer.uv.foreach_set("vector", np.random.default_rng(1).random(2 * len(layer.uv)).astype(np.float32))
    mat = bpy.data.materials.new("boxmat")      # Blender 5: a node tree from the start
    img = bpy.data.images.new("user_image", 4, 4, float_buffer=True, alpha=True)
    img.pixels.foreach_set(np.linspace(0, 1, 64, dtype=np.float32))
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    box.data.materials.append(mat)
    if nan:
        _mesh_object("nanmesh", [(0, 0, 1), (1, 0, 1), (float("nan"), 1, 1)], [(0, 1, 2)], sc)
    return sc


def save(path, **kw):
    build_scene(**kw)
    bpy.ops.wm.save_as_mainfile(filepath=str(path), check_existing=False)
    return path


def user_data():
    """Everything a failed bake must leave bit-identical: pixels, UV layers, node trees, custom props."""
    def pixels(img):
        a = np.empty(len(img.pixels), np.float32)
        img.pixels.foreach_get(a)
        return a.tobytes()
    return {
        "images": {im.name: pixels(im) for im in bpy.data.images if im.type != "RENDER_RESULT"},
        "uvs": {me.name: [(l.name, l.active, l.active_render, uv_layers.read_uvs(l).tobytes())
                          for l in me.uv_layers] for me in bpy.data.meshes},
        "mesh_props": {me.name: sorted((k, str(me[k])) for k in me.keys()) for me in bpy.data.meshes},
        "nodes": {m.name: (sorted(n.name for n in m.node_tree.nodes),
                           sorted((l.from_node.name, l.from_socket.identifier, l.to_node.name,
                                   l.to_socket.identifier) for l in m.node_tree.links))
                  for m in bpy.data.materials if m.node_tree is not None},
        "node_groups": sorted(g.name for g in bpy.data.node_groups),
    }


def run_cli(*args):
    env = dict(os.environ)
    # Generous: under `make test` the bounds-checked pass runs beside the suite, and its
    # first command compiles every bounds-checked kernel on a shared core.
    return subprocess.run([sys.executable, "-m", "photon_lightmaps", *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=1200)


def one_error_line(stderr):
    """The one "error: ..." line; a first run's kernel-compile progress may precede it."""
    lines = [ln for ln in stderr.splitlines()
             if ln.strip() and not re.match(r"compiling kernels \(|compiled \d+ kernels in ", ln)]
    assert len(lines) == 1 and lines[0].startswith("error: "), stderr
    assert "Traceback" not in stderr
    return lines[0]


# --------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------

def test_cli_nan_vertex_render_and_bake(tmp_path):
    blend = save(tmp_path / "nan.blend", nan=True)
    r = run_cli("render", blend, "--out", tmp_path / "x.png")
    assert r.returncode == 2, r.stderr
    assert "'nanmesh'" in one_error_line(r.stderr) and "NaN" in r.stderr
    assert "Python script error" not in r.stdout        # Blender printed no traceback of its own
    b = run_cli("bake", blend, "--out", tmp_path / "lm")
    assert b.returncode == 2, b.stderr
    assert "object 'nanmesh'" in one_error_line(b.stderr)
    # --debug (before or after the command) adds the traceback, still ending in the line.
    d = run_cli("bake", blend, "--out", tmp_path / "lm", "--debug")
    assert d.returncode == 2 and "Traceback" in d.stderr and "SceneError" in d.stderr
    assert d.stderr.strip().splitlines()[-1] == one_error_line(b.stderr)


def test_cli_missing_file_no_camera_and_bad_options(tmp_path, capsys):
    missing = tmp_path / "missing.blend"
    for cmd in ("render", "bake", "bake-ol"):
        args = [cmd, str(missing), "--out", str(tmp_path / ("x.png" if cmd == "render" else "lm"))]
        assert cli.main(args) == 2
        assert str(missing) in one_error_line(capsys.readouterr().err)
    not_blend = tmp_path / "text.blend"
    not_blend.write_text("not a blend file")
    assert cli.main(["bake", str(not_blend), "--out", str(tmp_path / "lm")]) == 2
    assert "cannot open" in one_error_line(capsys.readouterr().err)

    blend = save(tmp_path / "nocam.blend", camera=False)
    assert cli.main(["render", str(blend), "--out", str(tmp_path / "x.png")]) == 2
    assert "no camera" in one_error_line(capsys.readouterr().err)
    assert cli.main(["render", str(blend), "--out", str(tmp_path / "x.jpg")]) == 2
    assert one_error_line(capsys.readouterr().err).startswith("error: --out ")
    for bad in (["--photons", "-5"], ["--photons", "many"], ["--resolution", "0"], ["--target-error", "2"],
                ["--time", "0"]):
        with pytest.raises(SystemExit) as e:
            cli.main(["bake", str(blend), "--out", str(tmp_path / "lm"), *bad])
        assert e.value.code == 2
        assert one_error_line(capsys.readouterr().err).startswith(f"error: {bad[0]}: ")
    # An output folder that cannot be made: a file stands where the folder should go.
    (tmp_path / "taken").write_text("")
    assert cli.main(["bake", str(blend), "--out", str(tmp_path / "taken" / "lm")]) == 2
    assert "taken" in one_error_line(capsys.readouterr().err)


def test_cli_bug_is_an_internal_error_and_errors_start_a_fresh_line(tmp_path, capsys, monkeypatch):
    blend = save(tmp_path / "ok.blend")

    def bug(*_a, **_k):
        raise ZeroDivisionError("a bug")
    # Inside Blender's render: the engine keeps it, headless.py raises it again (no Blender traceback).
    monkeypatch.setattr(render_engine, "run_render", bug)
    assert cli.main(["render", str(blend), "--out", str(tmp_path / "x.png")]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert line == "error: internal error: ZeroDivisionError: a bug (rerun with --debug for the traceback)"
    assert cli.main(["--debug", "render", str(blend), "--out", str(tmp_path / "x.png")]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "in bug" in err
    assert render_engine.PRINT_ERRORS     # the UI path prints them again
    # A user error after "\rphotons N/M" progress starts on a line of its own.
    monkeypatch.setattr(session, "bake_texels", lambda *a, **k: (_ for _ in ()).throw(SceneError("texel density: too high")))
    assert cli.main(["bake", str(blend), "--out", str(tmp_path / "lm"), "--resolution", "8"]) == 2
    err = capsys.readouterr().err
    assert "\rphotons " in err and err.endswith("\nerror: texel density: too high\n")


def test_cli_progress_is_one_carriage_return_line_with_rate_and_eta():
    import io
    out, now = io.StringIO(), [10.0]
    progress = cli.progress_line("photons", stream=out, clock=lambda: now[0])
    now[0] = 12.0
    assert progress(131_072, 1_000_000) is True
    now[0] = 20.0
    progress(1_000_000, 1_000_000)
    first, second = out.getvalue().split("\r")[1:]
    # 65,536 photons/s over 2 s; 868,928 to go at that rate: 13 s
    assert first == "photons 131,072/1,000,000   13 %  65,536/s  ETA 13 s"
    # done: the rate over the whole phase and its time, padded over the longer line before
    assert second.rstrip() == "photons 1,000,000/1,000,000  100 %  100,000/s  10.0 s"
    assert "\n" not in out.getvalue()
    # a shorter line after a longer one is padded over it
    out, now = io.StringIO(), [0.0]
    progress = cli.progress_line("texels", stream=out, clock=lambda: now[0])
    now[0] = 1.0
    progress(4_000, 5_000)
    now[0] = 100.0
    progress(4_001, 5_000)
    first, second = out.getvalue().split("\r")[1:]
    assert first == "texels 4,000/5,000   80 %  4,000/s  ETA 0 s"
    assert second == "texels 4,001/5,000   80 %  40/s  ETA 25 s".ljust(len(first))
    assert len(second.rstrip()) < len(first)


def test_cli_json_reports_carry_warnings(tmp_path, capsys):
    from photon_lightmaps.operators.orientation_lightmaps import add_orientation_lightmap
    sc = build_scene()
    coll = bpy.data.collections.new("cluster")
    sc.collection.children.link(coll)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=8, ring_count=4, radius=0.3, location=(1.5, 0, 0.3))
    ball = bpy.context.object
    for c in list(ball.users_collection):
        c.objects.unlink(ball)
    coll.objects.link(ball)
    add_orientation_lightmap(sc, coll, resolution=4, samples=500)
    bpy.data.objects["floor"].photon_lightmaps.exclude = True
    blend = tmp_path / "ol.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    for cmd in ("bake", "bake-ol"):
        rep = tmp_path / f"{cmd}.json"
        assert cli.main([cmd, str(blend), "--out", str(tmp_path / "lm"), "--photons", "2000",
                         "--json", str(rep)]) == 0
        data = json.loads(rep.read_text())
        assert isinstance(data["warnings"], list)
    assert "floor" in json.loads((tmp_path / "bake.json").read_text())["skipped"]
    capsys.readouterr()


# --------------------------------------------------------------------------------------
# Blender: operators, render engine, user data
# --------------------------------------------------------------------------------------

def test_operators_and_render_engine_report_the_same_text():
    sc = build_scene(nan=True)
    before = user_data()
    # In background mode an ERROR report of a CANCELLED operator comes back as RuntimeError.
    with pytest.raises(RuntimeError) as e:
        bpy.ops.photon_lightmaps.bake(selected_only=False, resolution=8)
    rep = messages.last(sc.name)
    assert rep["source"] == "bake" and rep["error"].startswith("object 'nanmesh': vertex 2")
    assert str(e.value).strip() == f"Error: {rep['error']}"
    assert user_data() == before
    # The render engine: error_set, no exception out of bpy.ops.render.render, the error kept.
    bpy.ops.render.render(write_still=False)
    assert isinstance(render_engine.LAST_ERROR, SceneError)
    rep = messages.last(sc.name)
    assert rep["source"] == "render" and "'nanmesh'" in rep["error"]
    assert rep["error"] == messages.describe(render_engine.LAST_ERROR)
    # The panel shows it compactly.
    labels = []
    layout = types.SimpleNamespace(box=lambda: layout, column=lambda **k: layout,
                                   label=lambda text, **k: labels.append(text))
    from photon_lightmaps.ui import panels
    panels._draw_last_run(layout, sc)
    assert labels[0].startswith("Last render: failed") and labels[1] == rep["error"]


def _fail_late(monkeypatch, exc):
    """Makes the bake fail after the photon pass, once the Lightmap UV layers were made."""
    def late(*_a, **_k):
        raise exc
    monkeypatch.setattr(B_images, "lightmap_rgba", late)


def test_failed_or_cancelled_bake_leaves_user_data_identical(monkeypatch):
    sc = build_scene()
    floor, box = bpy.data.objects["floor"], bpy.data.objects["box"]
    # An earlier bake made the floor's Lightmap layer and image; then the floor was edited,
    # so the next bake would unwrap it again (UPDATED) and the box gets a new layer (CREATED).
    bake.bake_objects(bpy.context, [floor], photons=2000, seed=0, resolution=8)
    floor.data.vertices[0].co.x -= 0.5
    before = user_data()
    assert "Lightmap" in [l.name for l in floor.data.uv_layers] and "floor_Lightmap" in before["images"]
    for exc in (SceneError("texel density: needs more memory than this machine has"), RuntimeError("bug")):
        _fail_late(monkeypatch, exc)
        with pytest.raises(type(exc)):
            bake.bake_objects(bpy.context, [floor, box], photons=2000, seed=1, resolution=8, overwrite=True,
                           hook_materials=True)
        assert user_data() == before
        # The operator (blocking, as in background mode) rolls back the same way.
        with pytest.raises(RuntimeError) as e:
            bpy.ops.photon_lightmaps.bake(selected_only=False, resolution=8, hook_materials=True)
        assert user_data() == before
        text = messages.last(sc.name)["error"]
        assert str(e.value).strip() == f"Error: {text}"
        assert text.startswith("texel density" if isinstance(exc, SceneError) else
                               "internal error: RuntimeError: bug")
        monkeypatch.undo()
    # Cancelled in the photon pass: nothing changes either.
    with pytest.raises(bake.Cancelled):
        bake.bake_objects(bpy.context, [floor, box], photons=50_000, seed=1, resolution=8,
                       progress=lambda done, total: False)
    assert user_data() == before
    assert "Lightmap" not in box.data.uv_layers


# --------------------------------------------------------------------------------------
# Native crashes and degenerate geometry (xatlas segfaults, zero-area triangles)
# --------------------------------------------------------------------------------------

def test_dense_mesh_that_crashes_xatlas_still_renders_and_bakes(tmp_path):
    """xatlas 0.0.11 segfaults on a 512x256 UV sphere (261k triangles). The
    render does not unwrap it at all (above the default Unwrap Limit: xatlas
    never sees it); it gets the fast box-projection layout and a lightmap of
    its own, and the choice is reported. The bake does unwrap it, the crash
    stays in its worker, and the sphere is baked on the fast layout with a
    warning naming it. Nothing of the user's file is touched."""
    build_scene()
    bpy.ops.mesh.primitive_uv_sphere_add(segments=512, ring_count=256, radius=0.5, location=(1.5, 0, 0.5))
    blend = tmp_path / "dense.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    before = blend.read_bytes()
    rep = tmp_path / "render.json"
    r = run_cli("render", blend, "--out", tmp_path / "x.exr", "--json", rep)
    assert r.returncode == 0, r.stderr
    run = json.loads(rep.read_text())
    # one xatlas batch for the floor and the box, without the sphere
    assert run["xatlas_workers"] == 1 and not [w for w in run["warnings"] if "Sphere" in w]
    assert sorted(r["mesh"] for r in run["layouts"] if r["layout"] == "xatlas") == ["box", "floor"]
    row, = [r for r in run["layouts"] if r["mesh"] == "Sphere"]
    assert row["layout"] == "fast layout" and row["triangles"] > 200_000 and row["charts"] == 6
    assert not run.get("orientation_lightmaps")
    from blender_session import read_image
    assert np.all(np.isfinite(read_image(tmp_path / "x.exr")))
    rep = tmp_path / "bake.json"
    b = run_cli("bake", blend, "--out", tmp_path / "lm", "--json", rep)
    assert b.returncode == 0, b.stderr
    baked = json.loads(rep.read_text())
    assert {"floor", "box", "Sphere"} <= set(baked["objects"]), (baked["skipped"], baked["warnings"])
    assert [w for w in baked["warnings"] if "'Sphere'" in w and "crashed" in w and "fast" in w]
    sphere = read_image(baked["objects"]["Sphere"]["path"])
    assert np.all(np.isfinite(sphere)) and (sphere[..., 3] > 0).mean() > 0.2
    assert blend.read_bytes() == before       # the CLI bakes in memory; the user's file is untouched


def test_zero_area_triangles_render_with_a_warning_naming_the_mesh(tmp_path):
    sc = build_scene()
    # collinear, repeated vertex, and one real triangle
    _mesh_object("slivers", [(0, 0, 1), (1, 0, 1), (2, 0, 1), (0, 1, 1), (1, 1, 1)], [(0, 1, 2), (3, 3, 4), (0, 1, 4)], sc)
    blend = tmp_path / "slivers.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), check_existing=False)
    rep = tmp_path / "render.json"
    r = run_cli("render", blend, "--out", tmp_path / "x.exr", "--json", rep)
    assert r.returncode == 0, r.stderr
    warnings = json.loads(rep.read_text())["warnings"]
    assert [w for w in warnings if "'slivers'" in w and "zero-area triangles dropped" in w]
    from blender_session import read_image
    assert np.all(np.isfinite(read_image(tmp_path / "x.exr")))
