"""Operators: "Bake Photon Lightmaps" and "Remove Lightmap Hook".

The bake runs modal: meshes without a Lightmap UV layer are unwrapped by xatlas
on a worker thread first (told up front with an estimate, cancellable), the
scene is exported on the UI thread, the bake runs on a worker thread while a
timer shows its phase in the status bar, and the images are written on the UI
thread once every lightmap is done. Esc sets a flag the
photon pass polls between chunks; a cancelled or failed bake writes nothing
(the Lightmap UV layers it made are removed again), so images and layers from
an earlier bake stay as they were. A user error (engine SceneError) is reported
as its one-line text (messages.py).
"""
import threading

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from .. import messages
from ..bake import hooks
from ..bake import pipeline
from ..engine.core.errors import Cancelled
from ..export import uv_layers
from .common import ImageOutputOptions, ObjectModeOperator


def _bake_candidates(context, selected_only):
    obs = context.selected_objects if selected_only else context.scene.objects
    return [ob for ob in obs if ob.type == "MESH"]


def _without_layer(objects):
    """(how many meshes have no Lightmap UV layer, their triangles): cheap enough for draw()."""
    import numpy as np
    meshes = {ob.data for ob in objects if ob.data.uv_layers.get(uv_layers.LAYER_NAME) is None}
    triangles = 0
    for me in meshes:
        loops = np.empty(len(me.polygons), np.int32)
        me.polygons.foreach_get("loop_total", loops)
        triangles += int((loops - 2).sum())
    return len(meshes), triangles


