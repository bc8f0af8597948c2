"""The OpenPBR Surface fallback of a packaged BTF material: fitted maps, written and wired.

Renderers with MaterialX (Karma, Arnold, RenderMan, V-Ray, Storm's MaterialX path) render
the Material's ``outputs:mtlx:surface``: an ``ND_open_pbr_surface_surfaceshader`` whose
inputs come from textures fitted to the BTF by :func:`usdbtf.openpbr.fit_openpbr`.  The
UsdPreviewSurface on ``outputs:surface`` (:mod:`usdbtf.usd.asset.fallback`) stays for renderers
and viewers without MaterialX::

    <stem>_textures/fallback/openpbr_base.png      base_color       8-bit sRGB (Rec.709), colour
    <stem>_textures/fallback/openpbr_specular.png  specular_color   8-bit sRGB (Rec.709), colour
    <stem>_textures/fallback/openpbr_fuzz.png      fuzz_color       8-bit sRGB (Rec.709), colour
    <stem>_textures/fallback/openpbr_params.png    16-bit RGB data: specular_roughness,
                                                   specular_roughness_anisotropy, base_diffuse_roughness
    <stem>_textures/fallback/openpbr_lobes.png     16-bit RGB data: fuzz_weight, fuzz_roughness,
                                                   specular_weight / 25
    <stem>_textures/fallback/openpbr_tangent.png   8-bit RGB data (cos phi, sin phi, 0) * 0.5 + 0.5:
                                                   the anisotropy's direction, through ``normalmap``
                                                   into ``geometry_tangent``
    <stem>_textures/fallback/openpbr_normal.png    8-bit RGB data n * 0.5 + 0.5 -> ``normalmap`` ->
                                                   ``geometry_normal``

The network is one list of MaterialX nodes (:func:`network`), authored into USD
(:func:`author_openpbr`) and into a MaterialX document (:func:`materialx_document`, which
MaterialX's own validation checks).  Colour files are declared ``srgb_texture`` (the
MaterialX name of the sRGB-encoded Rec.709 space: the image nodes are MaterialX's, so is
their colour management), data files ``raw``.  The files are written as the
UsdPreviewSurface's (:func:`usdbtf.usd.asset.fallback.encode_map_file`: lossless PNGs).
:func:`encode_maps` / :func:`decode_maps` are what is written and what a renderer reads back
(through :func:`usdbtf.usd.asset.fallback.shipped_pixels`: a lossy file's decoded pixels), so
the benchmark measures the fallback as shipped.
"""
from __future__ import annotations

import numpy as np

from ...color import processor
from ...openpbr import OpenPbrMaps
from .fallback import COLOUR_ENCODING, FALLBACK_DIR, add_map_files, shipped_pixels

__all__ = ["FIT_ERROR_KEY", "fit_errors", "MAP_FILES", "SPECULAR_WEIGHT_SCALE", "MTLX_COLOUR_SPACE", "encode_maps", "decode_maps", "add_maps",
           "network", "author_openpbr", "materialx_document", "SHADER_ID"]

SHADER_ID = "ND_open_pbr_surface_surfaceshader"
#: The colour maps' colour space as MaterialX names it (the sRGB-encoded files of fallback.COLOUR_ENCODING).
MTLX_COLOUR_SPACE = "srgb_texture"
#: specular_weight is stored divided by this (the fit's largest weight: F0 0.04 x 25 ~ 1).
SPECULAR_WEIGHT_SCALE = 25.0
#: map -> (file under FALLBACK_DIR, texture kind for textures.TextureSet)
MAP_FILES = {"base": ("openpbr_base.png", "srgb"), "specular": ("openpbr_specular.png", "srgb"),
             "fuzz": ("openpbr_fuzz.png", "srgb"), "params": ("openpbr_params.png", "unorm"),
             "lobes": ("openpbr_lobes.png", "unorm"), "tangent": ("openpbr_tangent.png", "unorm"),
             "normal": ("openpbr_normal.png", "unorm")}
_COLOUR = {"base": "base_color", "specular": "specular_color", "fuzz": "fuzz_color"}


def _unorm(values: np.ndarray, top: int) -> np.ndarray:
    dtype = np.uint8 if top == 255 else np.uint16
    return np.rint(np.clip(values, 0.0, 1.0) * top).astype(dtype)


