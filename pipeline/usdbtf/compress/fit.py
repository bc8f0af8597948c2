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
from .linalg import Passes, exact_basis, randomized_basis
from .options import CompressOptions
from .convert import Scratch
from .parallel import in_threads, one_blas_thread, rows_gemm
from .texels import Texels

__all__ = ["BasisFit", "fit_basis", "fit_source", "streamed_fit", "fits_every_texel", "every_texel", "ImagePasses",
           "fit_weights", "norm_weights", "signal_only", "require_signal", "sampled_coefficients", "HDR_NORM_RANGE"]

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
    under a budget (:func:`fits_every_texel`) the basis is fitted on every texel in passes
    over the source (:func:`streamed_fit`); any other is fitted by :func:`fit_basis` on the
    columns of ``texels``."""
    own = getattr(source, "fit", None)
    if own is not None:
        return own(texels, k, options)
    if fits_every_texel(source, texels, options):
        return streamed_fit(source, texels, k, options)
    return fit_basis(source.columns(texels), k, options)


def fits_every_texel(source, texels: np.ndarray, options: CompressOptions) -> bool:
    """True when the basis is fitted on every texel rather than on the sample ``texels``: the
    rsvd solver under a byte budget or an error target, no ``--fit-texels`` and no
    ``--no-fit-every-texel``, the sample a strict subset of the image, and a source that passes
    over its rows (``row_chunks``; a Dask cluster's source fits the sample).

    A basis of the budget modes' 200-300 vectors fitted on a quarter of the texels fits those
    texels better than the rest (paper-scale metal_flakes at k 288: 6.19 % unquantised L1
    error over the image from 4096 texels, 5.71 % from all 16384; satin_weave 3.80 -> 3.63 %;
    ``benchmarks/probes/issue39_fit_texels.py``).  The default since rate control chooses the
    step on measured bytes and held-out error (``ratecontrol._measured_step``): before that it
    raised ridged_fabric's error at the paper's bytes 24 % while lowering four presets' 3-5 %
    (docs/compression-and-rate-control.md)."""
    btf = source.btf
    return every_texel(options, len(texels), btf.n_pixels, btf.n_samples) and hasattr(source, "row_chunks")


def every_texel(options: CompressOptions, n_fit: int, n_pixels: int, n_samples: int) -> bool:
    """The options' part of :func:`fits_every_texel` (``n_fit`` sampled texels of ``n_pixels``,
    ``n_samples`` samples).  By default (``fit_every_texel`` None) only where the fit's panels
    (:func:`every_texel_panel_bytes`) fit ``options.memory_budget``: they grow with the image
    (paper sampling: 0.61 GB at 128², 2.4 GB at 256²), where the sampled fit's do not; an
    explicit ``--fit-every-texel`` is taken at any size."""
    applies = (options.solver == "rsvd" and options.budgeted and not options.fit_texels and n_fit < n_pixels
               and options.fit_every_texel is not False)
    if applies and options.fit_every_texel is None:
        return every_texel_panel_bytes(options, n_samples, n_pixels) <= options.memory_budget
    return applies


def every_texel_panel_bytes(options: CompressOptions, n_samples: int, n_pixels: int) -> int:
    """Bytes a fit over every texel (:func:`streamed_fit`) holds: panels of every texel, X^T Q and
    Z (float32) and the float64 pair of orthonormalising them, (3 P) x (k_fit + oversample) each."""
    panel = options.fit_k(n_samples, n_pixels) + options.oversample
    return 3 * n_pixels * panel * (4 + 4 + 2 * 8)


def streamed_fit(source, texels: np.ndarray, k: int, options: CompressOptions) -> BasisFit:
    """The rsvd basis of every texel's columns (:func:`fit_basis`'s randomized SVD over the whole
    data matrix), in passes over the source's rows (:class:`ImagePasses`): the columns are
    never all decoded at once.  ``BasisFit.coefficients`` are those of the sample ``texels``
    (sorted), as :func:`fit_basis` on their columns reports them; the HDR weights of
    :func:`fit_weights` are decided on every texel's norm (one more pass when they apply)."""
    release = getattr(source, "release", None)
    if release is not None:          # the sample's columns: the domain choice was their last use
        release(texels)
    x = ImagePasses(source)
    cols = (3 * np.asarray(texels)[:, None] + np.arange(3)).ravel()
    kw = dict(oversample=options.oversample, power_iterations=options.power_iterations, seed=options.seed,
              return_coefficients=True, coefficient_columns=cols)
    u, sv, coeff = randomized_basis(x, min(k, x.shape[1]), **kw)
    weights = fit_weights(x.energy)
    if weights is not None:
        x.weights = weights
        u, sv, coeff = randomized_basis(x, min(k, x.shape[1]), **kw)
        coeff /= weights[cols]       # U^T (X W) = (U^T X) W
    return signal_only(BasisFit(u, sv, coeff, weights is not None))


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
    """Column weights (3 n,) float32 for the fit of ``x`` (S, 3 n; or (3 n,) float64 its
    columns' sums of squares, :func:`_column_energy`): ||x_t||^-1/2 per texel
    when the nonzero texel norms span more than HDR_NORM_RANGE, else None.

    The square root halves the dynamic range in log terms (1e-4..1e4 data: 1e8 -> 1e4 in
    norm): a dark region with a BRDF of its own then gets basis directions, while bright
    texels still weigh more, as the paper's absolute error metric wants.
    """
    energy = x if x.ndim == 1 else _column_energy(x)
    w = norm_weights(np.sqrt(energy.reshape(-1, 3).sum(axis=1)))
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


