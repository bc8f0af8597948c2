"""Lights for the reference renderer, and their command-line form.

Units are metres; world space is the mesh's (Y up for meshes written by ``usdbtf unwrap``).
The camera is :class:`usdbtf.camera.Camera`, the mesh :class:`usdbtf.mesh.Mesh`.

Light  ``"point:X,Y,Z[:INTENSITY]"`` or ``"dir:X,Y,Z[:INTENSITY]"``: a point light at X,Y,Z,
       or a distant light in direction X,Y,Z (pointing *towards* the light).  Intensity is
       the irradiance E of :mod:`usdbtf.photometry` (radiance = value x E / (pi W)): a distant
       light of intensity pi W reproduces the measured images; a point light gives
       ``INTENSITY / d^2`` at distance d metres.  Without ``:INTENSITY``: pi
       (:data:`DEFAULT_INTENSITY`, the capture light of a BTF that records no white level).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..camera import parse_vec3, unit
from ..errors import BTFError

__all__ = ["Light", "parse_light", "DEFAULT_INTENSITY"]

#: A command-line light's intensity when it gives none: pi, the capture light (usdbtf.photometry)
#: of a BTF that records no white level, so ``dir:X,Y,Z`` shows the measured brightness.
DEFAULT_INTENSITY = math.pi


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
    vec = parse_vec3(parts[1], f"--light {text}")
    try:
        intensity = float(parts[2]) if len(parts) == 3 else DEFAULT_INTENSITY
    except ValueError:
        raise BTFError(f"--light {text}: intensity must be a number") from None
    if not (np.isfinite(intensity) and intensity >= 0):
        raise BTFError(f"--light {text}: intensity must be a finite number >= 0")
    kind = kinds[parts[0]]
    if kind == "directional":
        if np.linalg.norm(vec) == 0:
            raise BTFError(f"--light {text}: direction must not be zero")
        vec = unit(vec)
    return Light(kind, vec, intensity)