def encode_maps(maps: OpenPbrMaps, ocio_config: str | None = None) -> dict[str, np.ndarray]:
    """{map: (H, W, 3) pixels as written} (uint8, or uint16 for ``params`` and ``lobes``).
    Raises BTFError rather than write a non-finite fit."""
    from ...errors import BTFError

    for name in (*OpenPbrMaps.COLOURS, *OpenPbrMaps.SCALARS, "normal"):
        if not np.isfinite(getattr(maps, name)).all():
            raise BTFError(f"the fitted OpenPBR fallback's {name} map is not finite (is the BTF?)")
    to_file = processor(maps.working_space, COLOUR_ENCODING, ocio_config)
    out = {key: _unorm(to_file.apply(np.ascontiguousarray(getattr(maps, name), np.float32)), 255)
           for key, name in _COLOUR.items()}
    out["params"] = _unorm(np.stack([maps.specular_roughness, maps.specular_anisotropy,
                                     maps.base_diffuse_roughness], axis=-1), 65535)
    out["lobes"] = _unorm(np.stack([maps.fuzz_weight, maps.fuzz_roughness,
                                    maps.specular_weight / SPECULAR_WEIGHT_SCALE], axis=-1), 65535)
    phi = np.asarray(maps.specular_rotation, np.float64)
    out["tangent"] = _unorm(np.stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)], axis=-1) * 0.5 + 0.5, 255)
    out["normal"] = _unorm(np.asarray(maps.normal) * 0.5 + 0.5, 255)
    return out


def decode_maps(pixels: dict[str, np.ndarray], working_space: str, *, ocio_config: str | None = None,
                white_level: float = 1.0) -> OpenPbrMaps:
    """The inputs a renderer reads from :func:`encode_maps`'s pixels (image nodes, the
    network's arithmetic, ``normalmap``), back in ``working_space`` for comparison with the BTF."""
    from_file = processor(COLOUR_ENCODING, working_space, ocio_config)
    colours = {name: from_file.apply(np.asarray(pixels[key], np.float32) / 255.0) for key, name in _COLOUR.items()}
    params = np.asarray(pixels["params"], np.float32) / 65535.0
    lobes = np.asarray(pixels["lobes"], np.float32) / 65535.0
    unit = lambda key: np.asarray(pixels[key], np.float32) / 255.0 * 2.0 - 1.0  # noqa: E731
    normal = unit("normal")
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)
    tangent = unit("tangent")
    rotation = np.mod(np.arctan2(tangent[..., 1], tangent[..., 0]), np.pi).astype(np.float32)
    return OpenPbrMaps(colours["base_color"], params[..., 2], lobes[..., 2] * np.float32(SPECULAR_WEIGHT_SCALE),
                       colours["specular_color"], params[..., 0], params[..., 1], rotation, lobes[..., 0],
                       colours["fuzz_color"], lobes[..., 1], normal.astype(np.float32), working_space,
                       float(white_level))


def add_maps(maps: OpenPbrMaps, textures, ocio_config: str | None = None, texels=None) -> dict:
    """Encode the maps as their files (in memory) into ``textures`` (a textures.TextureSet,
    under FALLBACK_DIR); {map: its name in ``textures``}.  ``texels``: as
    :func:`usdbtf.usd.asset.fallback.add_maps` (maps of a quilt's source texels, gathered per pixel)."""
    return add_map_files(encode_maps(maps, ocio_config), MAP_FILES, textures, texels, "OpenPBR maps")


