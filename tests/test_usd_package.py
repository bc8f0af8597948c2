"""``usdbtf package`` / ``inspect`` and reading assets back.

Real stages, real textures through OIIO, every UsdValidation validator, bit-exact
round trips from the asset (and from a stage that references it), and bad input.
"""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import usdbtf  # noqa: F401  (registers the schema plugin first)
from pxr import Sdf, Usd, UsdGeom, UsdShade

from cli_helpers import bad_input, bad_usage, ok, refused, run
from usdbtf import color
from usdbtf.cli import main
from usdbtf.compress import read_compressed, reconstruct
from usdbtf.compress.metrics import ErrorSums
from usdbtf.imageio import read_image
from usdbtf.model import ArrayBTF
from usdbtf.sampling import preset, to_vectors
from usdbtf.usd.asset import fallback, thumbnail
from usdbtf.usd.asset import package as pkg
from usdbtf.usd.read import load_btf, sample_image
from usdbtf.usd.asset.validate import validate_layer, validation_issues

OIIOTOOL = Path(__import__("sys").executable).parent / "oiiotool"


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("usdpkg")


@pytest.fixture(scope="module")
def src(work, synth_capture) -> Path:
    return synth_capture("pebbles", "small", 32, out=work / "src")


@pytest.fixture(scope="module", params=["jxlp", "jxl", "exr", "jpeg"])
def compressed(request, src, work) -> Path:
    out = work / f"c_{request.param}"
    solver = ["--solver", "paper"] if request.param == "jpeg" else []
    assert main(["compress", str(src), "-o", str(out), "--k", "12", "--codec", request.param, "-q"] + solver) == 0
    return out


@pytest.fixture(scope="module")
def asset(compressed, work) -> Path:
    out = work / f"asset_{compressed.name}" / "pebbles.usda"
    assert main(["package", str(compressed), "-o", str(out), "--usdz", "-q"]) == 0
    return out


def _layers(root: Path) -> list[Path]:
    return [root, root.with_name(root.stem + "_payload.usdc"), root.with_suffix(".usdz")]


# ------------------------------------------------------------------ validity
def test_every_validator_passes_on_every_layer(asset):
    from pxr import UsdValidation

    assert len(UsdValidation.ValidationRegistry().GetOrLoadAllValidators()) >= 25
    for layer in _layers(asset):
        assert layer.is_file()
        assert validate_layer(layer) == [], layer          # every lod selection


def test_validation_catches_a_broken_asset(asset, tmp_path):
    """The control: the same validators do report errors (here: no metersPerUnit, no
    upAxis, an unresolvable texture)."""
    bad = tmp_path / "bad.usda"
    stage = Usd.Stage.CreateNew(str(bad))
    stage.SetDefaultPrim(stage.DefinePrim("/A", "Xform"))
    tex = UsdShade.Shader.Define(stage, "/A/T")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("./missing.png")
    stage.Save()
    issues = "\n".join(validation_issues(bad))
    assert "StageMetadataChecker" in issues and "missing.png" in issues


def asset_values(asset: Path) -> list:
    """(attribute, Sdf.AssetPath) of every asset-valued attribute value on the composed stage."""
    stage = Usd.Stage.Open(str(asset))
    found = []
    for prim in stage.Traverse():
        for attr in prim.GetAuthoredAttributes():
            values = attr.Get()
            if attr.GetTypeName() == Sdf.ValueTypeNames.Asset:
                values = [values]
            elif attr.GetTypeName() != Sdf.ValueTypeNames.AssetArray:
                continue
            found += [(attr, a) for a in values or []]
    return found


def test_textures_open_in_oiiotool_and_paths_are_relative_and_resolve(asset):
    checked = 0
    for attr, a in asset_values(asset):
        assert a.path.startswith("./"), (attr.GetPath(), a.path)
        assert a.resolvedPath and Path(a.resolvedPath).is_file(), a.path
        assert Path(a.resolvedPath).suffix in (".png", ".exr", ".jpg")
        info = subprocess.run([str(OIIOTOOL), "--info", a.resolvedPath], capture_output=True, text=True)
        assert info.returncode == 0 and "x" in info.stdout, info.stderr
        checked += 1
    assert checked >= 1 + 1 + 4    # GPU tables (the basis), coefficient pages, fallback maps


def test_asset_structure(asset):
    layer = Sdf.Layer.FindOrOpen(str(asset))
    stage = Usd.Stage.Open(str(asset))
    root = stage.GetDefaultPrim()
    assert root.GetName() == "pebbles" and Usd.ModelAPI(root).GetKind() == "component"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Y"
    assert root.HasAuthoredPayloads() and list(layer.GetPrimAtPath("/pebbles").variantSets.keys()) == ["lod"]
    assert Sdf.Layer.FindOrOpen(str(asset.with_name("pebbles_payload.usdc"))).GetFileFormat().formatId == "usdc"
    assert not layer.GetPrimAtPath("/pebbles/geo")            # heavy data only behind the payload
    assert stage.GetPrimAtPath("/pebbles/geo").IsA(UsdGeom.Scope)
    material = stage.GetPrimAtPath("/pebbles/mtl/BtfMaterial")
    assert material.HasAPI("BtfMaterialAPI")
    assert Usd.ColorSpaceAPI(material).GetColorSpaceNameAttr().Get() == "lin_ap1_scene"
    swatch = UsdGeom.Mesh(stage.GetPrimAtPath("/pebbles/geo/swatch"))
    bound, _ = UsdShade.MaterialBindingAPI(swatch.GetPrim()).ComputeBoundMaterial()
    assert bound.GetPath() == material.GetPath()
    ext = np.asarray(swatch.GetExtentAttr().Get())
    np.testing.assert_allclose(ext[1] - ext[0], [0.05, 0.05, 0])         # physical size of the tile
    surface = UsdShade.Material(material).ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface" and surface.GetInput("useSpecularWorkflow").Get() == 1
    for name, node in (("diffuseColor", "DiffuseTexture"), ("specularColor", "SpecularTexture"),
                       ("roughness", "RoughnessTexture"), ("normal", "NormalTexture")):
        source = surface.GetInput(name).GetConnectedSources()[0][0].source.GetPrim()
        assert source.GetName() == node and UsdShade.Shader(source).GetIdAttr().Get() == "UsdUVTexture", name
    # Unloaded, the lod variant can still be chosen and the bounds are known (both outside the payload).
    unloaded = Usd.Stage.Open(str(asset), Usd.Stage.LoadNone)
    prim = unloaded.GetDefaultPrim()
    assert prim.GetVariantSets().GetVariantSet("lod").GetVariantNames() == ["full", "k6"]
    hint = np.asarray(UsdGeom.ModelAPI(prim).GetExtentsHint())
    np.testing.assert_allclose(hint, [[-0.025, -0.025, 0], [0.025, 0.025, 0]], atol=1e-7)
    bbox = UsdGeom.BBoxCache(Usd.TimeCode.Default(), ["default"], useExtentsHint=True).ComputeWorldBound(prim)
    np.testing.assert_allclose(np.asarray(bbox.ComputeAlignedRange().GetSize()), [0.05, 0.05, 0], atol=1e-7)


