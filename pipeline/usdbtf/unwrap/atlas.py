"""Texture atlases: charts and texture coordinates at the measured sample's texel density.

The atlas resolution follows from physics, not taste: a texel of the quilted texture must
cover the same surface patch as a texel of the measured sample, so mesostructure keeps its
real size.  The sample's density is ``texels / physical_size_m`` (texels per metre); xatlas
packs charts at that many texels per metre of surface (the mesh is in metres), which fixes
the atlas width and height (about sqrt(area) x density, plus packing overhead).  If that
exceeds ``max_resolution``, the density is lowered (recorded as ``texel_scale`` < 1: the
material then looks that much coarser).

Limits: the atlas side is at most ``max_resolution`` (16 .. :data:`MAX_ATLAS_SIDE` = 8192
texels; a chart map and the quilted textures hold W x H texels each), and the density is
lowered at most :data:`MIN_TEXEL_SCALE` = 1/8 (8x coarser than measured).  Past that the
request is refused *before* xatlas runs, saying how large an atlas it would need: sqrt(area)
x density texels per side is a lower bound (charts keep their surface area), so a unit
mistake cannot make xatlas allocate gigabytes.

Texture coordinates are USD's st (t up); atlas texel (row i, column j), row 0 at the top,
covers ``s in [j/W, (j+1)/W]``, ``t in [1-(i+1)/H, 1-i/H]``.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

from ..compress.format import CompressedBTF
from ..errors import BTFError, UsageError
from ..mesh import Mesh, mirrored_faces, uv_gradients, uv_stretch, weld
from ..raster import rasterize, st_to_texels

log = logging.getLogger(__name__)

__all__ = ["Atlas", "texel_density", "make_atlas", "keep_uvs", "chart_map", "uv_problems", "MAX_ATLAS_SIDE",
           "MIN_TEXEL_SCALE", "check_atlas_size", "MAX_KEPT_STRETCH"]

#: Largest atlas side (texels) ``usdbtf unwrap`` makes or ``quilt --atlas`` reads.
MAX_ATLAS_SIDE = 8192
#: Smallest allowed ratio of the atlas's texel density to the requested one.
MIN_TEXEL_SCALE = 1.0 / 8.0
#: Most stretch (:func:`~usdbtf.mesh.uv_stretch`: the area-weighted ratio of a triangle's largest
#: to smallest texel density direction) a mesh's own UVs may have and still be kept: 10 %
#: anisotropy, past which the material visibly looks squashed one way (a 0.6 x 0.4 m quad on the
#: UV square is at 1.5).  xatlas's charts on the meshes of `benchmarks/bench_scene_build.py`
#: measure 1.00-1.04.
MAX_KEPT_STRETCH = 1.1


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
        return st_to_texels(self.st[self.faces], self.width, self.height)

    @classmethod
    def from_mesh(cls, mesh: Mesh, width: int, height: int, texels_per_metre: float, texel_scale: float,
                  method: str) -> "Atlas":
        """The atlas of an unwrapped mesh (per-corner ``uv`` and ``charts``, e.g. read back from a
        layer): atlas vertices are the mesh's points split where their corners' st differ."""
        if mesh.uv is None or mesh.charts is None:
            raise BTFError(f"{mesh.source}: the mesh has no texture coordinates or charts (not unwrapped)")
        split = Mesh(mesh.points, mesh.triangles, uv=mesh.uv, source=mesh.source).split_corners()
        vertex_of = np.zeros(len(split.points), np.int64)
        vertex_of[split.triangles.ravel()] = mesh.triangles.ravel()
        return cls(vertex_of, split.triangles, split.uv, mesh.charts, int(width), int(height),
                   float(texels_per_metre), float(texel_scale), method)


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


def check_atlas_size(area_m2: float, density: float, max_resolution: int, where: str = "mesh") -> float:
    """The first texel scale to try for a mesh of ``area_m2`` square metres at ``density``
    texels per metre: 1 when sqrt(area) x density fits ``max_resolution``, else the ratio
    that makes it fit.  Raises (before anything large is allocated) past the limits of the
    module docstring, saying how large an atlas the request needs."""
    if not (density > 0 and np.isfinite(density)):
        raise UsageError(f"texel density must be a positive number, got {density}")
    if not 16 <= max_resolution <= MAX_ATLAS_SIDE:
        raise UsageError(f"--max-resolution must be in 16..{MAX_ATLAS_SIDE}, got {max_resolution}")
    estimate = np.sqrt(area_m2) * density          # a lower bound of the atlas side, texels
    if estimate < 4:
        raise BTFError(f"{where}: the mesh ({area_m2:.3g} m^2) is smaller than a few texels at {density:.4g} texels/m; "
                       "is it in metres? (--meters-per-unit)")
    if estimate <= max_resolution:
        return 1.0
    scale = max_resolution / estimate
    if scale < MIN_TEXEL_SCALE:
        raise UsageError(f"{where}: the mesh's {area_m2:.4g} m^2 at {density:.4g} texels/m need an atlas of at least "
                         f"{estimate:.3g} x {estimate:.3g} texels ({estimate ** 2 * 4 / 2 ** 30:.3g} GiB per "
                         f"32-bit channel); --max-resolution {max_resolution} would make the texture "
                         f"{1 / scale:.3g}x coarser than measured (at most {1 / MIN_TEXEL_SCALE:g}x is allowed, "
                         f"the atlas side is at most {MAX_ATLAS_SIDE}): lower the density to at most "
                         f"{max_resolution / MIN_TEXEL_SCALE / np.sqrt(area_m2):.4g} texels/m or check "
                         "the mesh's units (--meters-per-unit)")
    return float(scale)


def make_atlas(mesh: Mesh, density: float, *, max_resolution: int = 4096, padding: int = 4) -> Atlas:
    """Charts and packing by xatlas at ``density`` texels per metre (capped, see module docstring).

    mesh : per-vertex texture-less mesh with per-vertex normals (N, 3)."""
    import xatlas

    scale = check_atlas_size(mesh.area(), density, max_resolution, mesh.source)
    if scale < 1.0:
        # Start where the atlas will about fit (charts plus packing overhead), not at a size
        # xatlas could not allocate.
        scale *= 0.98
        log.info(f"the atlas at {density:.4g} texels/m would exceed {max_resolution}: texel density x {scale:.3f}")
    for _ in range(8):
        atlas = xatlas.Atlas()
        atlas.add_mesh(mesh.points.astype(np.float32), mesh.triangles.astype(np.uint32),
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
        log.info(f"atlas {atlas.width}x{atlas.height} exceeds {max_resolution}: texel density x {scale * shrink:.3f}")
        scale *= shrink
        if scale < MIN_TEXEL_SCALE:
            break
    else:
        scale = 0.0
    if not MIN_TEXEL_SCALE <= scale:
        raise UsageError(f"{mesh.source}: cannot fit the atlas into {max_resolution} texels without making the "
                         f"texture more than {1 / MIN_TEXEL_SCALE:g}x coarser than measured; lower the density or "
                         "raise --max-resolution")
    vmap, faces, texels, face_chart = xatlas_charts(atlas)
    side = max(int(atlas.width), int(atlas.height))
    return Atlas(vmap, faces, texels / side, face_chart, side, side, float(density * scale), float(scale), "xatlas")


def xatlas_charts(atlas) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A generated one-mesh ``xatlas.Atlas`` as arrays: (vmap (M,) input vertex of each output
    vertex, faces (F, 3), texel positions (M, 2), face_chart (F,)).

    xatlas's uv, like st, has v up for counter-clockwise faces; positions are in texels of its
    width x height.  Callers divide them by the larger side: the atlas is made square, st scaled
    into its corner, so texels are square in st too and usdbtf's own output passes --keep-uvs
    (which reads UVs as laid on a square texture) when a scene brings it back."""
    vmap, faces, uv = atlas.get_mesh(0)
    faces = np.asarray(faces, np.int64)
    face_chart = np.zeros(len(faces), np.int64)
    for c in range(atlas.get_mesh_chart_count(0)):
        face_chart[np.asarray(atlas.get_mesh_chart(0, c).faces, np.int64)] = c
    texels = np.asarray(uv, np.float64) * np.array([atlas.width, atlas.height], np.float64)
    return np.asarray(vmap, np.int64), faces, texels, face_chart


