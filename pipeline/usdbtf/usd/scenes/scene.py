"""A USD stage's camera and lights as the CPU renderer's, and the other way round.

So the CPU reference (``usdbtf render SCENE.usda --camera PRIM``) and Storm
(``usdbtf preview --renderer storm``, :mod:`usdbtf.usd.preview.hydra`) render the same stage.  The
light convention is the one Storm applies (measured in Storm 25.02 and 25.08 on a
Lambertian ``UsdPreviewSurface`` and on the BTF shader, ``tests/test_storm.py``), expressed
as the CPU renderer's irradiance (:mod:`usdbtf.render.scene`; what a BTF returns under it is
:mod:`usdbtf.photometry`'s ``value x E / (pi W)``):

============== ===================================================================== ========
UsdLux         Storm's simple lighting                                               CPU light
============== ===================================================================== ========
DistantLight   radiance over its disc: irradiance = intensity x 2 pi (1 - cos(angle/2)) directional
SphereLight    a point light at its centre: intensity x pi r^2 / d^2                  point
DiskLight      a point light at its centre: intensity x pi r^2 / d^2                  point
RectLight      a point light at its centre: intensity x width x height / d^2          point
DomeLight      indirect: the BTF measures directional light only, so it adds nothing  (none)
============== ===================================================================== ========

Each is also multiplied by ``2^exposure`` and the mean of its colour (the CPU renderer's
lights are white).  A DistantLight of intensity 1 therefore has irradiance 1 / 14880 at the
default 0.53 degree angle, 1 / 46747 of the capture light (pi W, W = 1): black, not ignored
(the schema's default intensity, 50000, is irradiance 3.4).  Lengths are scaled to metres by
the stage's metersPerUnit.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from ...camera import Camera
from ...errors import BTFError
from ...render.scene import Light

log = logging.getLogger(__name__)

__all__ = ["read_scene", "bound_btf_meshes", "btf_mesh_prims", "write_scene", "scene_camera", "camera_prim", "camera_prims", "scene_lights",
           "scene_light_prims", "render_resolution",
           "frame_times", "add_camera", "new_scene", "add_distant", "orient_towards", "distant_intensity", "POINT_RADIUS_M",
           "DISTANT_ANGLE"]

#: Radius (metres) of the SphereLight that stands for a CPU point light in a written stage.
POINT_RADIUS_M = 1e-3
#: UsdLux.DistantLight's default angular diameter (degrees).
DISTANT_ANGLE = 0.53


def _solid_angle(angle_deg: float) -> float:
    return 2.0 * math.pi * (1.0 - math.cos(math.radians(angle_deg) / 2.0))


def distant_intensity(angle_deg: float = DISTANT_ANGLE) -> float:
    """The ``inputs:intensity`` of a UsdLux.DistantLight of angular diameter ``angle_deg`` whose
    irradiance is 1: 1 / (2 pi (1 - cos(angle / 2))), 14880 at 0.53 deg (the capture light,
    irradiance pi W, is pi W times that: :mod:`usdbtf.photometry`)."""
    return 1.0 / _solid_angle(angle_deg)


def new_scene(asset: Path, out: Path, lod: str | None = None):
    """A new stage at ``out`` (Y up, metres) whose default prim /World references ``asset``
    (relative path) at /World/Asset with its ``lod`` selection.  Returns (stage, that prim)."""
    import os

    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(out))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    ref = stage.DefinePrim("/World/Asset")
    ref.GetReferences().AddReference(os.path.relpath(asset, out.parent))
    if lod:
        ref.GetVariantSets().GetVariantSet("lod").SetVariantSelection(lod)
    return stage, ref


def orient_towards(xformable, towards) -> None:
    """Rotate ``xformable``'s +Z onto ``towards`` (a distant or rect light shines along -Z)."""
    from pxr import Gf

    xformable.AddOrientOp().Set(Gf.Quatf(Gf.Rotation(Gf.Vec3d(0, 0, 1), Gf.Vec3d(*map(float, towards))).GetQuat()))


def add_distant(stage, path: str, towards, irradiance: float = 1.0):
    """A DistantLight at ``path`` shining from ``towards`` with ``irradiance`` (E of
    :mod:`usdbtf.photometry`; pi W is the capture light)."""
    from pxr import UsdLux

    light = UsdLux.DistantLight.Define(stage, path)
    light.CreateAngleAttr(DISTANT_ANGLE)
    light.CreateIntensityAttr(irradiance * distant_intensity(DISTANT_ANGLE))
    orient_towards(light, towards)
    return light


