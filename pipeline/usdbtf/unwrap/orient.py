"""Chart orientation: turn each chart of an atlas by a quarter turn so that the texture's axes
continue across as many chart borders as the surface allows.

A quilted texture runs along its chart's texel axes.  Where two charts meet on the surface with
their texel axes turned against each other, a directional material (ridges, a weave, brushed
metal) turns at the border: its ridges cannot continue however well the quilt matches there
(measured on a box with its own UVs kept, 64² ridged fabric: borders turned by 90 or 270 degrees
at 2-4x the material's natural neighbour difference, aligned ones at about 1x).  xatlas and a
user's UVs orient every chart independently; this pass chooses, per chart, one of the four
rotations by multiples of 90 degrees (never a mirror: that would flip the BTF frame's
handedness) that best align the charts across their borders, then packs the turned charts
again at the same texel density.

The turn across a border is measured on the surface: for every mesh edge whose two triangles
lie in different charts, the angle from the edge's direction in one chart's texture space to
its direction in the other's (both charts map the surface conformally up to stretch, so that
angle is how far one chart's axes are turned against the other's there).  The pass maximises
sum over borders of length x w(turn after the rotations) (w: 1 for no turn, 1/2 for a half
turn, 0 for a quarter turn), exactly (all 4^(n-1) choices) for
up to :data:`EXACT_CHARTS` charts, else greedily from the largest chart with sweeps of single
changes until none improves.  Not every border can be aligned: on a closed surface the axes
must turn somewhere (on a box, 4 of its 12 edges at least), and the pass puts those turns on
the shortest borders.
"""
from __future__ import annotations

import itertools
import logging
from dataclasses import replace

import numpy as np

from ..mesh import chart_border_edges, weld
from .atlas import xatlas_charts

log = logging.getLogger(__name__)

__all__ = ["chart_turns", "best_quarter_turns", "aligned_share", "orient_charts", "EXACT_CHARTS"]

#: Up to this many charts every combination of quarter turns is tried (4^(n-1) of them).
EXACT_CHARTS = 7


def chart_turns(points: np.ndarray, faces: np.ndarray, st_texels: np.ndarray, face_chart: np.ndarray) -> dict:
    """How each pair of adjacent charts is turned against the other across their border.

    Parameters
    ----------
    points : (V, 3) float
        Atlas vertex positions (metres); vertices split along chart seams may repeat positions.
    faces : (F, 3) int
        Atlas vertex indices per triangle.
    st_texels : (V, 2) float
        Texture coordinates in texels (s * width, t * height): one unit is one texel both ways.
    face_chart : (F,) int
        Chart per triangle.

    Returns
    -------
    dict
        {(a, b) with a < b: complex}: sum over the border's mesh edges of edge length (metres)
        x exp(i turn), where turn (radians) is the angle from the edge's direction in chart a's
        texture space to its direction in chart b's.  |value| / total length near 1: one
        consistent turn along the border.
    """
    f, i, g, ja, jb = chart_border_edges(weld(points)[faces], face_chart)
    if not len(f):
        return {}
    e_f = st_texels[faces[f, (i + 1) % 3]] - st_texels[faces[f, i]]
    e_g = st_texels[faces[g, jb]] - st_texels[faces[g, ja]]
    turn = np.arctan2(e_g[:, 1], e_g[:, 0]) - np.arctan2(e_f[:, 1], e_f[:, 0])
    length = np.linalg.norm(points[faces[f, (i + 1) % 3]] - points[faces[f, i]], axis=1)
    a, b = face_chart[f], face_chart[g]
    # Stored as (low chart, high chart): the turn from b to a is minus the turn from a to b.
    z = length * np.exp(1j * np.where(a < b, turn, -turn))
    out: dict = {}
    for lo, hi, value in zip(np.minimum(a, b), np.maximum(a, b), z):
        key = (int(lo), int(hi))
        out[key] = out.get(key, 0j) + complex(value)
    return out


def _edge_weight(turns: dict) -> dict:
    """{(a, b): (sum len exp(i turn), sum len exp(2 i turn), sum len)} -- the sums the
    alignment needs -- from :func:`chart_turns`'s per-pair sums.  (Per pair the border's turn
    is one angle up to rounding, so exp(2 i turn) is taken from the mean direction.)"""
    out = {}
    for key, z in turns.items():
        length = abs(z)
        unit = z / length if length > 0 else 1.0
        out[key] = (z, length * unit * unit, length)
    return out


