"""The hostile-input suite (issue 14): every class of bad input and fault, for every command
that reads that kind of input, checked by :func:`hostile_helpers.check_failure` -- the exit
status, exactly one ``usdbtf CMD: error:`` line naming the problem, no traceback, the output
path and everything beside it unchanged byte for byte, the inputs unchanged, ``$TMPDIR`` clean.

Classes: scene text as code (build), outputs that must not be replaced, damaged compressed
folders, damaged or escaping manifests, non-finite data, command-line numbers, operating-
system errors (read-only, disk full, permission denied, is-a-directory), process-level
faults (kill -9, a second writer, SIGTERM), exit statuses and --debug.  The checker itself
is checked first: deliberately bad commands must fail it.
"""
from __future__ import annotations

import ctypes
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hostile_helpers import Outcome, check_failure, in_process, snapshot, subprocess_runner
from quilt_render_data import write_obj, write_sphere
from usdbtf.cli import main

USAGE, DATA, REFUSED, IO, INTERNAL = 2, 65, 73, 74, 1


def cli_ok(*argv) -> None:
    code = main([str(a) for a in argv])
    assert code == 0, argv


# ------------------------------------------------------------------ shared inputs (module scope)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """Small real inputs of every kind: a manifest, a compressed folder, a packaged asset, an
    unwrap layer, a render, a board, a mesh with texture coordinates."""
    root = tmp_path_factory.mktemp("hostile_data")
    cli_ok("synth", "pebbles", "-o", root / "src", "--sampling", "tiny", "--size", 16, "-q")
    cli_ok("compress", root / "src", "-o", root / "c", "--k", 4, "--codec", "png", "-q")
    # A text payload: tests below edit it as text (the default is usdc).
    cli_ok("package", root / "c", "-o", root / "asset" / "a.usda", "--payload-format", "usda", "-q")
    write_sphere(root / "sphere.obj", subdivisions=1)
    cli_ok("unwrap", root / "sphere.obj", "-o", root / "uv", "--texels-per-metre", 200, "-q")
    cli_ok("render", root / "c", "--swatch", "--view", "0,0", "--light", "30,0", "-o", root / "r.exr", "-q")
    cli_ok("board", "-o", root / "board.png", "--json", root / "board.json", "--cell-px", 20)
    return root


@pytest.fixture
def case(tmp_path, data, capfd, monkeypatch):
    """A per-test checker: work folder (the outputs' home, the working directory), fresh
    ``$TMPDIR`` per run, the shared inputs watched too."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    counter = [0]

    def check(argv, *, code, names, watch=(), runner=None):
        counter[0] += 1
        return check_failure(runner or in_process(capfd), argv, code=code, names=names,
                             watch=[work, data, *watch], tmpdir=tmp_path / f"tmpdir{counter[0]}")

    check.work = work
    return check


def copy(src: Path, dst: Path) -> Path:
    if src.is_dir():
        shutil.copytree(src, dst, symlinks=True)
    else:
        shutil.copy2(src, dst)
    return dst


# ------------------------------------------------------------------ the checker is checked


def _fake(code=65, stderr="usdbtf x: error: victim.png: bad\n", effect=None):
    def run(argv, tmpdir):
        if effect:
            effect(Path(argv[1]), Path(tmpdir))
        return Outcome(code, "", stderr)
    return run


@pytest.mark.parametrize("bad", [
    _fake(code=0),                                                                  # exits 0
    _fake(code=139),                                                                # crashed (signal)
    _fake(code=2),                                                                  # wrong status
    _fake(stderr="Traceback (most recent call last):\nusdbtf x: error: victim.png: bad\n"),  # a traceback
    _fake(stderr="usdbtf x: error: victim.png: bad\nusdbtf x: error: again\n"),     # two lines
    _fake(stderr="x: error: victim.png: bad\n"),                                    # not the format
    _fake(stderr="usdbtf x: error: something\n"),                                   # does not name f
    _fake(effect=lambda out, tmp: (tmp / "usdbtf-leftover").mkdir()),               # dirty $TMPDIR
    _fake(effect=lambda out, tmp: (out.parent / ".o.usdbtf-tmp-1").mkdir()),        # left beside -o
    _fake(effect=lambda out, tmp: (out / "file").write_text("changed")),           # -o changed
], ids=["exit-0", "signal", "wrong-status", "traceback", "two-lines", "format", "unnamed", "tmpdir",
        "leftover", "changed"])
def test_the_checker_fails_bad_commands(tmp_path, bad):
    out = tmp_path / "work" / "o"
    out.mkdir(parents=True)
    (out / "file").write_text("original")
    with pytest.raises(AssertionError):
        check_failure(bad, ["x", out], code=65, names="victim.png", watch=[tmp_path / "work"], tmpdir=tmp_path / "t")


def test_the_checker_passes_a_clean_failure(tmp_path):
    out = tmp_path / "work" / "o"
    out.mkdir(parents=True)
    check_failure(_fake(), ["x", out], code=65, names="victim.png", watch=[tmp_path / "work"], tmpdir=tmp_path / "t")


def test_snapshot_sees_hidden_files_links_and_content(tmp_path):
    (tmp_path / "a").write_text("1")
    before = snapshot(tmp_path)
    (tmp_path / ".hidden").write_text("")
    assert snapshot(tmp_path) != before
    (tmp_path / ".hidden").unlink()
    (tmp_path / "a").write_text("2")
    assert snapshot(tmp_path) != before


# ------------------------------------------------------------------ 1. scene text is never code

CANARY = "usdbtf-canary"


def _scene(folder: Path, source: Path, asset: str, options) -> Path:
    """A scene binding one BTF material with the given recipe (authored through the USD API,
    so any string reaches the attribute exactly)."""
    from pxr import Sdf, Usd, UsdGeom, UsdShade

    path = folder / "scene.usda"
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    mat = UsdShade.Material.Define(stage, "/World/Looks/Pebbles")
    prim = mat.GetPrim()
    prim.AddAppliedSchema("BtfMaterialAPI")
    prim.CreateAttribute("btf:build:source", Sdf.ValueTypeNames.Asset, custom=False,
                         variability=Sdf.VariabilityUniform).Set(Sdf.AssetPath(os.path.relpath(source, folder)))
    prim.CreateAttribute("btf:build:asset", Sdf.ValueTypeNames.Asset, custom=False,
                         variability=Sdf.VariabilityUniform).Set(Sdf.AssetPath(asset))
    if options is not None:
        prim.CreateAttribute("btf:build:options", Sdf.ValueTypeNames.String, custom=False,
                             variability=Sdf.VariabilityUniform).Set(options)
    UsdShade.MaterialBindingAPI.Apply(ball.GetPrim()).Bind(mat)
    stage.GetRootLayer().Save()
    return path


HOSTILE_OPTIONS = [
    '--k 4 ${__import__("pathlib").Path("%s").touch()}',
    "--k 4 $(touch %s)",
    "--k 4 `touch %s`",
    "--k 4 ; touch %s",
    "--k 4 | touch %s",
    "--k 4 && touch %s",
    "--k 4\ntouch %s",
    '--k 4 "touch %s',
    "--codec /tmp/%s",
    "--codec ../../%s.sh",
    "--k $(touch %s)",
    "--k 4 -o /tmp/%s",
    "--k 4 --workers 1 %s",
    "--k 4 --force %s",
    "--k=4 --seed=${%s}",
    "--solver 'rsvd; touch %s'",
]


@pytest.mark.parametrize("options", HOSTILE_OPTIONS)
def test_hostile_scene_options_run_nothing(case, data, options):
    folder = case.work / "scene"
    folder.mkdir()
    src = copy(data / "src", folder / "captures")
    canary = folder / CANARY
    text = options.replace("%s", str(canary))
    scene = _scene(folder, src, "./build/a.usda", text)
    case(["build", scene, "-q"], code=DATA, names=["/World/Looks/Pebbles", "btf:build:options"])
    assert not canary.exists() and not Path("/tmp", CANARY).exists()
    assert not (folder / "build").exists()


def test_hostile_file_names_in_a_scene_build_and_run_nothing(tmp_path, data):
    """Paths full of shell and SCons syntax are data: the build works, nothing else runs."""
    folder = tmp_path / "s"
    folder.mkdir()
    weird = "src $(touch CANARY) ${TARGET} `touch CANARY`; | 'q' \"d\" $$x"
    src = copy(data / "src", folder / weird)
    scene = _scene(folder, src, "./out $(touch CANARY) ${SOURCE}/a.usda", "--k 3 --codec png")
    cli_ok("build", scene, "-q")
    asset = folder / "out $(touch CANARY) ${SOURCE}" / "a.usda"
    assert asset.is_file()
    assert not list(folder.rglob("CANARY")) and not Path("CANARY").exists()
    from usdbtf.usd.scenes.build import build
    assert build(scene)["ran"] == []                     # content signatures still work


@pytest.mark.parametrize("asset,sublayer,names", [
    ("./scene.usda", None, ["scene.usda", "btf:build:asset", "a layer of the scene"]),   # the scene itself
    ("./captures/a.usda", None, ["captures", "the source"]),                             # inside the source
    ("./x.usda", "./x_payload.usdc", ["x_payload.usdc", "a layer of the scene"]),        # a piece over a sublayer
])
def test_scene_outputs_over_the_scene_or_its_source_are_refused(case, data, asset, sublayer, names):
    from pxr import Sdf

    folder = case.work / "scene"
    folder.mkdir()
    src = copy(data / "src", folder / "captures")
    scene = _scene(folder, src, asset, "--k 4")
    if sublayer:
        Sdf.Layer.CreateNew(str(folder / sublayer)).Save()      # the payload is usdc by default
        layer = Sdf.Layer.FindOrOpen(str(scene))
        layer.subLayerPaths.append(sublayer)
        layer.Save()
    case(["build", scene, "-q"], code=REFUSED, names=names)


def test_scene_asset_over_a_foreign_file_is_refused_even_with_force(case, data):
    folder = case.work / "scene"
    (folder / "build").mkdir(parents=True)
    (folder / "build" / "a.usda").write_text("#usda 1.0\n# somebody's layer\n")
    src = copy(data / "src", folder / "captures")
    scene = _scene(folder, src, "./build/a.usda", "--k 4")
    case(["build", scene, "-q"], code=REFUSED, names=["a.usda", "--force"])


def test_failed_rebuild_keeps_the_last_good_build(tmp_path, data, capfd):
    folder = tmp_path / "s"
    folder.mkdir()
    src = copy(data / "src", folder / "captures")
    scene = _scene(folder, src, "./build/a.usda", "--k 3 --codec png")
    cli_ok("build", scene, "-q")
    built = snapshot(folder / "build")
    assert (folder / "build" / "a_compressed" / "btf-compressed.json").is_file()
    victim = sorted(src.glob("*.png"))[4]
    victim.write_bytes(victim.read_bytes()[:60])         # the source goes bad
    line = check_failure(in_process(capfd), ["build", scene, "-q"], code=DATA, names=[victim.name, "build failed"],
                         watch=[folder / "build"], tmpdir=tmp_path / "t")
    assert "usdbtf compress" in line
    assert snapshot(folder / "build") == built


# ------------------------------------------------------------------ 2. outputs usdbtf did not make


def _user_folder(path: Path) -> Path:
    path.mkdir(parents=True)
    (path / "holiday.jpg").write_bytes(b"\xff\xd8 my photo")
    (path / "notes.txt").write_text("keep me")
    return path


# (command line with OUT for the output, the kind of thing OUT must be)
WRITERS = {
    "synth": (["synth", "pebbles", "-o", "OUT", "--sampling", "tiny", "--size", 8, "-q"], "folder"),
    "compress": (["compress", "DATA/src", "-o", "OUT", "--k", 2, "-q"], "folder"),
    "decompress": (["decompress", "DATA/c", "-o", "OUT", "-q"], "folder"),
    "quilt": (["quilt", "DATA/c", "-o", "OUT", "--size", 24, 24, "-q"], "folder"),
    "unwrap": (["unwrap", "DATA/sphere.obj", "-o", "OUT", "--texels-per-metre", 100, "-q"], "folder"),
    "rectify": (["rectify", "DATA/nowhere", "-o", "OUT", "-q"], "folder"),
    "package": (["package", "DATA/c", "-o", "OUT.usda", "-q"], "file"),
    "render": (["render", "DATA/c", "--swatch", "--view", "0,0", "--light", "30,0", "-o", "OUT.exr", "-q"], "file"),
    "board": (["board", "-o", "OUT.png", "--json", "OUT.json"], "file"),
}


def _argv(template, data: Path, out: Path):
    res = []
    for a in template:
        if isinstance(a, str) and a.startswith("OUT"):
            res.append(str(out) + a[3:])
        elif isinstance(a, str) and a.startswith("DATA/"):
            res.append(str(data / a[5:]))
        else:
            res.append(a)
    return res


@pytest.mark.parametrize("command", sorted(WRITERS))
def test_existing_output_needs_force(case, data, command):
    template, kind = WRITERS[command]
    out = case.work / "out"
    if command != "rectify":
        code = main([str(a) for a in _argv(template, data, out)])
        assert code == 0
    else:
        copy(data / "src", out)                                    # a previous manifest
    case(_argv(template, data, out), code=REFUSED, names=["--force", "out"])


@pytest.mark.parametrize("command", sorted(WRITERS))
def test_foreign_output_is_never_replaced_even_with_force(case, data, command):
    template, kind = WRITERS[command]
    out = case.work / "out"
    if kind == "folder":
        _user_folder(out)
        names = [str(out), "not a usdbtf"]
    else:
        suffix = {"package": ".usda", "render": ".exr", "board": ".png"}[command]
        Path(str(out) + suffix).write_text("a file usdbtf did not write")
        names = [str(out) + suffix, "not a usdbtf"]
    case(_argv(template, data, out) + ["--force"], code=REFUSED, names=names)


@pytest.mark.parametrize("command", ["synth", "compress", "decompress", "quilt", "unwrap"])
def test_a_file_where_a_folder_goes(case, data, command):
    out = case.work / "notes.txt"
    out.write_text("my notes")
    case(_argv(WRITERS[command][0], data, out) + ["--force"], code=REFUSED, names=["notes.txt", "is a file"])


@pytest.mark.parametrize("command", ["render", "package", "board"])
def test_a_folder_where_a_file_goes(case, data, command):
    out = case.work / "out"
    suffix = {"package": ".usda", "render": ".exr", "board": ".png"}[command]
    Path(str(out) + suffix).mkdir()
    case(_argv(WRITERS[command][0], data, out) + ["--force"], code=REFUSED, names=[f"out{suffix}", "is a folder"])


@pytest.mark.parametrize("argv,names", [
    (["compress", "WORK/src", "-o", "WORK/src", "--force", "-q"], "is the input"),
    (["compress", "WORK/src", "-o", "WORK/src/sub", "-q"], "is inside the input"),
    (["compress", "WORK/src", "-o", "WORK", "--force", "-q"], "working directory"),
    (["decompress", "WORK/c", "-o", "WORK/c", "--force", "-q"], "is the input"),
    (["decompress", "WORK/c", "-o", ".", "--force", "-q"], "working directory"),
    (["decompress", "WORK/c", "-o", "..", "--force", "-q"], "working directory"),
    (["quilt", "WORK/c", "-o", "WORK/c", "--size", 24, 24, "--force", "-q"], "is the input"),
    (["package", "WORK/c", "-o", "WORK/c/a.usda", "-q"], "is inside the input"),
    (["render", "WORK/c", "--swatch", "--view", "0,0", "--light", "30,0", "-o", "WORK/c/r.exr", "-q"],
     "is inside the input"),
    (["synth", "pebbles", "-o", ".", "--force", "-q"], "working directory"),
    (["unwrap", "WORK/sphere.obj", "-o", "WORK/sphere.obj", "--texels-per-metre", 100, "--force", "-q"],
     "is the input"),
    (["compress", "WORK/src", "-o", "WORK/lnk", "--force", "-q"], "symbolic link"),
    (["synth", "pebbles", "-o", "WORK/notes.txt/sub", "-q"], "is not a folder"),
], ids=lambda v: "-".join(map(str, v)) if isinstance(v, list) else v)
def test_outputs_that_are_inputs_or_the_working_directory(case, data, argv, names):
    w = case.work
    copy(data / "src", w / "src")
    copy(data / "c", w / "c")
    copy(data / "sphere.obj", w / "sphere.obj")
    (w / "notes.txt").write_text("notes")
    (w / "lnk").symlink_to(w / "c")
    argv = [str(a).replace("WORK", str(w)) for a in argv]
    case(argv, code=REFUSED, names=names)


def test_failure_removes_the_folders_it_made_for_the_output(case, data):
    case(["compress", case.work / "missing", "-o", case.work / "new" / "deeper" / "out", "-q"], code=DATA,
         names="missing")
    case(["decompress", data / "c", "-o", case.work / "new" / "d", "--k", 99, "-q"], code=USAGE, names="--k")
    assert not (case.work / "new").exists()


def test_decompress_into_a_photo_folder_deletes_nothing(case, data):
    photos = _user_folder(case.work / "photos")
    case(["decompress", data / "c", "-o", photos, "--force"], code=REFUSED, names=["photos", "not a usdbtf"])


def test_output_of_another_kind_is_not_replaced(case, data):
    c = copy(data / "c", case.work / "c")
    case(["decompress", data / "c", "-o", c, "--force", "-q"], code=REFUSED,
         names=["btf-compressed/1", "not a btf-manifest/1"])
    src = copy(data / "src", case.work / "src")
    case(["compress", data / "src", "-o", src, "--force", "-q"], code=REFUSED,
         names=["btf-manifest/1", "not a btf-compressed/1"])


def test_capture_and_rig_sim_refuse_foreign_folders(case, data):
    photos = _user_folder(case.work / "photos")
    case(["capture", "--port", "socket://127.0.0.1:9", "-o", photos, "--camera-cmd", "true {out}", "-q"],
         code=REFUSED, names=["photos", "not a usdbtf"])
    case(["rig-sim", "--frames", photos / "notes.txt", "-q"], code=REFUSED, names=["notes.txt", "is a file"])
    case(["rig-sim", "--frames", photos, "-q"], code=REFUSED, names=["photos"])
    case(["rig-sim", "--frames", case.work / "f", "--port-file", photos / "notes.txt", "-q"], code=REFUSED,
         names=["notes.txt", "--force"])
    case(["bench", "--smoke", "-o", photos], code=REFUSED, names=["photos"])


def test_capture_that_fails_at_once_leaves_nothing(case):
    raw = case.work / "RAW"
    case(["capture", "--port", case.work / "no-such-port", "-o", raw, "--camera-cmd", "true {out}", "--sampling",
          "tiny", "--timeout", "0.2", "--reconnect-timeout", "0", "--retries", "0", "-q"],
         code=DATA, names="no-such-port")
    assert not raw.exists()


# ------------------------------------------------------------------ 3. damaged btf-compressed.json


def _damage(doc: dict, how: str):
    b, c0, s = doc["basis"], doc["coefficients"][0], doc["samples"]
    if how == "list":
        return [doc]
    if how == "no-basis-file":
        del b["file"]
    elif how == "width-string":
        doc["width"] = "abc"
    elif how == "width-zero":
        doc["width"] = 0
    elif how == "k-bool":
        doc["k"] = True
    elif how == "k-more-than-files":
        doc["coefficients"] = doc["coefficients"][:-1]
    elif how == "views-lights-lengths":
        s["light"] = s["light"][:-1]
    elif how == "scale-length":
        b["scale"] = b["scale"][:-1]
    elif how == "coeff-scale-length":
        c0["scale"] = c0["scale"] + [1.0]
    elif how == "nan-scale":
        c0["scale"][1] = float("nan")
    elif how == "inf-bias":
        b["bias"][0] = float("inf")
    elif how == "theta-200":
        s["light"][3] = [200.0, 0.0]
    elif how == "theta-nan":
        s["view"][0] = [float("nan"), 0.0]
    elif how == "duplicate-direction":
        s["view"][1], s["light"][1] = s["view"][0], s["light"][0]
    elif how == "interpolated-range":
        s["interpolated"] = [10_000]
    elif how == "coefficient-outside":
        c0["file"] = "../../../etc/passwd"
    elif how == "coefficient-absolute":
        c0["file"] = "/etc/passwd"
    elif how == "codec":
        doc["codec"] = "../../bin/sh"
    elif how == "matrix":
        doc["color_matrix"] = [[1, 0], [0, 1]]
    elif how == "layout":
        b["layout"] = {"kind": "tiles", "views": 3, "lights": 3, "grid": [1, 1]}
    elif how == "samples-list":
        doc["samples"] = []
    elif how == "coefficients-object":
        doc["coefficients"] = {"0": c0}
    elif how == "source-depth":
        doc["source"] = {"bit_depth": "uint3"}
    elif how == "huge":
        doc["width"] = doc["height"] = 60000
        doc["k"] = 4
    else:
        raise AssertionError(how)
    return doc


DAMAGES = {"list": "document", "no-basis-file": "basis.file", "width-string": "width", "width-zero": "width",
           "k-bool": "k", "k-more-than-files": "coefficients", "views-lights-lengths": "lights",
           "scale-length": "basis.scale", "coeff-scale-length": "coefficients[0].scale",
           "nan-scale": "coefficients[0].scale[1]", "inf-bias": "basis.bias[0]", "theta-200": "samples.light[3]",
           "theta-nan": "samples.view[0]", "duplicate-direction": "same view and light",
           "interpolated-range": "samples.interpolated", "coefficient-outside": "coefficients[0].file",
           "coefficient-absolute": "coefficients[0].file", "codec": "codec", "matrix": "color_matrix",
           "layout": "basis.layout", "samples-list": "samples", "coefficients-object": "coefficients",
           "source-depth": "source.bit_depth", "huge": "memory"}


def _damaged(data: Path, folder: Path, how: str) -> Path:
    c = copy(data / "c", folder)
    meta = c / "btf-compressed.json"
    meta.write_text(json.dumps(_damage(json.loads(meta.read_text()), how)))
    return c


@pytest.mark.parametrize("how", sorted(DAMAGES))
def test_damaged_metadata_decompress(case, data, how):
    c = _damaged(data, case.work / "c", how)
    case(["decompress", c, "-o", case.work / "d", "-q"], code=DATA, names=["btf-compressed.json", DAMAGES[how]])


READERS = {
    "info": lambda c, w: ["info", c],
    "render": lambda c, w: ["render", c, "--swatch", "--view", "0,0", "--light", "30,0", "-o", w / "r.exr", "-q"],
    "package": lambda c, w: ["package", c, "-o", w / "a.usda", "-q"],
    "quilt": lambda c, w: ["quilt", c, "-o", w / "q", "--size", 24, 24, "-q"],
    "unwrap": lambda c, w: ["unwrap", w / "sphere.obj", "--btf", c, "-o", w / "uv", "-q"],
}


@pytest.mark.parametrize("reader", sorted(READERS))
@pytest.mark.parametrize("how", ["nan-scale", "width-string", "theta-200", "k-more-than-files"])
def test_damaged_metadata_other_readers(case, data, reader, how):
    c = _damaged(data, case.work / "c", how)
    copy(data / "sphere.obj", case.work / "sphere.obj")
    case(READERS[reader](c, case.work), code=DATA, names=["btf-compressed.json", DAMAGES[how]])


def test_nan_in_a_half_float_coefficient_texture(case, data):
    c = case.work / "cx"
    cli_ok("compress", data / "src", "-o", c, "--k", 2, "--codec", "exr", "-q")
    from usdbtf.imageio import read_image, write_image
    px, _ = read_image(c / "coeff" / "c001.exr")
    px = px.copy()
    px[3, 2, 0] = np.nan
    write_image(c / "coeff" / "c001.exr", px, color_space="data", allow_non_finite=True)
    case(["decompress", c, "-o", case.work / "d", "-q"], code=DATA, names=["c001.exr", "NaN"])
    case(["render", c, "--swatch", "--view", "0,0", "--light", "30,0", "-o", case.work / "r.exr", "-q"],
         code=DATA, names=["c001.exr", "NaN"])


def test_missing_and_corrupt_texture_files(case, data):
    c = copy(data / "c", case.work / "c")
    (c / "coeff" / "c002.png").unlink()
    case(["decompress", c, "-o", case.work / "d", "-q"], code=DATA, names="c002.png")
    c2 = copy(data / "c", case.work / "c2")
    (c2 / "basis.png").write_bytes(b"\x89PNG garbage")
    case(["info", c2], code=DATA, names="basis.png")
    c3 = copy(data / "c", case.work / "c3")
    (c3 / "btf-compressed.json").write_text("{ not json")
    case(["decompress", c3, "-o", case.work / "d", "-q"], code=DATA, names=["btf-compressed.json", "not a readable"])


def test_truncated_png_is_one_line(case, data):
    """libpng prints its own "libpng error: ..." line on the C stderr while OIIO reads a
    truncated PNG: every reader still prints exactly one line, with libpng's reason in it."""
    c = copy(data / "c", case.work / "c")
    whole = (c / "basis.png").read_bytes()
    (c / "basis.png").write_bytes(whole[: len(whole) // 2])
    names = ["basis.png", "corrupt or truncated", "end of file"]
    case(["render", c, "--swatch", "--view", "0,0", "--light", "30,0", "-o", case.work / "r.exr", "-q"],
         code=DATA, names=names)
    case(["info", c], code=DATA, names=names)
    case(["render", c, "--swatch", "--view", "0,0", "--light", "30,0", "-o", case.work / "r.exr", "-q"],
         code=DATA, names=names, runner=subprocess_runner())


def test_native_stderr_capture_keeps_what_is_not_libpng(capfd):
    from usdbtf.imageio import native_stderr_captured

    with native_stderr_captured(), native_stderr_captured():        # nested, as concurrent reads are
        os.write(2, b"libpng warning: iCCP: known incorrect sRGB profile\nsomeone else's line\n")
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "someone else's line\nafter\n"


def test_a_child_forked_during_a_capture_gets_its_stderr_back(capfd):
    from usdbtf.imageio import native_stderr_captured

    with native_stderr_captured():
        pid = os.fork()
        if pid == 0:                        # the child: fd 2 is the real stderr again
            os.write(2, b"child line\n")
            os._exit(0)
        os.waitpid(pid, 0)
    assert capfd.readouterr().err == "child line\n"


# ------------------------------------------------------------------ 4. manifests


def _manifest(data: Path, folder: Path, edit) -> Path:
    m = copy(data / "src", folder)
    doc = json.loads((m / "btf.json").read_text())
    edit(doc, m)
    (m / "btf.json").write_text(json.dumps(doc))
    return m


def _outside(doc, m):
    secret = m.parent / "private"
    secret.mkdir()
    shutil.copy(m / doc["samples"][3]["image"], secret / "secret.png")
    doc["samples"][3]["image"] = "../private/secret.png"


def _absolute(doc, m):
    doc["samples"][2]["image"] = str((m / doc["samples"][2]["image"]).resolve())


def _symlink_out(doc, m):
    target = m.parent / "elsewhere.png"
    shutil.copy(m / doc["samples"][1]["image"], target)
    (m / "link.png").symlink_to(target)
    doc["samples"][1]["image"] = "link.png"


MANIFEST_DAMAGES = {
    "outside": (_outside, ["secret.png", "outside the manifest's folder", "--allow-outside-paths"]),
    "absolute": (_absolute, ["#2", "outside the manifest's folder"]),
    "symlink-out": (_symlink_out, ["link.png", "symbolic link"]),
    "declares-20000": (lambda d, m: d.update(width=20000, height=20000), ["declares 20000x20000", "16x16"]),
    "declares-100000": (lambda d, m: d.update(width=100000, height=3), ["declares 100000x3"]),
    "theta-200": (lambda d, m: d["samples"][5].update(light=[200.0, 0.0]), ["theta out of range"]),
    "nan-view": (lambda d, m: d["samples"][0].update(view=[float("nan"), 0]), ["finite"]),
    "image-null-byte": (lambda d, m: d["samples"][0].update(image="a\u0000b.png"), ["image"]),
    "samples-object": (lambda d, m: d.update(samples={"a": 1}), ["samples"]),
}


@pytest.mark.parametrize("how", sorted(MANIFEST_DAMAGES))
@pytest.mark.parametrize("command", ["compress", "info", "error"])
def test_damaged_or_escaping_manifests(case, data, how, command):
    edit, names = MANIFEST_DAMAGES[how]
    m = _manifest(data, case.work / "m", edit)
    argv = {"compress": ["compress", m, "-o", case.work / "c", "-q"], "info": ["info", m],
            "error": ["error", m, data / "src"]}[command]
    t0 = time.perf_counter()
    case(argv, code=DATA, names=names)
    assert time.perf_counter() - t0 < 10        # refused up front, not after allocating


@pytest.mark.parametrize("command", ["compress", "info"])
def test_btf_json_that_is_a_symlink_loop_or_dangling(case, data, command):
    """A manifest whose btf.json cannot be followed is named with the link's chain, not
    called an "unrecognised BTF input (folder)"."""
    m = copy(data / "src", case.work / "m")
    (m / "btf.json").unlink()
    (m / "btf.json").symlink_to("other.json")
    (m / "other.json").symlink_to("btf.json")
    argv = {"compress": ["compress", m, "-o", case.work / "c", "-q"], "info": ["info", m]}[command]
    case(argv, code=IO, names=["btf.json", "symbolic link loop (btf.json -> other.json -> btf.json)"])
    case([*argv[:1], m / "other.json", *argv[2:]], code=IO,
         names=["other.json", "symbolic link loop (other.json -> btf.json -> other.json)"])
    (m / "other.json").unlink()
    case(argv, code=DATA, names=["btf.json", "dangling symbolic link (-> other.json: no such file)"])


def test_allow_outside_paths_reads_them(tmp_path, data, capsys):
    m = _manifest(data, tmp_path / "m", _outside)
    assert main(["info", str(m), "--allow-outside-paths"]) == 0
    assert main(["--allow-outside-paths", "compress", str(m), "-o", str(tmp_path / "c"), "--k", "2", "-q"]) == 0


def test_rectify_refuses_raw_frames_outside_the_capture(case, data):
    m = _manifest(data, case.work / "RAW", _outside)
    case(["rectify", m, "-o", case.work / "R", "-q"], code=DATA, names=["secret.png", "outside"])


def test_info_reports_the_images_real_size(tmp_path, data, capsys):
    capsys.readouterr()
    assert main(["info", str(data / "src")]) == 0
    assert "samples of 16x16" in capsys.readouterr().out


# ------------------------------------------------------------------ 5. nothing non-finite is written


def test_nan_vertex_in_a_package_mesh(case, data):
    points = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0.1, 0.1, np.nan]])
    mesh = write_obj(case.work / "nan.obj", points, np.array([[0, 1, 2], [1, 3, 2]]),
                     uv=np.array([[0, 0], [1, 0], [0, 1], [1, 1.0]]))
    line = case(["package", data / "c", "-o", case.work / "a.usda", "--mesh", mesh, "-q"], code=DATA, names=[])
    # Refused by the mesh reader (naming the file) or, failing that, by the publish gate.
    assert "nan.obj" in line or ("a_payload.usdc" in line and "non-finite" in line), line


