"""The UsdPreviewSurface fallback of a packaged BTF material: fitted maps, written and wired.

Every renderer without BTF support (Karma, Arnold, RenderMan, RTX, AR viewers, ...) renders
the Material's universal ``outputs:surface``: a UsdPreviewSurface in the specular workflow
whose inputs come from four textures fitted to the BTF by :func:`usdbtf.svbrdf.fit_svbrdf`::

    <stem>_textures/fallback/diffuse.png     diffuseColor   8-bit sRGB (Rec.709), colour
    <stem>_textures/fallback/specular.png    specularColor  8-bit sRGB (Rec.709), colour
    <stem>_textures/fallback/roughness.png   roughness      8-bit grey, data (raw)
    <stem>_textures/fallback/normal.png      normal         8-bit RGB = n * 0.5 + 0.5, data (raw),
                                                            read with scale (2, 2, 2, 1), bias (-1, -1, -1, 0)

(other files with ``--texture-format``; each PNG at level 9 with the smaller of two libpng
filters, :func:`usdbtf.imageio.encode_png_smallest`).  The maps stay lossless: JPEG colour
maps (4:4:4) would save 17-43 % of the diffuse/base colour files at quality 98-95 but move
the fits' error as shipped by +1.6 to +6.7 % relative on the smoothest preset
(ridged_fabric; ``benchmarks/bench_fallback.py --png-baseline --what-if Q:MAPS``), the
specular and fuzz colours and the data maps gain little or nothing; a ``MAP_FILES`` name
ending ".jpg" would be written as a JPEG (:data:`MAP_JPEG`) and read back as one.  The
colour maps are the fit's working-space values converted by OCIO to Rec.709 and
sRGB-encoded, clipped to [0, 1]; the shader declares
``lin_rec709_scene`` (``Usd.ColorSpaceAPI``), the data inputs ``raw``.  The normal map is in
the texture's tangent space (x = +s, y = +t), which is the sample's (image right, image up).

:func:`encode_maps` / :func:`decode_maps` are exactly what is written and what a renderer
reads back from the pixels, :func:`shipped_pixels` what it decodes from the files (a JPEG's
pixels are not the encoded ones), so the benchmark measures the fallback as shipped.
"""
from __future__ import annotations

import numpy as np

from ...color import processor
from ...imageio import decode_image, encode_image, encode_png_smallest
from ...svbrdf import SvbrdfMaps

__all__ = ["COLOUR_ENCODING", "FALLBACK_DIR", "MAP_FILES", "MAP_JPEG", "encode_maps", "decode_maps", "encode_map_file",
           "shipped_pixels", "add_maps", "add_map_files", "author_fallback", "uv_texture", "st_reader"]

#: The colour maps' file encoding: what UsdUVTexture decodes with sourceColorSpace "sRGB".
COLOUR_ENCODING = "sRGB Encoded Rec.709 (sRGB)"
FALLBACK_DIR = "fallback"
#: map -> (file under FALLBACK_DIR, texture kind for textures.TextureSet); the suffix chooses
#: the encoding (:func:`encode_map_file`).
MAP_FILES = {"diffuse": ("diffuse.png", "srgb"), "specular": ("specular.png", "srgb"),
             "roughness": ("roughness.png", "unorm"), "normal": ("normal.png", "unorm")}
#: OIIO's options for a map stored as JPEG (none is, module docstring): no chroma subsampling
#: (a map's texels are the material's own, each one read by the fit's error).
MAP_JPEG = {"Compression": "jpeg:97", "jpeg:subsampling": "4:4:4"}
_SHADER_SPACE = "lin_rec709_scene"


def _to_uint8(values: np.ndarray) -> np.ndarray:
    return np.rint(np.clip(values, 0.0, 1.0) * 255.0).astype(np.uint8)


def encode_maps(maps: SvbrdfMaps, ocio_config: str | None = None) -> dict[str, np.ndarray]:
    """{map: (H, W, C) uint8 pixels as written}: colour maps sRGB-encoded Rec.709, roughness
    grey, normals ``n * 0.5 + 0.5``.  Raises BTFError rather than write a non-finite fit."""
    from ...errors import BTFError

    for name in ("diffuse", "specular", "roughness", "normal"):
        if not np.isfinite(getattr(maps, name)).all():
            raise BTFError(f"the fitted fallback's {name} map is not finite (is the BTF?)")
    to_file = processor(maps.working_space, COLOUR_ENCODING, ocio_config)
    return {"diffuse": _to_uint8(to_file.apply(np.ascontiguousarray(maps.diffuse, np.float32))),
            "specular": _to_uint8(to_file.apply(np.ascontiguousarray(maps.specular, np.float32))),
            "roughness": _to_uint8(maps.roughness[..., None]),
            "normal": _to_uint8(np.asarray(maps.normal) * 0.5 + 0.5)}


