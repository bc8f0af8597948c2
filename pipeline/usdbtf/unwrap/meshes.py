"""Triangle meshes from files: OBJ/PLY/STL/GLB/glTF/OFF through trimesh, USD through pxr.

Everything comes out in metres, as one triangle list (polygons fan-triangulated, every Mesh
prim of a USD stage with its world transform), with per-vertex normals and, when the file
has them, per-vertex texture coordinates (USD face-varying st is split into vertices).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BTFError

__all__ = ["TriMesh", "load_mesh", "MESH_SUFFIXES", "USD_SUFFIXES", "vertex_normals", "weld"]

TRIMESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
MESH_SUFFIXES = TRIMESH_SUFFIXES + USD_SUFFIXES


@dataclass
class TriMesh:
    """points (N, 3) float64 metres; faces (F, 3) int64; normals (N, 3) unit; uv (N, 2) or None
    (st, t up); up_axis "Y" or "Z" (what the source declared or was assumed)."""

    name: str
    points: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    uv: np.ndarray | None = None
    up_axis: str = "Y"

    def area(self) -> float:
        p = self.points[self.faces]
        return float(0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum())


def weld(points: np.ndarray, decimals: int = 9) -> np.ndarray:
    """(N,) id per vertex, equal for vertices at the same position (topology across split seams)."""
    _, inverse = np.unique(np.round(points, decimals), axis=0, return_inverse=True)
    return inverse.ravel()


def vertex_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(N, 3) area-weighted vertex normals, smooth across vertices split at the same position."""
    p = points[faces]
    face_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])        # length = 2 x area
    ids = weld(points)
    acc = np.zeros((ids.max() + 1, 3))
    for corner in range(3):
        np.add.at(acc, ids[faces[:, corner]], face_n)
    n = acc[ids]
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def _check(name: str, points, faces, path) -> None:
    if len(faces) == 0:
        raise BTFError(f"{path}: mesh has no faces")
    if not np.isfinite(points).all():
        raise BTFError(f"{path}: vertex positions include NaN or Inf")
    if faces.min() < 0 or faces.max() >= len(points):
        raise BTFError(f"{path}: face indices out of range")
    p = points[faces]
    if not np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum() > 0:
        raise BTFError(f"{path}: mesh has zero surface area")


def load_mesh(path, *, meters_per_unit: float | None = None, up_axis: str | None = None) -> TriMesh:
    """Read a mesh.  ``meters_per_unit`` overrides the file's unit (USD declares one; other
    formats are taken as metres); ``up_axis`` overrides the declared/assumed "Y"."""
    from ..usd.read import usd_exists

    path = Path(path)
    if not (path.is_file() or usd_exists(path)):       # USD files are found through the asset resolver
        raise BTFError(f"{path}: mesh file not found")
    suffix = path.suffix.lower()
    if suffix in USD_SUFFIXES:
        mesh = _load_usd(path, meters_per_unit)
    elif suffix in TRIMESH_SUFFIXES:
        mesh = _load_trimesh(path, meters_per_unit)
    else:
        raise BTFError(f"{path}: unknown mesh type {suffix!r} (OBJ, PLY, STL, GLB/glTF, OFF or USD)")
    if up_axis is not None:
        if up_axis not in ("Y", "Z"):
            raise BTFError(f"--up-axis must be Y or Z, got {up_axis!r}")
        mesh.up_axis = up_axis
    _check(mesh.name, mesh.points, mesh.faces, path)
    return mesh


def _load_trimesh(path: Path, meters_per_unit) -> TriMesh:
    import trimesh

    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:       # trimesh raises many exception types for corrupt files
        raise BTFError(f"{path}: cannot read mesh ({' '.join(str(exc).split())[:200]})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise BTFError(f"{path}: no triangle mesh in the file")
    points = np.asarray(mesh.vertices, np.float64) * (meters_per_unit or 1.0)
    faces = np.asarray(mesh.faces, np.int64)
    _check(path.stem, points, faces, path)
    uv = getattr(mesh.visual, "uv", None)
    uv = np.asarray(uv, np.float64) if uv is not None and len(uv) == len(points) else None
    # The file's normals when it has them (hard edges stay hard), else smooth area-weighted ones
    # (trimesh's own computation wants scipy).
    cache = getattr(mesh, "_cache", None)
    from_file = cache is not None and "vertex_normals" in cache
    normals = np.asarray(mesh.vertex_normals, np.float64) if from_file else vertex_normals(points, faces)
    return TriMesh(path.stem, points, faces, normals, uv)


def _load_usd(path: Path, meters_per_unit) -> TriMesh:
    from pxr import Tf, Usd, UsdGeom

    try:
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as exc:
        raise BTFError(f"{path}: cannot open USD layer ({' '.join(str(exc).split())[:200]})") from None
    if stage is None:
        raise BTFError(f"{path}: cannot open USD layer")
    scale = meters_per_unit or UsdGeom.GetStageMetersPerUnit(stage)
    up = str(UsdGeom.GetStageUpAxis(stage))
    parts = []
    cache = UsdGeom.XformCache()
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh):
            parts.append(_usd_mesh_part(prim, cache, scale, path))
    if not parts:
        raise BTFError(f"{path}: contains no Mesh prim")
    offset = np.cumsum([0] + [len(p[0]) for p in parts])
    points = np.concatenate([p[0] for p in parts])
    faces = np.concatenate([p[1] + o for p, o in zip(parts, offset)])
    uv = np.concatenate([p[2] for p in parts]) if all(p[2] is not None for p in parts) else None
    normals = vertex_normals(points, faces)
    name = stage.GetDefaultPrim().GetName() if stage.GetDefaultPrim() else path.stem
    return TriMesh(name or path.stem, points, faces, normals, uv, up)


def _usd_mesh_part(prim, cache, scale, path):
    """(points, faces, uv or None) of one Mesh prim, world space, vertices split per distinct st."""
    from pxr import UsdGeom

    mesh = UsdGeom.Mesh(prim)
    pts = np.asarray(mesh.GetPointsAttr().Get() or [], np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get() or [], np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get() or [], np.int64)
    if len(pts) == 0 or len(counts) == 0 or counts.sum() != len(indices) or (counts < 3).any():
        raise BTFError(f"{path}: {prim.GetPath()} has no valid faces")
    xf = np.asarray(cache.GetLocalToWorldTransform(prim), np.float64)
    pts = (np.c_[pts, np.ones(len(pts))] @ xf)[:, :3] * scale
    # Fan-triangulate each polygon over its corners (face-vertex positions).
    starts = np.cumsum(counts) - counts
    fan = np.concatenate([np.stack([np.full(c - 2, s), s + np.arange(1, c - 1), s + np.arange(2, c)], axis=1)
                          for s, c in zip(starts, counts)])                     # (F, 3) corner ids
    st = UsdGeom.PrimvarsAPI(prim).GetPrimvar("st")
    if st and st.HasValue():
        values = np.asarray(st.ComputeFlattened(), np.float64).reshape(-1, 2)
        interp = st.GetInterpolation()
        if interp == UsdGeom.Tokens.faceVarying and len(values) == len(indices):
            corner_uv = values
        elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) and len(values) == len(pts):
            corner_uv = values[indices]
        else:
            corner_uv = None
        if corner_uv is not None:
            key = np.c_[indices, np.round(corner_uv, 9)]
            _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
            return pts[indices[first]], inverse.ravel()[fan], corner_uv[first]
    return pts, indices[fan], None
