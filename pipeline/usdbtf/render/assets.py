"""What the renderer renders: resolving ``usdbtf render ASSET [--mesh MESH]`` to plain inputs.

:func:`resolve_asset` is the one place that knows file types:

* ASSET a ``btf-compressed/1`` folder (an original or a quilt) -> its CompressedBTF;
* ASSET a packaged USD asset (.usda/.usdc/.usd/.usdz) -> its BTF material through
  :func:`usdbtf.io.open_compressed` (the packaging stage's reader) and, without ``--mesh``,
  the asset's own Mesh (its ``st``; tangent frames recomputed from it);
* MESH the ``mesh.usda`` of ``usdbtf unwrap`` (its stored frames are used), or any
  OBJ/PLY/STL/GLB/USD mesh with texture coordinates (frames computed from them).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..compress.format import METADATA, CompressedBTF, read_compressed
from ..errors import BTFError
from ..unwrap.frames import tangent_frames
from ..unwrap.layer import UnwrappedMesh, read_layer
from ..unwrap.meshes import load_mesh
from .scene import RenderMesh

__all__ = ["resolve_asset", "render_mesh_from_file", "render_mesh_from_layer", "render_mesh_from_arrays"]


def render_mesh_from_arrays(points, faces, st, normals, tangents=None, bitangents=None) -> RenderMesh:
    """Per-vertex arrays (N, ...) and triangles (F, 3) -> RenderMesh (frames computed from st if not given)."""
    points, faces, st, normals = (np.asarray(a) for a in (points, faces, st, normals))
    if tangents is None or bitangents is None:
        tangents, bitangents = tangent_frames(points, faces, st, normals)
    return RenderMesh(points[faces], normals[faces], np.asarray(tangents)[faces], np.asarray(bitangents)[faces],
                      st[faces])


def render_mesh_from_layer(layer: UnwrappedMesh) -> RenderMesh:
    """The unwrap layer's stored frames and st, per triangle corner."""
    c = layer.corner
    return RenderMesh(layer.points[layer.faces], layer.normals[layer.faces], layer.tangents[c],
                      layer.bitangents[c], layer.st[c])


def render_mesh_from_file(path) -> RenderMesh:
    """A RenderMesh from an unwrap layer or any mesh file with texture coordinates."""
    from ..usd.read import usd_exists

    path = Path(path)
    if usd_exists(path) and _is_unwrap_layer(path):
        return render_mesh_from_layer(read_layer(path))
    mesh = load_mesh(path)
    if mesh.uv is None:
        raise BTFError(f"{path}: mesh has no texture coordinates; run `usdbtf unwrap {path}` first")
    return render_mesh_from_arrays(mesh.points, mesh.faces, mesh.uv, mesh.normals)


def _is_unwrap_layer(path: Path) -> bool:
    from pxr import Usd, UsdGeom

    try:
        stage = Usd.Stage.Open(str(path))
    except Exception:        # noqa: BLE001 - load_mesh reports unreadable files
        return False
    return stage is not None and any(p.IsA(UsdGeom.Mesh) and p.GetCustomDataByKey("usdbtf")
                                     for p in stage.Traverse())


def resolve_asset(asset, mesh=None) -> tuple[CompressedBTF, RenderMesh | None]:
    """(compressed BTF, mesh or None) for ``usdbtf render ASSET [--mesh MESH]`` (module docstring)."""
    from ..usd.read import usd_exists

    asset = Path(asset)
    if asset.is_dir() and (asset / METADATA).is_file():
        cbtf = read_compressed(asset)
        return cbtf, render_mesh_from_file(mesh) if mesh is not None else None
    if usd_exists(asset):                   # found through the asset resolver
        from ..io import open_compressed        # the packaging stage's asset reader

        cbtf = open_compressed(asset)
        return cbtf, render_mesh_from_file(mesh if mesh is not None else asset)
    raise BTFError(f"{asset}: not a compressed BTF folder (no {METADATA}) or a USD asset")
