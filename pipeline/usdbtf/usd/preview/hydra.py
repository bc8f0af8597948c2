"""Real Hydra Storm frames of a stage, from an isolated USD build with imaging.

usd-core (what usdbtf runs on) has no Hydra.  The USD inside PyPI's ``bpy`` wheels does
(bpy 4.5.15: USD 25.02; bpy 5.0.1: USD 25.08); ``scripts/bootstrap.sh`` installs each into
its own virtual environment, ``.venv-storm-<blender version>`` at the top of the project,
away from usd-core's ``pxr``.  :func:`render_frames` runs ``usdbtf/gpu/storm_frame.py`` with
that environment's Python in a subprocess whose environment is only ``PATH`` plus what
``usdbtf env`` prints (:func:`usdbtf.usd.plugin.apply_environment`), exactly what a studio's
launcher gives usdview, and returns the frames and what Storm said on stderr.
:func:`shader_problems` picks out the lines that mean the preview is broken: a shader that
does not compile, a node Sdr does not know.

:func:`swatch_scene` writes the stage the accuracy check renders: the asset referenced, an
orthographic camera looking down the swatch's normal (one pixel per texel) and one
``UsdLux.DistantLight`` from a given direction, by default of irradiance ``pi * W`` -- the
capture light, which reproduces the measured values (:mod:`usdbtf.photometry`,
:func:`usdbtf.usd.scenes.scene.distant_intensity`).
"""
from __future__ import annotations

import math
import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import BTFError
from ...lifetime import dying_with_parent
from ...plugin_folder import plugin_dir

__all__ = ["STORM_ENVIRONMENTS", "StormFrames", "storm_pythons", "storm_environment", "render_frames",
           "shader_problems", "swatch_scene", "LIGHT_KINDS"]

#: USD version -> (the bpy wheel that carries it, its virtual environment under the project root).
STORM_ENVIRONMENTS = {"25.02": ("bpy==4.5.15", ".venv-storm-4.5"), "25.08": ("bpy==5.0.1", ".venv-storm-5.0")}
FRAME_SCRIPT = Path(__file__).resolve().parents[2] / "gpu" / "storm_frame.py"
#: Exit statuses of storm_frame.py that mean "this machine cannot", not "the asset is broken".
_CANNOT = {3: "no imaging-capable pxr", 4: "no EGL OpenGL context"}
#: stderr lines that mean the Storm preview is broken (compile errors, unknown nodes).
#: (Not "GL error: invalid enum": a surfaceless EGL context reports those when Storm presents.)
_PROBLEMS = re.compile(r"Failed to compile|\d+:\d+\(\d+\): error|ERROR: \d+:\d+|Invalid info:id|"
                       r"Invalid shader|Failed to link|no function with name|invalid node")


def storm_pythons(root: Path | None = None) -> dict[str, Path]:
    """{USD version: Python of its storm environment} for the environments that exist."""
    root = Path(root or plugin_dir().parent)
    found = {}
    for version, (_, folder) in STORM_ENVIRONMENTS.items():
        python = root / folder / "bin" / "python"
        if python.is_file():
            found[version] = python
    return found


@dataclass
class StormFrames:
    """images : one (H, W, 4) float32 array per frame (linear, top row first); stderr : what
    the Storm process printed; problems : the lines of it that break the preview."""

    images: list
    stderr: str
    problems: list


def shader_problems(stderr: str) -> list[str]:
    """Lines of a Storm process's stderr that say its shader failed or a node is unknown."""
    return [line.strip() for line in stderr.splitlines() if _PROBLEMS.search(line)]


def storm_environment() -> dict[str, str]:
    """PATH and nothing else but what ``usdbtf env`` prints."""
    from ..plugin import apply_environment

    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin")}
    apply_environment(env)
    return env


def render_frames(python: Path, frames: list[tuple[Path, Path]], camera: str, size: tuple[int, int], *,
                  camera_light: bool = False, env: dict | None = None, timeout: float = 300.0) -> StormFrames:
    """Render each (scene, output .exr) of ``frames`` through ``UsdAppUtils.FrameRecorder`` with
    ``HdStormRendererPlugin`` in one process of ``python`` (a storm environment's), camera prim
    ``camera``, ``size`` = (width, height) pixels.  BTFError when this machine cannot (no
    imaging build, no EGL) or Storm wrote no frame.  ``env``: the process's environment
    (default :func:`storm_environment`)."""
    from ..asset.storm import read_rgba

    cmd = [str(python), str(FRAME_SCRIPT)]
    for scene, output in frames:
        cmd += [str(scene), str(output)]
    cmd += ["--camera", camera, "--size", f"{size[0]}x{size[1]}"] + ([] if camera_light else ["--no-camera-light"])
    try:
        # The render dies with this process (usdbtf.lifetime).
        proc = subprocess.run(cmd, capture_output=True, text=True, env=storm_environment() if env is None else env,
                              timeout=timeout, **dying_with_parent())
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise BTFError(f"{python}: cannot run Storm ({exc})") from None
    if proc.returncode in _CANNOT:
        raise BTFError(f"{python}: {_CANNOT[proc.returncode]}: {proc.stderr.strip().splitlines()[-1:]}")
    if proc.returncode != 0:
        raise BTFError(f"{python}: Storm wrote no frame (exit {proc.returncode}): "
                       f"{' | '.join(proc.stderr.strip().splitlines()[-3:])}")
    images = [np.asarray(read_rgba(output), np.float32) for _, output in frames]
    return StormFrames(images, proc.stderr, shader_problems(proc.stderr))


#: Light kinds :func:`swatch_scene` places: UsdLux schemas Storm's lighting context takes.
LIGHT_KINDS = ("distant", "sphere", "rect", "none")
#: How far sphere and rect lights are put (scene units): far enough to be one direction.
FAR = 10.0


