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
face-varying.  :func:`usdbtf.mesh.load_mesh` reads it like any USD mesh (frames and charts
included); :func:`layer_atlas_info` reads the atlas record, :func:`usdbtf.unwrap.read_unwrap`
both (with the chart map) for ``usdbtf quilt --atlas``.
"""
from __future__ import annotations

import re

import numpy as np

from ..errors import BTFError
from ..mesh import Mesh
from ..usdstage import open_usd, usd_warnings_silenced
from .atlas import MAX_ATLAS_SIDE, Atlas

__all__ = ["write_layer", "layer_atlas_info"]


def _prim_name(name: str) -> str:
    clean = re.sub(r"[^A-Za-z0-9_]", "_", name) or "mesh"
    return clean if not clean[0].isdigit() else "_" + clean


def _per_atlas_vertex(values: np.ndarray, atlas: Atlas) -> np.ndarray:
    """(M, k) values per atlas vertex from per-corner values (F, 3, k) (corners sharing an atlas
    vertex hold the same value)."""
    out = np.zeros((len(atlas.st), values.shape[-1]))
    out[atlas.faces.ravel()] = values.reshape(-1, values.shape[-1])
    return out


def write_layer(path, mesh: Mesh, atlas: Atlas, *, padding: int, source: str) -> None:
    """Write the geometry layer of the unwrapped ``mesh`` (per-vertex normals, per-corner
    tangents and bitangents; its triangles are ``atlas.vertex_of[atlas.faces]``) at ``path``
    (a new file; the caller makes it atomic)."""
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
    geom.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(mesh.triangles), 3, np.int32)))
    geom.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(mesh.triangles.astype(np.int32).ravel()))
    geom.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    geom.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    geom.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(mesh.normals.astype(np.float32)))
    geom.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    api = UsdGeom.PrimvarsAPI(geom)
    corner = Vt.IntArray.FromNumpy(atlas.faces.astype(np.int32).ravel())
    st = api.CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
    st.Set(Vt.Vec2fArray.FromNumpy(atlas.st.astype(np.float32)))
    st.SetIndices(corner)
    for name in ("tangents", "bitangents"):
        pv = api.CreatePrimvar(name, Sdf.ValueTypeNames.Vector3fArray, UsdGeom.Tokens.faceVarying)
        pv.Set(Vt.Vec3fArray.FromNumpy(_per_atlas_vertex(getattr(mesh, name), atlas).astype(np.float32)))
        pv.SetIndices(corner)
    chart = api.CreatePrimvar("usdbtf:chart", Sdf.ValueTypeNames.IntArray, UsdGeom.Tokens.uniform)
    chart.Set(Vt.IntArray.FromNumpy(atlas.face_chart.astype(np.int32)))
    info = {"width": atlas.width, "height": atlas.height, "texels_per_metre": atlas.texels_per_metre,
            "texel_scale": atlas.texel_scale, "padding": int(padding), "charts": atlas.charts,
            "method": atlas.method}
    geom.GetPrim().SetCustomDataByKey("usdbtf", {"atlas": info, "source": source})
    stage.GetRootLayer().Save()


def layer_atlas_info(path) -> dict:
    """The atlas record (width, height, texels_per_metre, texel_scale, padding, charts, method;
    plus ``source``) of a layer :func:`write_layer` wrote; BTFError naming the file when it is
    not one or the size is outside 1 .. MAX_ATLAS_SIDE."""
    from pxr import UsdGeom

    with usd_warnings_silenced():
        stage = open_usd(path)
    prims = [p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh) and p.GetCustomDataByKey("usdbtf")]
    if not prims:
        raise BTFError(f"{path}: no Mesh written by `usdbtf unwrap` (customData usdbtf missing)")
    if len(prims) > 1:
        raise BTFError(f"{path}: {len(prims)} meshes written by `usdbtf unwrap`; expected one")
    data = prims[0].GetCustomDataByKey("usdbtf")
    try:
        info = dict(data["atlas"])
        info["width"], info["height"] = int(info["width"]), int(info["height"])
        info["source"] = str(data.get("source", ""))
    except (KeyError, TypeError, ValueError) as exc:
        raise BTFError(f"{path}: not a valid `usdbtf unwrap` layer (customData usdbtf.atlas: {exc})") from None
    if not (1 <= info["width"] <= MAX_ATLAS_SIDE and 1 <= info["height"] <= MAX_ATLAS_SIDE):
        raise BTFError(f"{path}: atlas size {info['width']}x{info['height']} is outside 1..{MAX_ATLAS_SIDE}")
    return info
