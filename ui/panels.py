"""Properties-editor panels for the Photon Lightmaps engine.

Engine-generic built-in panels (dimensions, output, camera, ...) are reused
through COMPAT_ENGINES (ui/compat_panels.py); the panels here cover what
this engine reads that no generic panel shows: its settings, per-object
lightmap settings, and the material/light/world inputs the exporter uses.
"""
import bpy

from ..engine.shading.dispersion import PRESETS
from ..engine.shading.fluorescence import PRESETS as FL
from ..export.lights import LIGHT_LINE
from ..engine.shading import conductor
from ..export.materials import CONDUCTOR_IDS, CONDUCTOR_NONE, DISPERSION_ABBE, DISPERSION_NONE, \
    FLUORESCENCE_CUSTOM, FLUORESCENCE_IDS, FLUORESCENCE_NONE, GLASS_IDS
from ..operators.render_engine import ENGINE_ID


class _EnginePanel:
    bl_space_type = 'PROPERTIES'
    bl_region_type = 'WINDOW'
    needs = None        # a context member the panel shows (e.g. "light"); None: always

    @classmethod
    def poll(cls, context):
        return context.engine == ENGINE_ID and (cls.needs is None or getattr(context, cls.needs, None) is not None)


def _draw_surface(layout, owner, output_type, what_is_read, fallback):
    """The 'Surface' panel of a material or world: what the engine reads, then the
    shader at the active output (or the owner's plain colour without nodes)."""
    layout.use_property_split = True
    layout.label(text=f"Read: {what_is_read}", icon='INFO')
    if owner.node_tree is None or not _draw_output(layout, owner.node_tree, output_type, "Surface"):
        layout.prop(owner, fallback)


def _draw_output(layout, tree, output_type, input_name):
    """Draws the shader connected to the active output's input, as the node would show it."""
    outputs = [n for n in tree.nodes if n.bl_idname == output_type]
    if not outputs:
        return False
    node = next((n for n in outputs if n.is_active_output), outputs[0])
    layout.template_node_view(tree, node, node.inputs[input_name])
    return True


def _warmup_line(layout):
    """While kernels compile in the background (engine/warmup.py): how far it is."""
    from ..engine import warmup
    w = warmup.status()
    if w is None:
        return
    if w.error:
        layout.label(text="Kernel warm-up stopped; the first render compiles what it needs", icon="ERROR")
    elif not w.finished.is_set():
        layout.label(text=f"Preparing kernels, {w.fraction:.0%} ({w.current})", icon="TIME")


class PHOTON_LIGHTMAPS_PT_render(_EnginePanel, bpy.types.Panel):
    bl_label = "Photon Lightmaps"
    bl_context = "render"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        s = context.scene.photon_lightmaps
        _warmup_line(layout)
        col = layout.column(heading="Photon Pass")
        col.prop(s, "photons")
        col.prop(s, "max_bounces")
        col.prop(s, "seed")
        col.prop(s, "cluster")
        col = layout.column(heading="Lightmaps")
        col.prop(s, "texel_density")
        col.prop(s, "caustic_resolution")
        col.prop(s, "unwrap_limit")
        col.prop(s, "reconstruction")
        col = layout.column(heading="Render")
        col.prop(s, "samples")
        # Blender's own flag: keep the traced light after a render job, for the next
        # one (an animation keeps it between its frames either way)
        col.prop(context.scene.render, "use_persistent_data", text="Keep Light Between Renders")
        col = layout.column(heading="Renders and Bakes")
        col.prop(s, "bake_direct_samples")
        col.prop(s, "indirect")
        sub = col.column()
        sub.active = s.indirect == "GATHER"
        sub.prop(s, "gather_rays")
        sub.prop(s, "bake_photons")
        sub.prop(s, "bake_gather_rays")
        sub.prop(s, "bake_irradiance_cache")
        sub.prop(s, "bake_gather_lights")
        sub.prop(s, "irradiance_cache")
        sub.prop(s, "bake_target_error")
        row = sub.row()
        row.active = s.bake_target_error > 0.0 or s.bake_time > 0.0
        row.prop(s, "bake_max_rays")
        sub.prop(s, "bake_time")
        sub.prop(s, "bake_error_images")
        col.prop(s, "bake_keep_light")
        col.prop(s, "denoise")
        col.prop(s, "spectral")
        col.prop(s, "polarization")
        if s.denoise and not _denoiser_available():
            col.label(text="Denoise needs the pyoidn package (not installed)", icon='ERROR')
        _draw_last_run(layout, context.scene)