def test_inspect_validate_reports_non_finite_numbers(case, data):
    asset = copy(data / "asset", case.work / "asset")
    payload = asset / "a_payload.usda"
    payload.write_text(payload.read_text().replace("point3f[] points = [(-0.025", "point3f[] points = [(nan", 1))
    line = case(["inspect", asset / "a.usda", "--validate"], code=DATA, names=["a.usda", "fails validation"])
    assert "NonFiniteValue" in line and "points" in line


def test_write_image_refuses_non_finite_pixels(tmp_path):
    from usdbtf.errors import BTFError
    from usdbtf.imageio import write_image
    img = np.zeros((4, 4, 3), np.float32)
    img[1, 2, 0] = np.inf
    with pytest.raises(BTFError, match="x=2, y=1"):
        write_image(tmp_path / "x.exr", img, color_space="ACEScg")
    assert not (tmp_path / "x.exr").exists()


def test_package_refuses_layers_with_non_finite_numbers(tmp_path):
    from pxr import Sdf, Usd, UsdGeom
    from usdbtf.usd.asset.finite import non_finite_values
    path = tmp_path / "l.usda"
    stage = Usd.Stage.CreateNew(str(path))
    mesh = UsdGeom.Mesh.Define(stage, "/m")
    mesh.CreatePointsAttr([(0, 0, 0), (1, float("nan"), 0)])
    mesh.CreateExtentAttr().Set([(0, 0, 0), (1, 1, 0)], 3.0)
    stage.GetRootLayer().Save()
    assert non_finite_values(path) == ["/m.points"]
    mesh.GetExtentAttr().Set([(0, 0, 0), (float("inf"), 1, 0)], 5.0)
    stage.GetRootLayer().Save()
    assert sorted(non_finite_values(path)) == ["/m.extent at time 5", "/m.points"]
    assert Sdf  # imported for the layer API


