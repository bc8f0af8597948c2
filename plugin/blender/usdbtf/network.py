"""The usdbtf Cycles networks: read a usdbtf asset, build its two Blender surfaces.

No user interface here (``__init__.py`` has it), so scripts and tests call these directly:
:func:`import_asset` lets Blender's USD importer bring the geometry and the
``UsdPreviewSurface`` fallback, then :func:`build_material` replaces each BTF material's
nodes with the usdbtf OSL shader (a script node, Cycles with Open Shading Language) on the
asset's GPU textures: ``gpu/tables.exr`` and the coefficient pages of the chosen ``lod``.
Textures are read by OSL's ``texture()`` with the closest filter (the shader filters the
coefficients itself), so they are plain file paths, not Blender images.

What the OSL shader can do in Cycles: an OSL surface returns closures that Cycles lights
itself; it is never told a light's direction.  So the material evaluates the BTF for one
sun, whose direction and strength :func:`sync_sun` copies into the shader (the add-on does
it whenever the scene changes), and returns that as emission.  That sun casts no shadow on
the material and other lights, the world and bounces do not light it: the **measured BTF,
one sun** (``SURFACE_BTF``).

The other surface, the **fitted lobes, every light** (``SURFACE_PRINCIPLED``,
:func:`build_principled`): a Principled BSDF on the asset's OpenPBR fallback maps (the
``open_pbr_surface`` network usdbtf authors on ``outputs:mtlx:surface``,
:func:`read_openpbr_maps`), which Cycles lights like any material: every lamp, the world,
bounces, shadows.  It is the per-texel fit of the BTF, not the measurement.  Both networks are
in the material's node tree; :func:`set_surface` links the chosen one to the output.  The
OpenPBR -> Principled mapping (Blender 4.x/5.x Principled BSDF):

=============================== ==================================================
open_pbr_surface                Principled BSDF
=============================== ==================================================
base_diffuse_roughness          Diffuse Roughness
specular_weight                 Specular IOR Level = F0 / 0.08 (F0 = 0.04 specular_weight), IOR 1.5
specular_color (sRGB file)      Specular Tint: Cycles' multiscatter lobe solved to MaterialX's (principled.py)
base_color x throughput ratios  Base Color (principled.py: untinted vs tinted layers, Oren-Nayar's c^3)
specular_roughness, _anisotropy Roughness = (alpha_x alpha_y)^(1/4), Anisotropic ~ a / 0.9
tangent map (cos, sin, 0)       Anisotropic Rotation = atan2(sin, cos) / 2 pi, Tangent: the UV map's
fuzz_weight / _color / _rough.  Sheen Weight / Sheen Tint / Sheen Roughness
normal map                      Normal Map node (tangent space, the UV map) -> Normal
coat, metalness, transmission   0 (the fit does not use them)
=============================== ==================================================
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import bpy
import mathutils

#: The Storm shader's Sdr identifier in usdbtf assets: its inputs name the textures.
STORM_ID = "UsdBtfSurface"
MAX_PAGES = 15
#: The shader inputs holding the working -> rendering space matrix's rows, and their identity
#: (usdbtf.gpu.shaders.RENDERING_INPUTS, IDENTITY_ROWS).
RENDERING_INPUTS = ("renderingMatrixR", "renderingMatrixG", "renderingMatrixB")
IDENTITY_ROWS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
#: The generated OSL surface: beside this file in the add-on's zip (scripts/blender_addon_zip.py
#: puts it there), else the plugin's own copy when the add-on runs from a usdbtf checkout
#: (plugin/blender/usdbtf -> plugin/usdBtf/resources/osl): the source tree holds it once.
_HERE = Path(__file__).resolve().parent
SHADER_FILE = next((p for p in (_HERE / "usdbtf_surface.osl",
                                 _HERE.parent.parent / "usdBtf" / "resources" / "osl" / "usdbtf_surface.osl")
                    if p.is_file()), _HERE / "usdbtf_surface.osl")
SCRIPT_TEXT = "usdbtf_surface.osl"
SCRIPT_NODE = "usdbtf OSL"
UV_MAP = "st"
FRAME_ATTRIBUTES = ("tangents", "bitangents")
#: The material's two surfaces (the add-on's menu items).
SURFACE_BTF = "BTF"
SURFACE_PRINCIPLED = "PRINCIPLED"
PRINCIPLED_NODE = "usdbtf Principled (fitted OpenPBR)"
#: OpenPBR map -> the image node of the asset's network (usdbtf.usd.asset.openpbr: "OpenPbr<Map>Image").
OPENPBR_MAPS = ("base", "specular", "fuzz", "params", "lobes", "tangent", "normal")
#: Colour maps (sRGB files); the rest are data.
_OPENPBR_COLOURS = ("base", "specular", "fuzz")
#: lobes.b x this = specular_weight (usdbtf.usd.asset.openpbr.SPECULAR_WEIGHT_SCALE).
SPECULAR_WEIGHT_SCALE = 25.0


def page_name(page: int) -> str:
    return f"page{page:02d}"


def _pxr():
    """Blender's own USD Python bindings."""
    _bundled_site_packages()
    from pxr import Usd, UsdShade

    return Usd, UsdShade


