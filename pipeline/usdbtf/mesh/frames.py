"""Per-vertex tangent frames that agree with the rectified sample's axes.

The BTF's local frame is x = image right, y = image up, z = surface normal.  On a mesh with
texture coordinates (s right, t up) the image axes are the surface directions in which s
and t grow: per triangle ``dP/ds`` and ``dP/dt`` from its corners, accumulated per vertex
(area weighted), then ``tangent = dP/ds`` made perpendicular to the normal and
``bitangent = normal x tangent``, negated where the texture is mirrored (dP/dt points the
other way), so (tangent, bitangent, normal) is orthonormal.
"""
from __future__ import annotations

import numpy as np

__all__ = ["tangent_frames", "uv_gradients", "mirrored_faces", "uv_stretch"]


def uv_gradients(points: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per triangle dP/ds and dP/dt, (F, 3) each, and the uv-space signed area (F,).

    points : (F, 3, 3) corner positions; uv : (F, 3, 2) corner texture coordinates.
    Triangles with zero uv area get zero gradients.
    """
    e1, e2 = points[:, 1] - points[:, 0], points[:, 2] - points[:, 0]
    d1, d2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    inv = np.where(np.abs(det) > 1e-300, 1.0 / np.where(det == 0, 1.0, det), 0.0)[:, None]
    ds = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inv
    dt = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inv
    return ds, dt, 0.5 * det


def mirrored_faces(points: np.ndarray, faces: np.ndarray, uv: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(F,) bool: triangles whose texture is mirrored relative to the surface normal."""
    ds, dt, _ = uv_gradients(points[faces], uv[faces])
    n = normals[faces].sum(axis=1)
    return np.einsum("fd,fd->f", np.cross(ds, dt), n) < 0


def tangent_frames(points: np.ndarray, faces: np.ndarray, uv: np.ndarray, normals: np.ndarray):
    """(tangents, bitangents), each (N, 3) unit, for vertices ``points`` (N, 3) of triangles
    ``faces`` (F, 3) with texture coordinates ``uv`` (N, 2) and unit ``normals`` (N, 3)."""
    p = points[faces]
    ds, dt, _ = uv_gradients(p, uv[faces])
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    # Weight by triangle area (gradients have units metres per uv unit: normalise first so a
    # triangle's weight does not depend on its uv scale).
    ds_u = ds / np.maximum(np.linalg.norm(ds, axis=1, keepdims=True), 1e-300) * area[:, None]
    dt_u = dt / np.maximum(np.linalg.norm(dt, axis=1, keepdims=True), 1e-300) * area[:, None]
    t_acc = np.zeros_like(points, dtype=np.float64)
    b_acc = np.zeros_like(points, dtype=np.float64)
    for corner in range(3):
        np.add.at(t_acc, faces[:, corner], ds_u)
        np.add.at(b_acc, faces[:, corner], dt_u)
    n = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    t = t_acc - n * np.einsum("nd,nd->n", t_acc, n)[:, None]
    bad = np.linalg.norm(t, axis=1) < 1e-12
    if bad.any():          # no usable s direction (degenerate uv): any tangent perpendicular to n
        helper = np.where(np.abs(n[bad, 0:1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        t[bad] = helper - n[bad] * np.einsum("nd,nd->n", helper, n[bad])[:, None]
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    b = np.cross(n, t)
    b *= np.where(np.einsum("nd,nd->n", b, b_acc) < 0, -1.0, 1.0)[:, None]
    return t, b


def uv_stretch(mesh, width: int = 1, height: int = 1) -> float | None:
    """Area-weighted mean over triangles of the ratio of the largest to the smallest texel
    density direction (singular values of the metres -> texels map in the triangle's plane):
    1 for UVs that keep shapes, 1.5 for a 0.6 x 0.4 m quad on the UV square.  The area-based
    density alone cannot see this.  None without UVs.

    mesh : a :class:`~usdbtf.mesh.Mesh` (points in metres, ``uv`` per vertex or per corner).
    width, height : the texture's texels (the UV square's aspect; any scale gives the same
    ratio, so the defaults measure the UVs themselves)."""
    if mesh.uv is None:
        return None
    p = mesh.corner()                                              # (F, 3, 3) metres
    t = mesh.corner(mesh.uv) * np.array([width, height], np.float64)  # (F, 3, 2) texels
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    l1 = np.linalg.norm(d1, axis=1)
    area2 = np.linalg.norm(np.cross(d1, d2), axis=1)
    keep = (l1 > 0) & (area2 > 0)
    e1 = d1[keep] / l1[keep, None]
    q = np.stack([np.stack([l1[keep], np.zeros(keep.sum())], axis=1),
                  np.stack([(d2[keep] * e1).sum(axis=1), area2[keep] / l1[keep]], axis=1)], axis=2)  # (F, 2, 2)
    tt = np.stack([t[keep, 1] - t[keep, 0], t[keep, 2] - t[keep, 0]], axis=2)                          # (F, 2, 2)
    det = np.linalg.det(tt)
    ok = np.abs(det) > 0
    if not ok.any():
        return None
    sv = np.linalg.svd(tt[ok] @ np.linalg.inv(q[ok]), compute_uv=False)                             # (F, 2)
    weights = area2[keep][ok]
    return float((sv[:, 0] / sv[:, 1] * weights).sum() / weights.sum())
