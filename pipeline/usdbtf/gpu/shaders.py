"""One GLSL source, three shaders: Storm glslfx, MaterialX genglsl, the headless harness.

``glsl/btf_core.glsl`` is the only hand-written shading code (equation 2 with the CPU
renderer's hemisphere interpolation).  This module assembles it, unchanged, with a thin
environment-specific wrapper for each consumer:

* :func:`storm_glslfx` -> ``plugin/usdBtf/resources/shaders/UsdBtfSurface.glslfx``: the Storm
  surface shader (``surfaceShader(Peye, Neye, ...)``, lights from ``GetLightSource(i)``);
* :func:`sdr_definition_usda` -> ``plugin/usdBtf/resources/sdr/UsdBtfSurface.usda``: its Sdr
  definition, found by Sdr's filesystem discovery (the file's stem is the node identifier;
  see :mod:`usdbtf.usd.plugin`);
* :func:`materialx_impl` / :func:`materialx_defs` -> ``plugin/usdBtf/resources/materialx/``:
  the ``usdbtf_bsdf`` nodedef, its genglsl implementation (and its genosl one, from
  :mod:`usdbtf.gpu.osl`), and the ``usdbtf_surface`` node graph that feeds it from image nodes;
* :mod:`usdbtf.gpu.osl` -> ``plugin/usdBtf/resources/osl/usdbtf_surface.osl`` (which the Blender
  add-on reads, and its zip copies): the core translated to OSL
  (:mod:`usdbtf.gpu.glsl_to_osl`);
* :func:`harness_fragment` / :data:`HARNESS_VERTEX`: the headless OpenGL check (gpu.headless).

The plugin files are generated and committed; ``python -m usdbtf.gpu.shaders`` rewrites
them and ``--check`` reports stale ones (the tests check byte identity).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from ..plugin_folder import SHADER_ID
from . import osl
from .core import GLSL_DIR, MTLX_BSDF, MTLX_SURFACE, core_source, page_name, page_sampler
from .tables import MAX_PAGES

__all__ = ["SHADER_ID", "INPUTS", "IDENTITY_ROWS", "RENDERING_INPUTS", "PRIMVARS", "GLSL_DIR", "MTLX_BSDF",
           "core_source", "page_name", "page_sampler",
           "storm_glslfx", "sdr_definition_usda", "materialx_impl", "materialx_defs", "harness_fragment", "HARNESS_VERTEX", "plugin_files",
           "write_plugin_files", "stale_plugin_files"]

#: Primvars the Storm shader reads (texture coordinates, the packaged tangent frame).
PRIMVARS = ("st", "tangents", "bitangents")


#: The rendering matrix's rows that leave the working space as it is (an asset without them).
IDENTITY_ROWS = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
#: The shader inputs that carry the working -> rendering space matrix, one row each (usdbtf.color.linear_matrix).
RENDERING_INPUTS = ("renderingMatrixR", "renderingMatrixG", "renderingMatrixB")

# (name, Sdf type, glslfx default, doc) of the Storm shader's inputs, in order.  The matrix rows are
# color3f: what Sdr's glslfx parser (USD 25.08) makes of a 3-float default, so the two Sdr definitions
# (the glslfx's and the .usda's) agree; the asset declares them raw (data, no colour conversion).
INPUTS = ([("basisCount", "int", 0, "Basis vectors to use; 0 = all the tables hold (a LOD uses fewer)."),
           ("exposure", "float", 1.0, "Multiplier on the result (1: radiance = value x irradiance / (pi x whiteLevel), "
                                      "usdbtf.photometry)."),
           ("whiteLevel", "float", 1.0, "The BTF value a white Lambertian lit head-on reads (btf:whiteLevel): a light "
                                        "of irradiance pi x whiteLevel reproduces the measured values."),
           *[(f"renderingMatrix{c}", "color3f", row, f"Row {c} of the working space -> rendering space matrix "
                                                    "(btf:renderingColorSpace; usdbtf.color.linear_matrix): the "
                                                    "shader returns rendering-space radiance.  Identity: the "
                                                    "working space (an asset packaged before issue 40's colour fix).")
             for c, row in zip("RGB", IDENTITY_ROWS)],
           ("tables", "float", 0.0, "The tables texture (basis, hemisphere lookups, de-quantisation, the packs' "
                                    "directory); connect a UsdUVTexture, read with texelFetch.")]
          + [(page_name(p), "float", 0.0, f"Coefficient page {p}: tiles of coefficient packs (the tables' "
                                          "directory says which), read with texelFetch (all 4 channels).")
             for p in range(MAX_PAGES)])


def _lines(template: str, count: int = MAX_PAGES) -> str:
    return "".join(template.format(p=p, name=page_name(p)) for p in range(count))


# ------------------------------------------------------------------ Storm
_STORM_SURFACE = """\
// Storm's view of the tangent frame.  Storm's fragment stage has the eye-space position
// and normal, the interpolated primvars (object space), the prim's own transform and the
// view matrix, but not the instancers' transforms (instancing.glslfx is a vertex-stage
// library).  So: the packaged primvars:tangents / bitangents (object space -> eye space)
// on a prim that is not instanced (Storm defines HD_INSTANCER_NUM_LEVELS 0 then); else, and
// where the primvars are absent, the frame of
// dP/dst from screen-space derivatives (SurfaceHelpers.TangentSpace, what
// UsdPreviewSurface's normal maps use: the same axes, +s = image right, +t = image up,
// constant over a triangle).
mat3 usdBtfFrame(vec3 Peye, vec3 Neye, vec2 st)
{{
    mat3 tbn = ComputeTBNMatrix(Peye, Neye, st);
    vec3 tangent = tbn[0];
    vec3 bitangent = tbn[1];
#if defined(HD_HAS_tangents) && defined(HD_HAS_bitangents) && defined(HD_HAS_transform) && \\
    (!defined(HD_INSTANCER_NUM_LEVELS) || HD_INSTANCER_NUM_LEVELS == 0)
    MAT4 toEye = GetWorldToViewMatrix() * HdGet_transform();
    vec3 t = vec3(toEye * vec4(HdGet_tangents().xyz, 0.0));
    vec3 b = vec3(toEye * vec4(HdGet_bitangents().xyz, 0.0));
    if (dot(t, t) > 0.0 && dot(b, b) > 0.0) {{    // a fallback (absent primvar) reads zero
        tangent = t;
        bitangent = b;
    }}
#endif
    return btfFrame(Neye, tangent, bitangent);
}}

