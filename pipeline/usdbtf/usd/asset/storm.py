"""The real-time BTF preview inside a packaged Material: Storm shader, GPU textures, MaterialX.

:func:`add_gpu_textures` (``usd.asset.package.package``: the files, in memory) and
:func:`author_gpu_preview` (``usd.asset.package.write_package``: the network in the payload) add,
next to the UsdPreviewSurface fallback::

    mtl/BtfMaterial                  outputs:glslfx:surface -> StormSurface.outputs:surface
        StormSurface                 Shader, info:id = "UsdBtfSurface": its Sdr definition
                                     (plugin/usdBtf/resources/sdr/UsdBtfSurface.usda, found
                                     by Sdr's filesystem discovery) is implementationSource
                                     "sourceAsset" with shaders/UsdBtfSurface.glslfx
        StormTables, StormPageNN     UsdUVTexture (raw) of <stem>_textures/gpu/...

    <stem>_textures/gpu/tables.exr   basis rows, hemisphere lookups, de-quantisation, the
                                     packs' directory (float32)
    <stem>_textures/gpu/pageNN.png   coefficient packs (4 layers per RGBA tile) laid out on at
                                     most 14 atlas pages: 8-bit codes as PNG, 16-bit codes as
                                     float32 EXR (code / 65535), half floats as EXR; the stored
                                     codes exactly
    <stem>_textures/gpu/basis.png    the integer basis codes as 8-bit high / low planes (schema
                                     4, page slot 14, ``page14``; half codes stay in the tables):
                                     with the tables, at most 16 samplers for any k
                                     (usdbtf.gpu.tables)
    <stem>_textures/gpu/usdbtf.mtlx  the same material as a MaterialX document (usdbtf_surface)
    <stem>_textures/gpu/tables_k<n>.exr, basis_k<n>.png, usdbtf_k<n>.mtlx
                                     per lower level of detail: its own tables (its packs'
                                     entries only), basis page (its n vectors) and document

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

Levels of detail (:mod:`usdbtf.usd.asset.lod`): the Material's ``lod`` variant ``k<n>``, in the
root layer, sets ``basisCount``, points the tables node at the level's own tables and
points the basis page node at the level's own basis page and blocks the connections of the
pages beyond those holding its packs (pages end where levels end), so Storm loads only those
textures; the payload holds the full set.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ...compress.format import CompressedBTF
from ...compress.packs import encode_png_page
from ...errors import BTFError
from ...gpu import shaders
from ...gpu.tables import BASIS_PAGE, gpu_layout, page_slots
from ...imageio import read_rgba
from ...photometry import white_level_of

__all__ = ["plugin_dir_resources", "GPU_DIR", "STORM_SURFACE", "GpuTextures", "add_gpu_textures",
           "author_gpu_preview", "rendering_rows", "lod_tables_name", "lod_basis_name", "basis_node", "lod_mtlx_name",
           "author_materialx_preview", "materialx_document", "storm_shader", "rendering_space_of", "to_rendering_space",
           "layout_from_asset", "read_rgba"]

GPU_DIR = "gpu"
STORM_SURFACE = "StormSurface"
TABLES_NODE = "StormTables"
MTLX_FILE = "usdbtf.mtlx"
_RENDER_CONTEXT = "glslfx"


def plugin_dir_resources() -> Path:
    """``plugin/usdBtf/resources``: sdr/, shaders/, materialx/."""
    from ..plugin import resources_dir

    return resources_dir()


# ------------------------------------------------------------------ textures
@dataclass(frozen=True)
class GpuTextures:
    """The Storm preview's files in a texture set: ``tables`` and ``pages`` (names), the basis
    count ``k`` the tables hold, the first pack of each page (``first_packs``), and
    ``lod_tables``: {n: name of the tables of the first n vectors} per lower level of detail
    (:func:`lod_tables_name`; empty for a layout made without levels); ``basis``: the basis
    page's name (schema 4; None where the tables hold the codes) and ``lod_basis``: {n: name
    of the basis page of the first n vectors}."""

    tables: str
    pages: list
    k: int
    first_packs: list
    lod_tables: dict = field(default_factory=dict)
    basis: str | None = None
    lod_basis: dict = field(default_factory=dict)

    def slots(self, n: int | None = None) -> list:
        """The page slots' file names (None: unbound) of the first ``n`` (default k) vectors
        (:func:`usdbtf.gpu.tables.page_slots`)."""
        return page_slots(self.pages, self.first_packs, self.k, n, self.basis, self.lod_basis)


def lod_tables_name(n: int) -> str:
    """File stem of the tables of a level of detail of ``n`` vectors (``tables_k<n>``)."""
    return f"tables_k{n}"


def lod_basis_name(n: int) -> str:
    """File stem of the basis page of a level of detail of ``n`` vectors (``basis_k<n>``)."""
    return f"basis_k{n}"


def basis_node() -> str:
    """The name of the UsdUVTexture node of the basis page (page slot BASIS_PAGE)."""
    return f"Storm{shaders.page_name(BASIS_PAGE).capitalize()}"


def add_gpu_textures(cbtf: CompressedBTF, textures, lods=(), *, texels=None,
                     rendering_matrix=None) -> GpuTextures | None:
    """Encode tables.exr, the coefficient pages and the MaterialX document (in memory) into
    ``textures`` (a :class:`~usdbtf.usd.asset.textures.TextureSet`, under ``gpu/``), pages ending
    where the levels of detail ``lods`` (basis counts) end; None (nothing added) for a BTF
    whose sampling is not every light at every view, which the preview cannot interpolate.
    ``texels`` (a :class:`usdbtf.quilt.texels.QuiltTexels` of ``cbtf``): the packs are made
    from its compact source texels and gathered through its index (the same codes, without
    the whole quilt-sized set of packs in memory).  ``rendering_matrix``: (3, 3) working ->
    rendering space (:func:`rendering_rows`), given to the MaterialX documents' node."""
    import numpy as np

    from ...compress.format import cross_layout
    from ...imageio import encode_image
    from ...render.core import default_wrap
    from .textures import encode_in_workers

    if cross_layout(cbtf.sampling) is None:
        return None
    layout = gpu_layout(cbtf, lods=lods, wrap=default_wrap(cbtf), texels=texels)
    tables = textures.add(f"{GPU_DIR}/tables.exr", encode_image(layout.tables, "exr", color_space="data",
                                                                 attributes={"compression": "zip"}), "float")

    def encode(pixels):
        """(suffix, bytes, kind) of one page."""
        if pixels.dtype != np.uint8:
            # Half floats as they are; 16-bit codes as the float32 values a unorm16 read would
            # return (code / 65535, exact to float32 rounding): Storm's image readers load a
            # 16-bit PNG as 8 bits, which would drop the low byte of every code.
            if pixels.dtype == np.uint16:
                pixels = (pixels.astype(np.float64) / 65535.0).astype(np.float32)
            return ".exr", encode_image(pixels, "exr", color_space="data", attributes={"compression": "zip"}), "float"
        # The smaller of the PNG filter choices, as rate control measures packs (packs.py).
        return ".png", encode_png_page(pixels), "unorm"

    # Each worker builds its page and encodes it: a few atlas-sized pages in memory at once.
    # Forked workers only for 8-bit pages (PNG): the others are written as OpenEXR.
    pages_range = range(len(layout.pages))
    encoded = encode_in_workers(lambda p: encode(layout.pages[p]), pages_range, "GPU pages",
                                forkable=all(layout.pages.dtype(p) == np.uint8 for p in pages_range))
    pages = [textures.add(f"{GPU_DIR}/{shaders.page_name(p)}{suffix}", data, kind)
             for p, (suffix, data, kind) in enumerate(encoded)]
    basis = None if layout.basis_page is None else \
        textures.add(f"{GPU_DIR}/basis.png", encode_png_page(layout.basis_page), "unorm")
    lod_tables, lod_basis = {}, {}
    for n, table in layout.lod_tables.items():
        # Each lower level's own tables (its packs only) and basis page (its vectors only).
        lod_tables[n] = textures.add(f"{GPU_DIR}/{lod_tables_name(n)}.exr", encode_image(
            table, "exr", color_space="data", attributes={"compression": "zip"}), "float")
        if n in layout.lod_basis_pages:
            lod_basis[n] = textures.add(f"{GPU_DIR}/{lod_basis_name(n)}.png",
                                        encode_png_page(layout.lod_basis_pages[n]), "unorm")
    made = GpuTextures(tables, pages, layout.k, layout.first_packs, lod_tables, basis, lod_basis)
    # The MaterialX documents, the full level's and each lower level's own, on its files.
    white = white_level_of(cbtf.info)
    for n, name in [(layout.k, MTLX_FILE), *((n, lod_mtlx_name(n)) for n in lod_tables)]:
        slots = [None if f is None else Path(f).name for f in made.slots(n)]
        table = tables if n == layout.k else lod_tables[n]
        textures.add_file(f"{GPU_DIR}/{name}", materialx_document(Path(table).name, slots, n, white,
                                                                  rendering_matrix).encode())
    return made


