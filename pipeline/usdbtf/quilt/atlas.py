"""Quilting straight into a mesh's texture atlas.

Charts are quilted one at a time, each on its own canvas covering its bounding box, with
blocks only where the chart (plus its one-texel rim) is.  Chart borders are seamed as far as
quilting allows: before a chart is quilted, the triangles across its border that belong to
charts already done are *unfolded* into its texture space (rotated about the shared edge
into the chart's plane, two rings deep) and their quilted texels placed on the canvas as
fixed "ghost" texels.  Block matching then sees what lies across the border on the
surface, so the chart grows to continue its neighbours, and the ghosts stay in the chart's
rim (the texels just outside its triangles that bilinear filtering reads), so at the border
itself the texture is the neighbour's continued (measured: the squared difference across
chart borders falls 2-3x, see tests/test_unwrap.py).  (The tangent frames on the two
sides still differ by the charts' relative rotation: no atlas can avoid that.)  Charts are
visited breadth-first over the chart adjacency graph from the largest, so every chart but
the first of each connected piece has a done neighbour.

Afterwards every gutter texel copies its nearest chart texel (Voronoi fill), so bilinear and
mip filtering near chart edges never read unrelated data.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import cv2
import numpy as np

from ..compress.format import CompressedBTF
from ..errors import BTFError
from ..mesh import Mesh, chart_border_edges, face_neighbours, weld
from ..raster import barycentrics, pixel_barycentrics, rasterize, st_to_texels
from ..unwrap import UnwrapResult, read_unwrap
from .core import QuiltOptions, QuiltResult, prepare_source, quilt_record
from .engine import Grid, grid_for, place_blocks
from .seams import pair_error, seam_error_all_samples

__all__ = ["quilt_atlas", "face_neighbours", "chart_border_error"]

_RINGS = 2
#: Texels inside a chart, from a border with an earlier-quilted chart, that continue that chart:
#: every texel a point on the border can fall in (its centre within sqrt(2)/2 of the border).
_BAND = 1.0
log = logging.getLogger(__name__)


def _unfold(a2, b2, anchor2, pa, pb, pr):
    """2-D position of vertex r of triangle (a, b, r) unfolded across edge a-b, on the side
    opposite ``anchor2``, with the edge's own scale (a similarity of the 3-D triangle)."""
    e = pb - pa
    e2 = b2 - a2
    len3, len2 = np.linalg.norm(e), np.linalg.norm(e2)
    if len3 < 1e-15 or len2 < 1e-12:
        return None
    along = float(np.dot(pr - pa, e)) / len3 ** 2
    height = np.linalg.norm((pr - pa) - along * e) / len3
    perp = np.array([-e2[1], e2[0]])
    side = np.sign(perp @ (anchor2 - a2)) or 1.0
    return a2 + along * e2 - side * height * perp


def _ghost_triangles(c, face_chart, done_chart, neighbours, welded, points, corner_xy):
    """Triangles of done charts across chart c's border, unfolded into c's texel space.

    welded : (F, 3) welded vertex ids per face; points : (V, 3) position per welded id.
    Returns (unfolded (n, 3, 2) in the neighbour face's corner order, their face ids (n,),
    ring (n,) 1 or 2, apex (n,): the corner not on c's border for ring 1 (the other two are
    c's own corners), -1 for ring 2)."""
    out_xy, out_face, out_ring, out_apex = [], [], [], []
    seen = set()
    frontier = []
    for f in np.flatnonzero(face_chart == c):
        for i in range(3):
            g = neighbours[f, i]
            if g >= 0 and face_chart[g] != c and done_chart[face_chart[g]]:
                frontier.append((f, corner_xy[f], g))
    for ring in range(1, _RINGS + 1):
        nxt = []
        for f, f_xy, g in frontier:
            if g in seen:
                continue
            wf, wg = welded[f], welded[g]
            shared = [v for v in wg if v in wf]
            if len(shared) != 2:
                continue
            ia, ib = (int(np.flatnonzero(wf == v)[0]) for v in shared)
            ja, jb = (int(np.flatnonzero(wg == v)[0]) for v in shared)
            jr = 3 - ja - jb
            anchor = f_xy[3 - ia - ib]
            r2 = _unfold(f_xy[ia], f_xy[ib], anchor, points[wg[ja]], points[wg[jb]], points[wg[jr]])
            if r2 is None:
                continue
            g_xy = np.empty((3, 2))
            g_xy[ja], g_xy[jb], g_xy[jr] = f_xy[ia], f_xy[ib], r2
            seen.add(g)
            out_xy.append(g_xy)
            out_face.append(g)
            out_ring.append(ring)
            out_apex.append(jr if ring == 1 else -1)
            for i in range(3):
                h = neighbours[g, i]
                if h >= 0 and h not in seen and face_chart[h] != c and done_chart[face_chart[h]]:
                    nxt.append((g, g_xy, h))
        frontier = nxt
    if not out_xy:
        return np.zeros((0, 3, 2)), np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64)
    return (np.asarray(out_xy), np.asarray(out_face, np.int64), np.asarray(out_ring, np.float64),
            np.asarray(out_apex, np.int64))