# ------------------------------------------------------------------ 6. command-line numbers


NUMBERS = [
    (["synth", "nosuch", "-o", "O"], "nosuch"),
    (["synth", "pebbles", "-o", "O", "--size", 0], "--size"),
    (["synth", "pebbles", "-o", "O", "--size", 100000], "--size"),
    (["synth", "pebbles", "-o", "O", "--physical-size", "nan"], "--physical-size"),
    (["synth", "pebbles", "-o", "O", "--seed", -1], "--seed"),
    (["compress", "DATA/src", "-o", "O", "--k", 0], "--k"),
    (["compress", "DATA/src", "-o", "O", "--k", 100000], "--k"),
    (["compress", "DATA/src", "-o", "O", "--target-error", "nan"], "--target-error"),
    (["compress", "DATA/src", "-o", "O", "--target-error", -1], "--target-error"),
    (["compress", "DATA/src", "-o", "O", "--memory-budget", "inf"], "--memory-budget"),
    (["compress", "DATA/src", "-o", "O", "--workers", 0], "--workers"),
    (["compress", "DATA/src", "-o", "O", "--codec", "/tmp/x"], "--codec"),
    (["decompress", "DATA/c", "-o", "O", "--k", 0], "--k"),
    (["decompress", "DATA/c", "-o", "O", "--samples", "0-1000000000"], "--samples"),
    (["decompress", "DATA/c", "-o", "O", "--samples", "5-2"], "--samples"),
    (["quilt", "DATA/c", "-o", "O", "--size", 0, 64], "--size"),
    (["quilt", "DATA/c", "-o", "O", "--size", 99999, 64], "--size"),
    (["quilt", "DATA/c", "-o", "O", "--size", 64, 64, "--tolerance", "nan"], "--tolerance"),
    (["quilt", "DATA/c", "-o", "O", "--size", 64, 64, "--block", 1], "--block"),
    (["render", "DATA/c", "--swatch", "--view", "0,0", "--light", "30,0", "-o", "O.exr", "--size", 0, 9], "--size"),
    (["render", "DATA/c", "--swatch", "--view", "0,0", "--light", "30,0", "-o", "O.exr", "--threads", 0],
     "--threads"),
    (["render", "DATA/c", "--swatch", "--view", "nan,0", "--light", "30,0", "-o", "O.exr"], "--view"),
    (["render", "DATA/c", "--swatch", "--view", "0,0", "--light", "30,1e300", "-o", "O.exr"], "--light"),
    (["render", "DATA/c", "--mesh", "DATA/sphere.obj", "--light", "point:nan,1,1", "-o", "O.exr"], "point:nan"),
    (["preview", "DATA/asset/a.usda", "--swatch", "--view", "0,0", "--light", "30,0", "-o", "O.exr", "--size",
      -4, 4], "--size"),
    (["unwrap", "DATA/sphere.obj", "-o", "O", "--texels-per-metre", "1e12"], "--texels-per-metre"),
    (["unwrap", "DATA/sphere.obj", "-o", "O", "--texels-per-metre", 0], "--texels-per-metre"),
    (["unwrap", "DATA/sphere.obj", "-o", "O", "--texels-per-metre", 100, "--max-resolution", 0],
     "--max-resolution"),
    (["package", "DATA/c", "-o", "O.usda", "--physical-size", -1, 1], "--physical-size"),
    (["package", "DATA/c", "-o", "O.usda", "--lod", "a,b"], "--lod"),
    (["package", "DATA/c", "-o", "O.usda", "--lod", "99"], "--lod"),
    (["rectify", "DATA/nowhere", "-o", "O", "--size", 4], "--size"),
    (["rectify", "DATA/nowhere", "-o", "O", "--size", 999999], "--size"),
    (["rectify", "DATA/nowhere", "-o", "O", "--max-residual", "inf"], "--max-residual"),
    (["board", "-o", "O.png", "--json", "O.json", "--grid", 1], "--grid"),
    (["board", "-o", "O.png", "--json", "O.json", "--cell-px", 0], "--cell-px"),
    (["board", "-o", "O.png", "--json", "O.json", "--grid", 100, "--cell-px", 4000], "pixel board"),
    (["board", "-o", "O.png", "--json", "O.json", "--physical-size", 0], "--physical-size"),
    (["rig-sim", "--frames", "O", "--listen", "127.0.0.1:99999"], "--listen"),
    (["rig-sim", "--frames", "O", "--listen", "nonsense"], "--listen"),
    (["rig-sim", "--frames", "O", "--texture-size", 0], "--texture-size"),
    (["rig-sim", "--frames", "O", "--frame-size", "100000x10"], "--frame-size"),
    (["rig-sim", "--frames", "O", "--fill", 2], "--fill"),
    (["rig-sim", "--frames", "O", "--fault-rate", 1], "--fault-rate"),
    (["rig-sim", "--frames", "O", "--material", "nosuch"], "nosuch"),
    (["capture", "--port", "x", "-o", "O", "--camera-cmd", "true", "--timeout", 0], "--timeout"),
    (["capture", "--port", "x", "-o", "O", "--camera-cmd", "true", "--timeout", "nan"], "--timeout"),
    (["capture", "--port", "x", "-o", "O", "--camera-cmd", "true", "--baud", 0], "--baud"),
    (["capture", "--port", "x", "-o", "O", "--camera-cmd", "true", "--retries", -1], "--retries"),
    (["bench", "--smoke", "-o", "O", "--holdout", 2], "--holdout"),
    (["compress", "DATA/src", "-o", "O", "--no-such-option"], "--no-such-option"),
]


