"""``usdbtf package``: a compressed BTF as a USD asset (USD asset structure guidelines).

``package(compressed, PackageOptions) -> PackageResult`` does the work in memory: the
textures (the compressed BTF's files, portable; the fitted fallback maps; the Storm preview's
tables and packs; the thumbnail) are encoded into bytes the way ``compress`` encodes its own
(in-memory files), the mesh is read and the fallback fitted.  ``write_package(result, out)``
authors the layers, stages every file beside ``out``, validates them and publishes them as one
group.  A quilted folder's per-texel work (the fallback fit and maps, the GPU packs, the
thumbnail's texture) runs once per distinct source texel and is gathered through its position
map (:mod:`usdbtf.quilt.texels`): the same files as texel by texel.  Files written for
``out = out/pebbles.usda`` (or ``.usdc``)::

    out/pebbles.usda             root layer: /pebbles (Xform, kind component, defaultPrim),
                                 metersPerUnit 1, upAxis Y, assetInfo, extentsHint, the
                                 thumbnail (UsdMedia.AssetPreviewsAPI), the ``lod`` variant
                                 sets (usd.asset.lod), and a payload arc to:
    out/pebbles_payload.usdc     the heavy part (``--payload-format usdc``, the default, or
                                 usda): geo/ (swatch quad at physical size, or the given mesh)
                                 and mtl/BtfMaterial (BtfMaterialAPI, the fitted
                                 UsdPreviewSurface fallback, the Storm preview), bound
    out/pebbles_textures/        gpu/ (usd.asset.storm: the tables and coefficient pages, the asset's
                                 one copy of the BTF, which btf:basis and btf:coefficients
                                 name), fallback/ (usd.asset.fallback), thumbnail.png; for a
                                 sampling the preview cannot draw, basis and coeff/c000 ...
                                 instead of gpu/
    out/pebbles.usdz             with --usdz: the same, packaged (variants and payload kept)
    out/pebbles_ar.usdz          with --usdz-ar: one usdc layer for AR viewers (usd.asset.arkit)

Why the layers are authored by ``write_package`` and not held as anonymous layers: the names
in them (the root prim, ``<stem>_textures``, the relative provenance) follow ``out``, and
USD's crate (usdc) writer lays out a file in the order its specs were authored into a
file-backed layer, so authoring straight into the staged files keeps a given asset's bytes
what they have always been.  :func:`asset_layers` authors the same layers into anonymous,
in-memory ones (for inspection and tests).

The BTF is stored once (issue 39): its stored codes in the GPU tables and pages, read by
Storm, the MaterialX node, the OSL shader and ``load_btf`` alike (usd.material).  Textures
are re-encoded losslessly into formats every USD consumer reads (the pages: 8-bit PNG, 16-bit
codes and halves as OpenEXR; the files layout: JPEG XL and TIFF become PNG holding the same
integer codes; PNG, JPEG and EXR are copied), or into
tiled, mip-mapped files with ``--texture-format`` (usd.asset.textures; those are made from the
in-memory bytes while staging, as OIIO's maketx writes only files); a reconstruction from
the asset equals one from the compressed folder bit for bit.  Every asset path is relative,
and so is the provenance (the source's path relative to the asset).  Everything is written
into a staging folder beside the asset, checked for non-finite numbers and with every
UsdValidation validator on every ``lod`` selection, and only then moved into place as one
:func:`usdbtf.atomic.atomic_group` (:func:`asset_pieces`: textures, payload, usdz files,
root layer last): a failure leaves the previous asset byte-identical, and a run killed
while moving the pieces in is finished by the next one.  Every layer carries
``customLayerData = {"usdbtf": {"output": "usdbtf-asset"}, ...}`` (usd.asset.layers), so
``--force`` recognises a previous asset (and replaces nothing else).
"""
from __future__ import annotations