def test_asset_info_thumbnail_and_provenance(compressed, tmp_path, capsys):
    from pxr import UsdMedia

    out = tmp_path / "nested" / "deeper" / "rock.usdc"
    ok(capsys, "package", compressed, "-o", out, "--asset-name", "Rock", "--asset-version", "3.1",
       "--creator", "lookdev team", "--payload-format", "usda", "-q")
    assert Sdf.Layer.FindOrOpen(str(out)).GetFileFormat().formatId == "usdc"
    assert out.with_name("rock_payload.usda").is_file()
    stage = Usd.Stage.Open(str(out))
    root = stage.GetDefaultPrim()
    info = Usd.ModelAPI(root)
    assert (info.GetAssetName(), info.GetAssetVersion(), root.GetAssetInfoByKey("creator")) == \
        ("Rock", "3.1", "lookdev team")
    assert stage.GetRootLayer().customLayerData["creator"] == "lookdev team"
    thumbs = UsdMedia.AssetPreviewsAPI(root).GetDefaultThumbnails()
    thumb = Path(thumbs.defaultImage.resolvedPath)
    pixels, info = read_image(thumb)
    # A 256² JPEG (issue 39: a third of the RGBA PNG's bytes), its sRGB encoding declared (EXIF
    # ColorSpace, read back by OIIO), the render over the grey background where nothing was hit.
    assert thumb.name == "thumbnail.jpg" and thumb.read_bytes()[:3] == b"\xff\xd8\xff"
    assert thumb.parent.name == "rock_textures" and pixels.shape == (256, 256, 3) and info.channels == 3
    assert info.color_space == "srgb_rec709_scene"
    assert np.abs(pixels[:4, :4].astype(int) - thumbnail.BACKGROUND).max() <= 3    # a corner: background
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 50           # a render, not a flat colour
    assert thumb.stat().st_size < 30_000
    material = stage.GetPrimAtPath("/rock/mtl/BtfMaterial")
    source = material.GetAttribute("btf:provenance:source").Get()
    assert not Path(source).is_absolute() and source.startswith("../")
    assert (out.parent / source).resolve() == Path(read_compressed(compressed).info["provenance"]["source"]).resolve()
    # Nothing absolute anywhere in the layers.
    for layer in stage.GetUsedLayers():
        assert str(tmp_path) not in layer.ExportToString(), layer.identifier
    # Without --asset-version there is no version (not the tool's).
    plain = tmp_path / "plain" / "rock.usda"
    ok(capsys, "package", compressed, "-o", plain, "--no-thumbnail", "-q")
    plain_stage = Usd.Stage.Open(str(plain))
    plain_root = plain_stage.GetDefaultPrim()
    assert Usd.ModelAPI(plain_root).GetAssetVersion() == "" and not plain_root.HasAPI("AssetPreviewsAPI")


def test_data_is_raw_and_color_is_declared(asset):
    from pxr import UsdShade as S

    stage = Usd.Stage.Open(str(asset))
    cache = Usd.ColorSpaceHashCache()
    space = lambda attr: Usd.ColorSpaceAPI.ComputeColorSpaceName(attr, cache)  # noqa: E731
    material = stage.GetPrimAtPath("/pebbles/mtl/BtfMaterial")
    for name in ("basis", "coefficients", "basisScale", "coefficientScale", "coefficientBias", "colorMatrix",
                 "viewDirections"):
        assert space(material.GetAttribute(f"btf:{name}")) == "raw", name
    full = list(material.GetAttribute("btf:coefficients").Get())
    select = Usd.Stage.Open(Sdf.Layer.OpenAsAnonymous(str(asset)))       # the lod chosen off the shared layer
    select.GetDefaultPrim().GetVariantSets().SetSelection("lod", "k6")
    coeffs = select.GetPrimAtPath("/pebbles/mtl/BtfMaterial").GetAttribute("btf:coefficients")
    # The lod lists the pages its 6 vectors are on, a prefix of the full list's pages, then
    # (schema 4, integer basis codes) its own basis page where the full list has the full one.
    own = [a.path for a in coeffs.Get()]
    in_page = full[-1].path.endswith("gpu/basis.png")
    assert in_page == (asset.parent.name != "asset_c_exr")     # half codes (exr codec) stay in the tables
    pages = own[:-1] if in_page else own
    assert pages == [a.path for a in full[:len(pages)]]
    assert not in_page or own[-1].endswith("gpu/basis_k6.png")
    assert 1 <= len(pages) < len(full) and space(coeffs) == "raw"  # the lod override too
    files = {}
    for prim in stage.Traverse():
        shader = S.Shader(prim)
        if shader and shader.GetIdAttr().Get() == "UsdUVTexture":
            files[prim.GetName()] = (space(shader.GetInput("file").GetAttr()), shader.GetInput("sourceColorSpace").Get())
    for name in ("StormTables", "StormPage00", *(["StormPage14"] if in_page else []), "RoughnessTexture",
                 "NormalTexture"):
        assert files[name] == ("raw", "raw"), name
    for name in ("DiffuseTexture", "SpecularTexture"):
        assert files[name] == ("srgb_rec709_scene", "sRGB"), name
    surface = S.Shader(stage.GetPrimAtPath("/pebbles/mtl/BtfMaterial/PreviewSurface"))
    assert space(surface.GetInput("diffuseColor").GetAttr()) == "lin_rec709_scene"
    assert space(surface.GetInput("roughness").GetAttr()) == "raw"
    # The files say it too: OIIO reads the data PNGs as linear, not sRGB-encoded.
    tex = asset.with_name("pebbles_textures")
    for rel in ("coeff/c000.png", "gpu/page00.png", "gpu/basis.png", "fallback/normal.png"):
        if (tex / rel).is_file():
            assert read_info_space(tex / rel) != "srgb_rec709_scene", rel
    assert read_info_space(tex / "fallback" / "diffuse.png") == "srgb_rec709_scene"