vec4
surfaceShader(vec4 Peye, vec3 Neye, vec4 color, vec4 patchCoord)
{{
    vec3 c = vec3(0.0);
    // Storm defines HD_HAS_<input> for every input, HD_HAS_COORD_<input> only for those
    // bound to a texture: the latter says a sampler exists.
#if defined(HD_HAS_COORD_tables) && defined(HD_HAS_st)
    vec2 st = HdGet_st().xy;
    mat3 frame = usdBtfFrame(Peye.xyz, Neye, st);
    int k = HdGet_basisCount() > 0 ? HdGet_basisCount() : 1 << 20;     // 0: all the tables hold
    // Pages without a texture (a level of detail's blocked ones) read the tables: never
    // addressed, as the directory names only the pages the first k vectors use.
{pages}
    ivec3 viewIndex;
    vec3 viewWeight;
    // Towards the eye: from the point to the eye, or the view axis under an orthographic
    // camera (projection[3][3] == 1, as hdSt's volume shader tells them apart).
    vec3 toEye = abs(GetProjectionMatrix()[3][3] - 1.0) < 1e-5 ? vec3(0.0, 0.0, 1.0) : normalize(-Peye.xyz);
    btfViewLookup(HdGetSampler_tables(), btfLocal(frame, toEye), viewIndex, viewWeight);
#if NUM_LIGHTS > 0
    for (int i = 0; i < NUM_LIGHTS; ++i) {{
        LightSource light = GetLightSource(i);
        if (light.isIndirectLight) {{
            continue;
        }}
        vec3 l = (light.position.w == 0.0) ? normalize(light.position.xyz)
                                           : normalize((light.position - Peye).xyz);
        float intensity = lightDistanceAttenuation(Peye, i) * lightSpotAttenuation(l, i);
#if USE_SHADOWS
        intensity *= light.hasShadow ? shadowing(/*lightIndex=*/i, Peye) : 1.0;
#endif
        // One light at a time: a light's colour multiplies its whole contribution.
        // In the rendering space, where the light's colour is.
        c += light.diffuse.rgb * btfToRendering(btfShadeLight(HdGetSampler_tables(), BTF_PAGE_ARGS, viewIndex,
                                                              viewWeight, btfLocal(frame, l), intensity, st, k),
                                                HdGet_renderingMatrixR(), HdGet_renderingMatrixG(),
                                                HdGet_renderingMatrixB());
    }}
#endif
    c *= HdGet_exposure() * btfRadiancePerIrradiance(HdGet_whiteLevel());     // usdbtf.photometry
#endif
    return ApplyColorOverrides(vec4(c, 1.0));
}}
"""


def storm_glslfx() -> str:
    """The Storm surface shader (glslfx) around the shared core."""
    config = {
        "attributes": {name: {"type": "vec2" if name == "st" else "vec3"} for name in PRIMVARS},
        "parameters": {name: {"default": default, "documentation": doc} for name, _, default, doc in INPUTS},
        "parameterOrder": [name for name, *_ in INPUTS],
        "techniques": {"default": {"surfaceShader": {"source": ["SurfaceHelpers.TangentSpace", "UsdBtf.Core",
                                                                "UsdBtf.Surface"]}}},
    }
    pages = _lines("#ifdef HD_HAS_COORD_{name}\n    #define btfPage{p:02d} HdGetSampler_{name}()\n#else\n"
                   "    #define btfPage{p:02d} HdGetSampler_tables()\n#endif\n").rstrip("\n")
    surface = _STORM_SURFACE.format(pages=pages)
    return ("-- glslfx version 0.1\n\n"
            "// usdbtf: measured BTF (Koudelka et al. 2003) preview for Hydra Storm.\n"
            "// GENERATED by usdbtf.gpu.shaders from pipeline/usdbtf/gpu/glsl/btf_core.glsl; do not edit.\n\n"
            "#import $TOOLS/hdSt/shaders/surfaceHelpers.glslfx\n\n"
            "-- configuration\n" + json.dumps(config, indent=4) + "\n\n"
            "-- glsl UsdBtf.Core\n\n" + core_source() + "\n\n"
            "-- glsl UsdBtf.Surface\n\n" + surface)


def sdr_definition_usda() -> str:
    """Sdr definition of the Storm shader, for Sdr's filesystem discovery: the node is the
    root prim named like the file (``sdr/UsdBtfSurface.usda`` -> ``UsdBtfSurface``).

    Filesystem discovery gives a ``.usda`` node the usdShade parser's source type, which is
    empty, so the parser reads the universal ``info:sourceAsset``; ``info:glslfx:sourceAsset``
    names the same file for tools that read definitions by source type."""
    glslfx = f"@../shaders/{SHADER_ID}.glslfx@"
    lines = ["#usda 1.0",
             "(",
             '    doc = """GENERATED by usdbtf.gpu.shaders; do not edit.',
             "    Sdr definition of the usdbtf Storm preview shader.  Any USD process finds it with",
             "    PXR_SDR_FS_PLUGIN_SEARCH_PATHS=<plugin>/usdBtf/resources/sdr and",
             '    PXR_SDR_FS_PLUGIN_ALLOWED_EXTS=usda (what `usdbtf env` prints)."""',
             ")",
             "",
             f'def Shader "{SHADER_ID}" (',
             '    doc = "Measured BTF (Koudelka et al. 2003): equation 2 per light, for Hydra Storm."',
             "    sdrMetadata = {",
             f'        string primvars = "{"|".join(PRIMVARS)}"',
             '        token role = "surface"',
             "    }",
             ")",
             "{",
             f'    uniform token info:id = "{SHADER_ID}"',
             '    uniform token info:implementationSource = "sourceAsset"',
             f"    uniform asset info:sourceAsset = {glslfx}",
             f"    uniform asset info:glslfx:sourceAsset = {glslfx}",
             ""]
    for name, kind, default, doc in INPUTS:
        value = (repr(default) if kind == "float" else
                 "(" + ", ".join(repr(v) for v in default) + ")" if kind == "color3f" else str(default))
        lines += [f"    {kind} inputs:{name} = {value} (", f'        doc = "{doc}"', "    )"]
    lines += ["", "    token outputs:surface (", "        sdrMetadata = {",
              '            string renderType = "terminal surface"', "        }", "    )", "}", ""]
    return "\n".join(lines)


