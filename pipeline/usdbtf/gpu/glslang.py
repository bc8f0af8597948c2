"""Compile GLSL with Khronos glslang (``glslangValidator``, Debian package glslang-tools).

:func:`compile_glsl` checks one stage's source.  :func:`storm_translation_unit` turns a
Storm glslfx file into something glslang can compile: Storm is not in usd-core, so the
names Storm's code generator provides to a surface shader (``GetLightSource``,
``HdGet_<input>()``, ``HdGetSampler_<input>()``, ``HD_HAS_<input>``, ``NUM_LIGHTS``,
``ComputeTBNMatrix`` from surfaceHelpers.glslfx, ...) are declared by a small prelude with
the same signatures (as in OpenUSD's hdSt sources), and the glslfx sections are
concatenated in the order its configuration lists them.
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from ..errors import BTFError
from ..lifetime import dying_with_parent

__all__ = ["glslang_path", "compile_glsl", "glslfx_sections", "storm_translation_unit"]

_EXT = {"vert": ".vert", "frag": ".frag"}


def glslang_path() -> str | None:
    """The glslangValidator executable on PATH, or None."""
    return shutil.which("glslangValidator")


def compile_glsl(source: str, stage: str, name: str = "shader") -> None:
    """Compile ``source`` as an OpenGL GLSL ``stage`` ("vert" or "frag"); raises BTFError
    with glslang's messages (line numbers refer to ``source``) when it does not compile."""
    exe = glslang_path()
    if exe is None:
        raise BTFError("glslangValidator not found: install glslang-tools (scripts/bootstrap.sh does, as root)")
    with tempfile.TemporaryDirectory(prefix="usdbtf-glslang-") as tmp:
        path = Path(tmp) / f"{name}{_EXT[stage]}"
        path.write_text(source)
        run = subprocess.run([exe, str(path)], capture_output=True, text=True, timeout=120, **dying_with_parent())
    if run.returncode != 0:
        lines = [ln for ln in (run.stdout + run.stderr).splitlines() if "ERROR" in ln] or [run.stdout + run.stderr]
        raise BTFError(f"{name}: GLSL does not compile: " + " | ".join(ln.strip() for ln in lines[:8]))


def glslfx_sections(text: str) -> tuple[dict, dict[str, str]]:
    """(configuration dict, {section name: GLSL}) of a glslfx file."""
    parts = re.split(r"^-- (configuration|glsl [^\n]+)\n", text, flags=re.M)
    config, sections = None, {}
    for head, body in zip(parts[1::2], parts[2::2]):
        if head == "configuration":
            config = json.loads(body)
        else:
            sections[head[len("glsl "):].strip()] = body
    if config is None:
        raise BTFError("glslfx has no configuration section")
    return config, sections


