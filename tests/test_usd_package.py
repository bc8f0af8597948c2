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

from cli_helpers import bad_input, bad_usage, ok, refused
from usdbtf import colour
from usdbtf.cli import main
from usdbtf.compress import read_compressed, reconstruct
from usdbtf.imageio import read_image
from usdbtf.model import ArrayBTF
from usdbtf.sampling import preset, to_vectors
from usdbtf.usd import package as pkg
from usdbtf.usd.read import load_btf, sample_image
from usdbtf.usd.validate import validation_issues

OIIOTOOL = Path(__import__("sys").executable).parent / "oiiotool"


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("usdpkg")


@pytest.fixture(scope="module")
def src(work) -> Path:
    folder = work / "src"
    assert main(["synth", "pebbles", "-o", str(folder), "--sampling", "small", "--size", "32", "-q"]) == 0
    return folder


@pytest.fixture(scope="module", params=["jxl", "exr", "jpeg"])
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
    return [root, root.with_name(root.stem + "_payload.usda"), root.with_suffix(".usdz")]


# ------------------------------------------------------------------ validity
def test_every_validator_passes_on_every_layer(asset):
    from pxr import UsdValidation

    assert len(UsdValidation.ValidationRegistry().GetOrLoadAllValidators()) >= 25
    for layer in _layers(asset):
        assert layer.is_file()
        assert validation_issues(layer) == [], layer


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


def test_textures_open_in_oiiotool_and_paths_are_relative_and_resolve(asset):
    stage = Usd.Stage.Open(str(asset))
    checked = 0
    for prim in stage.Traverse():
        for attr in prim.GetAuthoredAttributes():
            values = attr.Get()
            if attr.GetTypeName() == Sdf.ValueTypeNames.Asset:
                values = [values]
            elif attr.GetTypeName() != Sdf.ValueTypeNames.AssetArray:
                continue
            for a in values or []:
                assert a.path.startswith("./"), (attr.GetPath(), a.path)
                assert a.resolvedPath and Path(a.resolvedPath).is_file(), a.path
                assert Path(a.resolvedPath).suffix in (".png", ".exr", ".jpg")
                info = subprocess.run([str(OIIOTOOL), "--info", a.resolvedPath], capture_output=True, text=True)
                assert info.returncode == 0 and "x" in info.stdout, info.stderr
                checked += 1
    assert checked >= 12 + 2    # coefficients, basis, albedo


def test_asset_structure(asset):
    layer = Sdf.Layer.FindOrOpen(str(asset))
    stage = Usd.Stage.Open(str(asset))
    root = stage.GetDefaultPrim()
    assert root.GetName() == "pebbles" and Usd.ModelAPI(root).GetKind() == "component"
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0 and UsdGeom.GetStageUpAxis(stage) == "Y"
    assert root.HasAuthoredPayloads() and list(layer.GetPrimAtPath("/pebbles").variantSets.keys()) == ["lod"]
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
    tex = UsdShade.Shader(stage.GetPrimAtPath("/pebbles/mtl/BtfMaterial/AlbedoTexture"))
    assert tex.GetInput("sourceColorSpace").Get() == "sRGB"
    surface = UsdShade.Material(material).ComputeSurfaceSource()[0]
    assert surface.GetIdAttr().Get() == "UsdPreviewSurface"
    assert 0.0 < surface.GetInput("roughness").Get() <= 1.0
    # Unloaded, the lod variant can still be chosen (it sits outside the payload).
    unloaded = Usd.Stage.Open(str(asset), Usd.Stage.LoadNone)
    vset = unloaded.GetDefaultPrim().GetVariantSets().GetVariantSet("lod")
    assert vset.GetVariantNames() == ["full", "k6"]


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
    tex = asset.with_name("pebbles_textures")
    on_disk = sum(p.stat().st_size for p in tex.rglob("*") if p.is_file() and p.name != "preview_albedo.png"
                  and "gpu" not in p.relative_to(tex).parts)    # the BTF's own textures, not the GPU packs
    assert f"bytes        {on_disk} " in out


