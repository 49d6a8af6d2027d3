"""Light transport: the photon pass (`photon_tracer`), the camera pass (`renderer`),
the gathers that bake lightmaps (`texel_gather`, `bake_gather`, `csg_bake`,
`final_gather`, `irradiance_cache`), open texel areas and denoising. Imports every
package below it."""
