"""``usdbtf.mesh``: the one mesh type and loader, and mesh input safety (issue 14).

Every format reaches the same :class:`Mesh` (an OBJ and a USD file of the same quad, the
latter in centimetres under a transform, give the same surface in metres); per-corner values
split into per-vertex ones only at seams; polygons survive for authoring.  Then every command
that reads a mesh -- ``unwrap``, ``package --mesh``, ``render --mesh``, ``preview --mesh``,
``quilt --atlas`` -- meets hostile meshes (a USD syntax error, NaN and infinite points, no
faces, only degenerate faces) with exit status "bad data", one stderr line naming the file
and nothing written; degenerate triangles among good ones are dropped, never written as
zero-length normals or frames; atlas sizes have limits that are checked before xatlas runs.
"""
from __future__ import annotations

import contextlib
import functools
import io
import json
import re
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from pxr import Usd, UsdGeom

from cli_helpers import ok, run
from quilt_render_data import pebbles, work  # noqa: F401 (fixtures)
from quilt_render_data import plane_with_uv, write_obj, write_sphere
from usdbtf.errors import EXIT_DATA, EXIT_USAGE, BTFError, UsageError
from usdbtf.mesh import Mesh, load_mesh, smooth_normals
from usdbtf.unwrap import MAX_ATLAS_SIDE, UnwrapOptions, unwrap


# ------------------------------------------------------------------ the model and the loader


def _usd_quad(path, *, cm: bool = True, face_varying: bool = True, extra: str = ""):
    """A 0.1 m quad with st, as a USD layer: centimetres under a 50 cm translate when ``cm``,
    else metres and no transform."""
    scale = 100.0 if cm else 1.0
    move = ('double3 xformOp:translate = (50, 0, 0)\n    uniform token[] xformOpOrder = ["xformOp:translate"]'
            if cm else "")
    pts = ", ".join(f"({x * scale:g}, {y * scale:g}, 0)" for x, y in ((0, 0), (0.1, 0), (0.1, 0.1), (0, 0.1)))
    interp = "faceVarying" if face_varying else "vertex"
    path.write_text(f"""#usda 1.0
(
    defaultPrim = "root"
    metersPerUnit = {0.01 if cm else 1}
    upAxis = "Z"
)

def Xform "root"
{{
    {move}

    def Mesh "quad"
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [{pts}]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (
            interpolation = "{interp}"
        )
{extra}    }}
}}
""")
    return path


def test_every_format_reaches_the_same_mesh(tmp_path):
    quad = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0.0]])
    obj = load_mesh(write_obj(tmp_path / "q.obj", quad, np.array([[0, 1, 2], [0, 2, 3]]),
                              np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])))
    usd = load_mesh(_usd_quad(tmp_path / "q.usda"))
    assert (obj.name, usd.name) == ("q", "root") and (obj.up_axis, usd.up_axis) == ("Y", "Z")
    assert usd.metres_per_unit == 0.01
    # Centimetres under a 50 cm translate -> metres in world space.
    np.testing.assert_allclose(usd.corner(), obj.corner() + [0.5, 0, 0], atol=1e-12)
    assert usd.area() == pytest.approx(obj.area()) == pytest.approx(0.01)
    # Per-vertex st in the OBJ, face-varying in the USD: the same value at every corner.
    assert obj.uv.shape == (4, 2) and usd.uv.shape == (2, 3, 2)
    np.testing.assert_allclose(usd.corner(usd.uv), obj.corner(obj.uv))
    # The USD quad stays a quad for writers.
    counts, ids = usd.polygons()
    assert counts.tolist() == [4] and usd.triangles.ravel()[ids].tolist() == [0, 1, 2, 3]
    # Without transform and unit, values pass through bit for bit.
    plain = load_mesh(_usd_quad(tmp_path / "m.usda", cm=False))
    stage = Usd.Stage.Open(str(tmp_path / "m.usda"))
    raw = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/root/quad")).GetPointsAttr().Get(), np.float64)
    np.testing.assert_array_equal(plain.points, raw)


def test_split_corners_splits_points_only_at_seams():
    points = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [0.5, 1], [0, 1.0]]])   # a seam at point 2 only
    mesh = Mesh(points, tris, uv=uv)
    split = mesh.split_corners()
    assert len(split.points) == 5 and split.uv.shape == (5, 2)
    np.testing.assert_array_equal(split.corner(), mesh.corner())             # same surface
    np.testing.assert_array_equal(split.corner(split.uv), mesh.corner(mesh.uv))
    per_vertex = Mesh(points, tris, uv=points[:, :2])
    assert per_vertex.split_corners() is per_vertex