# ------------------------------------------------------------------ preview fit
def test_preview_albedo_recovers_a_lambertian(tmp_path, capsys):
    """A flat Lambertian of known albedo: the preview texture must show that albedo."""
    sampling = preset("small")
    albedo = np.zeros((16, 16, 3), np.float32)
    albedo[:, :8] = (0.6, 0.3, 0.1)
    albedo[:, 8:] = (0.2, 0.5, 0.7)
    cos_l = np.clip(to_vectors(sampling.light)[:, 2], 0, 1).astype(np.float32)
    working = colour.processor("Linear Rec.709 (sRGB)", "scene_linear").apply(albedo)
    data = 0.8 * working[None] * cos_l[:, None, None, None]          # white level 0.8
    btf = ArrayBTF.from_linear(sampling, data)
    btf.metadata.update(physical_size_m=[0.02, 0.02], white_level=0.8)
    from compress_helpers import compress_into
    from usdbtf.compress import CompressOptions

    opts = CompressOptions(k=4, codec="exr")
    opts.extra = {"source_metadata": dict(btf.metadata)}
    compress_into(btf, tmp_path / "c", opts)
    pkg.package(tmp_path / "c", tmp_path / "a" / "flat.usda")
    png, _ = read_image(tmp_path / "a" / "flat_textures" / "preview_albedo.png")
    lin = colour.processor(pkg.preview.ALBEDO_SPACE, "Linear Rec.709 (sRGB)").apply(png.astype(np.float32) / 255)
    np.testing.assert_allclose(lin[:, 2:6], albedo[:, 2:6], atol=0.02)
    np.testing.assert_allclose(lin[:, 10:14], albedo[:, 10:14], atol=0.02)


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
    (copy / "pebbles_textures" / "coeff" / sorted(p.name for p in (copy / "pebbles_textures" / "coeff").iterdir())[5]).unlink()
    bad_input(capsys, "decompress", copy / "pebbles.usda", "-o", tmp_path / "d", names="does not resolve")
    assert not (tmp_path / "d").exists()


def test_corrupt_layer(asset, tmp_path, capsys):
    copy = tmp_path / "a"
    shutil.copytree(asset.parent, copy)
    (copy / "pebbles_payload.usda").write_text("#usda 1.0\ndef Xform \"pebbles\" {\n  garbage here\n")
    line = bad_input(capsys, "inspect", copy / "pebbles.usda", names="pebbles")
    assert "payload" in line or "no BtfMaterialAPI" in line
    root = copy / "pebbles.usda"
    root.write_bytes(b"\x00\x01 not usd at all")
    bad_input(capsys, "decompress", root, "-o", tmp_path / "d", names="pebbles.usda")
    assert not (tmp_path / "d").exists()


def test_schema_version_mismatch(asset, tmp_path, capsys):
    copy = tmp_path / "a"
    shutil.copytree(asset.parent, copy)
    payload = copy / "pebbles_payload.usda"
    payload.write_text(payload.read_text().replace("uniform int btf:schemaVersion = 1", "uniform int btf:schemaVersion = 7"))
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
    assert sorted(p.name for p in out.parent.iterdir()) == ["pebbles.usda", "pebbles_payload.usda",
                                                            "pebbles_textures"]


def test_no_physical_size_is_a_clear_error(src, tmp_path, capsys):
    c = tmp_path / "c"
    ok(capsys, "compress", src, "-o", c, "--k", "2", "-q")
    meta = c / "btf-compressed.json"
    meta.write_text(meta.read_text().replace('"physical_size_m"', '"no_size"'))
    bad_input(capsys, "package", c, "-o", tmp_path / "o" / "a.usda", names="--physical-size")
    ok(capsys, "package", c, "-o", tmp_path / "o" / "a.usda", "--physical-size", "0.1", "0.1", "-q")


@pytest.mark.parametrize("alpha", [0.2, 0.7])
def test_roughness_fit_recovers_a_flat_ggx_surface(alpha, tmp_path):
    """A flat synthetic surface with GGX alpha: the fitted preview roughness is sqrt(alpha)."""
    from usdbtf import synth
    from usdbtf.compress import CompressOptions, compress

    n = 8
    material = synth.Material(np.zeros((n, n), np.float32), np.full((n, n, 3), 0.5, np.float32),
                              np.full((n, n), 0.04, np.float32), np.full((n, n), alpha, np.float32))
    sampling = preset("small")
    data = colour.processor("Linear Rec.709 (sRGB)", "scene_linear").apply(synth.render_all(material, sampling))
    cbtf = compress(ArrayBTF.from_linear(sampling, data), CompressOptions(k=4, codec="exr"))
    roughness, residual = pkg.preview.fit_roughness(cbtf)
    assert abs(roughness - alpha ** 0.5) <= 0.05 and residual < 0.05
