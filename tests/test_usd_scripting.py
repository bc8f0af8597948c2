"""Issue 15 part 7: the CLI in pipelines — USD paths through the asset resolver, ``--json``
summaries on stdout (messages on stderr), documented exit statuses."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

import usdbtf  # noqa: F401  (sets up the USD plugin first)
from cli_helpers import run
from usdbtf.cli import main
from usdbtf.errors import EXIT_USAGE


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    work = tmp_path_factory.mktemp("scripting")
    assert main(["synth", "pebbles", "-o", str(work / "src"), "--sampling", "small", "--size", "16", "-q"]) == 0
    return work


def cli(*argv, cwd=None, env=None) -> subprocess.CompletedProcess:
    """``usdbtf argv`` in a subprocess (the resolver reads its environment when USD loads)."""
    return subprocess.run([sys.executable, "-m", "usdbtf.cli", *map(str, argv)], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ, **(env or {})}, timeout=300)


@pytest.fixture(scope="module")
def compressed(work) -> tuple[Path, dict]:
    proc = cli("compress", work / "src", "-o", work / "c", "--k", "8", "--codec", "png", "--json")
    assert proc.returncode == 0, proc.stderr
    return work / "c", json.loads(proc.stdout)          # stdout is the JSON and nothing else


@pytest.fixture(scope="module")
def packaged(compressed, work) -> tuple[Path, dict]:
    proc = cli("package", compressed[0], "-o", work / "lib" / "pebbles.usda", "--usdz", "--json")
    assert proc.returncode == 0, proc.stderr
    assert "packaged" in proc.stderr                     # progress goes to stderr
    return work / "lib" / "pebbles.usda", json.loads(proc.stdout)


def test_compress_and_info_json(compressed, work, capsys):
    folder, summary = compressed
    assert summary["kind"] == "compressed" and summary["k"] == 8 and summary["samples"] == 169
    assert summary["bytes"]["payload"] == summary["bytes"]["basis"] + summary["bytes"]["coefficients"]
    code, out, _ = run(capsys, "info", folder, "--json")
    assert code == 0 and json.loads(out) == summary
    code, out, _ = run(capsys, "info", work / "src", "--json")
    info = json.loads(out)
    assert (info["kind"], info["samples"], info["views"], info["lights"], info["bit_depth"]) == \
        ("btf", 169, 13, 13, "uint8")


def test_package_json(packaged):
    asset, summary = packaged
    assert summary["root"] == str(asset) and Path(summary["usdz"]).is_file() and Path(summary["payload"]).is_file()
    assert summary["k"] == 8 and summary["lods"] == [["full", 8], ["k4", 4]] and summary["validated"] is True


def test_inspect_finds_the_asset_through_the_resolver_and_prints_json(packaged, tmp_path):
    asset, _ = packaged
    env = {"PXR_AR_DEFAULT_SEARCH_PATH": str(asset.parent)}
    proc = cli("inspect", "pebbles.usda", "--json", "--validate", cwd=tmp_path, env=env)   # not a file here
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["asset"] == "pebbles.usda" and Path(info["resolved"]) == asset
    (material,) = info["materials"]
    assert material["k"] == 8 and material["bytes"]["total"] > 0
    assert [(lv["name"], lv["k"]) for lv in material["lod"]] == [("full", 8), ("k4", 4)]
    assert info["validation"]["errors"] == [] and info["validation"]["warnings"] == []
    assert len(info["validation"]["selections"]) == 3
    # decompress reads through the resolver too; without the search path nothing is found.
    assert cli("decompress", "pebbles.usda", "-o", tmp_path / "d", "--samples", "0", "-q", cwd=tmp_path,
               env=env).returncode == 0
    missing = cli("inspect", "pebbles.usda", cwd=tmp_path)
    assert missing.returncode != 0 and missing.stdout == ""
    (line,) = missing.stderr.strip().splitlines()
    assert line.startswith("usdbtf inspect: error: pebbles.usda: no such USD file")


def test_render_and_package_mesh_find_usd_through_the_resolver(packaged, compressed, tmp_path):
    """The mesh reader (usdbtf.mesh) and ``render``'s asset opening ask the resolver too."""
    from usdbtf.imageio import read_image

    asset, _ = packaged
    env = {"PXR_AR_DEFAULT_SEARCH_PATH": str(asset.parent)}
    proc = cli("render", "pebbles.usda", "--light", "dir:0.2,0.3,1", "--size", 24, 24, "-o", tmp_path / "r.exr",
               "--no-png", "-q", cwd=tmp_path, env=env)           # the asset's own mesh, found by name
    assert proc.returncode == 0, proc.stderr
    pixels, _ = read_image(tmp_path / "r.exr")
    lit = pixels[..., :3].sum(axis=2) > 0
    assert lit.sum() > 100 and not lit.all()                     # the swatch, and background around it
    out = tmp_path / "m" / "again.usda"
    proc = cli("package", compressed[0], "-o", out, "--mesh", "pebbles.usda", "--no-thumbnail", "--no-validate",
               "-q", cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "again.usda" in {p.name for p in out.parent.iterdir()}
    assert cli("render", "pebbles.usda", "--light", "dir:0,0,1", "-o", tmp_path / "x.exr", cwd=tmp_path).returncode \
        == 65                                                     # without the search path: not found


def test_usage_errors_exit_with_the_usage_status(compressed, tmp_path, capsys):
    code, out, err = run(capsys, "package", compressed[0], "-o", tmp_path / "a.usda", "--usdz",
                         "--texture-format", "tx")
    assert code == EXIT_USAGE and out == "" and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "package", compressed[0], "-o", tmp_path / "a.txt")
    assert code == EXIT_USAGE and "root layer must be" in err