@pytest.mark.parametrize("argv,names", NUMBERS, ids=lambda v: " ".join(map(str, v))[:60] if isinstance(v, list)
                         else v)
def test_command_line_numbers_are_bounded(case, data, argv, names):
    argv = [str(a).replace("DATA/", f"{data}/") for a in argv]
    argv = [str(case.work / a) if a in ("O", "O.exr", "O.png", "O.json", "O.usda") else a for a in argv]
    case(argv, code=USAGE, names=names)


# ------------------------------------------------------------------ 7. operating-system errors

_CAP_DAC_OVERRIDE, _CAP_DAC_READ_SEARCH, _PR_CAPBSET_DROP = 1, 2, 24


def _drop_file_capabilities():
    """In the child: root without the capabilities that bypass file permissions (so a 0555
    folder is read-only for it), the way an ordinary user meets one."""
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (_CAP_DAC_OVERRIDE, _CAP_DAC_READ_SEARCH):
        if libc.prctl(_PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl")


def _can_drop_capabilities() -> bool:
    if os.geteuid() != 0:
        return True            # an ordinary user meets permissions anyway
    probe = subprocess.run([sys.executable, "-c", "import os,sys; sys.exit(0 if os.access('/root', os.W_OK) else 3)"],
                           preexec_fn=_drop_file_capabilities, capture_output=True)
    return probe.returncode in (0, 3)


needs_permissions = pytest.mark.skipif(not _can_drop_capabilities(),
                                       reason="cannot drop CAP_DAC_OVERRIDE here (not Linux, or no CAP_SETPCAP)")


def _read_only_runner():
    return subprocess_runner(preexec_fn=_drop_file_capabilities if os.geteuid() == 0 else None)


@needs_permissions
@pytest.mark.parametrize("command", ["synth", "compress", "decompress", "package", "render"])
def test_read_only_output_folder(case, data, command):
    ro = case.work / "ro"
    ro.mkdir()
    template = WRITERS[command][0]
    argv = _argv(template, data, ro / "out")
    os.chmod(ro, 0o555)
    try:
        case(argv, code=IO, names=[str(ro), "ermission denied"], runner=_read_only_runner())
    finally:
        os.chmod(ro, 0o755)


@needs_permissions
def test_unreadable_inputs(case, data):
    m = copy(data / "src", case.work / "m")
    os.chmod(m / "btf.json", 0)
    c = copy(data / "c", case.work / "c")
    os.chmod(c / "coeff" / "c001.png", 0)
    try:
        case(["compress", m, "-o", case.work / "o", "-q"], code=IO, names=["btf.json", "ermission denied"],
             runner=_read_only_runner())
        case(["info", m], code=IO, names=["btf.json", "ermission denied"], runner=_read_only_runner())
        case(["decompress", c, "-o", case.work / "d", "-q"], code=IO, names=["c001.png", "ermission denied"],
             runner=_read_only_runner())
    finally:
        os.chmod(m / "btf.json", 0o644)
        os.chmod(c / "coeff" / "c001.png", 0o644)


def _file_size_limit(limit: int):
    def preexec():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)       # write() fails with EFBIG instead of a kill
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return preexec


