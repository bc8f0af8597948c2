"""``usdbtf package``: a compressed BTF as a USD asset (USD asset structure guidelines).

Files written for ``-o out/pebbles.usda`` (or ``.usdc``)::

    out/pebbles.usda             root layer: /pebbles (Xform, kind component, defaultPrim),
                                 metersPerUnit 1, upAxis Y, assetInfo, extentsHint, the
                                 thumbnail (UsdMedia.AssetPreviewsAPI), the ``lod`` variant
                                 sets (usd.lod), and a payload arc to:
    out/pebbles_payload.usdc     the heavy part (``--payload-format usdc``, the default, or
                                 usda): geo/ (swatch quad at physical size, or the given mesh)
                                 and mtl/BtfMaterial (BtfMaterialAPI, the fitted
                                 UsdPreviewSurface fallback, the Storm preview), bound
    out/pebbles_textures/        basis, coeff/c000 ..., fallback/ (usd.fallback), gpu/
                                 (usd.storm), thumbnail.png
    out/pebbles.usdz             with --usdz: the same, packaged (variants and payload kept)
    out/pebbles_ar.usdz          with --usdz-ar: one usdc layer for AR viewers (usd.arkit)

Textures are re-encoded losslessly into formats every USD consumer reads (JPEG XL and
TIFF become PNG holding the same integer codes; PNG, JPEG and EXR are copied), or into
tiled, mip-mapped files with ``--texture-format`` (usd.textures); a reconstruction from the
asset equals one from the compressed folder bit for bit.  Every asset path is relative, and
so is the provenance (the source's path relative to the asset).  Everything is written into
a staging folder beside the asset, checked for non-finite numbers and with every
UsdValidation validator on every ``lod`` selection, and only then moved into place as one
:func:`usdbtf.atomic.atomic_group` (:func:`asset_pieces`: textures, payload, usdz files,
root layer last): a failure leaves the previous asset byte-identical, and a run killed
while moving the pieces in is finished by the next one.  Every layer carries
``customLayerData = {"usdbtf": {"output": "usdbtf-asset"}, ...}`` (usd.layers), so
``--force`` recognises a previous asset (and replaces nothing else).
"""
from __future__ import annotations

import csv
import hashlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_group
from ..compress.format import METADATA, CompressedBTF, read_compressed
from ..errors import BTFError, UsageError
from ..mesh import Mesh, load_mesh
from ..mesh.author import author_mesh
from ..outputs import ASSET, ASSET_TEXTURES
from ..render.core import default_wrap
from . import fallback, lod, storm, thumbnail
from .arkit import AR_SUFFIX
from .finite import non_finite_in_stage, non_finite_values
from .layers import MATERIAL, make_usdz, stage_metadata, usd_write
from .lod import FULL_LOD, default_lods
from .material import LOD_VARIANT_SET, author_btf
from .textures import TEXTURE_FORMATS, USDZ_FORMATS, TextureSet, package_textures
from .validate import validate_layer

__all__ = ["PackageOptions", "package", "asset_pieces", "make_usdz", "default_lods", "LOD_VARIANT_SET", "FULL_LOD",
           "MATERIAL", "ROOT_FORMATS", "PAYLOAD_FORMATS", "error_curve", "physical_size_of", "provenance_path"]

ROOT_FORMATS = (".usda", ".usdc", ".usd")
PAYLOAD_FORMATS = ("usdc", "usda")


