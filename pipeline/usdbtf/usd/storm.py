"""The real-time BTF preview inside a packaged Material: Storm shader, GPU textures, MaterialX.

:func:`author_gpu_preview` (called by ``usd.package`` while it writes the payload) adds,
next to the UsdPreviewSurface fallback::

    mtl/BtfMaterial                  outputs:glslfx:surface -> StormSurface.outputs:surface
        StormSurface                 Shader, info:id = "UsdBtfSurface": its Sdr definition
                                     (plugin/usdBtf/resources/sdr/UsdBtfSurface.usda, found
                                     by Sdr's filesystem discovery) is implementationSource
                                     "sourceAsset" with shaders/UsdBtfSurface.glslfx
        StormTables, StormPackNN     UsdUVTexture (raw) of <stem>_textures/gpu/...

    <stem>_textures/gpu/tables.exr   basis rows, hemisphere lookups, de-quantisation (float32)
    <stem>_textures/gpu/packNN.png   coefficient packs, 4 layers per RGBA texture (PNG, or EXR
                                     for half-float codecs), the stored codes exactly
    <stem>_textures/gpu/usdbtf.mtlx  the same material as a MaterialX document (usdbtf_surface)

Renderers pick by render context: Storm takes ``glslfx``, every other renderer the
universal ``outputs:surface`` (UsdPreviewSurface).

Why ``info:id`` and not a ``.glslfx`` asset path on the asset's own Shader: a glslfx file
cannot travel with the asset and pass validation.  Inside a .usdz it fails
usdUtilsValidators:FileExtensionValidator (only USD layers, PNG/JPEG/EXR/AVIF and audio are
allowed), the usdz packager copies any resolvable dependency in (search paths included),
an unresolvable one fails MissingReferenceValidator, and usd-core has no Sdr parser for
.glslfx files, so usdShadeValidators:ShaderSdrCompliance rejects a glslfx sourceAsset
outright.  UsdPreviewSurface solves the same problem the same way: the asset names the
shader, the plugin ships its definition (sourceAsset + glslfx).

Levels of detail: the payload's root prim carries its own ``lod`` variant set, selected
by the root layer's ``lod`` selection.  Each ``k<n>`` variant sets ``basisCount`` and blocks
the connections of the packs beyond ``3 * ceil(n / 4)``, so Storm loads only those textures.
The full set of connections lives on an internal class the shader references (weaker
than variants): any other selection shows every layer.
"""
from __future__ import annotations

from pathlib import Path

from ..compress.format import CompressedBTF
from ..errors import BTFError
from ..gpu import shaders
from ..gpu.tables import MAX_GROUPS, gpu_layout, pack_count

__all__ = ["plugin_dir_resources", "GPU_DIR", "STORM_SURFACE", "FULL_CLASS", "author_gpu_preview",
           "write_gpu_textures", "materialx_document", "storm_shader", "layout_from_asset", "read_rgba"]

GPU_DIR = "gpu"
STORM_SURFACE = "StormSurface"
TABLES_NODE = "StormTables"
FULL_CLASS = "_UsdBtfStormFull"
MTLX_FILE = "usdbtf.mtlx"
_RENDER_CONTEXT = "glslfx"


def plugin_dir_resources() -> Path:
    """``plugin/usdBtf/resources``: sdr/, shaders/, materialx/."""
    from .plugin import resources_dir

    return resources_dir()


# ------------------------------------------------------------------ textures
def write_gpu_textures(cbtf: CompressedBTF, folder: Path) -> tuple[str, list[str], int]:
    """Write tables.exr and the coefficient packs into ``folder``; returns their names
    (relative to ``folder``) and the number of basis vectors they hold."""
    import numpy as np

    from ..imageio import write_image

    layout = gpu_layout(cbtf)
    folder.mkdir(parents=True, exist_ok=True)
    write_image(folder / "tables.exr", layout.tables, color_space="data", attributes={"compression": "zip"})
    names = []
    for p, pixels in enumerate(layout.packs):
        if pixels.dtype == np.float16:
            name = f"{shaders.pack_name(p)}.exr"
            write_image(folder / name, pixels, color_space="data", attributes={"compression": "zip"})
        else:
            name = f"{shaders.pack_name(p)}.png"
            # Alpha is the fourth coefficient layer, not coverage: OIIO must not
            # un-premultiply RGB by it (Storm's PNG reader takes the file's values as-is).
            write_image(folder / name, pixels, color_space="data",
                        attributes={"png:compressionLevel": 6, "oiio:UnassociatedAlpha": 1})
        names.append(name)
    return "tables.exr", names, layout.k


