"""A vectorised triangle rasteriser: which triangle covers each pixel centre, nearest first.

Coordinates are pixels: x to the right, y down, pixel (i, j) has its centre at
(j + 0.5, i + 0.5).  A pixel is covered by a triangle when its centre lies inside or on an
edge (both windings are accepted; callers cull by passing only the triangles they want).
Depth is any value linear in screen space per triangle (e.g. -1/w for a perspective camera,
z for an orthographic one); the smaller wins, ties go to the lower triangle index, so the
result is deterministic.

How: every triangle's bounding box is enumerated as candidate pixels (in chunks of at most
``max_fragments``), edge functions select the covered ones, and one ``np.minimum.at`` over a
64-bit key ``(depth bits, triangle index)`` resolves visibility.  Used for camera views,
shadow maps and texture-space (atlas) coverage.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Raster", "rasterize", "barycentrics", "pixel_barycentrics", "edge_coefficients", "st_to_texels"]

_EMPTY = np.iinfo(np.int64).max
_TRI_BITS = 31


@dataclass
class Raster:
    """tri : (H, W) int32 covering triangle index, -1 where none.  depth : (H, W) float32
    depth of the covering triangle at the pixel centre (+inf where none)."""

    tri: np.ndarray
    depth: np.ndarray


def _ordered_bits(z: np.ndarray) -> np.ndarray:
    """float32 -> int64 in [0, 2^32) with the same order (IEEE bit trick)."""
    bits = z.astype(np.float32).view(np.int32).astype(np.int64)
    return np.where(bits >= 0, bits, bits ^ 0x7FFFFFFF) + 2**31


def barycentrics(tri_xy: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n, 3) screen-space barycentric coordinates of points (x, y) in triangles tri_xy (n, 3, 2).

    Degenerate triangles give NaN.
    """
    x0, y0 = tri_xy[:, 0, 0], tri_xy[:, 0, 1]
    x1, y1 = tri_xy[:, 1, 0], tri_xy[:, 1, 1]
    x2, y2 = tri_xy[:, 2, 0], tri_xy[:, 2, 1]
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / area
        w0 = ((x2 - x1) * (y - y1) - (y2 - y1) * (x - x1)) * inv
        w1 = ((x0 - x2) * (y - y2) - (y0 - y2) * (x - x2)) * inv
        return np.stack([w0, w1, 1.0 - w0 - w1], axis=-1)


def edge_coefficients(tri_xy: np.ndarray, tri_z: np.ndarray) -> np.ndarray:
    """(T, 9) per triangle: w0 = a0 x + b0 y + c0, w1 = a1 x + b1 y + c1 (barycentrics of vertices
    0 and 1) and depth z = az x + bz y + cz, all affine in the pixel coordinates.  NaN for
    degenerate triangles."""
    x0, y0 = tri_xy[:, 0, 0], tri_xy[:, 0, 1]
    x1, y1 = tri_xy[:, 1, 0], tri_xy[:, 1, 1]
    x2, y2 = tri_xy[:, 2, 0], tri_xy[:, 2, 1]
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(area != 0, 1.0 / area, np.nan)
        a0, b0 = -(y2 - y1) * inv, (x2 - x1) * inv
        c0 = -(a0 * x1 + b0 * y1)
        a1, b1 = -(y0 - y2) * inv, (x0 - x2) * inv
        c1 = -(a1 * x2 + b1 * y2)
        dz0, dz1, z2 = tri_z[:, 0] - tri_z[:, 2], tri_z[:, 1] - tri_z[:, 2], tri_z[:, 2]
        az, bz, cz = a0 * dz0 + a1 * dz1, b0 * dz0 + b1 * dz1, c0 * dz0 + c1 * dz1 + z2
    return np.stack([a0, b0, c0, a1, b1, c1, az, bz, cz], axis=1)


