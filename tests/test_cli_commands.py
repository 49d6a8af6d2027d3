"""Every CLI command end to end, at tiny sizes, as a user runs it: the README's
`make demo` (through make, so the Makefile's command line is tested too; it renders the
spectral demo too), then
`render`, `bake` and `bake-ol` on the file the demo wrote, and `lsystem`.
Each checks its exit code, the files it wrote and the keys of its report."""
import json
import os
import pathlib
import re
import subprocess
import sys

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
TINY = ("--photons", "20000", "--seed", "1")


def run(*argv, timeout=900, env=None, check=True):
    """The CLI on argv; check: it must succeed (otherwise only: without a traceback)."""
    r = subprocess.run([sys.executable, "-m", "photon_lightmaps", *map(str, argv)], cwd=ROOT,
                       capture_output=True, text=True, timeout=timeout, env=env)
    assert r.returncode == 0 or not check, r.stderr[-3000:]
    assert "Traceback" not in r.stderr
    return r


def read_png(path):
    import bpy
    img = bpy.data.images.load(str(path))
    try:
        return tuple(img.size)
    finally:
        bpy.data.images.remove(img)


def exr_names(folder):
    return sorted(p.stem for p in pathlib.Path(folder).glob("*.exr"))


def test_readme_commands_are_the_makefile_targets_ci_runs():
    """The README's fresh-machine block is `make demo` and `make test`; CI runs exactly
    the second, and the demo fixture below runs the first."""
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"## Two commands on a fresh machine\s+```sh\n(.*?)```", readme, re.S).group(1)
    commands = [ln.split("#")[0].strip() for ln in block.splitlines() if ln.strip()]
    assert commands == ["make demo", "make test"]
    ci = [ln.strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines()
          if ln.strip() and not ln.startswith("#")]
    assert ci[-1] == "make test"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """`make demo` with tiny sizes, into a temporary folder."""
    out = tmp_path_factory.mktemp("demo")
    env = dict(os.environ, DEMO_OUT=str(out),
               DEMO_ARGS=" ".join([*TINY, "--samples", "1", "--size", "24x16", "--json", str(out / "demo.json")]))
    r = subprocess.run(["make", "-s", "-C", str(ROOT), "demo"], env=env, capture_output=True, text=True,
                       timeout=1800)
    assert r.returncode == 0, (r.stdout[-2000:], r.stderr[-3000:])
    return out, r


def test_make_demo_renders_and_bakes(demo):
    out, r = demo
    assert re.search(r"^demo: .*render\.png, .*spectral\.png, .*polarizer_0\.png and .*polarizer_90\.png and "
                     r"\d+ baked lightmaps", r.stdout, re.M), r.stdout[-2000:]
    assert (out / "demo.blend").is_file() and (out / "spectral.blend").is_file()
    assert read_png(out / "render.png") == (24, 16) and read_png(out / "spectral.png") == (24, 16)
    report = json.loads((out / "demo.json").read_text())
    assert set(report) >= {"blend", "render", "bake", "orientation_lightmaps", "spectral", "polarizer", "seconds"}
    assert report["spectral"]["photons"] > 0
    # the filter at 0° and 90° over water (the glare it takes off: tests/test_polarization_mitsuba.py)
    pol = report["polarizer"]
    assert (pol["0 deg"]["settings"]["polarizer"], pol["90 deg"]["settings"]["polarizer"]) == (0.0, 90.0)
    assert read_png(out / "polarizer_0.png") == (24, 16) and read_png(out / "polarizer_90.png") == (24, 16)
    assert report["render"]["photons"] > 0 and report["render"]["width"] == 24
    assert report["bake"]["indirect"] == "gather" and report["bake"]["photons"] > 0
    baked = report["bake"]["objects"]
    assert {"floor", "back", "left", "right"} <= set(baked)
    for name, row in baked.items():
        assert os.path.isfile(row["path"]) and row["bytes"] > 0 and np.all(np.isfinite(row["mean"])), name
    ols = report["orientation_lightmaps"]["orientation_lightmaps"]
    assert len(ols) == 1
    assert set(exr_names(out / "lightmaps")) == set(baked) | set(ols)


