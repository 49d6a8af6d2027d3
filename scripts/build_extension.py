#!/usr/bin/env python3
"""Builds the Photon Lightmaps extension packages, one zip per platform.

1. Downloads the pinned numba, llvmlite, xatlas and pyoidn wheels (cp311, as in
   Blender 4.2-5.0) for each platform into wheels/ (git-ignored). numpy is
   not bundled: Blender ships numpy 1.26, which numba 0.68 accepts
   (numpy >=1.22,<2.6).
2. Writes the `platforms` and `wheels` lists of blender_manifest.toml.
3. Runs Blender's own `extension build --split-platforms` code (blender_ext.py
   shipped inside the bpy module, so no Blender binary is needed), then
   validates every zip the way Blender does before installing one.

    python scripts/build_extension.py                       # all platforms -> dist/
    python scripts/build_extension.py --platforms linux-x64 --out /tmp/pkg
    python scripts/build_extension.py --offline             # reuse wheels/ only

Building a subset of the platforms leaves the source manifest alone (it keeps
listing every platform) and builds from a staged copy with a narrowed manifest.
"""
import argparse
import glob
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = os.path.join(ROOT, "blender_manifest.toml")
WHEELS_DIR = os.path.join(ROOT, "wheels")

# Same versions as the development venv, so the bundled kernels are the tested ones.
# pyoidn (the optional Denoise setting) is a py3-none wheel carrying OIDN's own
# libraries and TBB: about 50 MB per platform, the bulk of each package.
PINS = {"numba": "0.68.1", "llvmlite": "0.50.0", "xatlas": "0.0.11", "pyoidn": "2.5.1.0"}
PYTHON_VERSION = "3.11"

# Blender platform -> pip --platform tags. pip does not widen manylinux tags by
# itself, so each glibc level that a pinned wheel uses is listed (Blender 4.2+
# needs glibc 2.28 anyway). numba/llvmlite 0.68 need macOS 12 on arm64 and ship
# no Intel-mac wheels at all (numba dropped macos-x64 after 0.62), so there is
# no macos-x64 package.
PLATFORMS = {
    "windows-x64": ["win_amd64"],
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64"],
    "macos-arm64": ["macosx_12_0_arm64"],
}