#: Weights of the alignment, w(turn) = C0 + C1 cos(turn) + C2 cos(2 turn): 1 for no turn, 0 for a
#: quarter turn, 1/2 for a half turn (ridges and brushing continue as lines, an asymmetric weave
#: does not).
C0, C1, C2 = 0.375, 0.25, 0.375


def _pair_alignment(z1: complex, z2: complex, length: float, k: int) -> float:
    """Length-weighted w(turn) of one border after the two charts' turns differ by k quarters."""
    return C0 * length + C1 * (z1 * 1j ** k).real + C2 * (z2 * 1j ** (2 * k)).real


def _alignment(weights: dict, quarter: np.ndarray) -> float:
    """Sum over borders of length x w(turn after turning chart c by quarter[c] x 90 degrees).
    weights : :func:`_edge_weight` of the turns."""
    return float(sum(_pair_alignment(*w, int(quarter[b] - quarter[a])) for (a, b), w in weights.items()))


def best_quarter_turns(turns: dict, n_charts: int, chart_area: np.ndarray) -> np.ndarray:
    """(n_charts,) quarter turns (0-3, counter-clockwise in st) that maximise the alignment.

    turns : :func:`chart_turns`.  chart_area : (n_charts,) texture area, for the order of the
    greedy pass (the largest chart of each connected piece keeps its orientation).
    Deterministic; ties keep the smaller turn."""
    quarter = np.zeros(n_charts, np.int64)
    if not turns:
        return quarter
    charts = sorted({c for pair in turns for c in pair})
    weights = _edge_weight(turns)
    if len(charts) <= EXACT_CHARTS:
        rest = charts[1:]
        best, best_score = quarter.copy(), _alignment(weights, quarter)
        for combo in itertools.product(range(4), repeat=len(rest)):
            trial = np.zeros(n_charts, np.int64)
            trial[rest] = combo
            score = _alignment(weights, trial)
            if score > best_score + 1e-12:
                best, best_score = trial, score
        # Keep the largest chart as it was: turn everything by its inverse (alignment is unchanged).
        largest = max(charts, key=lambda c: (chart_area[c], -c))
        best[charts] = (best[charts] - best[largest]) % 4
        return best
    adjacency: dict = {}
    for (a, b), (z1, z2, length) in weights.items():
        adjacency.setdefault(a, []).append((b, (z1, z2, length)))
        adjacency.setdefault(b, []).append((a, (np.conj(z1), np.conj(z2), length)))

    def gain(c: int, q: int, only_placed: bool = False) -> float:
        # Alignment of chart c's borders if c takes q quarter turns (neighbours as they are).
        return sum(_pair_alignment(*w, int(quarter[d] - q)) for d, w in adjacency.get(c, ())
                   if placed[d] or not only_placed)

    placed = np.zeros(n_charts, bool)
    for start in sorted(charts, key=lambda c: (-chart_area[c], c)):
        if placed[start]:
            continue
        placed[start] = True
        queue = [start]
        while queue:
            c = queue.pop(0)
            for d, _ in sorted(adjacency.get(c, ()), key=lambda e: (-e[1][2], e[0])):
                if placed[d]:
                    continue
                # Only the placed neighbours count while placing.
                quarter[d] = max(range(4), key=lambda q: (round(gain(d, q, only_placed=True), 12), -q))
                placed[d] = True
                queue.append(d)
    for _ in range(20):                 # sweeps of single changes until none improves
        changed = False
        for c in charts:
            scores = [gain(c, q) for q in range(4)]
            q = int(np.argmax(np.round(scores, 12)))
            if scores[q] > scores[quarter[c]] + 1e-12:
                quarter[c] = q
                changed = True
        if not changed:
            break
    return quarter