# ------------------------------------------------------------------ MaterialX
_MTLX_FUNCTION = """\
// MaterialX genglsl implementation of ND_{bsdf}: called once per light with
// closureData.L / .V (world space, towards the light / the eye); the response is the
// measured BTF value, which already holds the light's foreshortening.  No environment
// term: the measurement has no such thing.
// lightdirection is for OSL (genosl), which cannot be called per light; GLSL is.
void mx_{bsdf}(ClosureData closureData, sampler2D btfTables, BTF_PAGE_PARAMS, vec2 texcoord, int basisCount,
               float weight, vec3 normal, vec3 tangent, vec3 bitangent, vec3 lightdirection, float whiteLevel,
               vec3 renderingMatrixR, vec3 renderingMatrixG, vec3 renderingMatrixB, inout BSDF bsdf)
{{
    bsdf.throughput = vec3(0.0);
    bsdf.response = vec3(0.0);
    if (closureData.closureType != CLOSURE_TYPE_REFLECTION || weight <= 0.0) {{
        return;
    }}
    mat3 frame = btfFrame(normal, tangent, bitangent);
    ivec3 viewIndex;
    vec3 viewWeight;
    btfViewLookup(btfTables, btfLocal(frame, closureData.V), viewIndex, viewWeight);
    int k = basisCount > 0 ? basisCount : 1 << 20;
    bsdf.response = weight * closureData.occlusion
                  * btfToRendering(btfShadeLight(btfTables, BTF_PAGE_ARGS, viewIndex, viewWeight,
                                                 btfLocal(frame, closureData.L), btfRadiancePerIrradiance(whiteLevel),
                                                 texcoord, k),
                                   renderingMatrixR, renderingMatrixG, renderingMatrixB);
}}
"""