def _denoiser_available():
    # find_spec, not an import: panels redraw often, and loading OIDN's libraries is slow.
    import importlib.util
    return importlib.util.find_spec("pyoidn") is not None


# Lines the warnings box shows; the rest are in the Info editor and the JSON report.
MAX_WARNING_LINES = 5


def _draw_last_run(layout, scene):
    """Compact box: the last render's or bake's error and warnings (messages.LAST)."""
    from .. import messages
    rep = messages.last(scene.name)
    if rep is None or not (rep["error"] or rep["warnings"]):
        return
    box = layout.box()
    n = len(rep["warnings"])
    head = f"Last {rep['source']}: " + ("failed" if rep["error"] else "") + \
        (", " if rep["error"] and n else "") + (f"{n} warning{'s' if n != 1 else ''}" if n else "")
    box.label(text=head, icon='ERROR' if rep["error"] else 'INFO')
    col = box.column(align=True)
    if rep["error"]:
        col.label(text=rep["error"], icon='CANCEL')
    for w in rep["warnings"][:MAX_WARNING_LINES]:
        col.label(text=w, icon='DOT')
    if n > MAX_WARNING_LINES:
        col.label(text=f"... and {n - MAX_WARNING_LINES} more (Info editor)")


class PHOTON_LIGHTMAPS_PT_object(_EnginePanel, bpy.types.Panel):
    bl_label = "Photon Lightmap"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        ob = context.object
        return super().poll(context) and ob is not None and ob.type in {'MESH', 'CURVE', 'SURFACE', 'META', 'FONT', 'EMPTY'}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        ob = context.object
        s = ob.photon_lightmaps
        if ob.type == 'EMPTY' and s.orientation_lightmap:
            _draw_orientation_lightmap(layout, context, ob)
            return
        layout.prop(s, "exclude")
        sub = layout.column()
        sub.active = not s.exclude
        sub.prop(s, "lightmap_resolution", text="Resolution")
        if ob.type == 'MESH':
            has_uv = ob.data.uv_layers.get("Lightmap") is not None
            sub.label(text="UVs: 'Lightmap' layer" if has_uv else "UVs: automatic (no 'Lightmap' UV layer)",
                      icon='UV' if has_uv else 'INFO')
            _draw_csg(layout, ob)
            ols = _covering_ols(context, ob)
            if ols:
                sub.label(text=f"Stored in orientation lightmap {', '.join(ols)}", icon='SPHERE')


def _covering_ols(context, ob):
    """Names of the OL empties whose collection holds `ob` (the innermost one wins at export)."""
    scene = getattr(context, "scene", None)
    if scene is None:
        return []
    out = []
    for o in scene.objects:
        s = getattr(o, "photon_lightmaps", None)
        if o.type == 'EMPTY' and s is not None and s.orientation_lightmap and s.ol_collection is not None:
            if ob.name in s.ol_collection.all_objects:
                out.append(o.name)
    return out


