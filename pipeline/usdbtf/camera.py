"""The one pinhole camera: the renderers' view, the GPU preview's and the simulated capture rig's.

Units are metres and degrees; world space is the scene's (Y up for meshes written by
``usdbtf unwrap``; the lab frame of :mod:`usdbtf.rig.kinematics` for the rig).  Pixel
coordinates have x to the right and y down, pixel (i, j) centred at (j + 0.5, i + 0.5); the
principal point is the image centre and pixels are square.

Command-line form (``usdbtf render/preview --camera``)::

    "eye=X,Y,Z target=X,Y,Z [up=X,Y,Z] [fov=DEG]"

a pinhole looking from eye at target, vertical field of view ``fov`` degrees (default 30),
up default +Y.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import BTFError

__all__ = ["Camera", "parse_camera", "auto_camera", "parse_vec3", "unit"]


def parse_vec3(text: str, what: str) -> np.ndarray:
    """(3,) float64 from ``"X,Y,Z"``; BTFError naming ``what`` unless three finite numbers."""
    try:
        v = np.array([float(x) for x in text.split(",")], np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise BTFError(f"{what}: expected three comma-separated numbers, got {text!r}")
    return v


def unit(v: np.ndarray) -> np.ndarray:
    """``v`` (..., 3) scaled to unit length along the last axis (zero stays zero)."""
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


@dataclass
class Camera:
    """A pinhole camera and its sensor.

    eye, target, up : (3,) world positions (metres) and the up direction.
    fov : vertical field of view, degrees in (0, 180).
    width, height : image size, pixels.
    vignetting : strength ``a`` of the lens falloff ``(1 + a (r / f)^2)^-2`` (0: none).
    read_noise, shot_noise : sensor noise, variance ``read^2 + shot * signal`` (0: none).
    The sensor fields are used by the capture-rig simulation (:mod:`usdbtf.rig.scene`); the
    renderers ignore them.
    """

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov: float
    width: int
    height: int
    vignetting: float = 0.0
    read_noise: float = 0.0
    shot_noise: float = 0.0

    def __post_init__(self):
        self.eye, self.target, self.up = (np.asarray(v, np.float64) for v in (self.eye, self.target, self.up))
        if not 0 < self.fov < 180:
            raise BTFError(f"camera fov must be in (0, 180) degrees, got {self.fov}")
        fwd = self.target - self.eye
        if np.linalg.norm(fwd) == 0 or np.linalg.norm(np.cross(fwd, self.up)) < 1e-9 * np.linalg.norm(fwd):
            raise BTFError("camera: eye equals target, or up is parallel to the viewing direction")

    @classmethod
    def framing(cls, board, width: int, height: int, fill: float = 0.62, *, distance_m: float = 1.0,
                vignetting: float = 1.0, read_noise: float = 0.001, shot_noise: float = 1e-4) -> "Camera":
        """The rig's camera: at (0, 0, ``distance_m``) looking at the lab origin, +Y up, with
        the head-on view of ``board`` (anything with ``physical_size_m`` (w, h) metres)
        spanning ``fill`` of the frame height; a real sensor's vignetting and noise."""
        focal = fill * height * distance_m / board.physical_size_m[1]
        fov = float(np.degrees(2.0 * np.arctan(0.5 * height / focal)))
        return cls(np.array([0.0, 0.0, distance_m]), np.zeros(3), np.array([0.0, 1.0, 0.0]), fov, width, height,
                   vignetting=vignetting, read_noise=read_noise, shot_noise=shot_noise)

    @property
    def focal_px(self) -> float:
        """Focal length in pixels."""
        return 0.5 * self.height / np.tan(np.radians(self.fov) / 2)

    @property
    def distance_m(self) -> float:
        """Eye to target, metres."""
        return float(np.linalg.norm(self.target - self.eye))

    def basis(self) -> np.ndarray:
        """(3, 3) rows right, up, forward (world space, orthonormal)."""
        fwd = unit(self.target - self.eye)
        right = unit(np.cross(fwd, self.up))
        return np.stack([right, np.cross(right, fwd), fwd])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) -> pixel coordinates (..., 2) (x right, y down) and depth (...,)
        along the viewing axis (metres, > 0 in front)."""
        cam = (np.asarray(points, np.float64) - self.eye) @ self.basis().T
        depth = cam[..., 2]
        focal = self.focal_px
        with np.errstate(divide="ignore", invalid="ignore"):
            x = 0.5 * self.width + focal * cam[..., 0] / depth
            y = 0.5 * self.height - focal * cam[..., 1] / depth
        return np.stack([x, y], axis=-1), depth

    def pixel_footprint(self, depth: np.ndarray) -> np.ndarray:
        """World-space width of one pixel at ``depth`` metres (for mip selection)."""
        return depth * 2 * np.tan(np.radians(self.fov) / 2) / self.height


def parse_camera(text: str, width: int, height: int) -> Camera:
    """Camera from its command-line form (module docstring)."""
    fields = {}
    for part in text.split():
        key, sep, value = part.partition("=")
        if not sep or key not in ("eye", "target", "up", "fov") or key in fields:
            raise BTFError(f"--camera: cannot parse {part!r} (use eye=X,Y,Z target=X,Y,Z [up=X,Y,Z] [fov=DEG])")
        fields[key] = value
    if "eye" not in fields or "target" not in fields:
        raise BTFError("--camera needs eye=X,Y,Z and target=X,Y,Z")
    try:
        fov = float(fields.get("fov", 30.0))
    except ValueError:
        raise BTFError(f"--camera: fov must be a number, got {fields['fov']!r}") from None
    return Camera(parse_vec3(fields["eye"], "--camera eye"), parse_vec3(fields["target"], "--camera target"),
                  parse_vec3(fields.get("up", "0,1,0"), "--camera up"), fov, width, height)


def auto_camera(points: np.ndarray, width: int, height: int, fov: float = 30.0,
                direction=(0.35, 0.45, 1.0)) -> Camera:
    """A camera framing the bounding box of ``points`` (..., 3) from ``direction`` (Y up)."""
    lo, hi = points.reshape(-1, 3).min(axis=0), points.reshape(-1, 3).max(axis=0)
    centre, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    half = np.radians(fov) / 2 * min(1.0, width / height)
    dist = radius / np.sin(half) * 1.05
    return Camera(centre + unit(np.asarray(direction, np.float64)) * dist, centre, np.array([0.0, 1.0, 0.0]),
                  fov, width, height)