def swatch_scene(asset: Path, out: Path, light_deg, *, lod: str | None = None, kind: str = "distant",
                 intensity: float | None = None, distance: float = 1.0,
                 irradiance: float | None = None, fallback: bool | str = False,
                 nearest: bool = False) -> tuple[str, tuple[int, int]]:
    """Write ``out`` (.usda): ``asset`` (its ``lod`` selection) seen orthographically from the
    pole of its swatch (the quad in z = 0, tangent +x, bitangent +y), its extent filling the
    frame, lit from ``light_deg`` = (theta, phi) degrees in the swatch's frame by one light of
    ``kind`` (:data:`LIGHT_KINDS`): a DistantLight of irradiance ``pi * W`` (the capture light,
    :mod:`usdbtf.photometry`) unless ``irradiance`` (or the raw ``intensity``) is given; a
    SphereLight or a RectLight facing the swatch :data:`FAR` away (intensity 1 unless given);
    "none" for only the renderer's camera light (a point light at the camera, ``distance`` above
    the swatch: make it far for one direction).  ``fallback``: the scene blocks the BTF
    materials' ``outputs:glslfx:surface`` connection, so Storm draws their fallback, what
    renderers without the BTF shader draw: the OpenPBR network (``outputs:mtlx:surface``) where
    the asset has one (Storm 25.02 and 25.08 both prefer the ``mtlx`` render context to the
    universal one), else the ``UsdPreviewSurface``; ``"openpbr"`` also blocks
    ``outputs:surface`` (only the MaterialX network can draw), ``"preview"`` also blocks
    ``outputs:mtlx:surface`` (the ``UsdPreviewSurface``, what renderers without MaterialX draw).
    ``nearest``: every ``UsdUVTexture`` in the scene samples its texture texel by texel
    (``inputs:minFilter`` and ``inputs:magFilter`` "nearest", sampler inputs Storm honours):
    Storm on llvmpipe low-passes a texture even at one texel a pixel, and a fallback's
    brightness is not linear in its maps (issue 40).  Returns
    (camera prim path, (width, height) = the texture's texels)."""
    from pxr import Gf, Usd, UsdGeom, UsdLux

    from ...photometry import capture_irradiance, white_level_of
    from ..read import load_btf
    from ..scenes.scene import add_distant, new_scene, orient_towards

    cbtf = load_btf(asset, lod=lod)
    stage, ref = new_scene(asset, out, lod)
    box = UsdGeom.BBoxCache(Usd.TimeCode.Default(), [UsdGeom.Tokens.default_, UsdGeom.Tokens.render])
    rng = box.ComputeWorldBound(ref).ComputeAlignedRange()
    if rng.IsEmpty():
        raise BTFError(f"{asset}: no geometry to frame")
    lo, hi = rng.GetMin(), rng.GetMax()
    centre = (lo + hi) / 2.0
    camera = UsdGeom.Camera.Define(stage, "/World/Camera")
    camera.CreateProjectionAttr(UsdGeom.Tokens.orthographic)
    # Orthographic apertures are in tenths of a scene unit (GfCamera::APERTURE_UNIT).
    camera.CreateHorizontalApertureAttr(float(hi[0] - lo[0]) * 10.0)
    camera.CreateVerticalApertureAttr(float(hi[1] - lo[1]) * 10.0)
    camera.CreateClippingRangeAttr(Gf.Vec2f(distance / 2.0, distance * 2.0))
    camera.AddTranslateOp().Set(Gf.Vec3d(centre[0], centre[1], hi[2] + distance))
    if kind not in LIGHT_KINDS:
        raise BTFError(f"light kind {kind!r}: choose from {', '.join(LIGHT_KINDS)}")
    theta, phi = (math.radians(float(a)) for a in light_deg)
    towards = (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))
    if kind == "distant":
        light = add_distant(stage, "/World/Light", towards,
                            capture_irradiance(white_level_of(cbtf.info)) if irradiance is None else irradiance)
        if intensity is not None:
            light.GetIntensityAttr().Set(intensity)
    elif kind in ("sphere", "rect"):
        light = (UsdLux.SphereLight.Define(stage, "/World/Light") if kind == "sphere"
                 else UsdLux.RectLight.Define(stage, "/World/Light"))
        light.AddTranslateOp().Set(Gf.Vec3d(*(centre[i] + FAR * towards[i] for i in range(3))))
        light.CreateIntensityAttr(1.0 if intensity is None else intensity)
        orient_towards(light, towards)
    if fallback:
        from pxr import UsdShade

        from ..material import btf_materials

        if fallback not in (True, "openpbr", "preview"):
            raise BTFError(f"fallback {fallback!r}: choose True, 'openpbr' or 'preview'")
        blocked = {True: ("glslfx",), "openpbr": ("glslfx", ""), "preview": ("glslfx", "mtlx")}[fallback]
        for material in btf_materials(stage):
            for context in blocked:
                output = UsdShade.Material(material).GetSurfaceOutput(context)
                if output:
                    output.GetAttr().SetConnections([])  # an explicit empty list blocks the asset's
    if nearest:
        from pxr import Sdf, UsdShade

        for prim in stage.Traverse():
            shader = UsdShade.Shader(prim)
            if shader and shader.GetIdAttr().Get() == "UsdUVTexture":
                for name in ("minFilter", "magFilter"):
                    shader.CreateInput(name, Sdf.ValueTypeNames.Token).Set("nearest")
    stage.GetRootLayer().customLayerData = {"usdbtf": {"output": "storm-check-scene"}}
    stage.Save()
    return "/World/Camera", (cbtf.width, cbtf.height)
