"""Baked lightmaps out to glTF (bake/gltf_export.py, CLI export-gltf): the file reads back
through Blender's own glTF importer, every lightmapped object's materials name its
lightmap (MOZ_lightmap) and Lightmap UV layer, and the RGBM images decode to the baked
values within the encoding's step."""
import json
import os

import numpy as np
import pytest

import bpy  # noqa: F401  (a missing bpy fails the suite, it is in requirements.txt)

from photon_lightmaps import demo_blend
from photon_lightmaps.bake import gltf_export
from photon_lightmaps.registration import ensure_registered

from test_cli_commands import run


def test_rgbm_round_trip_is_within_one_step():
    """Decoded RGBM is within half a step of the multiplier's range per channel; values
    above the range clip to it."""
    rng = np.random.default_rng(1)
    rgb = np.concatenate([rng.random((1000, 3)) * 10 ** rng.uniform(-3, 0.9, (1000, 1)), [[9.0, 1.0, 0.0]]])
    enc = gltf_export.rgbm_encode(rgb)
    dec = gltf_export.rgbm_decode(enc)
    m = enc[:, 3:4] / 255.0
    assert np.all(np.abs(dec - np.minimum(rgb, 8.0)) <= 0.5 / 255.0 * m * 8.0 + 1e-12)
    assert dec[-1, 0] == pytest.approx(8.0)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """The room baked here, then export-gltf from the CLI on its saved .blend (its images packed)."""
    from photon_lightmaps import bake
    tmp = tmp_path_factory.mktemp("gltf")
    ensure_registered()
    blend = tmp / "room.blend"
    demo_blend.build_cornell_blend(str(blend), width=24, height=16, spheres=True)
    objects = [ob for ob in bpy.context.scene.objects if ob.type == "MESH"]
    res = bake.bake_objects(bpy.context, objects, photons=20_000, seed=1, resolution=16, pack=True)
    baked = {name: np.array(bpy.data.images[img].pixels[:], np.float64) for name, img in res.images.items()}
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp / "room.glb"
    run("export-gltf", blend, out, "--json", tmp / "g.json")
    return tmp, out, json.loads((tmp / "g.json").read_text()), baked


def test_export_gltf_writes_moz_lightmap_that_blender_reads_back(exported):
    tmp, out, report, baked = exported
    gltf, blob = gltf_export.read_glb(out)
    assert gltf_export.EXTENSION in gltf["extensionsUsed"]
    assert set(report["objects"]) == set(baked) and report["skipped"] == [] and report["baked"] is None
    by_name = {n["name"]: n for n in gltf["nodes"]}
    for name, row in report["objects"].items():
        mesh = gltf["meshes"][by_name[name]["mesh"]]
        for prim in mesh["primitives"]:
            ext = gltf["materials"][prim["material"]]["extensions"][gltf_export.EXTENSION]
            assert ext["texCoord"] == row["texcoord"] and f"TEXCOORD_{ext['texCoord']}" in prim["attributes"]
            image = gltf["images"][gltf["textures"][ext["index"]]["source"]]
            view = gltf["bufferViews"][image["bufferView"]]
            assert image["mimeType"] == "image/png" and view["byteOffset"] + view["byteLength"] <= len(blob)
    # Blender's own importer reads the file: every object, with its materials
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert bpy.ops.import_scene.gltf(filepath=str(out)) == {"FINISHED"}
    names = {ob.name for ob in bpy.data.objects if ob.type == "MESH"}
    assert set(report["objects"]) <= names


def embedded_png(gltf, blob, texture, file):
    """Texture `texture`'s embedded PNG, read by Blender (rows bottom-up, as baked
    images hold them) -> its bytes (h, w, 4) as float64 0..255."""
    image = gltf["images"][gltf["textures"][texture]["source"]]
    view = gltf["bufferViews"][image["bufferView"]]
    file.write_bytes(blob[view["byteOffset"]:view["byteOffset"] + view["byteLength"]])
    img = bpy.data.images.load(str(file))
    img.colorspace_settings.name = "Non-Color"
    w, h = img.size
    q = np.round(np.array(img.pixels[:], np.float64).reshape(h, w, 4) * 255.0)
    bpy.data.images.remove(img)
    return q


def test_rgbm_images_decode_to_the_baked_values(exported):
    """Each object's embedded PNG, decoded, against its baked image, per texel within
    the RGBM step (Blender reads the PNG rows bottom-up, as the baked image holds them)."""
    tmp, out, report, baked = exported
    gltf, blob = gltf_export.read_glb(out)
    for name, row in report["objects"].items():
        q = embedded_png(gltf, blob, row["texture"], tmp / f"{name}.png")
        dec = gltf_export.rgbm_decode(q)
        ref = baked[name].reshape(q.shape)[..., :3]
        step = q[..., 3:4] / 255.0 * gltf_export.RGBM_RANGE / 255.0
        assert np.all(np.abs(dec - np.minimum(ref, gltf_export.RGBM_RANGE)) <= 0.5 * step + 1e-6), name
        assert ref.max() > 0.0


