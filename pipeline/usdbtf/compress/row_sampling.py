"""Coefficients from a sample of rows: least squares on leverage-sampled samples.

The projection c(t) = U^T x(t) needs every sample of every texel.  When the pixels are a
nonlinear function of something cheap to evaluate anywhere (a factorisation decoded through
a logarithmic colour model, :mod:`.factored`), evaluating m of the S samples for every texel
and solving

    c(t) = argmin_c || D (U_R c - x_R(t)) ||        (R the m sampled rows, D their weights)

costs m / S of the full pass.  If x(t) = U c*(t) + e(t), the solution is c* plus
(D U_R)^+ D e_R(t): exact for a texel inside the basis, and for the rest adding on average
about k / m of the residual's energy when rows are drawn with probability proportional to
their leverage ||U[s, :]||^2 and weighted 1 / (m p_s) (Drineas, Mahoney & Muthukrishnan,
"Sampling algorithms for l2 regression and applications", SODA 2006).  Rows drawn uniformly
instead miss the few samples a specular basis vector lives on; benchmarks/bench_transcode.py
measures both against the exact projection (benchmarks/RESULTS.md).

Half of each row's probability is uniform (1 / 2S), so no sample's weight can exceed 2 S / m.
"""
from __future__ import annotations

import numpy as np

__all__ = ["leverage_rows", "solve_operators", "default_rows", "ROWS_PER_COMPONENT"]

#: Default rows per basis vector (m = 16 k; see RESULTS.md for the error against m).
ROWS_PER_COMPONENT = 16


def default_rows(k: int, n_samples: int) -> int:
    """m = ROWS_PER_COMPONENT k, at most S (then every row: the exact projection)."""
    return int(min(n_samples, ROWS_PER_COMPONENT * max(k, 1)))


def leverage_rows(u: np.ndarray, m: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows to solve on, and their weights.

    Parameters
    ----------
    u : (S, k) orthonormal basis.
    m : rows to draw (with replacement; a row drawn twice counts twice).  m >= S: every row,
        weight 1 (the plain projection).
    seed : numpy Generator seed (the same seed draws the same rows).

    Returns
    -------
    rows : (n,) int, sorted, distinct (n <= m).
    weights : (n,) float64, (draws of the row) / (m p_row).
    """
    S = u.shape[0]
    if m >= S:
        return np.arange(S), np.ones(S)
    lev = np.einsum("sk,sk->s", u, u, dtype=np.float64)
    p = 0.5 / S + (0.5 * lev / lev.sum() if lev.sum() > 0 else 0.5 / S)
    p /= p.sum()
    draws = np.random.default_rng(seed).choice(S, size=m, p=p)
    rows, counts = np.unique(draws, return_counts=True)
    return rows, counts / (m * p[rows])


def solve_operators(u: np.ndarray, rows: np.ndarray, weights: np.ndarray, ks) -> list:
    """Per colour plane j, the (k_j, n) float32 operator P_j with c_j(t) = P_j x_R(t):
    the weighted least-squares solution on the first k_j basis vectors (None for k_j = 0).

    P_j = (D U_R[:, :k_j])^+ D, D = diag(sqrt(weights)); the pseudo-inverse makes an
    underdetermined request (fewer rows than vectors) the minimum-norm solution."""
    sw = np.sqrt(weights)
    ur = u[rows].astype(np.float64) * sw[:, None]
    ops = {}
    for kj in sorted(set(int(k) for k in ks if k)):
        ops[kj] = np.ascontiguousarray(np.linalg.pinv(ur[:, :kj]) * sw[None, :], dtype=np.float32)
    return [ops.get(int(k)) if k else None for k in ks]
