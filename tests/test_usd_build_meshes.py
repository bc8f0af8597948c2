"""``usdbtf build SCENE`` on bound meshes (issue 31): every (material, mesh) binding gets an
atlas at the material's measured density, a quilt across its charts and a packaged material,
composed by the built scene without editing the user's file; ``inspect`` checks the density."""
from __future__ import annotations

import json

import pytest

import usdbtf  # noqa: F401
from cli_helpers import bad_input, bad_usage, ok, refused, run
from scene_build_data import build_scene, open_stage
from usdbtf.usd.scenes.build import build
from usdbtf.usd.density import binding_densities

BOX = '''
        int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
        int[] faceVertexIndices = [0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3]
        point3f[] points = [(0, 0, 0), (0, 0, 0.15), (0, 0.1, 0), (0, 0.1, 0.15), (0.2, 0, 0), (0.2, 0, 0.15),
                            (0.2, 0.1, 0), (0.2, 0.1, 0.15)]
        texCoord2f[] primvars:st = [(0, 0), (0, 1), (1, 0), (1, 1), (1, 0), (1, 1), (0, 1), (0, 0)] (
            interpolation = "vertex"
        )
        rel material:binding = </World/Looks/Pebbles>'''


def _material(name: str, stem: str) -> str:
    """A Material with a build recipe (synthetic capture ``captures/STEM``, k = 4)."""
    lines = [f'def Material "{name}" (', '    prepend apiSchemas = ["BtfMaterialAPI"]',
             f'    prepend references = @./build/{stem}.usda@</{stem}/mtl/BtfMaterial>', ')', '{',
             f'    uniform asset btf:build:source = @./captures/{stem}@',
             '    uniform string btf:build:options = "--k 4 --codec png"',
             f'    uniform asset btf:build:asset = @./build/{stem}.usda@', '}']
    return "\n".join(" " * 8 + line for line in lines)


MATERIALS = _material("Pebbles", "pebbles") + "\n" + _material("Moss", "moss")

HEADER = '#usda 1.0\n(\n    defaultPrim = "World"\n    metersPerUnit = 1\n    upAxis = "Y"\n)\n\n'

SCENE = HEADER + '''def Xform "World"
{
    def Mesh "Box" (prepend apiSchemas = ["MaterialBindingAPI"])
    {''' + BOX + '''
        double3 xformOp:translate = (0.5, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Mesh "BoxCopy" (prepend apiSchemas = ["MaterialBindingAPI"])
    {''' + BOX + '''
        double3 xformOp:translate = (-0.5, 0, 0)
        float xformOp:rotateY = 90
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY"]
    }
    def Mesh "Plane" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(0, 0, 0), (0.3, 0, 0), (0.3, 0, 0.2), (0, 0, 0.2)]
        rel material:binding = </World/Looks/Moss>
        double3 xformOp:scale = (2, 2, 2)
        uniform token[] xformOpOrder = ["xformOp:scale"]
    }
    def Mesh "Floor" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, 0, -1), (1, 0, -1), (1, 0, 1), (-1, 0, 1)]
        texCoord2f[] primvars:st = [(0, 0), (1, 0), (1, 1), (0, 1)] (interpolation = "vertex")
        rel material:binding = </World/Looks/Moss>
        uniform token btf:build:mapping = "tile"
    }
    def Scope "Looks"
    {
''' + MATERIALS + '''
    }
}
'''


#: The floor's tileable quilt side in this module, texels (the product's default is
#: binding.TILE_SIZE = 256).  What these tests check of the "tile" mapping (st scaled so one tile
#: spans the quilt's physical size, the density ratio 1, one shared quilt, the same bytes at -j 1
#: and -j 2) holds at any side; at 64 the floor's quilt step takes a tenth of the time (it was the
#: slowest step of both builds).
TILE = 64


