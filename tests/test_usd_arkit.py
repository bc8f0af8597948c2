"""Issue 15 part 6: ``package --usdz-ar`` writes a usdz AR viewers accept.

The package is checked against the ARKit rules of USD's old compliance checker,
re-implemented from their published list in tests/arkit_rules.py.  The control: the
full ``--usdz`` (two layers, usda first, an EXR table, the Storm network) fails them.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

import usdbtf  # noqa: F401  (sets up the USD plugin first)
from pxr import Usd, UsdShade

from arkit_rules import check
from usdbtf.cli import main
from usdbtf.imageio import read_image


@pytest.fixture(scope="module")
def asset(tmp_path_factory, synth_capture) -> Path:
    work = tmp_path_factory.mktemp("ar")
    synth_capture("ridged_fabric", "small", 32, out=work / "src")
    assert main(["compress", str(work / "src"), "-o", str(work / "c"), "--k", "8", "--codec", "png", "-q"]) == 0
    out = work / "a" / "fabric.usda"
    assert main(["package", str(work / "c"), "-o", str(out), "--usdz", "--usdz-ar", "--asset-version", "2",
                 "-q"]) == 0
    return out


def test_ar_package_passes_every_arkit_rule(asset):
    ar = asset.with_name("fabric_ar.usdz")
    assert check(ar) == []
    with zipfile.ZipFile(ar) as z:
        names = z.namelist()
    assert names[0] == "fabric_ar.usdc" and all(n.endswith(".png") for n in names[1:])


def test_ar_package_is_the_fitted_fallback_only(asset):
    stage = Usd.Stage.Open(str(asset.with_name("fabric_ar.usdz")))
    assert [layer for layer in stage.GetUsedLayers() if layer.realPath] == [stage.GetRootLayer()]
    assert Usd.ModelAPI(stage.GetDefaultPrim()).GetAssetVersion() == "2"
    material = UsdShade.Material(stage.GetPrimAtPath("/fabric/mtl/BtfMaterial"))
    assert not material.GetPrim().HasAPI("BtfMaterialAPI") and not material.GetSurfaceOutput("glslfx")
    ids = {UsdShade.Shader(p).GetIdAttr().Get() for p in stage.Traverse() if p.IsA(UsdShade.Shader)}
    assert ids == {"UsdPreviewSurface", "UsdUVTexture", "UsdPrimvarReader_float2"}
    surface = material.ComputeSurfaceSource()[0]
    assert surface.GetInput("useSpecularWorkflow").Get() == 0 and surface.GetInput("metallic").Get() == 0
    connected = {i.GetBaseName() for i in surface.GetInputs() if i.HasConnectedSource()}
    assert connected == {"diffuseColor", "roughness", "normal"}
    # The same fit as the full asset's fallback.
    with zipfile.ZipFile(asset.with_name("fabric_ar.usdz")) as z:
        z.extract("fabric_ar_textures/fallback/diffuse.png", asset.parent / "x")
    ar_png, _ = read_image(asset.parent / "x" / "fabric_ar_textures" / "fallback" / "diffuse.png")
    main_png, _ = read_image(asset.with_name("fabric_textures") / "fallback" / "diffuse.png")
    assert np.array_equal(ar_png, main_png)


def test_ar_package_default_prim_has_the_geometry_extents_hint(asset):
    """AR viewers and asset browsers frame a model by its default prim's extentsHint: the
    geometry's bounds, the same box as the full asset's."""
    from pxr import UsdGeom

    stage = Usd.Stage.Open(str(asset.with_name("fabric_ar.usdz")))
    hint = UsdGeom.ModelAPI(stage.GetDefaultPrim()).GetExtentsHint()
    assert hint is not None and len(hint) == 2, "no extentsHint on the AR package's default prim"
    box = UsdGeom.BBoxCache(Usd.TimeCode.Default(), ["default"]).ComputeUntransformedBound(
        stage.GetDefaultPrim()).ComputeAlignedRange()
    assert np.allclose(np.array(hint), [box.GetMin(), box.GetMax()], atol=1e-6)
    assert (np.array(hint[1]) - np.array(hint[0])).max() > 0        # a real box, not a point
    full = Usd.Stage.Open(str(asset))
    assert np.allclose(np.array(hint), np.array(UsdGeom.ModelAPI(full.GetDefaultPrim()).GetExtentsHint()))


def test_control_the_full_usdz_breaks_the_arkit_rules(asset):
    failed = "\n".join(check(asset.with_suffix(".usdz")))
    for rule in ("ARKitRootLayerChecker", "ARKitShaderChecker", "ARKitFileExtensionChecker"):
        assert rule in failed, failed
    assert "UsdBtfSurface" in failed and "tables.exr" in failed


def test_every_piece_is_a_usdbtf_output_that_force_replaces(asset, tmp_path, capsys):
    """The pieces beside an asset (usdc payload, thumbnail and fallback maps in the texture
    folder, both usdz packages) are recognised as usdbtf outputs, so ``--force`` replaces
    them (here with another texture format), and refuses a texture folder holding anything
    else."""
    import shutil

    from cli_helpers import ok, refused
    from usdbtf import outputs

    pieces = {"fabric.usda": outputs.ASSET, "fabric_payload.usdc": outputs.ASSET, "fabric.usdz": outputs.ASSET,
              "fabric_ar.usdz": outputs.ASSET, "fabric_textures": outputs.ASSET_TEXTURES}
    assert {name: outputs.identify(asset.with_name(name)) for name in pieces} == pieces
    assert (asset.with_name("fabric_textures") / "thumbnail.jpg").is_file()
    folder = tmp_path / "a"
    folder.mkdir()
    for name in pieces:
        (shutil.copytree if asset.with_name(name).is_dir() else shutil.copy2)(asset.with_name(name), folder / name)
    compressed, root = asset.parent.parent / "c", folder / asset.name
    refused(capsys, "package", compressed, "-o", root, "--usdz", "--usdz-ar", "-q", names="--force")
    ok(capsys, "package", compressed, "-o", root, "--usdz", "--usdz-ar", "--texture-format", "exr", "--force", "-q")
    assert sorted(p.name for p in folder.iterdir()) == sorted(pieces)          # nothing else left behind
    assert {name: outputs.identify(folder / name) for name in pieces} == pieces
    assert {p.suffix for p in (folder / "fabric_textures" / "gpu").iterdir()} == {".exr", ".mtlx"}
    # Anything foreign in a piece: not a usdbtf output any more, so not replaced.
    (folder / "fabric_textures" / "notes.txt").write_text("mine\n")
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    refused(capsys, "package", compressed, "-o", root, "--usdz", "--usdz-ar", "--force", "-q", names="fabric_textures")
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before
