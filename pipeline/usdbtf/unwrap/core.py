"""``unwrap``: a mesh file -> USD geometry layer with an atlas at the sample's texel density.

    >>> from usdbtf.unwrap import UnwrapOptions, unwrap_to_folder
    >>> unwrap_to_folder("torus.obj", "torus_uv", texels_per_metre=2560.0)

Output folder::

    mesh.usda      the geometry layer (:mod:`.layer`): st, normals, tangent frames, charts
    charts.png     16-bit chart map: chart index + 1 per atlas texel, 0 = gutter
    unwrap.json    what was done: source, density, atlas size, charts, mirrored triangles
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import __version__
from ..atomic import atomic_dir
from ..errors import BTFError
from ..imageio import read_image, write_image
from .atlas import chart_map, keep_uvs, make_atlas, uv_problems
from .frames import mirrored_faces, tangent_frames
from .layer import read_layer, write_layer
from .meshes import load_mesh

__all__ = ["UnwrapOptions", "unwrap_to_folder", "read_chart_map", "LAYER", "CHARTS"]

LAYER = "mesh.usda"
CHARTS = "charts.png"
RECORD = "unwrap.json"


@dataclass
class UnwrapOptions:
    """keep_uvs : use the mesh's own texture coordinates when they pass the checks
    (:func:`~.atlas.uv_problems`), else unwrap; max_resolution : atlas side cap (texels);
    padding : gutter texels between charts; meters_per_unit / up_axis : override the file's."""

    keep_uvs: bool = False
    max_resolution: int = 4096
    padding: int = 4
    meters_per_unit: float | None = None
    up_axis: str | None = None


def unwrap_to_folder(mesh_path, out, *, texels_per_metre: float, opts: UnwrapOptions | None = None,
                     log=None) -> dict:
    """Unwrap ``mesh_path`` into folder ``out`` atomically; returns the record written to unwrap.json."""
    opts = opts or UnwrapOptions()
    say = log or (lambda msg: None)
    if opts.max_resolution < 16 or opts.padding < 1:
        raise BTFError("--max-resolution must be >= 16 and --padding >= 1")
    mesh = load_mesh(mesh_path, meters_per_unit=opts.meters_per_unit, up_axis=opts.up_axis)
    atlas = None
    kept_reason = None
    if opts.keep_uvs:
        kept_reason = uv_problems(mesh)
        if kept_reason is None:
            atlas = keep_uvs(mesh, texels_per_metre)
            if max(atlas.width, atlas.height) > opts.max_resolution:
                kept_reason = f"keeping them needs a {atlas.width}-texel atlas (> --max-resolution)"
                atlas = None
        if atlas is None:
            say(f"not keeping the mesh's texture coordinates: {kept_reason}; unwrapping with xatlas")
    if atlas is None:
        atlas = make_atlas(mesh, texels_per_metre, max_resolution=opts.max_resolution, padding=opts.padding, log=say)
    normals = mesh.normals[atlas.vertex_of]
    points = mesh.points[atlas.vertex_of]
    tangents, bitangents = tangent_frames(points, atlas.faces, atlas.st, normals)
    mirrored = int(mirrored_faces(points, atlas.faces, atlas.st, normals).sum())
    charts = chart_map(atlas)
    # The layer keeps the original points (watertight); triangles index them.
    faces = atlas.vertex_of[atlas.faces]
    mesh.faces = faces
    record = {"tool": "usdbtf unwrap", "version": __version__, "source": str(mesh_path),
              "triangles": int(len(faces)), "points": int(len(mesh.points)), "area_m2": mesh.area(),
              "atlas": {"width": atlas.width, "height": atlas.height, "charts": atlas.charts,
                        "method": atlas.method, "texels_per_metre": atlas.texels_per_metre,
                        "requested_texels_per_metre": float(texels_per_metre), "texel_scale": atlas.texel_scale,
                        "padding": opts.padding, "coverage": float((charts >= 0).mean())},
              "mirrored_triangles": mirrored, "kept_uvs_rejected": kept_reason, "up_axis": mesh.up_axis}
    with atomic_dir(out) as tmp:
        write_layer(tmp / LAYER, mesh, atlas, tangents, bitangents, padding=opts.padding, source=str(mesh_path))
        write_image(tmp / CHARTS, (charts + 1).astype(np.uint16)[:, :, None], color_space="data",
                    attributes={"png:compressionLevel": 6})
        (tmp / RECORD).write_text(json.dumps(record, indent=1) + "\n")
    say(f"{len(faces)} triangles, {atlas.charts} charts, atlas {atlas.width}x{atlas.height} at "
        f"{atlas.texels_per_metre:.1f} texels/m ({atlas.method})")
    return record


def read_chart_map(layer_path, layer=None) -> np.ndarray:
    """(H, W) int32 chart index per atlas texel (-1 gutter) from the charts.png beside a layer,
    checked against the layer's atlas size (``layer``: the already read layer)."""
    layer_path = Path(layer_path)
    png = layer_path.parent / CHARTS
    layer = layer or read_layer(layer_path)
    if not png.is_file():
        raise BTFError(f"{png}: chart map missing (it is written by `usdbtf unwrap` beside {layer_path.name})")
    px, _ = read_image(png, expect=(layer.atlas["width"], layer.atlas["height"]))
    return px[:, :, 0].astype(np.int32) - 1