def orient_charts(atlas, points: np.ndarray, padding: int):
    """``atlas`` (:class:`~usdbtf.unwrap.atlas.Atlas`) with its charts turned by
    :func:`best_quarter_turns` and packed again by xatlas at the same texel density.

    points : (N, 3) the mesh's points (metres), indexed by ``atlas.vertex_of``.
    padding : gutter texels between charts.

    Returns (atlas, info): the same ``atlas`` object when no chart needs turning; info is
    {"quarter_turns": per chart, "aligned_before", "aligned_after"} (aligned: the share of
    border length whose turn is within 45 degrees of none)."""
    positions = points[atlas.vertex_of]
    size = np.array([atlas.width, atlas.height], np.float64)
    texels = atlas.st * size
    turns = chart_turns(positions, atlas.faces, texels, atlas.face_chart)
    n = atlas.charts
    corners = texels[atlas.faces]
    u, v = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
    area = 0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    chart_area = np.bincount(atlas.face_chart, weights=area, minlength=n)
    quarter = best_quarter_turns(turns, n, chart_area)
    info = {"quarter_turns": [int(q) for q in quarter], "aligned_before": aligned_share(turns, np.zeros(n, int)),
            "aligned_after": aligned_share(turns, quarter)}
    if not quarter.any():
        return atlas, info
    turned = texels.copy()
    vertex_chart = np.zeros(len(texels), np.int64)
    vertex_chart[atlas.faces.ravel()] = np.repeat(atlas.face_chart, 3)
    for c in np.flatnonzero(quarter):
        mine = vertex_chart == c
        centre = turned[mine].mean(axis=0)
        d = turned[mine] - centre
        for _ in range(int(quarter[c])):                  # (x, y) -> (-y, x): a quarter turn
            d = np.stack([-d[:, 1], d[:, 0]], axis=1)
        turned[mine] = centre + d
    # xatlas finds charts by shared vertices: give it one vertex per (position, st), so a
    # triangle soup's charts stay whole.
    key = weld(np.concatenate([positions, turned], axis=1))
    first = np.full(int(key.max()) + 1, -1, np.int64)
    first[key[::-1]] = np.arange(len(key))[::-1]                 # the first atlas vertex of each key
    vmap, faces, st, face_chart, width, height = _pack(turned[first], key[atlas.faces], padding)
    vmap = first[vmap]
    log.info(f"turned {int((quarter > 0).sum())} of {n} charts by quarter turns: border length aligned "
             f"{info['aligned_before']:.0%} -> {info['aligned_after']:.0%}; atlas {atlas.width}x{atlas.height} -> "
             f"{width}x{height}")
    return replace(atlas, vertex_of=atlas.vertex_of[vmap], faces=faces, st=st, face_chart=face_chart,
                   width=width, height=height), info


def aligned_share(turns: dict, quarter: np.ndarray) -> float:
    """Share of border length whose turn, after the quarter turns, is within 45 degrees of 0."""
    total = sum(abs(z) for z in turns.values()) or 1.0
    return float(sum(abs(z) for (a, b), z in turns.items()
                     if (z * 1j ** int(quarter[b] - quarter[a])).real > abs(z) * np.cos(np.pi / 4)) / total)


def _pack(texels: np.ndarray, faces: np.ndarray, padding: int):
    """Pack charts given in texel units with xatlas, without rotating or scaling them, into a
    square atlas (xatlas chooses where each chart goes; the chart is moved there as it is).
    Returns (vmap (M,), faces (F, 3), st (M, 2) in [0, 1], face_chart (F,), width, height)."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_uv_mesh(np.ascontiguousarray(texels, np.float32), np.ascontiguousarray(faces, np.uint32))
    pack = xatlas.PackOptions()
    pack.rotate_charts = False          # the turns were chosen; xatlas may not add its own
    pack.rotate_charts_to_axis = False
    pack.texels_per_unit = 1.0          # one unit is one texel: the density stays as it was
    pack.padding = int(padding)
    pack.bilinear = True
    pack.resolution = 0
    atlas.generate(xatlas.ChartOptions(), pack)
    vmap, new_faces, placed, face_chart = xatlas_charts(atlas)
    # xatlas rounds each chart's extent up to whole texels, scaling it by up to ~1.5 %: take only
    # where it put the chart (its lowest corner) and move the chart there unscaled, so every edge
    # keeps its length in texels (the density) and the chart still fits its slot.
    mine = texels[vmap]
    n = int(face_chart.max()) + 1
    low_placed = np.full((n, 2), np.inf)
    low_mine = np.full((n, 2), np.inf)
    corner_chart = np.repeat(face_chart, 3)
    np.minimum.at(low_placed, corner_chart, placed[new_faces.ravel()])
    np.minimum.at(low_mine, corner_chart, mine[new_faces.ravel()])
    vertex_chart = np.zeros(len(vmap), np.int64)
    vertex_chart[new_faces.ravel()] = corner_chart
    moved = mine + (low_placed - low_mine)[vertex_chart]
    # A square atlas (see xatlas_charts; a 263 x 299 one would read as 1.14x stretched).
    side = max(int(atlas.width), int(atlas.height), int(np.ceil(moved.max())))
    return vmap, new_faces, np.clip(moved / side, 0.0, 1.0), face_chart, side, side