def _draw_orientation_lightmap(layout, context, ob):
    """Settings of an OL empty and what the last render or bake measured (ol_bake.REPORTS)."""
    from ..bake import orientation as ol_bake
    s = ob.photon_lightmaps
    layout.prop(s, "orientation_lightmap")
    col = layout.column()
    col.prop(s, "ol_collection")
    col.prop(s, "ol_resolution")
    col.prop(s, "ol_samples")
    col.prop(s, "ol_min_hits")
    col.prop(s, "ol_backup")
    if s.ol_collection is None:
        layout.label(text="No collection: this orientation lightmap is ignored", icon='ERROR')
    scene = getattr(context, "scene", None)
    rep = ol_bake.last_report(scene.name, ob) if scene is not None else None
    box = layout.box()
    if rep is None:
        box.label(text="Not rendered or baked yet", icon='INFO')
        return
    box.label(text=f"Last {rep['source']}", icon='SPHERE')
    box.label(text=f"Bins {rep['bins']:,} ({rep['resolution']}x{rep['resolution']}), "
                   f"{rep['bins_with_area']:,} with surface")
    box.label(text=f"Photons received {rep['photons']:,} ({rep['instances']:,} objects)")
    box.label(text=f"Memory {rep['memory_bytes'] / 1024:.1f} KiB")
    err = rep.get('area_rel_error')
    box.label(text=f"Area {rep['area']:.4g} m²" + (f" ± {100 * err:.1f} %" if err is not None else ""))
    box.label(text=f"Openness {rep['openness']:.2f}")
    if rep.get('parent'):
        box.label(text=f"Inside '{rep['parent']}'")
    for w in rep.get('warnings', []):
        box.label(text=w, icon='ERROR')


def _draw_csg(layout, ob):
    """What the exporter makes of a CSG primitive or a Boolean stack (export/csg.py)."""
    from ..export import csg as csg_export
    box = None
    try:
        tag = csg_export.primitive_tag(ob)
    except ValueError as exc:
        layout.label(text=str(exc), icon='ERROR')
        tag = None
    if tag is not None:
        box = layout.box()
        kind, params = tag
        box.label(text=f"Exact {kind} (display mesh only)", icon='MESH_UVSPHERE')
        if kind == "torus":
            box.label(text=f"Minor radius {params[0]:.4g} (major radius 1)")
        dims = tuple(round(s, 4) for s in ob.scale)
        box.label(text=f"Scale {dims[0]:g}, {dims[1]:g}, {dims[2]:g} (primitive = object transform)")
    bools = csg_export.boolean_modifiers(ob)
    if bools:
        box = box or layout.box()
        box.label(text=f"Exact CSG from {len(bools)} Boolean modifier{'s' if len(bools) != 1 else ''}",
                  icon='MOD_BOOLEAN')


def _size(n):
    n = float(n)
    for unit in ("B", "KB", "MB", "GB", "TB"):
        if abs(n) < 1000.0 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0


def _count(n):
    n = float(n)
    return f"{n:,.0f}" if n < 1e15 else f"{n:.3g}"


def lsystem_summary(ob):
    """(text, icon) lines the L-system panel shows below the settings: the grammar's status,
    the preview path, OL stubs, organs and the engine's statistics (export/lsystems.py)."""
    from ..export import lsystems
    props = ob.photon_lightmaps.lsystem
    meta = lsystems.info(ob)
    lines = []
    if props.status:
        lines.append((props.status, 'ERROR'))
        lines.append(("The preview shows the last valid grammar", 'INFO'))
    path = meta.get("path")
    if path == "symbols":
        syms = meta.get("symbols", [])
        lines.append((f"Preview: Repeat Zone over {len(syms)} symbol{'s' if len(syms) != 1 else ''}, "
                      f"depth {meta.get('depth', 0)}", 'NODETREE'))
    elif path == "flattened":
        lines.append((f"Preview: flattened, depth {meta.get('depth', 0)}", 'MESH_DATA'))
        lines.append((meta.get("note", ""), 'DOT'))
    for a in meta.get("approximate", []):
        lines.append((f"Preview is approximate: {a}", 'INFO'))
    lines.append((f"Blender shows at most {lsystems.MAX_PREVIEW_DEPTH} nested instance levels: "
                  f"the preview depth is capped at {lsystems.MAX_PREVIEW_DEPTH}", 'INFO'))
    stubs = meta.get("ol_stubs", [])
    lines.append(("OL stubs: " + (", ".join(stubs) if stubs else "none (one OL over the object)"), 'SPHERE'))
    organs = meta.get("organs", [])
    if organs:
        resolve = _organ_lookup(ob)
        lines.append(("Organs: " + ", ".join(f"{n} -> {resolve(n)}" for n in organs), 'OUTLINER_OB_GROUP_INSTANCE'))
    st = meta.get("stats", {})
    if "error" in st:
        lines.append((f"Statistics: {st['error']}", 'ERROR'))
    elif st:
        approx = "" if st.get("exact", True) else " (expected)"
        lines.append((f"Implicit primitives: {_count(st['primitives'])}{approx} at {st.get('steps')} steps", 'MOD_PARTICLES'))
        if st.get("graph"):
            lines.append((f"DCSG nodes: {st['dcsg_nodes']:,}, graph memory {_size(st['graph_bytes'])}", 'OUTLINER'))
            if "cache_subgraphs" in st:
                lines.append((f"Expansion cache: {st['cache_subgraphs']:,} subgraphs, "
                              f"{_size(st['cache_bytes'])}, serves {100 * st['cache_hit_rate']:.1f} % "
                              "of primitive visits", 'MEMORY'))
        else:
            lines.append(("Context-sensitive: derived and instanced (no scene graph)", 'OUTLINER'))
        lines.append((f"Flattened instances would cost ~{_size(st['flat_bytes'])} in Cycles "
                      f"(~{lsystems.CYCLES_BYTES_PER_INSTANCE / 1000:.1f} KB per instance)", 'MEMORY'))
        steps = int(st.get("steps", -1))
        if steps > lsystems.MAX_PREVIEW_DEPTH:
            lines.append((f"Cycles shows at most {lsystems.MAX_PREVIEW_DEPTH} nested instance levels: these "
                          f"{steps} steps as nested instances would not show there", 'ERROR'))
    return lines


