"""Blender -> engine.core.scene.Scene: reads an *evaluated* depsgraph into plain data (rank 1, over engine/).

Everything the tracer sees passes through `export_scene`, so Blender's
conventions are converted here, once:

* geometry: every visible mesh in `depsgraph.object_instances` (real objects,
  collection/particle/geometry-nodes instances, and the meshes Blender
  evaluates curves, text and metaballs into). Instances share one prototype
  per evaluated mesh datablock (and material assignment), so 100 linked
  duplicates cost one prototype and 100 transforms.
* lightmap UVs: the mesh UV layer named "Lightmap", when present and inside
  [0,1]², otherwise none (the core unwraps with xatlas).
* materials: the Principled BSDF (plus Diffuse, Glossy, Metallic, Glass and Emission
  shaders) mapped to diffuse/specular/transmission/emission weights.
* lights, camera and a constant world in Cycles' units (see engine/shading/lights.py).
* exact CSG (csg.py): an object with enabled Boolean modifiers becomes a
  prototype holding one CSG tree built from the *original* objects (tagged
  CSG primitives stay exact analytic surfaces), not Blender's tessellated
  Boolean result; a tagged CSG primitive without Booleans becomes a Primitive.
  Boolean operands are part of the solid they cut and are never exported as
  standalone geometry (ExportMap.csg_operands). Trees that cannot be exact
  (open operand meshes, other modifiers in the stack) fall back to the
  evaluated mesh, with a warning.

Per-object settings (`Object.photon_lightmaps`): `exclude` keeps the object in
the scene (it still casts shadows and reflects light) but gives it no lightmap,
so it records no photons and renders with direct light only; this is the
useful meaning for "leave this out of the bake" and never changes how other
surfaces are lit. `lightmap_resolution` > 0 forces R x R texels per surface.

Orientation lightmaps (thesis ch. 6): an Empty with `orientation_lightmap` set
is an OL attached to the collection `ol_collection` (never geometry). Each
exported instance goes to the innermost OL collection holding it (child
collections included; collection-instance and particle duplis follow their
instancer object); OLs nest as their collections do (fig. 6.3). See ol_routing.py.

Anything the exporter has to approximate is reported once per datablock
through `report(level, message)` and collected in `ExportMap.warnings`.
Modules, one per concept: scene.py (the driver), context.py (records, shared
state), materials.py (converter registry keyed by shader node type), meshes.py
and uv_layers.py, csg.py, lights.py, camera.py, world.py, ol_routing.py.
"""
from .context import DEFAULT_DIFFUSE, LIGHTMAP_UV, ExportMap, InstanceRecord, PrototypeRecord  # noqa: F401
from .ol_routing import OLRouter, is_orientation_lightmap  # noqa: F401
from .scene import export_scene  # noqa: F401