def test_polygons_come_back_for_writers():
    """A quad, a triangle and a pentagon, fan-triangulated: polygons() restores their corners."""
    polygons = [[0, 1, 2, 3], [4, 5, 6], [7, 8, 9, 10, 11]]
    fans = [[p[0], p[i], p[i + 1]] for p in polygons for i in range(1, len(p) - 1)]
    mesh = Mesh(np.random.default_rng(0).random((12, 3)), fans, face_sizes=[4, 3, 5])
    counts, ids = mesh.polygons()
    assert counts.tolist() == [4, 3, 5] and mesh.triangles.ravel()[ids].tolist() == list(range(12))
    with pytest.raises(BTFError, match="face sizes"):
        Mesh(mesh.points, fans, face_sizes=[3, 3, 3])


def test_smooth_normals_are_unit_where_faces_cancel():
    """Both sides of a sheet share its vertices: the area-weighted sum is zero there."""
    points = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    sheet = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])
    n = smooth_normals(points, sheet)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
    np.testing.assert_allclose(np.abs(n[:, 2]), 1.0)


def test_bad_values_are_errors_naming_the_source():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    with pytest.raises(BTFError, match=r"^here: vertex 1 is NaN"):
        Mesh(pts * [[1], [np.nan], [1]], [[0, 1, 2]], source="here")
    with pytest.raises(BTFError, match="out of range"):
        Mesh(pts, [[0, 1, 3]], source="here")
    with pytest.raises(BTFError, match="uv must be per vertex"):
        Mesh(pts, [[0, 1, 2]], uv=np.zeros((2, 2)), source="here")
    with pytest.raises(BTFError, match="no faces"):
        Mesh(pts, np.zeros((0, 3)), source="here")


# ------------------------------------------------------------------ hostile meshes, every command


@functools.lru_cache(maxsize=1)
def data_status() -> int:
    """What ``usdbtf.cli.main`` returns for bad input data (a BTFError) on this branch: 2 until
    the CLI maps every error class to its own status (issue 14, the safety work), then
    ``BTFError.exit_code`` (65).  The library-level tests check the class either way."""
    from usdbtf.cli import main

    with tempfile.TemporaryDirectory() as tmp:
        bad = Path(tmp) / "garbage.ply"
        bad.write_bytes(b"ply\nformat nonsense\n")
        with contextlib.redirect_stderr(io.StringIO()):
            code = main(["unwrap", str(bad), "-o", str(Path(tmp) / "o"), "--texels-per-metre", "100"])
    assert code in (EXIT_USAGE, EXIT_DATA), code
    return code


def bad_data(capsys, *argv, names: str, output) -> str:
    """The command must fail as bad input data with one stderr line naming ``names``, and leave
    ``output`` unwritten."""
    code, _, err = run(capsys, *argv)
    lines = err.strip().splitlines()
    assert code == data_status(), (code, err)
    assert len(lines) == 1 and lines[0].startswith(f"usdbtf {argv[0]}: error: "), err
    assert names in lines[0], lines[0]
    assert "Traceback" not in err
    assert not output.exists(), output
    return lines[0]


HOSTILE = {
    "syntax.usda": '#usda 1.0\ndef Mesh "m" {\n    point3f[] points = [(0, 0, 0), (1, 0, 0)\n}\n',
    "nan.usda": None,                  # a good quad with one NaN point (written below)
    "inf.obj": "v 0 0 0\nv 1 0 0\nv inf 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nf 1/1 2/2 3/3\n",
    "nomesh.usda": '#usda 1.0\ndef Xform "empty"\n{\n}\n',
    "nofaces.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n",
    "flat.obj": "v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 2/2 3/3 4/4\n",
}
WHY = {"syntax.usda": "parse error", "nan.usda": "NaN", "inf.obj": "inf.obj", "nomesh.usda": "no Mesh prim",
       "nofaces.obj": "nofaces.obj", "flat.obj": "zero surface area"}


