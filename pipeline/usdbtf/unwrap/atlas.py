"""Texture atlases: charts and texture coordinates at the measured sample's texel density.

The atlas resolution follows from physics, not taste: a texel of the quilted texture must
cover the same surface patch as a texel of the measured sample, so mesostructure keeps its
real size.  The sample's density is ``texels / physical_size_m`` (texels per metre); xatlas
packs charts at that many texels per metre of surface (the mesh is in metres), which fixes
the atlas width and height (about sqrt(area) x density, plus packing overhead).  If that
exceeds ``max_resolution``, the density is lowered (recorded as ``texel_scale`` < 1: the
material then looks that much coarser).

Texture coordinates are USD's st (t up); atlas texel (row i, column j), row 0 at the top,
covers ``s in [j/W, (j+1)/W]``, ``t in [1-(i+1)/H, 1-i/H]``.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..compress.format import CompressedBTF
from ..errors import BTFError
from ..render.raster import rasterize
from .meshes import TriMesh

__all__ = ["Atlas", "texel_density", "make_atlas", "keep_uvs", "chart_map", "uv_problems"]


@dataclass
class Atlas:
    """A mesh's atlas.

    vertex_of : (M,) original vertex index of each atlas vertex (vertices split along chart seams).
    faces : (F, 3) atlas vertex indices (same triangles, same order as the mesh's faces).
    st : (M, 2) texture coordinates in [0, 1], t up.
    face_chart : (F,) chart index per triangle.
    width, height : atlas texels.  texels_per_metre : the density used.
    texel_scale : used density / requested density (1 unless capped).  method : "xatlas" or "kept".
    """

    vertex_of: np.ndarray
    faces: np.ndarray
    st: np.ndarray
    face_chart: np.ndarray
    width: int
    height: int
    texels_per_metre: float
    texel_scale: float
    method: str

    @property
    def charts(self) -> int:
        return int(self.face_chart.max()) + 1 if len(self.face_chart) else 0

    def texel_coords(self) -> np.ndarray:
        """(F, 3, 2) corner positions in atlas texel units (x right, y down)."""
        st = self.st[self.faces]
        return np.stack([st[..., 0] * self.width, (1.0 - st[..., 1]) * self.height], axis=-1)


def texel_density(cbtf: CompressedBTF, where: str = "compressed BTF") -> float:
    """Texels per metre of the measured sample (its width over its physical width)."""
    size = (cbtf.info.get("source_metadata") or {}).get("physical_size_m")
    try:
        w, h = (float(v) for v in size)
    except (TypeError, ValueError):
        raise BTFError(f"{where}: no physical_size_m recorded, so the texel density is unknown; "
                       "pass --texels-per-metre") from None
    if not (w > 0 and h > 0 and np.isfinite(w) and np.isfinite(h)):
        raise BTFError(f"{where}: physical_size_m {size!r} must be two positive numbers")
    dx, dy = cbtf.width / w, cbtf.height / h
    if abs(dx - dy) > 0.01 * max(dx, dy):
        raise BTFError(f"{where}: texels are not square ({dx:.1f} x {dy:.1f} per metre); atlases need square texels")
    return float(np.sqrt(dx * dy))


def make_atlas(mesh: TriMesh, density: float, *, max_resolution: int = 4096, padding: int = 4,
               log=None) -> Atlas:
    """Charts and packing by xatlas at ``density`` texels per metre (capped, see module docstring)."""
    import xatlas

    say = log or (lambda msg: None)
    if not (density > 0 and np.isfinite(density)):
        raise BTFError(f"texel density must be a positive number, got {density}")
    estimate = np.sqrt(mesh.area()) * density
    if estimate < 4:
        raise BTFError(f"the mesh ({mesh.area():.3g} m^2) is smaller than a few texels at {density:.4g} texels/m; "
                       "is it in metres? (--meters-per-unit)")
    scale = 1.0
    for _ in range(8):
        atlas = xatlas.Atlas()
        atlas.add_mesh(mesh.points.astype(np.float32), mesh.faces.astype(np.uint32),
                       mesh.normals.astype(np.float32))
        chart_opts = xatlas.ChartOptions()
        chart_opts.fix_winding = True          # uv winding follows the faces': texture not mirrored
        pack = xatlas.PackOptions()
        # xatlas's "rotate charts to their hull axis" can mirror a chart (measured: 3 of 8 charts
        # on an icosphere), which would flip the BTF frame's handedness there: keep charts as cut.
        pack.rotate_charts = False
        pack.texels_per_unit = float(density * scale)
        pack.padding = int(padding)
        pack.bilinear = True
        pack.resolution = 0
        atlas.generate(chart_opts, pack)
        if atlas.atlas_count != 1:
            raise BTFError(f"xatlas produced {atlas.atlas_count} atlases; expected one")
        if max(atlas.width, atlas.height) <= max_resolution:
            break
        shrink = max_resolution / max(atlas.width, atlas.height) * 0.98
        say(f"atlas {atlas.width}x{atlas.height} exceeds {max_resolution}: texel density x {scale * shrink:.3f}")
        scale *= shrink
    else:
        raise BTFError(f"cannot fit the atlas into {max_resolution} texels")
    vmap, faces, uv = atlas.get_mesh(0)
    face_chart = np.zeros(len(faces), np.int64)
    for c in range(atlas.get_mesh_chart_count(0)):
        face_chart[np.asarray(atlas.get_mesh_chart(0, c).faces, np.int64)] = c
    st = np.asarray(uv, np.float64)        # xatlas uv, like st, has v up for counter-clockwise faces
    return Atlas(np.asarray(vmap, np.int64), np.asarray(faces, np.int64), st, face_chart,
                 int(atlas.width), int(atlas.height), float(density * scale), float(scale), "xatlas")


def uv_problems(mesh: TriMesh, width: int = 512) -> str | None:
    """Why the mesh's own texture coordinates are unusable for a BTF atlas, or None if they are fine:
    missing, outside [0, 1], degenerate or mirrored triangles, or charts overlapping."""
    if mesh.uv is None:
        return "the mesh has no texture coordinates"
    uv = mesh.uv
    if not np.isfinite(uv).all() or uv.min() < 0 or uv.max() > 1:
        return "texture coordinates outside [0, 1]"
    from .frames import mirrored_faces, uv_gradients

    _, _, area = uv_gradients(mesh.points[mesh.faces], uv[mesh.faces])
    if (np.abs(area) < 1e-14).any():
        return f"{int((np.abs(area) < 1e-14).sum())} triangles have zero texture area"
    if mirrored_faces(mesh.points, mesh.faces, uv, mesh.normals).any():
        return "some triangles have mirrored texture coordinates"
    xy = np.stack([uv[mesh.faces][..., 0] * width, (1 - uv[mesh.faces][..., 1]) * width], axis=-1)
    # Shrink every triangle a hair towards its centroid so neighbours sharing an edge do not
    # both claim texel centres lying exactly on it; then count texels claimed twice by
    # rasterising with the opposite tie order (a texel with two owners changes hands).
    centre = xy.mean(axis=1, keepdims=True)
    xy = centre + (xy - centre) * (1 - 1e-6)
    first = rasterize(xy, None, width, width).tri.ravel()
    last = rasterize(xy[::-1], None, width, width).tri.ravel()
    both = (first >= 0) & (last >= 0)
    twice = int((first[both] != len(xy) - 1 - last[both]).sum())
    if twice > 0.001 * both.sum():
        return "texture charts overlap"
    return None


def keep_uvs(mesh: TriMesh, density: float) -> Atlas:
    """An atlas from the mesh's own texture coordinates (checked by :func:`uv_problems`), sized so
    the mean texel density matches ``density``; charts are connected components in uv space."""
    problem = uv_problems(mesh)
    if problem:
        raise BTFError(problem)
    p = mesh.points[mesh.faces]
    area3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    u = mesh.uv[mesh.faces]
    area_uv = 0.5 * np.abs((u[:, 1, 0] - u[:, 0, 0]) * (u[:, 2, 1] - u[:, 0, 1])
                           - (u[:, 2, 0] - u[:, 0, 0]) * (u[:, 1, 1] - u[:, 0, 1])).sum()
    side = int(np.ceil(np.sqrt(area3 / area_uv) * density))
    return Atlas(np.arange(len(mesh.points)), mesh.faces.copy(), mesh.uv.copy(), _uv_components(mesh.faces),
                 side, side, float(density), 1.0, "kept")


def _uv_components(faces: np.ndarray) -> np.ndarray:
    """(F,) component index of each face, faces joined when they share a uv vertex."""
    parent = np.arange(faces.max() + 1)

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b, c in faces:
        ra, rb, rc = find(a), find(b), find(c)
        parent[rb] = ra
        parent[find(rc)] = ra
    roots = np.array([find(v) for v in faces[:, 0]])
    _, comp = np.unique(roots, return_inverse=True)
    return comp.ravel()


def chart_map(atlas: Atlas, rim: float = 1.5) -> np.ndarray:
    """(H, W) int32 chart index per atlas texel, -1 for gutter.

    A texel belongs to a chart when its centre lies in one of the chart's triangles, or it is
    within ``rim`` texels of one (bilinear filtering reads one texel beyond the centres), or it
    holds the uv centroid of a triangle too thin to cover any texel centre.
    """
    W, H = atlas.width, atlas.height
    coords = atlas.texel_coords()
    tri = rasterize(coords, None, W, H).tri
    charts = np.where(tri >= 0, atlas.face_chart[np.maximum(tri, 0)], -1).astype(np.int32)
    centre = np.floor(coords.mean(axis=1)).astype(np.int64)
    cx, cy = np.clip(centre[:, 0], 0, W - 1), np.clip(centre[:, 1], 0, H - 1)
    empty = charts[cy, cx] < 0
    charts[cy[empty], cx[empty]] = atlas.face_chart[empty]
    gutter = (charts < 0).astype(np.uint8)
    if gutter.all() or not gutter.any():
        return charts
    dist, labels = cv2.distanceTransformWithLabels(gutter, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    owners = np.flatnonzero(gutter.ravel() == 0)
    nearest = charts.ravel()[owners[labels.ravel() - 1]].reshape(H, W)
    return np.where((charts < 0) & (dist <= rim), nearest, charts).astype(np.int32)