@pytest.fixture(scope="module", autouse=True)
def small_tile():
    """binding.TILE_SIZE at :data:`TILE` for every build of the module (a rebuild with another
    side would re-quilt the floor)."""
    from usdbtf.usd.scenes import binding

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(binding, "TILE_SIZE", TILE)
        yield


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The scene built once: (scene path, the first build's report, the scene's bytes before)."""
    return build_scene(tmp_path_factory.mktemp("meshes"), SCENE, jobs=2)


def test_every_binding_has_the_materials_density_after_build(built):
    scene, report, before = built
    assert scene.read_bytes() == before                           # the user's file is never edited
    # Before: a 16-texel swatch over the box's [0, 1] UVs is about a third of its density; the
    # plane has no UVs at all.
    stretched = {e["prim"]: e for e in binding_densities(open_stage(scene))}
    assert stretched["/World/Box"]["ratio"] == pytest.approx(0.34, abs=0.01)
    assert stretched["/World/Plane"]["ratio"] is None
    entries = binding_densities(open_stage(report["built_scene"]))
    assert sorted(e["prim"] for e in entries) == ["/World/Box", "/World/BoxCopy", "/World/Floor", "/World/Plane"]
    for e in entries:
        # 16 texels over the synthetic swatch's 5 cm: 320 texels per metre.
        assert e["material_texels_per_metre"] == pytest.approx(320.0, rel=1e-6)
        assert abs(e["ratio"] - 1) <= 0.02, e
        assert e["stretch"] < 1.1, e                                 # shapes kept, not only areas
        assert e["material"].startswith("/UsdbtfBindings/")


def test_identical_meshes_of_a_material_share_one_quilt(built):
    scene, report, _ = built
    chains = {c.material: c for c in report["bindings"]}
    assert len(report["bindings"]) == 3                            # the rotated copy shares the box's
    assert chains["/World/Looks/Pebbles"].prims == ["/World/Box", "/World/BoxCopy"]
    steps = [line.split()[1] for line in report["ran"]]
    assert sorted(steps) == sorted(["compress", "package"] * 2 + ["unwrap", "quilt", "package"] * 2
                                   + ["quilt", "package"])       # the floor's tileable quilt
    # The shared quilt is the atlas's size and the material's data (k = 4).
    stage = open_stage(report["built_scene"])
    unwrap = json.loads((chains["/World/Looks/Pebbles"].unwrap.parent / "unwrap.json").read_text())
    from usdbtf.usd.material import NS
    from pxr import UsdShade

    for prim in ("/World/Box", "/World/BoxCopy"):
        material, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(prim)).ComputeBoundMaterial()
        assert tuple(material.GetPrim().GetAttribute(NS + "resolution").Get()) == \
            (unwrap["atlas"]["width"], unwrap["atlas"]["height"])
        assert material.GetPrim().GetAttribute(NS + "basisCount").Get() == 4


def _outputs(folder) -> dict:
    """{relative path: bytes} of every build output under ``folder`` (the assets, the bound
    meshes' chains, the coverage documents, the built stage), not the build's bookkeeping."""
    roots = [folder / "build", folder / ".usdbtf-build" / "scene" / "bindings",
             folder / ".usdbtf-build" / "scene" / "materials"]
    files = [p for root in roots if root.is_dir() for p in sorted(root.rglob("*")) if p.is_file()]
    return {str(p.relative_to(folder)): p.read_bytes() for p in files + [folder / "scene.built.usda"]}


def test_one_step_at_a_time_or_two_at_once_the_same_bytes(built):
    """Issue 41: SCons runs independent material and mesh chains at once (the fixture: -j 2);
    built again from scratch in the same folder one step at a time (-j 1), every output has the
    same bytes (the same folder: the compressed metadata records its source's absolute path)."""
    import shutil

    scene, report, _ = built
    want = _outputs(scene.parent)
    for old in (scene.parent / "build", scene.parent / ".usdbtf-build"):
        shutil.rmtree(old)
    (scene.parent / "scene.built.usda").unlink()
    serial = build(scene, jobs=1)
    assert sorted(serial["ran"]) == sorted(report["ran"]) and len(report["ran"]) == 12
    got = _outputs(scene.parent)
    assert sorted(got) == sorted(want) and len(want) > 30
    assert [name for name in want if got[name] != want[name]] == []


def test_inspect_validate_flags_a_stretched_material_and_passes_the_built_scene(built, capsys):
    scene, report, _ = built
    line = bad_input(capsys, "inspect", scene, "--validate", names="[usdbtf:TexelDensity] /World/Box")
    assert "more than 2 %" in line
    out = ok(capsys, "inspect", report["built_scene"], "--validate")
    assert "0 error(s)" in out and "texels/m on the mesh" in out


def test_tile_mapping_repeats_a_tileable_quilt_at_physical_scale(built):
    """``btf:build:mapping = "tile"``: the floor keeps its topology, its st is scaled so that one
    tile of the 64-texel tileable quilt (0.2 m at 320 texels/m) spans 0.2 m of the 2 m floor."""
    from pxr import UsdGeom

    scene, report, _ = built
    stage = open_stage(report["built_scene"])
    st = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Floor")).GetPrimvar("st").Get()
    assert TILE == 64 and max(p[0] for p in st) == pytest.approx(2.0 / 0.2, rel=1e-5)
    assert len(UsdGeom.Mesh(stage.GetPrimAtPath("/World/Floor")).GetFaceVertexCountsAttr().Get()) == 1
    floor = {e["prim"]: e for e in binding_densities(stage)}["/World/Floor"]
    assert floor["ratio"] == pytest.approx(1.0, abs=1e-4)


def test_a_bad_mapping_is_an_error_naming_the_prim(built, capsys):
    scene, _, _ = built
    bad = scene.parent / "bad_mapping.usda"
    bad.write_text(SCENE.replace('btf:build:mapping = "tile"', 'btf:build:mapping = "wrap"'))
    line = bad_input(capsys, "build", bad, "--dry-run", names="/World/Floor: btf:build:mapping")
    assert "atlas, tile" in line


def test_render_draws_every_bound_mesh_with_its_own_material(built, capsys):
    """``usdbtf render`` of the built scene (three BTF materials) draws each bound mesh with its
    own: where one mesh alone covers a pixel the frame is that mesh rendered alone with its
    material, where the box stands on the plane the box hides it."""
    from dataclasses import replace

    import numpy as np

    from usdbtf.camera import parse_camera
    from usdbtf.render import RenderOptions, parse_light, render, render_scene
    from usdbtf.usd.scenes.scene import bound_btf_meshes

    scene, report, _ = built
    out = scene.parent / "built_frame.exr"
    code, _, log = run(capsys, "render", report["built_scene"], "--camera", "eye=0.3,1.2,1.2 target=0.3,0,0.1 fov=40",
                       "--light", "dir:0.3,1,0.5", "--size", "64", "48", "-o", out, "--no-png")
    assert code == 0 and "4 meshes with 3 BTF materials" in log and out.is_file(), log
    parts = {mesh.name: (cbtf, mesh) for cbtf, mesh in bound_btf_meshes(open_stage(report["built_scene"]))}
    box = parts["Box"]
    assert box[0] is parts["BoxCopy"][0] and box[0] is not parts["Plane"][0]   # one CompressedBTF per material
    # The plane (facing down) lifted above the box; seen from below, the box hides part of it.
    plane = (parts["Plane"][0], replace(parts["Plane"][1], points=parts["Plane"][1].points + [0.3, 0.3, -0.1]))
    camera, lights = parse_camera("eye=0.6,-1,0.8 target=0.6,0.15,0.1 fov=40", 64, 48), [parse_light("dir:0,-1,0.3")]
    opts = RenderOptions(shadows=False)
    both = render_scene([box, plane], camera, lights, opts).image
    alone = [render(cbtf, mesh, camera, lights, opts).image for cbtf, mesh in (box, plane)]
    on_box, on_plane = (a[..., 3] > 0 for a in alone)
    overlap = on_box & on_plane
    assert overlap.sum() > 20 and (on_plane & ~on_box).sum() > 20
    np.testing.assert_allclose(both[on_box], alone[0][on_box], atol=1e-6)          # the box in front
    np.testing.assert_allclose(both[on_plane & ~on_box], alone[1][on_plane & ~on_box], atol=1e-6)
    assert not both[~(on_box | on_plane)].any()


def _resolved_dependencies(path) -> list:
    """Every layer and asset the stage at ``path`` depends on, each resolved (an unresolved one
    is listed as unresolved by UsdUtils)."""
    from pxr import Sdf, UsdUtils

    layers, assets, unresolved = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(path)))
    assert unresolved == [], unresolved
    return [layer.realPath for layer in layers] + list(assets)