@pytest.fixture(scope="module")
def hostile(work):
    folder = work / "hostile"
    folder.mkdir()
    for name, text in HOSTILE.items():
        if text is not None:
            (folder / name).write_text(text)
    text = _usd_quad(folder / "nan.usda").read_text()
    (folder / "nan.usda").write_text(text.replace("(10, 0, 0)", "(nan, 0, 0)"))
    assert "(nan, 0, 0)" in (folder / "nan.usda").read_text()
    return folder


@pytest.fixture(scope="module")
def asset(work, pebbles):
    """The pebbles sample packaged (for ``preview``)."""
    from usdbtf.cli import main

    out = work / "asset" / "pebbles.usda"
    assert main(["package", str(pebbles), "-o", str(out), "-q"]) == 0
    return out


COMMANDS = {
    "unwrap": lambda mesh, out, c, a: ("unwrap", mesh, "-o", out, "--texels-per-metre", 500),
    "package": lambda mesh, out, c, a: ("package", c, "-o", out / "a.usda", "--mesh", mesh, "--no-validate"),
    "render": lambda mesh, out, c, a: ("render", c, "--mesh", mesh, "--light", "dir:0,0,1", "--size", 16, 16,
                                       "-o", out / "r.exr"),
    "preview": lambda mesh, out, c, a: ("preview", a, "--mesh", mesh, "--light", "dir:0,0,1", "--size", 16, 16,
                                        "-o", out / "p.exr"),
}


@pytest.mark.parametrize("command", sorted(COMMANDS))
@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_hostile_meshes_are_bad_data_naming_the_file(hostile, pebbles, asset, work, capsys, command, name):
    out = work / f"out_{command}_{name.replace('.', '_')}"
    line = bad_data(capsys, *COMMANDS[command](hostile / name, out, pebbles, asset), names=WHY[name], output=out)
    assert name in line


def test_quilt_atlas_refuses_damaged_layers(work, pebbles, hostile, capsys):
    sphere = write_sphere(work / "tiny_sphere.obj", radius=0.02, subdivisions=1)
    ok(capsys, "unwrap", sphere, "-o", work / "tiny_uv", "--btf", pebbles, "-q")
    shutil.copytree(work / "tiny_uv", work / "tiny_uv_nan")
    nan_layer = work / "tiny_uv_nan" / "mesh.usda"
    text = re.sub(r"(point3f\[\] points = \[\()[^,]+", r"\1nan", nan_layer.read_text(), count=1)
    assert "points = [(nan, " in text
    nan_layer.write_text(text)
    for layer, why in ((nan_layer, "vertex 0 is NaN"), (hostile / "syntax.usda", "parse error"),
                       (hostile / "nan.usda", "usdbtf unwrap")):
        out = work / "quilt_bad"
        line = bad_data(capsys, "quilt", pebbles, "--atlas", layer, "-o", out, names=why, output=out)
        assert str(layer.name) in line
    # An atlas size past the limit, recorded as numbers.
    folder = work / "tiny_uv_wide"
    shutil.copytree(work / "tiny_uv", folder)
    stage = Usd.Stage.Open(str(folder / "mesh.usda"))
    prim = next(p for p in stage.Traverse() if p.GetCustomDataByKey("usdbtf"))
    prim.SetCustomDataByKey("usdbtf:atlas:width", MAX_ATLAS_SIDE * 4)
    stage.GetRootLayer().Save()
    bad_data(capsys, "quilt", pebbles, "--atlas", folder / "mesh.usda", "-o", work / "quilt_bad",
             names=f"outside 1..{MAX_ATLAS_SIDE}", output=work / "quilt_bad")


def _grid_with_degenerate_faces(path):
    """A 3 x 3 grid with st, plus a zero-area sliver and a triangle collapsed onto a vertex of
    its own (that vertex is used by no other face)."""
    points, faces, uv = plane_with_uv(0.1, n=3)
    n = len(points)
    points = np.concatenate([points, [[0.2, 0.2, 0.0]]])
    uv = np.concatenate([uv, [[0.9, 0.9]]])
    faces = np.concatenate([faces, [[0, 1, 2]], [[n, n, n]]])       # collinear row; a point
    return write_obj(path, points, faces, uv, normals=None), len(faces) - 2


def _unit_vectors(stage_path, attribute_paths) -> None:
    stage = Usd.Stage.Open(str(stage_path))
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        geom = UsdGeom.Mesh(prim)
        api = UsdGeom.PrimvarsAPI(prim)
        arrays = {"normals": geom.GetNormalsAttr().Get()}
        arrays.update({n: api.GetPrimvar(n).Get() for n in ("tangents", "bitangents") if api.HasPrimvar(n)})
        for name in attribute_paths:
            v = np.asarray(arrays[name], np.float64)
            assert np.isfinite(v).all() and np.allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-5), (prim, name)


