"""Image quilting (Efros & Freeman 2001) on a canvas of source positions.

The canvas is a position map: for every output texel, the flat index ``y * Ws + x`` of the
source texel it copies (-1 while empty).  Blocks are placed in raster order over a grid;
each is the source block whose features best match what is already on the canvas under
the block (any filled texel, including fixed "ghost" texels a caller put there), chosen at
random among those within ``tolerance`` of the best, then cut into its placed neighbours where
the neighbour pairs the cut creates differ least (:mod:`.cut`).  Working on positions, not
values, means one pass decides the output of every coefficient texture (and every (view,
light) image) at once.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UsageError
from .cut import keep_old_mask
from .matcher import Matcher

__all__ = ["Source", "Grid", "grid_for", "place_blocks", "default_block", "default_overlap"]

# Relative FFT round-off below which two overlap errors count as equal (float32 spectra).
_ERROR_FLOOR = 1e-5


@dataclass
class Source:
    """The sample being quilted, as features.

    match : (Hs*Ws, C) float32 matching features; image : (Hs*Ws, D) float32 features whose
    squared distance is the image-space error (boundary cuts); matcher : FFT matcher over
    ``match`` for blocks of side ``block``.
    """

    height: int
    width: int
    block: int
    match: np.ndarray
    image: np.ndarray
    matcher: Matcher

    @classmethod
    def build(cls, match: np.ndarray, image: np.ndarray, block: int) -> "Source":
        """match : (Hs, Ws, C); image : (Hs*Ws, D)."""
        h, w, c = match.shape
        if block > min(h, w):
            raise UsageError(f"block size {block} is larger than the {w}x{h} source")
        return cls(h, w, block, np.ascontiguousarray(match.reshape(-1, c)), image, Matcher(match, block))


@dataclass
class Grid:
    """Block corners ``ys`` x ``xs`` on a canvas of ``shape``; ``active[r, c]`` says whether block
    (r, c) is placed; ``torus`` wraps blocks around the canvas edges (tileable output)."""

    ys: np.ndarray
    xs: np.ndarray
    shape: tuple[int, int]
    torus: bool = False
    active: np.ndarray | None = None

    def __post_init__(self):
        if self.active is None:
            self.active = np.ones((len(self.ys), len(self.xs)), bool)


#: Smallest default block side (texels): samples under 32 texels get blocks this small.
MIN_DEFAULT_BLOCK = 6
#: Narrowest default overlap (texels).
MIN_DEFAULT_OVERLAP = 3


def default_block(source_width: int, source_height: int) -> int:
    """A quarter of the sample's shorter side, within 6..64 texels.

    The floor of 6 (it was 8) matters for samples under 32 texels only: a 16^2 sample then
    offers 11 x 11 candidate blocks instead of 9 x 9.  Measured on the ridged fabric at 16^2
    (a 147^2 plane, seeds 0-2, `benchmarks/bench_scene_build.py` for the atlas): the seam error
    over the natural neighbour difference is 2.05-2.09 with blocks of 8 and 2-texel overlaps,
    1.25-1.34 with blocks of 6 and 3-texel overlaps, and 1.56-1.61 with blocks of 8 overlapping by 4-5
    (all with the Efros-Freeman cut that preceded the pair cut of :mod:`.cut`)."""
    return int(np.clip(min(source_width, source_height) // 4, MIN_DEFAULT_BLOCK, 64))


def default_overlap(block: int) -> int:
    """A quarter of the block, at least 3 texels.

    Efros & Freeman suggest one sixth; a wider strip gives the pair cut (:mod:`.cut`) room to find
    where the two blocks continue each other, and costs blocks: the grid's step is the block less
    the overlap.  Measured on the scene benchmark's 64^2 materials over their meshes' charts
    (`benchmarks/bench_quilt_seams.py --size 64`, blocks of 16, seeds 0-1): seams inside charts over
    the natural neighbour difference on the sphere (pebbles) 1.42 / 1.33 / 1.28 / 1.23 with
    overlaps of 3 / 4 / 5 / 6 texels, for 7.6 / 9.9 / 12.7 / 16.0 s of quilting (Efros-Freeman's
    cut with 3: 1.72, 7.7 s).  A quarter takes most of the gain for +30 % time.  A 2-texel strip
    leaves the cut two columns to choose from: on small blocks it cannot route around a
    difference (see :func:`default_block`)."""
    return max(MIN_DEFAULT_OVERLAP, int(round(block / 4)))


def grid_for(width: int, height: int, block: int, overlap: int, *, torus: bool = False) -> Grid:
    """A block grid covering a width x height output.

    Plain: corners every ``block - overlap`` texels; the canvas is grown to fit the last
    block (crop it to width x height afterwards).  Torus: ``n = ceil(size / step)`` corners
    spread evenly over the size, so the last block overlaps the first by >= ``overlap``.
    """
    step = block - overlap
    if step < 1:
        raise UsageError(f"overlap {overlap} must be smaller than the block size {block}")

    def corners(size):
        if torus:
            n = max(2, -(-size // step))
            return (np.arange(n) * size) // n
        n = max(1, -(-(size - overlap) // step))
        return np.arange(n) * step

    if torus and min(width, height) < 2 * block:
        raise UsageError(f"--tileable needs an output of at least two blocks per side ({2 * block} texels), "
                       f"got {width}x{height}")
    ys, xs = corners(height), corners(width)
    shape = (height, width) if torus else (int(ys[-1]) + block, int(xs[-1]) + block)
    return Grid(ys, xs, shape, torus)


def _choose(err: np.ndarray, tolerance: float, rng) -> int:
    """Flat index of a random candidate within ``tolerance`` of the best error."""
    flat = err.ravel()
    best = float(flat.min())
    limit = best * (1.0 + tolerance) + _ERROR_FLOOR * float(flat.mean())
    near = np.flatnonzero(flat <= limit)
    return int(near[rng.integers(len(near))])


def _overlaps(grid: Grid, done: np.ndarray, r: int, c: int, block: int) -> tuple[int, int, int, int]:
    """Overlap widths (left, top, right, bottom) with already placed grid neighbours."""
    ys, xs = grid.ys, grid.xs
    left = int(xs[c - 1] + block - xs[c]) if c > 0 and done[r, c - 1] else 0
    top = int(ys[r - 1] + block - ys[r]) if r > 0 and done[r - 1, c] else 0
    right = bottom = 0
    if grid.torus and c == len(xs) - 1 and done[r, 0]:
        right = int(xs[c] + block - grid.shape[1])
    if grid.torus and r == len(ys) - 1 and done[0, c]:
        bottom = int(ys[r] + block - grid.shape[0])
    return left, top, right, bottom


def place_blocks(pos: np.ndarray, grid: Grid, source: Source, *, tolerance: float, rng,
                 domain: np.ndarray | None = None) -> int:
    """Quilt the active blocks of ``grid`` into ``pos`` in place; returns how many were placed.

    pos : (Hc, Wc) int32 canvas of source flat indices, -1 = empty.  Texels already >= 0 are
          matched against but never cut into (ghosts); only blocks placed here are cut.
    domain : (Hc, Wc) bool, the texels blocks may write (default all).
    """
    B = source.block
    ar = np.arange(B)
    n_cand_x = source.matcher.n_candidates[1]
    n_cand = source.matcher.n_candidates[0] * n_cand_x
    placed = np.zeros(pos.shape, bool)
    done = np.zeros(grid.active.shape, bool)
    count = 0
    for r, y in enumerate(grid.ys):
        for c, x in enumerate(grid.xs):
            if not grid.active[r, c]:
                continue
            rows = (y + ar) % pos.shape[0] if grid.torus else y + ar
            cols = (x + ar) % pos.shape[1] if grid.torus else x + ar
            at = np.ix_(rows, cols)
            old = pos[at]
            filled = old >= 0
            if filled.any():
                template = source.match[np.where(filled, old, 0)]
                pick = _choose(source.matcher.errors(template, filled), tolerance, rng)
            else:
                pick = int(rng.integers(n_cand))
            sy, sx = divmod(pick, n_cand_x)
            new = ((sy + ar)[:, None] * source.width + (sx + ar)[None, :]).astype(np.int32)
            was_placed = placed[at]
            widths = _overlaps(grid, done, r, c, B)
            keep = np.zeros((B, B), bool)
            if any(widths) and was_placed.any():
                keep = keep_old_mask(source.image, old, new, was_placed, widths) & was_placed
            write = ~keep if domain is None else ~keep & domain[at]
            pos[at] = np.where(write, new, old)
            placed[at] |= write
            done[r, c] = True
            count += 1
    return count

