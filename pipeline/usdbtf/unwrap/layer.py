"""The USD geometry layer ``usdbtf unwrap`` writes, and reading it back.

Layout (``mesh.usda``; metersPerUnit 1, the mesh's up axis, defaultPrim = the root)::

    def Xform "<name>" (kind = "component")
        def Mesh "mesh"
            point3f[] points, int[] faceVertexCounts (all 3), faceVertexIndices
            normal3f[] normals                       (vertex)
            texCoord2f[] primvars:st                 (faceVarying, indexed: one value per atlas vertex)
            vector3f[] primvars:tangents/bitangents  (faceVarying, same indices: image right / image up)
            int[] primvars:usdbtf:chart              (uniform: chart per triangle)
            customData usdbtf = {atlas = {width, height, texels_per_metre, texel_scale, padding,
                                          charts, method}, source = "<mesh file>"}

Points stay shared across chart seams (the surface is watertight), the per-chart values are
face-varying.  Packaging references this layer; ``usdbtf quilt --atlas`` and
``usdbtf render --mesh`` read it with :func:`read_layer`.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BTFError
from .atlas import Atlas
from .meshes import TriMesh

__all__ = ["UnwrappedMesh", "write_layer", "read_layer"]


@dataclass
class UnwrappedMesh:
    """A mesh with its atlas, as stored in the layer.

    points (N, 3) metres; faces (F, 3) point indices; normals (N, 3); corner (F, 3) atlas-vertex
    index per triangle corner; st, tangents, bitangents (M, ...) per atlas vertex;
    face_chart (F,); atlas : dict (width, height, texels_per_metre, ...).
    """

    points: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    corner: np.ndarray
    st: np.ndarray
    tangents: np.ndarray
    bitangents: np.ndarray
    face_chart: np.ndarray
    atlas: dict
    up_axis: str = "Y"

    def corner_texels(self) -> np.ndarray:
        """(F, 3, 2) corner positions in atlas texels (x right, y down)."""
        st = self.st[self.corner]
        return np.stack([st[..., 0] * self.atlas["width"], (1.0 - st[..., 1]) * self.atlas["height"]], axis=-1)


def _prim_name(name: str) -> str:
    clean = re.sub(r"[^A-Za-z0-9_]", "_", name) or "mesh"
    return clean if not clean[0].isdigit() else "_" + clean


def write_layer(path, mesh: TriMesh, atlas: Atlas, tangents: np.ndarray, bitangents: np.ndarray, *,
                padding: int, source: str) -> None:
    """Write the geometry layer at ``path`` (a new file; the caller makes it atomic)."""
    from pxr import Kind, Sdf, Usd, UsdGeom, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if mesh.up_axis == "Y" else UsdGeom.Tokens.z)
    root = UsdGeom.Xform.Define(stage, f"/{_prim_name(mesh.name)}")
    Usd.ModelAPI(root.GetPrim()).SetKind(Kind.Tokens.component)
    stage.SetDefaultPrim(root.GetPrim())
    geom = UsdGeom.Mesh.Define(stage, root.GetPath().AppendChild("mesh"))
    pts = mesh.points.astype(np.float32)
    geom.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    geom.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([pts.min(axis=0), pts.max(axis=0)])))
    geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(mesh.faces), 3, np.int32)))
    geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(mesh.faces.astype(np.int32).ravel()))
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    geom.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    geom.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(mesh.normals.astype(np.float32)))
    geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    api = UsdGeom.PrimvarsAPI(geom)
    corner = Vt.IntArray.FromNumpy(atlas.faces.astype(np.int32).ravel())
    st = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray.FromNumpy(atlas.st.astype(np.float32)))
    st.SetIndices(corner)
    for name, values in (("tangents", tangents), ("bitangents", bitangents)):
        pv = api.CreatePrimvar(name, Sdf.ValueTypeNames.Vector3fArray, UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec3fArray.FromNumpy(values.astype(np.float32)))
        pv.SetIndices(corner)
    chart = api.CreatePrimvar("usdbtf:chart", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.uniform)
    chart.Set(Vt.IntArray.FromNumpy(atlas.face_chart.astype(np.int32)))
    info = {"width": atlas.width, "height": atlas.height, "texels_per_metre": atlas.texels_per_metre,
            "texel_scale": atlas.texel_scale, "padding": int(padding), "charts": atlas.charts,
            "method": atlas.method}
    geom.GetPrim().SetCustomDataByKey("usdbtf", {"atlas": info, "source": source})
    stage.GetRootLayer().Save()


def read_layer(path) -> UnwrappedMesh:
    """Read a layer written by :func:`write_layer` (BTFError naming the file if it is not one)."""
    from pxr import Tf, Usd, UsdGeom

    path = Path(path)
    if not path.is_file():
        raise BTFError(f"{path}: no such file (run `usdbtf unwrap` first)")
    try:
        stage = Usd.Stage.Open(str(path))
    except Tf.ErrorException as exc:
        raise BTFError(f"{path}: cannot open USD layer ({' '.join(str(exc).split())[:200]})") from None
    prims = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and p.GetCustomDataByKey("usdbtf")]
    if not prims:
        raise BTFError(f"{path}: no Mesh written by `usdbtf unwrap` (customData usdbtf missing)")
    prim = prims[0]
    geom = UsdGeom.Mesh(prim)
    api = UsdGeom.PrimvarsAPI(prim)
    try:
        atlas = dict(prim.GetCustomDataByKey("usdbtf")["atlas"])
        atlas["width"], atlas["height"] = int(atlas["width"]), int(atlas["height"])
        counts = np.asarray(geom.GetFaceVertexCountsAttr().Get(), np.int64)
        if (counts != 3).any():
            raise ValueError("faces are not triangles")
        faces = np.asarray(geom.GetFaceVertexIndicesAttr().Get(), np.int64).reshape(-1, 3)
        points = np.asarray(geom.GetPointsAttr().Get(), np.float64) * UsdGeom.GetStageMetersPerUnit(stage)
        normals = np.asarray(geom.GetNormalsAttr().Get(), np.float64)
        st_pv = api.GetPrimvar("st")
        corner = np.asarray(st_pv.GetIndices(), np.int64).reshape(-1, 3)
        values = {name: np.asarray(api.GetPrimvar(name).Get(), np.float64) for name in ("st", "tangents", "bitangents")}
        face_chart = np.asarray(api.GetPrimvar("usdbtf:chart").Get(), np.int64)
        ok = (len(corner) == len(faces) == len(face_chart) and normals.shape == points.shape
              and faces.max() < len(points) and corner.max() < len(values["st"])
              and len(values["tangents"]) == len(values["bitangents"]) == len(values["st"]))
        if not ok:
            raise ValueError("array sizes do not agree")
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise BTFError(f"{path}: not a valid `usdbtf unwrap` layer ({exc})") from None
    up = str(UsdGeom.GetStageUpAxis(stage))
    return UnwrappedMesh(points, faces, normals, corner, values["st"], values["tangents"], values["bitangents"],
                         face_chart, atlas, up)