def _organ_lookup(ob):
    from ..export.lsystems import organ_resolver
    resolve = organ_resolver(ob)

    def name(n):
        t = resolve(n)
        if t is None:
            return "missing"
        return f"collection '{t.name}'" if isinstance(t, bpy.types.Collection) else f"'{t.name}'"
    return name


class PHOTON_LIGHTMAPS_PT_lsystem(_EnginePanel, bpy.types.Panel):
    bl_label = "Photon L-System"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        from ..export import lsystems
        return super().poll(context) and lsystems.is_lsystem(context.object)

    def draw(self, context):
        from ..export import lsystems
        from ..operators import lsystem as lsystem_ops
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        ob = context.object
        s = ob.photon_lightmaps.lsystem
        text = lsystems.grammar_text(ob)
        layout.prop(ob, f'["{lsystems.TEXT_PROP}"]', text="Grammar")
        row = layout.row(align=True)
        if text is None:
            row.label(text="No grammar Text", icon='ERROR')
        elif lsystem_ops.text_editor_area(context) is not None:
            row.operator(lsystem_ops.PHOTON_LIGHTMAPS_OT_lsystem_edit_text.bl_idname,
                         text=f"Edit '{text.name}'", icon='TEXT')
        else:
            row.label(text=f"Grammar: {text.name}", icon='TEXT')
        row.operator(lsystem_ops.PHOTON_LIGHTMAPS_OT_lsystem_update.bl_idname, text="", icon='FILE_REFRESH')
        col = layout.column()
        row = col.row(heading="Render Iterations")
        row.prop(s, "use_render_iterations", text="")
        sub = row.row()
        sub.active = s.use_render_iterations
        sub.prop(s, "render_iterations", text="")
        col.prop(s, "preview_iterations")
        row = col.row(heading="Angle")
        row.prop(s, "use_angle", text="")
        sub = row.row()
        sub.active = s.use_angle
        sub.prop(s, "angle", text="")
        row = col.row(heading="Seed")
        row.prop(s, "use_seed", text="")
        sub = row.row()
        sub.active = s.use_seed
        sub.prop(s, "seed", text="")
        col.prop(s, "organs")
        col.prop(s, "cache_mb")
        box = layout.box()
        for line, icon in lsystem_summary(ob):
            box.label(text=line, icon=icon)


class PHOTON_LIGHTMAPS_PT_material_slots(_EnginePanel, bpy.types.Panel):
    bl_label = ""
    bl_context = "material"
    bl_options = {'HIDE_HEADER'}

    @classmethod
    def poll(cls, context):
        return super().poll(context) and (context.material or context.object)

    def draw(self, context):
        layout = self.layout
        ob = context.object
        if ob:
            row = layout.row()
            row.template_list("MATERIAL_UL_matslots", "", ob, "material_slots", ob, "active_material_index",
                              rows=3)
            col = row.column(align=True)
            col.operator("object.material_slot_add", icon='ADD', text="")
            col.operator("object.material_slot_remove", icon='REMOVE', text="")
            layout.template_ID(ob, "active_material", new="material.new")
        elif context.material:
            layout.template_ID(context.space_data, "pin_id")


