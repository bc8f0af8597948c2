"""Reading meshes: OBJ/PLY/STL/GLB/glTF/OFF through trimesh, USD through pxr, one :class:`Mesh` out.

Everything comes out in metres, world space, as one triangle list (polygons fan-triangulated,
every Mesh prim of a USD stage with its world transform and the stage's metersPerUnit), with
what the file holds of texture coordinates, normals and, for USD, ``tangents``/``bitangents``
primvars and ``usdbtf:chart`` (so the layer ``usdbtf unwrap`` writes reads back with its
frames and charts).  Values stay per vertex or per corner as the file has them.

Checks (each a :class:`~usdbtf.errors.BTFError` naming the file, and the prim for USD):
missing or unreadable files, USD syntax and composition errors, no faces, NaN or infinite
points, normals or texture coordinates, indices out of range, primvars whose size does not
match their interpolation.  Degenerate triangles (repeated or collinear corners: no area, no
normal) are *dropped*, with a note in :attr:`Mesh.notes`; a mesh with nothing left is an
error.  File normals of zero length are replaced by computed ones (a note says so).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import BTFError, UsageError
from ..usdstage import USD_SUFFIXES, open_usd, usd_exists, usd_warnings_silenced
from .model import Mesh

__all__ = ["load_mesh", "load_prim", "MESH_SUFFIXES", "TRIMESH_SUFFIXES", "USD_SUFFIXES"]

TRIMESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
#: Every file type :func:`load_mesh` reads.
MESH_SUFFIXES = TRIMESH_SUFFIXES + USD_SUFFIXES
_KINDS = "OBJ, PLY, STL, GLB/glTF, OFF or USD"


def load_mesh(path, *, meters_per_unit: float | None = None, up_axis: str | None = None,
              need_uv: bool = False) -> Mesh:
    """Read the mesh in ``path`` (see the module docstring).

    Parameters
    ----------
    path : mesh file, one of :data:`MESH_SUFFIXES`.
    meters_per_unit : overrides the file's unit (USD declares one; other formats are taken
        as metres).
    up_axis : "Y" or "Z", overrides the declared (USD) or assumed ("Y") up axis.
    need_uv : raise BTFError when the mesh has no texture coordinates.
    """
    path = Path(path)
    if meters_per_unit is not None and not (np.isfinite(meters_per_unit) and meters_per_unit > 0):
        raise UsageError(f"--meters-per-unit must be a positive number, got {meters_per_unit}")
    if up_axis is not None and up_axis not in ("Y", "Z"):
        raise UsageError(f"--up-axis must be Y or Z, got {up_axis!r}")
    if not (path.is_file() or usd_exists(path)):       # USD files are found through the asset resolver
        raise BTFError(f"{path}: mesh file not found")
    suffix = path.suffix.lower()
    if suffix in USD_SUFFIXES:
        mesh = _load_usd(path, meters_per_unit)
    elif suffix in TRIMESH_SUFFIXES:
        mesh = _load_trimesh(path, meters_per_unit)
    else:
        raise BTFError(f"{path}: unknown mesh type {suffix!r} ({_KINDS})")
    if up_axis is not None:
        mesh.up_axis = up_axis
    mesh = mesh.without_degenerate()
    if need_uv:
        mesh.require_uv()
    return mesh


def _checked_normals(normals: np.ndarray | None) -> tuple[np.ndarray | None, tuple]:
    """File normals, or None (with a note) when some have zero length: those are recomputed.
    (NaN or infinite ones are an error of :class:`Mesh`.)"""
    if normals is None:
        return None, ()
    if (np.linalg.norm(normals.reshape(-1, 3), axis=1) == 0).any():
        return None, ("the file's normals include zero-length ones: computed smooth normals instead",)
    return normals, ()


def _load_trimesh(path: Path, meters_per_unit) -> Mesh:
    import trimesh

    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
    except Exception as exc:       # trimesh raises many exception types for corrupt files
        raise BTFError(f"{path}: cannot read mesh ({' '.join(str(exc).split())[:200]})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise BTFError(f"{path}: no triangle mesh in the file")
    points = np.asarray(mesh.vertices, np.float64) * (meters_per_unit or 1.0)
    faces = np.asarray(mesh.faces, np.int64)
    uv = getattr(mesh.visual, "uv", None)
    uv = np.asarray(uv, np.float64) if uv is not None and len(uv) == len(points) else None
    # The file's normals when it has them (hard edges stay hard); without, the users compute
    # smooth area-weighted ones (trimesh's own computation wants scipy).
    cache = getattr(mesh, "_cache", None)
    from_file = cache is not None and "vertex_normals" in cache
    normals, notes = _checked_normals(np.asarray(mesh.vertex_normals, np.float64) if from_file else None)
    return Mesh(points, faces, uv=uv, normals=normals, name=path.stem, source=str(path),
                metres_per_unit=float(meters_per_unit or 1.0), notes=notes)


def _load_usd(path: Path, meters_per_unit) -> Mesh:
    from pxr import UsdGeom

    with usd_warnings_silenced():         # open_usd reports what matters as one error
        stage = open_usd(path)
    scale = float(meters_per_unit or UsdGeom.GetStageMetersPerUnit(stage))
    cache = UsdGeom.XformCache()
    parts = [_usd_mesh(prim, cache, scale, path) for prim in stage.Traverse() if prim.IsA(UsdGeom.Mesh)]
    if not parts:
        raise BTFError(f"{path}: contains no Mesh prim")
    default = stage.GetDefaultPrim()
    name = (default.GetName() if default else "") or path.stem
    return Mesh.concatenate(parts, name=name, source=str(path), metres_per_unit=scale,
                            up_axis=str(UsdGeom.GetStageUpAxis(stage)))


def load_prim(prim, time=None) -> Mesh:
    """One Mesh prim of an open stage as a :class:`Mesh` in world space (metres) at ``time``
    (a time code; default the default time), degenerate triangles dropped, as
    :func:`load_mesh` reads each prim of a USD file."""
    from pxr import Usd, UsdGeom

    stage = prim.GetStage()
    scale = float(UsdGeom.GetStageMetersPerUnit(stage))
    code = Usd.TimeCode.Default() if time is None else Usd.TimeCode(time)
    return _usd_mesh(prim, UsdGeom.XformCache(code), scale, Path(stage.GetRootLayer().identifier),
                     code).without_degenerate()


def _usd_mesh(prim, cache, scale: float, path: Path, code=None) -> Mesh:
    """One Mesh prim in world space (metres) at time ``code`` (default: the default time),
    polygons fan-triangulated."""
    from pxr import Usd, UsdGeom

    code = Usd.TimeCode.Default() if code is None else code
    where = f"{path}: {prim.GetPath()}"
    mesh = UsdGeom.Mesh(prim)
    pts = np.asarray(mesh.GetPointsAttr().Get(code) or [], np.float64).reshape(-1, 3)
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(code) or [], np.int64)
    indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(code) or [], np.int64)
    if len(pts) == 0 or len(counts) == 0 or counts.sum() != len(indices) or (counts < 3).any():
        raise BTFError(f"{where} has no valid faces (empty, or face sizes and indices disagree)")
    xf = np.asarray(cache.GetLocalToWorldTransform(prim), np.float64)
    identity = np.array_equal(xf, np.eye(4))
    if not identity:
        pts = (np.c_[pts, np.ones(len(pts))] @ xf)[:, :3]
    pts = pts * scale
    # Fan-triangulate each polygon over its face-vertex corners.
    starts = np.cumsum(counts) - counts
    fan = np.concatenate([np.stack([np.full(c - 2, s), s + np.arange(1, c - 1), s + np.arange(2, c)], axis=1)
                          for s, c in zip(starts, counts)])                     # (F, 3) face-vertex ids
    face_of = np.repeat(np.arange(len(counts)), counts - 2)                     # (F,) polygon per triangle

    def per_element(values, interpolation, name):
        """Primvar values as per vertex (N, k) or per triangle corner (F, 3, k); None if unusable."""
        if interpolation in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying) and len(values) == len(pts):
            return values
        if interpolation == UsdGeom.Tokens.faceVarying and len(values) == len(indices):
            return values[fan]
        if interpolation == UsdGeom.Tokens.uniform and len(values) == len(counts):
            return np.repeat(values[face_of][:, None], 3, axis=1)
        if interpolation == UsdGeom.Tokens.constant and len(values) == 1:
            return np.repeat(values, len(pts), axis=0)
        raise BTFError(f"{where}: {name} has {len(values)} values, which does not fit {interpolation} "
                       f"interpolation ({len(pts)} points, {len(counts)} faces, {len(indices)} face-vertices)")

    api = UsdGeom.PrimvarsAPI(prim)

    def primvar(name, width):
        pv = api.GetPrimvar(name)
        if not (pv and pv.HasValue()):
            return None
        values = np.asarray(pv.ComputeFlattened(code), np.float64).reshape(-1, width)
        return per_element(values, pv.GetInterpolation(), f"primvars:{name}")

    linear = xf[:3, :3]

    def directions(values, matrix):
        """Unit vectors through ``matrix`` (row vectors); untouched when the prim is not moved."""
        if values is None or identity:
            return values
        v = values @ matrix
        return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)

    normals, notes = None, ()
    if mesh.GetNormalsAttr().HasValue():
        values = np.asarray(mesh.GetNormalsAttr().Get(code), np.float64).reshape(-1, 3)
        normals, notes = _checked_normals(per_element(values, mesh.GetNormalsInterpolation(), "normals"))
    elif api.HasPrimvar("normals"):
        normals, notes = _checked_normals(primvar("normals", 3))
    # Normals transform with the inverse transpose, surface directions with the matrix itself.
    normal_matrix = np.linalg.inv(linear).T if not identity and abs(np.linalg.det(linear)) > 0 else linear
    charts = api.GetPrimvar("usdbtf:chart")
    chart_ids = None
    if charts and charts.HasValue():
        values = np.asarray(charts.ComputeFlattened(), np.int64)
        if charts.GetInterpolation() != UsdGeom.Tokens.uniform or len(values) != len(counts) or \
                (len(values) and values.min() < 0):
            raise BTFError(f"{where}: primvars:usdbtf:chart must hold one chart index >= 0 per face")
        chart_ids = values[face_of]
    return Mesh(pts, indices[fan], uv=primvar("st", 2), normals=directions(normals, normal_matrix),
                tangents=directions(primvar("tangents", 3), linear),
                bitangents=directions(primvar("bitangents", 3), linear), charts=chart_ids,
                face_sizes=counts, name=prim.GetName(), source=where, notes=notes)