@pytest.mark.parametrize("command,limit", [("compress", 1500), ("package", 3000), ("render", 2000),
                                           ("synth", 300), ("decompress", 300)])
def test_disk_full(case, data, command, limit):
    argv = _argv(WRITERS[command][0], data, case.work / "out")
    case(argv, code=IO, names=["out", "file size limit exceeded" if command != "x" else ""],
         runner=subprocess_runner(preexec_fn=_file_size_limit(limit)))


def test_is_a_directory_inputs(case, data):
    (case.work / "board.json").mkdir()
    case(["rectify", case.work / "nowhere", "-o", case.work / "R", "--board", case.work / "board.json"],
         code=IO, names=["board.json", "Is a directory"])
    m = copy(data / "src", case.work / "m")
    first = json.loads((m / "btf.json").read_text())["samples"][0]["image"]
    (m / first).unlink()
    (m / first).mkdir()
    case(["compress", m, "-o", case.work / "o", "-q"], code=IO, names=[first, "is a folder"])


# ------------------------------------------------------------------ 8. process-level faults


def _usdbtf(*argv, **kw):
    env = dict(os.environ, OCIO="ocio://default")
    return subprocess.Popen([sys.executable, "-m", "usdbtf.cli", *map(str, argv)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def test_kill_9_mid_write_then_rerun(tmp_path, data):
    out = tmp_path / "C"
    clean = tmp_path / "clean"
    cli_ok("compress", data / "src", "-o", clean, "--k", 4, "--codec", "png", "-q")
    cli_ok("compress", data / "src", "-o", out, "--k", 2, "--codec", "png", "-q")   # a previous output
    previous = snapshot(out)
    from usdbtf import atomic

    # Stop the writer inside its commit-free window: the staging folder exists, the swap has not happened.
    proc = _usdbtf("compress", data / "src", "-o", out, "--k", 4, "--codec", "png", "-q", "--force")
    deadline = time.time() + 60
    while time.time() < deadline and not any(atomic.TMP_TAG in p.name for p in tmp_path.iterdir()):
        time.sleep(0.002)
    proc.kill()
    proc.wait()
    assert snapshot(out) == previous or snapshot(out) == snapshot(clean)  # never a mixture
    leftovers = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".C."))
    assert leftovers, "the test must kill the writer while it has something beside the output"
    cli_ok("compress", data / "src", "-o", out, "--k", 4, "--codec", "png", "-q", "--force")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["C", "clean"]     # the killed run's staging is gone
    assert snapshot(out) == snapshot(clean)                                  # and the output is the clean one