def _material_settings(layout, context):
    """(layout, the material's photon_lightmaps settings), property-split like Cycles' panels."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    return layout, context.material.photon_lightmaps


class _MaterialPanel(_EnginePanel):
    """A panel of the material tab, for a material that is not grease pencil."""
    bl_context = "material"

    @classmethod
    def poll(cls, context):
        mat = context.material
        return super().poll(context) and mat is not None and not mat.grease_pencil



class PHOTON_LIGHTMAPS_PT_material_surface(_MaterialPanel, bpy.types.Panel):
    bl_label = "Surface"

    def draw(self, context):
        _draw_surface(self.layout, context.material, "ShaderNodeOutputMaterial",
                      "Principled, Diffuse, Glossy, Metallic, Glass or Emission", "diffuse_color")


class PHOTON_LIGHTMAPS_PT_material_dispersion(_MaterialPanel, bpy.types.Panel):
    bl_label = "Dispersion"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout, s = _material_settings(self.layout, context)
        layout.prop(s, "dispersion")
        if s.dispersion == DISPERSION_ABBE:
            layout.prop(s, "abbe")
        elif s.dispersion in GLASS_IDS:
            g = PRESETS[GLASS_IDS[s.dispersion]]
            layout.label(text=f"IOR {g.n_d:.5f} at 587.6 nm, Abbe number {g.abbe}")
        if s.dispersion != DISPERSION_NONE and not context.scene.photon_lightmaps.spectral:
            layout.label(text="Seen with Spectral on (Render properties)", icon='INFO')


class PHOTON_LIGHTMAPS_PT_material_fluorescence(_MaterialPanel, bpy.types.Panel):
    bl_label = "Fluorescence"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout, s = _material_settings(self.layout, context)
        layout.prop(s, "fluorescence")
        if s.fluorescence == FLUORESCENCE_NONE:
            return
        layout.prop(s, "fl_strength")
        if s.fluorescence == FLUORESCENCE_CUSTOM:
            col = layout.column(align=True)
            col.prop(s, "fl_excitation_nm")
            col.prop(s, "fl_excitation_width")
            col = layout.column(align=True)
            col.prop(s, "fl_emission_nm")
            col.prop(s, "fl_emission_width")
            col = layout.column()
            col.prop(s, "fl_absorption")
            col.prop(s, "fl_quantum_yield")
        else:
            fl = FL[FLUORESCENCE_IDS[s.fluorescence]]
            layout.label(text=f"Absorbs {fl.excitation_nm:.0f} ± {fl.excitation_width:.0f} nm "
                              f"(peak {fl.peak:.2f}), glows {fl.emission_nm:.0f} ± {fl.emission_width:.0f} nm")
            layout.label(text=f"Quantum yield {fl.quantum_yield}")
        if not context.scene.photon_lightmaps.spectral:
            layout.label(text="Seen with Spectral on (Render properties)", icon='INFO')


class PHOTON_LIGHTMAPS_PT_material_conductor(_MaterialPanel, bpy.types.Panel):
    bl_label = "Conductor"
    bl_options = {'DEFAULT_CLOSED'}

    def draw(self, context):
        layout, s = _material_settings(self.layout, context)
        layout.prop(s, "conductor")
        if s.conductor == CONDUCTOR_NONE:
            return
        nk = conductor.rgb_index(CONDUCTOR_IDS[s.conductor])
        layout.label(text="n " + ", ".join(f"{v:.2f}" for v in nk[:, 0])
                          + "   k " + ", ".join(f"{v:.2f}" for v in nk[:, 1]) + " (R, G, B)")
        layout.label(text="Weighted by the shader's Metallic", icon='INFO')


class PHOTON_LIGHTMAPS_PT_light(_EnginePanel, bpy.types.Panel):
    bl_label = "Light"
    bl_context = "data"
    needs = "light"

    def draw(self, context):
        layout = self.layout
        light = context.light
        layout.row().prop(light, "type", expand=True)
        layout.use_property_split = True
        settings = light.photon_lightmaps
        layout.prop(settings, "spectrum")
        col = layout.column()
        if settings.spectrum == LIGHT_LINE:
            col.prop(settings, "line_nm")
            col.prop(settings, "line_width")
            if not context.scene.photon_lightmaps.spectral:
                col.label(text="RGB shows the line's colour; Spectral traces it", icon='INFO')
        else:
            row = col.row(heading="Temperature")
            row.prop(light, "use_temperature", text="")
            sub = row.row()
            sub.active = light.use_temperature
            sub.prop(light, "temperature", text="")
            col.prop(light, "color", text="Tint" if light.use_temperature else "Color")
        col = layout.column()
        col.prop(light, "energy", text="Strength" if light.type == 'SUN' else "Power")
        col.prop(light, "exposure")
        if light.type != 'SUN':
            col.prop(light, "normalize")
        col = layout.column()
        if light.type in {'POINT', 'SPOT'}:
            col.prop(light, "shadow_soft_size", text="Radius")
        elif light.type == 'SUN':
            col.prop(light, "angle")
        elif light.type == 'AREA':
            col.prop(light, "shape")
            sub = col.column(align=True)
            if light.shape in {'SQUARE', 'DISK'}:
                sub.prop(light, "size")
            else:
                sub.prop(light, "size", text="Size X")
                sub.prop(light, "size_y", text="Y")
        if light.type == 'SPOT':
            col = layout.column()
            col.prop(light, "spot_size", text="Angle")
            col.prop(light, "spot_blend", text="Blend", slider=True)
            col.prop(light, "show_cone")


def _draw_polarizer(layout, settings, note=None):
    """A light's or camera's polarizer: its angle, active when it is on."""
    layout.use_property_split = True
    layout.active = settings.use_polarizer
    layout.prop(settings, "polarizer_angle")
    if note:
        layout.label(text=note, icon='INFO')


class PHOTON_LIGHTMAPS_PT_light_polarizer(_EnginePanel, bpy.types.Panel):
    bl_label = "Polarizer"
    bl_context = "data"
    bl_parent_id = "PHOTON_LIGHTMAPS_PT_light"
    needs = "light"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.light.photon_lightmaps, "use_polarizer", text="")

    def draw(self, context):
        _draw_polarizer(self.layout, context.light.photon_lightmaps, "Passes half of the power")


class PHOTON_LIGHTMAPS_PT_camera_polarizer(_EnginePanel, bpy.types.Panel):
    bl_label = "Polarizing Filter"
    bl_context = "data"
    needs = "camera"
    bl_options = {'DEFAULT_CLOSED'}

    def draw_header(self, context):
        self.layout.prop(context.camera.photon_lightmaps, "use_polarizer", text="")

    def draw(self, context):
        _draw_polarizer(self.layout, context.camera.photon_lightmaps)


class PHOTON_LIGHTMAPS_PT_world(_EnginePanel, bpy.types.Panel):
    bl_label = "Surface"
    bl_context = "world"
    needs = "world"

    def draw(self, context):
        _draw_surface(self.layout, context.world, "ShaderNodeOutputWorld",
                      "a constant Background colour x strength", "color")


classes = (
    PHOTON_LIGHTMAPS_PT_render,
    PHOTON_LIGHTMAPS_PT_object,
    PHOTON_LIGHTMAPS_PT_lsystem,
    PHOTON_LIGHTMAPS_PT_material_slots,
    PHOTON_LIGHTMAPS_PT_material_surface,
    PHOTON_LIGHTMAPS_PT_material_dispersion,
    PHOTON_LIGHTMAPS_PT_material_fluorescence,
    PHOTON_LIGHTMAPS_PT_material_conductor,
    PHOTON_LIGHTMAPS_PT_light,
    PHOTON_LIGHTMAPS_PT_light_polarizer,
    PHOTON_LIGHTMAPS_PT_camera_polarizer,
    PHOTON_LIGHTMAPS_PT_world,
)