import csv
import hashlib
import logging
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ...atomic import atomic_group
from ...compress.codecs import get_codec
from ...compress.format import METADATA, CompressedBTF, EncodedTextures, basis_file, coefficient_file, read_compressed
from ...color import RENDERING_SPACE, linear_matrix, rendering_space
from ...errors import BTFError, UsageError
from ...mesh import Mesh, load_mesh
from ...mesh.author import author_mesh
from ...outputs import ASSET, ASSET_TEXTURES
from ...render.core import default_wrap
from ...svbrdf import SvbrdfMaps
from . import fallback, lod, storm, thumbnail
from . import openpbr as openpbr_fallback
from .arkit import AR_SUFFIX
from .fallback_count import BandFits, fit_bands, fit_fallbacks
from .finite import non_finite_in_stage, non_finite_values
from .layers import MATERIAL, make_usdz, stage_metadata, usd_write, valid_name
from .lod import FULL_LOD, default_lods
from ..material import FILES, GPU_PAGES, LOD_VARIANT_SET, author_btf
from .textures import TEXTURE_FORMATS, USDZ_FORMATS, TextureSet, package_textures
from .validate import validate_layer
from .formats import PAYLOAD_FORMATS
from ...numeric import single_blas_thread
from ...photometry import white_level_of
from ...resources import release_free_heap

__all__ = ["PackageOptions", "PackageResult", "package", "write_package", "asset_layers", "read_input",
           "asset_pieces", "check_root_layer", "make_usdz", "default_lods", "LOD_VARIANT_SET", "FULL_LOD",
           "MATERIAL", "ROOT_FORMATS", "PAYLOAD_FORMATS", "read_error_curve", "physical_size_of",
           "provenance_path", "rendering_matrix"]

ROOT_FORMATS = (".usda", ".usdc", ".usd")
log = logging.getLogger(__name__)