def test_shaders_return_the_recorded_rendering_space(asset):
    """Issue 40, colour: the Material records the space its BTF shaders return
    (btf:renderingColorSpace, linear Rec.709 by default: what UsdPreviewSurface colours and the
    renderers' frames mean), the Storm shader's renderingMatrixR/G/B and the packaged MaterialX
    document's node hold OCIO's working -> rendering matrix (ACEScg -> linear Rec.709: its red
    row 1.705, -0.622, -0.083), and the rows are data (raw).  The BTF itself is untouched
    (test_round_trip_bit_for_bit)."""
    import xml.etree.ElementTree as ET

    from usdbtf.gpu.shaders import RENDERING_INPUTS
    from usdbtf.usd.asset.storm import rendering_space_of, storm_shader

    stage = Usd.Stage.Open(str(asset))
    material = stage.GetPrimAtPath("/pebbles/mtl/BtfMaterial")
    assert material.GetAttribute("btf:renderingColorSpace").Get() == color.RENDERING_SPACE
    assert rendering_space_of(asset)[:2] == ("ACEScg", color.RENDERING_SPACE)
    want = color.linear_matrix("ACEScg", color.RENDERING_SPACE)
    assert np.allclose(want[0], [1.705051, -0.621792, -0.083259], atol=1e-5)
    shader = storm_shader(material)
    cache = Usd.ColorSpaceHashCache()
    for name, row in zip(RENDERING_INPUTS, want):
        assert np.allclose(shader.GetInput(name).Get(), row, atol=1e-6), name
        assert Usd.ColorSpaceAPI.ComputeColorSpaceName(shader.GetInput(name).GetAttr(), cache) == "raw"
    node = ET.parse(asset.with_name("pebbles_textures") / "gpu" / "usdbtf.mtlx").getroot().find("usdbtf_surface")
    values = {i.get("name"): i.get("value") for i in node.findall("input")}
    for name, row in zip(RENDERING_INPUTS, want):
        assert np.allclose([float(v) for v in values[name].split(",")], row, atol=1e-6), name


def test_rendering_space_option(compressed, tmp_path, capsys):
    """``package --rendering-space``: a USD token or OCIO name of a scene-linear space (the
    working space itself: identity rows, the shaders return working-space values); an encoded
    or unknown space is refused with one line naming the option (exit 2), nothing written."""
    from usdbtf.gpu.shaders import IDENTITY_ROWS, RENDERING_INPUTS
    from usdbtf.usd.asset.storm import storm_shader

    if compressed.name != "c_exr":
        pytest.skip("the option does not depend on the codec: checked once")
    out = tmp_path / "ap1" / "a.usda"
    assert main(["package", str(compressed), "-o", str(out), "--rendering-space", "lin_ap1_scene", "--no-thumbnail",
                 "--lod", "", "-q"]) == 0
    stage = Usd.Stage.Open(str(out))
    material = stage.GetPrimAtPath("/a/mtl/BtfMaterial")
    assert material.GetAttribute("btf:renderingColorSpace").Get() == "ACEScg"
    for name, row in zip(RENDERING_INPUTS, IDENTITY_ROWS):
        assert np.allclose(storm_shader(material).GetInput(name).Get(), row, atol=1e-7), name
    for space in ("srgb_rec709_scene", "no such space"):
        bad_usage(capsys, "package", compressed, "-o", tmp_path / "x" / "a.usda", "--rendering-space", space,
                  names="--rendering-space")
        _assert_nothing_written(tmp_path / "x")


def read_info_space(path: Path) -> str:
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    try:
        return inp.spec().getattribute("oiio:ColorSpace")
    finally:
        inp.close()


def test_lod_switches_from_a_scene_that_references_only_the_material(asset, compressed, tmp_path):
    """The README's scene pattern: a Material referencing </pebbles/mtl/BtfMaterial> picks its
    own lod, for the BTF data and for the Storm shader."""
    scene = tmp_path / "scene.usda"
    scene.write_text(f"""#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)
def Xform "World"
{{
    def Scope "Looks"
    {{
        def Material "Pebbles" (
            prepend references = @{asset}@</pebbles/mtl/BtfMaterial>
            variants = {{ string lod = "k6" }}
        )
        {{
        }}
        def Material "PebblesFull" (
            prepend references = @{asset}@</pebbles/mtl/BtfMaterial>
        )
        {{
        }}
    }}
}}
""")
    stage = Usd.Stage.Open(str(scene))
    low, full = stage.GetPrimAtPath("/World/Looks/Pebbles"), stage.GetPrimAtPath("/World/Looks/PebblesFull")
    assert low.GetVariantSets().GetVariantSet("lod").GetVariantNames() == ["full", "k6"]
    assert low.GetAttribute("btf:basisCount").Get() == 6 and full.GetAttribute("btf:basisCount").Get() == 12
    assert low.GetPrimAtPath("StormSurface").GetAttribute("inputs:basisCount").Get() == 6
    assert not UsdShade.Shader(low.GetPrimAtPath("StormSurface")).GetInput("page01").HasConnectedSource()
    assert UsdShade.Shader(full.GetPrimAtPath("StormSurface")).GetInput("page01").HasConnectedSource()
    cb = load_btf(stage, material="/World/Looks/Pebbles")
    assert cb.k == 6 and np.array_equal(reconstruct(cb), reconstruct(read_compressed(compressed), k=6))


# ------------------------------------------------------------------ round trips
def test_round_trip_bit_for_bit(asset, compressed):
    want = reconstruct(read_compressed(compressed))
    for layer in (asset, asset.with_suffix(".usdz")):
        got = reconstruct(load_btf(layer))
        assert got.dtype == want.dtype and np.array_equal(got, want), layer


