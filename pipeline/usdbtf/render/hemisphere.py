"""Interpolation over a set of measured directions: a triangulated hemisphere.

Directions are mapped to the unit disc by the azimuthal equidistant projection
``p = (theta / 90 deg) (cos phi, sin phi)`` (rings of constant theta stay circles, the pole is
the centre) and Delaunay-triangulated there (OpenCV's Subdiv2D).  A query direction's
weights are its barycentric coordinates in the triangle that contains its projection, so

* at a measured direction the weights are exactly one-hot (reproduces the sample);
* weights are continuous everywhere: across a triangle edge both triangles give the same
  two-vertex blend; outside the triangulated region (e.g. beyond the last measured ring, or
  below the horizon) the query is projected to the nearest point of the boundary, which is
  continuous because the region is convex.

Point location: a fine raster of the triangulation gives each query a first guess, checked
exactly by its barycentrics; the few queries near edges where the guess fails are resolved
among the triangles that overlap their cell of a coarse grid (still exact).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BTFError
from ..raster import edge_coefficients, rasterize

__all__ = ["Triangulation", "project", "directions_to_vectors"]

_SCALE = 1.0e4          # Subdiv2D works in float32: spread the unit disc over +-1e4
_GRID = 64
_ID_GRID = 256
_INSIDE_EPS = 1e-9


def project(vectors: np.ndarray) -> np.ndarray:
    """(n, 3) unit vectors (tangent frame, z = normal) -> (n, 2) disc coordinates.

    theta beyond 90 deg (below the horizon) maps outside the unit disc."""
    v = np.asarray(vectors, np.float64)
    theta = np.arccos(np.clip(v[:, 2] / np.maximum(np.linalg.norm(v, axis=1), 1e-300), -1.0, 1.0))
    rho = np.hypot(v[:, 0], v[:, 1])
    scale = np.where(rho > 0, theta / (np.pi / 2) / np.where(rho > 0, rho, 1.0), 0.0)
    return v[:, :2] * scale[:, None]


def directions_to_vectors(deg: np.ndarray) -> np.ndarray:
    """(n, 2) (theta, phi) degrees -> (n, 3) unit vectors."""
    d = np.radians(np.asarray(deg, np.float64).reshape(-1, 2))
    st = np.sin(d[:, 0])
    return np.stack([st * np.cos(d[:, 1]), st * np.sin(d[:, 1]), np.cos(d[:, 0])], axis=1)


@dataclass
class Triangulation:
    """Triangles over measured directions.

    directions : (N, 2) degrees; points : (N, 2) disc coordinates; triangles : (M, 3) vertex
    indices (counter-clockwise); boundary : (E, 2) vertex pairs on the outer boundary.
    """

    directions: np.ndarray
    points: np.ndarray
    triangles: np.ndarray
    boundary: np.ndarray

    @classmethod
    def from_directions(cls, directions_deg: np.ndarray, what: str = "directions") -> "Triangulation":
        dirs = np.asarray(directions_deg, np.float64).reshape(-1, 2)
        pts = project(directions_to_vectors(dirs))
        if len(pts) == 1:                                       # one direction: constant everywhere
            return cls(dirs, pts, np.zeros((0, 3), np.int64), np.zeros((0, 2), np.int64))
        if len(np.unique(np.round(pts, 9), axis=0)) != len(pts):
            raise BTFError(f"{what}: two measured directions coincide")
        tris = _delaunay(pts)
        if len(tris) == 0:                                      # all on a line: interpolate along it
            order = np.argsort(pts @ (pts[-1] - pts[0]))
            return cls(dirs, pts, np.zeros((0, 3), np.int64), np.stack([order[:-1], order[1:]], axis=1))
        return cls(dirs, pts, tris, _boundary_edges(tris))

    def __post_init__(self):
        self._build_lookup()

    # -- point location --------------------------------------------------------------------
    def _build_lookup(self) -> None:
        tri_pts = self.points[self.triangles]                   # (M, 3, 2)
        self._origin = self.points.min(axis=0) - 1e-6
        span = float(np.max(self.points.max(axis=0) - self._origin)) + 2e-6
        self._cell = span / _GRID
        if len(self.triangles) == 0:
            self._grid = np.full((_GRID, _GRID, 1), -1, np.int64)
            return
        lo = np.floor((tri_pts.min(axis=1) - self._origin) / self._cell).astype(int).clip(0, _GRID - 1)
        hi = np.floor((tri_pts.max(axis=1) - self._origin) / self._cell).astype(int).clip(0, _GRID - 1)
        lists = [[[] for _ in range(_GRID)] for _ in range(_GRID)]
        for t, ((x0, y0), (x1, y1)) in enumerate(zip(lo, hi)):
            for gy in range(y0, y1 + 1):
                for gx in range(x0, x1 + 1):
                    lists[gy][gx].append(t)
        depth = max(len(c) for row in lists for c in row)
        grid = np.full((_GRID, _GRID, max(depth, 1)), -1, np.int64)
        for gy in range(_GRID):
            for gx in range(_GRID):
                cell = lists[gy][gx]
                grid[gy, gx, :len(cell)] = cell
        self._grid = grid
        self._affine = edge_coefficients(tri_pts, np.zeros((len(tri_pts), 3)))[:, :6]
        self._id_cell = span / _ID_GRID
        ids = rasterize((tri_pts - self._origin) / self._id_cell, None, _ID_GRID, _ID_GRID).tri
        self._ids = ids.ravel()
        # Cells at least two cells away from every triangle are certainly outside.
        self._far = ~cv2.dilate((ids >= 0).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool).ravel()

    def weights(self, vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Interpolation weights for directions ``vectors`` (n, 3) in the tangent frame.

        Returns (indices (n, 3) int64 into ``directions``, weights (n, 3) float64 summing to 1,
        theta_used (n,) degrees of the point actually interpolated -- the query's own theta
        inside the triangulated region, the nearest boundary point's outside it).
        """
        q = project(vectors)
        n = len(q)
        idx = np.zeros((n, 3), np.int64)
        w = np.zeros((n, 3), np.float64)
        inside = np.zeros(n, bool)
        if len(self.triangles):
            far = self._locate_fast(q, idx, w, inside)
            self._locate_exact(q, idx, w, inside, far)
        out = ~inside
        used = np.empty(n)
        used[inside] = np.hypot(q[inside, 0], q[inside, 1]) * 90.0
        if out.any():
            idx[out], w[out], used[out] = self._nearest_on_boundary(q[out])
        return idx, w, used

    def stencil(self, vectors: np.ndarray, eps: float = 1e-6) -> np.ndarray:
        """(N,) bool: the measured directions that some of the query directions ``vectors``
        (n, 3) interpolate from with a weight above ``eps`` -- what a partial asset must keep
        to render those queries as the full set does (:mod:`usdbtf.compress.coverage`)."""
        idx, w, _ = self.weights(vectors)
        used = np.zeros(len(self.directions), bool)
        used[idx[w > eps]] = True
        return used

    def _set(self, sel, tri, bary, idx, w, inside) -> None:
        idx[sel] = self.triangles[tri]
        bary = np.clip(bary, 0.0, None)
        w[sel] = bary / bary.sum(axis=1, keepdims=True)
        inside[sel] = True

    def _locate_fast(self, q, idx, w, inside) -> np.ndarray:
        """First guess from the fine triangle-id raster, kept where its barycentrics confirm it.
        Returns (n,) bool: queries certainly outside every triangle."""
        cell = np.floor((q - self._origin) / self._id_cell).astype(np.int64)
        ok = ((cell >= 0) & (cell < _ID_GRID)).all(axis=1)
        sel = np.flatnonzero(ok)
        flat = cell[sel, 1] * _ID_GRID + cell[sel, 0]
        tri = self._ids[flat]
        far = np.zeros(len(q), bool)
        far[~ok] = True
        far[sel[self._far[flat]]] = True
        sel, tri = sel[tri >= 0], tri[tri >= 0]
        c = self._affine[tri]
        w0 = c[:, 0] * q[sel, 0] + c[:, 1] * q[sel, 1] + c[:, 2]
        w1 = c[:, 3] * q[sel, 0] + c[:, 4] * q[sel, 1] + c[:, 5]
        bary = np.stack([w0, w1, 1.0 - w0 - w1], axis=1)
        good = bary.min(axis=1) >= -_INSIDE_EPS
        self._set(sel[good], tri[good], bary[good], idx, w, inside)
        return far

    def _locate_exact(self, q, idx, w, inside, far) -> None:
        """The rest (not certainly outside): best of the triangles overlapping the query's coarse cell."""
        sel = np.flatnonzero(~inside & ~far)
        if not len(sel):
            return
        cell = np.floor((q[sel] - self._origin) / self._cell).astype(int)
        in_grid = ((cell >= 0) & (cell < _GRID)).all(axis=1)
        cand = np.full((len(sel), self._grid.shape[2]), -1, np.int64)
        cand[in_grid] = self._grid[cell[in_grid, 1], cell[in_grid, 0]]
        t = np.maximum(cand, 0)
        c = self._affine[t]                                                   # (m, K, 6)
        qx, qy = q[sel, 0][:, None], q[sel, 1][:, None]
        w0 = c[..., 0] * qx + c[..., 1] * qy + c[..., 2]
        w1 = c[..., 3] * qx + c[..., 4] * qy + c[..., 5]
        bary = np.stack([w0, w1, 1.0 - w0 - w1], axis=2)
        score = np.where(cand >= 0, bary.min(axis=2), -np.inf)
        best = np.argmax(score, axis=1)
        rows = np.arange(len(sel))
        good = score[rows, best] >= -_INSIDE_EPS
        self._set(sel[good], t[rows, best][good], bary[rows, best][good], idx, w, inside)

    def _nearest_on_boundary(self, q: np.ndarray):
        if len(self.boundary) == 0:                                         # a single direction
            return (np.zeros((len(q), 3), np.int64), np.tile([1.0, 0.0, 0.0], (len(q), 1)),
                    np.full(len(q), np.hypot(*self.points[0]) * 90.0))
        a = self.points[self.boundary[:, 0]]
        b = self.points[self.boundary[:, 1]]
        ab = b - a
        t = np.einsum("nek,ek->ne", q[:, None, :] - a[None], ab) / np.einsum("ek,ek->e", ab, ab)
        t = t.clip(0.0, 1.0)
        nearest = a[None] + t[..., None] * ab[None]
        d2 = np.einsum("nek,nek->ne", q[:, None] - nearest, q[:, None] - nearest)
        e = np.argmin(d2, axis=1)
        rows = np.arange(len(q))
        te = t[rows, e]
        idx = np.zeros((len(q), 3), np.int64)
        idx[:, 0], idx[:, 1] = self.boundary[e, 0], self.boundary[e, 1]
        w = np.stack([1.0 - te, te, np.zeros_like(te)], axis=1)
        p = nearest[rows, e]
        return idx, w, np.hypot(p[:, 0], p[:, 1]) * 90.0