def test_the_built_stage_is_a_visible_file_beside_the_scene(built, capsys):
    """Issue 41: the stage to open is ``scene.built.usda`` beside the user's ``scene.usda`` (its
    paths relative to it, every one resolving), ``build`` prints it last, ``inspect --validate``
    on the user's file names it, and ``-o`` puts it elsewhere; an existing file is replaced only
    when it is this scene's last built stage, or with --force another usdbtf built stage."""
    from pxr import Sdf

    scene, report, _ = built
    stage_path = scene.parent / "scene.built.usda"
    assert report["built_scene"] == stage_path and stage_path.is_file()
    assert not (scene.parent / ".usdbtf-build" / "scene" / "scene.usda").exists()
    layer = Sdf.Layer.FindOrOpen(str(stage_path))
    assert list(layer.subLayerPaths) == ["scene.usda"]                # relative to the built stage
    assert dict(layer.customLayerData)["usdbtf"] == {"output": "usdbtf-built-stage", "scene": "scene.usda"}
    deps = _resolved_dependencies(stage_path)
    assert str(scene) in deps and any("/.usdbtf-build/scene/bindings/" in d for d in deps)
    assert not open_stage(stage_path).GetCompositionErrors()
    # The user's own scene: still stretched (an error), and one line names the stage to open.
    code, out, err = run(capsys, "inspect", scene, "--validate")
    assert code == 65 and "[usdbtf:TexelDensity] /World/Box" in out
    names = [line for line in out.splitlines() if "[usdbtf:BuiltStage]" in line]
    assert names == [f"  [usdbtf:BuiltStage] {scene}: superseded by the built stage {stage_path} (usdbtf build: "
                     "its bound meshes quilted at measured scale); open that one"]
    # A rebuild replaces its own stage without --force, and prints its path last.
    code, out, err = run(capsys, "build", scene)
    assert code == 0 and out.splitlines()[-1] == str(stage_path), err
    # -o elsewhere: the paths are relative to that file, and still resolve.
    other = scene.parent / "shots" / "lit.usda"
    out = ok(capsys, "build", scene, "-o", other)
    assert out.splitlines()[-1] == str(other)
    assert list(Sdf.Layer.FindOrOpen(str(other)).subLayerPaths) == ["../scene.usda"]
    assert str(scene) in _resolved_dependencies(other) and not open_stage(other).GetCompositionErrors()
    assert f"superseded by the built stage {other} " in run(capsys, "inspect", scene, "--validate")[1]
    # Not a file of ours: refused, even with --force; the old default stage, no longer this
    # build's, needs --force (and is a built stage, so --force replaces it).
    mine = scene.parent / "mine.usda"
    mine.write_text("#usda 1.0\n")
    refused(capsys, "build", scene, "-o", mine, names=f"{mine}: exists")
    refused(capsys, "build", scene, "-o", mine, "--force", names="not a usdbtf usdbtf-built-stage")
    assert mine.read_text() == "#usda 1.0\n"
    refused(capsys, "build", scene, names=f"{stage_path}: exists; pass --force")
    bad_usage(capsys, "build", scene, "-o", scene.parent / "x.txt", names="*.usda")
    refused(capsys, "build", scene, "-o", scene, names="a layer of the scene being built")
    assert ok(capsys, "build", scene, "--force").splitlines()[-1] == str(stage_path)


def test_rebuilds_only_what_a_mesh_edit_touches(built):
    """Runs last: it edits the module's scene."""
    scene, report, _ = built
    assert build(scene)["ran"] == []                              # nothing changed: nothing runs
    # Moving a mesh needs no new atlas (its extracted mesh is in its own frame).
    scene.write_text(SCENE.replace("(0.5, 0, 0)", "(0.9, 0, 0)"))
    assert build(scene)["ran"] == []
    # Editing the plane re-quilts the plane alone.
    scene.write_text(SCENE.replace("(0.3, 0, 0.2), (0, 0, 0.2)", "(0.3, 0, 0.25), (0, 0, 0.25)"))
    ran = build(scene)["ran"]
    assert ran == [f"usdbtf-step {step} /World/Looks/Moss /World/Plane" for step in ("unwrap", "quilt", "package")]
    plane = {e["prim"]: e for e in binding_densities(open_stage(report["built_scene"]))}["/World/Plane"]
    assert abs(plane["ratio"] - 1) <= 0.02