def test_degenerate_faces_are_dropped_never_written(work, pebbles, capsys):
    obj, good = _grid_with_degenerate_faces(work / "degenerate.obj")
    code, _, err = run(capsys, "unwrap", obj, "-o", work / "degenerate_uv", "--texels-per-metre", 500)
    assert code == 0 and "dropped 2 degenerate triangles" in err, err
    record = json.loads((work / "degenerate_uv" / "unwrap.json").read_text())
    assert record["triangles"] == good and any("dropped 2 degenerate" in n for n in record["notes"])
    _unit_vectors(work / "degenerate_uv" / "mesh.usda", ("normals", "tangents", "bitangents"))
    # ... and packaged from the file directly: normals computed, all unit.
    ok(capsys, "package", pebbles, "--mesh", obj, "-o", work / "degenerate_asset" / "d.usda", "-q")
    _unit_vectors(work / "degenerate_asset" / "d_payload.usdc", ("normals",))


def test_zero_length_file_normals_are_recomputed(tmp_path):
    normals = ('        normal3f[] normals = [(0, 0, 1), (0, 0, 0), (0, 0, 1), (0, 0, 1)] (\n'
               '            interpolation = "vertex"\n        )\n')
    mesh = load_mesh(_usd_quad(tmp_path / "zero_n.usda", cm=False, extra=normals))
    assert mesh.normals is None and any("zero-length" in note for note in mesh.notes)
    np.testing.assert_allclose(mesh.with_normals().normals, np.tile([0.0, 0.0, 1.0], (4, 1)))


# ------------------------------------------------------------------ atlas size limits


@pytest.mark.parametrize("density", ["1e12", "1e6"])
def test_atlas_past_the_limit_is_refused_before_xatlas(work, capsys, density):
    """1e12 is past the option's own bound (the segfault of issue 14); 1e6 is a legal density
    whose atlas for this sphere would pass the size limit: refused from the estimate."""
    sphere = write_sphere(work / "limit_sphere.obj", radius=0.03, subdivisions=2)
    out = work / f"limit_{density}"
    t0 = time.perf_counter()
    code, _, err = run(capsys, "unwrap", sphere, "-o", out, "--texels-per-metre", density)
    assert time.perf_counter() - t0 < 10
    lines = err.strip().splitlines()
    assert code == EXIT_USAGE and len(lines) == 1, err
    if density == "1e12":
        assert "--texels-per-metre" in lines[0] and "1e12" in lines[0]
    else:
        assert "limit_sphere.obj" in lines[0] and "need an atlas of at least" in lines[0] and "texels/m" in lines[0]
    assert not out.exists()


def test_atlas_options_have_bounds(work, capsys):
    sphere = write_sphere(work / "bounds_sphere.obj", radius=0.03, subdivisions=1)
    for flag, value in (("--max-resolution", MAX_ATLAS_SIDE + 1), ("--max-resolution", 8), ("--padding", 0),
                        ("--padding", 1000), ("--texels-per-metre", "nan"), ("--texels-per-metre", "inf")):
        code, _, err = run(capsys, "unwrap", sphere, "-o", work / "bounds", "--texels-per-metre", 500, flag, value)
        assert code == EXIT_USAGE and flag in err and len(err.strip().splitlines()) == 1, (flag, value, err)
    assert not (work / "bounds").exists()
    with pytest.raises(UsageError):
        UnwrapOptions(texels_per_metre=-1.0).validate()


def test_a_modest_excess_lowers_the_density(work):
    """Past --max-resolution by less than the limit: the density is lowered (texel_scale < 1)."""
    mesh = load_mesh(write_sphere(work / "modest.obj", radius=0.03, subdivisions=2))
    density = 64 / np.sqrt(mesh.area()) * 1.5              # sqrt(area) x density = 1.5 x 64 texels
    result = unwrap(mesh, UnwrapOptions(texels_per_metre=density, max_resolution=64))
    assert max(result.atlas.width, result.atlas.height) <= 64
    assert 1 / 8 <= result.atlas.texel_scale < 1 / 1.5
    assert result.chart_map.shape == (result.atlas.height, result.atlas.width)
