"""Operators: "Bake Photon Lightmaps" and "Remove Lightmap Hook".

The bake runs modal: the scene is exported on the UI thread, the photon pass
runs on a worker thread while a timer updates the status bar, and the images
are written on the UI thread once every lightmap is done. Esc sets a flag the
photon pass polls between chunks; a cancelled or failed bake writes nothing
(the Lightmap UV layers it made are removed again), so images and layers from
an earlier bake stay as they were. A user error (engine SceneError) is reported
as its one-line text (messages.py).
"""
import threading

import bpy
from bpy.props import BoolProperty, IntProperty

from .. import messages
from ..bake import hooks
from ..bake import pipeline as B
from ..engine.photon_tracer import Cancelled
from .common import ImageOutputOptions, ObjectModeOperator


def _bake_candidates(context, selected_only):
    obs = context.selected_objects if selected_only else context.scene.objects
    return [ob for ob in obs if ob.type == "MESH"]


def _summary(res):
    n = len(res.images)
    text = f"Baked {n} lightmap{'s' if n != 1 else ''}"
    if res.stats is not None:
        text += f" ({res.stats.photons:,} photons, {res.seconds.get('total', 0.0):.1f} s)"
    return text


class PHOTON_LIGHTMAPS_OT_bake(ObjectModeOperator, ImageOutputOptions, bpy.types.Operator):
    """Bake photon lightmaps (direct + indirect irradiance) of mesh objects to float images"""
    bl_idname = "photon_lightmaps.bake"
    bl_label = "Bake Photon Lightmaps"
    bl_options = {"REGISTER"}
    poll_mode_message = "Bake in Object Mode"

    selected_only: BoolProperty(
        name="Selected Only", default=True,
        description="Bake the selected mesh objects; off: every mesh object of the scene")
    photons: IntProperty(
        name="Photons", default=0, min=0, soft_max=100_000_000,
        description="Photons to shoot; 0 uses the scene's Photon Lightmaps setting")
    resolution: IntProperty(
        name="Resolution", default=0, min=0, soft_max=4096,
        description="Force R x R texels per object; 0 uses each object's setting or the texel density")
    indirect_only: BoolProperty(
        name="Indirect Only", default=False,
        description="Leave direct light out of the lightmaps (for engines that add it themselves)")
    hook_materials: BoolProperty(
        name="Hook Materials", default=False,
        description="Add a removable 'Photon Lightmap' node setup to the materials, "
                    "so EEVEE and Material Preview show the baked light")
    run_modal: BoolProperty(
        default=False, options={"HIDDEN", "SKIP_SAVE"},
        description="Set by invoke: run in the background with progress in the status bar")

    _timer = None
    _thread = None

    # -- shared --------------------------------------------------------------------------
    def _start(self, context):
        objects = _bake_candidates(context, self.selected_only)
        if not objects:
            self.report({"ERROR"}, "No mesh objects to bake" + (" (select some)" if self.selected_only else ""))
            return None
        return B.prepare_bake(context, objects, photons=self.photons or None,
                              resolution=self.resolution or None, indirect_only=self.indirect_only)

    def _finish(self, job):
        # Objects may have been deleted while the photon pass ran.
        for name in [n for n in job.result.maps if n not in bpy.data.objects]:
            job.result.skipped[name] = "deleted during the bake"
            del job.result.maps[name]
        res = B.commit_bake(job, overwrite=self.overwrite, pack=self.pack,
                            hook_materials=self.hook_materials)
        warnings = [f"'{name}' not baked: {why}" for name, why in res.skipped.items()] + res.warnings
        for w in warnings:
            self.report({"WARNING"}, w)
        messages.record(bpy.context.scene.name, "bake", warnings)
        self.report({"INFO"}, _summary(res))
        return res

    def _failed(self, context, exc, job=None):
        # Nothing half-written: the Lightmap UV layers prepare_bake made go again.
        if job is not None:
            B.rollback_bake(job)
        if isinstance(exc, Cancelled):
            self.report({"WARNING"}, "Photon Lightmaps bake cancelled; nothing was changed")
            return {"CANCELLED"}
        return messages.operator_failed(self, exc, context.scene)

    # -- entry points ------------------------------------------------------------------------
    def invoke(self, context, event):
        # Options first; confirming the dialog calls execute, which then goes modal.
        self.run_modal = True
        return context.window_manager.invoke_props_dialog(self, confirm_text="Bake")

    def execute(self, context):
        job = None
        try:
            job = self._start(context)
            if job is None:
                return {"CANCELLED"}
            if self.run_modal and context.window is not None:
                return self._start_modal(context, job)
            # Blocking (scripts, background mode).
            B.compute_bake(job)
            self._finish(job)
        except Exception as e:  # noqa: BLE001  (reported to the user instead of a traceback)
            return self._failed(context, e, job)
        return {"FINISHED"}

    # -- modal (UI) ----------------------------------------------------------------------------
    def _start_modal(self, context, job):
        # The worker only touches these plain objects, never the operator (an RNA struct).
        cancel = threading.Event()
        state = {"done": 0, "total": max(int(job.settings.photons), 1), "error": None}

        def progress(done, total):
            state["done"], state["total"] = done, max(total, 1)
            return not cancel.is_set()

        def work():
            try:
                B.compute_bake(job, progress)
            except BaseException as e:  # noqa: BLE001  (handed to the UI thread)
                state["error"] = e

        self._job, self._cancel, self._state = job, cancel, state
        self._thread = threading.Thread(target=work, name="photon-lightmaps-bake", daemon=True)
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        self._status(context, "Photon Lightmaps: photon pass 0%  (Esc to cancel)")
        self._thread.start()
        return {"RUNNING_MODAL"}

    def _status(self, context, text):
        ws = getattr(context, "workspace", None)
        if ws is not None:
            ws.status_text_set(text)

    def _cleanup(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        ws = getattr(context, "workspace", None)
        if ws is not None:
            ws.status_text_set(None)

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self._cancel.set()
            self._status(context, "Photon Lightmaps: cancelling...")
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        pct = 100.0 * self._state["done"] / self._state["total"]
        context.window_manager.progress_update(pct)
        if not self._cancel.is_set():
            self._status(context, f"Photon Lightmaps: photon pass {pct:.0f}%  (Esc to cancel)")
        if self._thread.is_alive():
            return {"RUNNING_MODAL"}
        self._thread.join()
        self._cleanup(context)
        error = self._state["error"]
        if self._cancel.is_set():
            error = Cancelled("cancelled with Esc")
        try:
            if error is not None:
                raise error
            self._finish(self._job)
        except Exception as e:  # noqa: BLE001  (reported to the user instead of a traceback)
            return self._failed(context, e, self._job)
        return {"FINISHED"}

    def cancel(self, context):
        # Blender ends the operator (e.g. the window closes): stop the worker too.
        if self._thread is not None:
            self._cancel.set()
            self._thread.join()
            B.rollback_bake(self._job)
        self._cleanup(context)

    def draw(self, context):
        col = self.layout.column()
        for prop in ("selected_only", "photons", "resolution", "indirect_only", "hook_materials",
                     "overwrite", "pack"):
            col.prop(self, prop)


class PHOTON_LIGHTMAPS_OT_remove_lightmap_hook(bpy.types.Operator):
    """Remove the 'Photon Lightmap' nodes the bake added to materials (nothing else is touched)"""
    bl_idname = "photon_lightmaps.remove_lightmap_hook"
    bl_label = "Remove Lightmap Hook"
    bl_options = {"REGISTER", "UNDO"}

    selected_only: BoolProperty(
        name="Selected Only", default=False,
        description="Only the materials of the selected objects; off: every material")

    def execute(self, context):
        mats = None
        if self.selected_only:
            mats = {s.material for ob in context.selected_objects for s in ob.material_slots
                    if s.material is not None}
        n = hooks.remove_lightmap_hook(mats)
        self.report({"INFO"}, f"Removed {n} Photon Lightmap node{'s' if n != 1 else ''}")
        return {"FINISHED"}


classes = (PHOTON_LIGHTMAPS_OT_bake, PHOTON_LIGHTMAPS_OT_remove_lightmap_hook)
