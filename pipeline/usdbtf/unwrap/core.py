"""``unwrap``: a mesh -> the same surface with an atlas at the sample's texel density.

    >>> from usdbtf.mesh import load_mesh
    >>> from usdbtf.unwrap import UnwrapOptions, unwrap, write_unwrap
    >>> result = unwrap(load_mesh("torus.obj"), UnwrapOptions(texels_per_metre=2560.0))
    >>> write_unwrap(result, "torus_uv")

Output folder (:func:`write_unwrap`; :func:`read_unwrap` reads it back)::

    mesh.usda      the geometry layer (:mod:`.layer`): st, normals, tangent frames, charts
    charts.png     16-bit chart map: chart index + 1 per atlas texel, 0 = gutter
    unwrap.json    what was done: source, density, atlas size, charts, mirrored triangles
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import __version__
from ..atomic import atomic_dir
from ..errors import BTFError, UsageError
from ..imageio import read_image, write_image
from ..mesh import Mesh, load_mesh, mirrored_faces, tangent_frames
from .atlas import MAX_ATLAS_SIDE, Atlas, chart_map, keep_uvs, make_atlas, uv_problems
from .layer import layer_atlas_info, write_layer
from .orient import orient_charts
from ..numeric import single_blas_thread

log = logging.getLogger(__name__)

__all__ = ["UnwrapOptions", "UnwrapResult", "unwrap", "write_unwrap", "read_unwrap", "LAYER", "CHARTS"]

LAYER = "mesh.usda"
CHARTS = "charts.png"
RECORD = "unwrap.json"
MAX_PADDING = 64


@dataclass
class UnwrapOptions:
    """texels_per_metre : the sample's texel density (:func:`~.atlas.texel_density` of a compressed
    BTF); keep_uvs : use the mesh's own texture coordinates when they pass the checks
    (:func:`~.atlas.uv_problems`), else unwrap; max_resolution : atlas side cap, texels
    (16 .. :data:`~.atlas.MAX_ATLAS_SIDE`); padding : gutter texels between charts (1 .. 64);
    orient_charts : turn charts by quarter turns so the texture's axes continue across chart
    borders (:mod:`.orient`), packing them again at the same density."""

    texels_per_metre: float
    keep_uvs: bool = False
    max_resolution: int = 4096
    padding: int = 4
    orient_charts: bool = True

    def validate(self) -> None:
        """UsageError for values out of range (before any work)."""
        d = self.texels_per_metre
        if not (isinstance(d, (int, float)) and np.isfinite(d) and d > 0):
            raise UsageError(f"--texels-per-metre must be a positive number, got {d}")
        if not 16 <= self.max_resolution <= MAX_ATLAS_SIDE:
            raise UsageError(f"--max-resolution must be in 16..{MAX_ATLAS_SIDE}, got {self.max_resolution}")
        if not 1 <= self.padding <= MAX_PADDING:
            raise UsageError(f"--padding must be in 1..{MAX_PADDING}, got {self.padding}")


@dataclass
class UnwrapResult:
    """An unwrapped mesh.

    mesh : the surface with its atlas -- the source's points (shared across chart seams, so
        watertight) and triangles, per-vertex normals (N, 3), per-corner ``uv``, ``tangents``,
        ``bitangents`` (F, 3, k) and ``charts`` (F,).
    atlas : the :class:`~.atlas.Atlas` (atlas vertices, size, density actually used).
    chart_map : (H, W) int32 chart per atlas texel, -1 for gutter.
    record : what :func:`write_unwrap` stores as unwrap.json (source, density, atlas, ...).
    """

    mesh: Mesh
    atlas: Atlas
    chart_map: np.ndarray
    record: dict


def _prepared(mesh: Mesh) -> Mesh:
    """The input as xatlas and the frames need it: per-vertex values, no degenerate triangles,
    no unused points (their normals would be zero), per-vertex unit normals."""
    return mesh.split_corners().without_degenerate().compacted().with_normals()


@single_blas_thread
def unwrap(mesh: Mesh, options: UnwrapOptions) -> UnwrapResult:
    """Atlas, tangent frames and chart map of ``mesh`` at ``options.texels_per_metre`` (in
    memory; :func:`write_unwrap` writes it).  Degenerate triangles are dropped and points no
    triangle uses left out (``record["notes"]`` says what was dropped)."""
    options.validate()
    mesh = _prepared(mesh)
    density = float(options.texels_per_metre)
    atlas = None
    kept_reason = None
    if options.keep_uvs:
        kept_reason = uv_problems(mesh)
        if kept_reason is None:
            atlas = keep_uvs(mesh, density)
            if max(atlas.width, atlas.height) > options.max_resolution:
                kept_reason = f"keeping them needs a {atlas.width}-texel atlas (> --max-resolution)"
                atlas = None
        if atlas is None:
            log.info(f"not keeping the mesh's texture coordinates: {kept_reason}; unwrapping with xatlas")
    if atlas is None:
        atlas = make_atlas(mesh, density, max_resolution=options.max_resolution, padding=options.padding)
    orientation = None
    if options.orient_charts:
        turned, orientation = orient_charts(atlas, mesh.points, options.padding)
        if max(turned.width, turned.height) <= options.max_resolution:
            atlas = turned
        else:       # the turned charts pack larger than allowed: keep them as they were
            orientation["quarter_turns"] = [0] * atlas.charts
            orientation["aligned_after"] = orientation["aligned_before"]
            log.info(f"charts not turned: packed they would need more than {options.max_resolution} texels")
    normals = mesh.normals[atlas.vertex_of]
    points = mesh.points[atlas.vertex_of]
    tangents, bitangents = tangent_frames(points, atlas.faces, atlas.st, normals)
    mirrored = int(mirrored_faces(points, atlas.faces, atlas.st, normals).sum())
    charts = chart_map(atlas)
    # The layer keeps the original points (watertight); triangles index them.
    out = replace(mesh, triangles=atlas.vertex_of[atlas.faces], uv=atlas.st[atlas.faces],
                  tangents=tangents[atlas.faces], bitangents=bitangents[atlas.faces], charts=atlas.face_chart,
                  face_sizes=None)
    record = {"tool": "usdbtf unwrap", "version": __version__, "source": mesh.source,
              "triangles": int(len(out.triangles)), "points": int(len(out.points)), "area_m2": out.area(),
              "atlas": {"width": atlas.width, "height": atlas.height, "charts": atlas.charts,
                        "method": atlas.method, "texels_per_metre": atlas.texels_per_metre,
                        "requested_texels_per_metre": density, "texel_scale": atlas.texel_scale,
                        "padding": options.padding, "coverage": float((charts >= 0).mean()),
                        "orientation": orientation},
              "mirrored_triangles": mirrored, "kept_uvs_rejected": kept_reason, "up_axis": out.up_axis}
    if out.notes:
        record["notes"] = list(out.notes)
    for note in out.notes:
        log.info(f"{mesh.source}: {note}")
    log.info(f"{len(out.triangles)} triangles, {atlas.charts} charts, atlas {atlas.width}x{atlas.height} at "
        f"{atlas.texels_per_metre:.1f} texels/m ({atlas.method})")
    return UnwrapResult(out, atlas, charts, record)


def write_unwrap(result: UnwrapResult, out) -> None:
    """Write ``result`` into the folder ``out`` atomically (module docstring)."""
    with atomic_dir(out) as tmp:
        write_layer(tmp / LAYER, result.mesh, result.atlas, padding=int(result.record["atlas"]["padding"]),
                    source=str(result.record["source"]))
        write_image(tmp / CHARTS, (result.chart_map + 1).astype(np.uint16)[:, :, None], color_space="data",
                    attributes={"png:compressionLevel": 6})
        (tmp / RECORD).write_text(json.dumps(result.record, indent=1) + "\n")


def read_unwrap(layer_path) -> UnwrapResult:
    """An unwrap read back from its ``mesh.usda`` and the charts.png beside it: what
    ``usdbtf quilt --atlas`` fills (``record`` holds the layer's source and atlas entries).
    BTFError naming the file when it is not a layer ``usdbtf unwrap`` wrote or the chart map
    does not fit it."""
    layer_path = Path(layer_path)
    if not layer_path.is_file():
        raise BTFError(f"{layer_path}: no such file (run `usdbtf unwrap` first)")
    info = layer_atlas_info(layer_path)
    mesh = load_mesh(layer_path)
    missing = [n for n in ("uv", "tangents", "bitangents", "charts") if getattr(mesh, n) is None]
    if missing or not mesh.is_per_corner(mesh.uv):
        raise BTFError(f"{layer_path}: not a valid `usdbtf unwrap` layer "
                       f"(no face-varying {', '.join(missing) or 'st'})")
    W, H = info["width"], info["height"]
    atlas = Atlas.from_mesh(mesh, W, H, info.get("texels_per_metre") or 0.0, info.get("texel_scale", 1.0),
                            str(info.get("method", "")))
    png = layer_path.parent / CHARTS
    if not png.is_file():
        raise BTFError(f"{png}: chart map missing (it is written by `usdbtf unwrap` beside {layer_path.name})")
    px, _ = read_image(png, expect=(W, H))
    charts = px[:, :, 0].astype(np.int32) - 1
    if charts.max() >= atlas.charts:
        raise BTFError(f"{png}: chart {int(charts.max())} is not a chart of {layer_path} ({atlas.charts} charts)")
    record = {"source": str(info.get("source", "")), "atlas": info}
    return UnwrapResult(mesh, atlas, charts, record)

