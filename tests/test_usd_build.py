"""``usdbtf build SCENE``: only bound BTF materials are built, and only once."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import usdbtf  # noqa: F401
from cli_helpers import bad_input, ok, run
from usdbtf.cli import main
from usdbtf.compress import read_compressed, reconstruct
from usdbtf.usd.scenes.build import build, plan
from usdbtf.usd.read import load_btf
from usdbtf.usd.asset.validate import validation_issues

SCENE = '''#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "World"
{
    def Sphere "Ball" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        rel material:binding = </World/Looks/Pebbles>
    }
    def Sphere "Hidden" (
        active = false
        prepend apiSchemas = ["MaterialBindingAPI"]
    )
    {
        rel material:binding = </World/Looks/Moss>
    }
    def Sphere "Switch" (
        prepend apiSchemas = ["MaterialBindingAPI"]
        variants = { string look = "pebbles" }
        prepend variantSets = "look"
    )
    {
        variantSet "look" = {
            "pebbles" {
                rel material:binding = </World/Looks/Pebbles>
            }
            "fabric" {
                rel material:binding = </World/Looks/Fabric>
            }
        }
    }
    def Scope "Looks"
    {
        def Material "Pebbles" (
            prepend apiSchemas = ["BtfMaterialAPI"]
            prepend references = @./build/pebbles.usda@</pebbles/mtl/BtfMaterial>
        )
        {
            uniform asset btf:build:source = @./captures/pebbles@
            uniform string btf:build:options = "--k 6 --codec png"
            uniform asset btf:build:asset = @./build/pebbles.usda@
        }
        def Material "Moss" (
            prepend apiSchemas = ["BtfMaterialAPI"]
            prepend references = @./build/moss.usda@</moss/mtl/BtfMaterial>
        )
        {
            uniform asset btf:build:source = @./captures/moss@
            uniform asset btf:build:asset = @./build/moss.usda@
        }
        def Material "Fabric" (
            prepend apiSchemas = ["BtfMaterialAPI"]
            prepend references = @./build/fabric.usda@</fabric/mtl/BtfMaterial>
        )
        {
            uniform asset btf:build:source = @./captures/fabric@
            uniform asset btf:build:asset = @./build/fabric.usda@
        }
        def Material "Unbound" (
            prepend apiSchemas = ["BtfMaterialAPI"]
        )
        {
            uniform asset btf:build:source = @./captures/moss@
            uniform asset btf:build:asset = @./build/unbound.usda@
        }
    }
}
'''


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("captures")
    for preset in ("pebbles", "fuzzy_moss", "ridged_fabric"):
        name = {"fuzzy_moss": "moss", "ridged_fabric": "fabric"}.get(preset, preset)
        assert main(["synth", preset, "-o", str(root / name), "--sampling", "tiny", "--size", "16", "-q"]) == 0
    return root


@pytest.fixture
def scene(captures, tmp_path) -> Path:
    import shutil

    shutil.copytree(captures, tmp_path / "captures")
    path = tmp_path / "scene.usda"
    path.write_text(SCENE)
    return path


def test_plan_finds_only_bound_materials(scene):
    recipes, report = plan(scene)
    assert [r.material for r in recipes] == ["/World/Looks/Pebbles"]
    assert recipes[0].options == ("--k", "6", "--codec", "png")
    assert set(report["bound"]) == {"/World/Looks/Pebbles"}
    assert sorted(report["bound"]["/World/Looks/Pebbles"]) == ["/World/Ball", "/World/Switch"]


def test_build_builds_bound_material_once(scene):
    out = scene.parent / "build"
    first = build(scene)
    assert len(first["ran"]) == 2                         # compress, then package
    assert (out / "pebbles.usda").is_file()
    for never in ("moss", "fabric", "unbound"):            # inactive, unselected variant, unbound
        assert not list(out.glob(f"{never}*")), never
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    second = build(scene)
    assert second["ran"] == []
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()} == stamps
    # The scene now composes the built material, and it is the compressed data.
    cbtf = load_btf(scene, material="/World/Looks/Pebbles")
    assert cbtf.k == 6
    assert np.array_equal(reconstruct(cbtf), reconstruct(read_compressed(out / "pebbles_compressed")))


def test_another_numeric_platform_rebuilds(scene, monkeypatch):
    """The numeric platform is in every step's signature: a build cached on one platform
    (BLAS kernel, numpy SIMD level) is rebuilt on another, and the same platform rebuilds
    nothing."""
    from usdbtf import numeric

    assert len(build(scene)["ran"]) == 2
    assert build(scene)["ran"] == []
    here = numeric.platform()
    other = dict(here, blas_kernel="Prescott" if here["blas_kernel"] == "Nehalem" else "Nehalem")
    monkeypatch.setattr(numeric, "platform", lambda: other)
    assert len(build(scene)["ran"]) == 2
    assert build(scene)["ran"] == []


def test_changed_input_rebuilds_and_variant_switch_builds_the_other(scene, capsys):
    ok(capsys, "build", scene, "-q")
    image = sorted((scene.parent / "captures" / "pebbles").glob("*.png"))[0]
    data = bytearray(image.read_bytes())
    import usdbtf.imageio as io

    px, _ = io.read_image(image)
    px = px.copy()
    px[0, 0] = 255 - px[0, 0]
    io.write_image(image, px, color_space="sRGB Encoded Rec.709 (sRGB)")
    assert image.read_bytes() != bytes(data)
    again = build(scene)
    assert len(again["ran"]) == 2
    # Selecting the other look binds Fabric instead: now (only) it is built as well.
    scene.write_text(SCENE.replace('string look = "pebbles"', 'string look = "fabric"'))
    third = build(scene)
    assert [r.material for r in third["recipes"]] == ["/World/Looks/Fabric", "/World/Looks/Pebbles"]
    assert len(third["ran"]) == 2 and (scene.parent / "build" / "fabric.usda").is_file()
    assert not list((scene.parent / "build").glob("moss*"))
    assert validation_issues(scene.parent / "build" / "fabric.usda") == []


def test_missing_source_is_a_clear_error(scene, capsys):
    import shutil

    shutil.rmtree(scene.parent / "captures" / "pebbles")
    bad_input(capsys, "build", scene, names="captures/pebbles")
    assert not (scene.parent / "build").exists()


def test_failed_step_reports_the_usdbtf_error(scene, capsys):
    (scene.parent / "captures" / "pebbles" / "btf.json").write_text("{not json")
    line = bad_input(capsys, "build", scene, names="btf.json")
    assert "build failed" in line
    assert not (scene.parent / "build" / "pebbles.usda").exists()
    assert not (scene.parent / ".usdbtf-build").exists()        # nothing was built: nothing left


CYCLE_LAYERS = {
    "references": ('#usda 1.0\n(\n    defaultPrim = "World"\n)\n\ndef Xform "World" (\n'
                   '    prepend references = @./other.usda@\n)\n{\n}\n',
                   '#usda 1.0\n(\n    defaultPrim = "Thing"\n)\n\ndef Xform "Thing" (\n'
                   '    prepend references = @./scene.usda@\n)\n{\n}\n'),
    "sublayers": ('#usda 1.0\n(\n    subLayers = [@./other.usda@]\n)\n',
                  '#usda 1.0\n(\n    subLayers = [@./scene.usda@]\n)\n'),
}


@pytest.mark.parametrize("arc", sorted(CYCLE_LAYERS))
def test_layers_in_a_cycle_are_named_and_nothing_is_left(scene, capsys, arc):
    """A scene whose layers reference (or sublayer) each other in a cycle composes nothing:
    the error is USD's own cycle report, naming both layers, and no build folder is made."""
    scene_text, other_text = CYCLE_LAYERS[arc]
    scene.write_text(scene_text)
    (scene.parent / "other.usda").write_text(other_text)
    line = bad_input(capsys, "build", scene, names="composition error: ")
    assert f"@{scene}@" in line and f"@{scene.parent / 'other.usda'}@" in line
    assert ("Cycle detected" if arc == "references" else "has cycles") in line
    assert "anon:" not in line
    assert not (scene.parent / ".usdbtf-build").exists()


