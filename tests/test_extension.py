"""Packaging: the linux-x64 extension zip is laid out as Blender builds it, installs
with Blender's extension operators, renders, survives disable/enable and uninstalls.

Blender reads its user folders when bpy is first imported, so everything that
touches Blender runs in a subprocess whose BLENDER_USER_RESOURCES points at a
scratch folder.
"""
import contextlib
import importlib.util
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import textwrap
import tomllib
import urllib.request
import zipfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUILD_SCRIPT = os.path.join(ROOT, "scripts", "build_extension.py")
PLATFORM = "linux-x64"
PKG_ID = "photon_lightmaps"
MODULE = "bl_ext.user_default." + PKG_ID
ENGINE_ID = "PHOTON_LIGHTMAPS"

# Fixed rather than random: numba caches kernels per source path (and mtime, see
# BLENDER_SCRIPT), so a stable install path lets reruns skip minutes of compiling.
# The lock serialises test runs that share the machine.
USER_RESOURCES = os.path.join(tempfile.gettempdir(), "photon_lightmaps_extension_test")


def _load_build_script():
    spec = importlib.util.spec_from_file_location("build_extension", BUILD_SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _pypi_reachable():
    # Ask the index pip would use for a page the build needs, not just for a socket.
    index = os.environ.get("PIP_INDEX_URL", "https://pypi.org/simple/")
    try:
        with urllib.request.urlopen(index.rstrip("/") + "/numba/", timeout=20) as resp:
            return resp.status == 200
    except (OSError, ValueError):
        return False


@pytest.fixture(scope="module")
def build():
    return _load_build_script()


@pytest.fixture(scope="module")
def bext(build):
    return build.load_blender_ext()


@pytest.fixture(scope="module")
def linux_zip(build, bext, tmp_path_factory):
    cached = build.wheels_for(bext, PLATFORM, build.WHEELS_DIR)
    offline = all(name in cached for name in build.PINS)
    if not offline and not _pypi_reachable():
        pytest.skip("PyPI is unreachable and wheels/ lacks the %s wheels" % PLATFORM)
    with open(build.MANIFEST, "rb") as fh:
        manifest_before = fh.read()
    out = tmp_path_factory.mktemp("dist")
    cmd = [sys.executable, BUILD_SCRIPT, "--platforms", PLATFORM, "--out", str(out)]
    proc = subprocess.run(cmd + (["--offline"] if offline else []), capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    with open(build.MANIFEST, "rb") as fh:
        # A one-platform build stages its own manifest; the repository's keeps every platform.
        assert fh.read() == manifest_before
    path = out / ("%s-%s-%s.zip" % (PKG_ID, tomllib.loads(manifest_before.decode())["version"],
                                    PLATFORM.replace("-", "_")))
    assert path.is_file(), proc.stdout
    return str(path)


def test_zip_layout_and_manifest(linux_zip, build, bext):
    with zipfile.ZipFile(linux_zip) as zf:
        names = zf.namelist()
        # Blender's own install-time validation (strict, [build.generated] applied).
        manifest = bext.pkg_manifest_from_zipfile_and_validate_all_errors(zf, "", strict=True)
        assert not isinstance(manifest, list), manifest
        wheel_members = {}
        for name in names:
            if name.startswith("wheels/"):
                with zf.open(name) as fh, zipfile.ZipFile(fh) as wheel:
                    wheel_members[name[len("wheels/"):]] = set(wheel.namelist())

    # Package files sit at the zip root, as `extension build` writes them.
    for required in ("blender_manifest.toml", "__init__.py", "registration.py", "operators/render_engine.py",
                     "export/__init__.py", "bake/__init__.py", "ui/__init__.py",
                     "engine/__init__.py"):
        assert required in names
    for name in names:
        assert not name.startswith(("tests/", "scripts/", "benchmarks/", "docs/", "out/", "dist/", ".")), name
        assert "__pycache__" not in name and not name.endswith(".pyc"), name

    assert manifest.id == PKG_ID and manifest.type == "add-on"
    assert manifest.platforms == [PLATFORM]
    assert manifest.permissions == {"files": "Read .blend neighbours and write baked OpenEXR lightmaps"}
    listed = sorted(w[len("./wheels/"):] for w in manifest.wheels)
    assert listed == sorted(wheel_members), (listed, sorted(wheel_members))

    # Exactly the pinned numba, llvmlite, xatlas and pyoidn for this platform; numpy comes with Blender.
    by_name = {build.wheel_fields(w)[0]: w for w in listed}
    assert sorted(by_name) == sorted(build.PINS)
    for name, wheel in by_name.items():
        _, version, py_tag, plat_tag = build.wheel_fields(wheel)
        # pyoidn binds OIDN through cffi: one py3 wheel per platform, not per Python
        assert version == build.PINS[name] and py_tag == ("py3" if name == "pyoidn" else "cp311"), wheel
        assert bext.blender_platforms_from_wheel_platform(plat_tag.split(".")[0]) == [PLATFORM], wheel
    assert "numba/__init__.py" in wheel_members[by_name["numba"]]
    assert "llvmlite/binding/__init__.py" in wheel_members[by_name["llvmlite"]]
    assert any(m.startswith("xatlas") and m.endswith(".so") for m in wheel_members[by_name["xatlas"]])
    assert "pyoidn/__init__.py" in wheel_members[by_name["pyoidn"]]


# Runs inside a fresh bpy. Prints one `RESULT <json>` line; any failure raises.
BLENDER_SCRIPT = r'''
import glob, importlib, json, os, subprocess, sys, time, zipfile
import numpy as np
import bpy

t0 = time.perf_counter()
zip_path, src_root, out_dir = sys.argv[1:4]
MODULE, PKG_ID, ENGINE_ID = "bl_ext.user_default.photon_lightmaps", "photon_lightmaps", "PHOTON_LIGHTMAPS"
result = {"seconds": {}}


def lap(step):
    result["seconds"][step] = round(time.perf_counter() - t0, 2)


def engine_ids():
    # Unregistered classes linger in __subclasses__() until collected: count registered ones.
    return {getattr(cls, "bl_idname", None) for cls in bpy.types.RenderEngine.__subclasses__()
            if getattr(cls, "is_registered", False)}


def render(tag):
    scene = bpy.context.scene
    scene.render.engine = ENGINE_ID
    r = scene.render
    r.resolution_x = r.resolution_y = 64
    r.resolution_percentage = 100
    s = scene.photon_lightmaps
    s.photons, s.samples, s.seed, s.max_bounces = 20000, 1, 1, 4
    r.image_settings.file_format = "OPEN_EXR"
    r.filepath = os.path.join(out_dir, tag + ".exr")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(r.filepath)
    px = np.empty(len(img.pixels), np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    rgb = px.reshape(-1, 4)[:, :3]
    assert rgb.shape[0] == 64 * 64, rgb.shape
    return rgb


repo = next(r for r in bpy.context.preferences.extensions.repos if r.module == "user_default")
pkg_dir = os.path.join(repo.directory, PKG_ID)
site = os.path.join(bpy.utils.user_resource("EXTENSIONS"), ".local", "lib",
                    "python%d.%d" % sys.version_info[:2], "site-packages")

ret = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
assert ret == {"FINISHED"}, ret
assert MODULE in bpy.context.preferences.addons, list(bpy.context.preferences.addons.keys())
mod = importlib.import_module(MODULE)
assert os.path.dirname(mod.__file__) == pkg_dir, mod.__file__
result["installed"] = pkg_dir
lap("install")

# Blender extracted the bundled wheels into its shared site-packages and put it on sys.path.
assert site in sys.path, sys.path
for top in ("numba", "llvmlite"):
    assert os.path.isfile(os.path.join(site, top, "__init__.py")), top
assert glob.glob(os.path.join(site, "xatlas*.so")), os.listdir(site)
# This bpy runs in a venv that has numba too, so prove the extracted copies work on their own:
# a child Python sees `site` first, imports them from there and JIT-compiles a function.
probe = subprocess.run([sys.executable, "-c", (
    "import json, numba, llvmlite, xatlas\n"
    "from numba import njit\n"
    "@njit\n"
    "def f(x):\n"
    "    return x * 2.0 + 1.0\n"
    "print(json.dumps({m.__name__: m.__file__ for m in (numba, llvmlite, xatlas)} | {'f': f(3.0)}))\n")],
    env=dict(os.environ, PYTHONPATH=site), capture_output=True, text=True, timeout=300)
assert probe.returncode == 0, probe.stderr
files = json.loads(probe.stdout.strip().splitlines()[-1])
assert files.pop("f") == 7.0
for name, path in files.items():
    assert path.startswith(site), (name, path)
result["wheels_import_from"] = files
lap("wheel_probe")

assert ENGINE_ID in engine_ids(), engine_ids()

# numba's on-disk cache is keyed on each source file's path and mtime, captured when a
# kernel module is imported; zip extraction stamps files with the install time, so every
# install would recompile for minutes. Test plumbing only: give the installed sources their
# checkout mtimes (files identical to the checkout only) and import the add-on afresh.
ret = bpy.ops.preferences.addon_disable(module=MODULE)
assert ret == {"FINISHED"}, ret
with zipfile.ZipFile(zip_path) as zf:
    for info in zf.infolist():
        src, dst = os.path.join(src_root, info.filename), os.path.join(pkg_dir, info.filename)
        if info.filename.endswith(".py") and os.path.isfile(src) and os.path.isfile(dst):
            with open(src, "rb") as a, open(dst, "rb") as b:
                if a.read() == b.read():
                    st = os.stat(src)
                    os.utime(dst, ns=(st.st_atime_ns, st.st_mtime_ns))
for name in [m for m in sys.modules if m == MODULE or m.startswith(MODULE + ".")]:
    del sys.modules[name]
ret = bpy.ops.preferences.addon_enable(module=MODULE)
assert ret == {"FINISHED"}, ret

assert ENGINE_ID in engine_ids(), engine_ids()
bpy.context.scene.render.engine = ENGINE_ID
assert bpy.context.scene.render.engine == ENGINE_ID

first = render("first")
assert np.isfinite(first).all()
assert first.max() > 0.0 and first.mean() > 1e-4, (first.min(), first.mean(), first.max())
result["first_mean"] = float(first.mean())
lap("first_render")

ret = bpy.ops.preferences.addon_disable(module=MODULE)
assert ret == {"FINISHED"}, ret
assert MODULE not in bpy.context.preferences.addons
assert ENGINE_ID not in engine_ids(), engine_ids()
assert not hasattr(bpy.types.Scene, "photon_lightmaps")

ret = bpy.ops.preferences.addon_enable(module=MODULE)
assert ret == {"FINISHED"}, ret
assert ENGINE_ID in engine_ids(), engine_ids()
again = render("again")
assert np.isfinite(again).all() and again.max() > 0.0
# Same seed after a reload: the tracer is deterministic, so the image must not change.
np.testing.assert_allclose(again, first, rtol=1e-5, atol=1e-6)
result["reloaded_mean"] = float(again.mean())
lap("reload_render")

ret = bpy.ops.extensions.package_uninstall(repo_directory=repo.directory, pkg_id=PKG_ID)
assert ret == {"FINISHED"}, ret
assert MODULE not in bpy.context.preferences.addons
assert not os.path.exists(pkg_dir), os.listdir(pkg_dir)
assert ENGINE_ID not in engine_ids(), engine_ids()
# No other extension uses the wheels, so Blender removes them with the package.
assert not os.path.exists(os.path.join(site, "numba")), os.listdir(site)
result["uninstalled"] = True
lap("uninstall")
print("RESULT " + json.dumps(result), flush=True)
'''


@contextlib.contextmanager
def _user_resources():
    import fcntl  # POSIX only, like the round trip that needs it
    os.makedirs(os.path.dirname(USER_RESOURCES), exist_ok=True)
    with open(USER_RESOURCES + ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            shutil.rmtree(USER_RESOURCES, ignore_errors=True)
            os.makedirs(USER_RESOURCES)
            yield USER_RESOURCES
        finally:
            shutil.rmtree(USER_RESOURCES, ignore_errors=True)
            fcntl.flock(lock, fcntl.LOCK_UN)


@pytest.mark.skipif(not (sys.platform.startswith("linux") and platform.machine() == "x86_64"),
                    reason="installs the linux-x64 package, which only loads on linux-x64")
def test_install_render_reload_uninstall(linux_zip, tmp_path):
    script = tmp_path / "roundtrip.py"
    script.write_text(textwrap.dedent(BLENDER_SCRIPT))
    with _user_resources() as resources:
        env = dict(os.environ, BLENDER_USER_RESOURCES=resources)
        # Kernels compile once per source change into the checkout's cache (conftest sets it).
        env.setdefault("PHOTON_LIGHTMAPS_NUMBA_CACHE", os.path.join(ROOT, ".numba_cache"))
        proc = subprocess.run([sys.executable, str(script), linux_zip, ROOT, str(tmp_path)],
                              capture_output=True, text=True, timeout=1500, env=env)
    log = proc.stdout[-6000:] + proc.stderr[-6000:]
    assert proc.returncode == 0, log
    lines = [line for line in proc.stdout.splitlines() if line.startswith("RESULT ")]
    assert lines, log
    result = json.loads(lines[-1][len("RESULT "):])
    print("round trip:", json.dumps({k: result[k] for k in ("seconds", "first_mean", "reloaded_mean")}))
    assert result["uninstalled"] and result["first_mean"] > 0.0