#: Samples per piece of an :class:`ImagePasses` product (or a tile where tiles are shorter).
PASS_ROWS = 256
#: Texels per column cut of an :class:`ImagePasses` product (6144 columns: X^T q's rows of one
#: cut, 12.7 MB at 516 vectors, stay near the core that adds to them).
PASS_TEXELS = 2048


class ImagePasses(Passes):
    """The data matrix of every texel of a source, X (S, 3 P) in its current domain (the
    values ``source.columns`` gives), known by its products over the source's rows.

    ``source.row_chunks()`` yields (first sample, (n, 3 P) stored values) in sample order,
    chunks of whole tiles (:class:`.projection.WorkPlan`).  Each product cuts the texels into
    pieces of :data:`PASS_TEXELS` (over the CPUs' threads, each on one BLAS thread) and the
    samples into pieces of :data:`PASS_ROWS` (or a tile), converts one piece of a cut at a
    time and multiplies it: the pieces are a function of the data's shape alone and are summed
    in a fixed order, so any source and any number of CPUs give the same bits.

    Attributes
    ----------
    energy : (3 P,) float64 sum of squares of each column, measured by the first
        :meth:`times` (None before it).
    weights : (3 P,) float32 column weights W, or None: the products are then those of X W.
    """

    def __init__(self, source):
        self.source = source
        self.shape = (source.btf.n_samples, 3 * source.btf.n_pixels)
        self.energy: np.ndarray | None = None
        self.weights: np.ndarray | None = None
        self.rows = min(PASS_ROWS, source.plan.tile)
        edges = list(range(0, source.btf.n_pixels, PASS_TEXELS)) + [source.btf.n_pixels]
        self.cuts = [slice(3 * a, 3 * b) for a, b in zip(edges[:-1], edges[1:])]
        self._scratch = Scratch()

    def _pass(self, job, done=None) -> None:
        """One pass: per chunk of n samples a.., ``job(cut index, a, row in the chunk, (r, 3 n)
        float32 values of the cut's piece)`` for every piece of every cut (each cut's pieces
        in sample order on one thread, the cuts over the CPUs), then ``done(a, n)``."""
        for a, raw in self.source.row_chunks():
            if done is not None:
                done(a, len(raw), before=True)

            def cut_job(c):
                for r in range(0, len(raw), self.rows):
                    x = raw[r:r + self.rows, self.cuts[c]]
                    job(c, a, r, self.source.curves(x, out=self._scratch.get("x", x.shape)))

            with one_blas_thread():
                in_threads(cut_job, range(len(self.cuts)))
            if done is not None:
                done(a, len(raw), before=False)

    def times(self, p: np.ndarray) -> np.ndarray:
        """X W p (S, l) float32 (each chunk's cut products summed in cut order); the first call
        also measures :attr:`energy`."""
        if self.weights is not None:
            p = p * self.weights[:, None]
        out = np.empty((self.shape[0], p.shape[1]), np.float32)
        parts = np.empty((len(self.cuts), 0, p.shape[1]), np.float32)     # per cut, a chunk's products
        energy = np.zeros(self.shape[1]) if self.energy is None else None

        def job(c, a, r, x):
            np.matmul(x, p[self.cuts[c]], out=parts[c, r:r + len(x)])
            if energy is not None:
                energy[self.cuts[c]] += _column_energy(x)

        def done(a, n, before):
            nonlocal parts
            if before:
                if parts.shape[1] < n:
                    parts = np.empty((len(self.cuts), n, p.shape[1]), np.float32)
                return
            out[a:a + n] = parts[0, :n]
            for part in parts[1:]:
                out[a:a + n] += part[:n]

        self._pass(job, done)
        if energy is not None:
            self.energy = energy
        return out

    def t_times(self, q: np.ndarray) -> np.ndarray:
        """(X W)^T q (3 P, l) float32: each cut's rows summed over the pieces in sample order."""
        out = np.zeros((self.shape[1], q.shape[1]), np.float32)

        def job(c, a, r, x):
            out[self.cuts[c]] += x.T @ q[a + r:a + r + len(x)]

        self._pass(job)
        if self.weights is not None:
            out *= self.weights[:, None]
        return out
