"""Issue 15 part 1: packaged assets validate clean in any USD process set up by ``usdbtf env``.

A fresh Python that never imports usdbtf, started by bash with exactly the lines
``usdbtf env`` prints (and PATH), runs every UsdValidation validator on every ``lod``
selection of a held-out material (fuzzy_moss: the package tests use pebbles) packaged as
usda, as usdc, as usdz and as an AR usdz: 0 errors, 0 warnings.  The control: with only
PXR_PLUGINPATH_NAME (what the issue's reporter had) the Storm shader is unknown to Sdr.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from usdbtf.cli import main
from usdbtf.numeric import pinned_environment
from usdbtf.usd.plugin import defaults, environment, plugin_dir

HERE = Path(__file__).resolve().parent
SCRIPT = HERE / "fresh_usd_validate.py"
# Nothing but PATH (and PYTHONPATH, so the usdbtf printing the lines is the tree under test).
BARE_ENV = {"PATH": "/usr/bin:/bin", **{k: v for k, v in os.environ.items() if k == "PYTHONPATH"}}


@pytest.fixture(scope="module")
def outputs(tmp_path_factory) -> dict[str, Path]:
    work = tmp_path_factory.mktemp("env")
    src, comp = work / "src", work / "c"
    assert main(["synth", "fuzzy_moss", "-o", str(src), "--sampling", "small", "--size", "32", "--seed", "3",
                 "-q"]) == 0
    assert main(["compress", str(src), "-o", str(comp), "--k", "12", "--codec", "png", "-q"]) == 0
    usda, usdc = work / "a" / "moss.usda", work / "b" / "moss.usdc"     # not inside the input c
    assert main(["package", str(comp), "-o", str(usda), "--payload-format", "usda", "--usdz", "--lod", "6,3",
                 "-q"]) == 0
    assert main(["package", str(comp), "-o", str(usdc), "--lod", "6,3", "--usdz-ar", "-q"]) == 0
    return {"usda": usda, "usda payload": usda.with_name("moss_payload.usda"), "usdz": usda.with_suffix(".usdz"),
            "usdc": usdc, "usdc payload": usdc.with_name("moss_payload.usdc"), "ar": usdc.with_name("moss_ar.usdz")}


def usdbtf_env_lines() -> str:
    proc = subprocess.run([sys.executable, "-m", "usdbtf.cli", "env"], capture_output=True, text=True, env=BARE_ENV)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def fresh_validate(setup: str, paths) -> dict:
    """Run tests/fresh_usd_validate.py in bash after ``setup`` (shell lines), nothing else set."""
    script = setup + '\nexec "$@"\n'
    proc = subprocess.run(["bash", "-c", script, "bash", sys.executable, str(SCRIPT), *map(str, paths)],
                          capture_output=True, text=True, env=BARE_ENV, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_env_prints_the_plugin_and_sdr_discovery_variables():
    text = usdbtf_env_lines()
    lines = [line for line in text.splitlines() if not line.startswith("#")]
    numeric = [f"export {v}" for v in pinned_environment()]
    assert [line.split("=", 1)[0] for line in lines] == \
        [f"export {v}" for v in [*environment(), *defaults()]] + numeric
    # Both discovery families: Ndr's names (USD 24.x-25.02) and Sdr's (25.05 on), same folders.
    env = environment()
    assert env["PXR_NDR_FS_PLUGIN_SEARCH_PATHS"] == env["PXR_SDR_FS_PLUGIN_SEARCH_PATHS"]
    assert env["PXR_NDR_FS_PLUGIN_ALLOWED_EXTS"] == env["PXR_SDR_FS_PLUGIN_ALLOWED_EXTS"] == ["usda", "glslfx"]
    assert str(plugin_dir().resolve()) in text
    probe = subprocess.run(["bash", "-c", text + '\nprintf "%s\\n" "$PXR_PLUGINPATH_NAME" '
                            '"$PXR_SDR_FS_PLUGIN_SEARCH_PATHS" "$PXR_SDR_FS_PLUGIN_ALLOWED_EXTS"'],
                           capture_output=True, text=True, env={**BARE_ENV, "PXR_SDR_FS_PLUGIN_ALLOWED_EXTS": "oso"})
    plugin, search, exts = probe.stdout.splitlines()[:3]
    assert plugin == str(plugin_dir().resolve())
    assert search.split(":")[0].endswith("usdBtf/resources/sdr") and Path(search.split(":")[0]).is_dir()
    assert exts == "usda:glslfx:oso"          # a studio's own setting is kept, behind usdbtf's
    as_json = subprocess.run([sys.executable, "-m", "usdbtf.cli", "env", "--json"], capture_output=True, text=True)
    assert json.loads(as_json.stdout)["variables"] == environment()
    assert json.loads(as_json.stdout)["defaults"] == {"TF_ENV_SETTING_ALERTS_ENABLED": "0"}
    # The banner switch is a default: a user's own choice survives the lines.
    alerts = subprocess.run(["bash", "-c", text + '\nprintf "%s\\n" "$TF_ENV_SETTING_ALERTS_ENABLED"'],
                            capture_output=True, text=True, env={**BARE_ENV, "TF_ENV_SETTING_ALERTS_ENABLED": "1"})
    assert alerts.stdout.strip() == "1"


def test_fresh_process_with_usdbtf_env_validates_every_output_and_lod_clean(outputs):
    report = fresh_validate(usdbtf_env_lines(), outputs.values())
    assert not report["usdbtf_imported"] and report["schema_known"] and report["shader_known"]
    assert report["validators"] >= 25
    for path in outputs.values():
        per_lod = report["assets"][str(path)]
        if "payload" not in path.name and "_ar" not in path.name:
            assert {"", "full", "k6", "k3"} <= set(per_lod), (path, sorted(per_lod))
        for selection, issues in per_lod.items():
            assert issues == [], (path.name, selection, issues)


def test_control_plugin_path_alone_leaves_the_shader_unknown(outputs):
    report = fresh_validate(f"export PXR_PLUGINPATH_NAME={plugin_dir().resolve()}", [outputs["usda"]])
    assert report["schema_known"] and not report["shader_known"]
    issues = [i for lines in report["assets"][str(outputs["usda"])].values() for i in lines]
    assert issues and all("MissingShaderIdInRegistry" in i and "UsdBtfSurface" in i for i in issues)
