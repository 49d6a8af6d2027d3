"""The kernel warm-up (engine/warmup.py): what it covers, its marker, and how a
render meets a warm-up that is still running. That a warm-up leaves nothing for a
render to compile is checked end to end, on an empty cache, in test_cli_commands.py."""
import threading

import numba
import pytest

from photon_lightmaps.engine.core import features
from photon_lightmaps.engine import warmup
from photon_lightmaps.engine.geometry.assembly import compile_geometry


class Fake:
    """A family that runs `work` in this process (no spec: never in a helper)."""

    def __init__(self, name, work=None):
        self.name, self.work = name, work

    def __call__(self):
        self.work()


@pytest.mark.parametrize("ol", [True, False])
@pytest.mark.parametrize("mask", [0, features.CSG, features.DCSG, features.ALL])
def test_tiny_scenes_compile_to_their_feature_mask(mask, ol):
    scene = warmup._scene(mask, ol=ol)
    assert warmup.scene_mask(scene) == mask
    assert features.mask_of(compile_geometry(scene)[0].trace_features) == mask


def test_families_cover_every_traversal_variant():
    assert {f.mask for f in warmup.FAMILIES} == {0, features.CSG, features.DCSG}
    names = [f.name for f in warmup.FAMILIES]
    assert names[0] == "meshes and primitives: render"       # what F12 needs first
    assert sum("bake" in n for n in names) == 2
    for f in warmup.FAMILIES:
        g = warmup.Family.parse(f.spec)
        assert (g.mask, g.pass_, g.photons) == (f.mask, f.pass_, True)


def test_a_finished_warmup_marks_the_cache(tmp_path, monkeypatch):
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    calls = []
    monkeypatch.setattr(warmup, "FAMILIES", [Fake("a", lambda: calls.append("a")),
                                             Fake("b", lambda: calls.append("b"))])
    assert not warmup.is_warm()
    seen = []
    w = warmup.WarmUp().run(lambda k, n: seen.append(("before", k, n)), lambda k, n: seen.append(("after", k, n)),
                            processes=1)
    assert calls == ["a", "b"] and w.done == 2 and w.fraction == 1.0 and w.error is None
    assert seen == [("before", 1, "a"), ("after", 1, "a"), ("before", 2, "b"), ("after", 2, "b")]
    assert [r["family"] for r in w.reports] == ["a", "b"]
    assert warmup.is_warm()


def test_two_lanes_run_every_family_once(tmp_path, monkeypatch):
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))
    both = threading.Barrier(2, timeout=10)     # both lanes are under way at once
    calls = []
    monkeypatch.setattr(warmup, "FAMILIES", [Fake(n, lambda n=n: (both.wait() if n in "ab" else None,
                                                                  calls.append(n))) for n in "abcde"])
    w = warmup.WarmUp().run(processes=2)
    assert w.error is None and sorted(calls) == list("abcde") and w.done == 5 and warmup.is_warm()


def test_a_failing_family_stops_without_raising(tmp_path, monkeypatch):
    monkeypatch.setattr(numba.config, "CACHE_DIR", str(tmp_path))

    def broken():
        raise RuntimeError("no")
    monkeypatch.setattr(warmup, "FAMILIES", [Fake("ok", lambda: None), Fake("broken", broken), Fake("never")])
    w = warmup.WarmUp().run(processes=1)
    assert w.done == 1 and w.error == "broken: RuntimeError: no" and w.finished.is_set()
    assert not warmup.is_warm()


@pytest.fixture
def running(monkeypatch):
    """A background warm-up half done, finishing when the test sets `release`."""
    w = warmup.WarmUp()
    w.done, w.under_way = 2, ["exact CSG solids: render"]
    release = threading.Event()
    monkeypatch.setattr(warmup, "_background", w)

    def finish():
        release.wait(10)
        w.finished.set()
    threading.Thread(target=finish, daemon=True).start()
    return w, release


def test_a_render_waits_for_the_warmup_and_says_so(running):
    from photon_lightmaps.bake import render
    w, release = running
    lines = []

    def stats(text):
        lines.append(text)
        if len(lines) == 2:
            release.set()
    assert render._wait_for_warmup(stats, lambda: False)
    assert lines[0] == f"Preparing kernels (first run): {2 / len(warmup.FAMILIES):.0%}, exact CSG solids: render"


def test_a_render_cancelled_while_waiting_stops(running):
    from photon_lightmaps.bake import render
    w, release = running
    assert not render._wait_for_warmup(lambda text: None, lambda: True)
    release.set()


def test_headless_blender_starts_no_background_warmup():
    import bpy

    from photon_lightmaps.operators import render_engine
    assert bpy.app.background
    assert render_engine.start_warmup() is None and warmup.status() is None


def test_a_stuck_helper_never_holds_the_render(monkeypatch):
    """join stops waiting after JOIN_LIMIT_S; the render then compiles what it needs itself."""
    class Stuck:
        def wait(self, family, poll):
            while poll(self) is not False:
                pass
            return False
    monkeypatch.setattr(warmup, "JOIN_LIMIT_S", 0.2)
    monkeypatch.setitem(warmup._ahead, (0, "render"), (Stuck(), None))
    seen = []
    warmup.join(0, "render", poll=seen.append)
    assert seen and (0, "render") not in warmup._ahead