def _bundled_site_packages() -> None:
    """Put Blender's bundled site-packages (pxr, OpenImageIO, oslquery) on the path where it
    is not already: Blender does it at start, Blender as a Python module (the bpy wheel) not."""
    bundled = Path(bpy.utils.resource_path("LOCAL")) / "python" / "lib"
    for site in sorted(bundled.glob("python3*/site-packages")):
        if str(site) not in sys.path:
            sys.path.append(str(site))


def raw_texture(path: str) -> str:
    """A file OSL's texture() reads with the values ``path`` stores.

    OpenImageIO, which serves OSL's texture() in Cycles, premultiplies a PNG's colour by its
    alpha when it reads it (the PNG convention), and the coefficient pages hold a fourth
    coefficient in alpha, not a coverage.  So an 8-bit PNG page is re-encoded once, read with
    ``oiio:UnassociatedAlpha``, as a float32 EXR (exact: code / 255) in a cache folder named
    by the PNG's content; EXR pages (float codes) are used as they are."""
    if not path or not path.lower().endswith(".png"):
        return path
    import hashlib
    import tempfile

    _bundled_site_packages()
    import OpenImageIO as oiio

    data = Path(path).read_bytes()
    folder = Path(tempfile.gettempdir()) / "usdbtf-cycles"
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"{hashlib.sha256(data).hexdigest()[:32]}.exr"
    if out.is_file():
        return str(out)
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    source = oiio.ImageInput.open(path, config)
    if source is None:
        raise ValueError(f"{path}: cannot read ({oiio.geterror()})")
    pixels = source.read_image(oiio.FLOAT)
    spec = oiio.ImageSpec(source.spec().width, source.spec().height, source.spec().nchannels, oiio.FLOAT)
    source.close()
    spec.attribute("compression", "zip")
    partial = out.with_name(out.stem + f".{os.getpid()}.partial.exr")
    writer = oiio.ImageOutput.create(str(partial))
    if writer is None or not writer.open(str(partial), spec) or not writer.write_image(pixels) or not writer.close():
        raise ValueError(f"{out}: cannot write ({oiio.geterror()})")
    os.replace(partial, out)
    return str(out)


def _connected_file(shader, name: str) -> str:
    """Resolved path of the UsdUVTexture connected to ``shader``'s input ``name``, or ''."""
    _, UsdShade = _pxr()

    source = shader.GetInput(name)
    if not source or not source.HasConnectedSource():
        return ""
    node = UsdShade.Shader(source.GetConnectedSources()[0][0].source.GetPrim())
    value = node.GetInput("file").Get() if node.GetInput("file") else None
    return str(value.resolvedPath) if value is not None and value.resolvedPath else ""


def _storm_shader(stage):
    _, UsdShade = _pxr()

    for prim in stage.Traverse():
        shader = UsdShade.Shader(prim)
        if shader and shader.GetShaderId() == STORM_ID:
            return shader
    return None