def lod_mtlx_name(n: int) -> str:
    """The MaterialX document of a level of detail of ``n`` vectors (``usdbtf_k<n>.mtlx``)."""
    return f"{Path(MTLX_FILE).stem}_k{n}.mtlx"


def materialx_document(tables: str, pages: list, k: int, white_level: float = 1.0, rendering_matrix=None) -> str:
    """A MaterialX document instancing usdbtf_surface on the given texture files (paths
    relative to the document; ``pages`` per page slot, None for an unbound slot), bound to a
    surfacematerial named BtfMaterial; ``white_level``: the BTF's W (:mod:`usdbtf.photometry`);
    ``rendering_matrix``: (3, 3) working -> rendering space (None: the node's identity
    default, working-space values; :func:`rendering_rows`)."""
    lines = ['<?xml version="1.0"?>',
             "<!-- usdbtf: the packaged BTF as MaterialX; needs plugin/usdBtf/resources/materialx on the"
             " library search path (PXR_MTLX_PLUGIN_SEARCH_PATHS for Hydra). -->",
             '<materialx version="1.39">',
             '  <usdbtf_surface name="btf" type="surfaceshader">',
             f'    <input name="tables" type="filename" value="{tables}" />']
    lines += [f'    <input name="{shaders.page_name(p)}" type="filename" value="{name}" />'
              for p, name in enumerate(pages) if name is not None]
    lines += [f'    <input name="basisCount" type="integer" value="{k}" />',
              f'    <input name="whiteLevel" type="float" value="{float(white_level)!r}" />']
    lines += [f'    <input name="{name}" type="vector3" value="{", ".join(repr(v) for v in row)}" />'
              for name, row in rendering_rows(rendering_matrix)]
    lines += ["  </usdbtf_surface>",
              '  <surfacematerial name="BtfMaterial" type="material">',
              '    <input name="surfaceshader" type="surfaceshader" nodename="btf" />',
              "  </surfacematerial>",
              "</materialx>", ""]
    return "\n".join(lines)