def _delaunay(pts: np.ndarray) -> np.ndarray:
    """(M, 3) counter-clockwise triangles of the Delaunay triangulation of pts (N, 2)."""
    sub = cv2.Subdiv2D((-3 * int(_SCALE), -3 * int(_SCALE), 6 * int(_SCALE), 6 * int(_SCALE)))
    scaled = pts * _SCALE
    for x, y in scaled:
        sub.insert((float(x), float(y)))
    # No triangle (two directions): OpenCV returns an empty tuple, not an empty array.
    flat = np.asarray(sub.getTriangleList(), np.float64).reshape(-1, 3, 2)
    # Map corners back to input indices (Subdiv2D keeps float32 copies of the points).
    d = np.linalg.norm(flat[:, :, None, :] - scaled[None, None].astype(np.float32), axis=3)
    tris = np.argmin(d, axis=2)
    ok = d.min(axis=2).max(axis=1) < 1e-3 * _SCALE
    tris = tris[ok]
    p = pts[tris]
    area = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])
    keep = np.abs(area) > 1e-12
    tris, area = tris[keep], area[keep]
    tris[area < 0] = tris[area < 0][:, [0, 2, 1]]
    tris = np.unique(np.sort(tris, axis=1), axis=0)                 # canonical order: deterministic
    p = pts[tris]
    area = (p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 2, 0] - p[:, 0, 0]) * (p[:, 1, 1] - p[:, 0, 1])
    tris[area < 0] = tris[area < 0][:, [0, 2, 1]]
    return tris.astype(np.int64)


def _boundary_edges(tris: np.ndarray) -> np.ndarray:
    """Edges used by exactly one triangle."""
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    key = np.sort(edges, axis=1)
    uniq, counts = np.unique(key, axis=0, return_counts=True)
    return uniq[counts == 1]