# ------------------------------------------------------------------ the network
def network(files: dict, wrap: str = "repeat") -> list[tuple]:
    """The MaterialX nodes of the fallback: [(name, nodedef, {input: (type, value)})] where a
    value is a constant, ``("file", path, colour space)`` or ``("node", name, output)``;
    ``files``: {map: asset path}, ``wrap``: "repeat" or "clamp"."""
    address = "periodic" if wrap == "repeat" else "clamp"
    nodes = [("texcoord", "ND_texcoord_vector2", {})]

    def image(name, key, kind):
        space = MTLX_COLOUR_SPACE if MAP_FILES[key][1] == "srgb" else "raw"
        nodes.append((name, f"ND_image_{kind}", {"file": ("filename", ("file", files[key], space)),
                                                  "texcoord": ("vector2", ("node", "texcoord", "out")),
                                                  "uaddressmode": ("string", address),
                                                  "vaddressmode": ("string", address)}))

    for key in ("base", "specular", "fuzz"):
        image(f"{key}_image", key, "color3")
    for key in ("params", "lobes", "tangent", "normal"):
        image(f"{key}_image", key, "vector3")
    nodes += [
        ("params", "ND_separate3_vector3", {"in": ("vector3", ("node", "params_image", "out"))}),
        ("lobes", "ND_separate3_vector3", {"in": ("vector3", ("node", "lobes_image", "out"))}),
        ("specular_weight", "ND_multiply_float", {"in1": ("float", ("node", "lobes", "outz")),
                                                  "in2": ("float", SPECULAR_WEIGHT_SCALE)}),
        ("normal", "ND_normalmap_float", {"in": ("vector3", ("node", "normal_image", "out"))}),
        # normalmap turns the stored (cos, sin, 0) into T cos + B sin: the rotated tangent.
        ("tangent", "ND_normalmap_float", {"in": ("vector3", ("node", "tangent_image", "out"))}),
        ("OpenPbrSurface", SHADER_ID, {
            "base_color": ("color3", ("node", "base_image", "out")),
            "base_diffuse_roughness": ("float", ("node", "params", "outz")),
            "specular_weight": ("float", ("node", "specular_weight", "out")),
            "specular_color": ("color3", ("node", "specular_image", "out")),
            "specular_roughness": ("float", ("node", "params", "outx")),
            "specular_roughness_anisotropy": ("float", ("node", "params", "outy")),
            "fuzz_weight": ("float", ("node", "lobes", "outx")),
            "fuzz_color": ("color3", ("node", "fuzz_image", "out")),
            "fuzz_roughness": ("float", ("node", "lobes", "outy")),
            "geometry_normal": ("vector3", ("node", "normal", "out")),
            "geometry_tangent": ("vector3", ("node", "tangent", "out"))}),
    ]
    return nodes


_OUTPUT_TYPES = {"ND_texcoord_vector2": "vector2", "ND_image_color3": "color3", "ND_image_vector3": "vector3",
                 "ND_separate3_vector3": "float", "ND_multiply_float": "float", "ND_normalmap_float": "vector3",
                 SHADER_ID: "surfaceshader"}
_PREFIX = "OpenPbr"


def _usd_type(kind: str):
    from pxr import Sdf

    return {"float": Sdf.ValueTypeNames.Float, "color3": Sdf.ValueTypeNames.Color3f,
            "vector3": Sdf.ValueTypeNames.Float3, "vector2": Sdf.ValueTypeNames.Float2,
            "string": Sdf.ValueTypeNames.String, "filename": Sdf.ValueTypeNames.Asset,
            "surfaceshader": Sdf.ValueTypeNames.Token}[kind]


#: customData key on each fallback's surface prim: its fitted error (:func:`fit_errors`).
FIT_ERROR_KEY = "usdbtf:fitErrorPercent"


def author_openpbr(stage, material, textures: dict, *, wrap: str = "repeat", fit_errors: dict | None = None) -> None:
    """The OpenPBR network on ``material`` (its ``outputs:mtlx:surface``) from the textures of
    :func:`add_maps` ({map: textures.Texture}); node prims are named ``OpenPbr<node>`` beside
    the UsdPreviewSurface's.  ``fit_errors`` (:func:`fit_errors`): recorded as customData
    :data:`FIT_ERROR_KEY` on this surface and on the UsdPreviewSurface (``PreviewSurface``)."""
    from pxr import Sdf, UsdShade

    mpath = material.GetPath()
    prims = {}
    for name, nodedef, inputs in network({k: t.path for k, t in textures.items()}, wrap):
        prim_name = name if name == "OpenPbrSurface" else _PREFIX + "".join(p.title() for p in name.split("_"))
        shader = UsdShade.Shader.Define(stage, mpath.AppendChild(prim_name))
        shader.CreateIdAttr(nodedef)
        for inp, (kind, value) in inputs.items():
            attr_input = shader.CreateInput(inp, _usd_type(kind))
            if isinstance(value, tuple) and value[0] == "node":
                src = prims[value[1]]
                attr_input.ConnectToSource(src.ConnectableAPI(), value[2])
            elif isinstance(value, tuple) and value[0] == "file":
                attr_input.Set(Sdf.AssetPath(value[1]))
                attr_input.GetAttr().SetColorSpace(value[2])
            else:
                attr_input.Set(value)
        outputs = ("outx", "outy", "outz") if nodedef == "ND_separate3_vector3" else ("out",)
        for out in outputs:
            shader.CreateOutput(out, _usd_type(_OUTPUT_TYPES[nodedef]))
        prims[name] = shader
    material.CreateSurfaceOutput("mtlx").ConnectToSource(prims["OpenPbrSurface"].GetOutput("out"))
    if fit_errors:
        prims["OpenPbrSurface"].GetPrim().SetCustomDataByKey(FIT_ERROR_KEY, float(fit_errors["open_pbr"]))
        preview = stage.GetPrimAtPath(mpath.AppendChild("PreviewSurface"))
        if preview:
            preview.SetCustomDataByKey(FIT_ERROR_KEY, float(fit_errors["preview_surface"]))