def _scale(prim, code) -> float:
    """2^exposure times the mean colour of a UsdLux light at time ``code``."""
    from pxr import UsdLux

    api = UsdLux.LightAPI(prim)
    intensity = float(api.GetIntensityAttr().Get(code) or 0.0)
    exposure = float(api.GetExposureAttr().Get(code) or 0.0)
    colour = api.GetColorAttr().Get(code)
    mean = float(np.mean(colour)) if colour is not None else 1.0
    return intensity * 2.0 ** exposure * mean


def scene_camera(prim, width: int, meters: float, time=None) -> Camera:
    """The UsdGeom.Camera ``prim`` at ``time`` (default: the default time) as a :class:`Camera`
    (metres, ``width`` pixels wide, the height from its apertures)."""
    from pxr import Gf, Usd, UsdGeom

    cam = UsdGeom.Camera(prim).GetCamera(Usd.TimeCode.Default() if time is None else Usd.TimeCode(time))
    if cam.projection != Gf.Camera.Perspective:
        raise BTFError(f"{prim.GetPath()}: the CPU renderer takes perspective cameras only")
    m = cam.transform
    eye = np.array(m.Transform(Gf.Vec3d(0, 0, 0))) * meters
    forward = np.array(m.TransformDir(Gf.Vec3d(0, 0, -1)))
    up = np.array(m.TransformDir(Gf.Vec3d(0, 1, 0)))
    height = max(1, int(round(width * cam.verticalAperture / cam.horizontalAperture)))
    fov = float(cam.GetFieldOfView(Gf.Camera.FOVVertical))
    return Camera(eye, eye + forward / max(np.linalg.norm(forward), 1e-30), up, fov, width, height)


def read_scene(path, camera_path: str, width: int, time=None) -> tuple[Camera, list[Light]]:
    """(camera, lights) of the stage at ``path`` at ``time`` (default: the default time): the
    UsdGeom.Camera ``camera_path`` (its frame ``width`` pixels wide, the height from its
    apertures, as usdrecord frames it) and its UsdLux lights in the CPU renderer's units
    (module docstring; possibly none)."""
    from pxr import UsdGeom

    from ...usdstage import open_usd

    stage = open_usd(path)
    meters = float(UsdGeom.GetStageMetersPerUnit(stage))
    prim = camera_prim(stage, camera_path, path)
    return scene_camera(prim, width, meters, time), scene_lights(stage, time, path)


def camera_prim(stage, camera_path: str, where):
    """The UsdGeom.Camera prim at ``camera_path``; BTFError naming ``where`` when there is none."""
    from pxr import Usd, UsdGeom

    prim = stage.GetPrimAtPath(camera_path) if camera_path.startswith("/") else Usd.Prim()
    if not prim or not prim.IsA(UsdGeom.Camera):
        raise BTFError(f"{where}: no UsdGeom.Camera at {camera_path}")
    return prim


def camera_prims(stage) -> list:
    """Every UsdGeom.Camera prim of the composed ``stage`` (default predicate, traversal order):
    the cameras a scene plan (:mod:`usdbtf.usd.scenes.plan`) and the coverage check
    (:mod:`usdbtf.usd.scenes.reach`) look through."""
    from pxr import UsdGeom

    return [prim for prim in stage.Traverse() if prim.IsA(UsdGeom.Camera)]


def frame_times(stage) -> list[float]:
    """Every whole frame of the stage, startTimeCode..endTimeCode (the default time alone,
    as None, when the stage has no time range)."""
    if not stage.HasAuthoredTimeCodeRange():
        return [None]
    start, end = float(stage.GetStartTimeCode()), float(stage.GetEndTimeCode())
    return [float(t) for t in np.arange(math.ceil(start), math.floor(end) + 1)] or [start]


def render_resolution(stage) -> tuple[int, int] | None:
    """(width, height) of the stage's UsdRender.Settings (the one the stage metadata names,
    else the first one found); None without one."""
    from pxr import UsdRender

    settings = UsdRender.Settings.GetStageRenderSettings(stage)
    if not settings:
        found = [p for p in stage.Traverse() if p.IsA(UsdRender.Settings)]
        settings = UsdRender.Settings(found[0]) if found else None
    if not settings:
        return None
    res = settings.GetResolutionAttr().Get()
    return (int(res[0]), int(res[1])) if res is not None and min(res) > 0 else None


