"""A USD stage's own shots: its camera, UsdLux lights and every rendered mesh with the BTF
material bound to it, frame by frame (issue 26).

``usdbtf render SCENE.usda --camera PRIM [--frames A:B]`` renders these with the CPU
renderer (:func:`usdbtf.render.render_parts`: one z-buffer, every mesh its own material,
shadows from every mesh); Storm renders the same stage itself.  What counts as rendered is
what :mod:`usdbtf.usd.scenes.plan` analyses: ``Mesh`` prims of purpose default or render, visible at
the frame.  Each one's material is its bound material (all purposes) when that is a
BtfMaterialAPI material; a mesh bound to another material (or to one whose asset a
scene-shaped build left out, so it composes no BTF) is not rendered, with a warning; a mesh
bound to nothing takes the stage's only BTF material (a mesh written beside an asset by
``usdbtf preview``), else it is an error naming the prim.
"""
from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path

from ...errors import UsageError

log = logging.getLogger(__name__)

__all__ = ["Shot", "scene_shots", "parse_frames", "frame_path", "check_pattern"]


@dataclass
class Shot:
    """One frame: ``time`` (None: the default time), ``camera``, ``lights`` and ``parts``
    [(material path, :class:`usdbtf.mesh.Mesh` in world metres)]."""

    time: float | None
    camera: object
    lights: list
    parts: list


def parse_frames(text: str) -> list[int]:
    """``A:B`` (or ``A``) -> the whole frames A..B inclusive; UsageError otherwise."""
    m = re.fullmatch(r"\s*(-?\d+)\s*(?::\s*(-?\d+)\s*)?", text or "")
    if not m:
        raise UsageError(f"--frames must be A:B (whole frames, inclusive) or A, got {text!r}")
    first = int(m.group(1))
    last = int(m.group(2)) if m.group(2) is not None else first
    if last < first or last - first >= 100000:
        raise UsageError(f"--frames {text}: the last frame must be >= the first (and fewer than 100000 frames)")
    return list(range(first, last + 1))


def frame_path(pattern: Path, frame: int | None) -> Path:
    """The output of one frame: the run of ``#`` in ``pattern``'s name replaced by the frame
    number padded to its length (``out.####.exr`` -> ``out.0012.exr``, as Nuke, Houdini and
    usdrecord name sequences); the pattern itself for a single frame without ``#``."""
    name = pattern.name
    runs = list(re.finditer(r"#+", name))
    if frame is None and not runs:
        return pattern
    if len(runs) != 1:
        raise UsageError(f"{pattern}: a frame range needs one run of # in the output name for the frame number "
                         "(e.g. out.####.exr)")
    run = runs[0]
    number = f"{frame:0{len(run.group())}d}" if frame >= 0 else f"-{-frame:0{len(run.group())}d}"
    return pattern.with_name(name[:run.start()] + number + name[run.end():])


def scene_shots(path, camera_path: str, width: int | None, frames: list | None, *, k: int | None = None,
                lazy: bool = False):
    """(materials {material path: CompressedBTF}, [:class:`Shot`] per frame of ``frames``
    (None: the default time)) of the stage at ``path`` seen from the UsdGeom.Camera
    ``camera_path``; the frame ``width`` pixels wide (None: the stage's UsdRender.Settings
    width, else 512), the height from the camera's apertures; ``lazy``: each material's
    coefficients read when asked for (:func:`usdbtf.usd.material.read_btf`)."""
    from pxr import UsdGeom

    from ...mesh import load_prim
    from ..read import load_btf, open_stage
    from .scene import btf_mesh_prims, camera_prim, render_resolution, scene_camera, scene_lights

    stage = open_stage(path)
    meters = float(UsdGeom.GetStageMetersPerUnit(stage))
    prim = camera_prim(stage, camera_path, path)
    if width is None:
        resolution = render_resolution(stage)
        width = resolution[0] if resolution else 512
    materials: dict = {}
    warned: set = set()
    shots = []
    for time in (frames if frames is not None else [None]):
        parts = []
        for mesh_prim, material in btf_mesh_prims(stage, time=time, unbound="only", where=str(path), warned=warned):
            if material not in materials:
                materials[material] = load_btf(stage, material=material, k=k, lazy=lazy)
            parts.append((material, load_prim(mesh_prim, time)))
        shots.append(Shot(time, scene_camera(prim, width, meters, time), scene_lights(stage, time, path), parts))
    return materials, shots


def check_pattern(pattern: Path, frames: list | None) -> None:
    """UsageError unless ``pattern`` names every frame apart (see :func:`frame_path`)."""
    if frames is not None and len(frames) > 1:
        frame_path(pattern, frames[0])
    if frames is None and "#" in Path(pattern).name:
        raise UsageError(f"{pattern}: # in the output name numbers frames; give --frames A:B")
