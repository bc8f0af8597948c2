#!/usr/bin/env python
"""A scene's meshes at their material's measured scale (issue 31): ``usdbtf build`` on a scene of
three meshes (sphere r = 0.3 m, cylinder, box) with their own UVs on the [0, 1] square, as a user
brings them, bound to three synthetic materials (plus a camera and a light: the picture in docs/scenes-and-build.md,
``benchmarks/scene_build_picture.py``, renders this scene).

Measures, in one run:

density      per binding, the texel density on the mesh in the built scene against the
             material's (``usd.density.binding_densities``), and the same on the user's scene
             (the baseline: what binding the swatch directly gives), and the stretch of each built atlas
             (:func:`usdbtf.mesh.uv_stretch`, 1 = square texels) with the unwrap's method (the
             mesh's own UVs kept, or xatlas charts where keep-uvs refuses them).
seams        per binding, the mean squared difference (over every (view, light) image) across
             quilting seams inside charts and across chart boundaries on the surface, each
             against the material's natural neighbour difference (the same metric over the
             sample's own neighbours); see :func:`seams`.
rebuilds     wall time of the first build, of a second build with nothing changed, of one after
             the camera moved 1 cm (no material needs more), and of a build after one mesh
             (the cylinder) is edited, with the steps each ran.

Usage (repository root)::

    .venv/bin/python benchmarks/bench_scene_build.py              # 16-texel tiny materials, ~1 min

Writes benchmarks/out/scene_build_<timestamp>.json and prints a markdown block for RESULTS.md.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "pipeline"))
import usdbtf  # noqa: E402,F401  (pins the numeric platform before numpy's BLAS loads)
from common import OUT, format_machine, machine_info, timestamp, write_json  # noqa: E402

MATERIALS = (("Pebbles", "pebbles"), ("Moss", "fuzzy_moss"), ("Fabric", "ridged_fabric"))


def _meshes():
    """{name: (trimesh mesh, where it stands)}: side by side on the floor (y = 0)."""
    import trimesh

    return {"Sphere": (trimesh.creation.icosphere(subdivisions=3, radius=0.3), (-0.4, 0.3, 0.0)),
            "Cylinder": (trimesh.creation.cylinder(radius=0.1, height=0.3, sections=24), (0.12, 0.1, 0.05)),
            "Box": (trimesh.creation.box(extents=(0.2, 0.1, 0.15)), (0.45, 0.05, 0.1))}


#: The scene's camera (/World/Cam) and its one distant light (/World/Sun, irradiance 1.5: usdbtf.photometry).
CAMERA = "eye=-0.05,0.6,1.3 target=-0.05,0.15,0.05 fov=40"
SUN = (0.4, 1.0, 0.6)


def _user_uvs(points: np.ndarray, faces: np.ndarray):
    """The mesh as a user would bring it: unwrapped once into the [0, 1] square (usdbtf unwrap at
    640 texels/m, the suggestion in docs/scenes-and-build.md), st per face corner.  Returns (points, faces, st (F, 3, 2))."""
    from usdbtf.mesh import Mesh
    from usdbtf.unwrap import UnwrapOptions, unwrap

    unwrapped = unwrap(Mesh(points, faces), UnwrapOptions(texels_per_metre=640.0)).mesh
    return unwrapped.points, unwrapped.triangles, unwrapped.uv


def write_scene(root: Path, size: int, width: int = 480, height: int = 270) -> Path:
    """The scene: three meshes with their own [0, 1] UVs, each bound to one material with a build
    recipe, a camera (/World/Cam, ``width`` x ``height`` aspect) and a distant light."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    from usdbtf.camera import parse_camera
    from usdbtf.cli import main
    from usdbtf.usd.scenes.scene import add_camera, add_distant

    stage = Usd.Stage.CreateNew(str(root / "scene.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    add_camera(stage, "/World/Cam", {None: parse_camera(CAMERA, width, height)})
    add_distant(stage, "/World/Sun", SUN, 1.5)
    for (name, preset), (mesh_name, (mesh, where)) in zip(MATERIALS, _meshes().items()):
        assert main(["synth", preset, "-o", str(root / "captures" / name), "--sampling", "tiny", "--size",
                     str(size), "-q"]) == 0
        material = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
        prim = material.GetPrim()
        prim.AddAppliedSchema("BtfMaterialAPI")
        prim.GetReferences().AddReference(f"./build/{name}.usda", Sdf.Path(f"/{name}/mtl/BtfMaterial"))
        prim.CreateAttribute("btf:build:source", Sdf.ValueTypeNames.Asset).Set(f"./captures/{name}")
        prim.CreateAttribute("btf:build:options", Sdf.ValueTypeNames.String).Set("--k 6 --codec png")
        prim.CreateAttribute("btf:build:asset", Sdf.ValueTypeNames.Asset).Set(f"./build/{name}.usda")
        points, faces, st = _user_uvs(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64))
        geom = UsdGeom.Mesh.Define(stage, f"/World/{mesh_name}")
        geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(points, np.float32)))
        geom.CreateFaceVertexCountsAttr([3] * len(faces))
        geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(faces.ravel(), np.int32)))
        geom.CreateSubdivisionSchemeAttr("none")
        UsdGeom.PrimvarsAPI(geom).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                UsdGeom.Tokens.faceVarying).Set(
            Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(st.reshape(-1, 2), np.float32)))
        geom.AddTranslateOp().Set(Gf.Vec3d(*where))
        UsdShade.MaterialBindingAPI.Apply(geom.GetPrim()).Bind(material)
    stage.Save()
    return root / "scene.usda"