def materialx_document(tables: str, packs: list[str], k: int) -> str:
    """A MaterialX document instancing usdbtf_surface on the given texture files (paths
    relative to the document), bound to a surfacematerial named BtfMaterial."""
    lines = ['<?xml version="1.0"?>',
             "<!-- usdbtf: the packaged BTF as MaterialX; needs plugin/usdBtf/resources/materialx on the"
             " library search path (PXR_MTLX_PLUGIN_SEARCH_PATHS for Hydra). -->",
             '<materialx version="1.39">',
             '  <usdbtf_surface name="btf" type="surfaceshader">',
             f'    <input name="tables" type="filename" value="{tables}" />']
    lines += [f'    <input name="{shaders.pack_name(p)}" type="filename" value="{name}" />'
              for p, name in enumerate(packs)]
    lines += [f'    <input name="basisCount" type="integer" value="{k}" />',
              "  </usdbtf_surface>",
              '  <surfacematerial name="BtfMaterial" type="material">',
              '    <input name="surfaceshader" type="surfaceshader" nodename="btf" />',
              "  </surfacematerial>",
              "</materialx>", ""]
    return "\n".join(lines)


# ------------------------------------------------------------------ authoring
def _texture(stage, path, file: str, reader, wrap: str):
    from pxr import Sdf, UsdShade

    tex = UsdShade.Shader.Define(stage, path)
    tex.CreateIdAttr("UsdUVTexture")
    file_input = tex.CreateInput("file", Sdf.ValueTypeNames.Asset)
    file_input.Set(Sdf.AssetPath(file))
    file_input.GetAttr().SetColorSpace("raw")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("raw")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set(wrap)
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set(wrap)
    # The shader reads all four channels through the sampler (HdGetSampler_*); the
    # connection names output r, a float like the shader input it feeds.
    tex.CreateOutput("r", Sdf.ValueTypeNames.Float)
    return tex


def _st_reader(stage, material_path):
    from pxr import Sdf, UsdShade

    reader = UsdShade.Shader.Get(stage, material_path.AppendChild("StReader"))
    if reader and reader.GetIdAttr().Get() == "UsdPrimvarReader_float2":
        return reader                                    # the preview network's reader
    reader = UsdShade.Shader.Define(stage, material_path.AppendChild("StormStReader"))
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
    reader.CreateOutput("result", Sdf.ValueTypeNames.Float2)
    return reader


def author_gpu_preview(stage, material, cbtf: CompressedBTF, textures_dir: Path, textures_rel: str, *,
                       levels: list[int] | None = None) -> bool:
    """Write the GPU textures into ``textures_dir/gpu`` and author the Storm shader network
    in ``material`` (a UsdShade.Material on ``stage``, whose layer sits next to
    ``textures_rel``).  levels : the asset's LOD basis counts (default: package.default_lods).
    Returns False (and authors nothing) for a BTF whose sampling is not every light at
    every view, which the preview cannot interpolate."""
    from pxr import Sdf, UsdShade

    from ..compress.format import cross_layout
    from .package import LOD_VARIANT_SET, default_lods

    if cross_layout(cbtf.sampling) is None:
        return False
    tables, packs, k = write_gpu_textures(cbtf, Path(textures_dir) / GPU_DIR)
    (Path(textures_dir) / GPU_DIR / MTLX_FILE).write_text(materialx_document(tables, packs, k))
    rel = f"./{textures_rel}/{GPU_DIR}"
    mpath = material.GetPath()
    wrap = _default_wrap(cbtf)
    reader = _st_reader(stage, mpath)

    # Everything Storm needs for the full k, on an internal class the shader references:
    # weaker than the payload's lod variants, which trim it.
    full = stage.CreateClassPrim(f"/{FULL_CLASS}")
    full.SetDocumentation("usdbtf: the Storm preview's inputs for every basis vector; referenced by "
                          f"{mpath}/{STORM_SURFACE} and trimmed by the lod variants.")
    full_shader = UsdShade.Shader(full)
    full_shader.CreateInput("basisCount", Sdf.ValueTypeNames.Int).Set(k)
    tex = _texture(stage, mpath.AppendChild(TABLES_NODE), f"{rel}/{tables}", reader, "clamp")
    full_shader.CreateInput("tables", Sdf.ValueTypeNames.Float).ConnectToSource(tex.ConnectableAPI(), "r")
    for p, name in enumerate(packs):
        tex = _texture(stage, mpath.AppendChild(f"Storm{shaders.pack_name(p).capitalize()}"), f"{rel}/{name}",
                       reader, wrap)
        full_shader.CreateInput(shaders.pack_name(p), Sdf.ValueTypeNames.Float).ConnectToSource(
            tex.ConnectableAPI(), "r")

    surface = UsdShade.Shader.Define(stage, mpath.AppendChild(STORM_SURFACE))
    surface.GetPrim().GetReferences().AddInternalReference(full.GetPath())
    surface.CreateIdAttr(shaders.SHADER_ID)
    surface.CreateInput("exposure", Sdf.ValueTypeNames.Float).Set(1.0)
    surface.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    material.CreateSurfaceOutput(_RENDER_CONTEXT).ConnectToSource(surface.ConnectableAPI(), "surface")

    root = stage.GetPrimAtPath(mpath.GetPrefixes()[0])
    levels = sorted({n for n in (default_lods(cbtf.k) if levels is None else levels) if 1 <= n < cbtf.k},
                    reverse=True)
    if not levels:
        return True
    vset = root.GetVariantSets().AddVariantSet(LOD_VARIANT_SET)
    for n in levels:
        name = f"k{n}"
        vset.AddVariant(name)
        vset.SetVariantSelection(name)
        with vset.GetVariantEditContext():
            over = stage.OverridePrim(surface.GetPath())
            over.CreateAttribute("inputs:basisCount", Sdf.ValueTypeNames.Int).Set(min(n, k))
            for p in range(pack_count(n), len(packs)):
                over.CreateAttribute(f"inputs:{shaders.pack_name(p)}", Sdf.ValueTypeNames.Float).SetConnections([])
    vset.ClearVariantSelection()
    return True