def test_kill_9_during_the_swap_is_finished_by_the_next_run(tmp_path, data):
    """A READY staging folder (killed between moving the old output out and the new one in)
    is rolled forward by the next writer: the result is the complete new output."""
    from usdbtf import atomic

    out = tmp_path / "C"
    cli_ok("compress", data / "src", "-o", out, "--k", 2, "--codec", "png", "-q")
    newer = tmp_path / "newer"
    cli_ok("compress", data / "src", "-o", newer, "--k", 3, "--codec", "png", "-q")
    staging = tmp_path / f".C{atomic.TMP_TAG}99999-dead"
    (staging / "new").mkdir(parents=True)
    (staging / "old").mkdir()
    shutil.move(str(newer), staging / "new" / "C")
    (staging / "READY").write_text('["C"]')
    shutil.move(str(out), staging / "old" / "C")        # the kill came right after this rename
    assert not out.exists()
    from usdbtf.compress import read_compressed
    with atomic.claim(out, folder=True):               # the next writer (or any claim) finishes it
        pass
    assert read_compressed(out).k == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["C"]


@pytest.mark.parametrize("record", ["", '["C"', '["../C"]', '{"C": 1}', None],
                         ids=["empty", "cut-short", "outside", "not-a-list", "only-the-part"])