def materialx_impl() -> str:
    """genglsl source of ND_usdbtf_bsdf (the shared core plus the closure wrapper)."""
    return ("// GENERATED by usdbtf.gpu.shaders from pipeline/usdbtf/gpu/glsl/btf_core.glsl; do not edit.\n"
            '#include "libraries/pbrlib/genglsl/lib/mx_closure_type.glsl"\n\n' + core_source() + "\n"
            + _MTLX_FUNCTION.format(bsdf=MTLX_BSDF))


#: The nodedefs' white level (usdbtf.photometry): the BTF value a white Lambertian lit head-on reads.
_WHITE_LEVEL_INPUT = ('    <input name="whiteLevel" type="float" value="1.0" uniform="true" doc="The BTF value a white '
                      'Lambertian lit head-on reads (btf:whiteLevel): radiance = value x irradiance / (pi x '
                      'whiteLevel), usdbtf.photometry." />')
#: The nodedefs' rendering matrix rows (usdbtf.color.linear_matrix; identity: the working space).
_RENDERING_INPUTS = [f'    <input name="{name}" type="vector3" value="{", ".join(repr(v) for v in row)}" uniform="true" '
                     f'doc="Row {name[-1]} of the working space -> rendering space matrix (btf:renderingColorSpace): '
                     'the node returns rendering-space radiance; identity: the working space." />'
                     for name, row in zip(RENDERING_INPUTS, IDENTITY_ROWS)]