def test_cli_bakes_then_exports_exr_beside_the_file(tmp_path):
    """export-gltf --bake --encoding exr: every mesh baked, each lightmap an OpenEXR file
    beside the .glb that its image's uri names."""
    ensure_registered()
    blend = tmp_path / "room.blend"
    demo_blend.build_cornell_blend(str(blend), width=24, height=16)
    out = tmp_path / "room.glb"
    run("export-gltf", blend, out, "--bake", "--photons", "20000", "--resolution", "8", "--encoding", "exr",
        "--json", tmp_path / "g.json")
    report = json.loads((tmp_path / "g.json").read_text())
    gltf, _ = gltf_export.read_glb(out)
    assert report["baked"] and set(report["objects"]) == set(report["baked"])
    for name, row in report["objects"].items():
        image = gltf["images"][gltf["textures"][row["texture"]]["source"]]
        assert os.path.isfile(tmp_path / image["uri"]) and row["encoding"] == "EXR", name


def test_file_export_operator(tmp_path):
    """File > Export > glTF with Photon Lightmaps: one clear error before anything is
    baked, then the file with the baked object's lightmap; the menu entry is there."""
    from photon_lightmaps import bake
    ensure_registered()
    demo_blend.build_cornell_blend(width=24, height=16)
    out = tmp_path / "op.glb"
    with pytest.raises(RuntimeError, match="no baked lightmaps to export"):
        bpy.ops.photon_lightmaps.export_gltf(filepath=str(out))
    floor = bpy.data.objects["floor"]
    bake.bake_objects(bpy.context, [floor], photons=20_000, resolution=8, pack=True)
    assert bpy.ops.photon_lightmaps.export_gltf(filepath=str(out)) == {"FINISHED"}
    gltf, _ = gltf_export.read_glb(out)
    lit = [m for m in gltf["materials"] if gltf_export.EXTENSION in m.get("extensions", {})]
    assert len(lit) == 1 and lit[0]["name"].endswith("_floor")
    from photon_lightmaps.ui import menus
    assert any(fn is menus.export_menu for fn in bpy.types.TOPBAR_MT_file_export._dyn_ui_initialize())


@pytest.mark.parametrize("mode", ["DOMINANT", "SH"])
def test_directional_maps_go_along_in_the_materials_extras(tmp_path, mode):
    """A directional bake's images are textures that the object's materials name in
    their extras, on the lightmap's TEXCOORD; the PNGs decode to the baked values
    within their 8-bit step (the direction: 1/255; L1: 2/255 of the decoded lightmap)."""
    from photon_lightmaps import bake
    from test_directional import normal_mapped_plane
    ensure_registered()
    _, ob = normal_mapped_plane()
    res = bake.bake_objects(bpy.context, [ob], resolution=16, seed=1, directional=mode, pack=True)
    report = gltf_export.export_gltf(bpy.context, str(tmp_path / "plane.glb"))
    gltf, blob = gltf_export.read_glb(tmp_path / "plane.glb")
    row = report["objects"]["plane"]
    mat = gltf["materials"][gltf["meshes"][[n for n in gltf["nodes"] if n["name"] == "plane"][0]["mesh"]]
                            ["primitives"][0]["material"]]
    extra = mat["extras"]["photon_lightmaps"]["directional"]
    assert extra == row["directional"] and extra["mode"] == mode.lower()

    def png(texture, name):
        return embedded_png(gltf, blob, texture, tmp_path / f"{name}.png")

    E = gltf_export.rgbm_decode(png(row["texture"], "lightmap"))
    if mode == "DOMINANT":
        assert extra["direction"]["texCoord"] == row["texcoord"]
        got = gltf_export.signed_decode(png(extra["direction"]["index"], "direction"))
        want = res.direction_maps["plane"].rgba[..., :3]
        assert np.abs(got - want).max() <= 1.0 / 255.0 + 1e-6
        assert np.abs(want).max() > 0.5
    else:
        for a, tex in zip("xyz", extra["l1"]):
            assert tex["texCoord"] == row["texcoord"]
            got = gltf_export.signed_decode(png(tex["index"], "l1" + a), E)
            want = res.l1_maps[a]["plane"].rgba[..., :3]
            step = 2.0 / 255.0 * E + np.abs(want) * 0.01
            assert np.all(np.abs(got - want) <= step + 1e-6), a
        assert max(np.abs(res.l1_maps[a]["plane"].rgba[..., :3]).max() for a in "xyz") > 0.01