def scene_lights(stage, time=None, where="") -> list[Light]:
    """The stage's UsdLux lights at ``time`` in the CPU renderer's units (module docstring)."""
    return [light for _, light in scene_light_prims(stage, time, where)]


def scene_light_prims(stage, time=None, where="") -> list[tuple[str, Light]]:
    """[(light prim path, :class:`Light`)] of :func:`scene_lights`: what a report that names
    the lights reads (``inspect --validate``'s coverage check)."""
    from pxr import Gf, Usd, UsdGeom, UsdLux

    meters = float(UsdGeom.GetStageMetersPerUnit(stage))
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    cache = UsdGeom.XformCache(code)
    lights = []
    for light in stage.Traverse():
        if not light.HasAPI(UsdLux.LightAPI):
            continue
        m = cache.GetLocalToWorldTransform(light)
        centre = np.array(m.Transform(Gf.Vec3d(0, 0, 0))) * meters
        lengths = [np.linalg.norm(m.TransformDir(Gf.Vec3d(*axis))) * meters for axis in np.eye(3)]
        scale = _scale(light, code)
        if light.IsA(UsdLux.DistantLight):
            towards = np.array(m.TransformDir(Gf.Vec3d(0, 0, 1)))
            angle = float(UsdLux.DistantLight(light).GetAngleAttr().Get(code))
            made = Light("directional", towards / np.linalg.norm(towards), scale * _solid_angle(angle))
        elif light.IsA(UsdLux.SphereLight) or light.IsA(UsdLux.DiskLight):
            schema = UsdLux.SphereLight(light) if light.IsA(UsdLux.SphereLight) else UsdLux.DiskLight(light)
            r = float(schema.GetRadiusAttr().Get(code)) * max(lengths)
            made = Light("point", centre, scale * math.pi * r * r)
        elif light.IsA(UsdLux.RectLight):
            rect = UsdLux.RectLight(light)
            area = float(rect.GetWidthAttr().Get(code)) * lengths[0] * float(rect.GetHeightAttr().Get(code)) * lengths[1]
            made = Light("point", centre, scale * area)
        else:
            log.debug(f"{where}: {light.GetPath()} ({light.GetTypeName()}) adds nothing: a BTF measures "
                      "directional light only")
            continue
        lights.append((str(light.GetPath()), made))
    return lights


def add_camera(stage, path: str, cameras: dict, clipping=(1e-3, 1e4)):
    """A UsdGeom.Camera at ``path`` (metres) framing as each :class:`Camera` of ``cameras``
    {time code (None: the default time): Camera} does: its transform, and its apertures for
    the vertical field of view and the width / height of the first one (focal length 50)."""
    from pxr import Gf, Usd, UsdGeom

    cam = UsdGeom.Camera.Define(stage, path)
    first = next(iter(cameras.values()))
    focal = 50.0
    vertical = 2.0 * focal * math.tan(math.radians(first.fov) / 2.0)
    cam.CreateFocalLengthAttr(focal)
    cam.CreateVerticalApertureAttr(vertical)
    cam.CreateHorizontalApertureAttr(vertical * first.width / first.height)
    cam.CreateClippingRangeAttr(Gf.Vec2f(*map(float, clipping)))
    op = cam.AddTransformOp()
    for time, camera in cameras.items():
        right, up, forward = camera.basis()
        rows = [[*right, 0.0], [*up, 0.0], [*(-forward), 0.0], [*camera.eye, 1.0]]
        op.Set(Gf.Matrix4d(rows), Usd.TimeCode.Default() if time is None else Usd.TimeCode(time))
    return cam


