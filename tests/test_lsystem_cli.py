"""`python -m photon_lightmaps lsystem FILE`: counts through the scene graph, one-line errors."""
import json

import numpy as np

from photon_lightmaps import cli

ABOP_124A = "axiom: F\nderivation length: {n}\nangle: 25.7\nproduction:\nF --> F[+F]F[-F]F\n"


def _run(capsys, *argv):
    rc = cli.main(["lsystem", *map(str, argv)])
    out, err = capsys.readouterr()
    return rc, out, err


def test_published_counts_and_bounds(tmp_path, capsys):
    f = tmp_path / "a.lsys"
    f.write_text(ABOP_124A.format(n=5))
    rc, out, _ = _run(capsys, f, "--string")
    r = json.loads(out)
    assert rc == 0
    assert (r["length"], r["segments"], r["primitives"]) == (7811, 3125, 3125)
    assert r["counts"]["["] == r["counts"]["]"] == 1562
    assert len(r["string"]) == 7811                               # one character per module here
    # the trunk is 3^5 = 243 long and the tree lies in the H-L plane (y = 0)
    assert r["bounds_exact"] and r["bounds"]["max"][2] == 243.0
    assert r["bounds"]["min"][1] == r["bounds"]["max"][1] == 0.0
    assert r["dcsg_nodes"] < 20 and r["memory"]["peak_rss_bytes"] > 0


def test_counts_come_from_the_graph_for_huge_grammars(tmp_path, capsys):
    f = tmp_path / "a.lsys"
    f.write_text(ABOP_124A.format(n=5))
    rc, out, _ = _run(capsys, f, "--steps", 60)
    r = json.loads(out)
    assert rc == 0 and r["segments"] == r["primitives"] == 5 ** 60
    assert r["length"] == 5 ** 60 + 6 * (5 ** 60 - 1) // 4
    # 5^60 segments cannot have been expanded one by one: the counts are the
    # graph's (no wall-clock bound: a loaded machine would fail it, and
    # benchmarks/ times the L-systems)
    assert not r["bounds_exact"]


def test_bad_grammar_is_one_line_with_exit_code_2(tmp_path, capsys):
    f = tmp_path / "bad.lsys"
    f.write_text("axiom: F\nderivation length: 2\nproduction:\nF --> F(1 + F\n")
    rc, out, err = _run(capsys, f)
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and "line 4, column" in err and "Traceback" not in err
    rc, _, err = _run(capsys, tmp_path / "missing.lsys")
    assert rc == 2 and "cannot read" in err


def test_render_through_the_graph_in_the_studio(tmp_path, capsys):
    from photon_lightmaps.engine.lsystem.presets import preset_text
    f = tmp_path / "tree.lsys"
    f.write_text(preset_text("sympodial_tree"))
    out = tmp_path / "tree.png"
    rc, text, _ = _run(capsys, f, "--render", out, "--size", "48x40", "--photons", 20000,
                       "--samples", 1)
    r = json.loads(text)
    assert rc == 0 and out.stat().st_size > 0
    assert (r["render"]["width"], r["render"]["height"]) == (48, 40)
    # the tree's own OL and one per stub (7.4), all photons accounted for
    assert r["render"]["orientation_lightmaps"] > 1 and r["render"]["photons"] == 20000
    import bpy
    img = bpy.data.images.load(str(out))
    try:
        px = np.array(img.pixels[:]).reshape(40, 48, 4)
        assert px[..., :3].max() > 0.2 and px[..., :3].std() > 0.01      # lit, not flat
    finally:
        bpy.data.images.remove(img)
