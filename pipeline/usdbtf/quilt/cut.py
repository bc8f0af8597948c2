"""Minimum-error boundary cut (Efros & Freeman 2001): a dynamic-programming path through an
overlap strip, old texels on one side of it and the new block's on the other.

The path moves one row per step and at most one column sideways, so it is 8-connected and
splits the strip in two.  The loop is over the strip's rows (B of them), each step a vector
operation over its columns.
"""
from __future__ import annotations

import numpy as np

__all__ = ["min_cut_columns", "keep_old_mask"]


def min_cut_columns(err: np.ndarray) -> np.ndarray:
    """(n,) int column of the cheapest top-to-bottom path through ``err`` (n rows x w columns)."""
    n, w = err.shape
    cost = err.astype(np.float64)
    for y in range(1, n):
        prev = cost[y - 1]
        best = prev.copy()                                    # came from column c, c-1 or c+1
        np.minimum(best[1:], prev[:-1], out=best[1:])
        np.minimum(best[:-1], prev[1:], out=best[:-1])
        cost[y] += best
    rows = cost.tolist()
    col = rows[-1].index(min(rows[-1]))                       # ties: the leftmost, deterministically
    path = np.empty(n, np.intp)
    path[-1] = col
    for y in range(n - 1, 0, -1):
        lo = max(col - 1, 0)
        above = rows[y - 1][lo:col + 2]
        col = lo + above.index(min(above))
        path[y - 1] = col
    return path


def keep_old_mask(err: np.ndarray, widths: tuple[int, int, int, int]) -> np.ndarray:
    """(B, B) bool: texels of a block that keep the old (already placed) value.

    err : (B, B) squared difference between old and new texels (0 where nothing was placed).
    widths : overlap widths on the (left, top, right, bottom) sides, 0 for no neighbour there.
    A texel keeps the old value when it lies on the old side of any side's cut.
    """
    B = err.shape[0]
    keep = np.zeros(err.shape, bool)
    cols = np.arange(B)
    left, top, right, bottom = widths
    if left:
        keep |= cols[None, :] < min_cut_columns(err[:, :left])[:, None]
    if right:
        keep |= cols[None, ::-1] < min_cut_columns(err[:, ::-1][:, :right])[:, None]
    if top:
        keep |= cols[:, None] < min_cut_columns(err[:top, :].T)[None, :]
    if bottom:
        keep |= cols[::-1, None] < min_cut_columns(err[::-1][:bottom, :].T)[None, :]
    return keep
