"""Settings stored in .blend files: `Scene.photon_lightmaps`, `Object.photon_lightmaps`
(with `Object.photon_lightmaps.lsystem` for L-system objects), `Material.photon_lightmaps`
`Light.photon_lightmaps` and `Camera.photon_lightmaps`.

The scene defaults are engine.session.Settings' (one copy), the L-system ones
export.lsystems.LSystemSettings': code reads the PropertyGroup into that typed
object, never into a dict of its own.
"""
import math

import bpy
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty,
                       StringProperty)

from ..engine.session import Settings
from ..engine.shading.dispersion import PRESETS
from ..engine.shading.fluorescence import PRESETS as FL
from ..export.lights import LIGHT_COLOUR, LIGHT_LINE
from ..export.lsystems import MAX_PREVIEW_DEPTH, LSystemSettings
from ..engine.shading import conductor
from ..export.materials import (CONDUCTOR_IDS, CONDUCTOR_NONE, DISPERSION_ABBE, DISPERSION_NONE, FLUORESCENCE_CUSTOM,
                                FLUORESCENCE_IDS, FLUORESCENCE_NONE, GLASS_IDS)

_D = Settings()
_L = LSystemSettings()


def _lsystem_changed(self, context):
    """A setting of an L-system object changed: regenerate its preview."""
    from ..bake.lsystem_preview import update_preview
    from ..export.lsystems import is_lsystem
    ob = self.id_data
    if isinstance(ob, bpy.types.Object) and is_lsystem(ob):
        update_preview(ob)


class PhotonLSystemSettings(bpy.types.PropertyGroup):
    """Per-object settings of an L-system object (Add > Photon L-System)."""
    use_render_iterations: BoolProperty(
        name="Override Iterations", default=_L.use_render_iterations, update=_lsystem_changed,
        description="Render this many derivation steps instead of the grammar's derivation length")
    render_iterations: IntProperty(
        name="Render Iterations", default=_L.render_iterations, min=0, soft_max=40,
        update=_lsystem_changed,
        description="Derivation steps a render traces (the engine expands them lazily, without "
                    "unrolling the instances)")
    preview_iterations: IntProperty(
        name="Preview Iterations", default=_L.preview_iterations, min=0, max=MAX_PREVIEW_DEPTH,
        update=_lsystem_changed,
        description=f"Derivation steps the viewport preview shows (at most {MAX_PREVIEW_DEPTH}: Blender "
                    "drops instances nested deeper; never more than the render depth)")
    use_seed: BoolProperty(
        name="Override Seed", default=_L.use_seed, update=_lsystem_changed,
        description="Use this seed instead of the grammar's for the stochastic choices")
    seed: IntProperty(
        name="Seed", default=_L.seed, min=0, update=_lsystem_changed,
        description="Seed of the stochastic choices (the same seed gives the same plant)")
    use_angle: BoolProperty(
        name="Override Angle", default=_L.use_angle, update=_lsystem_changed,
        description="Use this turtle angle instead of the grammar's")
    angle: FloatProperty(
        name="Angle", default=_L.angle, min=-360.0, max=360.0, update=_lsystem_changed,
        description="Turtle turn of + - & ^ \\ / without a parameter, in degrees")
    cache_mb: FloatProperty(
        name="Expansion Cache (MB)", default=_L.cache_mb, min=0.0, soft_max=4096.0,
        update=_lsystem_changed,
        description="Memory for subgraphs kept expanded (thesis 4.4): rays walk a small BVH there "
                    "instead of the graph's levels; 0 expands everything lazily per ray")
    organs: PointerProperty(
        name="Organs", type=bpy.types.Collection, update=_lsystem_changed,
        description="Where ~(name) finds its organ: the object of that name in this collection "
                    "(or a child collection of that name); without one, any object or collection "
                    "of that name")
    status: StringProperty(
        name="Status", default="",
        description="The last grammar error (line and column), empty when the grammar is fine")