_STORM_PRELUDE = """\
#version 450
// Stand-ins for what Hydra Storm's code generator provides to a surface shader.
#define NUM_LIGHTS {lights}
#define USE_SHADOWS 1
#define MAT4 mat4
{defines}
struct LightSource {{
    vec4 position;
    vec4 ambient;
    vec4 diffuse;
    vec4 specular;
    vec3 spotDirection;
    float spotCutoff;
    float spotFalloff;
    vec3 attenuation;
    mat4 worldToLightTransform;
    int shadowIndexStart;
    int shadowIndexEnd;
    bool hasShadow;
    bool isIndirectLight;
}};
layout(std140) uniform LightingBlock {{ LightSource lightSource[{light_slots}]; }};
LightSource GetLightSource(int i) {{ return lightSource[i]; }}
float lightDistanceAttenuation(vec4 Peye, int i) {{
    float d = distance(GetLightSource(i).position.xyz, Peye.xyz);
    vec3 a = GetLightSource(i).attenuation;
    return 1.0 / max(a.x + a.y * d + a.z * d * d, 1e-6);
}}
float lightSpotAttenuation(vec3 l, int i) {{ return 1.0; }}
float shadowing(int lightIndex, vec4 Peye) {{ return 1.0; }}
vec4 ApplyColorOverrides(vec4 c) {{ return c; }}
uniform mat4 worldToViewMatrix;
uniform mat4 modelMatrix;
mat4 GetWorldToViewMatrix() {{ return worldToViewMatrix; }}
uniform mat4 projectionMatrix;
mat4 GetProjectionMatrix() {{ return projectionMatrix; }}
MAT4 HdGet_transform() {{ return modelMatrix; }}
// No ApplyInstanceTransform: instancing.glslfx is a vertex-stage library in Storm.
in vec2 stIn;
in vec3 tangentIn;
in vec3 bitangentIn;
vec2 HdGet_st() {{ return stIn; }}
vec3 HdGet_tangents() {{ return tangentIn; }}
vec3 HdGet_bitangents() {{ return bitangentIn; }}
{values}
{samplers}
// surfaceHelpers.glslfx (SurfaceHelpers.TangentSpace): same signature.
mat3 ComputeTBNMatrix(vec3 P, vec3 N, vec2 st)
{{
    vec3 dPdx = dFdx(P);
    vec3 dPdy = dFdy(P);
    vec2 dSTdx = dFdx(st);
    vec2 dSTdy = dFdy(st);
    vec3 T = normalize(dPdx * dSTdy.y - dPdy * dSTdx.y);
    return mat3(T, cross(N, T), N);
}}
"""

_STORM_MAIN = """
in vec4 PeyeIn;
in vec3 NeyeIn;
out vec4 fragColor;
void main()
{
    fragColor = surfaceShader(PeyeIn, normalize(NeyeIn), vec4(1.0), vec4(0.0));
}
"""


def _glsl_type(default) -> str:
    """The GLSL type Storm gives a glslfx parameter of this default value."""
    if isinstance(default, list):
        return f"vec{len(default)}"
    return "int" if isinstance(default, int) and not isinstance(default, bool) else "float"


def storm_translation_unit(glslfx_text: str, *, textures: list[str], primvars: bool = True, lights: int = 2) -> str:
    """A fragment shader around ``glslfx_text``'s surfaceShader as Storm would bind it:
    ``textures`` are the connected texture inputs (HD_HAS_<name>, HdGetSampler_<name>());
    ``primvars`` whether the mesh has tangents/bitangents and a transform; ``lights`` the
    NUM_LIGHTS Storm compiles with."""
    config, sections = glslfx_sections(glslfx_text)
    order = config["techniques"]["default"]["surfaceShader"]["source"]
    own = [name for name in order if name in sections]
    # Storm defines HD_HAS_<p> for every parameter and HD_HAS_COORD_<p> for the texture-bound ones.
    defines = [f"#define HD_HAS_{name} 1" for name in config.get("parameters", {})]
    defines += [f"#define HD_HAS_COORD_{name} 1" for name in textures]
    defines += ["#define HD_HAS_st 1"] + (["#define HD_HAS_tangents 1", "#define HD_HAS_bitangents 1",
                                           "#define HD_HAS_transform 1"] if primvars else [])
    samplers = "\n".join(f"uniform sampler2D sampler2d_{name};\n#define HdGetSampler_{name}() sampler2d_{name}"
                         for name in textures)
    # HdGet_<p>() of every parameter not bound to a texture: its value, typed by its default
    # (an int, a float, a list of 3: vec3), as Storm's code generator declares them.
    values = "\n".join(f"uniform {kind} {name}Value;\n{kind} HdGet_{name}() {{ return {name}Value; }}"
                       for name, kind in ((name, _glsl_type(spec["default"]))
                                          for name, spec in config.get("parameters", {}).items())
                       if name not in textures)
    prelude = _STORM_PRELUDE.format(lights=lights, light_slots=max(lights, 1), defines="\n".join(defines),
                                    samplers=samplers, values=values)
    return prelude + "\n".join(sections[name] for name in own) + _STORM_MAIN
