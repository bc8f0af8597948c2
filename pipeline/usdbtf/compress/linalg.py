"""Basis fitting and projection: functions over chunks of the data matrix.

The data matrix X is S x m (rows = samples, columns = pixel channels): column
``3 t + c`` is channel c of texel t, the apparent BRDF of that texel.  Functions
take and return plain arrays so each can run unchanged on a distributed engine.
"""
from __future__ import annotations

import numpy as np

from .parallel import one_blas_thread, rows_gemm

__all__ = ["fix_signs", "exact_basis", "randomized_basis", "orthonormalize"]


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
            with one_blas_thread():
                r = np.linalg.cholesky(g).T                   # upper: g = r^T r
                r_inv = np.linalg.inv(r)
            # Y R^-1 as a GEMM with the small inverse: a triangular solve with an S-column
            # right-hand side costs 10x more, and the second round restores orthogonality.
            q = rows_gemm(q64, r_inv).astype(np.float32)
        if not np.isfinite(q).all():
            raise np.linalg.LinAlgError("CholeskyQR lost precision")
        return np.ascontiguousarray(q)
    except np.linalg.LinAlgError:
        with one_blas_thread():
            return np.linalg.qr(y)[0]


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


def randomized_basis(x: np.ndarray, k: int, *, oversample: int = 16, power_iterations: int = 1,
                     seed: int = 0, return_coefficients: bool = False):
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
    """
    s_rows, m = x.shape
    l = min(k + oversample, s_rows, m)
    rng = np.random.default_rng(seed)
    omega = rng.standard_normal((m, l), dtype=np.float32)
    q = orthonormalize(rows_gemm(x, omega))
    if power_iterations < 1:
        b = rows_gemm(q.T, x).astype(np.float64)                          # (l, m)
        y = r = None                   # U = Q Ub with this Q itself
    else:
        for _ in range(power_iterations - 1):
            q = orthonormalize(rows_gemm(x, orthonormalize(rows_gemm(x.T, q))))
        # Last iteration: Y = X Z = Q R with Z orthonormal and X ~= X Z Z^T, so
        # B = Q^T X ~= R Z^T -- the small factors replace a fourth GEMM over X
        # (paper-scale pebbles and fuzzy moss: error within 0.1 % relative of Q^T X).
        z = orthonormalize(rows_gemm(x.T, q)).astype(np.float64)
        y = rows_gemm(x, z.astype(np.float32)).astype(np.float64)
        with one_blas_thread():
            r = np.linalg.qr(y, mode="r")       # R alone: half the time of Q and R (0.26 s of 0.56)
        b = rows_gemm(r, z.T)                                             # (l, m)
    with one_blas_thread():
        evals, ub = np.linalg.eigh(b @ b.T)          # (l, l): cheap
    order = np.argsort(evals)[::-1][:k]
    sv = np.sqrt(np.maximum(evals[order], 0.0))
    u64 = rows_gemm(q.astype(np.float64), ub[:, order]) if r is None else _q_times(y, r, ub[:, order])
    u = np.ascontiguousarray(u64, dtype=np.float32)
    signs = fix_signs(u)
    if not return_coefficients:
        return u, sv
    coeff = rows_gemm(ub[:, order].T * signs[:, None], b)     # U^T X = Ub^T B
    return u, sv, coeff.astype(np.float32)


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