class PhotonLightmapsSceneSettings(bpy.types.PropertyGroup):
    photons: IntProperty(
        name="Photons", default=_D.photons, min=0, soft_max=100_000_000,
        description="Photons shot from the lights in the photon pass")
    max_bounces: IntProperty(
        name="Max Bounces", default=_D.max_bounces, min=0, max=256,
        description="Longest photon path; energy still carried at the cap is booked as truncated")
    texel_density: FloatProperty(
        name="Texel Density", default=_D.texel_density, min=0.01, soft_max=1024.0, unit='NONE',
        description="Lightmap texels per metre for surfaces without a forced resolution")
    caustic_resolution: FloatProperty(
        name="Caustic Resolution", default=_D.caustic_resolution, min=1.0, soft_max=16.0,
        description="Renders keep photons that arrive only through sharp glass or mirrors in "
                    "lightmaps of their own, this many times finer, so caustics stay sharp")
    unwrap_limit: IntProperty(
        name="Unwrap Limit", default=_D.unwrap_limit, min=0, soft_max=1_000_000,
        description="Renders give meshes without a 'Lightmap' UV layer an xatlas unwrap up to this "
                    "many triangles (seconds for tens of thousands); larger ones get a fast "
                    "box-projection layout in seconds instead of waiting minutes. 0: always unwrap "
                    "with xatlas. Bakes always unwrap what they bake with xatlas")
    reconstruction: EnumProperty(
        name="Reconstruction", default=_D.reconstruction,
        items=(('BILINEAR', "Bilinear", "Interpolate irradiance between texel centres"),
               ('CONSTANT', "Constant", "One irradiance value per texel (shows the texels)")),
        description="How the renderer reads indirect light from the lightmaps")
    samples: IntProperty(
        name="Samples", default=_D.samples, min=1, soft_max=4096,
        description="Camera samples per pixel in the render pass")
    indirect: EnumProperty(
        name="Indirect Light", default=_D.indirect,
        items=(('GATHER', "Final Gather", "Gather rays read the lightmaps one bounce away: smooth, "
                                          "no texel pattern"),
               ('LOOKUP', "Lightmap", "Read the hit's own lightmap texel (the thesis's renderer and "
                                      "bake): fastest, shows photon noise and texels")),
        description="How renders and bakes compute indirect light at diffuse surfaces")
    gather_rays: IntProperty(
        name="Gather Rays", default=_D.gather_rays, min=1, soft_max=256,
        description="Final-gather rays per camera sample at the first diffuse hit")
    bake_photons: IntProperty(
        name="Bake Photons", default=_D.bake_photons, min=0, soft_max=100_000_000,
        description="Photons a gathered bake shoots. Its gather rays average the photon noise, "
                    "so more photons than this rarely lower its error (a Lookup bake shoots Photons)")
    bake_gather_rays: IntProperty(
        name="Bake Gather Rays", default=_D.bake_gather_rays, min=1, soft_max=4096,
        description="Final-gather rays per baked texel and lit side: its indirect noise falls "
                    "as one over the square root of this")
    bake_direct_samples: IntProperty(
        name="Bake Direct Samples", default=_D.bake_direct_samples, min=1, soft_max=4096,
        description="Light samples per baked texel for its direct light (one per stratified point): its "
                    "noise falls about as one over the square root of this")
    bake_target_error: FloatProperty(
        name="Bake Target Error", default=_D.bake_target_error, min=0.0, max=0.5, soft_max=0.1,
        subtype='FACTOR', precision=3,
        description="Adaptive bake gather: texels whose estimated relative error is above this "
                    "get more gather rays, up to Bake Max Rays (0: every texel gets Bake Gather Rays)")
    bake_irradiance_cache: BoolProperty(
        name="Bake Irradiance Cache", default=_D.bake_irradiance_cache,
        description="Bakes gather from a sparse set of points placed densest where light changes "
                    "(contact, corners), interpolated at every texel: several times fewer gather "
                    "rays and lower error than gathering at every texel, no seams")
    bake_gather_lights: BoolProperty(
        name="Bake Gather Lights", default=_D.bake_gather_lights,
        description="Bake gather rays sample point, spot and sun lights where they land, and the "
                    "photon lightmaps leave those lights' first hits out: a sun patch one bounce away "
                    "is as sharp as the sun, not as coarse as the texels it falls on (a shadow ray "
                    "per gather ray; area lights and the world stay in the lightmaps)")
    bake_keep_light: BoolProperty(
        name="Keep Bake Light", default=_D.bake_keep_light,
        description="Keep the last bake's photon pass in memory: baking other objects of the unchanged "
                    "scene reuses it instead of tracing it again (and reads the same light as their "
                    "neighbours' bake). Costs a copy of its lightmaps; the bake's report gives the size")
    irradiance_cache: BoolProperty(
        name="Render Irradiance Cache", default=_D.irradiance_cache,
        description="Renders gather from the same sparse, interpolated points instead of at every "
                    "camera hit (made once per photon pass and kept across the frames of a camera "
                    "animation): faster, but its error stops near a texel's scale")
    bake_max_rays: IntProperty(
        name="Bake Max Rays", default=_D.bake_max_rays, min=1, soft_max=65536,
        description="The most final-gather rays a texel and lit side can get with a target error")
    bake_time: FloatProperty(
        name="Bake Time", default=_D.bake_time, min=0.0, soft_max=3600.0, subtype='TIME_ABSOLUTE',
        unit='TIME_ABSOLUTE',
        description="Bake in about this many seconds: after one pass of Bake Gather Rays, the time "
                    "left goes to the texels with the highest estimated error (0: no time limit)")
    bake_error_images: BoolProperty(
        name="Bake Error Images", default=False,
        description="Gathered bakes also write each texel's estimated relative error to an "
                    "image \"<object>_LightmapError\" (and <object>_error.exr beside the lightmap)")
    denoise: BoolProperty(
        name="Denoise", default=_D.denoise,
        description="Run Intel Open Image Denoise (the pyoidn package) over renders, guided by "
                    "albedo and normal, and over baked lightmaps, chart by chart. Removes noise "
                    "at the cost of some bias")
    spectral: BoolProperty(
        name="Spectral", default=_D.spectral,
        description="Trace 16 wavelength bands over 380-780 nm instead of RGB; renders and bakes come "
                    "back as RGB. Colours become smooth spectra (Jakob & Hanika); glass disperses and "
                    "dyes fluoresce where their material asks")
    polarization: BoolProperty(
        name="Polarization", default=_D.polarization,
        description="Camera paths carry the light's polarization through smooth glass and clear coats "
                    "(Fresnel per component, not their mean): what chains of glass pass changes by a few "
                    "percent. The camera's polarizing filter traces it either way")
    seed: IntProperty(
        name="Seed", default=_D.seed, min=0,
        description="Random seed; the same seed gives the same image")
    cluster: StringProperty(
        name="Cluster", default=_D.cluster,
        description="Run photon passes, render tiles and bake gathers on a Dask cluster: its scheduler's "
                    "address (tcp://host:8786), or local:N for N worker processes on this machine; empty: "
                    "here. Images and lightmaps are the same, bit for bit (workers: python -m "
                    "photon_lightmaps worker)")


