"""Settings stored in .blend files: `Scene.photon_lightmaps` and `Object.photon_lightmaps`.

The scene defaults are engine.session.Settings' (one copy): code reads the
PropertyGroup into that typed object, never into a dict of its own.
"""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

from ..engine.session import Settings

_D = Settings()


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
    reconstruction: EnumProperty(
        name="Reconstruction", default=_D.reconstruction,
        items=(('BILINEAR', "Bilinear", "Interpolate irradiance between texel centres"),
               ('CONSTANT', "Constant", "One irradiance value per texel (shows the texels)")),
        description="How the renderer reads indirect light from the lightmaps")
    samples: IntProperty(
        name="Samples", default=_D.samples, min=1, soft_max=4096,
        description="Camera samples per pixel in the render pass")
    seed: IntProperty(
        name="Seed", default=_D.seed, min=0,
        description="Random seed; the same seed gives the same image")


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


classes = (PhotonLightmapsSceneSettings, PhotonLightmapsObjectSettings)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Scene.photon_lightmaps = PointerProperty(type=PhotonLightmapsSceneSettings)
    bpy.types.Object.photon_lightmaps = PointerProperty(type=PhotonLightmapsObjectSettings)


def unregister():
    del bpy.types.Object.photon_lightmaps
    del bpy.types.Scene.photon_lightmaps
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