def materialx_document(files: dict, wrap: str = "repeat"):
    """A MaterialX document (MaterialX.Document, standard libraries imported) of the same
    network, with a ``surfacematerial`` node: what :func:`author_openpbr` writes, for
    MaterialX's own validation and code generation."""
    import MaterialX as mx

    lib = mx.createDocument()
    mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), lib)
    doc = mx.createDocument()
    doc.importLibrary(lib)
    made = {}
    for name, nodedef, inputs in network(files, wrap):
        nd = lib.getNodeDef(nodedef)
        if nd is None:
            raise LookupError(f"MaterialX has no nodedef {nodedef}")
        node = doc.addNodeInstance(nd, name)
        for inp, (kind, value) in inputs.items():
            port = node.addInput(inp, kind)
            if isinstance(value, tuple) and value[0] == "node":
                port.setNodeName(value[1])
                if made[value[1]].getType() == "multioutput":
                    port.setOutputString(value[2])
            elif isinstance(value, tuple) and value[0] == "file":
                port.setValueString(value[1])
                port.setColorSpace(value[2])
            else:
                port.setValue(value, kind) if kind != "string" else port.setValueString(value)
        made[name] = node
    doc.addMaterialNode("OpenPbrMaterial", made["OpenPbrSurface"])
    return doc


# ------------------------------------------------------------------ the fits' errors
def fit_errors(cbtf, preview, openpbr: OpenPbrMaps, *, samples: int = 256, texels_per_block: int = 4096) -> dict:
    """{"preview_surface": %, "open_pbr": %}: each fallback, as shipped (its maps encoded and
    decoded as the files hold them), against ``cbtf``'s reconstruction at ``samples`` measured
    samples the fits did not use (:func:`usdbtf.svbrdf.validation_samples`), in the working
    space: 100 sum|BTF - fallback| / sum(BTF), the paper's metric."""
    from ... import openpbr as model
    from ... import svbrdf
    from ...svbrdf import _reconstruct
    from .fallback import MAP_FILES as PREVIEW_FILES
    from .fallback import decode_maps as decode_preview
    from .fallback import encode_maps as encode_preview

    white = openpbr.white_level
    sv = decode_preview(shipped_pixels(encode_preview(preview, cbtf.ocio_config), PREVIEW_FILES), cbtf.working_space,
                        ocio_config=cbtf.ocio_config, white_level=white)
    op = decode_maps(shipped_pixels(encode_maps(openpbr, cbtf.ocio_config), MAP_FILES), cbtf.working_space,
                     ocio_config=cbtf.ocio_config, white_level=white)
    val = svbrdf.validation_samples(cbtf, svbrdf.fit_samples(cbtf), samples)
    view, light = cbtf.sampling.view[val], cbtf.sampling.light[val]
    rows = cbtf.basis_values()[val]
    total = err_sv = err_op = 0.0
    n = cbtf.width * cbtf.height
    for t0 in range(0, n, texels_per_block):
        block = slice(t0, min(t0 + texels_per_block, n))
        truth = _reconstruct(cbtf, rows, block)
        total += float(np.abs(truth).sum(dtype=np.float64))
        err_sv += float(np.abs(truth - svbrdf.evaluate(sv, view, light, block)).sum(dtype=np.float64))
        err_op += float(np.abs(truth - model.evaluate(op, view, light, block)).sum(dtype=np.float64))
    total = max(total, 1e-30)
    return {"preview_surface": 100.0 * err_sv / total, "open_pbr": 100.0 * err_op / total}