@dataclass
class PackageOptions:
    """What ``usdbtf package`` writes besides the root layer.

    mesh : mesh with texture coordinates (OBJ/PLY/STL/GLB/USD); None for a swatch quad.
    usdz / usdz_ar : also write ``<stem>.usdz`` (everything, variants and payload kept) /
        ``<stem>_ar.usdz`` (one usdc layer for AR viewers, usd.asset.arkit).
    lods : basis counts of the ``lod`` variants besides "full" (default :func:`default_lods`).
    physical_size : (width, height) in metres; default the source's ``physical_size_m``.
    payload_format : "usdc" (default) or "usda".
    texture_format : "png" (default), "tx" or "exr" (usd.asset.textures).
    asset_name : assetInfo name (default the file stem); asset_version : assetInfo version
        (none unless given); creator : assetInfo and layer metadata (none unless given).
    thumbnail : render and declare a thumbnail (UsdMedia.AssetPreviewsAPI).
    validate : run every UsdValidation validator before publishing.
    rendering_space : the scene-linear space the BTF shaders return (an OCIO name, alias or role,
        or a USD token such as ``lin_rec709_scene``; default :data:`usdbtf.color.RENDERING_SPACE`,
        linear Rec.709: what UsdPreviewSurface colours and Storm's and Blender's frames mean).
        The shaders apply OCIO's working -> rendering matrix after the stored colour matrix;
        the Material records it (``btf:renderingColorSpace``); the BTF data do not change.
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
    rendering_space: str = RENDERING_SPACE

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


@dataclass
class PackageResult:
    """A packaged BTF in memory, everything but the layers (which name the files they sit
    beside: :func:`write_package` authors them, :func:`asset_layers` in memory).

    compressed : the compressed BTF; options : the :class:`PackageOptions`; mesh : the geometry
    (the swatch quad or the loaded mesh, in metres); physical_size : (w, h) metres; levels :
    the ``lod`` basis counts below k (descending); curve : [(k, percent)] error curve;
    source : the provenance source as recorded (made relative to the asset when written).
    textures : the ``<stem>_textures`` folder's files (:class:`~usdbtf.usd.asset.textures.TextureSet`):
    ``basis``, ``coefficients`` (names of the BTF's textures), ``fallback`` ({map: name}),
    ``gpu`` (:class:`~usdbtf.usd.asset.storm.GpuTextures`, or None without a Storm preview),
    ``thumbnail`` (its name, or None).  maps : the fitted fallback (svbrdf.SvbrdfMaps).
    ar : (TextureSet, {map: name}) of the AR package with ``usdz_ar``, else None.
    input_name : what was packaged, for messages (the folder, or "compressed BTF").
    openpbr : the OpenPBR fallback's maps ({map: name}); openpbr_maps : its fit
    (usdbtf.openpbr.OpenPbrMaps, of a quilt's source texels); fit_errors : {fallback: percent}
    (:func:`usdbtf.usd.asset.openpbr.fit_errors`); svbrdf_fit : the UsdPreviewSurface fit
    (of a quilt's source texels; ``maps`` is it gathered onto the quilt).
    """

    compressed: CompressedBTF
    options: PackageOptions
    mesh: Mesh
    physical_size: tuple
    levels: list
    curve: list
    source: str
    textures: TextureSet
    basis: str
    coefficients: list
    fallback: dict
    gpu: storm.GpuTextures | None
    thumbnail: str | None
    maps: SvbrdfMaps
    ar: tuple | None = None
    input_name: str = "compressed BTF"
    openpbr: dict | None = None
    openpbr_maps: object = None
    fit_errors: dict | None = None
    svbrdf_fit: object = None


def read_error_curve(folder: Path, cbtf: CompressedBTF) -> list[tuple[int, float]]:
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


def read_input(folder) -> CompressedBTF:
    """The compressed BTF folder ``folder`` as :func:`package` takes it: its codes, the bytes of
    its texture files (``encoded``: the asset gets exact copies, not re-encodings) and its
    error curve (``curve``, from error_curve.csv)."""
    folder = Path(folder)
    cbtf = read_compressed(folder)
    codec = get_codec(cbtf.codec)
    enc = EncodedTextures(cbtf.codec, (folder / basis_file(codec)).read_bytes(),
                          tuple((folder / coefficient_file(codec, i)).read_bytes() for i in range(cbtf.k)),
                          (cbtf.basis.pixels, *(st.pixels for st in cbtf.coefficients)))
    curve = read_error_curve(folder, cbtf)
    return replace(cbtf, encoded=enc, curve={"k": [k for k, _ in curve], "percent": [p for _, p in curve]})


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


def budget_of(cbtf: CompressedBTF) -> int | None:
    """The ``--max-bytes`` budget ``compress`` recorded for ``cbtf`` (None without one)."""
    options = (cbtf.info.get("provenance") or {}).get("options") or {}
    value = options.get("max_bytes")
    return int(value) if isinstance(value, (int, float)) and value > 0 else None


def budget_for_of(cbtf: CompressedBTF) -> str:
    """What ``cbtf``'s recorded budget counted: "asset" or "folder" (``compress --budget-for``;
    a folder from before issue 39, which records none, budgeted the folder)."""
    options = (cbtf.info.get("provenance") or {}).get("options") or {}
    return str(options.get("budget_for") or "folder")


def shipped_bytes(root) -> dict:
    """{lod name: bytes of every file that ``lod`` loads} of the written asset ``root``
    (:func:`usdbtf.usd.asset.inspect.lod_files`: its layers, thumbnail, the BTF's textures and
    what its shader networks read), largest first."""
    return {lv["name"] or FULL_LOD: lv["total"] for lv in shipped_levels(root, shares=False)}


def shipped_levels(root, budget: int | None = None, *, shares: bool = True) -> list[dict]:
    """:func:`usdbtf.usd.asset.inspect.lod_files` of the written asset ``root``: per ``lod``, the
    files it loads, their total and (with ``shares``) its share of ``budget`` (default the full
    lod's bytes; else None)."""
    from .inspect import lod_files
    from ..read import find_material, open_stage

    stage = open_stage(root)
    return lod_files(stage, find_material(stage), budget, shares=shares)


def asset_overhead(cbtf: CompressedBTF, fallback_fits: tuple | None = None) -> dict:
    """What packaging ``cbtf`` ships beside its coefficients and basis codes: the bytes a
    ``--max-bytes`` budget of the asset (``compress --budget-for asset``, issue 39) must keep
    for them, measured by packaging ``cbtf`` for real (this module's :func:`package` and
    :func:`write_package` into a temporary folder, no validation) and counting what its full
    ``lod`` loads (:func:`shipped_bytes`).

    ``cbtf`` : a quantised (or encoded) compressed BTF near the budget's choice; without a
    recorded physical size a 1 m swatch is packaged (the size changes no texture).
    ``fallback_fits`` : the "fallback_fits" of an earlier call on the same material (another
    k): its fallback fits are reused instead of fitted again (:func:`package`'s ``fallback_fits``).  The
    fits are most of a packaging's time (issue 42: 39 of 43 s, metal_flakes 64², paper
    sampling) and their maps' bytes barely move with k, which is all this count needs.  An
    image of 64 texel rows or more is fitted on half of them (:mod:`.fallback_count`: bands of
    16 rows in every 32) and its fallback maps' bytes scaled by the rows left out.

    Returns
    -------
    dict : "full" (bytes the full lod loads), "pages" (bytes of its coefficient files: GPU pages,
    or coefficient files and basis image when the sampling has no GPU preview), "paged" (GPU
    pages were written), "overhead" (full - pages: tables, fallback maps, thumbnail, MaterialX,
    layers; with pages the basis page, or the tables' basis block, is still in it), "k", "fallback_fits" (the
    fallback fits used, to pass to a later call).
    """
    import tempfile

    from ...compress.curve import curve_ks

    size = physical_size_of(cbtf) or (1.0, 1.0)
    if not cbtf.curve:
        # The error curve compress writes after rate control: its 48 points are in the layers.
        ks = curve_ks(cbtf.k)
        cbtf = replace(cbtf, curve={"k": [int(k) for k in ks], "percent": [float(30.0 / np.sqrt(k)) for k in ks]})
    quiet = logging.getLogger("usdbtf")
    level = quiet.level
    quiet.setLevel(max(level, logging.WARNING))      # the probe's own "packaged ..." lines are noise here
    try:
        bands = fallback_fits
        if bands is None:
            bands = fit_bands(cbtf, white_level_of(cbtf.info, "compressed BTF: source_metadata.white_level"))
            release_free_heap()    # the fit threads' freed heaps, before the package peaks on top of them
        fits = bands.fits if isinstance(bands, BandFits) else fallback_fits
        result = package(cbtf, PackageOptions(physical_size=size, validate=False), fallback_fits=fits)
        with tempfile.TemporaryDirectory(prefix="usdbtf-overhead-") as tmp:
            summary = write_package(result, Path(tmp) / "probe.usda")
            full = int(summary["bytes"][FULL_LOD])
            paged = result.gpu is not None
            # The coefficient files: without the basis page listed after the GPU pages (schema
            # 4), whose bytes stay in the overhead as the tables' basis block did before.
            names = (set(result.gpu.pages) if paged else set(result.coefficients) | {result.basis})
            folder = Path(summary["textures"])
            pages = int(sum((folder / n).stat().st_size for n in names))
            if isinstance(bands, BandFits):
                # The maps of half the rows, as shipped: the rest of the rows' bytes added.
                maps = {*result.fallback.values(), *(result.openpbr or {}).values()}
                full += round(sum((folder / n).stat().st_size for n in maps) * (bands.scale - 1.0))
    finally:
        quiet.setLevel(level)
    if not isinstance(bands, BandFits):
        bands = (result.svbrdf_fit, result.openpbr_maps, result.fit_errors)
    # The package (its textures' bytes, GPU pages, thumbnail) is only counted: drop it and hand
    # what its threads freed back to the system, else compress's next step (another packaging,
    # the encode, the evaluation) peaks on top of it (issue 42; :func:`release_free_heap`).
    del result
    release_free_heap()
    return {"full": full, "pages": pages, "paged": paged, "overhead": full - pages, "k": cbtf.k,
            "fallback_fits": bands}


def check_root_layer(out) -> None:
    """UsageError unless ``out`` names a root layer :data:`ROOT_FORMATS` allows."""
    out = Path(out)
    if out.suffix not in ROOT_FORMATS:
        raise UsageError(f"{out}: the asset's root layer must be a {', '.join(ROOT_FORMATS)} file")


@single_blas_thread
def package(compressed, options: PackageOptions | None = None, *,
            fallback_fits: tuple | None = None) -> PackageResult:
    """Package ``compressed`` -- a compressed BTF folder (read by :func:`read_input`) or a
    :class:`CompressedBTF` (its ``encoded`` bytes and ``curve`` are used when it has them, e.g.
    straight from ``compress``) -- in memory (module docstring); :func:`write_package` writes it.
    UsageError for options that do not fit, BTFError for bad data.

    ``fallback_fits`` : (UsdPreviewSurface fit, OpenPBR fit, fit errors) of the same material's
    texels to use instead of fitting them (compress's rate control packages several k of one
    material only to count bytes: :func:`asset_overhead`); None fits them here."""
    options = options or PackageOptions()
    options.check()
    name = where = "compressed BTF"
    folder = None
    if not isinstance(compressed, CompressedBTF):
        folder = Path(compressed)
        name, where = str(folder), str(folder / METADATA)
        compressed = read_input(folder)
    cbtf = compressed
    rendering_matrix(cbtf, options)          # refuse a space OCIO cannot reach by a matrix, before any work
    size = options.physical_size or physical_size_of(cbtf)
    if size is None:
        raise BTFError(f"{where}: no physical_size_m recorded; pass --physical-size W H (metres)")
    levels = sorted({int(n) for n in (default_lods(cbtf.k) if options.lods is None else options.lods)} - {cbtf.k},
                    reverse=True)
    bad = [n for n in levels if not 1 <= n < cbtf.k]
    if bad:
        raise UsageError(f"--lod {bad[0]} is outside 1..{cbtf.k} (the asset's k)")
    shape = load_mesh(options.mesh, need_uv=True).compacted().with_normals() if options.mesh else Mesh.swatch(*size)
    white = white_level_of(cbtf.info, f"{where}: source_metadata.white_level")
    curve = list(zip(cbtf.curve["k"], cbtf.curve["percent"])) if cbtf.curve else []
    source = str((cbtf.info.get("provenance") or {}).get("source") or cbtf.source.get("path") or "")

    from ...quilt.texels import quilt_texels

    textures = TextureSet(options.texture_format)
    # Per-texel work (the fallback fit, the GPU packs, the thumbnail's texture) on a quilt
    # runs once per distinct source texel and is gathered through the position map.
    texels = quilt_texels(cbtf, folder)
    # One copy of the BTF: the GPU tables and pages, which every consumer reads, where the
    # preview can draw the sampling; else one file per coefficient and a basis image.
    gpu = storm.add_gpu_textures(cbtf, textures, levels, texels=texels,
                                 rendering_matrix=rendering_matrix(cbtf, options)[1])
    if gpu is not None:
        # Schema 4: the basis page (integer codes) listed after the coefficient pages.
        basis, coefficients = gpu.tables, list(gpu.pages) + ([gpu.basis] if gpu.basis else [])
    else:
        basis, coefficients = package_textures(cbtf, textures)
    if fallback_fits is None:
        fallback_fits = fit_fallbacks(cbtf if texels is None else texels.compact, white,
                                      None if texels is None else texels.multiplicity())
        log.info(f"fallbacks against the BTF at held-out samples: UsdPreviewSurface "
                 f"{fallback_fits[2]['preview_surface']:.2f} %, OpenPBR {fallback_fits[2]['open_pbr']:.2f} %")
    fitted, op_fitted, errors = fallback_fits
    maps_added = fallback.add_maps(fitted, textures, cbtf.ocio_config, texels=texels)
    op_added = openpbr_fallback.add_maps(op_fitted, textures, cbtf.ocio_config, texels=texels)
    thumb = None
    if options.thumbnail:
        thumb = textures.add_file(thumbnail.THUMBNAIL_FILE, thumbnail.thumbnail_jpeg(cbtf, shape, texels=texels))
    # The quilt-sized maps after the thumbnail, whose mip levels are the other large arrays.
    maps = fitted if texels is None else fitted.gathered(texels.gather)
    log.info(f"fallback fitted: median roughness {float(np.median(maps.roughness)):.2f}, "
             f"{float(np.mean(maps.normal[..., 2] < 0.999)) * 100:.0f} % of texels with a normal"
             + ("" if texels is None else f" (once per source texel: {texels.compact.width} of them)"))
    ar = None
    if options.usdz_ar:
        from .arkit import ar_textures

        ar = ar_textures(fitted, cbtf.ocio_config, texels)
    return PackageResult(cbtf, options, shape, tuple(size), levels, curve, source, textures, basis, coefficients,
                         maps_added, gpu, thumb, maps, ar, name, op_added, op_fitted, errors, fitted)


@dataclass
class _Names:
    """The names an asset written as ``out`` uses: the root prim, the texture folder and the
    payload (relative to ``out``'s folder), and the asset name."""

    stem: str
    root: str
    textures: str
    payload: str
    asset_name: str

    @classmethod
    def of(cls, out: Path, result: PackageResult) -> "_Names":
        o = result.options
        return cls(out.stem, valid_name(out.stem), f"{out.stem}_textures", f"{out.stem}_payload.{o.payload_format}",
                   o.asset_name or out.stem)


def _stage_metadata(layer, names: _Names, options: PackageOptions, what: str) -> None:
    stage_metadata(layer, names.root, asset_name=names.asset_name, what=what, creator=options.creator)


def _author_payload(stage, result: PackageResult, names: _Names, provenance: str) -> tuple[list, tuple | None]:
    """The payload layer's content on ``stage`` (its root layer): the geometry and the bound
    BTF material with its fallback and Storm preview.  Returns (the coefficient asset paths,
    the Storm tuple for :func:`usdbtf.usd.asset.lod.author_lod_variants`)."""
    from pxr import Kind, Usd, UsdGeom, UsdShade

    cbtf, textures = result.compressed, result.textures
    _stage_metadata(stage.GetRootLayer(), names, result.options, "payload")
    asset = UsdGeom.Xform.Define(stage, f"/{names.root}")
    Usd.ModelAPI(asset).SetKind(Kind.Tokens.component)
    UsdGeom.Scope.Define(stage, f"/{names.root}/geo")
    UsdGeom.Scope.Define(stage, f"/{names.root}/mtl")
    material = UsdShade.Material.Define(stage, f"/{names.root}/mtl/{MATERIAL}")
    coefficients = [textures.texture(name, names.textures).path for name in result.coefficients]
    author_btf(material.GetPrim(), cbtf, textures.texture(result.basis, names.textures).path, coefficients,
               physical_size=result.physical_size, error_curve=result.curve, provenance_source=provenance,
               layout=FILES if result.gpu is None else GPU_PAGES)
    maps = result.maps
    summary = {"diffuse": np.median(maps.diffuse.reshape(-1, 3), axis=0),
               "roughness": float(np.median(maps.roughness))}
    wrap = default_wrap(cbtf)
    fallback.author_fallback(stage, material, {m: textures.texture(name, names.textures)
                                               for m, name in result.fallback.items()},
                             wrap=wrap, summary=summary)
    if result.openpbr:
        openpbr_fallback.author_openpbr(stage, material, {m: textures.texture(name, names.textures)
                                                          for m, name in result.openpbr.items()},
                                        wrap=wrap, fit_errors=result.fit_errors)
    gpu = None
    if result.gpu is not None:
        from pxr import Sdf

        g = result.gpu
        space, matrix = rendering_matrix(cbtf, result.options)
        gpu = storm.author_gpu_preview(stage, material, textures.texture(g.tables, names.textures),
                                       [p and textures.texture(p, names.textures) for p in g.slots()], g.k, wrap,
                                       g.first_packs, white_level_of(cbtf.info), matrix)
        # Issue 40: the space the BTF shaders return (the data stay in btf:colorSpace).
        material.GetPrim().CreateAttribute("btf:renderingColorSpace", Sdf.ValueTypeNames.String, custom=False,
                                           variability=Sdf.VariabilityUniform).Set(space)
    prim = author_mesh(stage, f"/{names.root}/geo/{valid_name(result.mesh.name)}", result.mesh)
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)
    return coefficients, gpu


def rendering_matrix(cbtf: CompressedBTF, options: PackageOptions) -> tuple[str, np.ndarray]:
    """(OCIO name of ``options.rendering_space``, (3, 3) float64 matrix from ``cbtf``'s working
    space to it: :func:`usdbtf.color.linear_matrix` in the BTF's OCIO config).  UsageError
    naming ``--rendering-space`` for a space that is unknown or not a matrix away."""
    try:
        name = rendering_space(options.rendering_space, cbtf.ocio_config)
        return name, linear_matrix(cbtf.working_space, name, cbtf.ocio_config)
    except UsageError:
        raise
    except BTFError as exc:
        raise UsageError(f"--rendering-space {options.rendering_space!r}: {exc}") from None


def _author_root(stage, result: PackageResult, names: _Names, root_name: str, coefficients: list,
                 gpu: tuple | None, payload: str | None = None) -> None:
    """The root layer's content on ``stage``: the asset prim, its metadata and bounds, the
    thumbnail, the payload arc and the ``lod`` variant sets (``root_name``: the layer's file;
    ``payload``: the arc's asset path, default the payload file beside it).  The payload must
    resolve: the variants' overrides of its prims are authored against what it defines."""
    from pxr import Kind, Sdf, Usd, UsdGeom, Vt

    options = result.options
    _stage_metadata(stage.GetRootLayer(), names, options, "root layer")
    prim = UsdGeom.Xform.Define(stage, f"/{names.root}").GetPrim()
    model = Usd.ModelAPI(prim)
    model.SetKind(Kind.Tokens.component)
    model.SetAssetName(names.asset_name)
    model.SetAssetIdentifier(Sdf.AssetPath(f"./{root_name}"))
    if options.asset_version is not None:
        model.SetAssetVersion(options.asset_version)
    if options.creator is not None:
        prim.SetAssetInfoByKey("creator", options.creator)
    prim.GetPayloads().AddPayload(payload or f"./{names.payload}")
    # Bounds above the payload: an unloaded asset still has its box.
    UsdGeom.ModelAPI.Apply(prim).SetExtentsHint(Vt.Vec3fArray.FromNumpy(result.mesh.bounds().astype(np.float32)))
    if result.thumbnail:
        thumbnail.declare_thumbnail(prim, f"./{names.textures}/{result.thumbnail}")
    lod_tables = None if result.gpu is None else {
        n: result.textures.texture(name, names.textures).path for n, name in result.gpu.lod_tables.items()}
    lod_basis = None if result.gpu is None else {
        n: result.textures.texture(name, names.textures).path for n, name in result.gpu.lod_basis.items()}
    lod.author_lod_variants(stage, f"/{names.root}", f"/{names.root}/mtl/{MATERIAL}", result.levels, coefficients,
                            gpu, paged=result.gpu is not None, tables=lod_tables, basis_pages=lod_basis)


def _authored(path: Path, author):
    """A new layer file at ``path`` with ``author(stage)``'s content, saved; returns what
    ``author`` returned."""
    from pxr import Usd

    with usd_write(path):
        stage = Usd.Stage.CreateNew(str(path))
    made = author(stage)
    with usd_write(path):
        stage.GetRootLayer().Save()
    return made


def asset_layers(result: PackageResult, out) -> dict:
    """{file name: Sdf.Layer} of the root layer and the payload :func:`write_package` would write
    as ``out``, authored into anonymous, in-memory layers (no file is made)."""
    from pxr import Sdf, Usd

    out = Path(out)
    names = _Names.of(out, result)
    provenance = provenance_path(result.source, out.parent)
    payload = Sdf.Layer.CreateAnonymous(names.payload)
    coefficients, gpu = _author_payload(Usd.Stage.Open(payload), result, names, provenance)
    root = Sdf.Layer.CreateAnonymous(out.name)
    # The arc points at the in-memory payload while the root is authored (see _author_root),
    # then at the payload's file name, as the written root layer has it.
    _author_root(Usd.Stage.Open(root), result, names, out.name, coefficients, gpu, payload=payload.identifier)
    root.GetPrimAtPath(f"/{names.root}").payloadList.prependedItems = [Sdf.Payload(f"./{names.payload}")]
    return {out.name: root, names.payload: payload}


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


def write_package(result: PackageResult, out) -> dict:
    """Write ``result`` as the asset ``out`` (.usda/.usdc/.usd): every piece staged beside it,
    checked and published together (module docstring).  Returns a summary: the paths written
    ("root", "payload", "textures", "usdz", "usdz_ar"), "k", "lods" ([name, basis count]
    pairs), "texture_format", "validated"."""
    out = Path(out)
    check_root_layer(out)
    options, cbtf = result.options, result.compressed
    names = _Names.of(out, result)
    provenance = provenance_path(result.source, out.parent)
    pieces = asset_pieces(out, usdz=options.usdz, usdz_ar=options.usdz_ar, payload_format=options.payload_format)
    with atomic_group(out.parent, pieces, what="asset") as staging:
        result.textures.write(staging / names.textures)
        coefficients, gpu = _authored(staging / names.payload,
                                      lambda stage: _author_payload(stage, result, names, provenance))
        _authored(staging / out.name, lambda stage: _author_root(stage, result, names, out.name, coefficients, gpu))
        published = [names.textures, names.payload]
        if options.usdz:
            published.append(make_usdz(staging / out.name, staging / f"{names.stem}.usdz").name)
        if options.usdz_ar:
            from .arkit import write_ar_usdz

            ar_set, ar_names = result.ar
            published.append(write_ar_usdz(staging, names.stem, names.root, result.mesh, ar_set, ar_names,
                                           names.asset_name, options.asset_version, options.creator,
                                           wrap=default_wrap(cbtf)).name)
        for name in published[1:] + [out.name]:
            _check_published(staging / name, out.parent / name, options.validate)
    extra = published[2:]
    log.info(f"packaged {result.input_name} (k = {cbtf.k}, LODs {[cbtf.k] + result.levels}) as {out}"
             + (f" and {', '.join(extra)}" if extra else ""))
    budget = budget_of(cbtf)
    # The shares re-encode basis blocks (about 2 s at paper scale): with the publish checks
    # only, not in asset_overhead's probe, which skips them.
    levels = shipped_levels(out, budget, shares=options.validate)
    shipped = {lv["name"] or FULL_LOD: lv["total"] for lv in levels}
    shares = {lv["name"] or FULL_LOD: lv["share"] for lv in levels}
    log.info(f"the asset's bytes (every file the full lod loads): {shipped[FULL_LOD]:,}"
             + ("" if budget is None else f", {shipped[FULL_LOD] / budget:.3f} of the --max-bytes budget of {budget:,}")
             + "".join(f"; {name} {n:,}" + ("" if shares[name] is None else f" (share {shares[name]:,})")
                       for name, n in shipped.items() if name != FULL_LOD))
    if budget is not None and budget_for_of(cbtf) != "asset":
        log.warning(f"{result.input_name}: its --max-bytes {budget:,} budgeted the compressed folder's textures, "
                    f"not this asset ({shipped[FULL_LOD] / budget:.2f}x it); compress with --budget-for asset "
                    f"to budget what is shipped")
    summary = {"root": out, "payload": out.parent / names.payload, "textures": out.parent / names.textures,
               "k": cbtf.k, "lods": [[FULL_LOD, cbtf.k]] + [[lod.lod_name(n), n] for n in result.levels],
               "texture_format": options.texture_format, "validated": options.validate,
               "bytes": shipped, "max_bytes": budget, "shares": shares}
    if options.usdz:
        summary["usdz"] = out.parent / f"{names.stem}.usdz"
    if options.usdz_ar:
        summary["usdz_ar"] = out.parent / f"{names.stem}{AR_SUFFIX}.usdz"
    return summary
