"""Light transport: the photon pass (`photon_tracer`), the camera pass (`renderer`),
the gathers that bake lightmaps (`texel_gather`, `bake_gather`, `csg_bake`,
`final_gather`, `irradiance_cache`), open texel areas and denoising. The kernels
take the scene as one record (`kernel_scene`) and share what a path does at a
hit (`path_vertex`). Imports every package below it."""
