"""The BtfMaterialAPI schema: generated files reproduce byte for byte, SCons builds them
once, USD finds the plugin from PXR_PLUGINPATH_NAME alone and from ``import usdbtf``."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import usdbtf  # noqa: F401  (registers the plugin before any stage exists)
from usdbtf.errors import BTFError
from usdbtf.usd import genschema
from usdbtf.usd.plugin import API_SCHEMA, plugin_dir

ROOT = Path(__file__).resolve().parent.parent
SOURCE = ROOT / "schemas" / "usdBtf" / "schema.usda"
RESOURCES = ROOT / "plugin" / "usdBtf" / "resources"
PYTHON = sys.executable


def test_rebuild_reproduces_committed_files_byte_for_byte(tmp_path):
    written = genschema.generate(SOURCE, tmp_path)
    assert [p.name for p in written] == ["generatedSchema.usda", "plugInfo.json"]
    for path in written:
        assert path.read_bytes() == (RESOURCES / path.name).read_bytes(), f"{path.name} is stale: run `scons schema`"


def test_generated_schema_is_flat_and_documented():
    text = (RESOURCES / "generatedSchema.usda").read_text()
    assert "inherits" not in text and "apiSchemaType" not in text   # plugin bookkeeping moved to plugInfo
    assert 'class "BtfMaterialAPI"' in text and "DO NOT EDIT" in text


def test_scons_builds_schema_once(tmp_path):
    """A fresh tree builds the schema; the second `scons schema` does no work."""
    for name in ("SConstruct", "schemas", "pipeline"):
        src = ROOT / name
        (shutil.copytree if src.is_dir() else shutil.copy)(src, tmp_path / name)
    env = dict(os.environ, PYTHONPATH=str(tmp_path / "pipeline"))
    scons = [PYTHON, "-m", "SCons", "-Q", "schema"]
    first = subprocess.run(scons, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert first.returncode == 0, first.stderr
    assert "genschema" in first.stdout
    out = tmp_path / "plugin" / "usdBtf" / "resources"
    for name in ("generatedSchema.usda", "plugInfo.json"):
        assert (out / name).read_bytes() == (RESOURCES / name).read_bytes()
    stamp = (out / "plugInfo.json").stat().st_mtime_ns
    second = subprocess.run(scons, cwd=tmp_path, env=env, capture_output=True, text=True)
    assert second.returncode == 0, second.stderr
    assert "genschema" not in second.stdout and "up to date" in second.stdout
    assert (out / "plugInfo.json").stat().st_mtime_ns == stamp


_PROBE = """
from pxr import Usd
d = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("BtfMaterialAPI")
print("found" if d else "missing")
if d:
    print(d.GetAttributeDefinition("btf:schemaVersion").GetFallbackValue())
    print(d.GetAttributeDefinition("btf:basisLayout").GetFallbackValue())
    print(d.GetAttributeDefinition("btf:colorSpace").GetFallbackValue())
    s = Usd.Stage.CreateInMemory()
    print(s.DefinePrim("/M", "Material").CanApplyAPI("BtfMaterialAPI"))
    print(bool(s.DefinePrim("/X", "Xform").CanApplyAPI("BtfMaterialAPI")))
"""


def test_fresh_process_finds_schema_from_pxr_pluginpath_alone(tmp_path):
    """Only PXR_PLUGINPATH_NAME (no usdbtf import, no PYTHONPATH): what a DCC or usdview does."""
    env = {"PATH": "/usr/bin:/bin", "PXR_PLUGINPATH_NAME": str(plugin_dir()), "HOME": str(tmp_path)}
    proc = subprocess.run([PYTHON, "-c", _PROBE], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["found", "1", "columns", "ACEScg", "True", "False"]


def test_without_the_plugin_the_schema_is_unknown(tmp_path):
    """The control for the test above: the same probe without the variable finds nothing."""
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    proc = subprocess.run([PYTHON, "-c", _PROBE], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.stdout.split() == ["missing"]


def test_import_usdbtf_registers_before_first_stage(tmp_path):
    code = "import usdbtf\n" + _PROBE
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "PYTHONPATH": str(ROOT / "pipeline")}
    proc = subprocess.run([PYTHON, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.stdout.split()[0] == "found", proc.stderr


def test_stage_before_import_is_a_clear_error(tmp_path):
    """Using USD's registry before importing usdbtf is the classic trap: say so."""
    code = ("from pxr import Usd\nUsd.Stage.CreateInMemory().DefinePrim(\"/M\", \"Material\")\nimport usdbtf\n"
            "from usdbtf.usd.plugin import require_schema\nrequire_schema()\n")
    env = {"PATH": "/usr/bin:/bin", "HOME": str(tmp_path), "PYTHONPATH": str(ROOT / "pipeline")}
    proc = subprocess.run([PYTHON, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert proc.returncode != 0 and "PXR_PLUGINPATH_NAME" in proc.stderr


def test_schema_attributes_have_docs_and_fallbacks():
    from pxr import Usd

    d = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(API_SCHEMA)
    names = d.GetPropertyNames()
    for required in ("btf:basis", "btf:coefficients", "btf:coefficientScale", "btf:coefficientBias",
                     "btf:basisScale", "btf:basisBias", "btf:basisCount", "btf:viewDirections",
                     "btf:lightDirections", "btf:colorSpace", "btf:physicalSize", "btf:errorCurve:k",
                     "btf:errorCurve:percent", "btf:provenance:source", "btf:provenance:solver",
                     "btf:provenance:version"):
        assert required in names
        assert d.GetPropertyDocumentation(required), f"{required} has no doc"
    assert d.GetAttributeDefinition("btf:basisCount").GetFallbackValue() == 0


def test_generator_rejects_bad_source(tmp_path):
    bad = tmp_path / "schema.usda"
    bad.write_text('#usda 1.0\nclass "Broken" (\n')
    with pytest.raises(BTFError, match="schema.usda"):
        genschema.generate(bad, tmp_path / "out")
    nolib = tmp_path / "nolib.usda"
    nolib.write_text('#usda 1.0\nclass "ThingAPI" {\n}\n')
    with pytest.raises(BTFError, match="libraryName"):
        genschema.generate(nolib, tmp_path / "out")
    assert not (tmp_path / "out" / "plugInfo.json").exists()