def test_round_trip_through_a_referencing_stage(asset, compressed, tmp_path):
    scene = tmp_path / "scene.usda"
    stage = Usd.Stage.CreateNew(str(scene))
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    ref = stage.DefinePrim("/World/Rock")
    ref.GetReferences().AddReference(str(Path(asset).resolve()))
    stage.Save()
    cbtf = load_btf(scene)
    assert cbtf.info["material"] == "/World/Rock/mtl/BtfMaterial"
    assert np.array_equal(reconstruct(cbtf), reconstruct(read_compressed(compressed)))


def test_lod_variant_reads_fewer_layers(asset, compressed):
    cb = load_btf(asset, lod="k6")
    assert cb.k == 6
    assert np.array_equal(reconstruct(cb), reconstruct(read_compressed(compressed), k=6))


def test_sample_by_direction_equals_decompress(asset, compressed, tmp_path, capsys):
    cbtf = load_btf(asset)
    s = 40
    view, light = cbtf.sampling.view[s], cbtf.sampling.light[s]
    img = sample_image(cbtf, view, light)
    ok(capsys, "decompress", asset, "-o", tmp_path / "d", "--samples", str(s), "-q")
    ok(capsys, "decompress", compressed, "-o", tmp_path / "e", "--samples", str(s), "-q")
    a = sorted((tmp_path / "d").glob("*.*[!n]"))
    b = sorted((tmp_path / "e").glob("*.*[!n]"))
    assert [p.name for p in a] == [p.name for p in b]
    for x, y in zip(a, b):
        assert x.read_bytes() == y.read_bytes()
    assert np.array_equal(img, reconstruct(read_compressed(compressed), [s])[0])


def test_inspect_reports_k_bytes_directions_error(asset, capsys):
    out = ok(capsys, "inspect", asset, "--validate")
    assert "k            12 of 12" in out
    assert "169 samples: 13 views" in out
    assert "% at k = 12" in out and "0 error(s)" in out
    assert "shaders return Linear Rec.709 (sRGB)" in out          # issue 40: btf:renderingColorSpace
    gpu = asset.with_name("pebbles_textures") / "gpu"
    on_disk = sum(p.stat().st_size for p in gpu.iterdir() if p.name.startswith(("tables.", "page", "basis.")))
    basis = sum(p.stat().st_size for p in gpu.iterdir() if p.name.startswith(("tables.", "basis.")))
    # the BTF's one copy: the GPU tables, its pages and (schema 4) basis page, counted as the basis's
    assert f"bytes        {on_disk} (basis {basis}, coefficients {on_disk - basis}" in out
    # (the full lod's: each lower lod's own tables, gpu/tables_k<n>.exr, are not counted)


def test_inspect_lists_the_files_each_lod_loads(asset, capsys):
    """Every lod's file list is files on disk with their sizes, totals are their sums, the full
    lod loads every file of the asset but the usdz and the lower lods' own tables, basis pages
    and MaterialX documents (its own document, which no layer names, counts: a MaterialX consumer
    loads it); a lower lod loads fewer pages and its own tables, basis page and document (issue
    39) in place of the full ones, and inspect says it is within its share."""
    import json

    info = json.loads(ok(capsys, "inspect", asset, "--json"))
    levels = {lv["name"]: lv for lv in info["materials"][0]["lod_files"]}
    assert list(levels) == ["full", "k6"]
    for lv in levels.values():
        sizes = {f["path"]: f["bytes"] for f in lv["files"]}
        assert all(sizes[p] == (asset.parent / p).stat().st_size for p in sizes), sizes
        assert lv["total"] == sum(sizes.values())
    full = {f["path"] for f in levels["full"]["files"]}
    shipped = {str(p.relative_to(asset.parent)) for p in asset.parent.rglob("*") if p.is_file()
               and p.suffix != ".usdz" and not p.name.startswith(("tables_k", "basis_k", "usdbtf_k"))}
    assert full == shipped
    low = {f["path"] for f in levels["k6"]["files"]}
    in_page = "pebbles_textures/gpu/basis.png" in full        # schema 4: integer basis codes (not exr's halves)
    assert in_page == (asset.parent.name != "asset_c_exr")
    assert low - full == {"pebbles_textures/gpu/tables_k6.exr", "pebbles_textures/gpu/usdbtf_k6.mtlx"} | (
        {"pebbles_textures/gpu/basis_k6.png"} if in_page else set())
    own = {"pebbles_textures/gpu/tables.exr", "pebbles_textures/gpu/basis.png", "pebbles_textures/gpu/usdbtf.mtlx"}
    assert full - low - own and all("page" in Path(p).name for p in full - low - own)
    assert levels["full"]["share"] == levels["full"]["total"]
    assert levels["k6"]["total"] <= levels["k6"]["share"] < levels["full"]["total"]
    out = ok(capsys, "inspect", asset)
    assert f"loads        full (k = 12): {len(full)} files, {levels['full']['total']} bytes\n" in out
    assert f"loads        k6 (k = 6): {len(low)} files, {levels['k6']['total']} bytes; within its share " \
           f"{levels['k6']['share']} " in out