def materialx_defs() -> str:
    """The nodedefs, the genglsl implementation element and the usdbtf_surface graph."""
    pages = [page_name(p) for p in range(MAX_PAGES)]
    doc = "Measured BTF (Koudelka et al. 2003), equation 2 per light; textures written by usdbtf package."
    files = ['    <input name="tables" type="filename" uniform="true" />']
    files += [f'    <input name="{n}" type="filename" uniform="true" />' for n in pages]
    out = ['<?xml version="1.0"?>',
           "<!-- GENERATED by usdbtf.gpu.shaders; do not edit. Put this folder on PXR_MTLX_PLUGIN_SEARCH_PATHS"
           " (Hydra) or a MaterialX library search path. -->",
           '<materialx version="1.39">',
           # nodegroup texture2d: Storm's MaterialX path binds the filename inputs of texture
           # nodes only (a pbr node's files would reach the shader as unbound HdGetSampler_*).
           f'  <nodedef name="ND_{MTLX_BSDF}" node="{MTLX_BSDF}" nodegroup="texture2d" doc="{doc} The tables and '
           'the coefficient pages are read texel by texel (the shader filters the packs itself).">',
           *files,
           '    <input name="texcoord" type="vector2" defaultgeomprop="UV0" />',
           '    <input name="basisCount" type="integer" value="0" uniform="true" />',
           '    <input name="weight" type="float" value="1.0" />',
           '    <input name="normal" type="vector3" defaultgeomprop="Nworld" />',
           '    <input name="tangent" type="vector3" defaultgeomprop="Tworld" />',
           '    <input name="bitangent" type="vector3" defaultgeomprop="Bworld" />',
           '    <input name="lightdirection" type="vector3" value="0.0, 0.0, 0.0" doc="genosl only (an OSL closure '
           'cannot be evaluated per light): world-space direction towards the one light the BTF is evaluated for, '
           'returned as emission; 0: the view direction. genglsl ignores it (it is called per light)." />',
           _WHITE_LEVEL_INPUT,
           *_RENDERING_INPUTS,
           '    <output name="out" type="BSDF" />',
           "  </nodedef>",
           f'  <implementation name="IM_{MTLX_BSDF}_genglsl" nodedef="ND_{MTLX_BSDF}" '
           f'file="genglsl/mx_{MTLX_BSDF}.glsl" function="mx_{MTLX_BSDF}" target="genglsl" />',
           f'  <implementation name="IM_{MTLX_BSDF}_genosl" nodedef="ND_{MTLX_BSDF}" '
           f'file="genosl/mx_{MTLX_BSDF}.osl" function="mx_{MTLX_BSDF}" target="genosl" />',
           f'  <nodedef name="ND_{MTLX_SURFACE}" node="{MTLX_SURFACE}" nodegroup="pbr" doc="{doc}">',
           *files,
           '    <input name="basisCount" type="integer" value="0" uniform="true" />',
           '    <input name="texcoord" type="vector2" defaultgeomprop="UV0" />',
           _WHITE_LEVEL_INPUT,
           *_RENDERING_INPUTS,
           '    <output name="out" type="surfaceshader" />',
           "  </nodedef>",
           f'  <nodegraph name="NG_{MTLX_SURFACE}" nodedef="ND_{MTLX_SURFACE}">',
           f'    <{MTLX_BSDF} name="btf" type="BSDF">']
    out += [f'      <input name="{n}" type="filename" interfacename="{n}" />' for n in ["tables", *pages]]
    out += ['      <input name="texcoord" type="vector2" interfacename="texcoord" />',
            '      <input name="basisCount" type="integer" interfacename="basisCount" />',
            '      <input name="whiteLevel" type="float" interfacename="whiteLevel" />',
            *[f'      <input name="{n}" type="vector3" interfacename="{n}" />' for n in RENDERING_INPUTS],
            f"    </{MTLX_BSDF}>",
            '    <surface name="surface" type="surfaceshader">',
            '      <input name="bsdf" type="BSDF" nodename="btf" />',
            "    </surface>",
            '    <output name="out" type="surfaceshader" nodename="surface" />',
            "  </nodegraph>",
            "</materialx>", ""]
    return "\n".join(out)


# ------------------------------------------------------------------ headless harness
HARNESS_VERTEX = """\
#version 330
in vec4 aClip;
in vec3 aP;
in vec3 aN;
in vec3 aT;
in vec3 aB;
in vec2 aSt;
out vec3 vP;
out vec3 vN;
out vec3 vT;
out vec3 vB;
out vec2 vSt;
void main()
{
    gl_Position = aClip;
    vP = aP;
    vN = aN;
    vT = aT;
    vB = aB;
    vSt = aSt;
}
"""

HARNESS_MAX_LIGHTS = 8