def _chart_order(charts: np.ndarray, face_chart: np.ndarray, neighbours: np.ndarray) -> list[int]:
    """Breadth-first over chart adjacency, from the largest chart (texels) of each connected piece."""
    n = int(face_chart.max()) + 1
    size = np.bincount(charts[charts >= 0].ravel(), minlength=n)
    adj = [set() for _ in range(n)]
    f, i = np.nonzero(neighbours >= 0)
    for a, b in zip(face_chart[f], face_chart[neighbours[f, i]]):
        if a != b:
            adj[a].add(int(b))
    order, seen = [], np.zeros(n, bool)
    for start in np.argsort(-size, kind="stable"):
        if seen[start]:
            continue
        queue = [int(start)]
        seen[start] = True
        while queue:
            c = queue.pop(0)
            order.append(c)
            for d in sorted(adj[c], key=lambda d: (-size[d], d)):
                if not seen[d]:
                    seen[d] = True
                    queue.append(d)
    return order


def corner_texels(mesh: Mesh, width: int, height: int) -> np.ndarray:
    """(F, 3, 2) triangle corners of an unwrapped ``mesh`` in the texels of its
    ``width`` x ``height`` atlas (x right, y down)."""
    return st_to_texels(mesh.corner(mesh.uv), width, height)


def quilt_atlas(cbtf: CompressedBTF, atlas, opts: QuiltOptions | None = None) -> QuiltResult:
    """Quilt ``cbtf`` into the atlas of ``atlas``: an :class:`~usdbtf.unwrap.UnwrapResult`
    (:func:`usdbtf.unwrap.unwrap`: its mesh's per-corner st and charts, and the chart map) or
    the path of an ``usdbtf unwrap`` layer (read by :func:`~usdbtf.unwrap.read_unwrap`, and
    recorded).  ``opts.ghosts``: match chart borders against their quilted neighbours."""
    layer_path = None
    if not isinstance(atlas, UnwrapResult):
        layer_path = Path(atlas)
        atlas = read_unwrap(layer_path)
    unwrapped, opts = atlas, (opts or QuiltOptions()).resolved(cbtf)
    ghosts = opts.ghosts
    if opts.tileable:
        raise BTFError("--tileable does not apply to an atlas")
    layer, charts = unwrapped.mesh, unwrapped.chart_map
    H, W = unwrapped.atlas.height, unwrapped.atlas.width
    if charts.shape != (H, W):
        raise BTFError(f"chart map is {charts.shape[1]}x{charts.shape[0]}, the atlas {W}x{H}")
    t0 = time.perf_counter()
    source = prepare_source(cbtf, opts)
    rng = np.random.default_rng(opts.seed)
    welded_ids = weld(layer.points)
    welded = welded_ids[layer.triangles]
    welded_points = np.zeros((int(welded_ids.max()) + 1, 3))
    welded_points[welded_ids] = layer.points
    neighbours = face_neighbours(welded)
    corner_xy = corner_texels(layer, W, H)
    face_chart = layer.charts
    n_charts = int(face_chart.max()) + 1
    done = np.zeros(n_charts, bool)
    positions = np.full((H, W), -1, np.int32)
    blocks = ghost_texels = 0
    order = _chart_order(charts, face_chart, neighbours)
    for c in order:
        domain = charts == c
        if not domain.any():
            done[c] = True
            continue
        y0, x0, box_h, box_w = _chart_box(charts, c)
        grid = grid_for(box_w, box_h, opts.block, opts.overlap)
        gh, gw = grid.shape
        local_domain = np.zeros((gh, gw), bool)
        h, w = min(gh, H - y0), min(gw, W - x0)
        local_domain[:h, :w] = domain[y0:y0 + h, x0:x0 + w]
        canvas = np.full((gh, gw), -1, np.int32)
        if ghosts:
            ghost_texels += _place_ghosts(canvas, c, (y0, x0), positions, face_chart, done, neighbours,
                                          welded, welded_points, corner_xy, band=_BAND)
        active = np.array([[local_domain[y:y + opts.block, x:x + opts.block].any() for x in grid.xs]
                           for y in grid.ys])
        # Ghosts are kept where they fall in the chart's rim (texels just outside its triangles
        # that filtering reads): there the texture continues the neighbour's exactly.
        write = local_domain & (canvas < 0)
        blocks += place_blocks(canvas, Grid(grid.ys, grid.xs, grid.shape, False, active), source,
                               tolerance=opts.tolerance, rng=rng, domain=write)
        region = positions[y0:y0 + h, x0:x0 + w]
        region[local_domain[:h, :w]] = canvas[:h, :w][local_domain[:h, :w]]
        done[c] = True
    if ghosts:
        ghost_texels += _continue_rims(positions, charts, order, face_chart, neighbours, welded, welded_points,
                                       corner_xy)
    valid = charts >= 0
    positions = _fill_gutters(positions, valid)
    seconds = time.perf_counter() - t0
    seam = seam_error_all_samples(positions, source.image, cbtf.width, cbtf.n_samples, labels=charts)
    border = chart_border_error(positions, layer, neighbours, source.image, cbtf.width, cbtf.n_samples)
    log.info(f"atlas {W}x{H}: {n_charts} charts, {blocks} blocks, {ghost_texels} ghost texels, "
        f"seam error {seam:.4g} (inside charts), {border:.4g} (across chart borders)")
    record = quilt_record(cbtf, opts, W, H, blocks=blocks, seam=seam, seconds=seconds,
                          atlas={"charts": n_charts, "ghost_texels": int(ghost_texels), "ghosts": bool(ghosts),
                                 "chart_border_error": border, "coverage": float(valid.mean()),
                                 "texels_per_metre": unwrapped.atlas.texels_per_metre or None})
    if layer_path is not None:
        record["atlas"]["layer"] = str(layer_path)
    return QuiltResult(positions, valid, opts, record, cbtf)


