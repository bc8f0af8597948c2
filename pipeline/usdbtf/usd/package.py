"""``usdbtf package``: a compressed BTF as a USD asset (USD asset structure guidelines).

Files written for ``-o out/pebbles.usda``::

    out/pebbles.usda             root layer: /pebbles (Xform, kind component, defaultPrim),
                                 metersPerUnit 1, upAxis Y, assetInfo, the ``lod`` variant
                                 set, and a payload arc to:
    out/pebbles_payload.usda     the heavy part: geo/ (swatch quad at physical size, or the
                                 given mesh) and mtl/BtfMaterial (BtfMaterialAPI, the preview
                                 network), bound with MaterialBindingAPI
    out/pebbles_textures/        basis.png|exr, coeff/c000.png ..., preview_albedo.png
    out/pebbles.usdz             with --usdz: the same, packaged (variants and payload kept)

Textures are re-encoded losslessly into formats every USD consumer reads (JPEG XL and
TIFF become PNG holding the same integer codes; PNG, JPEG and EXR are copied), so a
reconstruction from the asset equals one from the compressed folder bit for bit.
Every asset path is relative.  Everything is written into a staging folder beside the
asset, checked with every UsdValidation validator and for non-finite numbers, and only
then moved into place as one :func:`usdbtf.atomic.atomic_group` (textures, payload,
usdz, root layer last): a failure leaves the previous asset byte-identical, and a run
killed while moving the pieces in is finished by the next one.  Every layer carries
``customLayerData = {"usdbtf": {"output": "usdbtf-asset"}}``, so ``--force`` recognises
a previous asset (and replaces nothing else).
"""
from __future__ import annotations

import contextlib
import csv
import shutil
from pathlib import Path

import numpy as np

from .. import __version__
from ..atomic import atomic_group
from ..colour import processor
from ..compress.codecs import Codec
from ..compress.format import METADATA, CompressedBTF, basis_file, coefficient_file, read_compressed
from ..errors import BTFError, UsageError
from ..imageio import write_image
from ..mesh import Mesh, load_mesh
from ..mesh.author import author_mesh
from . import preview, storm  # storm: issue 7 (Hydra preview)
from .lods import default_lods
from ..outputs import ASSET, ASSET_TEXTURES, usd_marker
from .material import LOD_VARIANT_SET, author_btf
from .finite import non_finite_values
from .validate import validate_layer

MATERIAL = "BtfMaterial"
FULL_LOD = "full"
#: Extensions every USD consumer (and the usdz spec) reads; others are re-encoded.
_PORTABLE = {".png", ".jpg", ".jpeg", ".exr"}


def _portable_copy(src: Path, dst_no_ext: Path) -> str:
    """Copy ``src`` (PNG/JPEG/EXR) or re-encode it as PNG (same integer codes); returns the new suffix."""
    suffix = src.suffix.lower()
    if suffix in _PORTABLE:
        dst = dst_no_ext.with_suffix(suffix)
        shutil.copyfile(src, dst)
        return suffix
    pixels = Codec.read(src)
    if pixels.dtype not in (np.uint8, np.uint16):
        raise BTFError(f"{src}: cannot re-encode {pixels.dtype} texture as PNG")
    write_image(dst_no_ext.with_suffix(".png"), pixels, color_space="data", attributes={"png:compressionLevel": 6})
    return ".png"


def package_textures(cbtf: CompressedBTF, src: Path, dst: Path) -> tuple[str, list[str]]:
    """Copy/re-encode the basis and the k coefficient textures from the compressed folder
    ``src`` into ``dst``.  Returns their paths relative to ``dst``."""
    from ..compress.codecs import get_codec

    codec = get_codec(cbtf.codec)
    (dst / "coeff").mkdir(parents=True, exist_ok=True)
    basis_src = src / basis_file(codec)
    basis = "basis" + _portable_copy(basis_src, dst / "basis")
    coeffs = []
    for i in range(cbtf.k):
        rel = Path(coefficient_file(codec, i))
        coeffs.append(str(rel.with_suffix(_portable_copy(src / rel, dst / rel.with_suffix("")))))
    return basis, coeffs


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


def _prim_name(stem: str) -> str:
    from pxr import Tf

    return Tf.MakeValidIdentifier(stem)


def _stage_metadata(layer, root: str) -> None:
    from pxr import UsdGeom

    layer.defaultPrim = root
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.metersPerUnit, 1.0)
    layer.pseudoRoot.SetInfo(UsdGeom.Tokens.upAxis, UsdGeom.Tokens.y)


