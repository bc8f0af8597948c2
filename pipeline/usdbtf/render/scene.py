"""Cameras, lights and meshes for the reference renderer, and their command-line forms.

Units are metres; world space is the mesh's (Y up for meshes written by ``usdbtf unwrap``).

Camera  ``"eye=X,Y,Z target=X,Y,Z [up=X,Y,Z] [fov=DEG]"``: a pinhole looking from eye at
        target, vertical field of view ``fov`` degrees (default 30), up default +Y.
Light   ``"point:X,Y,Z[:INTENSITY]"`` or ``"dir:X,Y,Z[:INTENSITY]"``: a point light at X,Y,Z,
        or a distant light in direction X,Y,Z (pointing *towards* the light).  Intensity is
        irradiance relative to the capture's light: a distant light of intensity 1 reproduces
        the measured images; a point light gives ``INTENSITY / d^2`` at distance d metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BTFError

__all__ = ["Camera", "Light", "RenderMesh", "parse_camera", "parse_light", "auto_camera"]


def _vec3(text: str, what: str) -> np.ndarray:
    try:
        v = np.array([float(x) for x in text.split(",")], np.float64)
    except ValueError:
        v = np.zeros(0)
    if v.shape != (3,) or not np.isfinite(v).all():
        raise BTFError(f"{what}: expected three comma-separated numbers, got {text!r}")
    return v


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


@dataclass
class Camera:
    """A pinhole camera; ``width`` x ``height`` pixels, ``fov`` vertical degrees."""

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov: float
    width: int
    height: int

    def __post_init__(self):
        self.eye, self.target, self.up = (np.asarray(v, np.float64) for v in (self.eye, self.target, self.up))
        if not 0 < self.fov < 180:
            raise BTFError(f"camera fov must be in (0, 180) degrees, got {self.fov}")
        fwd = self.target - self.eye
        if np.linalg.norm(fwd) == 0 or np.linalg.norm(np.cross(fwd, self.up)) < 1e-9 * np.linalg.norm(fwd):
            raise BTFError("camera: eye equals target, or up is parallel to the viewing direction")

    def basis(self) -> np.ndarray:
        """(3, 3) rows right, up, forward (world space, orthonormal)."""
        fwd = _unit(self.target - self.eye)
        right = _unit(np.cross(fwd, self.up))
        return np.stack([right, np.cross(right, fwd), fwd])

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) -> pixel coordinates (..., 2) (x right, y down) and depth (...,)
        along the viewing axis (metres, > 0 in front)."""
        cam = (np.asarray(points, np.float64) - self.eye) @ self.basis().T
        depth = cam[..., 2]
        focal = 0.5 * self.height / np.tan(np.radians(self.fov) / 2)
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
    return Camera(_vec3(fields["eye"], "--camera eye"), _vec3(fields["target"], "--camera target"),
                  _vec3(fields.get("up", "0,1,0"), "--camera up"), fov, width, height)


def auto_camera(points: np.ndarray, width: int, height: int, fov: float = 30.0,
                direction=(0.35, 0.45, 1.0)) -> Camera:
    """A camera framing the bounding sphere of ``points`` from ``direction`` (Y up)."""
    lo, hi = points.reshape(-1, 3).min(axis=0), points.reshape(-1, 3).max(axis=0)
    centre, radius = (lo + hi) / 2, max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    half = np.radians(fov) / 2 * min(1.0, width / height)
    dist = radius / np.sin(half) * 1.05
    return Camera(centre + _unit(np.asarray(direction, np.float64)) * dist, centre, np.array([0.0, 1.0, 0.0]),
                  fov, width, height)


@dataclass
class Light:
    """kind "point" (``vector`` = position) or "directional" (``vector`` = unit direction towards the light)."""

    kind: str
    vector: np.ndarray
    intensity: float = 1.0

    def at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions towards the light (n, 3) and irradiance scale (n,) at world points (n, 3)."""
        if self.kind == "directional":
            return np.broadcast_to(self.vector, points.shape), np.full(len(points), self.intensity)
        d = self.vector - points
        dist2 = np.einsum("ij,ij->i", d, d)
        return d / np.sqrt(np.maximum(dist2, 1e-300))[:, None], self.intensity / np.maximum(dist2, 1e-300)


def parse_light(text: str) -> Light:
    """Light from its command-line form (module docstring)."""
    parts = text.split(":")
    kinds = {"point": "point", "dir": "directional", "directional": "directional"}
    if len(parts) not in (2, 3) or parts[0] not in kinds:
        raise BTFError(f"--light: cannot parse {text!r} (use point:X,Y,Z[:I] or dir:X,Y,Z[:I])")
    vec = _vec3(parts[1], f"--light {text}")
    try:
        intensity = float(parts[2]) if len(parts) == 3 else 1.0
    except ValueError:
        raise BTFError(f"--light {text}: intensity must be a number") from None
    if not (np.isfinite(intensity) and intensity >= 0):
        raise BTFError(f"--light {text}: intensity must be a finite number >= 0")
    kind = kinds[parts[0]]
    if kind == "directional":
        if np.linalg.norm(vec) == 0:
            raise BTFError(f"--light {text}: direction must not be zero")
        vec = _unit(vec)
    return Light(kind, vec, intensity)


@dataclass
class RenderMesh:
    """Triangles with per-corner attributes (metres, world space).

    corners : (T, 3, 3) positions; normals, tangents, bitangents : (T, 3, 3); st : (T, 3, 2).
    The tangent frame at a point is the sample's: tangent = image right (+s),
    bitangent = image up (+t), normal out of the surface.
    """

    corners: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    bitangents: np.ndarray
    st: np.ndarray

    def __post_init__(self):
        T = len(self.corners)
        for name in ("corners", "normals", "tangents", "bitangents", "st"):
            a = np.asarray(getattr(self, name), np.float64)
            want = (T, 3, 2 if name == "st" else 3)
            if a.shape != want:
                raise BTFError(f"mesh {name}: expected shape {want}, got {a.shape}")
            if not np.isfinite(a).all():
                raise BTFError(f"mesh {name}: contains NaN or Inf")
            setattr(self, name, a)
        if T == 0:
            raise BTFError("mesh has no triangles")
