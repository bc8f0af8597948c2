"""Issue 30: the OSL shading is generated from the GLSL core, and it compiles.

* the translator (usdbtf.gpu.glsl_to_osl) on each construct of the subset, and its refusals;
* every OSL file in the plugin is the translation of the one core (the committed files are
  current: a drift of the GLSL or the OSL from the core fails);
* Cycles' own OSL compiler (``_cycles.osl_compile`` in the bpy 5.0.1 environment) compiles the
  standalone shader and the OSL that MaterialX's genosl generator writes for the packaged
  ``usdbtf.mtlx`` with no error and no warning (skipped without that environment).
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from usdbtf.gpu import osl, shaders
from usdbtf.gpu.glsl_to_osl import TranslationError, translate
from usdbtf.usd.preview import cycles


@pytest.mark.parametrize("glsl, expected", [
    ("vec2 q = d.xy;", "btfVec2 q = btf_xy(d);"),
    ("float a = f(x, 1).x;", "float a = btfAt(f(x, 1), 0);"),
    ("vec3 c = btfFetch(t, m).xyz;", "vector c = btf_xyz(btfFetch(t, m));"),
    ("int t = int(ids[j]);", "int t = int(btfAt(ids, j));"),
    ("stored[c] += dot(row, value);", "stored[c] = btfAt(stored, c) + (dot(row, value));"),
    ("row *= vec4(greaterThan(ivec4(k), ivec4(1)));",
     "row = row * (btfMakeVec4(greaterThan(btfMakeIVec4(k), btfMakeIVec4(1))));"),
    ("float t = atan(rho, d.z); float s = atan(x);", "float t = atan2(rho, d.z); float s = atan(x);"),
    ("void f(sampler2D s, vec3 v, out ivec3 index, mat3 m)",
     "void f(string s, vector v_, output btfIVec3 index, btfMat3 m)"),
    ("vec4 x = texelFetch(s, ivec2(0, textureSize(s, 0).y - 1), 0); // keep vec4 and v[i]",
     "btfVec4 x = btfTexelFetch(s, btfMakeIVec2(0, btfAt(btfTextureSize(s, 0), 1) - 1), 0); // keep vec4 and v[i]"),
])
def test_translator_constructs(glsl, expected):
    assert translate(glsl) == expected


@pytest.mark.parametrize("glsl", ["/* block */ float a;", "void f(inout vec3 a)", "float w[4];", "a.xy = b;"])
def test_translator_refuses_what_it_does_not_take(glsl):
    with pytest.raises(TranslationError):
        translate(glsl)


def test_osl_files_are_the_translation_of_the_one_core():
    core = shaders.core_source()
    translated = translate(core)
    assert osl.osl_core().endswith(translated)
    files = shaders.plugin_files()
    osl_files = {rel: text for rel, text in files.items() if rel.endswith(".osl")}
    assert set(osl_files) == {"usdBtf/resources/osl/usdbtf_surface.osl", "usdBtf/resources/materialx/genosl/mx_usdbtf_bsdf.osl"}
    for text in osl_files.values():
        assert osl.osl_core() in text                  # the same translation, not a hand-made copy
    for text in (files["usdBtf/resources/shaders/UsdBtfSurface.glslfx"],
                 files["usdBtf/resources/materialx/genglsl/mx_usdbtf_bsdf.glsl"]):
        assert core in text
    # The committed files are what the core makes now (a drift of either language fails).
    assert shaders.stale_plugin_files() == [], "run: python -m usdbtf.gpu.shaders"
    assert "genosl/mx_usdbtf_bsdf.osl" in files["usdBtf/resources/materialx/usdbtf_defs.mtlx"]


_COMPILE = """
import sys, bpy, _cycles
ok = all(_cycles.osl_compile(path, path + ".oso") for path in sys.argv[1:])
sys.exit(0 if ok else 1)
"""


def _genosl(tmp_path) -> str:
    """The OSL MaterialX's genosl generator writes for a usdbtf_surface document, beside the
    MaterialX OSL headers it includes."""
    import MaterialX as mx
    from MaterialX import PyMaterialXGenOsl as mx_osl
    from MaterialX import PyMaterialXGenShader as mx_gen

    from usdbtf.gpu.materialx import load_document, materialx_dir
    from usdbtf.usd.asset.storm import materialx_document

    document = tmp_path / "btf.mtlx"
    document.write_text(materialx_document("tables.exr", ["page00.png", "page01.png"], 8))
    doc = load_document(document)
    generator = mx_osl.OslShaderGenerator.create()
    context = mx_gen.GenContext(generator)
    libraries = Path(mx.__file__).parent / "libraries"
    for folder in (mx.getDefaultDataSearchPath(), mx.FileSearchPath(str(libraries)),
                   mx.FileSearchPath(str(materialx_dir()))):
        context.registerSourceCodeSearchPath(folder)
    shutil.copytree(libraries / "stdlib" / "genosl" / "include", tmp_path, dirs_exist_ok=True)
    node = doc.getMaterialNodes()[0]
    source = generator.generate(node.getName(), node, context).getSourceCode(mx_gen.PIXEL_STAGE)
    path = tmp_path / "btf_genosl.osl"
    path.write_text(source)
    return str(path)


def test_cycles_osl_compiler_takes_the_surface_shader_and_the_genosl_output(tmp_path):
    python = cycles.cycles_python()
    if python is None:
        pytest.skip("no .venv-storm-5.0 (bpy 5.0.1): scripts/bootstrap.sh could not install it")
    pytest.importorskip("MaterialX")
    surface = tmp_path / "usdbtf_surface.osl"
    surface.write_text(osl.surface_shader())
    genosl = _genosl(tmp_path)
    proc = subprocess.run([str(python), "-c", _COMPILE, str(surface), genosl], capture_output=True, text=True,
                          timeout=120, env={"PATH": os.environ.get("PATH", "/usr/bin:/bin")})
    output = proc.stdout + proc.stderr
    assert proc.returncode == 0, output[-3000:]
    # The OSL compiler's diagnostics: "WARNING: FILE.osl:LINE: warning: ..." (Blender's own start-up
    # messages are not about the shaders).
    assert not re.findall(r"\.osl:\d+: (?:warning|error)", output), output[-3000:]


def test_blender_addon_constants_follow_the_pipeline():
    """The add-on runs inside Blender without usdbtf, so it restates two facts: how many page
    inputs the shader has, the Storm shader's identifier it reads the textures from, and the
    rendering matrix's inputs (issue 40) with their identity."""
    from usdbtf.gpu.tables import MAX_PAGES
    from usdbtf.plugin_folder import SHADER_ID, plugin_dir

    text = (plugin_dir() / "blender" / "usdbtf" / "network.py").read_text()
    assert re.search(r"^MAX_PAGES = (\d+)$", text, re.M).group(1) == str(MAX_PAGES)
    assert re.search(r'^STORM_ID = "(\w+)"$', text, re.M).group(1) == SHADER_ID
    from usdbtf.gpu.shaders import IDENTITY_ROWS, RENDERING_INPUTS

    import ast

    for name, value in (("RENDERING_INPUTS", RENDERING_INPUTS), ("IDENTITY_ROWS", IDENTITY_ROWS)):
        assert ast.literal_eval(re.search(rf"^{name} = (.+)$", text, re.M).group(1)) == value, name