def decode_maps(pixels: dict[str, np.ndarray], working_space: str, *, ocio_config: str | None = None,
                white_level: float = 1.0) -> SvbrdfMaps:
    """The maps a renderer reads from :func:`encode_maps`'s pixels (UsdUVTexture's decode,
    then the shader's inputs), back in ``working_space`` for comparison with the BTF."""
    from ...svbrdf import MIN_ROUGHNESS

    from_file = processor(COLOUR_ENCODING, working_space, ocio_config)
    unit = {name: np.asarray(px, np.float32) / 255.0 for name, px in pixels.items()}
    normal = unit["normal"] * 2.0 - 1.0
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)   # as shaders normalise
    return SvbrdfMaps(from_file.apply(unit["diffuse"].copy()), from_file.apply(unit["specular"].copy()),
                      np.maximum(unit["roughness"][..., 0], MIN_ROUGHNESS), normal.astype(np.float32),
                      working_space, float(white_level))


def encode_map_file(pixels: np.ndarray, file: str, kind: str, jpeg: dict | None = None) -> bytes:
    """The bytes of the map file ``file`` (a name from a ``MAP_FILES``: its suffix chooses the
    encoding) holding the (H, W, C) uint8/uint16 ``pixels`` of a ``kind`` texture: a JPEG with
    ``jpeg`` (default :data:`MAP_JPEG`) for ".jpg", else the smaller-filter PNG at level 9.
    Colour ("srgb") files declare :data:`COLOUR_ENCODING`, the others data."""
    from .textures import DATA

    space = COLOUR_ENCODING if kind == "srgb" else DATA
    if file.lower().endswith(".jpg"):
        return encode_image(pixels, "jpg", color_space=space, attributes=MAP_JPEG if jpeg is None else jpeg)
    # The smaller of two filters (issue 39: fitted maps of a noisy material compress best
    # unfiltered, smooth ones filtered); the same pixels either way.
    return encode_png_smallest(pixels, color_space=space, level=9)


def shipped_pixels(encoded: dict, files: dict, jpeg: dict | None = None) -> dict:
    """{map: (H, W, C) pixels a renderer decodes from its file}: ``encoded`` ({map: pixels},
    an ``encode_maps``) through the lossy files of ``files`` ({map: (file, kind)}, a
    ``MAP_FILES``) and back (:func:`encode_map_file`); the lossless files' pixels unchanged."""
    out = {}
    for name, pixels in encoded.items():
        file, kind = files[name]
        if file.lower().endswith(".jpg"):
            back = decode_image(encode_map_file(pixels, file, kind, jpeg))
            pixels = back[..., :pixels.shape[-1]] if pixels.ndim == 3 else back[..., 0]
        out[name] = pixels
    return out


def add_maps(maps: SvbrdfMaps, textures, ocio_config: str | None = None, names=tuple(MAP_FILES),
             texels=None) -> dict:
    """Encode the maps ``names`` as their files (in memory) into ``textures`` (a
    textures.TextureSet, under :data:`FALLBACK_DIR`); {map: its name in ``textures``}.
    ``texels`` (a :class:`usdbtf.quilt.texels.QuiltTexels`): ``maps`` are those of its compact
    source texels, and the encoded pixels are gathered through its index (encoding is per
    texel, so this is the encoding of the gathered maps)."""
    encoded = {name: pixels for name, pixels in encode_maps(maps, ocio_config).items() if name in names}
    return add_map_files(encoded, MAP_FILES, textures, texels, "fallback maps")


def add_map_files(encoded: dict, files: dict, textures, texels, label: str) -> dict:
    """Encode fallback map pixels as their files (:func:`encode_map_file`; in memory, on every
    CPU) into ``textures`` under :data:`FALLBACK_DIR`: the one writer of the
    UsdPreviewSurface and OpenPBR maps.

    encoded : {map: (H, W, C) uint8/uint16 pixels}, or a quilt's source-texel pixels when
        ``texels`` (a :class:`usdbtf.quilt.texels.QuiltTexels`) gathers them per pixel.
    files : {map: (file name, kind)}; kind "srgb" is colour (:data:`COLOUR_ENCODING`), any
        other kind data; a ".jpg" name is a JPEG (:data:`MAP_JPEG`), any other a PNG.
    Returns {map: its name in ``textures``}."""
    from .textures import encode_in_workers

    def encode(name):
        pixels = encoded[name] if texels is None else texels.gather(encoded[name])
        return encode_map_file(pixels, files[name][0], files[name][1])

    data = encode_in_workers(encode, encoded, label)
    return {name: textures.add(f"{FALLBACK_DIR}/{files[name][0]}", blob, files[name][1])
            for name, blob in zip(encoded, data)}


