"""The ARKit rules of USD's old compliance checker (usdUtils/complianceChecker.py, `usdchecker
--arkit`), re-implemented from their published descriptions for tests/test_usd_arkit.py
(usd-core ships neither the checker nor usdchecker).

Base rules that apply to a package: ByteAlignmentChecker, CompressionChecker,
MissingReferenceChecker, StageMetadataChecker, TextureChecker (consumer level: only jpg,
jpeg, png), NormalMapTextureChecker, MaterialBindingAPIAppliedChecker.  ARKit rules:
ARKitLayerChecker, ARKitPrimTypeChecker, ARKitShaderChecker, ARKitMaterialBindingChecker,
ARKitFileExtensionChecker (here: usdc, png, jpg, jpeg only), ARKitPackageEncapsulationChecker,
and the former ARKitRootLayerChecker (one usdc layer, first in the package).

:func:`check` returns one line per failed rule: "<Rule>: <what>".
"""
from __future__ import annotations

from pathlib import Path

ALLOWED_PRIM_TYPES = ("", "Scope", "Xform", "Camera", "Shader", "Material", "Mesh", "Sphere", "Cube", "Cylinder",
                      "Cone", "Capsule", "GeomSubset", "Points", "SkelRoot", "Skeleton", "SkelAnimation",
                      "BlendShape", "SpatialAudio", "PhysicsScene")
ALLOWED_SHADER_IDS = ("UsdPreviewSurface", "UsdUVTexture", "UsdTransform2d")
PACKAGE_EXTENSIONS = ("usdc", "png", "jpg", "jpeg")
TEXTURE_EXTENSIONS = ("png", "jpg", "jpeg")
EIGHT_BIT = ("bmp", "tga", "jpg", "jpeg", "png", "tif")


def _zip_rules(path: Path) -> list[str]:
    from pxr import Sdf

    zf = Sdf.ZipFile.Open(str(path))
    if not zf:
        return [f"Package: cannot open {path}"]
    names = list(zf.GetFileNames())
    out = []
    if not names or not names[0].endswith(".usdc"):
        out.append(f"ARKitRootLayerChecker: first file {names[:1]} is not a .usdc layer")
    for name in names:
        info = zf.GetFileInfo(name)
        if info.dataOffset % 64:
            out.append(f"ByteAlignmentChecker: {name} at offset {info.dataOffset}")
        if info.compressionMethod != 0:
            out.append(f"CompressionChecker: {name} is compressed (method {info.compressionMethod})")
        if name.rsplit(".", 1)[-1].lower() not in PACKAGE_EXTENSIONS:
            out.append(f"ARKitFileExtensionChecker: {name}")
    return out


def _input_value(shader, name: str):
    from pxr import Usd, UsdShade

    inp = shader.GetInput(name)
    if not inp:
        return None
    attrs = UsdShade.Utils.GetValueProducingAttributes(inp)
    if len(attrs) != 1 or not UsdShade.Input.IsInput(attrs[0]):
        return None
    return attrs[0].Get(Usd.TimeCode.EarliestTime())