def _duration(seconds):
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


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
        description="Photons to shoot; 0 uses the scene's setting (Bake Photons when the bake "
                    "gathers, Photons for a Lookup bake)")
    resolution: IntProperty(
        name="Resolution", default=0, min=0, soft_max=4096,
        description="Force R x R texels per object; 0 uses each object's setting or the texel density")
    indirect_only: BoolProperty(
        name="Indirect Only", default=False,
        description="Leave direct light out of the lightmaps (for engines that add it themselves)")
    bake_pass: EnumProperty(
        name="Pass", default="COMBINED",
        items=[("COMBINED", "Combined", "Direct and indirect light"),
               ("DIRECT", "Direct", "Direct light alone (light samples per texel; no photons)"),
               ("INDIRECT", "Indirect", "Indirect light alone (as Indirect Only)"),
               ("AO", "Ambient Occlusion", "The share of the hemisphere open within AO Distance (no photons)"),
               ("SHADOWMASK", "Shadowmask", "Up to four lights' visibility, one per channel R, G, B, A "
                                            "(no photons)")],
        description="What the lightmaps hold; game engines mix split passes with their own light")
    ao_distance: FloatProperty(
        name="AO Distance", default=1.0, min=1e-4, soft_max=100.0, subtype="DISTANCE",
        description="Ambient Occlusion: rays that meet nothing within this distance are unoccluded")
    shadowmask_lights: StringProperty(
        name="Lights", default="",
        description="Shadowmask: up to four lights, comma-separated, for channels R, G, B, A; empty: every "
                    "light, when there are at most four")
    pass_rays: IntProperty(
        name="Rays", default=16, min=1, soft_max=1024,
        description="Ambient Occlusion and Shadowmask: rays (light samples) per point, 16 points a texel; "
                    "noise falls as one over the square root")
    texel_validity: BoolProperty(
        name="Texel Validity", default=False,
        description="Fill texels that lie inside geometry (most of their rays meet back faces, as under a box "
                    "on the floor) from their neighbours, so no light leaks out of them; each object's "
                    "<object>_LightmapValidity image shows them in red")
    directional: EnumProperty(
        name="Directional", default="NONE",
        description="Also bake which way each texel's light comes from, so normal-mapped materials show their "
                    "bumps under baked light (with Hook Materials, EEVEE)",
        items=(("NONE", "None", "The lightmap alone"),
               ("DOMINANT", "Dominant Direction",
                "One direction per texel, of the light's brightness (<object>_LightmapDirection): exact for one "
                "key light plus sky"),
               ("SH", "L1 SH per Colour",
                "First-order spherical harmonics per colour (<object>_LightmapL1x, y, z): light of different "
                "colours from different sides, but a key light's lobe widened")))
    stitch_seams: BoolProperty(
        name="Stitch Seams", default=False,
        description="Make texels that meet across UV seams, and across edges objects share, agree where they "
                    "meet, so a real-time engine's texture filter shows no line there (smooth edges only: a "
                    "crease keeps its jump)")
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
    def _objects(self, context):
        objects = _bake_candidates(context, self.selected_only)
        if not objects:
            self.report({"ERROR"}, "No mesh objects to bake" + (" (select some)" if self.selected_only else ""))
        return objects

    def _prepare(self, context, objects):
        return pipeline.prepare_bake(context, objects, photons=self.photons or None,
                                     resolution=self.resolution or None, indirect_only=self.indirect_only,
                                     bake_pass=None if self.bake_pass == "COMBINED" else self.bake_pass,
                                     ao_distance=self.ao_distance, shadowmask_lights=self.shadowmask_lights,
                                     texel_validity=self.texel_validity or None, pass_rays=self.pass_rays,
                                     stitch_seams=self.stitch_seams or None,
                                     directional="" if self.directional == "NONE" else self.directional)

    def _finish(self, job):
        # Objects may have been deleted while the photon pass ran.
        for name in [n for n in job.result.maps if n not in bpy.data.objects]:
            job.result.skipped[name] = "deleted during the bake"
            del job.result.maps[name]
        res = pipeline.commit_bake(job, overwrite=self.overwrite, pack=self.pack,
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
            pipeline.rollback_bake(job)
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
            objects = self._objects(context)
            if not objects:
                return {"CANCELLED"}
            if self.run_modal and context.window is not None:
                return self._start_modal(context, objects)
            # Blocking (scripts, background mode).
            job = self._prepare(context, objects)
            pipeline.compute_bake(job)
            self._finish(job)
        except Exception as e:  # noqa: BLE001  (reported to the user instead of a traceback)
            return self._failed(context, e, job)
        return {"FINISHED"}

    # -- modal (UI) ----------------------------------------------------------------------------
    # The status bar and progress bar follow the phases: xatlas unwraps (on a
    # worker thread, before the export reads their layers), then the bake's
    # scene, kernels, photons, direct light, gather and images.
    _SPAN = {"unwrap": (0, 15), "scene": (15, 18), "kernels": (18, 20), "photons": (20, 55),
             "direct": (55, 65), "gather": (65, 95), "images": (95, 98), "denoise": (98, 100)}

    def _start_modal(self, context, objects):
        # Workers only touch these plain objects, never the operator (an RNA struct).
        cancel = threading.Event()
        state = {"phase": "unwrap", "detail": "", "done": 0, "total": 1, "error": None}
        self._job, self._cancel, self._state, self._objects_left = None, cancel, state, objects
        plan = pipeline.unwrap_plan(context, objects, self.resolution or None)
        if plan:
            triangles = sum(t.shape[0] for _, _, t, _ in plan)
            state.update(total=len(plan), estimate=pipeline.unwrap_seconds(triangles),
                         detail=f"{len(plan)} mesh{'es' if len(plan) != 1 else ''} without a Lightmap "
                                f"UV layer, {triangles:,} triangles, about {_duration(pipeline.unwrap_seconds(triangles))}")

            def progress(done, total):
                state["done"], state["total"] = done, max(total, 1)

            def unwrap():
                try:
                    pipeline.run_unwraps(plan, progress, cancel.is_set)
                except BaseException as e:  # noqa: BLE001  (handed to the UI thread)
                    state["error"] = e
            self._thread = threading.Thread(target=unwrap, name="photon-lightmaps-unwrap", daemon=True)
        else:
            self._thread = None
        if self._thread is None:
            self._start_compute(context)    # before the handler: a failed export ends execute()
        else:
            self._thread.start()
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.modal_handler_add(self)
        self._show(context)
        return {"RUNNING_MODAL"}

    def _start_compute(self, context):
        """UI thread: the export (its unwraps are cached now), then the bake on a worker."""
        job = self._prepare(context, self._objects_left)
        state, cancel = self._state, self._cancel
        self._job = job
        state.update(phase="scene", detail="", done=0, total=max(int(job.settings.photons), 1))

        def progress(done, total):
            state["phase"], state["done"], state["total"] = "photons", done, max(total, 1)
            return not cancel.is_set()

        def phase(name, detail):
            state["phase"], state["detail"] = name, detail

        def work():
            try:
                pipeline.compute_bake(job, progress, phase, should_stop=cancel.is_set)
            except BaseException as e:  # noqa: BLE001  (handed to the UI thread)
                state["error"] = e
        self._thread = threading.Thread(target=work, name="photon-lightmaps-bake", daemon=True)
        self._thread.start()

    def _show(self, context):
        st = self._state
        lo, hi = self._SPAN.get(st["phase"], (0, 100))
        within = st["done"] / st["total"] if st["phase"] in ("unwrap", "photons") else 0.0
        context.window_manager.progress_update(lo + (hi - lo) * within)
        if self._cancel.is_set():
            return
        if st["phase"] == "unwrap":
            text = f"unwrapping {st['done']}/{st['total']} ({st['detail']})"
        elif st["phase"] == "photons":
            text = f"photon pass {100.0 * within:.0f}% ({st['done']:,}/{st['total']:,} photons)"
        else:
            label = {"scene": "compiling the scene", "kernels": "compiling kernels", "direct": "direct light",
                     "gather": "final gather", "ao": "ambient occlusion", "shadowmask": "shadowmask",
                     "validity": "texel validity", "seams": "stitching seams",
                     "images": "writing images",
                     "denoise": "denoising"}
            text = label.get(st["phase"], st["phase"]) + (f" ({st['detail']})" if st["detail"] else "")
        self._status(context, f"Photon Lightmaps: {text}  (Esc to cancel)")

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
        self._show(context)
        if self._thread.is_alive():
            return {"RUNNING_MODAL"}
        self._thread.join()
        error = self._state["error"]
        if self._cancel.is_set():
            error = Cancelled("cancelled with Esc")
        try:
            if error is not None:
                raise error
            if self._job is None:           # the unwraps are done: on to the bake
                self._start_compute(context)
                return {"RUNNING_MODAL"}
            self._cleanup(context)
            self._finish(self._job)
        except Exception as e:  # noqa: BLE001  (reported to the user instead of a traceback)
            self._cleanup(context)
            return self._failed(context, e, self._job)
        return {"FINISHED"}

    def cancel(self, context):
        # Blender ends the operator (e.g. the window closes): stop the worker too.
        if self._thread is not None:
            self._cancel.set()
            self._thread.join()
            if self._job is not None:
                pipeline.rollback_bake(self._job)
        self._cleanup(context)

    def draw(self, context):
        col = self.layout.column()
        for prop in ("selected_only", "photons", "resolution", "bake_pass", "indirect_only", "texel_validity",
                     "directional", "stitch_seams", "hook_materials", "overwrite", "pack"):
            col.prop(self, prop)
            if prop == "bake_pass" and self.bake_pass == "AO":
                col.prop(self, "ao_distance")
            if prop == "bake_pass" and self.bake_pass == "SHADOWMASK":
                col.prop(self, "shadowmask_lights")
            if prop == "bake_pass" and self.bake_pass in ("AO", "SHADOWMASK"):
                col.prop(self, "pass_rays")
        # Told before the bake starts: meshes without a Lightmap layer need xatlas first.
        n, triangles = _without_layer(_bake_candidates(context, self.selected_only))
        if n:
            col.label(text=f"{n} mesh{'es' if n != 1 else ''} without a Lightmap UV layer: xatlas unwraps "
                           f"{triangles:,} triangles first, about {_duration(pipeline.unwrap_seconds(triangles))}",
                      icon="INFO")


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


class PHOTON_LIGHTMAPS_OT_export_gltf(bpy.types.Operator):
    """Export the scene as glTF 2.0 with each object's baked lightmap (MOZ_lightmap, read by
    Mozilla Hubs and three.js-based viewers), through Blender's glTF exporter"""
    bl_idname = "photon_lightmaps.export_gltf"
    bl_label = "glTF with Photon Lightmaps (.glb)"
    bl_options = {"REGISTER"}

    filepath: StringProperty(subtype="FILE_PATH")
    filter_glob: StringProperty(default="*.glb;*.gltf", options={"HIDDEN"})
    encoding: EnumProperty(
        name="Lightmaps", default="RGBM",
        items=[("RGBM", "RGBM PNG", "8-bit RGBM images inside the file (decode: rgb * a * 8)"),
               ("EXR", "OpenEXR", "Float images beside the file, for engines that read OpenEXR")],
        description="How the lightmaps (E/pi, linear) are stored")

    def invoke(self, context, event):
        if not self.filepath:
            stem = bpy.path.display_name_from_filepath(bpy.data.filepath) or "scene"
            self.filepath = stem + ".glb"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        from ..bake import gltf_export
        try:
            out = gltf_export.export_gltf(context, self.filepath, encoding=self.encoding)
        except Exception as e:  # noqa: BLE001  (one line for the user, not a traceback)
            self.report({"ERROR"}, messages.bug_text(e))
            return {"CANCELLED"}
        n = len(out["objects"])
        extra = f"; without a baked lightmap: {', '.join(out['skipped'])}" if out["skipped"] else ""
        self.report({"INFO"}, f"Exported {out['path']} with {n} lightmap{'s' if n != 1 else ''}{extra}")
        return {"FINISHED"}


classes = (PHOTON_LIGHTMAPS_OT_bake, PHOTON_LIGHTMAPS_OT_remove_lightmap_hook, PHOTON_LIGHTMAPS_OT_export_gltf)
