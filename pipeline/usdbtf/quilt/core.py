"""Quilting a plane: the options, the result, and a ``width`` x ``height`` synthesis.

Block matching compares the leading ``m`` coefficient textures (weighted by singular values,
:mod:`.features`); boundary cuts use all k through the image-space metric.  The result is a
position map, applied to every coefficient texture when written (:func:`~.folder.write_quilt`)
or gathered in memory (:func:`~.folder.quilted_btf`).  The stage itself is :mod:`.stage`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import __version__
from ..compress.format import CompressedBTF
from ..errors import UsageError
from .engine import Source, default_block, default_overlap, grid_for, place_blocks
from .features import image_features, matching_features, vector_energies
from .seams import seam_error_all_samples

__all__ = ["DEFAULT_M", "QuiltOptions", "QuiltResult", "prepare_source", "quilt_plane", "quilt_record"]

# Leading coefficients matched by default, from `benchmarks/bench_quilt_render.py` (m sweep on
# paper-scale pebbles, k = 150, 512^2, seeds 1-3; benchmarks/RESULTS.md): seam error (all samples)
# 7.41e-3 at m = 1, 7.01e-3 at m = 2, 7.05e-3 at m = 4, 6.97e-3 at m = 8, 7.20e-3 at m = 150 --
# flat from m = 2 within seed noise -- for 1.23, 1.27, 1.39, 1.65 and 16.3 s.  m = 4 keeps a
# margin for materials whose energy spreads over more components, at +10 % time over m = 2.
DEFAULT_M = 4
DEFAULT_TOLERANCE = 0.1


#: The options the output's metadata records (``quilt.options``), in this order.
RECORDED_OPTIONS = ("block", "overlap", "m", "tolerance", "seed", "tileable")


@dataclass(frozen=True)
class QuiltOptions:
    """block, overlap : texels (defaults :func:`default_block`, :func:`default_overlap`);
    m : leading coefficients matched; tolerance : blocks within (1 + tolerance) x the best
    overlap error are equally likely; seed : the only source of randomness; tileable : the
    output wraps around seamlessly; size : (width, height) of the output in texels (a plane;
    unused when quilting into an atlas); ghosts : atlas only, match chart borders against the
    neighbouring charts already quilted (:mod:`.atlas`)."""

    block: int | None = None
    overlap: int | None = None
    m: int | None = None
    tolerance: float = DEFAULT_TOLERANCE
    seed: int = 0
    tileable: bool = False
    size: tuple | None = None
    ghosts: bool = True

    def resolved(self, cbtf: CompressedBTF) -> "QuiltOptions":
        """Defaults filled in and checked against the sample."""
        block = self.block or default_block(cbtf.width, cbtf.height)
        overlap = self.overlap if self.overlap is not None else default_overlap(block)
        m = self.m if self.m is not None else min(DEFAULT_M, cbtf.k)
        if block < 3:
            raise UsageError(f"--block must be at least 3 texels, got {block}")
        if block > min(cbtf.width, cbtf.height):
            raise UsageError(f"--block {block} is larger than the {cbtf.width}x{cbtf.height} sample")
        if not 1 <= overlap < block:
            raise UsageError(f"--overlap must be in 1..{block - 1} for block {block}, got {overlap}")
        if not 1 <= m <= cbtf.k:
            raise UsageError(f"--m must be in 1..{cbtf.k}, got {m}")
        if not (self.tolerance >= 0 and np.isfinite(self.tolerance)):
            raise UsageError(f"tolerance must be a finite number >= 0, got {self.tolerance}")
        return replace(self, block=block, overlap=overlap, m=m)


@dataclass
class QuiltResult:
    """A synthesis result.

    positions : (H, W) int32 flat source texel index ``y * Ws + x`` per output texel.
    valid : (H, W) bool, texels that were synthesised (False: gutter padding in an atlas).
    options : the resolved options.  record : provenance for the output's metadata.
    source : the compressed BTF quilted; source_folder : its folder when it was read from one
        (recorded, and its error-curve files copied, by :func:`~.folder.write_quilt`).
    """

    positions: np.ndarray
    valid: np.ndarray
    options: QuiltOptions
    record: dict
    source: CompressedBTF
    source_folder: Path | None = None

    @property
    def height(self) -> int:
        return self.positions.shape[0]

    @property
    def width(self) -> int:
        return self.positions.shape[1]


def prepare_source(cbtf: CompressedBTF, opts: QuiltOptions) -> Source:
    """Matching and image features plus the FFT matcher for resolved ``opts``."""
    return Source.build(matching_features(cbtf, opts.m), image_features(cbtf), opts.block)


def check_size(width: int, height: int, limit: int = 1 << 15) -> None:
    if not (isinstance(width, (int, np.integer)) and isinstance(height, (int, np.integer))
            and 1 <= width <= limit and 1 <= height <= limit):
        raise UsageError(f"--size must be two integers in 1..{limit}, got {width} {height}")


def quilt_plane(cbtf: CompressedBTF, width: int, height: int, opts: QuiltOptions) -> QuiltResult:
    """A ``width`` x ``height`` output (texels) from ``cbtf``'s coefficient textures."""
    check_size(width, height)
    opts = opts.resolved(cbtf)
    t0 = time.perf_counter()
    source = prepare_source(cbtf, opts)
    grid = grid_for(width, height, opts.block, opts.overlap, torus=opts.tileable)
    canvas = np.full(grid.shape, -1, np.int32)
    blocks = place_blocks(canvas, grid, source, tolerance=opts.tolerance, rng=np.random.default_rng(opts.seed))
    positions = np.ascontiguousarray(canvas[:height, :width])
    seconds = time.perf_counter() - t0
    seam = seam_error_all_samples(positions, source.image, cbtf.width, cbtf.n_samples, wrap=opts.tileable)
    return QuiltResult(positions, np.ones(positions.shape, bool), opts,
                       quilt_record(cbtf, opts, width, height, blocks=blocks, seam=seam, seconds=seconds), cbtf)


def quilt_record(cbtf: CompressedBTF, opts: QuiltOptions, width: int, height: int, *, blocks: int,
                 seam: float, seconds: float, **extra) -> dict:
    """The provenance stored under ``quilt`` in the output's metadata (no timings: outputs are
    byte-identical for identical inputs); ``seconds`` is kept out of the files by the writer."""
    _, energy_source = vector_energies(cbtf)
    return {"tool": "usdbtf quilt", "version": __version__, "method": "Efros-Freeman image quilting in "
            "coefficient space (Koudelka et al. 2003, sec. IV)",
            "options": {name: getattr(opts, name) for name in RECORDED_OPTIONS},
            "source": {"path": str(cbtf.source.get("path", "")), "size": [cbtf.width, cbtf.height], "k": cbtf.k},
            "size": [int(width), int(height)], "blocks": int(blocks), "matching": {
                "features": f"leading {opts.m} coefficient textures x 3 channels, each normalised to unit "
                            "energy and weighted by its singular value", "energies": energy_source},
            "seam_error": {"all_samples_mean": seam, "definition": "mean over seam pairs, channels and all "
                           "(view, light) samples of the squared difference, working space"},
            "_seconds": seconds, **extra}