def test_scene_without_recipes_builds_nothing_and_leaves_nothing(scene, capsys):
    scene.write_text(SCENE.replace("rel material:binding = </World/Looks/Pebbles>", ""))
    assert build(scene)["ran"] == []
    assert not (scene.parent / ".usdbtf-build").exists()


def test_build_on_dask_gives_the_same_outputs_and_stays_up_to_date(scene, capsys):
    """``usdbtf build --dask local:2``: the two bound materials' steps run as Dask tasks on a
    LocalCluster; every output file is byte-identical to a build without --dask, and a
    second build (on the cluster too) runs nothing."""
    import shutil

    scene.write_text(SCENE.replace('string look = "pebbles"', 'string look = "fabric"'))
    out = scene.parent / "build"
    first = build(scene)
    assert len(first["ran"]) == 4                          # two materials: compress + package each
    want = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    shutil.rmtree(out)
    shutil.rmtree(scene.parent / ".usdbtf-build")
    code, _, err = run(capsys, "build", scene, "--dask", "local:2")
    assert code == 0, err
    assert "dask: local:2: 2 worker(s)" in err and "4 step(s) run" in err
    steps = json.loads((scene.parent / ".usdbtf-build" / "scene" / "steps.json").read_text())
    assert steps["dask"]["scheduler"].startswith("tcp://127.0.0.1:")      # the SConstruct submitted them
    got = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    assert got == want
    again = build(scene, dask="local:2")
    assert again["ran"] == []
def test_build_json_report(scene, capsys):
    import json

    from cli_helpers import run

    code, out, _ = run(capsys, "build", scene, "--dry-run", "--json")
    report = json.loads(out)
    assert code == 0 and report["dry_run"] and [r["material"] for r in report["recipes"]] == ["/World/Looks/Pebbles"]
    assert report["recipes"][0]["options"] == ["--k", "6", "--codec", "png"]
    assert sorted(report["bound"]["/World/Looks/Pebbles"]) == ["/World/Ball", "/World/Switch"]
    code, out, err = run(capsys, "build", scene, "--json")
    report = json.loads(out)
    assert code == 0 and not report["dry_run"] and len(report["ran"]) == 2
    assert Path(report["recipes"][0]["asset"]).is_file() and "usdbtf" not in out.split("{", 1)[0]


@pytest.mark.parametrize("suffix", [".usdc", ".usd", ".usdz", ".obj"])
def test_build_asset_may_be_any_root_layer_format_package_writes(scene, capsys, suffix):
    scene.write_text(SCENE.replace("./build/pebbles.usda", f"./build/pebbles{suffix}"))
    if suffix in (".usdz", ".obj"):
        bad_input(capsys, "build", scene, "--dry-run", names="btf:build:asset (.usda/.usdc/.usd)")
        return
    recipes, _ = plan(scene)
    asset = scene.parent / "build" / f"pebbles{suffix}"
    assert recipes[0].asset == asset
    assert asset.with_name("pebbles_payload.usdc") in recipes[0].outputs()