class PhotonLightmapsObjectSettings(bpy.types.PropertyGroup):
    exclude: BoolProperty(
        name="Exclude from Lightmaps", default=False,
        description="Give this object no lightmap: it still casts shadows and reflects light, "
                    "but records no photons and renders with direct light only")
    lightmap_resolution: IntProperty(
        name="Lightmap Resolution", default=0, min=0, soft_max=4096,
        description="Texels per side of each lightmap of this object; 0 uses the scene's texel density")
    # Orientation lightmap (thesis ch. 6), read on Empties only: an Empty is an OL
    # exactly when `orientation_lightmap` is set (export/ol_routing.is_orientation_lightmap), so
    # a stray pointer on some other object never turns it into one.
    orientation_lightmap: BoolProperty(
        name="Orientation Lightmap", default=False,
        description="This Empty is an orientation lightmap: the objects of its collection record "
                    "photons per surface normal here instead of on their own lightmaps")
    ol_collection: PointerProperty(
        name="Collection", type=bpy.types.Collection,
        description="Collection whose objects (child collections included) this orientation "
                    "lightmap covers; a child collection with its own one takes its objects")
    ol_resolution: IntProperty(
        name="Resolution", default=16, min=2, max=512,
        description="Octahedral direction bins per side (R x R bins over the sphere of normals); "
                    "nested orientation lightmaps use their outermost one's resolution")
    ol_samples: IntProperty(
        name="Area Samples", default=20000, min=1, soft_max=1_000_000,
        description="Sample points for the stochastic estimate of the surface area per bin")
    ol_min_hits: IntProperty(
        name="Min Hits", default=16, min=1, soft_max=10000,
        description="A bin with fewer photons than this reads the enclosing orientation lightmap "
                    "(or, as a backup, stands in for noisier texels)")
    ol_backup: BoolProperty(
        name="Backup", default=False,
        description="The objects keep their own lightmaps; this orientation lightmap is read only "
                    "where their texels received too few photons")
    lsystem: PointerProperty(type=PhotonLSystemSettings)


