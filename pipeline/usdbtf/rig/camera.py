"""Where capture gets its frames: an OpenCV video source or a command hook.

Both return ``(pixels (H, W, 3) native dtype, colour space name)``; the capture loop
stores them with OIIO, declaring that colour space.

* :class:`OpenCVCamera` -- anything ``cv2.VideoCapture`` opens: a device index ("0"),
  a stream URL, or an image file that camera software keeps overwriting (re-read per
  trigger; the simulator's ``latest.tif``).  OpenCV hands out 8-bit BGR; the frames are
  taken to be in ``color_space`` (sRGB by default, what webcams deliver).
* :class:`CommandCamera` -- runs a command per trigger that writes the frame to a file,
  e.g. ``gphoto2 --capture-image-and-download --filename {out}`` or, for the
  simulator, ``cp FRAMES/{tag}.tif {out}``.  Fields: ``{out}`` (the file to write),
  ``{tag}`` (the frame tag sent with TRIG), ``{frame}`` (the rig's frame counter).
  The command is split like a shell line (shlex) but not run by a shell.  The file's
  declared colour space is used unless ``color_space`` overrides it.
"""
from __future__ import annotations

import os
import shlex
import signal
import subprocess
from pathlib import Path

import numpy as np

from .. import color
from ..errors import BTFError
from ..imageio import read_image
from ..lifetime import dying_with_parent

__all__ = ["OpenCVCamera", "CommandCamera", "DEFAULT_SPACE"]

DEFAULT_SPACE = "sRGB Encoded Rec.709 (sRGB)"


class OpenCVCamera:
    def __init__(self, source: str, *, color_space: str | None = None):
        import cv2
        self.label = str(source)
        self.color_space = color.resolve_space(color_space or DEFAULT_SPACE)
        self.source = int(source) if str(source).isdigit() else str(source)
        # A plain file is reopened per grab (its content changes between triggers).
        self.is_file = isinstance(self.source, str) and "://" not in self.source
        self._cap = None
        if not self.is_file:
            self._cap = cv2.VideoCapture(self.source)
            if not self._cap.isOpened():
                raise BTFError(f"camera {self.label}: cv2.VideoCapture cannot open it")
            self._cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)

    def describe(self) -> dict:
        return {"kind": "opencv", "source": self.label, "color_space": self.color_space}

    def grab(self, tag: str, frame: int):
        import cv2
        if self.is_file:
            if not os.path.isfile(self.source):
                raise BTFError(f"camera {self.label}: no such file (for frame {tag})")
            cap = cv2.VideoCapture(self.source)
            ok, img = cap.read()
            cap.release()
        else:
            self._cap.grab()            # drop the frame buffered before the trigger
            ok, img = self._cap.read()
        if not ok or img is None:
            raise BTFError(f"camera {self.label}: no frame delivered for {tag}")
        img = np.asarray(img)
        if img.ndim == 2:
            img = np.repeat(img[..., None], 3, axis=2)
        return np.ascontiguousarray(img[..., 2::-1]), self.color_space   # BGR -> RGB

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()


class CommandCamera:
    def __init__(self, template: str, workdir, *, color_space: str | None = None, ext: str = "tif",
                 timeout: float = 120.0):
        self.template = template
        try:
            self.argv = shlex.split(template)
            [w.format(out="x", tag="t", frame=0) for w in self.argv]
        except (ValueError, KeyError, IndexError) as exc:
            raise BTFError(f"camera command {template!r}: bad template ({exc}); fields are {{out}}, {{tag}}, "
                           "{frame}") from None
        if not self.argv:
            raise BTFError("camera command is empty")
        if not any("{out}" in w for w in self.argv):
            raise BTFError(f"camera command {template!r} must write the frame to {{out}}")
        self.workdir = Path(workdir)
        self.color_space = color.resolve_space(color_space) if color_space else None
        self.ext = ext.lstrip(".")
        self.timeout = float(timeout)

    def describe(self) -> dict:
        return {"kind": "command", "command": self.template, "color_space": self.color_space}

    def grab(self, tag: str, frame: int):
        out = self.workdir / f".hook-{tag}.{self.ext}"
        if out.exists():
            out.unlink()
        argv = [w.format(out=out, tag=tag, frame=frame) for w in self.argv]
        try:
            # SIGTERM when this process dies: the rig's program may want to release its camera.
            done = subprocess.run(argv, capture_output=True, timeout=self.timeout,
                                  **dying_with_parent(signal.SIGTERM))
        except FileNotFoundError:
            raise BTFError(f"camera command {argv[0]!r} not found") from None
        except subprocess.TimeoutExpired:
            raise BTFError(f"camera command {argv[0]} took longer than {self.timeout:g} s for {tag}") from None
        if done.returncode != 0:
            why = (done.stderr.decode(errors="replace").strip().splitlines() or ["no message"])[-1]
            raise BTFError(f"camera command {argv[0]} failed for {tag} (exit {done.returncode}): {why}")
        if not out.is_file():
            raise BTFError(f"camera command {argv[0]} did not write {out.name} for {tag}")
        try:
            pixels, info = read_image(out)
        finally:
            out.unlink(missing_ok=True)
        space = self.color_space or info.color_space or DEFAULT_SPACE
        try:
            space = color.resolve_space(space)
        except BTFError:
            raise BTFError(f"camera frame {tag}: declared colour space {space!r} is unknown to OCIO; "
                           "pass --camera-space") from None
        return pixels, space

    def close(self) -> None:
        pass
