"""``--usdz-ar``: the asset for AR viewers (Quick Look, RealityKit): one usdc layer, PNGs.

AR viewers read a single USD layer with UsdPreviewSurface materials and PNG/JPEG textures;
they have no BTF support, no Storm, no payloads or variants worth carrying.  The package
(``<stem>_ar.usdz``) therefore holds, rule by rule of the ARKit compliance checker's
published list (usdUtils/complianceChecker.py, ARKit rules, and its former
ARKitRootLayerChecker):

* one layer, ``<stem>_ar.usdc``, the package's first file (root layer checker);
* only PNG textures next to it, stored uncompressed and 64-byte aligned
  (``UsdUtils.CreateNewUsdzPackage``; file extension, byte alignment, compression checkers);
* ``/<root>`` (Xform, kind component, defaultPrim; metersPerUnit, upAxis; ``extentsHint``, the
  mesh's bounds, which AR viewers and asset browsers frame by) with the mesh and
  ``mtl/BtfMaterial``: the fitted fallback (usd.asset.fallback) in the metallic workflow at
  metallic 0 (AR renderers ignore UsdPreviewSurface's specular workflow): diffuse colour,
  roughness and the normal map (8-bit, raw, scale 2 bias -1: the normal-map checker);
  only UsdPreviewSurface, UsdUVTexture and UsdPrimvarReader_float2 shaders by ``info:id``
  (shader checker), bound with MaterialBindingAPI (binding checkers);
* no BtfMaterialAPI data and no Storm network: nothing an AR viewer could use.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["AR_SUFFIX", "AR_MAPS", "ar_textures", "write_ar_usdz"]

AR_SUFFIX = "_ar"
#: The fallback maps an AR package holds (the metallic workflow has no specular map).
AR_MAPS = ("diffuse", "roughness", "normal")


def ar_textures(maps, ocio_config: str | None = None, texels=None):
    """The AR package's PNG textures of the fitted ``maps`` (svbrdf.SvbrdfMaps), encoded in
    memory: (textures.TextureSet, {map: name in it}).  ``texels``: ``maps`` are a quilt's
    source texels' (:func:`usdbtf.usd.asset.fallback.add_maps`)."""
    from . import fallback
    from .textures import TextureSet

    textures = TextureSet("png")
    return textures, fallback.add_maps(maps, textures, ocio_config, names=AR_MAPS, texels=texels)


def write_ar_usdz(staging: Path, stem: str, root: str, mesh, textures, names: dict, asset_name: str,
                  asset_version: str | None = None, creator: str | None = None, *, wrap: str = "repeat") -> Path:
    """Write ``<staging>/<stem>_ar.usdz`` from ``mesh`` (a :class:`usdbtf.mesh.Mesh`) and the
    textures of :func:`ar_textures` (``textures``, ``names``); returns its path."""
    import numpy as np
    from pxr import Kind, Sdf, Usd, UsdGeom, UsdShade, Vt

    from ...mesh.author import author_mesh
    from . import fallback
    from .layers import MATERIAL, make_usdz, stage_metadata, usd_write, valid_name

    work = staging / f".{stem}{AR_SUFFIX}"
    textures_rel = f"{stem}{AR_SUFFIX}_textures"
    textures.write(work / textures_rel)
    written = {name: textures.texture(file, textures_rel) for name, file in names.items()}
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
    # The box viewers frame the model by, from the geometry (as the full asset's root prim has).
    UsdGeom.ModelAPI.Apply(prim).SetExtentsHint(Vt.Vec3fArray.FromNumpy(mesh.bounds().astype(np.float32)))
    UsdGeom.Scope.Define(stage, f"/{root}/geo")
    UsdGeom.Scope.Define(stage, f"/{root}/mtl")
    material = UsdShade.Material.Define(stage, f"/{root}/mtl/{MATERIAL}")
    fallback.author_fallback(stage, material, written, wrap=wrap, specular_workflow=False)
    geom = author_mesh(stage, f"/{root}/geo/{valid_name(mesh.name)}", mesh)
    UsdShade.MaterialBindingAPI.Apply(geom).Bind(material)
    with usd_write(layer_path):
        stage.GetRootLayer().Save()
    del stage
    return make_usdz(layer_path, staging / f"{stem}{AR_SUFFIX}.usdz")