@dataclass
class PackageOptions:
    """What ``usdbtf package`` writes besides the root layer.

    mesh : mesh with texture coordinates (OBJ/PLY/STL/GLB/USD); None for a swatch quad.
    usdz / usdz_ar : also write ``<stem>.usdz`` (everything, variants and payload kept) /
        ``<stem>_ar.usdz`` (one usdc layer for AR viewers, usd.arkit).
    lods : basis counts of the ``lod`` variants besides "full" (default :func:`default_lods`).
    physical_size : (width, height) in metres; default the source's ``physical_size_m``.
    payload_format : "usdc" (default) or "usda".
    texture_format : "png" (default), "tx" or "exr" (usd.textures).
    asset_name : assetInfo name (default the file stem); asset_version : assetInfo version
        (none unless given); creator : assetInfo and layer metadata (none unless given).
    thumbnail : render and declare a thumbnail (UsdMedia.AssetPreviewsAPI).
    validate : run every UsdValidation validator before publishing.
    """

    mesh: Path | None = None
    usdz: bool = False
    usdz_ar: bool = False
    lods: list | None = None
    physical_size: tuple | None = None
    payload_format: str = "usdc"
    texture_format: str = "png"
    asset_name: str | None = None
    asset_version: str | None = None
    creator: str | None = None
    thumbnail: bool = True
    validate: bool = True

    def check(self) -> None:
        """Raise UsageError for options that contradict each other or are out of range."""
        if self.payload_format not in PAYLOAD_FORMATS:
            raise UsageError(f"--payload-format {self.payload_format!r}: choose from {', '.join(PAYLOAD_FORMATS)}")
        if self.texture_format not in TEXTURE_FORMATS:
            raise UsageError(f"--texture-format {self.texture_format!r}: choose from {', '.join(TEXTURE_FORMATS)}")
        if self.usdz and self.texture_format not in USDZ_FORMATS:
            raise UsageError(f"--usdz cannot hold {self.texture_format} textures (the usdz spec allows PNG, JPEG, "
                             f"EXR): use --texture-format {' or '.join(USDZ_FORMATS)}")
        for flag, value in (("--asset-name", self.asset_name), ("--asset-version", self.asset_version),
                            ("--creator", self.creator)):
            if value is not None and (not value.strip() or any(ord(ch) < 32 for ch in value)):
                raise UsageError(f"{flag} {value!r}: must be non-empty text without control characters")


def error_curve(folder: Path, cbtf: CompressedBTF) -> list[tuple[int, float]]:
    """[(k, percent)] from the compressed folder's error_curve.csv (empty when absent)."""
    name = (cbtf.info.get("error_curve") or {}).get("file", "error_curve.csv")
    path = folder / name
    if not path.is_file():
        return []
    try:
        with path.open(newline="") as fh:
            return [(int(r["k"]), float(r["percent_error"])) for r in csv.DictReader(fh)]
    except (KeyError, ValueError) as exc:
        raise BTFError(f"{path}: unreadable error curve ({exc})") from None


def physical_size_of(cbtf: CompressedBTF) -> tuple[float, float] | None:
    size = (cbtf.info.get("source_metadata") or {}).get("physical_size_m")
    if size is None:
        return None
    try:
        w, h = (float(x) for x in size)
    except (TypeError, ValueError):
        raise BTFError(f"physical_size_m {size!r} is not [width, height] in metres") from None
    if not (w > 0 and h > 0 and np.isfinite([w, h]).all()):
        raise BTFError(f"physical_size_m {size!r} must be positive")
    return w, h


def provenance_path(source: str, asset_dir: Path) -> str:
    """``source`` (the path the compressed BTF records) as the asset should record it:
    relative to the asset's folder, never absolute.  A relative record is taken relative to
    the working directory (where compress ran, as far as anyone knows); a path that cannot
    be made relative (another drive) is recorded as ``sha256:<hash of the absolute path>``."""
    if not source:
        return ""
    absolute = Path(os.path.abspath(source))
    try:
        return Path(os.path.relpath(absolute, os.path.abspath(asset_dir))).as_posix()
    except ValueError:
        return "sha256:" + hashlib.sha256(str(absolute).encode()).hexdigest()


def _prim_name(stem: str) -> str:
    from pxr import Tf

    return Tf.MakeValidIdentifier(stem)


def _stage_metadata(layer, root: str, options: PackageOptions, what: str) -> None:
    stage_metadata(layer, root, asset_name=options.asset_name, what=what, creator=options.creator)


@dataclass
class _Written:
    """What the payload holds that the root layer needs."""

    coefficients: list
    storm: tuple | None
    extent: np.ndarray
    maps: object          # svbrdf.SvbrdfMaps, for the AR package


