"""The one mesh type: :class:`Mesh`, triangles in metres with optional texture coordinates,
tangent frames and charts, each per vertex or per triangle corner.

A BTF is evaluated in the texture's tangent frame: x = tangent = image right (+s), y =
bitangent = image up (+t), z = normal out of the surface.  Every stage speaks this type:
:func:`usdbtf.mesh.load_mesh` makes one from any file, ``usdbtf unwrap`` adds an atlas
(``uv``, frames and ``charts``), the renderers and the GPU preview draw it, packaging
authors it as a ``UsdGeom.Mesh``.

Attributes live where the source put them: *per vertex*, shape (N, k) beside ``points``, or
*per corner*, shape (F, 3, k) beside ``triangles`` (USD's faceVarying: a texture seam or a
hard edge gives one point two values).  :meth:`Mesh.corner` reads either as per-corner
values; :meth:`Mesh.split_corners` turns per-corner attributes into per-vertex ones by
splitting points where their corners disagree (what xatlas and per-vertex frames need).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from ..errors import BTFError

__all__ = ["Mesh", "CornerFrames", "ATTRIBUTES", "weld", "smooth_normals", "degenerate_triangles"]

#: The optional per-vertex / per-corner attributes and their widths.
ATTRIBUTES = {"uv": 2, "normals": 3, "tangents": 3, "bitangents": 3}

# A triangle is degenerate (no area, no normal) when twice its area is below this fraction of
# its longest edge squared: collinear or repeated corners, up to rounding.
_DEGENERATE = 1e-12


class CornerFrames(NamedTuple):
    """Per-corner arrays, (F, 3, k) float64 each, of a mesh with frames: what a renderer
    interpolates across a triangle (:meth:`Mesh.corner_frames`)."""

    points: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    bitangents: np.ndarray
    uv: np.ndarray


@dataclass
class Mesh:
    """A triangle mesh in metres, world space.

    Parameters
    ----------
    points : (N, 3) float64
        Vertex positions, metres.
    triangles : (F, 3) int64
        Indices into ``points``.
    uv : (N, 2) or (F, 3, 2) float64, optional
        Texture coordinates st (s right, t up), per vertex or per corner.
    normals, tangents, bitangents : (N, 3) or (F, 3, 3) float64, optional
        Unit vectors per vertex or per corner: the surface normal, image right (+s) and image
        up (+t) (see the module docstring).
    charts : (F,) int64, optional
        Atlas chart of each triangle (``usdbtf unwrap``).
    face_sizes : (P,) int64, optional
        Vertex counts of the source's polygons when ``triangles`` are their fans, in order
        (polygon p with c corners gives c - 2 consecutive triangles); lets a writer author the
        polygons back.  None: plain triangles.
    name : str
        A name for the mesh (file stem, default prim).
    source : str
        Where it came from (a file), for messages.
    metres_per_unit : float
        The source's unit; ``points`` are already scaled to metres.
    up_axis : {"Y", "Z"}
        What the source declared (or was assumed).
    notes : tuple of str
        What loading changed, for the user (e.g. degenerate triangles dropped).

    Raises BTFError naming ``source`` when shapes disagree, an index is out of range or a
    value is NaN or infinite.
    """

    points: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray | None = None
    normals: np.ndarray | None = None
    tangents: np.ndarray | None = None
    bitangents: np.ndarray | None = None
    charts: np.ndarray | None = None
    face_sizes: np.ndarray | None = None
    name: str = "mesh"
    source: str = "mesh"
    metres_per_unit: float = 1.0
    up_axis: str = "Y"
    notes: tuple = field(default_factory=tuple)

    def __post_init__(self):
        where = self.source
        self.points = np.asarray(self.points, np.float64)
        self.triangles = np.asarray(self.triangles, np.int64)
        N = len(self.points)
        if self.points.ndim != 2 or self.points.shape[1] != 3:
            raise BTFError(f"{where}: points must be (N, 3), got {self.points.shape}")
        if self.triangles.ndim != 2 or self.triangles.shape[1] != 3:
            raise BTFError(f"{where}: triangles must be (F, 3), got {self.triangles.shape}")
        F = len(self.triangles)
        if F == 0:
            raise BTFError(f"{where}: mesh has no faces")
        bad = np.flatnonzero(~np.isfinite(self.points).all(axis=1))
        if len(bad):
            raise BTFError(f"{where}: vertex {bad[0]} is NaN or infinite"
                           + (f" ({len(bad)} such vertices)" if len(bad) > 1 else ""))
        if self.triangles.min() < 0 or self.triangles.max() >= N:
            raise BTFError(f"{where}: face indices out of range (the mesh has {N} points)")
        for name, width in ATTRIBUTES.items():
            values = getattr(self, name)
            if values is None:
                continue
            values = np.asarray(values, np.float64)
            if values.shape not in ((N, width), (F, 3, width)):
                raise BTFError(f"{where}: {name} must be per vertex ({N}, {width}) or per corner "
                               f"({F}, 3, {width}), got {values.shape}")
            if not np.isfinite(values).all():
                raise BTFError(f"{where}: {name} include NaN or Inf")
            setattr(self, name, values)
        if self.charts is not None:
            self.charts = np.asarray(self.charts, np.int64)
            if self.charts.shape != (F,) or (F and self.charts.min() < 0):
                raise BTFError(f"{where}: charts must be one index >= 0 per triangle, got shape {self.charts.shape}")
        if self.face_sizes is not None:
            self.face_sizes = np.asarray(self.face_sizes, np.int64)
            if (self.face_sizes < 3).any() or int((self.face_sizes - 2).sum()) != F:
                raise BTFError(f"{where}: face sizes do not match the {F} triangles")
        if self.up_axis not in ("Y", "Z"):
            raise BTFError(f"{where}: up axis must be Y or Z, got {self.up_axis!r}")

    # -- reading attributes ----------------------------------------------------------
    def require_uv(self) -> None:
        """BTFError naming the source when the mesh has no texture coordinates (a BTF needs them)."""
        if self.uv is None:
            raise BTFError(f"{self.source}: mesh has no texture coordinates; run `usdbtf unwrap {self.source}` first")

    def is_per_corner(self, values: np.ndarray) -> bool:
        """Whether ``values`` (one of the attributes) is per corner (F, 3, k)."""
        return values.ndim == 3

    def corner(self, values: np.ndarray | None = None) -> np.ndarray:
        """(F, 3, k) per-corner values of a per-vertex (N, k) or per-corner (F, 3, k) array;
        default the corner positions (F, 3, 3)."""
        values = self.points if values is None else values
        return values if values.ndim == 3 else values[self.triangles]

    def face_areas(self) -> np.ndarray:
        """(F,) triangle areas, square metres."""
        p = self.points[self.triangles]
        return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)

    def area(self) -> float:
        """Surface area, square metres."""
        return float(self.face_areas().sum())

    def bounds(self) -> np.ndarray:
        """(2, 3) lowest and highest corner of the triangles' bounding box, metres."""
        p = self.corner().reshape(-1, 3)
        return np.stack([p.min(axis=0), p.max(axis=0)])

    def polygons(self) -> tuple[np.ndarray, np.ndarray]:
        """The source's polygons: vertex counts (P,) and, per polygon corner in order, its index
        into the flattened triangle corners (F * 3,) -- ``triangles.ravel()[ids]`` are the
        polygons' point indices, ``corner(values).reshape(-1, k)[ids]`` their face-varying values."""
        F = len(self.triangles)
        if self.face_sizes is None:
            return np.full(F, 3, np.int64), np.arange(3 * F)
        # Fan (0, i, i + 1): corners 0-2 of a polygon are its first triangle's, corner k >= 3 is
        # the last corner of its triangle k - 2.
        sizes = self.face_sizes
        first_tri = np.repeat(np.cumsum(sizes - 2) - (sizes - 2), sizes)
        k = np.arange(int(sizes.sum())) - np.repeat(np.cumsum(sizes) - sizes, sizes)
        return sizes.copy(), np.where(k < 3, 3 * first_tri + k, 3 * (first_tri + k - 2) + 2)

    # -- derived meshes ----------------------------------------------------------------
    def split_corners(self) -> "Mesh":
        """The same surface with every attribute per vertex: each point is split into one copy
        per distinct combination of its corners' values (rounded to 1e-9), e.g. along texture
        seams.  Positions are unchanged; the copies come in sorted (point, values) order.
        Returns ``self`` when nothing is per corner."""
        per_corner = [n for n in ATTRIBUTES if getattr(self, n) is not None and getattr(self, n).ndim == 3]
        if not per_corner:
            return self
        flat = self.triangles.ravel()
        key = np.concatenate([flat[:, None].astype(np.float64)]
                             + [np.round(getattr(self, n).reshape(len(flat), -1), 9) for n in per_corner], axis=1)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        changes = {"points": self.points[flat[first]], "triangles": inverse.ravel().reshape(-1, 3)}
        for name in ATTRIBUTES:
            values = getattr(self, name)
            if values is None:
                continue
            changes[name] = (values.reshape(len(flat), -1) if values.ndim == 3 else values[flat])[first]
        return replace(self, **changes)

    def compacted(self) -> "Mesh":
        """Without points no triangle uses (per-vertex attributes follow); ``self`` if none."""
        used = np.zeros(len(self.points), bool)
        used[self.triangles.ravel()] = True
        if used.all():
            return self
        new_index = np.cumsum(used) - 1
        changes = {"points": self.points[used], "triangles": new_index[self.triangles]}
        for name in ATTRIBUTES:
            values = getattr(self, name)
            if values is not None and values.ndim == 2:
                changes[name] = values[used]
        return replace(self, **changes)

    def without_triangles(self, drop: np.ndarray, note: str) -> "Mesh":
        """A copy without the triangles where ``drop`` (F,) is True (per-corner attributes and
        charts follow; the polygon structure is given up), ``note`` added to :attr:`notes`."""
        if not drop.any():
            return self
        keep = ~drop
        if not keep.any():
            raise BTFError(f"{self.source}: every triangle is degenerate (the mesh has zero surface area)")
        changes = {"triangles": self.triangles[keep], "face_sizes": None, "notes": self.notes + (note,)}
        for name in ATTRIBUTES:
            values = getattr(self, name)
            if values is not None and values.ndim == 3:
                changes[name] = values[keep]
        if self.charts is not None:
            changes["charts"] = self.charts[keep]
        return replace(self, **changes)

    def without_degenerate(self) -> "Mesh":
        """Without :func:`degenerate_triangles` (no area, no normal), with a note when any were
        dropped; BTFError when nothing is left."""
        drop = degenerate_triangles(self.points, self.triangles)
        return self.without_triangles(drop, f"dropped {int(drop.sum())} degenerate triangles (no area)")

    def with_normals(self) -> "Mesh":
        """``self`` if it has normals, else a copy with :func:`smooth_normals` per vertex."""
        if self.normals is not None:
            return self
        return replace(self, normals=smooth_normals(self.points, self.triangles))

    def with_frames(self) -> "Mesh":
        """A mesh with normals, tangents and bitangents: its own when it has all three, else
        normals as :meth:`with_normals` and frames from the texture coordinates
        (:func:`usdbtf.mesh.frames.tangent_frames`, on :meth:`split_corners`).

        Raises BTFError when the mesh has no texture coordinates."""
        if self.normals is not None and self.tangents is not None and self.bitangents is not None:
            return self
        self.require_uv()
        from .frames import tangent_frames

        mesh = self.split_corners().with_normals()
        tangents, bitangents = tangent_frames(mesh.points, mesh.triangles, mesh.uv, mesh.normals)
        return replace(mesh, tangents=tangents, bitangents=bitangents)

    def corner_frames(self) -> CornerFrames:
        """Positions, normals, tangents, bitangents and st per triangle corner, frames as
        :meth:`with_frames` gives them (BTFError without texture coordinates)."""
        m = self.with_frames()
        return CornerFrames(m.corner(), m.corner(m.normals), m.corner(m.tangents), m.corner(m.bitangents),
                            m.corner(m.uv))

    @classmethod
    def concatenate(cls, meshes: list["Mesh"], **kw) -> "Mesh":
        """One mesh of several (points and triangles appended, in order).  An attribute is kept
        when every part has it, per corner if any part has it per corner; ``kw`` sets the
        remaining fields (name, source, ...)."""
        offsets = np.cumsum([0] + [len(m.points) for m in meshes])
        fields = {"points": np.concatenate([m.points for m in meshes]),
                  "triangles": np.concatenate([m.triangles + o for m, o in zip(meshes, offsets)])}
        for name in ATTRIBUTES:
            parts = [getattr(m, name) for m in meshes]
            if all(p is not None for p in parts):
                corner = any(p.ndim == 3 for p in parts)
                fields[name] = np.concatenate([m.corner(p) if corner else p for m, p in zip(meshes, parts)])
        if all(m.charts is not None for m in meshes):
            fields["charts"] = np.concatenate([m.charts for m in meshes])
        if all(m.face_sizes is not None for m in meshes):
            fields["face_sizes"] = np.concatenate([m.face_sizes for m in meshes])
        fields["notes"] = tuple(n for m in meshes for n in m.notes)
        fields.update(kw)
        return cls(**fields)

    @classmethod
    def swatch(cls, width_m: float, height_m: float) -> "Mesh":
        """A quad of the tile's physical size in the XY plane, facing +Z, centred on the origin;
        its texture axes are the sample's: +s along +X (image right), +t along +Y (image up)."""
        w, h = width_m / 2.0, height_m / 2.0
        ones = np.ones((4, 3))
        return cls(np.array([[-w, -h, 0], [w, -h, 0], [w, h, 0], [-w, h, 0]], np.float64),
                   np.array([[0, 1, 2], [0, 2, 3]]), uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64),
                   normals=ones * [0, 0, 1], tangents=ones * [1, 0, 0], bitangents=ones * [0, 1, 0],
                   face_sizes=np.array([4]), name="swatch", source="swatch")