def _author_preview(stage, material, textures_rel: str, roughness: float) -> None:
    """UsdPreviewSurface network: albedo texture (sRGB PNG) + fitted roughness."""
    from pxr import Sdf, Usd, UsdShade

    mpath = material.GetPath()
    reader = UsdShade.Shader.Define(stage, mpath.AppendChild("StReader"))
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    tex = UsdShade.Shader.Define(stage, mpath.AppendChild("AlbedoTexture"))
    tex.CreateIdAttr("UsdUVTexture")
    file_input = tex.CreateInput("file", Sdf.ValueTypeNames.Asset)
    file_input.Set(Sdf.AssetPath(f"./{textures_rel}/preview_albedo.png"))
    file_input.GetAttr().SetColorSpace("srgb_rec709_scene")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface = UsdShade.Shader.Define(stage, mpath.AppendChild("PreviewSurface"))
    surface.CreateIdAttr("UsdPreviewSurface")
    Usd.ColorSpaceAPI.Apply(surface.GetPrim()).CreateColorSpaceNameAttr("lin_rec709_scene")
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    surface.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(roughness))
    surface.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(0.0)
    surface.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")


def _write_albedo(cbtf: CompressedBTF, path: Path, white_level: float) -> None:
    albedo = preview.mean_albedo(cbtf, white_level=white_level)
    srgb = processor(cbtf.working_space, preview.ALBEDO_SPACE, cbtf.ocio_config).apply(albedo)
    write_image(path, (np.clip(srgb, 0, 1) * 255 + 0.5).astype(np.uint8), color_space=preview.ALBEDO_SPACE)


@contextlib.contextmanager
def _usd_write(path: Path):
    """USD's write failures (Tf errors) as usdbtf errors naming ``path``: an operating-system
    problem (disk full, permission) is an IOFailure, anything else bad data."""
    from pxr import Tf

    from ..errors import OS_ERROR_WORDS, IOFailure
    from ..usdstage import tf_message

    try:
        yield
    except Tf.ErrorException as exc:
        text = tf_message(exc)
        cls = IOFailure if any(w in text for w in OS_ERROR_WORDS) else BTFError
        raise cls(f"{path}: cannot write the USD layer ({text})") from None


def _write_payload(path: Path, root: str, cbtf: CompressedBTF, mesh: Mesh, textures_rel: str,
                   basis: str, coeffs: list[str], *, physical_size, curve, roughness: float) -> None:
    from pxr import Kind, Usd, UsdGeom, UsdShade

    with _usd_write(path):
        stage = Usd.Stage.CreateNew(str(path))
    _stage_metadata(stage.GetRootLayer(), root)
    asset = UsdGeom.Xform.Define(stage, f"/{root}")
    Usd.ModelAPI(asset).SetKind(Kind.Tokens.component)
    UsdGeom.Scope.Define(stage, f"/{root}/geo")
    UsdGeom.Scope.Define(stage, f"/{root}/mtl")
    material = UsdShade.Material.Define(stage, f"/{root}/mtl/{MATERIAL}")
    author_btf(material.GetPrim(), cbtf, f"./{textures_rel}/{basis}", [f"./{textures_rel}/{c}" for c in coeffs],
               physical_size=physical_size, error_curve=curve)
    _author_preview(stage, material, textures_rel, roughness)
    # Issue 7 hook: Storm glslfx preview (render context "glslfx") + GPU textures in <textures>/gpu/.
    storm.author_gpu_preview(stage, material, cbtf, path.parent / textures_rel, textures_rel)
    prim = author_mesh(stage, f"/{root}/geo/{_prim_name(mesh.name)}", mesh)
    UsdShade.MaterialBindingAPI.Apply(prim).Bind(material)
    stage.GetRootLayer().customLayerData = usd_marker()
    with _usd_write(path):
        stage.GetRootLayer().Save()


def _write_root(path: Path, root: str, payload_name: str, coeffs_abs: list[str], levels: list[int], k: int) -> None:
    from pxr import Kind, Sdf, Usd, UsdGeom

    with _usd_write(path):
        stage = Usd.Stage.CreateNew(str(path))
    _stage_metadata(stage.GetRootLayer(), root)
    prim = UsdGeom.Xform.Define(stage, f"/{root}").GetPrim()
    Usd.ModelAPI(prim).SetKind(Kind.Tokens.component)
    model = Usd.ModelAPI(prim)
    model.SetAssetName(root)
    model.SetAssetIdentifier(Sdf.AssetPath(f"./{path.name}"))
    model.SetAssetVersion(__version__)
    prim.GetPayloads().AddPayload(f"./{payload_name}")
    # The variant set lives on the root prim, outside the payload, so a consumer can pick
    # a level of detail before (or without) loading it.  Coefficients are energy-ordered:
    # a level is the first n textures of the same files.
    vset = prim.GetVariantSets().AddVariantSet(LOD_VARIANT_SET)
    for name in [FULL_LOD] + [f"k{n}" for n in levels]:
        vset.AddVariant(name)
    for n in levels:
        vset.SetVariantSelection(f"k{n}")
        with vset.GetVariantEditContext():
            mat = stage.OverridePrim(f"/{root}/mtl/{MATERIAL}")
            mat.CreateAttribute("btf:basisCount", Sdf.ValueTypeNames.Int, custom=False, variability=Sdf.VariabilityUniform).Set(n)
            mat.CreateAttribute("btf:coefficients", Sdf.ValueTypeNames.AssetArray, custom=False,
                                variability=Sdf.VariabilityUniform).Set(
                Sdf.AssetPathArray([Sdf.AssetPath(p) for p in coeffs_abs[:n]]))
    vset.SetVariantSelection(FULL_LOD)
    stage.GetRootLayer().customLayerData = usd_marker()
    with _usd_write(path):
        stage.GetRootLayer().Save()


