"""Basis fitting and projection: functions over chunks of the data matrix.

The data matrix X is S x m (rows = samples, columns = pixel channels): column
``3 t + c`` is channel c of texel t, the apparent BRDF of that texel.  Functions
take and return plain arrays so each can run unchanged on a distributed engine.
"""
from __future__ import annotations

import numpy as np

from .parallel import in_threads, one_blas_thread, rows_gemm

__all__ = ["fix_signs", "exact_basis", "randomized_basis", "orthonormalize", "Passes"]


def fix_signs(u: np.ndarray) -> np.ndarray:
    """Sign convention: flip each column of ``u`` (S, k) so its largest-magnitude entry
    (first one on ties) is positive.  Returns the (k,) signs applied (in place)."""
    idx = np.argmax(np.abs(u), axis=0)
    signs = np.sign(u[idx, np.arange(u.shape[1])])
    signs[signs == 0] = 1
    u *= signs.astype(u.dtype)
    return signs


def orthonormalize(y: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the columns of ``y`` (S, l), float32.

    CholeskyQR2: two rounds of Q = Y R^-1 with R from the Cholesky factor of the small
    Gram Y^T Y (computed in float64) -- GEMMs instead of Householder QR, 3x faster on
    10^4 x 166 panels and as orthogonal after the second round.  Falls back to QR when
    the Gram is not positive definite (rank-deficient Y).  The small factorisations run
    on one BLAS thread (:func:`.parallel.one_blas_thread`): split over threads they gain
    nothing at this size, spin-wait on a shared machine, and round differently with every
    thread count.
    """
    q = y
    try:
        for _ in range(2):
            q64 = q.astype(np.float64)   # the Gram in float64: float32 overflows past ~1e19
            g = q64.T @ q64
            # Y R^-1 as a GEMM with the small inverse: a triangular solve with an S-column
            # right-hand side costs 10x more, and the second round restores orthogonality.
            q = rows_gemm(q64, _cholesky_inverse(g)).astype(np.float32)
        if not np.isfinite(q).all():
            raise np.linalg.LinAlgError("CholeskyQR lost precision")
        return np.ascontiguousarray(q)
    except np.linalg.LinAlgError:
        with one_blas_thread():
            return np.linalg.qr(y)[0]


def orthonormalize_in_place(y: np.ndarray) -> np.ndarray:
    """:func:`orthonormalize` of a tall ``y`` (m, l) float32 (m >> l) that overwrites it, piece
    by piece of :data:`_GRAM_ROWS` rows: no float64 copy of ``y`` (at 49152 x 516 that copy
    and its product were 0.4 GB).  Falls back to QR (a new array) as :func:`orthonormalize`
    does.  Returns ``y``, orthonormalised, or the QR's Q."""
    try:
        for _ in range(2):
            r_inv = _cholesky_inverse(_gram_columns(y))

            def piece(a):
                y[a:a + _GRAM_ROWS] = y[a:a + _GRAM_ROWS].astype(np.float64) @ r_inv

            with one_blas_thread():
                in_threads(piece, range(0, y.shape[0], _GRAM_ROWS))
        if not np.isfinite(y).all():
            raise np.linalg.LinAlgError("CholeskyQR lost precision")
        return y
    except np.linalg.LinAlgError:
        with one_blas_thread():
            return np.linalg.qr(y)[0]


def _cholesky_inverse(g: np.ndarray) -> np.ndarray:
    """R^-1 (l, l) for the Gram ``g`` = R^T R (R upper), on one BLAS thread (raises
    LinAlgError when ``g`` is not positive definite)."""
    with one_blas_thread():
        return np.linalg.inv(np.linalg.cholesky(g).T)


def exact_basis(x: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Top-k left singular vectors of ``x`` (S, m) by an exact float64 eigensolve.

    Uses whichever Gram matrix is smaller (m x m or S x S).
    Returns U (S, k) float32 with signs fixed, and the singular values (k,) float64.
    """
    x64 = x.astype(np.float64)
    s_rows, m = x64.shape
    if not np.any(x64):
        return np.zeros((s_rows, 0), np.float32), np.zeros(0)
    if m <= s_rows:
        evals, v = np.linalg.eigh(rows_gemm(x64.T, x64))
        order = np.argsort(evals)[::-1][:k]
        sv = np.sqrt(np.maximum(evals[order], 0.0))
        keep = sv > sv[0] * 1e-12 if len(sv) and sv[0] > 0 else np.zeros(len(sv), bool)
        u = rows_gemm(x64, v[:, order[keep]]) / sv[keep]
        # Re-orthonormalise: the Gram route loses orthogonality for tiny singular values.
        u, r = np.linalg.qr(u)
        u *= np.sign(np.diag(r))
    else:
        evals, u = np.linalg.eigh(rows_gemm(x64, x64.T))
        order = np.argsort(evals)[::-1][:k]
        sv = np.sqrt(np.maximum(evals[order], 0.0))
        keep = sv > sv[0] * 1e-12 if len(sv) and sv[0] > 0 else np.zeros(len(sv), bool)
        u = u[:, order[keep]]
    u = np.ascontiguousarray(u, dtype=np.float32)
    fix_signs(u)
    return u, sv[keep]


def randomized_basis(x, k: int, *, oversample: int = 16, power_iterations: int = 1,
                     seed: int = 0, return_coefficients: bool = False, coefficient_columns: np.ndarray | None = None):
    """Top-k left singular vectors of ``x`` (S, m) by randomized SVD (Halko et al. 2011).

    ``power_iterations`` passes of X X^T sharpen the spectrum; each costs two GEMMs of
    X with an (m, k + oversample) panel (the range finder one more).  The small core SVD
    runs in float64.  Large products are cut by rows over threads, each on one BLAS thread
    (:func:`.parallel.rows_gemm`), small ones run on one: the result does not depend on
    thread counts.  The last range's QR forms R alone, and U = Q Ub is taken as Y (R^-1 Ub):
    one parallel GEMM instead of Householder's Q, formed on one thread (paper scale, 500
    vectors: R alone takes 0.26 s where Q and R took 0.56 s; the same output bytes).
    Returns U (S, k) float32 with signs fixed, singular values (k,) float64, and with
    ``return_coefficients`` also U^T X (k, m) float32, which the fit has already computed.

    ``x`` may also be a matrix too large to hold, given by its products (:class:`Passes`:
    ``shape``, ``times(p)`` = X p and ``t_times(q)`` = X^T q, each one pass over its rows):
    then Z stays float32 and B's Gram is R (Z^T Z) R^T, so nothing m x l is held in float64,
    and the coefficients are those of ``coefficient_columns`` (sorted column indices) only.
    """
    s_rows, m = x.shape
    l = min(k + oversample, s_rows, m)
    rng = np.random.default_rng(seed)
    omega = rng.standard_normal((m, l), dtype=np.float32)
    q = orthonormalize(_times(x, omega))
    del omega
    held = isinstance(x, np.ndarray)
    cols = slice(None) if held or coefficient_columns is None else coefficient_columns
    if power_iterations < 1:
        b = (rows_gemm(q.T, x) if held else x.t_times(q).T).astype(np.float64)      # (l, m)
        bbt, b = _gram_rows(b), b[:, cols]
        y = r = None                   # U = Q Ub with this Q itself
    else:
        for _ in range(power_iterations - 1):
            q = orthonormalize(_times(x, _orthonormal_rows(x, _t_times(x, q))))
        # Last iteration: Y = X Z = Q R with Z orthonormal and X ~= X Z Z^T, so
        # B = Q^T X ~= R Z^T -- the small factors replace a fourth GEMM over X
        # (paper-scale pebbles and fuzzy moss: error within 0.1 % relative of Q^T X).
        z = _orthonormal_rows(x, _t_times(x, q))
        if held:
            z = z.astype(np.float64)
        y = _times(x, z.astype(np.float32)).astype(np.float64)
        with one_blas_thread():
            r = np.linalg.qr(y, mode="r")       # R alone: half the time of Q and R (0.26 s of 0.56)
        if held:
            b = rows_gemm(r, z.T)                                         # (l, m)
            bbt = _gram_rows(b)
        else:
            b = rows_gemm(r, z[cols].astype(np.float64).T)                # (l, columns asked for)
            with one_blas_thread():
                bbt = r @ _gram_columns(z) @ r.T
    with one_blas_thread():
        evals, ub = np.linalg.eigh(bbt)              # (l, l): cheap
    order = np.argsort(evals)[::-1][:k]
    sv = np.sqrt(np.maximum(evals[order], 0.0))
    u64 = rows_gemm(q.astype(np.float64), ub[:, order]) if r is None else _q_times(y, r, ub[:, order])
    u = np.ascontiguousarray(u64, dtype=np.float32)
    signs = fix_signs(u)
    if not return_coefficients:
        return u, sv
    coeff = rows_gemm(ub[:, order].T * signs[:, None], b)     # U^T X = Ub^T B
    return u, sv, coeff.astype(np.float32)


class Passes:
    """A data matrix X (S, m) known by its products, each one pass over its rows (what
    :func:`randomized_basis` needs of a matrix too large to hold).

    Attributes
    ----------
    shape : (S, m).

    Methods
    -------
    times(p) : X p, (S, l) float32 for p (m, l) float32.
    t_times(q) : X^T q, (m, l) float32 for q (S, l) float32.
    """

    shape: tuple

    def times(self, p: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def t_times(self, q: np.ndarray) -> np.ndarray:
        raise NotImplementedError


def _times(x, p: np.ndarray) -> np.ndarray:
    """X p for an array or :class:`Passes` ``x``."""
    return rows_gemm(x, p) if isinstance(x, np.ndarray) else x.times(p)


def _t_times(x, q: np.ndarray) -> np.ndarray:
    """X^T q for an array or :class:`Passes` ``x``."""
    return rows_gemm(x.T, q) if isinstance(x, np.ndarray) else x.t_times(q)


def _orthonormal_rows(x, w: np.ndarray) -> np.ndarray:
    """``w`` (m, l) orthonormalised: as :func:`orthonormalize` for an array ``x``, in place for
    :class:`Passes` (whose m may be too large for a float64 copy)."""
    return orthonormalize(w) if isinstance(x, np.ndarray) else orthonormalize_in_place(w)


def _gram_rows(b: np.ndarray) -> np.ndarray:
    """b b^T (l, l) of ``b`` (l, m) float64, on one BLAS thread."""
    with one_blas_thread():
        return b @ b.T


#: Rows of Z per piece of its float64 Gram (:func:`_gram_columns`): 8 MB of float64 at l = 516.
_GRAM_ROWS = 2048


def _gram_columns(z: np.ndarray) -> np.ndarray:
    """Z^T Z (l, l) float64 of ``z`` (m, l) float32, piece by piece of rows in order (no
    float64 copy of Z; the pieces a function of m alone)."""
    def piece(a):
        part = z[a:a + _GRAM_ROWS].astype(np.float64)
        return part.T @ part

    with one_blas_thread():
        parts = in_threads(piece, range(0, z.shape[0], _GRAM_ROWS))
    g = np.zeros((z.shape[1], z.shape[1]))
    for part in parts:            # in order: the same sum on any number of CPUs
        g += part
    return g


#: Largest ratio of R's diagonal extremes for which Q = Y R^-1 replaces Householder's Q: in
#: float64 its columns are then orthonormal to ~1e-10, far below the float32 basis's rounding.
_R_INVERSE_RANGE = 1e6


def _q_times(y: np.ndarray, r: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Q w (S, n) float64 for the QR factorisation Y = Q R of ``y`` (S, l) float64, given its
    ``r`` (l, l) and ``w`` (l, n): as Y (R^-1 w), a small solve and one GEMM over Y cut by
    rows, where R is well conditioned (the randomized range is, but for rank-deficient
    data); else with Householder's Q, formed only then."""
    d = np.abs(np.diag(r))
    with one_blas_thread():
        if len(d) and d.min() > d.max() * (1.0 / _R_INVERSE_RANGE):
            return rows_gemm(y, np.linalg.solve(r, w))
        return rows_gemm(np.linalg.qr(y)[0], w)
