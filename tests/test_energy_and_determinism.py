"""Energy audit, determinism, and the Cornell render through the whole pipeline."""
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.lightmaps import lightmap
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.core.errors import Cancelled
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
from photon_lightmaps.engine.transport.renderer import render
from photon_lightmaps.engine.core.scene import Light, Material, Primitive, compose, scale, translate


def test_energy_audit_closes_on_cornell_box():
    scene = demo_scenes.cornell_box(light_power=80.0)
    # One light of every kind, so each emitter's flux bookkeeping is exercised.
    scene.lights += [Light("point", power=20.0, transform=translate(0.5, -0.5, 1.5)),
                     Light("spot", power=30.0, transform=translate(-0.5, 0, 1.8)),
                     Light("sun", power=2.0, transform=np.eye(4)[:3])]
    emitter = scene.add_material(Material("lamp", diffuse=0.0, emission=[4.0, 3.0, 2.0]))
    scene.add_object(Primitive("sphere", material=emitter), compose(translate(0, 0.6, 1.5), scale(0.1)))
    cs = compile_scene(scene)
    stats = trace_photons(cs, 100_000, seed=11, max_bounces=6, record_direct=True)
    assert stats.audit_error() < 1e-12
    # Photons carry the lights' exact flux (up to Monte Carlo noise of the light choice).
    np.testing.assert_allclose(stats.emitted, cs.lights.flux.sum(axis=0), rtol=0.02)
    # The room is open at the front: some light escapes, most is absorbed.
    assert np.all(stats.escaped > 0) and np.all(stats.absorbed > stats.escaped)
    # The emissive sphere's flux is pi L A (outward only, a closed solid).
    lamp = int(np.where(cs.lights.kind == 4)[0][0])
    np.testing.assert_allclose(cs.lights.flux[lamp], math.pi * np.array([4.0, 3.0, 2.0]) * 4 * math.pi * 0.01,
                               rtol=1e-4)


_THREADS_SCRIPT = """
import hashlib, sys
import numba
import photon_lightmaps.engine
from photon_lightmaps.engine import demo_scenes
from photon_lightmaps.engine.compile import compile_scene
from photon_lightmaps.engine.transport.photon_tracer import trace_photons
for threads, seed in ((4, 7), (1, 7), (3, 7), (4, 8)):
    numba.set_num_threads(threads)
    cs = compile_scene(demo_scenes.cornell_box())
    trace_photons(cs, 30_000, seed=seed, max_bounces=5, chunk=4096)
    # photons aimed at the tall box (importance emission) are as reproducible
    aimed = compile_scene(demo_scenes.cornell_box())
    trace_photons(aimed, 30_000, seed=seed, max_bounces=5, chunk=4096, aim=((-0.35, 0.3, 0.6), 0.4))
    print(threads, seed, numba.get_num_threads(),
          hashlib.sha1(cs.lightmaps.flux.tobytes() + aimed.lightmaps.flux.tobytes()).hexdigest())
"""


def test_same_seed_is_bit_identical_across_thread_counts():
    """1, 3 and 4 threads whatever the machine has: numba's pool is sized by
    NUMBA_NUM_THREADS when it loads, so the run gets a process of its own."""
    env = dict(os.environ, NUMBA_NUM_THREADS="4")
    out = subprocess.run([sys.executable, "-c", _THREADS_SCRIPT], env=env, capture_output=True,
                         text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    rows = [ln.split() for ln in out.stdout.splitlines() if ln.strip()]
    assert [(int(t), int(g)) for t, _, g, _ in rows] == [(4, 4), (1, 1), (3, 3), (4, 4)]
    digests = [d for *_, d in rows]
    assert digests[0] == digests[1] == digests[2]      # seed 7 on 4, 1 and 3 threads
    assert digests[3] != digests[0]                    # another seed, other photons


def test_cornell_two_pass_agrees_with_photon_direct_light():
    """Direct light sampled by shadow rays and direct light from photons must agree."""
    scene = demo_scenes.cornell_box(width=32, height=32, with_primitives=False)
    cs = compile_scene(scene)
    trace_photons(cs, 300_000, seed=3, max_bounces=8, record_direct=False)
    two_pass = render(cs, samples=16, seed=1)
    cs_all = compile_scene(scene)
    trace_photons(cs_all, 300_000, seed=3, max_bounces=8, record_direct=True)
    # Render with the lightmap alone: switch light sampling off by removing the lights.
    cs_all.lights = cs_all.lights._replace(kind=cs_all.lights.kind[:0])
    photons_only = render(cs_all, samples=16, seed=1)
    assert np.all(np.isfinite(two_pass)) and two_pass.min() >= 0
    m2, m1 = two_pass.mean(axis=(0, 1)), photons_only.mean(axis=(0, 1))
    np.testing.assert_allclose(m2, m1, rtol=0.05)
    # The red wall's side of the image is red, the green wall's side green (the
    # columns also hold white floor and ceiling, hence the modest ratios).
    left, right = two_pass[:, :8].mean(axis=(0, 1)), two_pass[:, -8:].mean(axis=(0, 1))
    assert left[0] / left[1] > 3 and right[1] / right[0] > 1.5


def test_progress_callback_can_cancel():
    cs = compile_scene(demo_scenes.cornell_box(width=64, height=64))
    calls = []
    with pytest.raises(Cancelled):
        trace_photons(cs, 50_000, chunk=4096, progress=lambda done, total: calls.append(done) or False)
    assert calls == [4096]
    trace_photons(cs, 10_000)
    tiles = []
    with pytest.raises(Cancelled):
        render(cs, samples=1, tile=32, progress=lambda x, y, tile, img: tiles.append((x, y)) or len(tiles) < 2)
    assert tiles == [(0, 0), (32, 0)]