def seams(chain, compressed: Path) -> dict:
    """Seam errors of a chain's quilt against the material's natural neighbour difference, all
    from image features (squared differences summed exactly over every (view, light) image in the
    working space, :mod:`usdbtf.quilt.features`):

    in charts   output neighbours of one chart whose source texels are not neighbours (the
                quilting seams, :func:`usdbtf.quilt.seams.seam_error_all_samples`);
    boundary    across chart boundaries on the surface: along every mesh edge whose two
                triangles lie in different charts, points one texel apart looked up in both
                charts' UV space (:func:`usdbtf.quilt.atlas.chart_border_error`);
    natural     the sample's own horizontal and vertical neighbours."""
    from usdbtf.compress import read_compressed
    from usdbtf.mesh import weld
    from usdbtf.quilt.atlas import chart_border_error, face_neighbours
    from usdbtf.quilt.features import image_features
    from usdbtf.quilt.folder import read_position_map
    from usdbtf.quilt.seams import natural_neighbour_error, seam_error_all_samples
    from usdbtf.unwrap import read_unwrap

    cbtf = read_compressed(compressed)
    features, S, ws = image_features(cbtf), cbtf.n_samples, cbtf.width
    x, y = read_position_map(chain.quilt)
    positions = (y * ws + x).astype(np.int32)
    unwrapped = read_unwrap(chain.unwrap)
    layer = unwrapped.mesh
    in_charts = seam_error_all_samples(positions, features, ws, S, labels=unwrapped.chart_map)
    neighbours = face_neighbours(weld(layer.points)[layer.triangles])
    boundary = chart_border_error(positions, layer, neighbours, features, ws, S)
    natural = natural_neighbour_error(features, ws, cbtf.height, S)
    return {"charts": int(unwrapped.atlas.charts), "method": unwrapped.atlas.method, "in_charts": in_charts,
            "boundary": boundary, "natural_neighbour": natural, "in_charts_ratio": in_charts / natural,
            "boundary_ratio": boundary / natural}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=16, help="synthetic sample side in texels (default 16)")
    args = p.parse_args()
    from pxr import Gf, Usd, UsdGeom

    from usdbtf.usd.scenes.build import build
    from usdbtf.usd.density import binding_densities

    from usdbtf.usdstage import usd_warnings_silenced

    with tempfile.TemporaryDirectory(prefix="bench_scene_build_") as tmp:
        with usd_warnings_silenced():           # the materials' assets do not exist before the build
            scene = write_scene(Path(tmp), args.size)
        runs = {}
        for name in ("first", "nothing changed", "camera moved", "cylinder edited"):
            if name == "camera moved":         # 1 cm sideways: no material needs more than it has
                stage = Usd.Stage.Open(str(scene))
                op = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Cam")).GetOrderedXformOps()[0]
                matrix = Gf.Matrix4d(op.Get())
                op.Set(matrix.SetTranslateOnly(matrix.ExtractTranslation() + Gf.Vec3d(0.01, 0.0, 0.0)))
                stage.Save()
            if name == "cylinder edited":
                stage = Usd.Stage.Open(str(scene))
                points = UsdGeom.Mesh.Get(stage, "/World/Cylinder").GetPointsAttr()
                points.Set([(px * 1.1, py, pz) for px, py, pz in points.Get()])
                stage.Save()
            t = time.perf_counter()
            report = build(scene)
            runs[name] = {"wall_s": time.perf_counter() - t, "ran": report["ran"]}
        before = binding_densities(Usd.Stage.Open(str(scene)))
        after = binding_densities(Usd.Stage.Open(str(report["built_scene"])))
        compressed = {r.material: r.compressed for r in report["recipes"]}
        seam = {c.prims[0]: seams(c, compressed[c.material]) for c in report["bindings"]}
    machine = machine_info()
    doc = {"machine": machine, "size": args.size, "runs": runs, "density_user_scene": before,
           "density_built_scene": after, "seams": seam}
    path = write_json(OUT / f"scene_build_{timestamp()}.json", doc)
    print(format_machine(machine))
    print(f"\ninputs: synth pebbles / fuzzy_moss / ridged_fabric, sampling tiny, {args.size}^2, k 6; sphere r 0.3 m "
          "(icosphere 3), cylinder r 0.1 h 0.3, box 0.2 x 0.1 x 0.15 m, each with its own UVs on [0, 1] (usdbtf "
          "unwrap at 640 texels/m)\n")
    print("| binding | user scene texels/m | built scene texels/m | material texels/m | built / material | "
          "stretch | charts (atlas) | natural neighbour | seams in charts / natural | chart boundaries / natural |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    user = {e["prim"]: e for e in before}
    for e in after:
        u, s = user[e["prim"]]["mesh_texels_per_metre"], seam[e["prim"]]
        print(f"| {e['prim']} | {'no UVs' if u is None else f'{u:.1f}'} | {e['mesh_texels_per_metre']:.2f} | "
              f"{e['material_texels_per_metre']:.2f} | {e['ratio']:.4f} | {e['stretch']:.3f} | "
              f"{s['charts']} ({s['method']}) | {s['natural_neighbour']:.5g} | {s['in_charts_ratio']:.2f} | "
              f"{s['boundary_ratio']:.2f} |")
    print("\n| build | wall s | steps run |\n|---|---|---|")
    for name, r in runs.items():
        print(f"| {name} | {r['wall_s']:.1f} | {len(r['ran'])}: {', '.join(x.split(' ', 1)[1] for x in r['ran'])} |")
    print(f"\n{path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