# ------------------------------------------------------------------ authoring
def st_reader(stage, material_path):
    """The material's ``UsdPrimvarReader_float2`` of ``st`` (created once, shared by every texture)."""
    from pxr import Sdf, UsdShade

    path = material_path.AppendChild("StReader")
    reader = UsdShade.Shader.Get(stage, path)
    if reader and reader.GetIdAttr().Get() == "UsdPrimvarReader_float2":
        return reader
    reader = UsdShade.Shader.Define(stage, path)
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    return reader


def uv_texture(stage, path, texture, reader, wrap: str, output: tuple, *, scale=None, bias=None):
    """A UsdUVTexture of ``texture`` (a textures.Texture: file, colour spaces) at ``path``,
    reading ``st`` from ``reader``; ``output`` = (name, Sdf type) of the output it provides."""
    from pxr import Gf, Sdf, UsdShade

    tex = UsdShade.Shader.Define(stage, path)
    tex.CreateIdAttr("UsdUVTexture")
    file_input = tex.CreateInput("file", Sdf.ValueTypeNames.Asset)
    file_input.Set(Sdf.AssetPath(texture.path))
    file_input.GetAttr().SetColorSpace(texture.color_space)
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(texture.source_color_space)
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(wrap)
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wrap)
    for name, value in (("scale", scale), ("bias", bias)):
        if value is not None:
            tex.CreateInput(name, Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*value))
    tex.CreateOutput(*output)
    return tex


def author_fallback(stage, material, textures: dict, *, wrap: str = "repeat", summary: dict | None = None,
                    specular_workflow: bool = True) -> None:
    """The UsdPreviewSurface network on ``material`` (its universal ``outputs:surface``) from
    the textures of :func:`add_maps` ({map: textures.Texture}).  ``summary``: {"diffuse": (3,), "roughness": float} used as
    the inputs' values for readers that ignore connections.  Without ``specular_workflow``
    (AR viewers): metallic workflow at metallic 0, no specular map."""
    from pxr import Gf, Sdf, Usd, UsdShade

    mpath = material.GetPath()
    reader = st_reader(stage, mpath)
    f3, f1 = Sdf.ValueTypeNames.Float3, Sdf.ValueTypeNames.Float
    nodes = {
        "diffuse": uv_texture(stage, mpath.AppendChild("DiffuseTexture"), textures["diffuse"], reader, wrap,
                              ("rgb", f3)),
        "roughness": uv_texture(stage, mpath.AppendChild("RoughnessTexture"), textures["roughness"], reader,
                                wrap, ("r", f1)),
        "normal": uv_texture(stage, mpath.AppendChild("NormalTexture"), textures["normal"], reader, wrap,
                             ("rgb", f3), scale=(2, 2, 2, 1), bias=(-1, -1, -1, 0)),
    }
    surface = UsdShade.Shader.Define(stage, mpath.AppendChild("PreviewSurface"))
    surface.CreateIdAttr("UsdPreviewSurface")
    Usd.ColorSpaceAPI.Apply(surface.GetPrim()).CreateColorSpaceNameAttr(_SHADER_SPACE)
    diffuse = surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
    roughness = surface.CreateInput("roughness", f1)
    normal = surface.CreateInput("normal", Sdf.ValueTypeNames.Normal3f)
    if summary:
        diffuse.Set(Gf.Vec3f(*map(float, summary["diffuse"])))
        roughness.Set(float(summary["roughness"]))
    diffuse.ConnectToSource(nodes["diffuse"].ConnectableAPI(), "rgb")
    roughness.ConnectToSource(nodes["roughness"].ConnectableAPI(), "r")
    normal.ConnectToSource(nodes["normal"].ConnectableAPI(), "rgb")
    if specular_workflow:
        specular = uv_texture(stage, mpath.AppendChild("SpecularTexture"), textures["specular"], reader, wrap,
                              ("rgb", f3))
        surface.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(
            specular.ConnectableAPI(), "rgb")
    workflow = surface.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int)
    workflow.Set(1 if specular_workflow else 0)
    metallic = surface.CreateInput("metallic", f1)
    metallic.Set(0.0)
    for inp in (roughness, normal, workflow, metallic):       # data, not colour
        inp.GetAttr().SetColorSpace("raw")
    surface.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
