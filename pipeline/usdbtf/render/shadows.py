"""Cast shadows by shadow mapping: the mesh rasterised from each light, depths compared.

Distant lights get one orthographic map over the mesh's bounding sphere; point lights one
perspective map aimed at the mesh when they are outside its bounding sphere, else a cube of
six.  Lookups offset the point along its normal by two map texels (no self-shadowing acne)
and blend the four nearest depth tests bilinearly (soft one-texel edges).  Self-shadowing
*within* the material (mesostructure) is in the measured data already; these are the
shadows the object casts on itself at the scale of the mesh.
"""
from __future__ import annotations

import numpy as np

from ..raster import rasterize
from ..camera import Camera
from .scene import Light

__all__ = ["ShadowMap"]

_CUBE = ((1, 0, 0, 0, 1, 0), (-1, 0, 0, 0, 1, 0), (0, 1, 0, 0, 0, 1), (0, -1, 0, 0, 0, 1),
         (0, 0, 1, 0, 1, 0), (0, 0, -1, 0, 1, 0))


class _OrthoView:
    """Orthographic projection along ``forward`` over a sphere (centre, radius)."""

    def __init__(self, forward, centre, radius, res):
        fwd = forward / np.linalg.norm(forward)
        helper = np.array([0.0, 1.0, 0.0]) if abs(fwd[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
        right = np.cross(fwd, helper)
        right /= np.linalg.norm(right)
        self.axes = np.stack([right, np.cross(right, fwd), fwd])
        self.centre, self.radius, self.res = centre, radius, res

    def project(self, points):
        p = (points - self.centre) @ self.axes.T
        scale = self.res / (2 * self.radius)
        xy = np.stack([(p[..., 0] + self.radius) * scale, (self.radius - p[..., 1]) * scale], axis=-1)
        return xy, p[..., 2]

    def texel_size(self, depth):
        return np.full(np.shape(depth), 2 * self.radius / self.res)


class _PerspectiveView:
    def __init__(self, camera: Camera):
        self.camera = camera

    def project(self, points):
        return self.camera.project(points)

    def texel_size(self, depth):
        return self.camera.pixel_footprint(np.abs(depth))


class ShadowMap:
    """Depth maps of ``corners`` (T, 3, 3) seen from ``light``; :meth:`visibility` looks them up."""

    def __init__(self, corners: np.ndarray, light: Light, resolution: int = 2048):
        pts = corners.reshape(-1, 3)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        centre = (lo + hi) / 2
        radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-9) * 1.02
        self.res = resolution
        self.light = light
        if light.kind == "directional":
            self.views = [_OrthoView(-light.vector, centre, radius, resolution)]
            self.forward = np.array([-light.vector])
        else:
            to_centre = centre - light.vector
            dist = float(np.linalg.norm(to_centre))
            if dist > radius * 1.01:
                fov = 2 * np.degrees(np.arcsin(radius / dist)) * 1.02
                up = np.array([0.0, 1.0, 0.0]) if abs(to_centre[1]) < 0.9 * dist else np.array([1.0, 0.0, 0.0])
                cams = [Camera(light.vector, centre, up, fov, resolution, resolution)]
            else:                                   # inside the bounds: a cube map (fov a bit over 90)
                cams = [Camera(light.vector, light.vector + np.array(f[:3], float), np.array(f[3:], float),
                               92.0, resolution, resolution) for f in _CUBE]
            self.views = [_PerspectiveView(c) for c in cams]
            self.forward = np.array([c.basis()[2] for c in cams])
        self.depths = []
        for view in self.views:
            xy, depth = view.project(corners)
            ok = np.isfinite(xy).all(axis=(1, 2)) & (depth > 0).all(axis=1) if light.kind != "directional" \
                else np.ones(len(corners), bool)
            key = depth if light.kind == "directional" else -1.0 / np.where(depth > 0, depth, 1.0)
            raster = rasterize(xy[ok], key[ok], resolution, resolution, depth=True)
            d = raster.depth.astype(np.float64)
            if light.kind != "directional":
                with np.errstate(divide="ignore"):
                    d = np.where(np.isfinite(d), -1.0 / d, np.inf)
            self.depths.append(d)

    def visibility(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        """(n,) fraction of the light reaching points (n, 3) with unit normals (n, 3)."""
        out = np.ones(len(points))
        if len(self.views) == 1:
            face = np.zeros(len(points), np.int64)
        else:
            face = np.argmax((points - self.light.vector) @ self.forward.T, axis=1)
        for f, (view, depth_map) in enumerate(zip(self.views, self.depths)):
            sel = np.flatnonzero(face == f)
            if not len(sel):
                continue
            p = points[sel]
            _, d0 = view.project(p)
            texel = view.texel_size(d0)
            shifted = p + normals[sel] * (2.0 * texel)[:, None]
            xy, depth = view.project(shifted)
            out[sel] = self._lookup(depth_map, xy, depth, texel)
        return out

    def _lookup(self, depth_map, xy, depth, texel):
        res = self.res
        x, y = xy[:, 0] - 0.5, xy[:, 1] - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = x - x0, y - y0
        vis = np.zeros(len(x))
        bias = 1.0 * texel
        for dy, dx, w in ((0, 0, (1 - fx) * (1 - fy)), (0, 1, fx * (1 - fy)), (1, 0, (1 - fx) * fy), (1, 1, fx * fy)):
            xi, yi = x0.astype(np.int64) + dx, y0.astype(np.int64) + dy
            inside = (xi >= 0) & (xi < res) & (yi >= 0) & (yi < res)
            stored = np.full(len(x), np.inf)
            stored[inside] = depth_map[yi[inside], xi[inside]]
            vis += w * (depth <= stored + bias)
        return np.where(np.isfinite(xy).all(axis=1), vis, 1.0)