class PhotonLightmapsMaterialSettings(bpy.types.PropertyGroup):
    # Blender's shaders have no dispersion input: the engine's own, read by export/materials.py
    dispersion: EnumProperty(
        name="Dispersion", default=DISPERSION_NONE,
        items=[(DISPERSION_NONE, "None", "One index of refraction for every wavelength"),
               (DISPERSION_ABBE, "Abbe Number", "Spread the shader's IOR (taken as n_d, at 587.6 nm) over "
                                                "wavelengths by an Abbe number")]
              + [(key, name, f"{name} from the glass catalogue (Sellmeier): n_d {PRESETS[name].n_d}, "
                             f"Abbe number {PRESETS[name].abbe}; replaces the shader's IOR")
                 for key, name in GLASS_IDS.items()],
        description="How the index of refraction changes with wavelength: glass splits white light "
                    "into colours (rainbows through a prism). Traced in Spectral mode")
    abbe: FloatProperty(
        name="Abbe Number", default=40.0, min=1.0, soft_max=100.0,
        description="V_d = (n_d - 1) / (n_F - n_C): lower spreads the colours more "
                    "(crown glass about 60, flint glass about 30, diamond 55)")
    fluorescence: EnumProperty(
        name="Fluorescence", default=FLUORESCENCE_NONE,
        items=[(FLUORESCENCE_NONE, "None", "The surface only reflects"),
               (FLUORESCENCE_CUSTOM, "Custom", "Excitation and emission spectra set below")]
              + [(key, name.title(), f"{name}: absorbs around {FL[name].excitation_nm:.0f} nm, glows around "
                                     f"{FL[name].emission_nm:.0f} nm (quantum yield {FL[name].quantum_yield})")
                 for key, name in FLUORESCENCE_IDS.items()],
        description="Diffuse light the surface absorbs at short wavelengths comes back at longer ones "
                    "(a highlighter glowing under blue or UV light). Traced in Spectral mode")
    fl_strength: FloatProperty(
        name="Strength", default=1.0, min=0.0, max=1.0, subtype='FACTOR',
        description="Scales how much light the fluorescent dye absorbs at its excitation peak")
    fl_excitation_nm: FloatProperty(
        name="Excitation", default=450.0, min=300.0, max=800.0,
        description="Wavelength (nm) the dye absorbs most")
    fl_excitation_width: FloatProperty(
        name="Width", default=20.0, min=1.0, max=200.0,
        description="Standard deviation (nm) of the excitation spectrum")
    fl_emission_nm: FloatProperty(
        name="Emission", default=520.0, min=300.0, max=900.0,
        description="Wavelength (nm) the dye glows at most; only light at shorter wavelengths excites it")
    fl_emission_width: FloatProperty(
        name="Width", default=25.0, min=1.0, max=200.0,
        description="Standard deviation (nm) of the emission spectrum")
    fl_absorption: FloatProperty(
        name="Absorption", default=0.8, min=0.0, max=1.0, subtype='FACTOR',
        description="Fraction of the light at the excitation peak the dye absorbs")
    fl_quantum_yield: FloatProperty(
        name="Quantum Yield", default=0.9, min=0.0, max=1.0, subtype='FACTOR',
        description="Photons re-emitted per photon absorbed (the rest becomes heat)")
    conductor: EnumProperty(
        name="Conductor", default=CONDUCTOR_NONE,
        items=[(CONDUCTOR_NONE, "None", "The shader's own metal colour (Schlick's Fresnel)")]
              + [(key, conductor.NAMES[name], f"{conductor.NAMES[name]} ({name}) at its measured complex index")
                 for key, name in CONDUCTOR_IDS.items()],
        description="A measured metal: its complex index of refraction gives the metal's colour, how it "
                    "changes toward grazing angles, and what it does to polarized light. Replaces the "
                    "colour of the shader's metal, weighted by its Metallic")