def read_lods(asset: str) -> tuple[str, str, dict]:
    """(material prim name, default lod, {lod: {"basisCount", "whiteLevel", "rendering", "tables", "pages"}}) of a
    usdbtf asset (a .usda/.usdc on disk: the textures must be files OSL can open).

    The textures and basis count come from the asset's Storm network under each selection
    of its ``lod`` variant set (a level loads only its own pages)."""
    Usd, _ = _pxr()

    stage = Usd.Stage.Open(str(asset))
    if stage is None:
        raise ValueError(f"{asset}: cannot open as USD")
    root = stage.GetDefaultPrim() or next(iter(stage.GetPseudoRoot().GetChildren()), None)
    sets = root.GetVariantSets() if root else None
    lod_set = sets.GetVariantSet("lod") if sets is not None and sets.HasVariantSet("lod") else None
    names = lod_set.GetVariantNames() if lod_set else [""]
    default = lod_set.GetVariantSelection() if lod_set else ""
    lods, material = {}, ""
    for name in names:
        if lod_set:
            with Usd.EditContext(stage, stage.GetSessionLayer()):
                lod_set.SetVariantSelection(name)
        shader = _storm_shader(stage)
        if shader is None:
            raise ValueError(f"{asset}: no {STORM_ID} shader (not a usdbtf asset, or packaged without --gpu)")
        material = shader.GetPrim().GetParent().GetName()
        tables = _connected_file(shader, "tables")
        if not tables:
            raise ValueError(f"{asset}: the {STORM_ID} shader has no tables texture on disk (open the .usda, "
                             "not a .usdz)")
        count = shader.GetInput("basisCount").Get() if shader.GetInput("basisCount") else 0
        # The white level (usdbtf.photometry); an asset from before it has none: 1.
        white = shader.GetInput("whiteLevel").Get() if shader.GetInput("whiteLevel") else None
        # The working -> rendering space rows (issue 40: linear Rec.709, Blender's default scene
        # linear); an asset from before them has none: identity, the working space as before.
        rendering = [list(shader.GetInput(row).Get()) if shader.GetInput(row) else list(identity)
                     for row, identity in zip(RENDERING_INPUTS, IDENTITY_ROWS)]
        lods[name] = {"basisCount": int(count or 0), "whiteLevel": float(white or 1.0), "rendering": rendering,
                      "tables": tables,
                      "pages": [_connected_file(shader, page_name(p)) for p in range(MAX_PAGES)]}
    return material, default, lods


def read_openpbr_maps(asset: str) -> dict:
    """{map: resolved file} of the asset's OpenPBR fallback (:data:`OPENPBR_MAPS`), from the
    ``ND_image_*`` nodes named ``OpenPbr<Map>Image``; {} for an asset without one (older assets)."""
    Usd, UsdShade = _pxr()

    stage = Usd.Stage.Open(str(asset))
    found = {}
    for prim in stage.Traverse() if stage else ():
        shader = UsdShade.Shader(prim)
        name = prim.GetName()
        if not shader or not name.startswith("OpenPbr") or not name.endswith("Image"):
            continue
        key = name[len("OpenPbr"):-len("Image")].lower()
        value = shader.GetInput("file").Get() if shader.GetInput("file") else None
        if key in OPENPBR_MAPS and value is not None and value.resolvedPath:
            found[key] = str(value.resolvedPath)
    return found if all(k in found for k in OPENPBR_MAPS) else {}


def _image(tree, path: str, colour: bool, location):
    node = tree.nodes.new("ShaderNodeTexImage")
    node.image = bpy.data.images.load(path, check_existing=True)
    node.image.colorspace_settings.name = "sRGB" if colour else "Non-Color"
    node.interpolation = "Linear"
    node.extension = "REPEAT"
    node.location = location
    return node