def test_kill_9_while_the_ready_record_is_written_leaves_the_output_as_it_was(tmp_path, data, record):
    """A staging folder whose READY record is empty or unusable (a kill -9 while it was written,
    the CI failure of stop 51) or that only has the record's ``.part`` never reached its commit:
    the next writer removes it, leaves the existing output byte-identical, and then succeeds."""
    from usdbtf import atomic

    out = tmp_path / "C"
    cli_ok("compress", data / "src", "-o", out, "--k", 2, "--codec", "png", "-q")
    before = snapshot(out)
    staging = tmp_path / f".C{atomic.TMP_TAG}99999-dead"
    (staging / "new").mkdir(parents=True)
    cli_ok("compress", data / "src", "-o", staging / "new" / "C", "--k", 3, "--codec", "png", "-q")
    if record is None:
        (staging / "READY.part").write_text('["C"]')
    else:
        (staging / "READY").write_text(record)
    with atomic.claim(out, folder=True):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["C"]      # the staging folder is gone
    assert snapshot(out) == before                                   # and the output untouched
    cli_ok("compress", data / "src", "-o", out, "--k", 3, "--codec", "png", "-q", "--force")
    from usdbtf.compress import read_compressed
    assert read_compressed(out).k == 3


def test_a_second_writer_is_told_another_process_is_writing(case, data):
    from usdbtf import atomic

    out = case.work / "C"
    lock = atomic._Lock(atomic._real(out))
    lock.acquire(out)                                  # another process holds the output
    try:
        line = case(["compress", data / "src", "-o", out, "-q"], code=REFUSED,
                    names=["being written by another process", f"pid {os.getpid()}"],
                    watch=[], runner=subprocess_runner())
    finally:
        lock.release()
    assert str(out) in line