class PhotonLightmapsLightSettings(bpy.types.PropertyGroup):
    spectrum: EnumProperty(
        name="Spectrum", default=LIGHT_COLOUR,
        items=[(LIGHT_COLOUR, "Colour", "The light's colour (or temperature) as a smooth spectrum"),
               (LIGHT_LINE, "Line", "A narrow band of wavelengths, as an LED, a UV lamp or a laser emits")],
        description="What the light emits in Spectral mode; RGB renders show a line as its colour")
    line_nm: FloatProperty(
        name="Wavelength", default=395.0, min=300.0, max=900.0,
        description="Centre of the line in nm (UV lamps: 365-405; the spectral bands cover 380-780)")
    line_width: FloatProperty(
        name="Width", default=15.0, min=0.1, max=200.0,
        description="Full width at half maximum of the line, nm (LEDs 10-30, lasers below 1)")
    use_polarizer: BoolProperty(
        name="Polarizer", default=False,
        description="A linear polarizer in front of the light: it passes half of the power, polarized "
                    "along its axis. Photons carry it through smooth glass, coats and metals")
    polarizer_angle: FloatProperty(
        name="Angle", default=0.0, subtype='ANGLE', soft_min=-math.pi, soft_max=math.pi,
        description="The polarizer's axis, from the light's local X axis toward its Y")


class PhotonLightmapsCameraSettings(bpy.types.PropertyGroup):
    use_polarizer: BoolProperty(
        name="Polarizing Filter", default=False,
        description="A linear polarizing filter in front of the lens: turned across the glare's plane it "
                    "takes reflections off water and glass, as in a photograph (it passes half of "
                    "unpolarized light). Traced through smooth glass and clear coats")
    polarizer_angle: FloatProperty(
        name="Angle", default=0.0, subtype='ANGLE', soft_min=-math.pi, soft_max=math.pi,
        description="The filter's axis, from the image's horizontal toward its vertical: light polarized "
                    "along it passes, across it is blocked (glare off a level surface is polarized "
                    "horizontally: 90° removes it)")


classes = (PhotonLightmapsSceneSettings, PhotonLSystemSettings, PhotonLightmapsObjectSettings,
           PhotonLightmapsMaterialSettings, PhotonLightmapsLightSettings, PhotonLightmapsCameraSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.photon_lightmaps = PointerProperty(type=PhotonLightmapsSceneSettings)
    bpy.types.Object.photon_lightmaps = PointerProperty(type=PhotonLightmapsObjectSettings)
    bpy.types.Material.photon_lightmaps = PointerProperty(type=PhotonLightmapsMaterialSettings)
    bpy.types.Light.photon_lightmaps = PointerProperty(type=PhotonLightmapsLightSettings)
    bpy.types.Camera.photon_lightmaps = PointerProperty(type=PhotonLightmapsCameraSettings)


def unregister():
    del bpy.types.Camera.photon_lightmaps
    del bpy.types.Light.photon_lightmaps
    del bpy.types.Material.photon_lightmaps
    del bpy.types.Object.photon_lightmaps
    del bpy.types.Scene.photon_lightmaps
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