def _pixels(path: str, colour: bool):
    """(H, W, 3) float64 of an image file as stored (bottom row first, as Blender holds it):
    sRGB-encoded values for colour files, data for the rest."""
    import numpy as np

    image = bpy.data.images.load(path, check_existing=True)
    image.colorspace_settings.name = "sRGB" if colour else "Non-Color"
    w, h = image.size
    rgba = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(rgba)
    return rgba.reshape(h, w, 4)[..., :3].astype(np.float64)


def _baked(name: str, rgb, data: bool):
    """A float image (packed into the .blend) holding ``rgb`` (H, W, 3), bottom row first."""
    import numpy as np

    h, w = rgb.shape[:2]
    image = bpy.data.images.get(name)
    if image is None or tuple(image.size) != (w, h):
        if image is not None:
            bpy.data.images.remove(image)
        image = bpy.data.images.new(name, w, h, alpha=False, float_buffer=True, is_data=data)
    rgba = np.ones((h, w, 4), np.float32)
    rgba[..., :3] = rgb
    image.pixels.foreach_set(rgba.ravel())
    try:
        image.pack()
    except RuntimeError:            # kept in memory; a saved .blend then lacks it
        pass
    return image


def build_principled(material, maps: dict, uv_map: str = UV_MAP):
    """Add to ``material``'s node tree the Principled BSDF of the fitted OpenPBR lobes on
    ``maps`` (:func:`read_openpbr_maps`); returns the Principled node (not linked to the
    output).  The inputs whose parameterisation differs from open_pbr_surface's (anisotropy,
    the specular energy compensation, the tinted layers' throughput, the base's multiple
    scattering: ``principled.py``) are baked per texel into float images
    named after the material; the rest read the asset's files."""
    import numpy as np

    from .principled import principled_inputs

    tree = material.node_tree
    links = tree.links
    inputs = principled_inputs(*(_pixels(maps[k], k in _OPENPBR_COLOURS)
                                 for k in ("base", "specular", "fuzz", "params", "lobes")))
    prefix = f"usdbtf {material.name} "
    baked = {"base": _baked(prefix + "base (Principled)", inputs["Base Color"], False),
             "tint": _baked(prefix + "specular tint (Principled)", inputs["Specular Tint"], False),
             "specular": _baked(prefix + "specular (Principled)", np.stack(
                 [inputs["Roughness"], inputs["Anisotropic"], inputs["Specular IOR Level"]], axis=-1), True)}
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.uv_map = uv_map
    uv.location = (-1400, -600)
    images = {}
    for row, key in enumerate(("fuzz", "params", "lobes", "tangent", "normal")):
        images[key] = _image(tree, maps[key], key in _OPENPBR_COLOURS, (-1100, -400 - 280 * row))
    for row, (key, image) in enumerate(baked.items()):
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image, node.interpolation, node.extension = image, "Linear", "REPEAT"
        node.location = (-1100, -1900 - 280 * row)
        images[key] = node
    for node in images.values():
        links.new(uv.outputs["UV"], node.inputs["Vector"])
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.name = bsdf.label = PRINCIPLED_NODE
    bsdf.location = (0, -600)
    bsdf.inputs["Metallic"].default_value = 0.0
    bsdf.inputs["IOR"].default_value = 1.5
    bsdf.inputs["Coat Weight"].default_value = 0.0
    links.new(images["base"].outputs["Color"], bsdf.inputs["Base Color"])
    links.new(images["tint"].outputs["Color"], bsdf.inputs["Specular Tint"])
    links.new(images["fuzz"].outputs["Color"], bsdf.inputs["Sheen Tint"])

    def separate(key, x):
        node = tree.nodes.new("ShaderNodeSeparateColor")
        node.location = (x, images[key].location[1])
        links.new(images[key].outputs["Color"], node.inputs["Color"])
        return node

    specular, params, lobes, tangent = (separate(k, -800) for k in ("specular", "params", "lobes", "tangent"))
    links.new(specular.outputs["Red"], bsdf.inputs["Roughness"])
    links.new(specular.outputs["Green"], bsdf.inputs["Anisotropic"])
    links.new(specular.outputs["Blue"], bsdf.inputs["Specular IOR Level"])
    if "Diffuse Roughness" in bsdf.inputs:               # Blender 4.3+
        links.new(params.outputs["Blue"], bsdf.inputs["Diffuse Roughness"])
    links.new(lobes.outputs["Red"], bsdf.inputs["Sheen Weight"])
    links.new(lobes.outputs["Green"], bsdf.inputs["Sheen Roughness"])

    def math_node(operation, a, b, x, c=None):
        node = tree.nodes.new("ShaderNodeMath")
        node.operation = operation
        node.location = (x, tangent.location[1])
        for i, value in enumerate((a, b, c)):
            if value is None:
                continue
            if isinstance(value, (int, float)):
                node.inputs[i].default_value = value
            else:
                links.new(value, node.inputs[i])
        return node.outputs["Value"]

    # The stored (cos, sin) * 0.5 + 0.5 -> phi / 2 pi (Blender's rotation is a fraction of a turn).
    cos_phi = math_node("MULTIPLY_ADD", tangent.outputs["Red"], 2.0, -650, -1.0)
    sin_phi = math_node("MULTIPLY_ADD", tangent.outputs["Green"], 2.0, -650, -1.0)
    phi = math_node("ARCTAN2", sin_phi, cos_phi, -500)
    links.new(math_node("DIVIDE", phi, 2.0 * 3.141592653589793, -350), bsdf.inputs["Anisotropic Rotation"])
    uv_tangent = tree.nodes.new("ShaderNodeTangent")
    uv_tangent.direction_type = "UV_MAP"
    uv_tangent.uv_map = uv_map
    uv_tangent.location = (-350, -2700)
    links.new(uv_tangent.outputs["Tangent"], bsdf.inputs["Tangent"])
    normal = tree.nodes.new("ShaderNodeNormalMap")
    normal.space = "TANGENT"
    normal.uv_map = uv_map
    normal.location = (-350, -2900)
    links.new(images["normal"].outputs["Color"], normal.inputs["Color"])
    links.new(normal.outputs["Normal"], bsdf.inputs["Normal"])
    return bsdf


