"""Cycles frames of a usdbtf asset through the Blender add-on (OSL), from the bpy environment.

usd-core has no Blender.  ``scripts/bootstrap.sh`` installs the ``bpy`` 5.0.1 wheel (Blender
as a Python module, Cycles with Open Shading Language on the CPU) into ``.venv-storm-5.0``,
the environment the Storm checks use (:mod:`usdbtf.usd.preview.hydra`).  :func:`render_frames` runs
``usdbtf/gpu/cycles_frame.py`` with that Python in a subprocess whose environment is only
``PATH``: the script loads the add-on from ``plugin/blender/usdbtf``, which imports the asset
with Blender's USD importer and gives it the OSL network, and renders each frame to EXR.

A frame is a :class:`CyclesFrame`: the asset (and ``lod``), a camera (``"pole"``: orthographic
down the swatch's normal, or a :class:`usdbtf.camera.Camera` in the asset's USD space), one
sun (direction towards it in the asset's USD space; irradiance E, a Blender sun of strength E
W/m^2, radiance = value x E / (pi W) as in :mod:`usdbtf.photometry`, so pi W is the capture
light), the image size and the samples.
"""
from __future__ import annotations

import json
import os
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...errors import BTFError
from ...lifetime import dying_with_parent
from ...plugin_folder import plugin_dir

__all__ = ["BLENDER_VERSION", "CyclesFrame", "CyclesFrames", "cycles_python", "render_frames", "srgb8", "common_gain"]

#: The bpy wheel whose Cycles the add-on is checked in (hydra.STORM_ENVIRONMENTS' 25.08 entry).
BLENDER_VERSION = "5.0.1"
FRAME_SCRIPT = Path(__file__).resolve().parents[2] / "gpu" / "cycles_frame.py"
_CANNOT = {3: "no bpy"}


@dataclass
class CyclesFrame:
    """One frame: see the module docstring.  camera : "pole" or a usdbtf.camera.Camera."""

    asset: Path
    output: Path
    sun: tuple
    camera: object = "pole"
    size: tuple = (64, 64)
    lod: str | None = None
    irradiance: float = 1.0
    samples: int = 1
    #: True: Blender's USD importer only (the UsdPreviewSurface fallback as a Principled BSDF).
    fallback: bool = False
    #: The add-on's surface: "BTF" (the OSL BTF, one sun) or "PRINCIPLED" (the fitted OpenPBR lobes).
    surface: str = "BTF"
    #: {map: file} of OpenPBR maps (usd.asset.openpbr.MAP_FILES' keys): instead of ``asset``, a unit
    #: swatch carrying the add-on's Principled BSDF of these maps (``asset`` then only names the frame).
    maps: dict | None = None

    def job(self) -> dict:
        camera = {"kind": "pole"} if isinstance(self.camera, str) else {
            "kind": "perspective", "eye": list(map(float, self.camera.eye)),
            "target": list(map(float, self.camera.target)), "up": list(map(float, self.camera.up)),
            "fov": float(self.camera.fov)}
        return {"asset": str(Path(self.asset).resolve()), "lod": self.lod, "output": str(self.output),
                "size": [int(s) for s in self.size], "camera": camera, "sun": [float(x) for x in self.sun],
                "irradiance": float(self.irradiance), "samples": int(self.samples), "fallback": bool(self.fallback),
                "surface": str(self.surface),
                "maps": {k: str(Path(v).resolve()) for k, v in self.maps.items()} if self.maps else None}


@dataclass
class CyclesFrames:
    """images : (H, W, 4) float32 per frame (linear, top row first); seconds : each frame's
    render time (Cycles' own, the import not included); import_seconds; stderr."""

    images: list
    seconds: list
    import_seconds: list
    stderr: str


def cycles_python(root: Path | None = None) -> Path | None:
    """The bpy 5.0.1 environment's Python, or None where bootstrap could not make it."""
    from .hydra import storm_pythons

    return storm_pythons(root).get("25.08")


def render_frames(python: Path, frames: list[CyclesFrame], *, timeout: float = 300.0,
                  addon: Path | None = None) -> CyclesFrames:
    """Render ``frames`` in one Blender process of ``python``.  ``addon``: the folder holding
    the add-on package ``usdbtf/`` (default the plugin's ``blender``; a benchmark's copy with
    an earlier revision's module, say).  BTFError when it cannot run or writes no frame (its
    last stderr lines say why)."""
    from ..asset.storm import read_rgba

    with tempfile.TemporaryDirectory(prefix="usdbtf-cycles-") as work:
        jobs, report = Path(work) / "jobs.json", Path(work) / "report.json"
        jobs.write_text(json.dumps({"frames": [f.job() for f in frames], "report": str(report)}))
        cmd = [str(python), str(FRAME_SCRIPT), str(jobs), str(addon or plugin_dir() / "blender")]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout,
                                  env={"PATH": os.environ.get("PATH", "/usr/bin:/bin")},
                                  **dying_with_parent())     # Blender dies with this process
        except (OSError, subprocess.TimeoutExpired) as exc:
            raise BTFError(f"{python}: cannot run Cycles ({exc})") from None
        if proc.returncode in _CANNOT:
            raise BTFError(f"{python}: {_CANNOT[proc.returncode]}")
        if proc.returncode != 0 or not report.is_file():
            raise BTFError(f"{python}: Cycles wrote no frame (exit {proc.returncode}): "
                           f"{' | '.join(proc.stderr.strip().splitlines()[-4:])}")
        done = json.loads(report.read_text())["frames"]
    images = [np.asarray(read_rgba(f.output), np.float32) for f in frames]
    return CyclesFrames(images, [d["seconds"] for d in done], [d["import_seconds"] for d in done], proc.stderr)


def srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear values -> 8-bit sRGB steps (float, 0..255), clipped to [0, 1] first."""
    from ...render.output import srgb_encoded

    return 255.0 * srgb_encoded(linear)


def common_gain(pairs) -> tuple[float, list[float], list[float]]:
    """(gain common to all, each pair's own gain, each pair's mean |difference| in 8-bit sRGB
    steps after the common gain) of (rendered, reference) linear RGB pairs: renderers' light
    units differ, so one least-squares gain per light direction, their mean applied to all
    (the Storm and Cycles swatch checks both use it)."""
    own = [float((img * ref).sum() / max((img * img).sum(), 1e-30)) for img, ref in pairs]
    gain = float(np.mean(own))
    steps = [float(np.abs(srgb8(img * gain) - srgb8(ref)).mean()) for img, ref in pairs]
    return gain, own, steps
