"""``--usdz-ar``: the asset for AR viewers (Quick Look, RealityKit): one usdc layer, PNGs.

AR viewers read a single USD layer with UsdPreviewSurface materials and PNG/JPEG textures;
they have no BTF support, no Storm, no payloads or variants worth carrying.  The package
(``<stem>_ar.usdz``) therefore holds, rule by rule of the ARKit compliance checker's
published list (usdUtils/complianceChecker.py, ARKit rules, and its former
ARKitRootLayerChecker):

* one layer, ``<stem>_ar.usdc``, the package's first file (root layer checker);
* only PNG textures next to it, stored uncompressed and 64-byte aligned
  (``UsdUtils.CreateNewUsdzPackage``; file extension, byte alignment, compression checkers);
* ``/<root>`` (Xform, kind component, defaultPrim; metersPerUnit, upAxis) with the mesh and
  ``mtl/BtfMaterial``: the fitted fallback (usd.fallback) in the metallic workflow at
  metallic 0 (AR renderers ignore UsdPreviewSurface's specular workflow): diffuse colour,
  roughness and the normal map (8-bit, raw, scale 2 bias -1: the normal-map checker);
  only UsdPreviewSurface, UsdUVTexture and UsdPrimvarReader_float2 shaders by ``info:id``
  (shader checker), bound with MaterialBindingAPI (binding checkers);
* no BtfMaterialAPI data and no Storm network: nothing an AR viewer could use.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["AR_SUFFIX", "make_ar_usdz"]

AR_SUFFIX = "_ar"


def make_ar_usdz(staging: Path, stem: str, root: str, mesh, maps, asset_name: str, asset_version: str | None = None,
                 creator: str | None = None, ocio_config: str | None = None, *, wrap: str = "repeat") -> Path:
    """Write ``<staging>/<stem>_ar.usdz`` from ``mesh`` (a :class:`usdbtf.mesh.Mesh`) and the fitted
    ``maps`` (svbrdf.SvbrdfMaps); returns its path."""
    from pxr import Kind, Sdf, Usd, UsdGeom, UsdShade

    from ..mesh.author import author_mesh
    from . import fallback
    from .layers import MATERIAL, make_usdz, stage_metadata, usd_write
    from .textures import TextureSet

    work = staging / f".{stem}{AR_SUFFIX}"
    textures_rel = f"{stem}{AR_SUFFIX}_textures"
    textures = TextureSet(work / textures_rel, textures_rel, "png")
    textures.folder.mkdir(parents=True)
    written = fallback.write_maps(maps, textures, ocio_config, names=("diffuse", "roughness", "normal"))
    layer_path = work / f"{stem}{AR_SUFFIX}.usdc"
    with usd_write(layer_path):
        stage = Usd.Stage.CreateNew(str(layer_path))
    stage_metadata(stage.GetRootLayer(), root, asset_name=asset_name, what="AR package", creator=creator)
    prim = UsdGeom.Xform.Define(stage, f"/{root}").GetPrim()
    model = Usd.ModelAPI(prim)
    model.SetKind(Kind.Tokens.component)
    model.SetAssetName(asset_name)
    model.SetAssetIdentifier(Sdf.AssetPath(f"./{layer_path.name}"))
    if asset_version is not None:
        model.SetAssetVersion(asset_version)
    UsdGeom.Scope.Define(stage, f"/{root}/geo")
    UsdGeom.Scope.Define(stage, f"/{root}/mtl")
    material = UsdShade.Material.Define(stage, f"/{root}/mtl/{MATERIAL}")
    fallback.author_fallback(stage, material, written, wrap=wrap, specular_workflow=False)
    geom = author_mesh(stage, f"/{root}/geo/{geometry_name(mesh)}", mesh)
    UsdShade.MaterialBindingAPI.Apply(geom).Bind(material)
    with usd_write(layer_path):
        stage.GetRootLayer().Save()
    del stage
    return make_usdz(layer_path, staging / f"{stem}{AR_SUFFIX}.usdz")


def geometry_name(mesh) -> str:
    from pxr import Tf

    return Tf.MakeValidIdentifier(mesh.name)