def set_surface(material, surface: str) -> None:
    """Link ``surface`` (:data:`SURFACE_BTF` or :data:`SURFACE_PRINCIPLED`) to the material output."""
    tree = material.node_tree
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    source = (tree.nodes.get(PRINCIPLED_NODE).outputs["BSDF"] if surface == SURFACE_PRINCIPLED and
              tree.nodes.get(PRINCIPLED_NODE) else script_node(material).outputs["Radiance"])
    if surface == SURFACE_PRINCIPLED and tree.nodes.get(PRINCIPLED_NODE) is None:
        raise ValueError(f"usdbtf: {material.name} has no OpenPBR fallback (an asset packaged before it)")
    tree.links.new(source, output.inputs["Surface"])
    material["usdbtf_surface"] = surface


def _script_text():
    """The OSL source as a text data-block (saved inside the .blend, so a file renders on
    machines without the add-on's folder)."""
    text = bpy.data.texts.get(SCRIPT_TEXT)
    if text is None:
        text = bpy.data.texts.new(SCRIPT_TEXT)
    source = SHADER_FILE.read_text()
    if text.as_string() != source:
        text.clear()
        text.write(source)
    return text


def _compile(node) -> None:
    """Compile the script node's OSL and make its sockets (what the node's Update button does)."""
    import addon_utils

    _bundled_site_packages()                       # oslquery
    if not addon_utils.check("cycles")[1]:        # Blender as a Python module starts without it
        addon_utils.enable("cycles", default_set=False)
    from cycles import osl   # Blender's own Cycles add-on

    problems = []
    if not osl.update_script_node(node, lambda kind, message: problems.append((kind, message))):
        raise RuntimeError(f"usdbtf: the OSL shader did not compile: {problems}")