def load_blender_ext():
    """Imports blender_ext.py, the implementation of `blender --command extension`, from bpy's scripts."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        sys.exit("error: the bpy module is needed (it ships Blender's extension build code)")
    found = []
    for loc in spec.submodule_search_locations:
        found += glob.glob(os.path.join(loc, "*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py"))
    if not found:
        sys.exit("error: blender_ext.py not found inside the bpy module")
    path = sorted(found)[-1]
    mod_spec = importlib.util.spec_from_file_location("blender_ext", path)
    mod = importlib.util.module_from_spec(mod_spec)
    mod_spec.loader.exec_module(mod)
    # Blender's CLI validates tags against this file by default; do the same.
    mod.tags_path = os.path.join(os.path.dirname(path), "..", "..", "..", "modules",
                                 "_bpy_internal", "extensions", "tags.py")
    return mod


def wheel_fields(filename):
    """(distribution, version, python tag, platform tag) of a wheel file name."""
    parts = filename[:-len(".whl")].split("-")
    return parts[0].lower().replace("_", "-"), parts[1], parts[-3], parts[-1]


def wheels_for(bext, platform, directory):
    """The pinned wheels in `directory` that Blender considers compatible with `platform`."""
    found = {}
    for path in sorted(glob.glob(os.path.join(directory, "*.whl"))):
        name, version, py_tag, plat_tag = wheel_fields(os.path.basename(path))
        if PINS.get(name) != version or py_tag not in ("cp311", "py3"):
            continue
        if bext.blender_platform_compatible_with_wheel_platform(platform, plat_tag):
            found[name] = os.path.basename(path)
    return found


def download(bext, platform, offline):
    have = wheels_for(bext, platform, WHEELS_DIR)
    missing = [name for name in PINS if name not in have]
    if missing and offline:
        sys.exit("error: --offline but wheels/ lacks %s for %s" % (", ".join(missing), platform))
    if missing:
        print("downloading %s for %s" % (", ".join(missing), platform), flush=True)
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--only-binary=:all:", "--no-deps",
               "--python-version", PYTHON_VERSION, "--dest", WHEELS_DIR]
        for tag in PLATFORMS[platform]:
            cmd += ["--platform", tag]
        cmd += ["%s==%s" % (name, PINS[name]) for name in missing]
        if subprocess.run(cmd).returncode != 0:
            sys.exit("error: pip could not download the %s wheels (offline? try --offline)" % platform)
        have = wheels_for(bext, platform, WHEELS_DIR)
        missing = [name for name in PINS if name not in have]
        if missing:
            sys.exit("error: pip gave no %s wheel for %s" % (", ".join(missing), platform))
    return sorted(have.values())


def toml_list(values):
    return "[\n%s]" % "".join('  "%s",\n' % v for v in values)


def manifest_with(text, platforms, wheels):
    """Manifest text with its top-level `platforms` and `wheels` arrays replaced."""
    for key, values in (("platforms", platforms), ("wheels", wheels)):
        text, n = re.subn(r"^%s = \[.*?\]" % key, lambda _m: "%s = %s" % (key, toml_list(values)),
                          text, count=1, flags=re.MULTILINE | re.DOTALL)
        if n != 1:
            sys.exit("error: blender_manifest.toml has no `%s = [...]` list to fill in" % key)
    return text


def stage(bext, manifest_text, wheel_files, directory):
    """Copies what the package would contain into `directory`, with `manifest_text` as its manifest."""
    with open(MANIFEST, "rb") as fh:
        patterns = tomllib.load(fh)["build"]["paths_exclude_pattern"]
    exclude = bext.PathPatternMatch(patterns)

    def keep(rel, is_dir):
        rel = rel.replace(os.sep, "/")
        return not exclude.test_path(rel + "/" if is_dir else rel) and rel != "blender_manifest.toml"

    for src, rel in bext.scandir_recursive(ROOT, filter_fn=keep):
        dst = os.path.join(directory, rel)
        os.makedirs(os.path.dirname(dst), exist_ok=True)
        shutil.copy2(src, dst)
    os.makedirs(os.path.join(directory, "wheels"), exist_ok=True)
    for name in wheel_files:
        shutil.copy2(os.path.join(WHEELS_DIR, name), os.path.join(directory, "wheels", name))
    with open(os.path.join(directory, "blender_manifest.toml"), "w", encoding="utf-8") as fh:
        fh.write(manifest_text)


def check_zip(bext, path, platform, wheel_files):
    """Validates a built zip as Blender does on install, and that it holds exactly this platform's wheels."""
    with zipfile.ZipFile(path) as zf:
        errors = bext.pkg_manifest_from_zipfile_and_validate_all_errors(zf, "", strict=True)
        if isinstance(errors, list):
            sys.exit("error: %s: %s" % (path, "; ".join(errors)))
        manifest = errors
        packed = sorted(n[len("wheels/"):] for n in zf.namelist() if n.startswith("wheels/"))
    expected = sorted(wheel_files)
    if manifest.platforms != [platform] or packed != expected or \
            sorted(os.path.basename(w) for w in manifest.wheels) != expected:
        sys.exit("error: %s: platforms %s, manifest wheels %s, packed wheels %s (expected %s)"
                 % (path, manifest.platforms, manifest.wheels, packed, expected))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--platforms", default=",".join(PLATFORMS),
                    help="comma-separated Blender platforms (default: %(default)s)")
    ap.add_argument("--offline", action="store_true", help="use wheels/ as it is, never run pip")
    ap.add_argument("--out", default=os.path.join(ROOT, "dist"), help="output folder (default: dist/)")
    args = ap.parse_args(argv)

    platforms = [p.strip() for p in args.platforms.split(",") if p.strip()]
    unknown = [p for p in platforms if p not in PLATFORMS]
    if unknown or not platforms:
        ap.error("unknown platform(s) %s; known: %s (numba %s has no macos-x64 wheels)"
                 % (", ".join(unknown), ", ".join(PLATFORMS), PINS["numba"]))
    platforms = [p for p in PLATFORMS if p in platforms]  # canonical order, no duplicates

    bext = load_blender_ext()
    os.makedirs(WHEELS_DIR, exist_ok=True)
    per_platform = {p: download(bext, p, args.offline) for p in platforms}
    wheels = ["./wheels/" + w for w in sorted({w for ws in per_platform.values() for w in ws})]

    with open(MANIFEST, encoding="utf-8") as fh:
        source_text = fh.read()
    manifest_text = manifest_with(source_text, platforms, wheels)

    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    argv_build = ["build", "--output-dir", out, "--split-platforms", "--valid-tags", bext.tags_path]
    if platforms == list(PLATFORMS):
        # The full set is what the repository's manifest describes: keep it in sync, and build
        # straight from the checkout exactly as `blender --command extension build` would.
        if manifest_text != source_text:
            with open(MANIFEST, "w", encoding="utf-8") as fh:
                fh.write(manifest_text)
            print("updated blender_manifest.toml: platforms and wheels", flush=True)
        rc = bext.main(["build", "--source-dir", ROOT, *argv_build[1:]], args_internal=False,
                       prog="blender --command extension")
    else:
        with tempfile.TemporaryDirectory(prefix="photon_lightmaps_stage_") as staged:
            stage(bext, manifest_text, sorted({w for ws in per_platform.values() for w in ws}), staged)
            rc = bext.main(["build", "--source-dir", staged, *argv_build[1:]], args_internal=False,
                           prog="blender --command extension")
    if rc != 0:
        return rc

    with open(MANIFEST, "rb") as fh:
        ext = tomllib.load(fh)
    for p in platforms:
        path = os.path.join(out, "%s-%s-%s.zip" % (ext["id"], ext["version"], p.replace("-", "_")))
        check_zip(bext, path, p, per_platform[p])
        print("%s  %.1f MiB  (%s)" % (path, os.path.getsize(path) / 2**20, ", ".join(per_platform[p])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