# ------------------------------------------------------------------ authoring
def _texture(stage, path, texture, reader, wrap: str):
    """A UsdUVTexture of ``texture`` (a textures.Texture) whose output r feeds a shader input."""
    from pxr import Sdf

    from .fallback import uv_texture

    # The shader reads all four channels through the sampler (HdGetSampler_*); the
    # connection names output r, a float like the shader input it feeds.
    return uv_texture(stage, path, texture, reader, wrap, ("r", Sdf.ValueTypeNames.Float))


def rendering_rows(matrix) -> list[tuple[str, tuple]]:
    """[(shader input name, row as 3 floats)] of the working -> rendering space ``matrix``
    ((3, 3), :func:`usdbtf.color.linear_matrix`) as the shaders take it
    (:data:`usdbtf.gpu.shaders.RENDERING_INPUTS`); None: []."""
    if matrix is None:
        return []
    return [(name, tuple(float(v) for v in row)) for name, row in zip(shaders.RENDERING_INPUTS, matrix)]


def author_gpu_preview(stage, material, tables, pages: list, k: int, wrap: str,
                       first_packs: list, white_level: float = 1.0, rendering_matrix=None) -> tuple[str, list, int]:
    """Author the Storm shader network in ``material`` (a UsdShade.Material on ``stage``, whose
    layer sits next to the texture folder) on the GPU textures ``tables`` and ``pages`` (per page
    slot, None where unbound: :meth:`GpuTextures.slots`)
    (:class:`~usdbtf.usd.asset.textures.Texture`\\ s of :func:`add_gpu_textures`' files; the tables
    hold ``k`` basis vectors; ``wrap`` for the page nodes, which the shader reads texel by
    texel; ``first_packs``: the first pack of each page; ``white_level``: the BTF's W,
    :mod:`usdbtf.photometry`; ``rendering_matrix``: (3, 3) working -> rendering space, the
    shader's ``renderingMatrix*`` rows, :func:`rendering_rows`; None: unauthored, identity).  Returns (the
    shader's name under the material, ``first_packs``, k) for the ``lod`` variants (:mod:`usdbtf.usd.asset.lod`)."""
    from pxr import Gf, Sdf, UsdShade

    from .fallback import st_reader

    mpath = material.GetPath()
    reader = st_reader(stage, mpath)

    # The full set of connections, as local opinions: the lod variants live in the root
    # layer, whose opinions are stronger than the payload's (usdbtf.usd.asset.lod).
    surface = UsdShade.Shader.Define(stage, mpath.AppendChild(STORM_SURFACE))
    surface.CreateIdAttr(shaders.SHADER_ID)
    data_inputs = [surface.CreateInput("basisCount", Sdf.ValueTypeNames.Int),
                   surface.CreateInput("exposure", Sdf.ValueTypeNames.Float)]
    data_inputs[0].Set(k)
    data_inputs[1].Set(1.0)
    data_inputs.append(surface.CreateInput("whiteLevel", Sdf.ValueTypeNames.Float))
    data_inputs[-1].Set(float(white_level))
    for name, row in rendering_rows(rendering_matrix):
        data_inputs.append(surface.CreateInput(name, Sdf.ValueTypeNames.Color3f))     # the Sdr definitions' type
        data_inputs[-1].Set(Gf.Vec3f(*row))
    tex = _texture(stage, mpath.AppendChild(TABLES_NODE), tables, reader, "clamp")
    data_inputs.append(surface.CreateInput("tables", Sdf.ValueTypeNames.Float))
    data_inputs[-1].ConnectToSource(tex.ConnectableAPI(), "r")
    for p, texture in enumerate(pages):
        if texture is None:
            continue
        tex = _texture(stage, mpath.AppendChild(f"Storm{shaders.page_name(p).capitalize()}"), texture, reader,
                       "clamp" if p == BASIS_PAGE else wrap)
        data_inputs.append(surface.CreateInput(shaders.page_name(p), Sdf.ValueTypeNames.Float))
        data_inputs[-1].ConnectToSource(tex.ConnectableAPI(), "r")
    for inp in data_inputs:             # data, not colour (the material declares its working space)
        inp.GetAttr().SetColorSpace("raw")
    surface.CreateOutput("surface", Sdf.ValueTypeNames.Token)
    material.CreateSurfaceOutput(_RENDER_CONTEXT).ConnectToSource(surface.ConnectableAPI(), "surface")
    return STORM_SURFACE, list(first_packs), k