def test_asset_holds_each_coefficient_once(asset, compressed):
    """One copy: the BTF's names are the Storm preview's textures, no coeff/ or basis image
    beside them, and the pages hold each stored code once (one tile per pack)."""
    from usdbtf.gpu.tables import pack_count

    tex = asset.with_name("pebbles_textures")
    assert not (tex / "coeff").exists() and not list(tex.glob("basis.*"))
    stage = Usd.Stage.Open(str(asset))
    material = stage.GetPrimAtPath("/pebbles/mtl/BtfMaterial")
    assert material.GetAttribute("btf:coefficientLayout").Get() == "gpuPages"
    pages = [a.path for a in material.GetAttribute("btf:coefficients").Get()]
    storm_files = {}
    for prim in stage.Traverse():
        if prim.GetName().startswith("Storm") and UsdShade.Shader(prim).GetInput("file"):
            storm_files[prim.GetName()] = UsdShade.Shader(prim).GetInput("file").Get().path
    assert material.GetAttribute("btf:basis").Get().path == storm_files["StormTables"]
    # the coefficient pages from slot 0, then (schema 4: integer basis codes, not exr's halves)
    # the basis page in the last slot
    if pages[-1].endswith("gpu/basis.png"):
        assert pages.pop() == storm_files["StormPage14"] and asset.parent.name != "asset_c_exr"
    assert pages == [storm_files[f"StormPage{i:02d}"] for i in range(len(pages))]
    from usdbtf.usd.asset.storm import layout_from_asset

    layout, _, _ = layout_from_asset(asset)
    flat = layout.tables.reshape(-1, 4)
    directory = flat[int(flat[3, 0]):int(flat[3, 0]) + pack_count(12), :3].astype(int)
    assert len({tuple(d) for d in directory}) == pack_count(12)                  # no tile twice
    used = {tuple(d) for d in directory}
    for page, pixels in enumerate(layout.pages):                                 # and nothing else: the
        for y0 in range(0, pixels.shape[0], 32):                                 # rest of a page's grid
            for x0 in range(0, pixels.shape[1], 32):                             # is empty
                if (page, x0, y0) not in used:
                    assert not np.any(pixels[y0:y0 + 32, x0:x0 + 32]), (page, x0, y0)


def test_old_files_layout_assets_keep_reading(compressed, tmp_path, monkeypatch):
    """An asset of schema version 1 (one file per coefficient, a basis image: no
    btf:coefficientLayout) reads back as before, bit for bit; so does the files layout a
    sampling the preview cannot draw gets."""
    from usdbtf.usd.asset import storm

    monkeypatch.setattr(storm, "add_gpu_textures", lambda *a, **k: None)
    out = tmp_path / "old" / "pebbles.usda"
    pkg.write_package(pkg.package(compressed, pkg.PackageOptions(thumbnail=False)), out)
    tex = out.with_name("pebbles_textures")
    assert len(list((tex / "coeff").iterdir())) == 12 and list(tex.glob("basis.*"))
    want = reconstruct(read_compressed(compressed))
    assert np.array_equal(reconstruct(load_btf(out)), want)
    payload = Sdf.Layer.FindOrOpen(str(out.with_name("pebbles_payload.usdc")))
    prim = payload.GetPrimAtPath("/pebbles/mtl/BtfMaterial")
    prim.attributes["btf:schemaVersion"].default = 1
    prim.RemoveProperty(prim.attributes["btf:coefficientLayout"])
    payload.Save()
    assert np.array_equal(reconstruct(load_btf(out)), want)


def test_schema3_gpu_assets_keep_reading(compressed, tmp_path):
    """An asset of schema version 3 (integer basis codes in the GPU tables, 2^23 + code; no
    basis page in btf:coefficients) reads back bit for bit: the readers follow the tables,
    not the version number."""
    from basis_helpers import schema3_tables
    from usdbtf.imageio import encode_image, read_rgba

    cbtf = read_compressed(compressed)
    if cbtf.basis.pixels.dtype == np.float16:
        pytest.skip("half basis codes stay in the tables: no basis page to undo")
    out = tmp_path / "v3" / "pebbles.usda"
    pkg.write_package(pkg.package(compressed, pkg.PackageOptions(thumbnail=False)), out)
    gpu = out.with_name("pebbles_textures") / "gpu"
    tables = gpu / "tables.exr"
    tables.write_bytes(encode_image(schema3_tables(read_rgba(tables), cbtf), "exr", color_space="data",
                                    attributes={"compression": "zip"}))
    payload = Sdf.Layer.FindOrOpen(str(out.with_name("pebbles_payload.usdc")))
    prim = payload.GetPrimAtPath("/pebbles/mtl/BtfMaterial")
    prim.attributes["btf:schemaVersion"].default = 3
    listed = list(prim.attributes["btf:coefficients"].default)
    assert listed[-1].path.endswith("gpu/basis.png")
    prim.attributes["btf:coefficients"].default = Sdf.AssetPathArray(listed[:-1])
    payload.Save()
    (gpu / "basis.png").unlink()
    got = load_btf(out)
    np.testing.assert_array_equal(got.basis.pixels, cbtf.basis.pixels)
    for a, b in zip(got.coefficients, cbtf.coefficients):
        np.testing.assert_array_equal(a.pixels, b.pixels)


# ------------------------------------------------------------------ the fallback
def test_fallback_maps_recover_a_lambertian(tmp_path, capsys):
    """A flat Lambertian of known albedo: the fallback's diffuse map shows that albedo, with
    no specular and no normal tilt."""
    sampling = preset("small")
    albedo = np.zeros((16, 16, 3), np.float32)
    albedo[:, :8] = (0.6, 0.3, 0.1)
    albedo[:, 8:] = (0.2, 0.5, 0.7)
    cos_l = np.clip(to_vectors(sampling.light)[:, 2], 0, 1).astype(np.float32)
    working = color.processor("Linear Rec.709 (sRGB)", "scene_linear").apply(albedo)
    data = 0.8 * working[None] * cos_l[:, None, None, None]          # white level 0.8
    btf = ArrayBTF.from_linear(sampling, data)
    btf.metadata.update(physical_size_m=[0.02, 0.02], white_level=0.8)
    from compress_helpers import compress_into
    from usdbtf.compress import CompressOptions

    opts = CompressOptions(k=4, codec="exr")
    opts.extra = {"source_metadata": dict(btf.metadata)}
    compress_into(btf, tmp_path / "c", opts)
    pkg.write_package(pkg.package(tmp_path / "c", pkg.PackageOptions(thumbnail=False)), tmp_path / "a" / "flat.usda")
    folder = tmp_path / "a" / "flat_textures" / "fallback"
    png, _ = read_image(folder / "diffuse.png")
    lin = color.processor(fallback.COLOUR_ENCODING, "Linear Rec.709 (sRGB)").apply(png.astype(np.float32) / 255)
    np.testing.assert_allclose(lin[:, 2:6], albedo[:, 2:6], atol=0.02)
    np.testing.assert_allclose(lin[:, 10:14], albedo[:, 10:14], atol=0.02)
    spec, _ = read_image(folder / "specular.png")
    normal, _ = read_image(folder / "normal.png")
    assert spec.max() <= 28                                           # F0 < 0.012
    assert np.abs(normal.astype(int) - [128, 128, 255]).max() <= 3    # flat


