"""Boundary cut between a new block and the texels already placed, through each overlap strip.

Efros & Freeman (2001) cut along the path of least ``|old - new|^2`` over the strip's texels, a
proxy for what the seam looks like.  What an observer sees, and what :mod:`.seams` measures, is
the difference between the two texels the cut makes neighbours: ``old(a)`` next to ``new(b)``.
The cut here minimises exactly that, summed over the neighbour pairs it creates.  In a left
strip, row ``y`` keeps the old texels left of column ``k_y`` and takes the new block's from
``k_y`` on, which makes the horizontal pair ``old(y, k_y - 1) | new(y, k_y)``; where two
consecutive rows cut at different columns, the texels between them are old above new (or new
above old), vertical pairs too.  So a seam settles where the two sides continue each other,
often where the material itself is smooth, instead of merely where the overlap agrees.

Measured on the scene benchmark's 64^2 tiny materials quilted over their meshes' charts
(`benchmarks/bench_quilt_seams.py --size 64`, blocks of 16 and 3-texel overlaps both ways,
seeds 0-1), seams inside charts against the natural neighbour difference went from 1.72 to
1.42 (pebbles on the sphere), 1.33 to 1.08 (moss on the cylinder), 1.34 to 1.08 (fabric on the
box) with this cut alone, at the same quilting time; `benchmarks/RESULTS.md` has the table.

A dynamic program over the strip's rows (B of them, a vector operation over the columns each),
any column to any column, the vertical pairs' cost summed against an indicator of the columns
between two cuts.  Features are image features (:func:`~.features.image_features`): squared
distances are image differences summed over every (view, light) sample.
"""
from __future__ import annotations

import numpy as np

__all__ = ["pair_cut_columns", "keep_old_mask"]


def _squared(d: np.ndarray) -> np.ndarray:
    """(...,) squared norms of (..., D) differences, float64."""
    return np.einsum("...d,...d->...", d, d, dtype=np.float64)


def pair_cut_columns(old: np.ndarray, new: np.ndarray, placed: np.ndarray) -> np.ndarray:
    """(S, n) int: per strip and row, the first column (1..w) that takes the new block.

    old : (S, n, w, D) features of the old texels in S left overlap strips of width w.
    new : (S, n, w + 1, D) features of the new block's texels there and one column beyond.
    placed : (S, n, w) bool, where an old texel exists (a missing one costs nothing: new goes there).
    Minimises, per strip, the summed squared difference of the (old, new) neighbour pairs the cut
    creates.  Strips are batched so that one loop over the rows serves all of a block's sides.
    """
    S, n, w = placed.shape
    weight = placed.astype(np.float64)
    # Horizontal pair of a cut at k (1..w): old(y, k - 1) | new(y, k).
    h = _squared(old - new[:, :, 1:]) * weight                                 # (S, n, w), column k - 1
    # Vertical pairs between rows y and y + 1 at column c: new above old when k_y <= c < k_{y+1},
    # old above new when k_{y+1} <= c < k_y.
    new_above = _squared(new[:, :-1, :w] - old[:, 1:]) * weight[:, 1:]        # (S, n - 1, w)
    old_above = _squared(old[:, :-1] - new[:, 1:, :w]) * weight[:, :-1]
    # trans[y, s, k, k2]: the vertical pairs' cost of cuts k (row y) and k2 (row y + 1), summed
    # against the indicator of the columns in between (einsum's own loops, not BLAS: the same
    # bits on every machine).
    pairs = np.concatenate([new_above, old_above], axis=2)                     # (S, n - 1, 2w)
    trans = np.einsum("syc,cq->ysq", pairs, _between(w)).reshape(n - 1, S, w, w)
    h = np.ascontiguousarray(h.transpose(1, 0, 2))                             # (n, S, w)
    totals = np.empty((n - 1, S, w, w))
    cost = h[0]
    for y in range(n - 1):
        np.add(cost[:, :, None], trans[y], out=totals[y])
        cost = totals[y].min(axis=1)
        cost += h[y + 1]
    back = totals.argmin(axis=2)                                              # ties: the lowest column
    path = np.empty((S, n), np.intp)
    strips = np.arange(S)
    path[:, -1] = np.argmin(cost, axis=1)
    for y in range(n - 2, -1, -1):
        path[:, y] = back[y, strips, path[:, y + 1]]
    return path + 1


_BETWEEN: dict[int, np.ndarray] = {}


def _between(w: int) -> np.ndarray:
    """(2w, w * w) float64 indicator: row c is 1 at (k, k2) (cuts of two consecutive rows, 1..w)
    when column c lies between them new above old (k <= c < k2); row w + c, old above new
    (k2 <= c < k)."""
    if w not in _BETWEEN:
        k = np.arange(1, w + 1)
        c = np.arange(w)[:, None, None]
        src, dst = k[None, :, None], k[None, None, :]
        rows = np.concatenate([(src <= c) & (c < dst), (dst <= c) & (c < src)])
        _BETWEEN[w] = rows.reshape(2 * w, w * w).astype(np.float64)
    return _BETWEEN[w]


def keep_old_mask(image: np.ndarray, old: np.ndarray, new: np.ndarray, placed: np.ndarray,
                  widths: tuple[int, int, int, int]) -> np.ndarray:
    """(B, B) bool: texels of a block that keep the old (already placed) value.

    image : (P, D) image features of the source texels.  old, new : (B, B) int source texel
    indices of the old and the new block (old: anything where ``placed`` is False).
    placed : (B, B) bool.  widths : overlap widths on the (left, top, right, bottom) sides, 0 for
    no neighbour there.  A texel keeps the old value when it lies on the old side of any side's cut.
    """
    B = old.shape[0]
    keep = np.zeros((B, B), bool)
    cols = np.arange(B)
    old = np.where(placed, old, 0)
    left, top, right, bottom = widths
    # Each side seen as a left strip, and the way back to block coordinates.
    sides = ((left, lambda a: a, lambda m: m),
             (right, lambda a: a[:, ::-1], lambda m: m[:, ::-1]),
             (top, lambda a: a.T, lambda m: m.T),
             (bottom, lambda a: a[::-1].T, lambda m: m.T[::-1]))
    for width in sorted({min(w, B - 1) for w in widths if w}):
        group = [(view, back) for w, view, back in sides if w and min(w, B - 1) == width]
        o = np.stack([view(old)[:, :width] for view, _ in group])
        nw = np.stack([view(new)[:, :width + 1] for view, _ in group])
        p = np.stack([view(placed)[:, :width] for view, _ in group])
        cuts = pair_cut_columns(image[o], image[nw], p)
        for (_, back), k in zip(group, cuts):
            keep |= back(cols[None, :] < k[:, None])
    return keep
