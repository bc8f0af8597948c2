"""examples/built_figure.py (the docs' Storm and Cycles pictures of a built scene): what it refuses
to overwrite, the user UVs of its knot and the scene it hands to ``usdbtf build``.  The renders
themselves take minutes and need the bpy environments: they are run by hand (the script's usage)."""
from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "examples" / "built_figure.py"


@pytest.fixture(scope="module")
def figure():
    spec = importlib.util.spec_from_file_location("built_figure", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_refuses_to_overwrite_what_is_not_a_png(tmp_path):
    notes = tmp_path / "notes.png"
    notes.write_text("not a picture\n")
    proc = subprocess.run([sys.executable, str(SCRIPT), "--renderer", "storm", "-o", str(notes)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 73
    assert proc.stderr.strip().splitlines() == [
        f"built_figure: error: {notes}: exists and is not a PNG picture; refusing to replace it"]
    assert notes.read_text() == "not a picture\n"


def test_refusals_before_any_work(figure, tmp_path, capsys):
    text = tmp_path / "picture.txt"
    assert figure.main(["--renderer", "cycles", "-o", str(text)]) == 73
    assert not text.exists()
    folder = tmp_path / "folder.png"
    folder.mkdir()
    assert figure.main(["--renderer", "storm", "-o", str(folder)]) == 73
    foreign = tmp_path / "work"
    foreign.mkdir()
    (foreign / "mine.txt").write_text("keep\n")
    assert figure.main(["--renderer", "storm", "-o", str(tmp_path / "a.png"), "--workdir", str(foreign)]) == 73
    assert sorted(p.name for p in foreign.iterdir()) == ["mine.txt"]
    assert figure.main(["--renderer", "storm", "-o", str(tmp_path / "a.png"), "--size", "640"]) == 2
    errors = capsys.readouterr().err.splitlines()
    assert [e.split(": ")[-1] for e in errors] == ["the picture must be a .png path",
                                                   "exists and is not a plain file; refusing to replace it",
                                                   "--workdir exists and was not made by this script; refusing to "
                                                   "use it", "want WIDTHxHEIGHT, each at least 16"]
    # A PNG there already (a previous picture) may be replaced.
    png = tmp_path / "old.png"
    png.write_bytes(figure.PNG_SIGNATURE + b"\0" * 8)
    assert figure.picture_refusal(png) is None


def test_knot_uvs_wrap_without_crossing_the_square(figure):
    points, faces, st = figure.knot_with_uvs()
    assert points.shape == (figure.SEGMENTS * figure.SIDES, 3)
    assert st.shape == (len(faces), 3, 2)
    assert st.min() == 0.0 and st.max() == 1.0
    # Every face spans one grid step in u and in v: no face runs back across the square at a seam.
    span = st.max(axis=1) - st.min(axis=1)
    assert np.allclose(span.max(axis=0), [1 / figure.SEGMENTS, 1 / figure.SIDES])
    # The knot is 20 cm across, as the legend says.
    extent = points.max(axis=0) - points.min(axis=0)
    assert 0.19 < max(extent[0], extent[2]) < 0.21


def test_scene_is_what_build_reads(figure):
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    text = figure.scene_text(640, 400)
    assert figure.scene_text(640, 400) == text         # rewritten only when it changes: same bytes
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.ImportFromString(text)
    stage = Usd.Stage.Open(layer)
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    knot = stage.GetPrimAtPath("/World/Knot")
    material = UsdShade.MaterialBindingAPI(knot).GetDirectBinding().GetMaterialPath()
    assert material == Sdf.Path("/World/Looks/Pebbles")
    recipe = stage.GetPrimAtPath(material)
    assert recipe.GetAttribute("btf:build:source").Get().path == f"./captures/{figure.PRESET}"
    assert recipe.GetAttribute("btf:build:options").Get() == f"--k {figure.K}"
    assert stage.GetPrimAtPath("/World/Sun").GetTypeName() == "DistantLight"
    assert stage.GetPrimAtPath("/World/Cam").GetTypeName() == "Camera"


@pytest.mark.parametrize("script,args", [("storm_figure", ["asset.usda"]), ("preview_figure", ["asset.usda"]),
                                         ("fig5", []), ("figure", ["raw", "compressed"])])
def test_every_picture_script_refuses_a_file_that_is_not_a_png(script, args, tmp_path, monkeypatch, capsys):
    """The other example scripts that draw pictures share examples/pictures.py's rule, checked
    before any work (their inputs here do not exist)."""
    monkeypatch.syspath_prepend(str(SCRIPT.parent))
    spec = importlib.util.spec_from_file_location(f"example_{script}", SCRIPT.parent / f"{script}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    scene = tmp_path / "scene.png"
    scene.write_text("#usda 1.0\n")
    assert module.main([*args, "-o", str(scene)]) == 73
    assert scene.read_text() == "#usda 1.0\n"
    assert capsys.readouterr().err == f"{script}: error: {scene}: exists and is not a PNG picture; refusing to " \
                                      "replace it\n"