@pytest.mark.parametrize("alpha", [0.1, 0.3])
def test_fit_recovers_a_ggx_surface_per_texel(alpha, tmp_path):
    """A synthetic surface with GGX alpha and F0 0.04 on a sloped and a flat half: the fit
    finds roughness sqrt(alpha), F0 and the slope's normal, and beats the flat fallback."""
    from usdbtf import synth, svbrdf
    from usdbtf.compress import CompressOptions, compress

    n = 8
    height = np.zeros((n, n), np.float32)
    height[:, : n // 2] = np.arange(n // 2, dtype=np.float32)[None, :] * 0.4       # a 22 degree slope along +x
    material = synth.Material(height, np.full((n, n, 3), 0.5, np.float32), np.full((n, n), 0.04, np.float32),
                              np.full((n, n), alpha, np.float32))
    sampling = preset("small")
    data = color.processor("Linear Rec.709 (sRGB)", "scene_linear").apply(synth.render_all(material, sampling))
    cbtf = compress(ArrayBTF.from_linear(sampling, data), CompressOptions(k=12, codec="exr"))
    maps = svbrdf.fit_svbrdf(cbtf)
    flat = slice(n // 2 + 1, None)
    assert abs(float(np.median(maps.roughness[:, flat])) - alpha ** 0.5) <= 0.1
    assert 0.01 <= float(np.median(maps.specular[:, flat])) <= 0.07
    # The slope rises along +x by 0.4 texel per texel: n ~ (-0.37, 0, 0.93) (x = image right).
    np.testing.assert_allclose(maps.normal[:, 1:3], np.broadcast_to([-0.37, 0, 0.93], (n, 2, 3)), atol=0.06)
    np.testing.assert_allclose(maps.normal[:, flat], np.broadcast_to([0, 0, 1], maps.normal[:, flat].shape), atol=0.02)
    truth = reconstruct(cbtf).reshape(cbtf.n_samples, -1, 3)
    err = {}
    for name, m in (("fit", maps), ("flat", svbrdf.flat_fallback(cbtf))):
        sums = ErrorSums()
        sums.add(truth, svbrdf.evaluate(m, cbtf.sampling.view, cbtf.sampling.light))
        err[name] = sums.percent
    assert err["fit"] < 0.7 * err["flat"], err


# ------------------------------------------------------------------ meshes
def test_mesh_with_uvs_is_packaged(compressed, tmp_path, capsys):
    obj = tmp_path / "quad.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
                   "f 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    out = tmp_path / "m" / "rock.usda"
    ok(capsys, "package", compressed, "-o", out, "--mesh", obj, "-q")
    stage = Usd.Stage.Open(str(out))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/rock/geo/quad"))
    assert len(mesh.GetPointsAttr().Get()) == 4 and list(mesh.GetFaceVertexCountsAttr().Get()) == [3, 3]
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == "vertex" and len(st.Get()) == 4
    assert validation_issues(out) == []


def test_mesh_without_uvs_is_refused(compressed, tmp_path, capsys):
    stl = tmp_path / "tri.obj"
    stl.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    bad_input(capsys, "package", compressed, "-o", tmp_path / "x" / "a.usda", "--mesh", stl, names="tri.obj")
    assert not (tmp_path / "x" / "a.usda").exists()


# ------------------------------------------------------------------ bad input
def _assert_nothing_written(folder: Path):
    assert not folder.exists() or not any(folder.iterdir()), list(folder.iterdir())


def test_missing_texture(compressed, tmp_path, capsys):
    broken = tmp_path / "c"
    shutil.copytree(compressed, broken)
    victim = sorted((broken / "coeff").iterdir())[3]
    victim.unlink()
    bad_input(capsys, "package", broken, "-o", tmp_path / "out" / "a.usda", names=victim.name)
    _assert_nothing_written(tmp_path / "out")


def test_missing_texture_in_packaged_asset(asset, tmp_path, capsys):
    copy = tmp_path / "a"
    shutil.copytree(asset.parent, copy)
    (copy / "pebbles_textures" / "gpu" / "page01.png").unlink(missing_ok=True)
    (copy / "pebbles_textures" / "gpu" / "page01.exr").unlink(missing_ok=True)
    bad_input(capsys, "decompress", copy / "pebbles.usda", "-o", tmp_path / "d", names="does not resolve")
    assert not (tmp_path / "d").exists()


def test_a_page_that_no_longer_holds_the_codes_is_refused(asset, tmp_path, capsys):
    """The one copy read back strictly: a page of the wrong size, or whose texels are not
    codes of the recorded storage type (a lossy re-save), is one line naming the problem."""
    from usdbtf.imageio import write_image

    copy = tmp_path / "a"
    shutil.copytree(asset.parent, copy)
    page = next((copy / "pebbles_textures" / "gpu").glob("page00.*"))
    small = np.zeros((8, 8, 4), np.float16 if page.suffix == ".exr" else np.uint8)
    page.unlink()
    write_image(page, small, color_space="data")
    bad_input(capsys, "decompress", copy / "pebbles.usda", "-o", tmp_path / "d", names="does not hold coefficient pack")
    assert not (tmp_path / "d").exists()
    if page.suffix == ".png":       # the same size, but values between 8-bit codes: not codes
        from usdbtf.usd.asset.storm import read_rgba

        original = read_rgba(asset.with_name("pebbles_textures") / "gpu" / page.name)
        page.unlink()
        write_image(page.with_suffix(".exr"), original.astype(np.float32) / 255 + 0.3 / 255, color_space="data")
        page.with_suffix(".exr").rename(page)       # an EXR under the PNG's name: OIIO reads it by content
        bad_input(capsys, "decompress", copy / "pebbles.usda", "-o", tmp_path / "d", names="not uint8 codes")


def test_corrupt_layer(asset, tmp_path, capsys):
    copy = tmp_path / "a"
    shutil.copytree(asset.parent, copy)
    (copy / "pebbles_payload.usdc").write_text("#usda 1.0\ndef Xform \"pebbles\" {\n  garbage here\n")
    line = bad_input(capsys, "inspect", copy / "pebbles.usda", names="pebbles")
    assert "payload" in line or "no BtfMaterialAPI" in line
    root = copy / "pebbles.usda"
    root.write_bytes(b"\x00\x01 not usd at all")
    bad_input(capsys, "decompress", root, "-o", tmp_path / "d", names="pebbles.usda")
    assert not (tmp_path / "d").exists()


def test_schema_version_mismatch(asset, tmp_path, capsys):
    copy = tmp_path / "a"
    shutil.copytree(asset.parent, copy)
    payload = Sdf.Layer.FindOrOpen(str(copy / "pebbles_payload.usdc"))
    payload.GetAttributeAtPath("/pebbles/mtl/BtfMaterial.btf:schemaVersion").default = 7
    payload.Save()
    bad_input(capsys, "decompress", copy / "pebbles.usda", "-o", tmp_path / "d", names="btf:schemaVersion = 7")
    assert not (tmp_path / "d").exists()


def test_failed_package_leaves_previous_asset_intact(compressed, work, tmp_path, capsys):
    out = tmp_path / "keep" / "pebbles.usda"
    ok(capsys, "package", compressed, "-o", out, "-q")
    before = {p: p.read_bytes() for p in out.parent.rglob("*") if p.is_file()}
    bad_usage(capsys, "package", compressed, "-o", out, "--lod", "999", "--force", names="--lod 999")
    after = {p: p.read_bytes() for p in out.parent.rglob("*") if p.is_file()}
    assert after == before
    # A previous asset is replaced only with --force (and then only once the new one is complete).
    refused(capsys, "package", compressed, "-o", out, "-q", names="--force")
    ok(capsys, "package", compressed, "-o", out, "-q", "--force")
    assert sorted(p.name for p in out.parent.iterdir()) == ["pebbles.usda", "pebbles_payload.usdc",
                                                            "pebbles_textures"]


def test_no_physical_size_is_a_clear_error(src, tmp_path, capsys):
    c = tmp_path / "c"
    ok(capsys, "compress", src, "-o", c, "--k", "2", "-q")
    meta = c / "btf-compressed.json"
    meta.write_text(meta.read_text().replace('"physical_size_m"', '"no_size"'))
    bad_input(capsys, "package", c, "-o", tmp_path / "o" / "a.usda", names="--physical-size")
    ok(capsys, "package", c, "-o", tmp_path / "o" / "a.usda", "--physical-size", "0.1", "0.1", "-q")


# ------------------------------------------------------------------ textures for renderers
def _texture_files(asset: Path) -> list[Path]:
    return sorted({Path(a.resolvedPath) for _, a in asset_values(asset) if a.resolvedPath})


@pytest.mark.parametrize("fmt", ["tx", "exr"])
def test_texture_formats_are_tiled_mipmapped_and_bit_exact(compressed, tmp_path, capsys, fmt):
    import OpenImageIO as oiio

    out = tmp_path / fmt / "pebbles.usda"
    ok(capsys, "package", compressed, "-o", out, "--texture-format", fmt, "--no-thumbnail", "-q")
    files = _texture_files(out)
    assert len(files) >= 1 + 2 + 4 and {p.suffix for p in files} == {f".{fmt}"}   # tables, pages, fallback
    for path in files:
        inp = oiio.ImageInput.open(str(path))
        spec, levels = inp.spec(), 0
        while inp.seek_subimage(0, levels):
            levels += 1
        inp.close()
        assert spec.tile_width == 64 and levels > 1, path
    want = reconstruct(read_compressed(compressed))
    assert np.array_equal(reconstruct(load_btf(out)), want)                     # level 0 holds the codes
    assert np.array_equal(reconstruct(load_btf(out, lod="k6")), reconstruct(read_compressed(compressed), k=6))
    assert validate_layer(out) == []
    # The GPU pages hold what the sampler read from the PNG pages.
    from usdbtf.usd.asset import storm

    layout, _, _ = storm.layout_from_asset(out)
    png_layout, _, _ = storm.layout_from_asset(pkg.write_package(pkg.package(compressed, pkg.PackageOptions(
        thumbnail=False)), tmp_path / "png" / "p.usda")["root"])
    assert len(layout.pages) == len(png_layout.pages)
    for got, ref in zip(layout.pages, png_layout.pages):
        if fmt == "exr" and np.issubdtype(ref.dtype, np.integer):          # normalised, as a sampler reads it
            got = np.rint(np.asarray(got, np.float64) * np.iinfo(ref.dtype).max)
        assert np.array_equal(np.asarray(got, np.float64), np.asarray(ref, np.float64))


def test_usdz_refuses_tiff_textures(compressed, tmp_path, capsys):
    code, _, err = run(capsys, "package", compressed, "-o", tmp_path / "a.usda", "--texture-format", "tx", "--usdz")
    assert code != 0 and "--usdz cannot hold tx" in err
    assert not (tmp_path / "a.usda").exists()


def test_max_bytes_budgets_the_packaged_asset(src, tmp_path, capsys):
    """Issue 39: ``compress --max-bytes B`` (the CLI budgets the asset by default) then
    ``package``: the files the full lod loads (as ``inspect`` lists them) total within
    [0.99 (B - 4 KB), 1.01 B]; each lower lod loads a prefix of the pages and its own tables (its n basis
    vectors only) beside the same maps and layers, within its share of B (usd.asset.lod: B less
    what the full lod spends on the vectors it drops, recomputed here from the compressed
    folder's codes); compress recorded what it budgeted and the asset's bytes; the shipped
    8-bit packs hold exactly the folder's codes, so the folder's error is the asset's.  A folder
    budgeted for itself (``--budget-for folder``): package says so in one warning line."""
    import json

    # Below what the material's 169 components ship (94,212 bytes with the budgets' dead zone, issue
    # 39; 113,513 since the JPEG thumbnail; 131,471..142,500 before), so rate control has a k to
    # choose rather than all of them.
    budget = 85_000
    folder = tmp_path / "c"
    ok(capsys, "compress", src, "-o", folder, "--max-bytes", str(budget), "--codec", "png", "-q")
    out = tmp_path / "a" / "pebbles.usda"
    summary = json.loads(ok(capsys, "package", folder, "-o", out, "--json", "-q"))
    assert summary["max_bytes"] == budget
    info = json.loads(ok(capsys, "inspect", out, "--json"))
    lods = info["materials"][0]["lod_files"]
    totals = {lv["name"]: sum(f["bytes"] for f in lv["files"]) for lv in lods}
    assert summary["bytes"] == totals
    full = totals["full"]
    # Rate control keeps _RECORD_ALLOWANCE (4 KB: the provenance and curve the layers add) below
    # B; at this small budget that is 4 % of it.
    from usdbtf.compress.ratecontrol import _RECORD_ALLOWANCE

    assert 0.99 * (budget - _RECORD_ALLOWANCE) <= full <= 1.01 * budget, (full, budget)
    assert len(totals) > 1 and all(n < full for name, n in totals.items() if name != "full")
    _assert_lods_within_their_shares(out, lods, read_compressed(folder), budget, summary["shares"])
    cbtf = read_compressed(folder)
    assert cbtf.info["provenance"]["options"]["budget_for"] == "asset"
    choice = cbtf.info["choice"]
    # choice.bytes is rate control's last packaging, whose fallback maps come from the first packaging's
    # fits (issue 42: fitted once per run); package fits the final k's own, so on this 85 KB budget,
    # where the maps are a quarter of the bytes or more, the two differ by ~1 % (1,295 B measured at
    # 120 KB).  The asset itself is held to [0.99 (B - 4 KB), 1.01 B] above.
    assert choice["budget_for"] == "asset" and abs(choice["bytes"] - full) <= 0.02 * budget
    assert choice["folder_bytes"] == cbtf.info["bytes"]["payload"] < full
    # The asset ships the folder's codes exactly: every coefficient layer and basis vector.
    shipped = load_btf(out)
    assert shipped.k == cbtf.k
    assert {st.pixels.dtype for st in cbtf.coefficients} == {np.dtype(np.uint8)}
    for got, want in zip(shipped.coefficients, cbtf.coefficients):
        np.testing.assert_array_equal(got.pixels, want.pixels)
    np.testing.assert_array_equal(shipped.basis.pixels, cbtf.basis.pixels)
    code, _, err = run(capsys, "package", folder, "-o", out, "--force")
    assert code == 0 and f"the asset's bytes (every file the full lod loads): {full:,}" in err
    assert f"{full / budget:.3f} of the --max-bytes budget of {budget:,}" in err
    assert "--budget-for asset" not in err

    old = tmp_path / "f"
    ok(capsys, "compress", src, "-o", old, "--max-bytes", "30000", "--budget-for", "folder", "--codec", "png",
       "--k", "8", "-q")
    assert read_compressed(old).info["choice"]["budget_for"] == "folder"
    code, _, err = run(capsys, "package", old, "-o", tmp_path / "b" / "f.usda")
    assert code == 0 and [line for line in err.splitlines() if "--budget-for asset" in line] == [
        next(line for line in err.splitlines() if "budgeted the compressed folder's textures" in line)]


def _assert_lods_within_their_shares(out: Path, lods: list, cbtf, budget: int, shares: dict) -> None:
    """Issue 39: each lower lod of the asset ``out`` (``lods``: inspect's lod_files) loads its own
    tables and basis page (schema 4), the page holding exactly its first n basis vectors'
    codes, and no more than its share of ``budget``, recomputed from the compressed BTF
    ``cbtf``'s codes; ``shares``: what package reported, the same numbers."""
    from usdbtf.compress.format import cross_layout
    from usdbtf.compress.packs import basis_page_codes, shipped_basis_bytes
    from usdbtf.gpu.tables import basis_in_page
    from usdbtf.usd.asset.lod import lod_share
    from usdbtf.usd.asset.storm import read_rgba

    full = lods[0]
    sizes = {f["path"]: f["bytes"] for f in full["files"]}
    assert full["name"] == "full" and shares["full"] == budget and full["total"] <= 1.01 * budget
    assert sizes["pebbles_textures/gpu/basis.png"] == shipped_basis_bytes(cbtf)     # rate control's count
    for lv in lods[1:]:
        n, own = lv["k"], {f["path"] for f in lv["files"]}
        tables, basis = f"pebbles_textures/gpu/tables_k{n}.exr", f"pebbles_textures/gpu/basis_k{n}.png"
        assert {tables, basis} <= own and not {"pebbles_textures/gpu/tables.exr", "pebbles_textures/gpu/basis.png"} & own
        flat = read_rgba(out.parent / tables).reshape(-1, 4)
        groups = -(-n // 4)
        assert int(flat[1, 0]) == n and int(flat[0, 3]) == groups         # its n vectors, its groups
        assert basis_in_page(flat)
        codes = basis_page_codes(read_rgba(out.parent / basis), *cross_layout(cbtf.sampling), n)
        np.testing.assert_array_equal(codes, cbtf.basis.pixels[:, :n, 0])
        assert (out.parent / basis).stat().st_size == shipped_basis_bytes(cbtf, n)
        dropped = sum(sizes[p] for p in set(sizes) - own if "/gpu/page" in p)
        share = lod_share(budget, dropped, shipped_basis_bytes(cbtf), shipped_basis_bytes(cbtf, n))
        assert shares[lv["name"]] == share
        assert lv["total"] <= share, (lv["name"], lv["total"], share)
        # Its own tables and basis page cost less than the full ones, which it loaded before.
        assert (out.parent / tables).stat().st_size < sizes["pebbles_textures/gpu/tables.exr"]
        assert (out.parent / basis).stat().st_size < sizes["pebbles_textures/gpu/basis.png"]


def test_cross_sampling_stores_each_direction_once(asset, compressed):
    """13 views x 13 lights: btf:directionLayout 'cross' stores 13 + 13 directions, and
    load_btf expands them to the compressed folder's 169 rows exactly."""
    stage = Usd.Stage.Open(str(asset))
    material = stage.GetPrimAtPath("/pebbles/mtl/BtfMaterial")
    assert material.GetAttribute("btf:directionLayout").Get() == "cross"
    assert len(material.GetAttribute("btf:viewDirections").Get()) == 13
    assert len(material.GetAttribute("btf:lightDirections").Get()) == 13
    got, want = load_btf(asset).sampling, read_compressed(compressed).sampling
    assert np.array_equal(got.view, want.view) and np.array_equal(got.light, want.light)