def weld(points: np.ndarray, decimals: int = 9) -> np.ndarray:
    """(N,) id per vertex, equal for vertices at the same position (topology across split seams)."""
    _, inverse = np.unique(np.round(points, decimals), axis=0, return_inverse=True)
    return inverse.ravel()


def face_neighbours(faces_welded: np.ndarray) -> np.ndarray:
    """(F, 3) face across edge i (corners i, i+1) of each face, -1 on boundaries.

    faces_welded : (F, 3) vertex ids welded by position (so split seams still connect).
    Non-manifold edges pair their first two faces.
    """
    F = len(faces_welded)
    a = faces_welded
    edges = np.stack([a, np.roll(a, -1, axis=1)], axis=2).reshape(-1, 2)          # (3F, 2)
    key = np.sort(edges, axis=1)
    order = np.lexsort((np.arange(3 * F), key[:, 1], key[:, 0]))
    ks = key[order]
    same = (ks[1:] == ks[:-1]).all(axis=1)
    out = np.full(3 * F, -1, np.int64)
    first = order[:-1][same]
    second = order[1:][same]
    keep = out[first] < 0                                 # a third face on the edge is ignored
    out[first[keep]] = second[keep] // 3
    out[second[keep]] = first[keep] // 3
    return out.reshape(F, 3)