def _chart_box(charts: np.ndarray, c: int) -> tuple[int, int, int, int]:
    """(y0, x0, height, width) of chart c's bounding box in the chart map."""
    ys, xs = np.nonzero(charts == c)
    y0, x0 = int(ys.min()), int(xs.min())
    return y0, x0, int(ys.max()) - y0 + 1, int(xs.max()) - x0 + 1


def _continue_rims(positions, charts, order, face_chart, neighbours, welded, points, corner_xy) -> int:
    """Every chart's rim (its texels outside its own triangles, which bilinear filtering reads at
    the border) takes the texels that continue it across the border, from all its neighbours.

    While quilting, a chart's rim continues only the neighbours quilted before it; the first
    chart of a border kept its own blocks there, so at a border lying mid-texel the two sides
    read different surface content (measured on a box whose UVs were packed at another density:
    2.4x the natural neighbour difference across chart boundaries).  Returns the texels set."""
    done = np.ones(int(face_chart.max()) + 1, bool)
    count = 0
    for c in order:
        if not (charts == c).any():
            continue
        y0, x0, h, w = _chart_box(charts, c)
        canvas = np.full((h, w), -1, np.int32)
        _place_ghosts(canvas, c, (y0, x0), positions, face_chart, done, neighbours, welded, points, corner_xy)
        rim = (charts[y0:y0 + h, x0:x0 + w] == c) & (canvas >= 0)
        positions[y0:y0 + h, x0:x0 + w][rim] = canvas[rim]
        count += int(rim.sum())
    return count


def _place_ghosts(canvas, c, origin, positions, face_chart, done, neighbours, welded, points, corner_xy,
                  band: float = 0.0) -> int:
    """Put the unfolded neighbours' quilted texels on chart c's canvas (outside c's own
    triangles); returns how many texels were placed.

    band : also put them on c's own texels whose centres lie within ``band`` texels of a border
    with a done chart, the neighbour's texture continued across the border (read from its rim,
    quilted with it).  The border itself then continues the neighbour exactly, and the quilting
    seam lies ``band`` texels inside c, where block matching against these ghosts put it."""
    tri_xy, tri_face, ring, apex = _ghost_triangles(c, face_chart, done, neighbours, welded, points, corner_xy)
    if not len(tri_xy):
        return 0
    y0, x0 = origin
    gh, gw = canvas.shape
    local = tri_xy - np.array([x0, y0], np.float64)
    raster = rasterize(local, np.repeat(ring[:, None], 3, axis=1), gw, gh)
    own = rasterize(corner_xy[face_chart == c] - np.array([x0, y0], np.float64), None, gw, gh).tri >= 0
    idx, t, bary = pixel_barycentrics(local, raster.tri)
    keep = ~own.ravel()[idx]
    idx, t, bary = idx[keep], t[keep], bary[keep]
    if band > 0:
        b_idx, b_t, b_bary = _border_band(local, apex, own, band)
        idx, t, bary = np.concatenate([idx, b_idx]), np.concatenate([t, b_t]), np.concatenate([bary, b_bary])
    src_xy = np.einsum("nk,nkd->nd", bary, corner_xy[tri_face[t]])
    H, W = positions.shape
    sx = np.clip(np.floor(src_xy[:, 0]).astype(np.int64), 0, W - 1)
    sy = np.clip(np.floor(src_xy[:, 1]).astype(np.int64), 0, H - 1)
    values = positions[sy, sx]
    ok = values >= 0
    canvas.ravel()[idx[ok]] = values[ok]
    return int(ok.sum())


