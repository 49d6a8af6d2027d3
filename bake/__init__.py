"""Baking photon lightmaps to image textures (and Blender's own Bake button).

One photon pass lights the whole scene; each baked mesh object's lightmap is
then written to a float RGBA image:

* RGB = E / pi, the irradiance E of the texel divided by pi: the radiance a
  white Lambertian surface would reflect there. This is what Cycles' Diffuse
  bake gives with Direct + Indirect and without Color.
  E = E_direct + E_indirect (thesis 3.5.2 / 8.2): photons are recorded only
  after their first bounce (indirect), and the direct part is gathered per
  texel by sampling the lights with shadow rays, averaged over the texel's
  surface (engine/transport/texel_gather.py), which takes the photon noise out of the
  brightest component. `indirect_only` skips the direct gather.
* A = the texel's UV coverage (0 where no UV triangle touches it). RGB next to
  the charts holds the lightmap's dilated values, so texture filtering at
  chart borders reads sensible colours.

Texel (x, y) of a lightmap is image pixel (x, y): both count rows bottom-up,
like UV v. Images are called "<object>_Lightmap" and use the mesh's
`Lightmap` UV layer (export/uv_layers.py makes one where missing).

Image policy. An image we made carries the custom property
``photon_lightmaps_object`` and is updated in place by the next bake. An
image of the same name that we did not make belongs to the user: with
``overwrite`` it is replaced (its users are remapped to the new image);
otherwise the bake writes a new image with a unique name (".001", ...) and
says so in `BakeResult.warnings`. Nothing is written until every lightmap
has been computed, so a cancelled or failed bake leaves all images as they
were; the Lightmap UV layers the export needs are made first and put back as
they were (rollback_bake) when the bake fails or is cancelled. The output
folder is checked before the first image is written. A user error (bad scene
data) is an engine SceneError naming the object, e.g. a NaN vertex.

Files. `save_dir` saves "<dir>/<object>.exr"; otherwise an image is saved to
"//lightmaps/<object>.exr" next to a saved .blend, or packed with `pack`.
OpenEXR, 32-bit float, ZIP, RGBA, alpha stored as is (images use the
"Channel Packed" alpha mode: coverage is data, not transparency).

Material hook (`hook_materials`): a node group "Photon Lightmap" is added to
each material of a baked object, with its own Material Output for EEVEE only,
so EEVEE and Material Preview show baked light while Cycles keeps rendering
the material as it was. Every node we add is named "Photon Lightmap ..." and
tagged; `remove_lightmap_hook` deletes exactly those nodes.

Exact primitives and CSG solids. A tagged Photon CSG primitive is baked from its
analytic charts: F faces give F tiles of R x R side by side, which is the layout
of its display mesh's generated `Lightmap` layer. A CSG solid (an object with
Boolean modifiers, exported as an exact CSG tree) gets ONE image,
"<base object>_Lightmap", in which the lightmap of every primitive leaf (F·R x R
texels) is a block of one atlas (engine/transport/csg_bake.py: shelf packing, square
texels, a 1-texel gutter repeating each block's border, alpha 0). A texel's
alpha is the visible fraction of its surface (0 where the CSG operation removed
all of it; RGB then holds the dilated neighbours). The direct light of leaf
texels is gathered over their visible part only, with the solid's outward
normal (inverted on subtracted operands). After the image is written, each
leaf's `Lightmap` layer is moved into its block, (U, V) -> (x0 + sx U, y0 + sy V),
and the rect is kept in the mesh property `export.uv_layers.TILE_PROP`; Blender's
Boolean result carries the operands' UVs over, so the image shows on the
evaluated mesh in EEVEE, and the hook goes into the base's materials and those
the result takes from its operands. Re-baking first maps the layer back with
the stored rect, so it never shrinks twice (an unchanged rect writes nothing);
a stand-alone primitive whose layer was moved gets the chart layout back.
A layer is only moved while it still *is* the generated layout (every vertex on
the chart point of its UV, export.uv_layers.primitive_chart_uvs): an operand whose layer
the user made or edited, a plain mesh operand, a mesh shared with other objects
or an operand used twice is left out of the solid's image with a warning naming
it, and its UVs are never touched. A Boolean whose operands are all plain
meshes is a polyhedron that Blender's Exact Boolean already gives exactly: it
is baked as that result mesh, with the operands' generated layers laid out as
one atlas (boolean_meshes.py). Operands passed as bake targets are skipped
(they are part of their solid's image).

Split texels. Where a CSG boundary cuts a texel into several visible regions,
the engine keeps one sub-texel per region (engine/geometry/csg.py). An image texel holds
one value, so it shows the region with the largest visible area (if that
region holds no measurement, the texel's own dilated value). This is not enough
where the other regions matter: thin slivers or slots narrower than a texel,
and walls meeting at a cut, show the dominant side's light on both sides
(light bleeds across the cut, e.g. a lit rim next to a dark groove). Bake at a
higher resolution (Object > Photon Lightmaps > resolution, or the scene's texel
density) until the features span several texels.

Modules: pipeline.py (BakeSettings; prepare -> compute -> commit), images.py
(image policy, the one save-or-pack), hooks.py (UV and OL material hooks),
csg_atlas.py, boolean_meshes.py, orientation.py (orientation lightmaps), bake_api.py (Blender's
Bake button), render.py (the render pipeline's Blender end), lsystem_preview.py (an
L-system object's viewport preview: the grammar -> its Geometry Nodes group and realized
mesh). The command `python -m photon_lightmaps bake` is in cli.py.
"""
from .hooks import HOOK_PREFIX, HOOK_PROP, add_lightmap_hook, remove_lightmap_hook  # noqa: F401,E402
from .images import IMAGE_SUFFIX, LIGHTMAP_DIR, OWNER_PROP, BakedMap, check_writable, write_exr  # noqa: F401,E402
from .pipeline import (BakeJob, BakeResult, BakeSettings, bake_objects, commit_bake, compute_bake,  # noqa: F401,E402
                       layout_resolution, prepare_bake, rollback_bake, run_unwraps, unwrap_plan,
                       unwrap_seconds)
from .bake_api import clear_cache  # noqa: F401,E402
from ..engine.core.errors import Cancelled  # noqa: F401,E402  (what a cancelled bake raises)
