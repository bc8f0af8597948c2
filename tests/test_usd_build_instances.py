"""``usdbtf build`` on instanced meshes (issue 31): the meshes of instanceable prims and a
PointInstancer's prototype are unwrapped, quilted and packaged once per (material, prototype),
and the built scene gives every instance the material at its measured scale while the
instances keep sharing one prototype (real USD stages, real build)."""
from __future__ import annotations

import pytest

import usdbtf  # noqa: F401
from scene_build_data import build_scene, open_stage
from usdbtf.usd.scenes.binding import BINDINGS_SCOPE, INSTANCE_CLASS
from usdbtf.usd.density import binding_densities

# A 0.1 x 0.05 x 0.075 m box without texture coordinates (six quads).
BOX = '''
        int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]
        int[] faceVertexIndices = [0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3]
        point3f[] points = [(0, 0, 0), (0, 0, 0.075), (0, 0.05, 0), (0, 0.05, 0.075), (0.1, 0, 0),
                            (0.1, 0, 0.075), (0.1, 0.05, 0), (0.1, 0.05, 0.075)]'''


def _material(name: str) -> str:
    stem = name.lower()
    return f'''
        def Material "{name}" (
            prepend apiSchemas = ["BtfMaterialAPI"]
            prepend references = @./build/{stem}.usda@</{stem}/mtl/BtfMaterial>
        )
        {{
            uniform asset btf:build:source = @./captures/{stem}@
            uniform string btf:build:options = "--k 4 --codec png"
            uniform asset btf:build:asset = @./build/{stem}.usda@
        }}'''


def _instance(name: str, xform: str) -> str:
    return f'''
    def Xform "{name}" (
        instanceable = true
        prepend apiSchemas = ["MaterialBindingAPI"]
        prepend references = </RockPrototype>
    )
    {{
        rel material:binding = </World/Looks/Pebbles>{xform}
    }}'''


SCENE = '''#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
)

def Xform "World"
{''' + _instance("RockA", '''
        double3 xformOp:translate = (0.5, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]''') + _instance("RockB", '''
        double3 xformOp:translate = (-0.5, 0, 0)
        float xformOp:rotateY = 90
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateY"]''') + '''
    def PointInstancer "Scatter"
    {
        rel prototypes = [</World/Scatter/Prototypes/Pebble>]
        int[] protoIndices = [0, 0, 0]
        point3f[] positions = [(0, 0, 1), (0.3, 0, 1), (0.6, 0, 1)]
        def Scope "Prototypes"
        {
            def Mesh "Pebble" (prepend apiSchemas = ["MaterialBindingAPI"])
            {''' + BOX + '''
                rel material:binding = </World/Looks/Moss>
            }
        }
    }
    def Scope "Looks"
    {''' + _material("Pebbles") + _material("Moss") + '''
    }
}

class "RockPrototype"
{
    def Mesh "Rock"
    {''' + BOX + '''
    }
}
'''

ROCKS = ["/World/RockA/Rock", "/World/RockB/Rock"]
PEBBLE = "/World/Scatter/Prototypes/Pebble"


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """The scene built once: (scene path, the first build's report, the scene's bytes before)."""
    return build_scene(tmp_path_factory.mktemp("instances"), SCENE)


def test_instances_of_one_prototype_are_quilted_once(built):
    scene, report, before = built
    chains = {c.material: c for c in report["bindings"]}
    assert sorted(chains) == ["/World/Looks/Moss", "/World/Looks/Pebbles"]
    assert chains["/World/Looks/Pebbles"].prims == ROCKS            # two instances, one chain
    assert chains["/World/Looks/Moss"].prims == [PEBBLE]            # three points, one prototype
    assert sum(step.startswith("usdbtf-step quilt") for step in report["ran"]) == 2
    assert scene.read_bytes() == before                             # the user's file is not edited


def test_built_instances_share_a_prototype_and_have_the_materials_density(built):
    from pxr import UsdGeom, UsdShade

    scene, report, _ = built
    user = {e["prim"]: e for e in binding_densities(open_stage(scene))}
    assert sorted(user) == sorted(ROCKS + [PEBBLE])                  # instance proxies are measured
    assert all(e["ratio"] is None for e in user.values())           # no UVs in the user's scene
    stage = open_stage(report["built_scene"])
    a, b = stage.GetPrimAtPath("/World/RockA"), stage.GetPrimAtPath("/World/RockB")
    assert a.IsInstance() and b.IsInstance() and a.GetPrototype() == b.GetPrototype()
    assert [str(p) for p in a.GetInherits().GetAllDirectInherits()][0].startswith("/" + INSTANCE_CLASS)
    for path in ROCKS + [PEBBLE]:
        prim = stage.GetPrimAtPath(path)
        assert prim.IsInstanceProxy() == (path in ROCKS)
        material, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
        assert str(material.GetPath()).startswith(BINDINGS_SCOPE + "/"), path
        st = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
        assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying and len(st.ComputeFlattened()) == 36
    built_density = {e["prim"]: e for e in binding_densities(stage)}
    assert sorted(built_density) == sorted(ROCKS + [PEBBLE])
    for e in built_density.values():
        assert e["ratio"] == pytest.approx(1.0, abs=0.02), e
        assert e["stretch"] < 1.1, e
