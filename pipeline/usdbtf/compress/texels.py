"""Texel sampling: which texels the basis is fitted on, and which estimate the error.

Texels are numbered row-major, ``t = y * W + x`` (y = 0 the top row of the image).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..model import BTF
from .options import CompressOptions

__all__ = ["Texels", "sample_texels", "fit_texels", "evaluation_texels", "in_sample_texels", "default_fit_texels", "RUN"]

#: Texels per contiguous run of the rsvd fitting sample (whole cache lines, cheap to gather).
RUN = 64
#: The in-sample stratum's fewest runs (:func:`in_sample_texels`): runs of neighbouring texels
#: vary together, and fewer than four would leave the stratum to one or two patches.
MIN_IN_SAMPLE_RUNS = 4


@dataclass(frozen=True)
class Texels:
    """The texels one compress fits on and evaluates on.

    Attributes
    ----------
    fit : (n_fit,) int, sorted texel indices the basis is fitted on (the paper's M, Eq. (1)).
    evaluation : (n_eval,) int, sorted texel indices the error is estimated on.
    in_sample : (m,) int, sorted, a sample of ``fit`` standing for the fitted texels in the
        estimate (:func:`in_sample_texels`); None when ``evaluation`` is every texel.
    """

    fit: np.ndarray
    evaluation: np.ndarray
    in_sample: np.ndarray | None = None

    @property
    def held_out(self) -> bool:
        """True when no evaluation texel was used in the fit (an out-of-sample estimate)."""
        return not np.isin(self.evaluation, self.fit).any()


def sample_texels(btf: BTF, options: CompressOptions) -> Texels:
    """The fitting and evaluation texels of ``btf`` (a function of its size, the solver,
    ``fit_texels``/``region``, ``eval_texels`` and ``seed`` only).

    Parameters
    ----------
    btf : the BTF (only its width and height are used).
    options : solver, ``region`` (paper), ``fit_texels`` and ``seed`` (rsvd), ``eval_texels``.

    Returns
    -------
    Texels : see :func:`fit_texels` and :func:`evaluation_texels`.
    """
    fit = fit_texels(btf.width, btf.height, options)
    texels = Texels(fit, evaluation_texels(btf.width * btf.height, fit, options))
    return replace(texels, in_sample=in_sample_texels(fit, options, btf.width * btf.height)) if texels.held_out else texels


def in_sample_texels(fit: np.ndarray, options: CompressOptions, n_pixels: int | None = None) -> np.ndarray:
    """(m,) sorted texel indices, a sample of the fitting texels ``fit`` in random pieces of
    :data:`RUN` consecutive entries of ``fit`` (seed + 2; all of ``fit`` when it is no larger).

    The fitted texels are reconstructed better than the others (in-sample: at paper-scale
    pebbles' k = 320 from 4096 texels, ~0.7x the held-out error), so an error over all
    texels weighs the held-out estimate with a sample of them (issue 39).

    How many runs: under a byte or error target, as many as the held-out sample's
    ``eval_texels``: the estimate steers the choice (with 6 runs, paper-scale metal_flakes'
    ``--target-error`` chose k 109 instead of 104, +3.4 % bytes at a 1.2 % lower exact error:
    the estimate's noise moved the choice).  For a plain k the estimate is a report, and the
    fitted stratum stands for a small share of ``n_pixels`` (at 128^2, 2048 of 16384 texels):
    a sample the held-out one's size spent half the evaluation on an eighth of the estimate
    (issue 42).  There the runs are in proportion to the texels each stratum stands for, at
    least :data:`MIN_IN_SAMPLE_RUNS` (4 instead of 16 at 128^2): the estimate's standard error
    grows by a few percent of itself, the evaluation costs 0.6x.  ``n_pixels`` None: the
    held-out sample's size.
    """
    fit = np.asarray(fit)
    eval_runs = max(1, options.eval_texels // RUN)
    if n_pixels is None or n_pixels <= len(fit) or options.budgeted:
        count = eval_runs
    else:
        count = min(eval_runs, max(MIN_IN_SAMPLE_RUNS, math.ceil(eval_runs * len(fit) / (n_pixels - len(fit)))))
    if len(fit) // RUN <= count:
        return fit
    # Runs of positions in ``fit`` (not of texels): pieces of RUN consecutive fitted texels.
    return np.sort(fit[_runs(len(fit), count, np.random.default_rng(options.seed + 2))])


def default_fit_texels(options: CompressOptions) -> int:
    """2048 texels for a plain k; 4096 when a byte or error target lets quality pay for time
    (measured on paper-scale pebbles at the paper's bytes: 8.22 % -> 7.96 % error)."""
    if options.fit_texels:
        return options.fit_texels
    return 4096 if options.budgeted else 2048


def fit_texels(width: int, height: int, options: CompressOptions) -> np.ndarray:
    """(n,) sorted texel indices the basis is fitted on.

    ``paper``: the contiguous central square of side ``region`` (default a quarter of the
    shorter side, at least 4), the paper's region of "representative" texels forming M in
    Eq. (1).  ``rsvd``: :func:`default_fit_texels` texels in random runs of :data:`RUN`
    consecutive texels (seeded), spread over the whole image.
    """
    if options.solver == "paper":
        side = options.region or max(4, min(width, height) // 4)
        side = min(side, width, height)
        y0, x0 = (height - side) // 2, (width - side) // 2
        yy, xx = np.mgrid[y0:y0 + side, x0:x0 + side]
        return (yy * width + xx).ravel()
    # Random runs of RUN consecutive texels: spread over the whole image, but each run is
    # one contiguous slice of every sample (a gather of random single texels costs more
    # than the fit itself at paper scale).
    n_pixels = width * height
    runs = n_pixels // RUN
    n_runs = min(runs, max(1, default_fit_texels(options) // RUN))
    if runs == 0 or n_runs == runs:
        return np.arange(n_pixels)
    return _runs(n_pixels, n_runs, np.random.default_rng(options.seed))


def evaluation_texels(n_pixels: int, fit: np.ndarray, options: CompressOptions) -> np.ndarray:
    """(n,) sorted texel indices for error estimates: about ``eval_texels`` texels in random
    runs disjoint from the fitting runs (seed + 1); all texels when the image is too small
    to hold any out."""
    runs = n_pixels // RUN
    used = np.unique(fit // RUN)
    free = runs - len(used)
    if free <= 0 or len(fit) == n_pixels:
        return np.arange(n_pixels)
    return _runs(n_pixels, max(1, options.eval_texels // RUN), np.random.default_rng(options.seed + 1), exclude=used)


def _runs(n_pixels: int, count: int, rng, exclude: np.ndarray | None = None) -> np.ndarray:
    """Sorted texel indices of ``count`` random runs of RUN texels (whole runs only),
    avoiding runs listed in ``exclude`` (run indices)."""
    runs = np.arange(n_pixels // RUN)
    if exclude is not None:
        runs = np.setdiff1d(runs, exclude)
    pick = np.sort(rng.choice(runs, size=min(count, len(runs)), replace=False)) * RUN
    return (pick[:, None] + np.arange(RUN)[None, :]).ravel()