def _write_payload(path: Path, root: str, cbtf: CompressedBTF, compressed: Path, mesh: Mesh,
                   textures: TextureSet, options: PackageOptions, *, physical_size, curve, provenance: str,
                   white_level: float, log) -> _Written:
    from pxr import Kind, Usd, UsdGeom, UsdShade

    from ..svbrdf import fit_svbrdf

    with usd_write(path):
        stage = Usd.Stage.CreateNew(str(path))
    _stage_metadata(stage.GetRootLayer(), root, options, "payload")
    asset = UsdGeom.Xform.Define(stage, f"/{root}")
    Usd.ModelAPI(asset).SetKind(Kind.Tokens.component)
    UsdGeom.Scope.Define(stage, f"/{root}/geo")
    UsdGeom.Scope.Define(stage, f"/{root}/mtl")
    material = UsdShade.Material.Define(stage, f"/{root}/mtl/{MATERIAL}")
    basis, coeffs = package_textures(cbtf, compressed, textures)
    author_btf(material.GetPrim(), cbtf, basis.path, [c.path for c in coeffs], physical_size=physical_size,
               error_curve=curve, provenance_source=provenance)

    maps = fit_svbrdf(cbtf, white_level=white_level)
    log(f"fallback fitted: median roughness {float(np.median(maps.roughness)):.2f}, "
        f"{float(np.mean(maps.normal[..., 2] < 0.999)) * 100:.0f} % of texels with a normal")
    summary = {"diffuse": np.median(maps.diffuse.reshape(-1, 3), axis=0),
               "roughness": float(np.median(maps.roughness))}
    fallback.author_fallback(stage, material, fallback.write_maps(maps, textures, cbtf.ocio_config),
                             wrap=default_wrap(cbtf), summary=summary)
    gpu = storm.author_gpu_preview(stage, material, cbtf, textures)
    prim = author_mesh(stage, f"/{root}/geo/{_prim_name(mesh.name)}", mesh)
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)
    with usd_write(path):
        stage.GetRootLayer().Save()
    return _Written([c.path for c in coeffs], gpu, mesh.bounds(), maps)


def _write_root(path: Path, root: str, payload_name: str, written: _Written, levels: list[int],
                options: PackageOptions, thumbnail_path: str | None) -> None:
    from pxr import Kind, Sdf, Usd, UsdGeom, Vt

    with usd_write(path):
        stage = Usd.Stage.CreateNew(str(path))
    _stage_metadata(stage.GetRootLayer(), root, options, "root layer")
    prim = UsdGeom.Xform.Define(stage, f"/{root}").GetPrim()
    model = Usd.ModelAPI(prim)
    model.SetKind(Kind.Tokens.component)
    model.SetAssetName(options.asset_name)
    model.SetAssetIdentifier(Sdf.AssetPath(f"./{path.name}"))
    if options.asset_version is not None:
        model.SetAssetVersion(options.asset_version)
    if options.creator is not None:
        prim.SetAssetInfoByKey("creator", options.creator)
    prim.GetPayloads().AddPayload(f"./{payload_name}")
    # Bounds above the payload: an unloaded asset still has its box.
    UsdGeom.ModelAPI.Apply(prim).SetExtentsHint(Vt.Vec3fArray.FromNumpy(written.extent.astype(np.float32)))
    if thumbnail_path:
        thumbnail.declare_thumbnail(prim, thumbnail_path)
    lod.author_lod_variants(stage, f"/{root}", f"/{root}/mtl/{MATERIAL}", levels, written.coefficients,
                            written.storm)
    with usd_write(path):
        stage.GetRootLayer().Save()


def asset_pieces(out, *, usdz: bool = False, usdz_ar: bool = False,
                 payload_format: str = PackageOptions.payload_format) -> list[tuple[str, bool, str]]:
    """[(name, is_folder, output kind)] of the files ``package`` writes for root layer ``out``,
    in the order they are published (the root layer last).  The texture folder holds the
    thumbnail and every texture format's files (usdbtf.outputs recognises them)."""
    out = Path(out)
    stem = out.stem
    pieces = [(f"{stem}_textures", True, ASSET_TEXTURES), (f"{stem}_payload.{payload_format}", False, ASSET)]
    if usdz:
        pieces.append((f"{stem}.usdz", False, ASSET))
    if usdz_ar:
        pieces.append((f"{stem}{AR_SUFFIX}.usdz", False, ASSET))
    return pieces + [(out.name, False, ASSET)]


def _check_published(path: Path, shown: Path, validate: bool) -> None:
    """The publish gate for one staged layer or package: no non-finite numbers (in a usdz, in
    any layer it holds: the AR package's layer is nowhere else) and, when ``validate``, every
    UsdValidation validator on every ``lod`` selection.  BTFError naming ``shown``."""
    bad = non_finite_in_stage(path) if path.suffix == ".usdz" else non_finite_values(path)
    if bad:
        raise BTFError(f"{shown}: would hold non-finite numbers ({bad[0]}"
                       + (f" and {len(bad) - 1} more" if len(bad) > 1 else "") + "); not published")
    if validate:
        problems = validate_layer(path)
        if problems:
            raise BTFError(f"{shown}: fails USD validation: {problems[0]}"
                           + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""))