def asset_pieces(out, *, usdz: bool = False) -> list[tuple[str, bool, str]]:
    """[(name, is_folder, output kind)] of the files ``package`` writes for root layer ``out``,
    in the order they are published (the root layer last)."""
    out = Path(out)
    stem = out.stem
    pieces = [(f"{stem}_textures", True, ASSET_TEXTURES), (f"{stem}_payload.usda", False, ASSET)]
    if usdz:
        pieces.append((f"{stem}.usdz", False, ASSET))
    return pieces + [(out.name, False, ASSET)]


def package(compressed, out, *, mesh=None, usdz: bool = False, lods: list[int] | None = None,
            physical_size: tuple[float, float] | None = None, validate: bool = True, log=None) -> dict:
    """Package the compressed BTF folder ``compressed`` as ``out`` (.usda); returns the paths written.

    mesh : path of a mesh (OBJ/PLY/STL/GLB/USD with texture coordinates); None for a swatch quad.
    lods : basis counts of the ``lod`` variants besides "full" (default :func:`default_lods`).
    physical_size : (width, height) in metres; default the source's ``physical_size_m``.
    """
    log = log or (lambda msg: None)
    compressed, out = Path(compressed), Path(out)
    if out.suffix != ".usda":
        raise UsageError(f"{out}: the asset's root layer must be a .usda file")
    cbtf = read_compressed(compressed)
    size = physical_size or physical_size_of(cbtf)
    if size is None:
        raise BTFError(f"{compressed / METADATA}: no physical_size_m recorded; pass --physical-size W H (metres)")
    levels = sorted({int(n) for n in (default_lods(cbtf.k) if lods is None else lods)} - {cbtf.k}, reverse=True)
    bad = [n for n in levels if not 1 <= n < cbtf.k]
    if bad:
        raise UsageError(f"--lod {bad[0]} is outside 1..{cbtf.k} (the asset's k)")
    shape = load_mesh(mesh, need_uv=True).compacted().with_normals() if mesh else Mesh.swatch(*size)
    white = float((cbtf.info.get("source_metadata") or {}).get("white_level", 1.0))
    curve = error_curve(compressed, cbtf)
    roughness, _ = preview.fit_roughness(cbtf)

    stem, root = out.stem, _prim_name(out.stem)
    textures_rel, payload_name = f"{stem}_textures", f"{stem}_payload.usda"
    with atomic_group(out.parent, asset_pieces(out, usdz=usdz), what="asset") as staging:
        tex_dir = staging / textures_rel
        basis, coeffs = package_textures(cbtf, compressed, tex_dir)
        _write_albedo(cbtf, tex_dir / "preview_albedo.png", white)
        _write_payload(staging / payload_name, root, cbtf, shape, textures_rel, basis, coeffs,
                       physical_size=size, curve=curve, roughness=roughness)
        _write_root(staging / out.name, root, payload_name, [f"./{textures_rel}/{c}" for c in coeffs], levels, cbtf.k)
        names = [textures_rel, payload_name]
        if usdz:
            names.append(make_usdz(staging / out.name, staging / f"{stem}.usdz").name)
        for name in names[1:] + [out.name]:
            if not name.endswith(".usdz"):
                bad = non_finite_values(staging / name)
                if bad:
                    raise BTFError(f"{out.parent / name}: would hold non-finite numbers ({bad[0]}"
                                   + (f" and {len(bad) - 1} more" if len(bad) > 1 else "") + "); not published")
            if validate:
                problems = validate_layer(staging / name)
                if problems:
                    raise BTFError(f"{out.parent / name}: fails USD validation: {problems[0]}"
                                   + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""))
    log(f"packaged {compressed} (k = {cbtf.k}, LODs {[cbtf.k] + levels}, roughness fit {roughness:.2f}) as {out}"
        + (f" and {out.with_suffix('.usdz').name}" if usdz else ""))
    written = {"root": out, "payload": out.parent / payload_name, "textures": out.parent / textures_rel}
    if usdz:
        written["usdz"] = out.with_suffix(".usdz")
    return written


def make_usdz(root_layer: Path, usdz: Path) -> Path:
    """Package ``root_layer`` and everything it references into ``usdz`` (variants and payloads kept)."""
    from pxr import Sdf, UsdUtils

    with _usd_write(usdz):
        made = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(root_layer)), str(usdz))
    if not made:
        raise BTFError(f"{usdz}: usdz packaging failed")
    return usdz