def _border_band(local: np.ndarray, apex: np.ndarray, own: np.ndarray, band: float):
    """Chart c's own texels within ``band`` texels of its border with done charts, each with the
    ring-1 ghost triangle across the nearest border edge and its (extrapolated) barycentrics.

    local : (n, 3, 2) ghost triangles in canvas texels; apex : (n,) their corner off c's border
    (-1: ring 2, skipped); own : (h, w) texels whose centres lie in c's triangles.
    Returns (flat canvas index (m,), triangle (m,), barycentrics (m, 3)); a texel near two
    edges takes the nearer."""
    gh, gw = own.shape
    best_d = np.full(gh * gw, np.inf)
    best_t = np.full(gh * gw, -1, np.int64)
    for t in np.flatnonzero(apex >= 0):
        a, b = (local[t, j] for j in range(3) if j != apex[t])
        lo = np.floor(np.minimum(a, b) - band).astype(np.int64)
        hi = np.ceil(np.maximum(a, b) + band).astype(np.int64)
        xs = np.arange(max(lo[0], 0), min(hi[0], gw - 1) + 1)
        ys = np.arange(max(lo[1], 0), min(hi[1], gh - 1) + 1)
        if not len(xs) or not len(ys):
            continue
        cx, cy = np.meshgrid(xs + 0.5, ys + 0.5)
        p = np.stack([cx.ravel(), cy.ravel()], axis=1)
        e = b - a
        along = np.clip(((p - a) @ e) / max(float(e @ e), 1e-12), 0.0, 1.0)
        d = np.linalg.norm(p - (a + along[:, None] * e), axis=1)
        flat = (np.floor(p[:, 1]).astype(np.int64)) * gw + np.floor(p[:, 0]).astype(np.int64)
        take = (d <= band) & own.ravel()[flat] & (d < best_d[flat])
        best_d[flat[take]] = d[take]
        best_t[flat[take]] = t
    idx = np.flatnonzero(best_t >= 0)
    t = best_t[idx]
    bary = barycentrics(local[t], idx % gw + 0.5, idx // gw + 0.5)
    ok = np.isfinite(bary).all(axis=1)              # (a degenerate ghost triangle continues nothing)
    return idx[ok], t[ok], bary[ok]


def _fill_gutters(positions: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Every texel outside the charts copies the position of its nearest chart texel."""
    filled = positions >= 0
    if filled.all() or not filled.any():
        return positions
    dist, labels = cv2.distanceTransformWithLabels((~filled).astype(np.uint8), cv2.DIST_L2, 5,
                                                   labelType=cv2.DIST_LABEL_PIXEL)
    owners = np.flatnonzero(filled.ravel())
    return positions.ravel()[owners[labels.ravel() - 1]].reshape(positions.shape).astype(np.int32)


def chart_border_error(positions: np.ndarray, layer: Mesh, neighbours: np.ndarray,
                       image_features: np.ndarray, source_width: int, n_samples: int) -> float:
    """Mean squared image difference across chart borders on the surface: along every mesh edge
    whose two faces lie in different charts, points one texel apart are looked up on both
    sides (each face's own texture coordinates, nearest texel), all samples averaged.

    layer : the unwrapped mesh (per-corner st, charts) of the atlas ``positions`` (H, W) covers."""
    H, W = positions.shape
    corner_xy = corner_texels(layer, W, H)
    f, i, g, ja, jb = chart_border_edges(weld(layer.points)[layer.triangles], layer.charts, neighbours)
    if not len(f):
        return 0.0
    a_f, b_f = corner_xy[f, i], corner_xy[f, (i + 1) % 3]
    a_g, b_g = corner_xy[g, ja], corner_xy[g, jb]
    n = np.maximum(1, np.ceil(np.linalg.norm(b_f - a_f, axis=1)).astype(np.int64))
    edge = np.repeat(np.arange(len(f)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n) + 0.5) / np.repeat(n, n)

    def lookup(a, b):
        p = a[edge] + t[:, None] * (b[edge] - a[edge])
        x = np.clip(np.floor(p[:, 0]).astype(np.int64), 0, W - 1)
        y = np.clip(np.floor(p[:, 1]).astype(np.int64), 0, H - 1)
        return positions[y, x]

    return pair_error(image_features, lookup(a_f, b_f), lookup(a_g, b_g), n_samples)
