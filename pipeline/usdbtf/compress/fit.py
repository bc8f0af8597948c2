"""Basis fit: the apparent-BRDF basis U from the fitting texels' columns of the data matrix.

The data matrix X is S x 3P (rows = samples, column ``3 t + c`` = channel c of texel t:
the apparent BRDF b(t) of the paper's Eq. (1), one colour channel at a time).  The fit
works on the fitting texels' columns only, held as plain arrays, so it can run unchanged
wherever those columns are (a worker of a distributed engine, say).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import BTFError
from ..model import BTF
from .linalg import exact_basis, randomized_basis
from .options import CompressOptions
from .parallel import rows_gemm
from .texels import Texels

__all__ = ["BasisFit", "fit_basis", "fit_source", "fit_weights", "norm_weights", "signal_only", "require_signal",
           "sampled_coefficients", "HDR_NORM_RANGE"]

#: Fitted texels whose norms span more than this get equalising fit weights: an energy-
#: weighted float32 fit cannot see a region below ~1e-6 of the brightest (its singular
#: values fall under the rank cut, and its terms under float32 rounding of the sums).
HDR_NORM_RANGE = 1e6
#: Directions whose singular value is below this fraction of the first carry no signal.
_RANK_CUT = 1e-6


@dataclass(frozen=True)
class BasisFit:
    """The fitted basis.

    Attributes
    ----------
    basis : (S, k) float32 U, orthonormal columns in decreasing singular value, signs fixed
        (:func:`.linalg.fix_signs`).  k is at most the requested count and the numerical rank.
    singular_values : (k,) float64 sigma_i of the (weighted) fitting columns.
    coefficients : (k, 3 n) float32 U^T X of the n fitting texels (curve-decoded values,
        interleaved channels), which the randomized fit computes anyway; None for ``paper``.
    weighted : the HDR fit weights of :func:`fit_weights` were applied.
    """

    basis: np.ndarray
    singular_values: np.ndarray
    coefficients: np.ndarray | None
    weighted: bool

    @property
    def k(self) -> int:
        return self.basis.shape[1]

    @property
    def has_signal(self) -> bool:
        return len(self.singular_values) > 0 and bool(self.singular_values[0] > 0)


def fit_basis(x: np.ndarray, k: int, options: CompressOptions) -> BasisFit:
    """Fit the basis on the fitting columns ``x``.

    ``paper``: exact SVD of M = ``x`` (Eq. (1) of Koudelka et al. 2003: "the eigenvectors
    corresponding to the k largest eigenvalues are kept").  ``rsvd``: randomized SVD
    (Halko et al. 2011, Alg. 4.4 with ``power_iterations``), on ``x`` times the HDR weights
    of :func:`fit_weights` when the texel norms call for them.  Directions with sigma below
    1e-6 sigma_1 are dropped (they carry no signal, only rounding).

    Parameters
    ----------
    x : (S, 3 n) float32, curve-decoded values of the n fitting texels (see :mod:`.source`).
    k : number of basis vectors wanted (``options.fit_k``).
    options : solver, seed, oversample, power_iterations.

    Returns
    -------
    BasisFit : an all-zero ``x`` gives an empty or zero-sigma fit (see :func:`require_signal`).
    """
    weights = None
    if options.solver == "paper":
        u, sv = exact_basis(x, k)
        coeff = None
    else:
        weights = fit_weights(x)
        u, sv, coeff = randomized_basis(x if weights is None else x * weights, min(k, x.shape[1]),
                                        oversample=options.oversample, power_iterations=options.power_iterations,
                                        seed=options.seed, return_coefficients=True)
        if weights is not None:
            coeff /= weights             # U^T (X W) = (U^T X) W
    return signal_only(BasisFit(u, sv, coeff, weights is not None))


def signal_only(fit: BasisFit) -> BasisFit:
    """``fit`` without the directions whose sigma is below 1e-6 sigma_1 (they carry no signal,
    only rounding); an all-zero fit as it is."""
    if not fit.has_signal:
        return fit
    sv = fit.singular_values
    rank = int(np.count_nonzero(sv > sv[0] * _RANK_CUT))
    coeff = None if fit.coefficients is None else fit.coefficients[:rank]
    return BasisFit(fit.basis[:, :rank], sv[:rank], coeff, fit.weighted)


def fit_source(source, texels: np.ndarray, k: int, options: CompressOptions) -> BasisFit:
    """The fit step on a source: a source that fits from its own structure (one with a
    ``fit(texels, k, options)`` method, e.g. :class:`~.factored.FactoredSource`) does so;
    any other is fitted by :func:`fit_basis` on the columns of ``texels``."""
    own = getattr(source, "fit", None)
    return own(texels, k, options) if own is not None else fit_basis(source.columns(texels), k, options)


def require_signal(fit: BasisFit, btf: BTF, texels: Texels, options: CompressOptions) -> None:
    """Raise BTFError, naming the input and what to try, when the fit found no signal."""
    if fit.has_signal:
        return
    where = btf.path or "input BTF"
    if len(texels.fit) < btf.n_pixels:
        raise BTFError(f"{where}: the {len(texels.fit)} texels the basis is fitted on are all zero "
                       f"({'central region: try --region' if options.solver == 'paper' else 'try --fit-texels'})")
    raise BTFError(f"{where}: every pixel is zero; there is nothing to compress")


def fit_weights(x: np.ndarray) -> np.ndarray | None:
    """Column weights (3 n,) float32 for the fit of ``x`` (S, 3 n): ||x_t||^-1/2 per texel
    when the nonzero texel norms span more than HDR_NORM_RANGE, else None.

    The square root halves the dynamic range in log terms (1e-4..1e4 data: 1e8 -> 1e4 in
    norm): a dark region with a BRDF of its own then gets basis directions, while bright
    texels still weigh more, as the paper's absolute error metric wants.
    """
    w = norm_weights(np.sqrt(_column_energy(x).reshape(-1, 3).sum(axis=1)))
    return None if w is None else np.repeat(w, 3).astype(np.float32)


def norm_weights(norms: np.ndarray) -> np.ndarray | None:
    """Per-texel fit weights (n,) float64 from texel norms ||x_t|| (n,): ||x_t||^-1/2 when the
    nonzero norms span more than HDR_NORM_RANGE (zero texels weigh 1), else None."""
    pos = norms[norms > 0]
    if len(pos) == 0 or pos.max() <= HDR_NORM_RANGE * pos.min():
        return None
    return np.where(norms > 0, 1.0 / np.sqrt(np.maximum(norms, pos.min())), 1.0)


def _column_energy(x: np.ndarray, rows: int = 256) -> np.ndarray:
    """(n,) float64 sum of squares of each column of ``x`` (S, n) float32: float32 dot
    products over blocks of ``rows`` samples, summed in float64 (an einsum with
    dtype=float64 casts every element and is ~10x slower on a 10800 x 6144 fit matrix)."""
    acc = np.zeros(x.shape[1])
    for a in range(0, x.shape[0], rows):
        part = x[a:a + rows]
        acc += np.einsum("st,st->t", part, part)
    return acc


def sampled_coefficients(fit: BasisFit, to_working, truth: np.ndarray, n_pixels: int) -> tuple[np.ndarray, float]:
    """Working-space coefficients of the sampled texels, and the energy outside the basis.

    What colour decorrelation and the choice of a quantisation step look at before the
    projection: c = U^T b for the fitting texels (from the fit, rsvd only) and for the
    held-out texels (computed here).

    Parameters
    ----------
    fit : the basis fit.
    to_working : callable, curve-decoded (..., 3 n) -> working space (``source.to_working``).
    truth : (S, n, 3) float32 working-space values of the held-out texels.
    n_pixels : P, texels per image (to scale the held-out estimate to the whole image).

    Returns
    -------
    sampled : (k, m, 3) float32 coefficients, fitting texels first (when the fit has them),
        then the n held-out texels.
    outside : float, ||X||^2 - ||U^T X||^2 over the whole image (working space, linear
        units squared), estimated on the held-out texels.
    """
    S, n, _ = truth.shape
    k = fit.k
    c_eval = rows_gemm(fit.basis.T, truth.reshape(S, -1)).reshape(k, n, 3)
    sampled = c_eval if fit.coefficients is None else np.concatenate(
        [to_working(fit.coefficients).reshape(k, -1, 3), c_eval], axis=1)
    outside = float(np.einsum("ij,ij->", truth.reshape(S, -1), truth.reshape(S, -1), dtype=np.float64)
                    - np.einsum("kpc,kpc->", c_eval, c_eval, dtype=np.float64))
    return sampled, max(outside, 0.0) * n_pixels / n