def _default_wrap(cbtf: CompressedBTF) -> str:
    """Repeat for a tileable quilt, else clamp: what the CPU renderer does."""
    from ..render.core import default_wrap

    return default_wrap(cbtf)


# ------------------------------------------------------------------ reading back
def read_rgba(path) -> "np.ndarray":
    """(H, W, 4) pixels of a GPU texture in the file's own type (usdbtf.imageio.read_image
    returns RGB only; the packs and tables use all four channels)."""
    import numpy as np
    import OpenImageIO as oiio

    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)       # the fourth layer is data, not coverage
    inp = oiio.ImageInput.open(str(path), config)
    if inp is None:
        raise BTFError(f"{path}: cannot open GPU texture ({' '.join(oiio.geterror().split())})")
    try:
        spec = inp.spec()
        if spec.nchannels != 4:
            raise BTFError(f"{path}: GPU texture has {spec.nchannels} channels, expected 4 (RGBA)")
        data = inp.read_image(0, 0, 0, 4, spec.format)
        if data is None or inp.has_error:
            raise BTFError(f"{path}: GPU texture is corrupt or truncated ({' '.join(inp.geterror().split())})")
    finally:
        inp.close()
    return np.asarray(data)


def storm_shader(material):
    """The Storm preview Shader of a Material prim (composed), or None."""
    from pxr import UsdShade

    output = UsdShade.Material(material).GetSurfaceOutput(_RENDER_CONTEXT)
    if not output:
        return None
    sources = output.GetConnectedSources()[0] if output.HasConnectedSource() else []
    return UsdShade.Shader(sources[0].source.GetPrim()) if sources else None


def layout_from_asset(asset, *, lod: str | None = None):
    """(GpuLayout, wrap, k) read back from a packaged asset's Storm network: the textures
    its connected UsdUVTexture nodes name and its composed basisCount (``lod`` selects a
    variant).  What the headless renderer draws, so the test sees what Storm would load."""
    import numpy as np
    from pxr import UsdShade

    from ..gpu.tables import GpuLayout
    from .material import btf_materials
    from .read import open_stage

    stage = open_stage(asset, lod=lod)
    materials = btf_materials(stage)
    if not materials:
        raise BTFError(f"{asset}: no BtfMaterialAPI material")
    shader = storm_shader(materials[0])
    if shader is None:
        raise BTFError(f"{asset}: {materials[0].GetPath()} has no {_RENDER_CONTEXT} surface (no Storm preview)")

    def texture(name):
        """(pixels, wrap) of the UsdUVTexture connected to input ``name``, or (None, None)."""
        source = shader.GetInput(name)
        if not source or not source.HasConnectedSource():
            return None, None
        node = UsdShade.Shader(source.GetConnectedSources()[0][0].source.GetPrim())
        path = node.GetInput("file").Get()
        if not path.resolvedPath or "[" in path.resolvedPath:
            raise BTFError(f"{asset}: {node.GetPath()} texture {path.path!r} is not a file on disk "
                           "(open the .usda asset, not a .usdz)")
        return read_rgba(path.resolvedPath), str(node.GetInput("wrapS").Get())

    tables, _ = texture("tables")
    if tables is None:
        raise BTFError(f"{asset}: {shader.GetPath()} has no tables texture connected")
    packs, wrap = [], "clamp"
    for p in range(3 * MAX_GROUPS):
        pixels, pack_wrap = texture(shaders.pack_name(p))
        if pixels is None:
            break
        packs.append(pixels)
        wrap = pack_wrap
    k = int(shader.GetInput("basisCount").Get())
    return GpuLayout(np.asarray(tables, np.float32), packs, k), wrap, k