def chart_border_edges(welded: np.ndarray, face_chart: np.ndarray, neighbours: np.ndarray | None = None):
    """The mesh edges between two charts, each once: (f, i, g, ja, jb), arrays of length E.

    Edge i of face f (its corners i, i + 1) borders face g of another chart (f < g); ja and jb
    are g's corners at the same two vertices (g's corner order may differ).

    welded : (F, 3) vertex ids welded by position (:func:`weld`); face_chart : (F,) chart per
    face; neighbours : :func:`face_neighbours` of ``welded`` when the caller has it."""
    neighbours = face_neighbours(welded) if neighbours is None else neighbours
    f, i = np.nonzero(neighbours >= 0)
    g = neighbours[f, i]
    cross = (face_chart[f] != face_chart[g]) & (f < g)
    f, i, g = f[cross], i[cross], g[cross]
    ja = np.argmax(welded[g] == welded[f, i][:, None], axis=1)
    jb = np.argmax(welded[g] == welded[f, (i + 1) % 3][:, None], axis=1)
    return f, i, g, ja, jb


def degenerate_triangles(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(F,) bool: triangles without area -- repeated or collinear corners (twice the area at
    most 1e-12 of the longest edge squared, so rounding does not hide them)."""
    p = points[triangles]
    edges = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]], axis=1)
    longest2 = np.einsum("fed,fed->fe", edges, edges).max(axis=1)
    twice_area = np.linalg.norm(np.cross(edges[:, 0], -edges[:, 2]), axis=1)
    return ~(twice_area > _DEGENERATE * longest2)


def smooth_normals(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(N, 3) area-weighted vertex normals, smooth across vertices split at the same position.

    Where the incident faces cancel (both sides of a sheet meet at a vertex) the normal of the
    largest incident face is used instead, so no normal of a used vertex is zero or NaN
    (vertices no triangle uses get zero: drop them first, :meth:`Mesh.compacted`)."""
    p = points[triangles]
    face_n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])        # length = 2 x area
    ids = weld(points)
    acc = np.zeros((ids.max() + 1, 3))
    mag = np.zeros(ids.max() + 1)
    face_len = np.linalg.norm(face_n, axis=1)
    for corner in range(3):
        np.add.at(acc, ids[triangles[:, corner]], face_n)
        np.add.at(mag, ids[triangles[:, corner]], face_len)
    cancelled = np.flatnonzero(np.linalg.norm(acc, axis=1) <= 1e-9 * mag)
    cancelled = cancelled[mag[cancelled] > 0]
    if len(cancelled):
        # Per welded vertex, its largest incident face: sort corners by (vertex, area).
        corner_ids = ids[triangles].ravel()
        corner_face = np.repeat(np.arange(len(triangles)), 3)
        order = np.lexsort((face_len[corner_face], corner_ids))
        last = np.flatnonzero(np.r_[corner_ids[order][1:] != corner_ids[order][:-1], True])
        largest = np.zeros(len(acc), np.int64)
        largest[corner_ids[order][last]] = corner_face[order][last]
        acc[cancelled] = face_n[largest[cancelled]]
    n = acc[ids]
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