_HARNESS_MAIN = """\
uniform sampler2D uTables;
{samplers}
uniform int uBasisCount;
uniform vec4 uEye;                       // w = 1: eye position; w = 0: direction towards the eye
uniform int uLightCount;
uniform vec4 uLight[{max_lights}];               // w = 1: point light position; w = 0: direction towards it
uniform float uIntensity[{max_lights}];          // irradiance (point: / d^2), usdbtf.photometry
uniform float uWhiteLevel;
in vec3 vP;
in vec3 vN;
in vec3 vT;
in vec3 vB;
in vec2 vSt;
out vec4 fragColor;

void main()
{{
    mat3 frame = btfFrame(vN, vT, vB);
    vec3 toEye = uEye.w > 0.5 ? normalize(uEye.xyz - vP) : normalize(uEye.xyz);
    ivec3 viewIndex;
    vec3 viewWeight;
    btfViewLookup(uTables, btfLocal(frame, toEye), viewIndex, viewWeight);
    vec3 c = vec3(0.0);
    for (int i = 0; i < uLightCount; ++i) {{
        vec3 d = uLight[i].w > 0.5 ? uLight[i].xyz - vP : uLight[i].xyz;
        float scale = uIntensity[i] * btfRadiancePerIrradiance(uWhiteLevel);
        if (uLight[i].w > 0.5) {{
            scale /= max(dot(d, d), 1e-30);
        }}
        c += btfShadeLight(uTables, BTF_PAGE_ARGS, viewIndex, viewWeight, btfLocal(frame, normalize(d)), scale, vSt,
                           uBasisCount);
    }}
    fragColor = vec4(c, 1.0);
}}
"""


def harness_fragment() -> str:
    """Fragment shader of the headless harness: the core lit by white point/distant lights,
    exactly the CPU renderer's light model."""
    return ("#version 330\n" + core_source() + "\n"
            + _HARNESS_MAIN.format(samplers=_lines("uniform sampler2D btfPage{p:02d};\n").rstrip("\n"),
                                   max_lights=HARNESS_MAX_LIGHTS))


# ------------------------------------------------------------------ plugin files
def plugin_files() -> dict[str, str]:
    """Relative path under the plugin folder (``plugin/``) -> generated text: the Storm,
    MaterialX (genglsl, genosl) and OSL shaders.  The Blender add-on reads the OSL surface from
    here in a checkout; its zip (``scripts/blender_addon_zip.py``) carries a copy."""
    resources = "usdBtf/resources"
    surface = osl.surface_shader()
    return {f"{resources}/shaders/{SHADER_ID}.glslfx": storm_glslfx(),
            f"{resources}/sdr/{SHADER_ID}.usda": sdr_definition_usda(),
            f"{resources}/materialx/usdbtf_defs.mtlx": materialx_defs(),
            f"{resources}/materialx/genglsl/mx_{MTLX_BSDF}.glsl": materialx_impl(),
            f"{resources}/materialx/genosl/mx_{MTLX_BSDF}.osl": osl.materialx_osl(),
            f"{resources}/osl/{osl.SURFACE_NAME}.osl": surface}


def _root(plugin: Path | None) -> Path:
    from ..plugin_folder import plugin_dir

    return plugin or plugin_dir()


def stale_plugin_files(plugin: Path | None = None) -> list[str]:
    """Generated plugin files (paths under ``plugin/``) that are missing or differ from a
    fresh generation."""
    root = _root(plugin)
    return [rel for rel, text in plugin_files().items()
            if not (root / rel).is_file() or (root / rel).read_text() != text]


def write_plugin_files(plugin: Path | None = None) -> list[Path]:
    """(Re)write the generated plugin files; returns the paths written."""
    from ..atomic import atomic_file

    root = _root(plugin)
    written = []
    for rel, text in plugin_files().items():
        path = root / rel
        with atomic_file(path, owner_checked=True) as tmp:     # generated files of the plugin
            tmp.write_text(text)
        written.append(path)
    return written


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--check"]:
        stale = stale_plugin_files()
        for rel in stale:
            print(f"stale: plugin/{rel} (run python -m usdbtf.gpu.shaders)", file=sys.stderr)
        return 1 if stale else 0
    for path in write_plugin_files():
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