def author_materialx_preview(stage, material_path: str, tables: str, pages: list[str], k: int,
                             white_level: float = 1.0, rendering_matrix=None):
    """A Material at ``material_path`` whose ``outputs:mtlx:surface`` is the usdbtf node in
    Hydra's MaterialX path: ``ND_surface`` <- ``ND_usdbtf_bsdf`` (the tables and pages as
    asset inputs, ``pages`` per page slot, None where unbound: :meth:`GpuTextures.slots`, ``texcoord`` from ``ND_texcoord_vector2``, ``basisCount`` = ``k``).  Storm
    25.08 generates and compiles it (``tests/test_storm.py``); the ``usdbtf_surface`` node
    graph cannot be used there: Storm's MaterialX code defines a macro named after each texture
    input, which rewrites the graph function's parameters of the same name.  ``rendering_matrix``:
    (3, 3) working -> rendering space (:func:`rendering_rows`; None: the node's identity).
    Returns the UsdShade.Material."""
    from pxr import Gf, Sdf, UsdShade

    material = UsdShade.Material.Define(stage, material_path)
    bsdf = UsdShade.Shader.Define(stage, f"{material_path}/BtfBsdf")
    bsdf.CreateIdAttr(f"ND_{shaders.MTLX_BSDF}")
    bsdf.CreateInput("tables", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(tables))
    for p, page in enumerate(pages):          # per page slot; None: unbound
        if page is not None:
            bsdf.CreateInput(shaders.page_name(p), Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(page))
    bsdf.CreateInput("basisCount", Sdf.ValueTypeNames.Int).Set(int(k))
    bsdf.CreateInput("whiteLevel", Sdf.ValueTypeNames.Float).Set(float(white_level))     # usdbtf.photometry
    for name, row in rendering_rows(rendering_matrix):
        bsdf.CreateInput(name, Sdf.ValueTypeNames.Vector3f).Set(Gf.Vec3f(*row))
    st = UsdShade.Shader.Define(stage, f"{material_path}/TexCoord")
    st.CreateIdAttr("ND_texcoord_vector2")
    bsdf.CreateInput("texcoord", Sdf.ValueTypeNames.Float2).ConnectToSource(
        st.CreateOutput("out", Sdf.ValueTypeNames.Float2))
    surface = UsdShade.Shader.Define(stage, f"{material_path}/Surface")
    surface.CreateIdAttr("ND_surface")
    surface.CreateInput("bsdf", Sdf.ValueTypeNames.Token).ConnectToSource(
        bsdf.CreateOutput("out", Sdf.ValueTypeNames.Token))
    material.CreateSurfaceOutput("mtlx").ConnectToSource(surface.CreateOutput("out", Sdf.ValueTypeNames.Token))
    return material