def _uses_frame_attributes(material) -> bool:
    """Whether every mesh using ``material`` has the packaged tangents and bitangents."""
    meshes = [o.data for o in bpy.data.objects if o.type == "MESH" and
              any(slot.material == material for slot in o.material_slots)]
    return bool(meshes) and all(all(a in m.attributes for a in FRAME_ATTRIBUTES) for m in meshes)


def build_material(material, asset: str, lods: dict, lod: str, surface: str = SURFACE_BTF,
                   openpbr: dict | None = None) -> None:
    """Replace ``material``'s nodes with the usdbtf OSL network for ``asset`` at ``lod`` and,
    where ``openpbr`` ({map: file}, :func:`read_openpbr_maps`) is given, the Principled BSDF of
    the fitted lobes beside it; ``surface`` is linked to the output (:func:`set_surface`)."""
    material.use_nodes = True
    tree = material.node_tree
    tree.nodes.clear()
    output = tree.nodes.new("ShaderNodeOutputMaterial")
    output.location = (600, 0)
    script = tree.nodes.new("ShaderNodeScript")
    script.name = script.label = SCRIPT_NODE
    script.mode = "INTERNAL"
    script.script = _script_text()
    script.location = (300, 0)
    _compile(script)
    tree.links.new(script.outputs["Radiance"], output.inputs["Surface"])
    script.inputs["incidentTowardsViewer"].default_value = 1     # Cycles' I is sd->wi
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.uv_map = UV_MAP
    uv.location = (0, 200)
    tree.links.new(uv.outputs["UV"], script.inputs["st"])
    if _uses_frame_attributes(material):
        # The packaged frame (object space): the same tangents usdbtf render uses.
        for row, (name, socket) in enumerate(zip(FRAME_ATTRIBUTES, ("frameTangent", "frameBitangent"))):
            attribute = tree.nodes.new("ShaderNodeAttribute")
            attribute.attribute_type = "GEOMETRY"
            attribute.attribute_name = name
            attribute.location = (-300, -150 * row)
            to_world = tree.nodes.new("ShaderNodeVectorTransform")
            to_world.vector_type = "VECTOR"
            to_world.convert_from = "OBJECT"
            to_world.convert_to = "WORLD"
            to_world.location = (0, -150 * row)
            tree.links.new(attribute.outputs["Vector"], to_world.inputs["Vector"])
            tree.links.new(to_world.outputs["Vector"], script.inputs[socket])
    else:
        # No packaged frame: MikkTSpace tangents of the UV map.
        tangent = tree.nodes.new("ShaderNodeTangent")
        tangent.direction_type = "UV_MAP"
        tangent.uv_map = UV_MAP
        tangent.location = (0, -150)
        tree.links.new(tangent.outputs["Tangent"], script.inputs["frameTangent"])
    if openpbr:
        build_principled(material, openpbr)
    set_surface(material, surface)
    material["usdbtf_asset"] = str(asset)
    material["usdbtf_lods"] = json.dumps(lods)
    apply_lod(material, lod)
    if hasattr(material, "usdbtf_lod"):       # the add-on's lod menu (registered): show the level
        material.usdbtf_lod = lod


def script_node(material):
    return material.node_tree.nodes.get(SCRIPT_NODE) if material and material.node_tree else None


def lods_of(material) -> dict:
    return json.loads(material.get("usdbtf_lods", "{}"))


def apply_lod(material, lod: str) -> None:
    """Point the shader at the textures and basis count of level ``lod``."""
    lods = lods_of(material)
    if lod not in lods:
        raise ValueError(f"usdbtf: {material.name} has no lod {lod!r} (has {', '.join(lods)})")
    node = script_node(material)
    level = lods[lod]
    node.inputs["tables"].default_value = level["tables"]
    for p, path in enumerate(level["pages"]):
        node.inputs[page_name(p)].default_value = raw_texture(path)
    node.inputs["basisCount"].default_value = level["basisCount"]
    node.inputs["whiteLevel"].default_value = level.get("whiteLevel", 1.0)
    for row, values in zip(RENDERING_INPUTS, level.get("rendering", IDENTITY_ROWS)):
        node.inputs[row].default_value = values