def uv_problems(mesh: Mesh, width: int = 512) -> str | None:
    """Why the mesh's own texture coordinates are unusable for a BTF atlas, or None if they are fine:
    missing, outside [0, 1], degenerate or mirrored triangles, stretched (more than
    :data:`MAX_KEPT_STRETCH`), or charts overlapping."""
    if mesh.uv is None:
        return "the mesh has no texture coordinates"
    uv = mesh.uv
    if not np.isfinite(uv).all() or uv.min() < 0 or uv.max() > 1:
        return "texture coordinates outside [0, 1]"
    _, _, area = uv_gradients(mesh.points[mesh.triangles], uv[mesh.triangles])
    if (np.abs(area) < 1e-14).any():
        return f"{int((np.abs(area) < 1e-14).sum())} triangles have zero texture area"
    if mirrored_faces(mesh.points, mesh.triangles, uv, mesh.normals).any():
        return "some triangles have mirrored texture coordinates"
    # Areas alone cannot see a quad squashed onto the UV square: texels must stay square.
    stretch = uv_stretch(mesh)
    if stretch is not None and stretch > MAX_KEPT_STRETCH:
        return (f"texture coordinates stretched {stretch:.3g}x (one direction has that many more texels per "
                f"metre than the other; at most {MAX_KEPT_STRETCH:g} is kept)")
    xy = st_to_texels(uv[mesh.triangles], width, width)
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


def keep_uvs(mesh: Mesh, density: float) -> Atlas:
    """An atlas from the mesh's own texture coordinates (checked by :func:`uv_problems`), sized so
    the mean texel density matches ``density``; charts are connected components in uv space."""
    problem = uv_problems(mesh)
    if problem:
        raise BTFError(problem)
    p = mesh.points[mesh.triangles]
    area3 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    u = mesh.uv[mesh.triangles]
    area_uv = 0.5 * np.abs((u[:, 1, 0] - u[:, 0, 0]) * (u[:, 2, 1] - u[:, 0, 1])
                           - (u[:, 2, 0] - u[:, 0, 0]) * (u[:, 1, 1] - u[:, 0, 1])).sum()
    # The side is whole texels, the UVs are scaled into its corner so that the density is exact:
    # a 2 cm tile at 320 texels/m is 6.4 texels, and a whole side would be 6 % off.  (The
    # tolerance: a 5 cm quad at 640 texels/m is 32.000000001 texels, not 33.)
    exact = float(np.sqrt(area3 / area_uv) * density)
    side = max(1, int(np.ceil(exact - 1e-6)))
    uv = mesh.uv * min(1.0, exact / side)
    return Atlas(np.arange(len(mesh.points)), mesh.triangles.copy(), uv,
                 _uv_components(mesh.triangles, mesh.points, mesh.uv), side, side, float(density), 1.0, "kept")


def _uv_components(faces: np.ndarray, points: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(F,) component index of each face, faces joined when they share a vertex: one with the
    same position and the same uv (so a file that repeats vertices per triangle, a "triangle
    soup", still has the charts its UVs draw)."""
    same = weld(np.concatenate([points, uv], axis=1))
    faces = same[faces]
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