def _shader_rules(prim) -> list[str]:
    from pxr import Gf, Sdf, Usd, UsdShade

    out = []
    shader = UsdShade.Shader(prim)
    if shader.GetImplementationSource() != UsdShade.Tokens.id:
        out.append(f"ARKitShaderChecker: {prim.GetPath()} implementation source {shader.GetImplementationSource()}")
    sid = shader.GetShaderId() or ""
    if not (sid in ALLOWED_SHADER_IDS or sid.startswith("UsdPrimvarReader") or sid.startswith("ND_")):
        out.append(f"ARKitShaderChecker: {prim.GetPath()} has info:id {sid!r}")
    for inp in shader.GetInputs():
        conns = inp.GetAttr().GetConnections()
        if conns:
            source = inp.GetConnectedSource()
            if len(conns) > 1:
                out.append(f"ARKitShaderChecker: {inp.GetAttr().GetPath()} has {len(conns)} sources")
            if not source or not (source[0].GetPrim().IsA(UsdShade.Shader) or source[0].GetPrim().IsA(UsdShade.Material)):
                out.append(f"ARKitShaderChecker: {inp.GetAttr().GetPath()} has no valid source")
        if inp.GetTypeName() in (Sdf.ValueTypeNames.Asset, Sdf.ValueTypeNames.AssetArray):
            value = inp.Get(Usd.TimeCode.EarliestTime())
            for asset in ([value] if inp.GetTypeName() == Sdf.ValueTypeNames.Asset else list(value or [])):
                if asset and asset.path.rsplit(".", 1)[-1].lower() not in TEXTURE_EXTENSIONS:
                    out.append(f"TextureChecker: {inp.GetAttr().GetPath()} @{asset.path}@")
                if asset and not asset.resolvedPath:
                    out.append(f"MissingReferenceChecker: {inp.GetAttr().GetPath()} @{asset.path}@")
    if sid == "UsdPreviewSurface" and shader.GetInput("normal"):
        producers = UsdShade.Utils.GetValueProducingAttributes(shader.GetInput("normal"))
        if producers and producers[0].GetPrim() != prim:
            source = UsdShade.Shader(producers[0].GetPrim())
            if source.GetShaderId() == "UsdUVTexture":
                tex = _input_value(source, "file")
                if not tex or not tex.resolvedPath:
                    out.append(f"NormalMapTextureChecker: {source.GetPath()} file does not resolve")
                elif tex.resolvedPath.rstrip("]").rsplit(".", 1)[-1].lower() in EIGHT_BIT:
                    if _input_value(source, "sourceColorSpace") != "raw":
                        out.append(f"NormalMapTextureChecker: {source.GetPath()} sourceColorSpace is not raw")
                    scale, bias = _input_value(source, "scale"), _input_value(source, "bias")
                    if not (isinstance(scale, Gf.Vec4f) and isinstance(bias, Gf.Vec4f)
                            and tuple(scale)[:3] == (2, 2, 2) and tuple(bias)[:3] == (-1, -1, -1)):
                        out.append(f"NormalMapTextureChecker: {source.GetPath()} scale {scale} bias {bias}")
    return out


def _binding_rules(prim) -> list[str]:
    from pxr import UsdShade

    out = []
    for rel in prim.GetRelationships():
        if not rel.GetName().startswith(UsdShade.Tokens.materialBinding):
            continue
        if not prim.HasAPI(UsdShade.MaterialBindingAPI):
            out.append(f"MaterialBindingAPIAppliedChecker: {prim.GetPath()}")
        targets = rel.GetTargets()
        if len(targets) == 1 and not UsdShade.MaterialBindingAPI.DirectBinding(rel).GetMaterial():
            out.append(f"ARKitMaterialBindingChecker: {rel.GetPath()} -> {targets[0]}")
    return out


def check(path: Path) -> list[str]:
    """Every ARKit rule (module docstring) on the package at ``path``."""
    from pxr import Ar, Sdf, Usd, UsdGeom, UsdUtils

    path = Path(path)
    out = _zip_rules(path)
    stage = Usd.Stage.Open(str(path))
    for key in ("upAxis", "metersPerUnit"):
        if not stage.HasAuthoredMetadata(key):
            out.append(f"StageMetadataChecker: no {key}")
    if not stage.GetDefaultPrim():
        out.append("StageMetadataChecker: no defaultPrim")
    on_disk = [layer for layer in stage.GetUsedLayers() if layer.realPath]
    if len(on_disk) != 1:
        out.append(f"ARKitRootLayerChecker: the stage uses {len(on_disk)} layers")
    for layer in on_disk:
        if layer.GetFileFormat().formatId not in ("usd", "usda", "usdc", "usdz"):
            out.append(f"ARKitLayerChecker: {layer.identifier}")
    with Ar.ResolverContextBinder(stage.GetPathResolverContext()):
        layers, assets, unresolved = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(path)))
    for item in list(unresolved):
        out.append(f"MissingReferenceChecker: {item}")
    package = str(path.resolve())
    for layer in layers:
        if layer.realPath and not layer.realPath.startswith(package):
            out.append(f"ARKitPackageEncapsulationChecker: layer {layer.identifier}")
    for asset in assets:
        if not asset.startswith(package):
            out.append(f"ARKitPackageEncapsulationChecker: asset {asset}")
    for prim in Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies()):
        if prim.GetTypeName() not in ALLOWED_PRIM_TYPES and not prim.GetTypeName().startswith("RealityKit"):
            out.append(f"ARKitPrimTypeChecker: {prim.GetPath()} is a {prim.GetTypeName()}")
        if prim.IsA(UsdGeom.PointInstancer):
            out.append(f"ARKitPrimTypeChecker: {prim.GetPath()} is a PointInstancer")
        from pxr import UsdShade

        if prim.IsA(UsdShade.Shader):
            out += _shader_rules(prim)
        out += _binding_rules(prim)
    return out
