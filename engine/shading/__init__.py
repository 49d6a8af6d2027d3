"""What surfaces and lights do: materials, BSDFs, textures, lights, photon aiming and
the environment. Imports engine.core, engine.geometry and engine.lightmaps."""
