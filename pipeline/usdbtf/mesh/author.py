"""Writing a :class:`~usdbtf.mesh.Mesh` as a ``UsdGeom.Mesh`` (what packaging puts in an asset).

The source's polygons come back (:meth:`Mesh.polygons`), per-vertex attributes as ``vertex``
and per-corner ones as (flattened) ``faceVarying`` primvars: ``st``, ``normals`` and the
``tangents``/``bitangents`` of the BTF frame, so a reader gets the frames the asset was made
with.  ``usdbtf unwrap`` writes its own, indexed layout (:mod:`usdbtf.unwrap.layer`).
"""
from __future__ import annotations

import numpy as np

from .model import Mesh

__all__ = ["author_mesh"]


def _as_primvar(mesh: Mesh, values: np.ndarray, corner_ids: np.ndarray) -> tuple[np.ndarray, str]:
    """(float32 values, interpolation) of one attribute in the authored polygons' layout."""
    if mesh.is_per_corner(values):
        flat = values.reshape(-1, values.shape[-1])[corner_ids]
        return np.ascontiguousarray(flat, np.float32), "faceVarying"
    return np.ascontiguousarray(values, np.float32), "vertex"


def author_mesh(stage, path: str, mesh: Mesh):
    """Define a UsdGeom.Mesh at ``path`` on ``stage`` from ``mesh`` (which must have texture
    coordinates); returns the prim."""
    from pxr import Sdf, UsdGeom, Vt

    mesh.require_uv()
    counts, corner_ids = mesh.polygons()
    points = np.ascontiguousarray(mesh.points, np.float32)
    geom = UsdGeom.Mesh.Define(stage, path)
    geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(points))
    geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(
        mesh.triangles.ravel()[corner_ids], np.int32)))
    geom.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([points.min(axis=0), points.max(axis=0)])))
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    geom.CreateDoubleSidedAttr(False)
    if mesh.normals is not None:
        values, interpolation = _as_primvar(mesh, mesh.normals, corner_ids)
        geom.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(values))
        geom.SetNormalsInterpolation(interpolation)
    api = UsdGeom.PrimvarsAPI(geom)
    values, interpolation = _as_primvar(mesh, mesh.uv, corner_ids)
    api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interpolation).Set(Vt.Vec2fArray.FromNumpy(values))
    for name in ("bitangents", "tangents"):
        if getattr(mesh, name) is not None:
            values, interpolation = _as_primvar(mesh, getattr(mesh, name), corner_ids)
            pv = api.CreatePrimvar(name, Sdf.ValueTypeNames.Vector3fArray, interpolation)
            pv.Set(Vt.Vec3fArray.FromNumpy(values))
    return geom.GetPrim()