def test_render(demo, tmp_path):
    out, _ = demo
    rep = tmp_path / "r.json"
    r = run("render", out / "demo.blend", "--out", tmp_path / "r.exr", "--json", rep, *TINY,
            "--samples", "1", "--indirect", "lookup")
    report = json.loads(rep.read_text())
    assert (tmp_path / "r.exr").stat().st_size > 0 and "r.exr" in r.stdout
    assert report["settings"]["indirect"] == "LOOKUP" and report["settings"]["samples"] == 1
    assert set(report["seconds"]) >= {"load", "pipeline", "total", "photon_pass", "render"}
    assert (report["width"], report["height"]) == (24, 16)


def test_render_frames(demo, tmp_path):
    """--frames renders one image per frame; the demo's camera does not move, so
    the second frame reuses the first's light (and its irradiance cache)."""
    out, _ = demo
    rep = tmp_path / "f.json"
    r = run("render", out / "demo.blend", "--out", tmp_path / "f_##.png", "--json", rep, *TINY,
            "--samples", "1", "--frames", "1-2", "--irradiance-cache")
    report = json.loads(rep.read_text())
    assert [read_png(tmp_path / f"f_0{f}.png") for f in (1, 2)] == [(24, 16)] * 2
    assert [f["frame"] for f in report["frames"]] == [1, 2]
    assert [f["light_from_frame"] for f in report["frames"]] == [None, 1]
    assert report["frames_reusing_light"] == 1 and "light of frame 1 reused" in r.stdout
    # the irradiance cache's records are made with the light, and kept with it
    assert report["settings"]["irradiance_cache"] is True
    assert report["frames"][0]["seconds"]["records"] > 0.0 and report["frames"][1]["seconds"]["records"] == 0.0
    assert set(report["seconds"]) >= {"load", "pipeline", "total", "photon_pass", "render"}


def test_bake(demo, tmp_path):
    out, _ = demo
    rep = tmp_path / "b.json"
    run("bake", out / "demo.blend", "--out", tmp_path / "maps", "--json", rep, *TINY,
        "--resolution", "8", "--bake-gather-rays", "2", "--error-images")
    report = json.loads(rep.read_text())
    assert report["bake_gather_rays"] == 2
    assert set(report) >= {"photons", "rays", "seconds", "objects", "skipped", "warnings", "memory"}
    for name, row in report["objects"].items():
        assert (row["width"], row["height"]) == (8, 8) or name.startswith("csg"), name
        assert os.path.isfile(row["path"]) and os.path.isfile(row["error_image"]), name


