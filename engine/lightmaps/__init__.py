"""Where light is stored: lightmaps and their exact texel areas, CSG split texels,
lightmap UVs (xatlas in a watched child process, or the fast layout), orientation
lightmaps and their stochastic area estimation. Imports engine.core and
engine.geometry."""