def _check_output(out: Path) -> None:
    if out.suffix not in ROOT_FORMATS:
        raise UsageError(f"{out}: the asset's root layer must be a {', '.join(ROOT_FORMATS)} file")


def package(compressed, out, options: PackageOptions | None = None, *, log=None, **overrides) -> dict:
    """Package the compressed BTF folder ``compressed`` as ``out`` (.usda/.usdc/.usd); returns
    a summary: the paths written ("root", "payload", "textures", "usdz", "usdz_ar"), "k",
    "lods" ([name, basis count] pairs), "validated".  ``options`` (or keyword overrides of
    its fields) as :class:`PackageOptions`."""
    from dataclasses import replace

    log = log or (lambda msg: None)
    options = replace(options or PackageOptions(), **overrides)
    options.check()
    compressed, out = Path(compressed), Path(out)
    _check_output(out)
    cbtf = read_compressed(compressed)
    size = options.physical_size or physical_size_of(cbtf)
    if size is None:
        raise BTFError(f"{compressed / METADATA}: no physical_size_m recorded; pass --physical-size W H (metres)")
    levels = sorted({int(n) for n in (default_lods(cbtf.k) if options.lods is None else options.lods)} - {cbtf.k},
                    reverse=True)
    bad = [n for n in levels if not 1 <= n < cbtf.k]
    if bad:
        raise UsageError(f"--lod {bad[0]} is outside 1..{cbtf.k} (the asset's k)")
    shape = load_mesh(options.mesh, need_uv=True).compacted().with_normals() if options.mesh else Mesh.swatch(*size)
    source_meta = cbtf.info.get("source_metadata") or {}
    white = float(source_meta.get("white_level", 1.0))
    if not (np.isfinite(white) and white > 0):
        raise BTFError(f"{compressed / METADATA}: white_level {white!r} must be a positive number")
    curve = error_curve(compressed, cbtf)

    stem, root = out.stem, _prim_name(out.stem)
    options = replace(options, asset_name=options.asset_name or stem)
    textures_rel, payload_name = f"{stem}_textures", f"{stem}_payload.{options.payload_format}"
    prov = provenance_path(str((cbtf.info.get("provenance") or {}).get("source") or cbtf.source.get("path") or ""),
                           out.parent)
    pieces = asset_pieces(out, usdz=options.usdz, usdz_ar=options.usdz_ar, payload_format=options.payload_format)
    with atomic_group(out.parent, pieces, what="asset") as staging:
        textures = TextureSet(staging / textures_rel, textures_rel, options.texture_format)
        textures.folder.mkdir(parents=True)
        written = _write_payload(staging / payload_name, root, cbtf, compressed, shape, textures, options,
                                 physical_size=size, curve=curve, provenance=prov, white_level=white, log=log)
        thumb = None
        if options.thumbnail:
            thumbnail.write_thumbnail(cbtf, shape, textures.folder / thumbnail.THUMBNAIL_FILE)
            thumb = f"./{textures_rel}/{thumbnail.THUMBNAIL_FILE}"
        _write_root(staging / out.name, root, payload_name, written, levels, options, thumb)
        names = [textures_rel, payload_name]
        if options.usdz:
            names.append(make_usdz(staging / out.name, staging / f"{stem}.usdz").name)
        if options.usdz_ar:
            from .arkit import make_ar_usdz

            names.append(make_ar_usdz(staging, stem, root, shape, written.maps, options.asset_name,
                                      options.asset_version, options.creator, cbtf.ocio_config,
                                      wrap=default_wrap(cbtf)).name)
        for name in names[1:] + [out.name]:
            _check_published(staging / name, out.parent / name, options.validate)
    extra = [n for n in names[2:]]
    log(f"packaged {compressed} (k = {cbtf.k}, LODs {[cbtf.k] + levels}) as {out}"
        + (f" and {', '.join(extra)}" if extra else ""))
    summary = {"root": out, "payload": out.parent / payload_name, "textures": out.parent / textures_rel,
               "k": cbtf.k, "lods": [[FULL_LOD, cbtf.k]] + [[lod.lod_name(n), n] for n in levels],
               "texture_format": options.texture_format, "validated": options.validate}
    if options.usdz:
        summary["usdz"] = out.parent / f"{stem}.usdz"
    if options.usdz_ar:
        summary["usdz_ar"] = out.parent / f"{stem}{AR_SUFFIX}.usdz"
    return summary