def test_spectral_render_and_bake_come_back_as_rgb(demo, tmp_path):
    """--spectral traces 16 bands (and --polarization Stokes rows) and writes RGB like the
    plain run: the demo's bake
    in both modes, the same seed, each object's mean within 1 % per channel (measured
    0.4 %: the two differ where colours mix)."""
    out, _ = demo
    run("render", out / "demo.blend", "--out", tmp_path / "s.exr", "--json", tmp_path / "s.json", *TINY,
        "--samples", "1", "--spectral", "--polarization")
    used = json.loads((tmp_path / "s.json").read_text())["settings"]
    assert used["spectral"] is True and used["polarization"] is True
    means = {}
    for mode in ("--spectral", "--no-spectral"):
        rep = tmp_path / f"{mode}.json"
        run("bake", out / "demo.blend", "--out", tmp_path / mode, "--json", rep, "--photons", "200000", "--seed",
            "1", "--resolution", "8", "--bake-gather-rays", "16", mode,
            *(["--spectral-exr"] if mode == "--spectral" else []))
        means[mode] = {name: _exr_mean(row["path"]) for name, row in json.loads(rep.read_text())["objects"].items()}
    assert means["--spectral"].keys() == means["--no-spectral"].keys()
    for name, rgb in means["--no-spectral"].items():
        print(f"\n{name}: RGB {np.round(rgb, 4)}, spectral {np.round(means['--spectral'][name], 4)}")
        np.testing.assert_allclose(means["--spectral"][name], rgb, rtol=0.01, err_msg=name)
    # --spectral-exr: every band of each (mesh) lightmap, which goes to the RGB map's values
    from photon_lightmaps.bake import spectral_exr
    from photon_lightmaps.engine.shading import spectrum
    bands = spectrum.Bands()
    objects = json.loads((tmp_path / "--spectral.json").read_text())["objects"]
    written = {name: row["spectral_exr"] for name, row in objects.items() if "spectral_exr" in row}
    assert {"floor", "back", "left", "right"} <= set(written)
    for name, path in written.items():
        values, nm = spectral_exr.read(path)
        np.testing.assert_allclose(nm, bands.lo + (np.arange(16) + 0.5) * 25.0)
        rgb = _exr_pixels(objects[name]["path"])
        np.testing.assert_allclose(spectrum.to_rgb(values.astype(np.float64), bands), rgb[..., :3], rtol=1e-4,
                                   atol=1e-6, err_msg=name)
    r = run("bake", out / "demo.blend", "--out", tmp_path / "x", "--no-spectral", "--spectral-exr", check=False)
    assert r.returncode == 2 and "spectral EXR files need a spectral bake" in r.stderr


def _exr_pixels(path):
    """(height, width, 4) of an RGBA EXR, bottom row first."""
    import bpy
    img = bpy.data.images.load(str(path))
    try:
        return np.array(img.pixels[:], np.float64).reshape(img.size[1], img.size[0], 4)
    finally:
        bpy.data.images.remove(img)


def _exr_mean(path):
    import bpy
    img = bpy.data.images.load(str(path))
    try:
        px = np.array(img.pixels[:], np.float64).reshape(-1, 4)
    finally:
        bpy.data.images.remove(img)
    keep = px[:, 3] > 0.0
    assert keep.any(), path
    return (px[keep, :3] * px[keep, 3:]).sum(axis=0) / px[keep, 3].sum()


def test_bake_ol(demo, tmp_path):
    out, _ = demo
    rep = tmp_path / "o.json"
    run("bake-ol", out / "demo.blend", "--out", tmp_path / "ol", "--json", rep, *TINY)
    report = json.loads(rep.read_text())
    (name, row), = report["orientation_lightmaps"].items()
    assert os.path.isfile(row["path"]) and row["resolution"] > 0 and row["objects"]
    assert exr_names(tmp_path / "ol") == [name]


def test_lsystem(tmp_path):
    grammar = tmp_path / "tree.lsys"
    grammar.write_text("axiom: F\nderivation length: 3\nangle: 25.7\nproduction:\nF --> F[+F]F[-F]F\n")
    rep = tmp_path / "l.json"
    run("lsystem", grammar, "--json", rep, "--render", tmp_path / "l.png", "--photons", "20000",
        "--samples", "1", "--size", "16x16")
    report = json.loads(rep.read_text())
    assert report["segments"] == 5 ** 3 and report["primitives"] == 5 ** 3
    assert read_png(tmp_path / "l.png") == (16, 16)


def test_compile_line_is_ended_before_other_output():
    import io

    from photon_lightmaps import cli
    from photon_lightmaps.engine.core.kernel_watch import KernelWatch
    out = io.StringIO()
    tracker = cli._LineTracker(out)
    watch = KernelWatch(cli.compile_line(tracker, clock=iter(range(100)).__next__))
    for _ in range(2):
        watch.started += 1
        watch.on_compile(watch, "k")
    tracker.write("\rphotons 10/10")
    text = out.getvalue()
    assert text.count("compiling kernels (first run") == 2
    assert "2 so far" in text and text.endswith("s \n\rphotons 10/10")