def rasterize(tri_xy: np.ndarray, tri_z: np.ndarray | None, width: int, height: int, *,
              max_fragments: int = 1 << 21, depth: bool = False) -> Raster:
    """Rasterise triangles tri_xy (T, 3, 2) pixels with depths tri_z (T, 3) (None: all 0).

    ``depth`` : also fill ``Raster.depth`` (else it is left +inf)."""
    tri_xy = np.asarray(tri_xy, np.float64)
    T = len(tri_xy)
    tri_z = np.zeros((T, 3)) if tri_z is None else np.asarray(tri_z, np.float64)
    buf = np.full(width * height, _EMPTY, np.int64)
    coef = edge_coefficients(tri_xy, tri_z) if T else np.zeros((0, 9))
    if T:
        y_lo = np.ceil(tri_xy[:, :, 1].min(axis=1) - 0.5)                  # first row whose centre >= min
        y_hi = np.floor(tri_xy[:, :, 1].max(axis=1) - 0.5)
        finite = np.isfinite(coef).all(axis=1) & np.isfinite(y_lo) & np.isfinite(y_hi)
        y_lo = np.maximum(np.where(finite, y_lo, 0), 0).astype(np.int64)
        y_hi = np.minimum(np.where(finite, y_hi, -1), height - 1).astype(np.int64)
        rows = (y_hi - y_lo + 1).clip(0)
        ends = np.cumsum(rows)
        # Chunks of triangles with at most ~max_fragments / 16 scanlines each (spans are short).
        budget = max(1, max_fragments // 16)
        start = 0
        while start < T:
            base = ends[start] - rows[start]
            stop = max(start + 1, int(np.searchsorted(ends, base + budget, side="right")))
            _rasterize_rows(coef, np.arange(start, stop), y_lo, rows, tri_xy, width, buf)
            start = stop
    covered = buf != _EMPTY
    tri = np.where(covered, buf & ((1 << _TRI_BITS) - 1), -1).astype(np.int32)
    raster = Raster(tri.reshape(height, width), np.full((height, width), np.inf, np.float32))
    if depth and covered.any():
        idx = np.flatnonzero(covered)
        y, x = np.divmod(idx, width)
        c = coef[tri[idx]]
        raster.depth.ravel()[idx] = c[:, 6] * (x + 0.5) + c[:, 7] * (y + 0.5) + c[:, 8]
    return raster


def _rasterize_rows(coef, tris, y_lo, rows, tri_xy, width, buf) -> None:
    """Scanline spans: on each pixel row a triangle covers one run of pixel centres, found from
    its three edge half-planes ``w_i(x) = a_i x + (b_i y + c_i) >= 0``; only those are visited."""
    n = rows[tris]
    if int(n.sum()) == 0:
        return
    rep = np.repeat(tris, n)
    py = y_lo[rep] + (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n))
    y = py + 0.5
    c = coef[rep]
    a = np.stack([c[:, 0], c[:, 3], -c[:, 0] - c[:, 3]], axis=1)                  # w2 = 1 - w0 - w1
    s = np.stack([c[:, 1] * y + c[:, 2], c[:, 4] * y + c[:, 5], 1.0 - (c[:, 1] + c[:, 4]) * y - c[:, 2] - c[:, 5]],
                 axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = -s / a
    lo = np.where(a > 0, bound, -np.inf).max(axis=1)
    hi = np.where(a < 0, bound, np.inf).min(axis=1)
    empty = ((a == 0) & (s < 0)).any(axis=1)
    x_min = tri_xy[rep, :, 0].min(axis=1)
    x_max = tri_xy[rep, :, 0].max(axis=1)
    # Widened by a hair: the exact test below decides centres on an edge (no cracks between
    # neighbours from rounding in the bounds).
    j_lo = np.ceil(np.maximum(lo, x_min - 1.0) - 0.5 - 1e-6)
    j_hi = np.floor(np.minimum(hi, x_max + 1.0) - 0.5 + 1e-6)
    j_lo = np.maximum(j_lo, 0).astype(np.int64)
    j_hi = np.minimum(j_hi, width - 1).astype(np.int64)
    span = np.where(empty, 0, j_hi - j_lo + 1).clip(0)
    total = int(span.sum())
    if total == 0:
        return
    run = np.repeat(np.arange(len(rep)), span)
    px = j_lo[run] + (np.arange(total) - np.repeat(np.cumsum(span) - span, span))
    cr = c[run]
    x = px + 0.5
    yy = y[run]
    # Re-check the centres exactly (a span end can be off by rounding).
    w0 = cr[:, 0] * x + cr[:, 1] * yy + cr[:, 2]
    w1 = cr[:, 3] * x + cr[:, 4] * yy + cr[:, 5]
    inside = (w0 >= 0) & (w1 >= 0) & (w0 + w1 <= 1)
    z = cr[inside, 6] * x[inside] + cr[inside, 7] * yy[inside] + cr[inside, 8]
    key = (_ordered_bits(z) << _TRI_BITS) | rep[run[inside]]
    np.minimum.at(buf, py[run[inside]] * width + px[inside], key)


def pixel_barycentrics(tri_xy: np.ndarray, tri_map: np.ndarray):
    """For covered pixels of ``tri_map`` (H, W): flat pixel indices (n,), triangle ids (n,) and
    screen-space barycentrics (n, 3) at the pixel centres."""
    W = tri_map.shape[1]
    idx = np.flatnonzero(tri_map.ravel() >= 0)
    t = tri_map.ravel()[idx].astype(np.int64)
    y, x = np.divmod(idx, W)
    return idx, t, barycentrics(np.asarray(tri_xy, np.float64)[t], x + 0.5, y + 0.5)


def st_to_texels(st: np.ndarray, width: int, height: int) -> np.ndarray:
    """Texture coordinates (..., 2) (USD st: s right, t up, [0, 1] over the image) -> texel
    coordinates (..., 2) of a ``width`` x ``height`` image in this module's convention
    (x right, y down, texel (i, j) centred at (j + 0.5, i + 0.5))."""
    return np.stack([st[..., 0] * width, (1.0 - st[..., 1]) * height], axis=-1)

