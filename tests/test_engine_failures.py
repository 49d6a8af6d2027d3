"""An internal error never takes Blender down: a bug in the render pipeline, or
a kernel that fails to compile, ends that render with one line, and the same
process renders again. Each case runs in a process of its own, as a user's
Blender would, so a crash shows as a signal instead of killing the test run.
The second failed render also writes its still as OpenEXR, which Blender 5.0
crashes on when no engine filled the Render Result (a failed render leaves a
black frame there)."""
import os
import subprocess
import sys

import pytest

_SCRIPT = r'''
import math, sys
import bpy
from photon_lightmaps.registration import ensure_registered
ensure_registered()
from photon_lightmaps.bake import render as R
from photon_lightmaps.engine import session

bpy.ops.wm.read_factory_settings(use_empty=True)
sc = bpy.context.scene
sc.render.engine = "PHOTON_LIGHTMAPS"
sc.render.resolution_x, sc.render.resolution_y = 16, 12
sc.photon_lightmaps.photons, sc.photon_lightmaps.samples = 2000, 1
cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
sc.collection.objects.link(cam)
cam.location, cam.rotation_euler = (0, -6, 2), (math.radians(75), 0, 0)
sc.camera = cam
light = bpy.data.objects.new("L", bpy.data.lights.new("L", "POINT"))
light.data.energy = 500
light.location = (0, 0, 4)
sc.collection.objects.link(light)
bpy.ops.mesh.primitive_plane_add(size=6)

mode = sys.argv[-1]
if mode == "exception":
    def broken(*args, **kw):
        raise ZeroDivisionError("injected")
    original, R.run_render = R.run_render, broken
    restore = lambda: setattr(R, "run_render", original)
else:
    from numba import njit

    @njit
    def broken_kernel(x):
        return x.no_such_attribute      # fails numba's typing when first called

    def photon_pass(*args, **kw):
        return broken_kernel(1.0)
    original, session.render_photon_pass = session.render_photon_pass, photon_pass
    restore = lambda: setattr(session, "render_photon_pass", original)
import tempfile
sc.render.filepath = tempfile.mkdtemp() + "/failed.exr"
sc.render.image_settings.file_format = "OPEN_EXR"
for i in range(2):
    bpy.ops.render.render(write_still=i == 1)
    assert R.LAST_ERROR is not None and R.LAST_RUN is None or R.LAST_RUN.image is None
    # The kept error holds no Blender data past the render (its frames' locals are cleared).
    tb = R.LAST_ERROR.__traceback__
    while tb is not None:
        assert not any(isinstance(x, bpy.types.bpy_struct) for x in tb.tb_frame.f_locals.values())
        tb = tb.tb_next
restore()
bpy.ops.render.render()
assert R.LAST_ERROR is None and R.LAST_RUN.image is not None, R.LAST_ERROR
print("SURVIVED", flush=True)
'''


@pytest.mark.parametrize("mode, error", [
    ("exception", "internal error: ZeroDivisionError: injected"),
    ("compile", "internal error: TypingError: "),
])
def test_injected_failure_ends_the_render_with_one_line_and_blender_goes_on(mode, error):
    env = dict(os.environ)
    env.pop("PHOTON_LIGHTMAPS_DEBUG", None)
    r = subprocess.run([sys.executable, "-c", _SCRIPT, mode], env=env, capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, (r.returncode, r.stderr[-3000:])
    assert "SURVIVED" in r.stdout
    ours = [ln for ln in (r.stdout + r.stderr).splitlines() if "internal error" in ln]
    # One line per failed render, no traceback.
    assert len(ours) == 2 and all(error in ln for ln in ours), ours
    assert "Traceback" not in r.stderr, r.stderr[-3000:]


def test_viewport_callbacks_never_raise_into_blender(capsys, monkeypatch):
    """What escapes a viewport callback's own handling (here: the engine's data
    already freed by Blender) is one console line, not an exception in Blender's
    draw loop."""
    from photon_lightmaps.bake import viewport
    monkeypatch.delenv("PHOTON_LIGHTMAPS_DEBUG", raising=False)

    class FreedEngine:
        def __getattr__(self, name):
            raise ReferenceError("StructRNA of type PhotonLightmapsRenderEngine has been removed")

    for callback in (viewport.view_update, viewport.view_draw):
        assert callback(FreedEngine(), None, None) is None
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 2 and all(ln.startswith("Photon Lightmaps viewport: internal error: "
                                                 "ReferenceError: StructRNA") for ln in lines), lines
