"""Geometry for packaged assets: the swatch quad, meshes from files, authoring UsdGeom.Mesh.

A BTF is evaluated in the texture's tangent frame (x = +u, y = +v, z = normal), so a
mesh must carry texture coordinates ``st``; tangents/bitangents are copied when the
source has them (``usdbtf unwrap`` writes them).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import BTFError

TRIMESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


@dataclass
class MeshData:
    """A polygon mesh in metres.

    points : (N, 3) float32.  counts : (F,) int32 vertices per face.  indices : (sum counts,) int32.
    st : (M, 2) float32 texture coordinates, ``st_interpolation`` "vertex" (M = N) or
    "faceVarying" (M = len(indices)).  ``primvars``: other per-vertex/face-varying arrays
    to copy (name -> (values, interpolation)), e.g. normals, tangents, bitangents.
    """

    name: str
    points: np.ndarray
    counts: np.ndarray
    indices: np.ndarray
    st: np.ndarray
    st_interpolation: str = "vertex"
    normals: tuple | None = None
    primvars: dict = field(default_factory=dict)

    def extent(self) -> np.ndarray:
        return np.stack([self.points.min(axis=0), self.points.max(axis=0)])


def swatch(width_m: float, height_m: float) -> MeshData:
    """A quad of the tile's physical size in the XY plane, facing +Z, centred on the origin.

    Its texture axes are the sample's: +u along +X (image right), +v along +Y (image up).
    """
    w, h = width_m / 2.0, height_m / 2.0
    points = np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]], np.float32)
    st = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    ones = np.ones((4, 3), np.float32)
    return MeshData("swatch", points, np.array([4], np.int32), np.arange(4, dtype=np.int32), st,
                    normals=(ones * [0, 0, 1], "vertex"),
                    primvars={"tangents": (ones * [1, 0, 0], "vertex"), "bitangents": (ones * [0, 1, 0], "vertex")})


def load_mesh(path) -> MeshData:
    """A mesh with texture coordinates from OBJ/PLY/STL/GLB (trimesh) or a USD file."""
    from .read import usd_exists

    path = Path(path)
    suffix = path.suffix.lower()
    if not (path.is_file() or usd_exists(path)):       # USD files are found through the asset resolver
        raise BTFError(f"{path}: mesh file not found")
    if suffix in USD_SUFFIXES:
        return _load_usd_mesh(path)
    if suffix in TRIMESH_SUFFIXES:
        return _load_trimesh(path)
    raise BTFError(f"{path}: unknown mesh type {suffix!r} (OBJ, PLY, STL, GLB or USD)")


def _no_uv(path) -> BTFError:
    return BTFError(f"{path}: mesh has no texture coordinates; run `usdbtf unwrap {path}` first")


def _load_trimesh(path: Path) -> MeshData:
    import trimesh

    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise BTFError(f"{path}: cannot read mesh ({' '.join(str(exc).split())})") from None
    if not len(mesh.faces):
        raise BTFError(f"{path}: mesh has no faces")
    uv = getattr(mesh.visual, "uv", None)
    if uv is None or len(uv) != len(mesh.vertices):
        raise _no_uv(path)
    faces = np.asarray(mesh.faces, np.int32)
    return MeshData(path.stem, np.asarray(mesh.vertices, np.float32), np.full(len(faces), 3, np.int32),
                    faces.ravel(), np.asarray(uv, np.float32),
                    normals=(np.asarray(mesh.vertex_normals, np.float32), "vertex"))


def _load_usd_mesh(path: Path) -> MeshData:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise BTFError(f"{path}: cannot open USD layer")
    meshes = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)]
    if not meshes:
        raise BTFError(f"{path}: contains no Mesh prim")
    prim = meshes[0]
    mesh = UsdGeom.Mesh(prim)
    xf = np.asarray(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.Default()), np.float64)
    scale = UsdGeom.GetStageMetersPerUnit(stage)
    points = np.asarray(mesh.GetPointsAttr().Get(), np.float64)
    points = (np.c_[points, np.ones(len(points))] @ xf)[:, :3] * scale
    api = UsdGeom.PrimvarsAPI(prim)
    st = api.GetPrimvar("st")
    if not st or not st.HasValue():
        raise _no_uv(path)
    linear = xf[:3, :3]

    def flat(pv):
        """Primvar values with indices expanded."""
        return np.asarray(pv.ComputeFlattened(), np.float32)

    def direction(values):
        v = np.asarray(values, np.float64) @ linear
        return (v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)).astype(np.float32)

    normals = None
    if mesh.GetNormalsAttr().HasValue():
        normals = (direction(mesh.GetNormalsAttr().Get()), mesh.GetNormalsInterpolation())
    extra = {}
    for name in ("tangents", "bitangents"):
        pv = api.GetPrimvar(name)
        if pv and pv.HasValue():
            extra[name] = (direction(flat(pv)), pv.GetInterpolation())
    return MeshData(prim.GetName(), points.astype(np.float32), np.asarray(mesh.GetFaceVertexCountsAttr().Get(), np.int32),
                    np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), np.int32), flat(st), st.GetInterpolation(),
                    normals=normals, primvars=extra)


def author_mesh(stage, path: str, mesh: MeshData):
    """Define a UsdGeom.Mesh at ``path`` from ``mesh``; returns the prim."""
    from pxr import Sdf, UsdGeom, Vt

    geom = UsdGeom.Mesh.Define(stage, path)
    geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(mesh.points, np.float32)))
    geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(mesh.counts, np.int32)))
    geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.ascontiguousarray(mesh.indices, np.int32)))
    geom.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(mesh.extent().astype(np.float32)))
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    geom.CreateDoubleSidedAttr(False)
    if mesh.normals is not None:
        geom.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(mesh.normals[0], np.float32)))
        geom.SetNormalsInterpolation(mesh.normals[1])
    api = UsdGeom.PrimvarsAPI(geom)
    st = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, mesh.st_interpolation)
    st.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(mesh.st, np.float32)))
    for name, (values, interp) in sorted(mesh.primvars.items()):
        pv = api.CreatePrimvar(name, Sdf.ValueTypeNames.Vector3fArray, interp)
        pv.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(values, np.float32)))
    return geom.GetPrim()
