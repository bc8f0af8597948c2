"""Small USD scenes with bound BTF build recipes, cameras and lights: what the scene-aware
build's tests and ``benchmarks/bench_scene_aware.py`` build from (issue 26).

A scene is written as text-free USD authoring (pxr), in metres, Y up: quads (two triangles,
``st`` over [0, 1], normals +Z in the quad's own frame) placed by a translate and a rotation,
each bound to a Material with a ``btf:build`` recipe; UsdGeom cameras with one transform per
frame; one DistantLight; a UsdRender.Settings resolution.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["Quad", "Shot", "write_scene"]


@dataclass
class Quad:
    """A square mesh of ``size`` metres at ``centre``, rotated by ``rotate`` (degrees about X,
    Y, Z in that order; a quad faces +Z before), bound to ``material`` (a key of the scene's
    materials).  ``visible`` False authors visibility = invisible; ``purpose`` is authored
    when not "default"."""

    name: str
    material: str
    size: float
    centre: tuple
    rotate: tuple = (0.0, 0.0, 0.0)
    visible: bool = True
    purpose: str = "default"


@dataclass
class Shot:
    """A camera: ``eyes`` and ``targets`` per frame (lists of (3,) metres, or one of each for
    every frame), vertical field of view ``fov`` degrees."""

    name: str
    eyes: list
    targets: list
    fov: float = 40.0
    frames: list = field(default_factory=list)


def write_scene(path: Path, materials: dict, quads: list, shots: list, *, light_towards=(0.3, 0.5, 1.0),
                resolution=(192, 128), frames: tuple | None = None, build_dir: str = "build",
                options: str = "--k 8 --codec png") -> Path:
    """Write the scene ``path`` (.usda).

    materials : {name: source folder} (a measured BTF or a compressed folder); each becomes
        /World/Looks/<name> with ``btf:build:source``, ``btf:build:options`` = ``options``
        and ``btf:build:asset`` = ``<build_dir>/<name>.usda`` (relative to the scene).
    quads : :class:`Quad` list; shots : :class:`Shot` list (cameras /World/<name>).
    frames : (first, last) whole frames: the stage's time range (None: no range, one frame).
    """
    from ..usdstage import usd_warnings_silenced

    # The materials reference assets a build has not written yet.
    with usd_warnings_silenced():
        return _author(Path(path), materials, quads, shots, light_towards, resolution, frames, build_dir, options)


def _author(path: Path, materials, quads, shots, light_towards, resolution, frames, build_dir, options) -> Path:
    """:func:`write_scene`'s authoring."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdRender, UsdShade, Vt

    from ..camera import Camera
    from ..usd.scenes.scene import add_camera, add_distant

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    if frames is not None:
        stage.SetStartTimeCode(frames[0])
        stage.SetEndTimeCode(frames[1])
    UsdGeom.Scope.Define(stage, "/World/Looks")
    for name, source in materials.items():
        prim = UsdShade.Material.Define(stage, f"/World/Looks/{name}").GetPrim()
        asset = f"./{build_dir}/{name}.usda"
        prim.GetReferences().AddReference(asset, Sdf.Path(f"/{name}/mtl/BtfMaterial"))
        rel = os.path.relpath(source, path.parent)
        prim.CreateAttribute("btf:build:source", Sdf.ValueTypeNames.Asset, custom=False,
                             variability=Sdf.VariabilityUniform).Set(Sdf.AssetPath(f"./{rel}"))
        prim.CreateAttribute("btf:build:options", Sdf.ValueTypeNames.String, custom=False,
                             variability=Sdf.VariabilityUniform).Set(options)
        prim.CreateAttribute("btf:build:asset", Sdf.ValueTypeNames.Asset, custom=False,
                             variability=Sdf.VariabilityUniform).Set(Sdf.AssetPath(asset))
    for q in quads:
        mesh = UsdGeom.Mesh.Define(stage, f"/World/{q.name}")
        h = q.size / 2
        mesh.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(-h, -h, 0), Gf.Vec3f(h, -h, 0), Gf.Vec3f(h, h, 0),
                                             Gf.Vec3f(-h, h, 0)]))
        mesh.CreateFaceVertexCountsAttr([4])
        mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        mesh.CreateNormalsAttr(Vt.Vec3fArray([Gf.Vec3f(0, 0, 1)] * 4))
        mesh.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
        mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        st = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                    UsdGeom.Tokens.vertex)
        st.Set(Vt.Vec2fArray([Gf.Vec2f(0, 0), Gf.Vec2f(1, 0), Gf.Vec2f(1, 1), Gf.Vec2f(0, 1)]))
        mesh.AddTranslateOp().Set(Gf.Vec3d(*map(float, q.centre)))
        mesh.AddRotateXYZOp().Set(Gf.Vec3f(*map(float, q.rotate)))
        if not q.visible:
            mesh.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
        if q.purpose != "default":
            mesh.CreatePurposeAttr(q.purpose)
        UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(
            UsdShade.Material(stage.GetPrimAtPath(f"/World/Looks/{q.material}")))
    width, height = resolution
    for shot in shots:
        times = shot.frames or ([None] if frames is None else list(range(frames[0], frames[1] + 1)))
        eyes = shot.eyes if len(shot.eyes) == len(times) else [shot.eyes[0]] * len(times)
        targets = shot.targets if len(shot.targets) == len(times) else [shot.targets[0]] * len(times)
        add_camera(stage, f"/World/{shot.name}",
                   {t: Camera(np.asarray(e, float), np.asarray(g, float), np.array([0.0, 1.0, 0.0]), shot.fov, width,
                              height) for t, e, g in zip(times, eyes, targets)}, clipping=(0.01, 100.0))
    add_distant(stage, "/World/Sun", np.asarray(light_towards, float) / np.linalg.norm(light_towards))
    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.CreateResolutionAttr(Gf.Vec2i(int(width), int(height)))
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    stage.GetRootLayer().Save()
    return path