def test_two_concurrent_writers(tmp_path, data):
    out = tmp_path / "C"
    procs = [_usdbtf("compress", data / "src", "-o", out, "--k", 4, "--codec", "png", "-q", "--force")
             for _ in range(2)]
    results = [(p.wait(timeout=120), p.stderr.read()) for p in procs]
    codes = sorted(c for c, _ in results)
    assert codes in ([0, 0], [0, REFUSED]), results      # one may finish before the other starts
    for code, err in results:
        if code:
            assert "being written by another process" in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["C"]


def test_sigterm_cleans_up(tmp_path, data):
    out = tmp_path / "C"
    proc = _usdbtf("compress", data / "src", "-o", out, "--k", 4, "--codec", "png", "-q")
    deadline = time.time() + 60
    while time.time() < deadline and not any(p.name.startswith(".C.") for p in tmp_path.iterdir()):
        time.sleep(0.002)
    proc.send_signal(signal.SIGTERM)
    code = proc.wait(timeout=60)
    err = proc.stderr.read()
    assert code in (0, 143), err                          # finished first, or terminated cleanly
    if code == 143:
        assert err.strip() == "usdbtf compress: terminated"
        assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_output_modes_follow_the_umask(tmp_path, data, mask):
    out = tmp_path / "c"
    old = os.umask(mask)
    try:
        cli_ok("compress", data / "src", "-o", out, "--k", 2, "--codec", "png", "-q")
        cli_ok("render", out, "--swatch", "--view", "0,0", "--light", "30,0", "-o", tmp_path / "r.exr", "-q")
    finally:
        os.umask(old)
    assert (out.stat().st_mode & 0o777) == 0o777 & ~mask
    assert ((out / "coeff").stat().st_mode & 0o777) == 0o777 & ~mask
    assert ((out / "btf-compressed.json").stat().st_mode & 0o777) == 0o666 & ~mask
    assert ((tmp_path / "r.exr").stat().st_mode & 0o777) == 0o666 & ~mask


# ------------------------------------------------------------------ 9. exit statuses, --debug, --help


def test_internal_error_is_one_line_and_debug_shows_the_traceback(case, data, monkeypatch, capfd):
    import usdbtf.compress.decompress as dec

    def boom(*a, **k):
        raise RuntimeError("a bug")

    monkeypatch.setattr(dec, "decompress_to_folder", boom)
    line = case(["decompress", data / "c", "-o", case.work / "d", "-q"], code=INTERNAL,
                names=["internal error", "RuntimeError: a bug", "rerun with --debug"])
    assert line.endswith("rerun with --debug for the traceback")
    capfd.readouterr()
    assert main(["decompress", str(data / "c"), "-o", str(case.work / "d"), "-q", "--debug"]) == INTERNAL
    err = capfd.readouterr().err
    assert "Traceback (most recent call last)" in err and "RuntimeError: a bug" in err
    assert err.strip().splitlines()[-1].startswith("usdbtf decompress: error: internal error")


def test_argparse_errors_are_one_line(case, capfd):
    case(["compress"], code=USAGE, names="required")
    case(["compress", "x", "-o", "y", "--nonsense"], code=USAGE, names="--nonsense")
    with pytest.raises(SystemExit) as exc:
        main(["nosuchcommand"])
    err = capfd.readouterr().err.strip().splitlines()
    assert exc.value.code == USAGE and len(err) == 1 and err[0].startswith("usdbtf: error: ") \
        and "nosuchcommand" in err[0]


def test_help_documents_exit_statuses_force_debug(capsys):
    from usdbtf.cli import build_parser

    parser = build_parser()
    text = parser.format_help()
    for needle in ("exit status:", "65", "73", "74", "--force", "--debug", "--allow-outside-paths"):
        assert needle in text, needle
    sub = next(a for a in parser._actions if a.dest == "command")
    writers = set()
    for name, p in sub.choices.items():
        page = p.format_help()
        assert "exit status:" in page and "--debug" in page, name
        if "--force" in page:
            writers.add(name)
    assert {"board", "capture", "rectify", "synth", "compress", "decompress", "quilt", "unwrap", "package",
            "render", "preview", "build", "bench", "rig-sim"} <= writers
    for reader in ("compress", "info", "error", "rectify"):
        assert "--allow-outside-paths" in sub.choices[reader].format_help(), reader


def test_usd_syntax_error_and_wrong_inputs(case, data):
    bad = case.work / "bad.usda"
    bad.write_text("#usda 1.0\ndef Mesh \"m\" {\n  point3f[] points = [(0, 0, 0), (1, \n")
    case(["package", data / "c", "-o", case.work / "a.usda", "--mesh", bad, "-q"], code=DATA, names="bad.usda")
    case(["inspect", bad], code=DATA, names="bad.usda")
    case(["decompress", bad, "-o", case.work / "d", "-q"], code=DATA, names="bad.usda")
    case(["preview", data / "c", "--swatch", "--view", "0,0", "--light", "30,0", "-o", case.work / "p.exr", "-q"],
         code=DATA, names=str(data / "c"))
    case(["render", data / "src", "--swatch", "--view", "0,0", "--light", "30,0", "-o", case.work / "r.exr", "-q"],
         code=DATA, names="src")


# ------------------------------------------------------------------ 10. the recognisers follow the formats


def test_output_markers_match_the_formats(data):
    """usdbtf.outputs knows each format's marker without importing the writers: the names
    must stay those the writers use, and every fresh output must be recognised."""
    from usdbtf import fiducials, manifest, outputs
    from usdbtf.compress import format as fmt
    from usdbtf.quilt import folder as quilt_folder
    from usdbtf.rig import capture
    from usdbtf.unwrap import core as unwrap_core

    assert (outputs._MANIFEST_FILE, outputs.MANIFEST) == (manifest.MANIFEST, manifest.FORMAT)
    assert (outputs._COMPRESSED_FILE, outputs.COMPRESSED) == (fmt.METADATA, fmt.FORMAT)
    assert outputs._COMPRESSED_EXTRAS == {quilt_folder.POSITION_MAP, *quilt_folder._CURVE_FILES}
    assert outputs._UNWRAP_FILES == {unwrap_core.LAYER, unwrap_core.CHARTS, unwrap_core.RECORD}
    assert outputs.BOARD == fiducials.FORMAT
    assert outputs._CAPTURE_FILES.fullmatch(capture.JOURNAL) and outputs._CAPTURE_FILES.fullmatch(capture.FLAT_FILE)
    expected = {"src": outputs.MANIFEST, "c": outputs.COMPRESSED, "uv": outputs.UNWRAP, "r.exr": outputs.RENDER,
                "r.png": outputs.RENDER, "board.png": outputs.BOARD_IMAGE, "board.json": outputs.BOARD,
                "asset/a.usda": outputs.ASSET, "asset/a_payload.usda": outputs.ASSET,
                "asset/a_textures": outputs.ASSET_TEXTURES, "sphere.obj": None}
    assert {name: outputs.identify(data / name) for name in expected} == expected