def btf_mesh_prims(stage, *, time=None, rendered_only: bool = True, unbound: str = "skip", where: str = "",
                   warned: set | None = None) -> list[tuple]:
    """[(Mesh prim, BTF material path)]: the one walk over a stage's meshes and the BTF material
    each is drawn with (``render ASSET`` through :func:`bound_btf_meshes`, ``render --camera``
    through :func:`usdbtf.usd.scenes.shots.scene_shots`), in traversal order, instance proxies included.

    A mesh's material is the one bound to it (all purposes: all, full, preview; a BtfMaterialAPI
    one first).  A mesh bound to another material (or to one whose asset a scene-shaped build left
    out, so it composes no BTF) is skipped with a warning (once per material: ``warned`` holds
    those already named, shared across frames).

    time : the time code of the visibility test (None: the default time).
    rendered_only : keep only what a final render shows at ``time`` (purpose default or render,
        not invisible); False keeps every Mesh prim (``render ASSET``, as it always drew).
    unbound : what a mesh bound to nothing takes: "skip" (nothing: it is not drawn), or "only"
        (the stage's only BTF material, as ``usdbtf preview`` writes a mesh beside an asset; with
        several, BTFError naming the prim).
    where : the stage's name in messages (default: its root layer).
    """
    from pxr import Usd, UsdGeom, UsdShade

    from ..density import mesh_prims
    from ..material import btf_materials
    from ..plugin import API_SCHEMA

    if unbound not in ("skip", "only"):
        raise ValueError(f"unbound must be 'skip' or 'only', got {unbound!r}")
    where = where or stage.GetRootLayer().identifier
    warned = set() if warned is None else warned
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    only = btf_materials(stage) if unbound == "only" else []
    out = []
    for prim in mesh_prims(stage):
        if rendered_only:
            img = UsdGeom.Imageable(prim)
            if img.ComputePurpose() not in (UsdGeom.Tokens.default_, UsdGeom.Tokens.render):
                continue
            if img.ComputeVisibility(code) == UsdGeom.Tokens.invisible:
                continue
        api = UsdShade.MaterialBindingAPI(prim)
        material = other = None
        for purpose in (UsdShade.Tokens.allPurpose, UsdShade.Tokens.full, UsdShade.Tokens.preview):
            bound, _ = api.ComputeBoundMaterial(purpose)
            if bound and bound.GetPrim().HasAPI(API_SCHEMA):
                material = str(bound.GetPath())
                break
            other = other or (str(bound.GetPath()) if bound else None)
        if material is None and other is not None:
            if other not in warned:
                log.warning(f"{where}: {prim.GetPath()} is bound to {other}, which is not a BTF material (here): "
                            "not rendered")
            warned.add(other)
            continue
        if material is None:
            if unbound == "skip":
                continue
            if len(only) != 1:
                raise BTFError(f"{where}: {prim.GetPath()} has no material bound (and the stage has {len(only)} "
                               "BTF materials, so none stands in)")
            material = str(only[0].GetPath())
        out.append((prim, material))
    return out


def bound_btf_meshes(stage, *, k: int | None = None, lazy: bool = False) -> list[tuple]:
    """[(CompressedBTF, Mesh)] for every Mesh prim of ``stage`` bound to a BTF material
    (:func:`btf_mesh_prims`, every purpose and visibility), each mesh in world space (metres):
    what ``usdbtf render ASSET`` draws (:func:`usdbtf.render.render_scene`).  Meshes of one
    material share one CompressedBTF (``lazy``: its coefficients read when asked for,
    :func:`usdbtf.usd.material.read_btf`)."""
    from ...mesh import load_prim
    from ..material import read_btf

    materials, parts = {}, []
    # Every Mesh prim, as render ASSET always drew (render --camera keeps what a final render shows).
    for prim, material in btf_mesh_prims(stage, rendered_only=False):
        if material not in materials:
            materials[material] = read_btf(stage.GetPrimAtPath(material), k=k, lazy=lazy)
        parts.append((materials[material], load_prim(prim)))
    return parts


def write_scene(asset: Path, out: Path, camera: Camera, lights: list[Light], *, lod: str | None = None) -> str:
    """Write ``out`` (.usda): ``asset`` referenced (its ``lod`` selection), ``camera`` as a
    UsdGeom.Camera and ``lights`` as UsdLux lights of the same irradiance (directional: a
    DistantLight; point: a SphereLight of radius :data:`POINT_RADIUS_M`), metres.  Returns the
    camera's prim path."""
    from pxr import Gf, UsdLux

    stage, _ = new_scene(asset, out, lod)
    add_camera(stage, "/World/Camera", {None: camera})
    for i, light in enumerate(lights):
        if light.kind == "directional":
            add_distant(stage, f"/World/Light{i}", light.vector, light.intensity)
        else:
            lux = UsdLux.SphereLight.Define(stage, f"/World/Light{i}")
            lux.CreateRadiusAttr(POINT_RADIUS_M)
            lux.CreateIntensityAttr(light.intensity / (math.pi * POINT_RADIUS_M ** 2))
            lux.AddTranslateOp().Set(Gf.Vec3d(*(float(x) for x in light.vector)))
    stage.GetRootLayer().customLayerData = {"usdbtf": {"output": "scene"}}
    stage.Save()
    return "/World/Camera"
