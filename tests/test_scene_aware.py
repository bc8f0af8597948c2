"""Builds shaped by the scene (issue 26): the plan of a real USD stage (visibility, frustum,
screen size, directions with the renderers' interpolation neighbours), the requirements in
the SCons signature, ``--full`` as before, and ``render --camera --frames``.  The builds are real (SCons, the
usdbtf steps as processes) on 32-texel materials of the 13 x 13 ``small`` sampling."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import usdbtf  # noqa: F401
from cli_helpers import ok
from usdbtf.bench.scenes import Quad, Shot, write_scene
from usdbtf.commands.build import source_facts
from usdbtf.render.hemisphere import Triangulation
from usdbtf.usd.scenes.build import build, plan, steps

LIGHT = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])


@pytest.fixture(scope="module")
def captures(tmp_path_factory, synth_capture) -> Path:
    root = tmp_path_factory.mktemp("captures")
    for preset in ("pebbles", "fuzzy_moss", "ridged_fabric"):
        synth_capture(preset, "small", 32, out=root / preset)
    return root


def _scene(folder: Path, captures: Path, *, second_camera: bool = False) -> Path:
    """Near: a 5 cm quad filling the frame; Far: a 2 cm quad 2 m away (a few pixels);
    Hidden: an invisible quad and a proxy one in front of the floor; one camera moving
    sideways over three frames, one light."""
    if not (folder / "captures").exists():
        shutil.copytree(captures, folder / "captures")
    mats = {"Near": folder / "captures/pebbles", "Far": folder / "captures/ridged_fabric",
            "Hidden": folder / "captures/fuzzy_moss"}
    quads = [Quad("Floor", "Near", 0.05, (0, 0, 0)), Quad("Tile", "Far", 0.02, (0.05, 0.0, -2.0)),
             Quad("Ghost", "Hidden", 0.05, (0, 0.1, 0), visible=False),
             Quad("Stand_in", "Hidden", 0.05, (0, 0, 0.01), purpose="proxy")]      # in view, but a proxy
    shots = [Shot("Cam", [(-0.01 + 0.01 * i, 0.0, 0.12) for i in range(3)], [(0, 0, 0)], fov=40)]
    if second_camera:      # a grazing view of the floor: views the first camera never asks for
        shots.append(Shot("Side", [(0.15, 0.0, 0.04)], [(0, 0, 0)], fov=40))
    path = folder / "scene.usda"
    path.unlink(missing_ok=True)
    return write_scene(path, mats, quads, shots, light_towards=LIGHT, frames=(1, 3), resolution=(96, 64),
                       options="--k 8 --codec png --domain srgb")


def test_plan_skips_the_invisible_material_and_says_why(captures, tmp_path):
    recipes, report = plan(_scene(tmp_path, captures), source_facts=source_facts)
    needs = report["needs"]
    assert report["skipped"] == [] and report["stand_ins"] == ["/World/Looks/Hidden"]
    assert needs["/World/Looks/Hidden"].prims == {
        "/World/Ghost": "invisible at every frame",
        "/World/Stand_in": "proxy-only (purpose proxy: not in a final render)"}
    assert not needs["/World/Looks/Hidden"].needed
    assert [r.material for r in recipes if not r.stand_in] == ["/World/Looks/Far", "/World/Looks/Near"]
    hidden = next(r for r in recipes if r.stand_in)
    assert hidden.options[-2:] == ("--k", "1") and "--max-texels" in hidden.shape
    assert len(needs["/World/Looks/Hidden"].coverage()["views"]) == 1
    near, far = needs["/World/Looks/Near"], needs["/World/Looks/Far"]
    assert near.frames == 3 and near.max_texels is None              # close up: every texel
    # Far: 2 cm at 2 m under a 64-pixel-high 40-degree frame: ~1 pixel for its 32 texels,
    # filtered down to the floor of 16 texels.
    assert far.pixels_per_texel < 0.1 and far.max_texels == 16 and far.mip_levels["finest"] == 1
    shaped = {r.material: r.shape for r in recipes}
    assert "--max-texels" in shaped["/World/Looks/Far"] and "--max-texels" not in shaped["/World/Looks/Near"]


def test_fixed_camera_and_light_need_a_thin_slice_with_its_interpolation_neighbours(captures, tmp_path):
    _, report = plan(_scene(tmp_path, captures), source_facts=source_facts)
    near = report["needs"]["/World/Looks/Near"]
    facts = near.facts
    assert len(near.lights) * len(near.views) < 0.25 * len(facts.lights) * len(facts.views)
    # The floor's tangent frame is the world's (st along +X, +Y; normal +Z), so the local light
    # is LIGHT everywhere: exactly the three corners of its triangle of the measured lights.
    lights = Triangulation.from_directions(facts.lights)
    idx, w, _ = lights.weights(LIGHT[None])
    assert near.lights == sorted(idx[0].tolist())
    # Every view the camera sees at the floor's centre and corners, with its triangle's corners.
    views = Triangulation.from_directions(facts.views)
    for eye in ([-0.01, 0, 0.12], [0.01, 0, 0.12]):
        for point in ([0, 0, 0], [0.025, 0.025, 0], [-0.025, -0.025, 0]):
            d = np.subtract(eye, point)
            idx, _, _ = views.weights((d / np.linalg.norm(d))[None])
            assert set(idx[0].tolist()) <= set(near.views), (eye, point)
    cov = near.coverage()
    assert cov["format"] == "usdbtf-coverage/1" and len(cov["views"]) == len(near.views)


def test_requirements_rebuild_on_a_needier_camera_and_nothing_on_no_change(captures, tmp_path, capsys):
    scene = _scene(tmp_path, captures)
    first = build(scene, source_facts=source_facts)
    assert any("compress" in s and "Near" in s for s in first["ran"])
    # The hidden material is a one-direction, k = 1 stand-in: the scene's reference resolves.
    stand_in = json.loads((tmp_path / "build/Hidden_compressed/btf-compressed.json").read_text())
    assert stand_in["k"] == 1 and len(stand_in["coverage"]["views"]) == len(stand_in["coverage"]["lights"]) == 1
    from pxr import Usd
    assert not Usd.Stage.Open(str(scene)).GetCompositionErrors()
    from cli_helpers import run
    code, out, err = run(capsys, "inspect", str(first["built_scene"]), "--validate")
    assert code == 0, err
    assert "validation: 0 error(s)" in out
    assert "[usdbtf:Coverage]" not in out          # the plan keeps what its own camera and light ask for
    _check_frames(scene, tmp_path / "frames", capsys)
    _check_mesh_walks(scene)
    meta = json.loads((tmp_path / "build/Near_compressed/btf-compressed.json").read_text())
    kept = meta["coverage"]["views"]
    assert build(scene, source_facts=source_facts)["ran"] == []             # nothing changed
    _scene(tmp_path, captures, second_camera=True)
    third = build(scene, source_facts=source_facts)
    assert [s for s in third["ran"] if s.startswith("usdbtf-step compress")] == \
        ['usdbtf-step compress "/World/Looks/Near"']                      # Far's needs did not change
    meta = json.loads((tmp_path / "build/Near_compressed/btf-compressed.json").read_text())
    assert len(meta["coverage"]["views"]) > len(kept)
    assert {tuple(v) for v in kept} <= {tuple(v) for v in meta["coverage"]["views"]}   # the union
    assert build(scene, source_facts=source_facts)["ran"] == []


def test_full_is_todays_build(captures, tmp_path):
    scene = _scene(tmp_path, captures)
    recipes, report = plan(scene)
    assert not report["shaped"] and "needs" not in report
    assert [r.shape for r in recipes] == [(), (), ()]
    doc = steps(recipes)
    for s in doc["steps"]:
        assert s["compress"]["argv"][:3] == ["compress", "--force", "-q"]
        assert "--coverage" not in s["compress"]["argv"] and not s["compress"]["requirements"]


def _check_frames(scene: Path, folder: Path, capsys) -> None:
    """``render SCENE --camera --frames`` writes the numbered frames of the moving camera."""
    import OpenImageIO as oiio

    ok(capsys, "render", str(scene), "--camera", "/World/Cam", "--frames", "2:3", "-o", str(folder / "f.####.exr"),
       "--no-png")
    images = [np.asarray(oiio.ImageBuf(str(folder / f"f.000{i}.exr")).get_pixels(oiio.FLOAT)) for i in (2, 3)]
    assert images[0].shape == (64, 96, 4)
    assert 0.1 < images[0][..., 3].mean() < 1.0 and images[0][..., :3].max() > 0.05     # the floor, lit
    assert not np.array_equal(images[0], images[1])                                     # the camera moved


def _check_mesh_walks(scene: Path) -> None:
    """The one walk over a stage's BTF meshes (issue 41) gives both callers the prims they took
    before: ``render ASSET`` (:func:`usdbtf.usd.scenes.scene.bound_btf_meshes`) every bound mesh, the
    invisible and the proxy one included; ``render --camera`` (:func:`usdbtf.usd.scenes.shots.scene_shots`)
    only what a final render shows at each frame."""
    from pxr import Usd

    from usdbtf.usd.scenes.scene import bound_btf_meshes
    from usdbtf.usd.scenes.shots import scene_shots

    parts = bound_btf_meshes(Usd.Stage.Open(str(scene)))
    assert [m.name for _, m in parts] == ["Floor", "Tile", "Ghost", "Stand_in"]
    assert parts[2][0] is parts[3][0] and parts[0][0] is not parts[1][0]      # one CompressedBTF a material
    materials, shots = scene_shots(scene, "/World/Cam", 96, [1, 3])
    assert [[(material, m.name) for material, m in shot.parts] for shot in shots] == \
        [[("/World/Looks/Near", "Floor"), ("/World/Looks/Far", "Tile")]] * 2
    assert sorted(materials) == ["/World/Looks/Far", "/World/Looks/Near"]


def test_screen_error_target_becomes_a_per_texel_target(captures, tmp_path):
    recipes, report = plan(_scene(tmp_path, captures), source_facts=source_facts, target_error=2.0)
    near, far = report["needs"]["/World/Looks/Near"], report["needs"]["/World/Looks/Far"]
    assert near.target_error == 2.0                        # a texel covers pixels: the screen's target
    # Far: a pixel averages many texels, so each texel may be off by more (capped at 100 %).
    assert far.target_error == pytest.approx(min(100.0, 2.0 / (far.pixels_per_texel * 2)))
    shape = {r.material: r.shape for r in recipes}
    assert shape["/World/Looks/Near"][-2:] == ("--target-error", "2.0")


def test_dry_run_json_and_table(captures, tmp_path, capsys):
    from cli_helpers import run

    scene = _scene(tmp_path, captures)
    code, out, err = run(capsys, "build", str(scene), "--dry-run", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["shaped"] and doc["skipped"] == [] and doc["stand_ins"] == ["/World/Looks/Hidden"]
    near = doc["needs"]["/World/Looks/Near"]
    assert near["needed"] and near["lights"] == {"kept": 3, "measured": 13} and near["coverage"]["lights"]
    assert "no, stand-in (k 1): invisible at every frame; proxy-only" in err            # the table on stderr
    assert not (tmp_path / "build").exists()                              # a dry run builds nothing