# ------------------------------------------------------------------ reading back
def storm_shader(material):
    """The Storm preview Shader of a Material prim (composed), or None."""
    from pxr import UsdShade

    output = UsdShade.Material(material).GetSurfaceOutput(_RENDER_CONTEXT)
    if not output:
        return None
    sources = output.GetConnectedSources()[0] if output.HasConnectedSource() else []
    return UsdShade.Shader(sources[0].source.GetPrim()) if sources else None


def rendering_space_of(asset) -> tuple[str, str, str | None]:
    """(working space, rendering space, OCIO config) of a packaged ``asset``'s first BTF
    Material: the space its data are in (``btf:colorSpace``) and the one its shaders return
    (``btf:renderingColorSpace``; unauthored, an asset packaged before issue 40's colour fix:
    the working space, as its shaders' identity rows return)."""
    from pxr import Usd

    from ..material import btf_materials

    stage = Usd.Stage.Open(str(asset))
    material = btf_materials(stage)[0]
    get = lambda name: (material.GetAttribute(name).Get() if material.GetAttribute(name) else None)  # noqa: E731
    working = get("btf:colorSpace") or "ACEScg"
    return working, get("btf:renderingColorSpace") or working, get("btf:ocioConfig") or None


def to_rendering_space(asset, rgb, *, back: bool = False):
    """(..., 3 or 4) float32: working-space values of ``asset``'s BTF (a reconstruction, a
    ``usdbtf render`` frame) taken through OCIO to the space its shaders return
    (:func:`rendering_space_of`; linear Rec.709 for an asset packaged now), alpha kept, so a
    Storm or Cycles frame of the asset compares with them channel by channel; ``back``: the
    other way, a Storm or Cycles frame of it to its working space (``usdbtf render``'s)."""
    import numpy as np

    from ...color import processor

    working, rendering, config = rendering_space_of(asset)
    rgb = np.asarray(rgb, np.float32)
    proc = processor(rendering, working, config) if back else processor(working, rendering, config)
    return np.concatenate([proc.apply(np.ascontiguousarray(rgb[..., :3])), rgb[..., 3:]], axis=-1)


def layout_from_asset(asset, *, lod: str | None = None):
    """(GpuLayout, wrap, k) read back from a packaged asset's Storm network: the textures
    its connected UsdUVTexture nodes name and its composed basisCount (``lod`` selects a
    variant).  What the headless renderer draws, so the test sees what Storm would load."""
    import numpy as np
    from pxr import UsdShade

    from ...gpu.tables import GpuLayout
    from ..material import btf_materials
    from ..read import open_stage

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
    tables = np.asarray(tables, np.float32)
    pages, wrap = [], "clamp"
    for p in range(BASIS_PAGE):
        pixels, page_wrap = texture(shaders.page_name(p))
        if pixels is None:
            break
        pages.append(pixels)
        wrap = page_wrap
    basis_page, _ = texture(shaders.page_name(BASIS_PAGE))          # schema 4 (None before)
    k = int(shader.GetInput("basisCount").Get())
    flat = tables.reshape(-1, 4)
    directory = flat[int(flat[3, 0]):int(flat[3, 0]) + 3 * -(-int(flat[1, 0]) // 4), 0].astype(int)
    first_packs = [int(np.argmax(directory == page)) for page in range(int(directory.max()) + 1)]
    return GpuLayout(tables, pages, k, first_packs, basis_page=basis_page), wrap, k