def sun_direction(sun) -> tuple[float, float, float]:
    """World-space direction towards a sun lamp (its local +Z)."""
    axis = sun.matrix_world.to_3x3() @ mathutils.Vector((0.0, 0.0, 1.0))
    axis.normalize()
    return tuple(axis)


def sync_sun(material, sun) -> None:
    """Copy ``sun``'s direction and strength (W/m^2: the irradiance; pi x the white level is the
    capture light, usdbtf.photometry) into the shader."""
    node = script_node(material)
    if node is None or sun is None or sun.type != "LIGHT" or sun.data.type != "SUN":
        return
    direction = sun_direction(sun)
    if tuple(node.inputs["lightDirection"].default_value) != direction:
        node.inputs["lightDirection"].default_value = direction
    if node.inputs["lightIrradiance"].default_value != sun.data.energy:
        node.inputs["lightIrradiance"].default_value = sun.data.energy


#: Blender 5's working spaces (bpy.data.colorspace.working_space_interop_id) -> OCIO names, as
#: usdbtf records btf:renderingColorSpace (usdbtf.color._USD_NAMES).
_WORKING_SPACES = {"lin_rec709_scene": "Linear Rec.709 (sRGB)", "lin_rec2020_scene": "Linear Rec.2020",
                   "lin_ap1_scene": "ACEScg"}


def working_space_warning(asset: str) -> str | None:
    """A line saying the OSL BTF's colours will be off, where the asset's BTF returns another
    space than this Blender file's working space (Blender 5: Linear Rec.709 by default, or
    Rec.2020 or ACEScg; the shader's renderingMatrix rows were computed for the asset's
    btf:renderingColorSpace, or are absent: its working space); None where they agree or
    Blender does not say (4.x: always Linear Rec.709)."""
    Usd, _ = _pxr()

    stage = Usd.Stage.Open(str(asset))
    shader = _storm_shader(stage) if stage else None
    if shader is None:
        return None
    material = shader.GetPrim().GetParent()
    attr = material.GetAttribute("btf:renderingColorSpace")
    returns = (attr.Get() if attr else "") or (material.GetAttribute("btf:colorSpace").Get() or "ACEScg")
    interop = getattr(getattr(bpy.data, "colorspace", None), "working_space_interop_id", "lin_rec709_scene")
    blender = _WORKING_SPACES.get(interop, interop)
    if blender == returns:
        return None
    return (f"usdbtf: {os.path.basename(asset)}'s BTF returns {returns} and this file's working space is "
            f"{blender}: the OSL BTF's colours will be off (package with --rendering-space {interop})")


def import_asset(asset: str, lod: str | None = None, surface: str = SURFACE_BTF) -> tuple[list, list]:
    """Import ``asset`` with Blender's USD importer and give its BTF materials the OSL
    network at ``lod`` (default: the asset's own selection) and the Principled BSDF of its
    fitted OpenPBR lobes, ``surface`` shown (:data:`SURFACE_BTF`: the measured BTF under one
    sun, Cycles with Open Shading Language, ``scene.cycles.shading_system = True``;
    :data:`SURFACE_PRINCIPLED`: the fit, lit by every light).  Returns (new objects, BTF materials)."""
    asset = os.path.abspath(asset)
    name, default, lods = read_lods(asset)
    openpbr = read_openpbr_maps(asset)
    lod = default if lod is None else lod
    if lod not in lods:
        raise ValueError(f"{asset}: no lod {lod!r} (has {', '.join(lods)})")
    objects, materials = set(bpy.data.objects), set(bpy.data.materials)
    result = bpy.ops.wm.usd_import(filepath=asset, import_usd_preview=True)
    if "FINISHED" not in result:
        raise RuntimeError(f"{asset}: Blender's USD import failed")
    new_objects = [o for o in bpy.data.objects if o not in objects]
    btf = [m for m in bpy.data.materials if m not in materials and (m.name == name or m.name.startswith(name + "."))]
    for material in btf:
        build_material(material, asset, lods, lod, surface, openpbr)
    return new_objects, btf
