"""Rate-distortion choice of (k, quantisation step) for the default solver.

With an orthonormal basis U (S x k) and coefficients C (k x m), quantising
coefficient rows with a uniform step D and basis column i with step a_i adds
squared error  m D^2/12 (per row)  and  S a_i^2 sigma_i^2 / 12  (per column),
sigma_i = ||C_i||.  Equal marginal returns (reverse water-filling) give one
global step: a_i = D / sigma_i.  Bits are estimated from the zero-order entropy
of the quantised symbols on a texel subsample, times a codec efficiency factor
calibrated by a real encode.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RDTable", "rd_table", "choose_for_bytes", "choose_for_error", "choose_for_k"]

FILE_OVERHEAD_BYTES = 120  # header + container of one small lossless image


def _entropy_bits(q: np.ndarray) -> float:
    """Zero-order entropy of integer symbols, in bits for the whole array."""
    q = q.ravel()
    counts = np.bincount(q - q.min())
    p = counts[counts > 0] / q.size
    return float(-(p * np.log2(p)).sum() * q.size)


@dataclass
class RDTable:
    """Per component i and candidate step j: estimated bytes and squared error.

    steps (J,), coeff_bytes (k, J), basis_bytes (k, J), coeff_sqerr (k, J), basis_sqerr (J,) per component,
    energy (k,) = sigma_i^2, residual = energy outside the k fitted components.
    """

    steps: np.ndarray
    coeff_bytes: np.ndarray
    basis_bytes: np.ndarray
    coeff_sqerr: np.ndarray
    basis_sqerr: np.ndarray
    energy: np.ndarray
    residual: float

    def curves(self, factor: float, basis_factor: float | None = None):
        """bytes (k+1, J) and sqerr (k+1, J) of keeping the first 0..k components.

        ``factor`` (and ``basis_factor``, default the same) scale the entropy estimates to
        what the codec really writes (measured by :func:`..core` on a probe encode)."""
        basis_factor = factor if basis_factor is None else basis_factor
        per_bytes = factor * self.coeff_bytes + basis_factor * self.basis_bytes + FILE_OVERHEAD_BYTES
        per_err = self.coeff_sqerr + self.basis_sqerr[None, :]
        k, J = per_bytes.shape
        bytes_ = np.vstack([np.full((1, J), FILE_OVERHEAD_BYTES), FILE_OVERHEAD_BYTES + np.cumsum(per_bytes, 0)])
        dropped = np.concatenate([np.cumsum(self.energy[::-1])[::-1], [0.0]])  # energy of components >= k
        err = np.vstack([np.zeros((1, J)), np.cumsum(per_err, 0)]) + dropped[:, None] + self.residual
        return bytes_, err


_HIGH_RATE_BITS = 6.0  # past this entropy a uniform quantiser follows H = h - log2(step), err = step^2/12


def _rate_and_error(values: np.ndarray, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Entropy (bits, whole array) and squared error of quantising ``values`` (n,) at each step.

    Steps run coarse -> fine.  Exact bincounts are taken until the entropy passes
    ``_HIGH_RATE_BITS`` per symbol; finer steps use the high-rate laws (each halving of
    the step adds one bit per symbol, error = n step^2 / 12), which are accurate there
    and keep this table cheap (a handful of bincounts per channel instead of ~40).
    """
    n = values.size
    bits = np.empty(len(steps))
    err = np.empty(len(steps))
    exact_until = len(steps)
    for j, d in enumerate(steps):
        q = np.rint(values / d).astype(np.int64)
        bits[j] = _entropy_bits(q)
        err[j] = float(((values - q * d) ** 2).sum())
        if bits[j] > _HIGH_RATE_BITS * n:
            exact_until = j + 1
            break
    if exact_until < len(steps):
        ref = exact_until - 1
        finer = steps[exact_until:]
        bits[exact_until:] = bits[ref] + n * np.log2(steps[ref] / finer)
        err[exact_until:] = n * finer**2 / 12.0
    span = (values.max() - values.min()) / steps if n else np.zeros(len(steps))
    bits[span >= 2**16 - 1] = np.inf          # would need more than 16 bits per sample
    return bits, err


def rd_table(coeff: np.ndarray, basis: np.ndarray, total_energy: float | None, *, n_steps: int = 40,
             subsample: int = 2048, seed: int = 0) -> RDTable:
    """Build the table.

    coeff : (k, P, 3) float32 coefficients (decorrelated channels), energy-ordered.
    basis : (S, k) float32 orthonormal basis.
    total_energy : sum of squares of the whole data matrix, for the out-of-basis residual;
        None when unknown (the residual is then 0: a constant offset that does not change
        which (k, step) a byte budget or a fixed k picks).
    """
    k, P, _ = coeff.shape
    S = basis.shape[0]
    energy = np.einsum("kpc,kpc->k", coeff, coeff, dtype=np.float64)
    rms0 = np.sqrt(energy[0] / (3 * P)) if k else 1.0
    steps = rms0 * 2.0 ** (-np.arange(n_steps) / 2.0 - 1.0)
    rng = np.random.default_rng(seed)
    sub = np.sort(rng.choice(P, size=min(P, subsample), replace=False))
    scale = P / len(sub)
    cb = np.zeros((k, n_steps))
    ce = np.zeros((k, n_steps))
    bb = np.zeros((k, n_steps))
    for i in range(k):
        c = coeff[i, sub].astype(np.float64)                       # (n, 3)
        for ch in range(3):
            b, e = _rate_and_error(c[:, ch], steps)
            cb[i] += scale * b / 8
            ce[i] += scale * e
        sigma = np.sqrt(energy[i])
        # Basis column i is quantised with step / sigma_i: the same table, rescaled.
        b, _ = _rate_and_error(basis[:, i].astype(np.float64) * sigma, steps)
        bb[i] = b / 8
    basis_err = S * steps**2 / 12.0                                 # per component, independent of i
    residual = 0.0 if total_energy is None else max(float(total_energy - energy.sum()), 0.0)
    return RDTable(steps, cb, bb, ce, basis_err, energy, residual)


def _best(bytes_, err, feasible):
    err = np.where(feasible, err, np.inf)
    flat = int(np.argmin(err))
    kk, j = np.unravel_index(flat, err.shape)
    return int(kk), int(j)


def choose_for_bytes(table: RDTable, max_bytes: float, factor: float,
                     basis_factor: float | None = None) -> tuple[int, float]:
    """(k, step) with least squared error within ``max_bytes``."""
    bytes_, err = table.curves(factor, basis_factor)
    feasible = bytes_ <= max_bytes
    feasible[0] = False
    if not feasible.any():
        return 1, float(table.steps[0])
    k, j = _best(bytes_, err, feasible)
    return k, float(table.steps[j])


def choose_for_error(table: RDTable, max_sqerr: float, factor: float) -> tuple[int, float]:
    """(k, step) with fewest bytes whose squared error is <= ``max_sqerr`` (best error if none)."""
    bytes_, err = table.curves(factor)
    ok = err <= max_sqerr
    ok[0] = False
    if not ok.any():
        k, j = _best(bytes_, err, np.isfinite(bytes_) & (np.arange(len(bytes_)) > 0)[:, None])
        return k, float(table.steps[j])
    cost = np.where(ok, bytes_, np.inf)
    k, j = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return int(k), float(table.steps[j])


def choose_for_k(table: RDTable, k: int, quant_fraction: float = 0.1) -> float:
    """Largest step whose added quantisation error stays within ``quant_fraction`` of the
    truncation error at ``k`` (so quantisation never dominates what k already costs).

    At full rank the truncation error is ~0; the budget then has a floor of 1e-6 of the
    total energy (60 dB below the signal), and only steps that fit 16 bits are eligible.
    """
    bytes_, err = table.curves(1.0)
    kept = np.cumsum(table.coeff_sqerr + table.basis_sqerr[None, :], 0)[k - 1]
    trunc = err[k, :] - kept
    total = float(table.energy.sum() + table.residual)
    added = kept
    allowed = quant_fraction * np.maximum(trunc, 1e-6 * total)
    finite = np.isfinite(bytes_[k, :])
    ok = finite & (added <= allowed)
    if ok.any():
        return float(table.steps[np.flatnonzero(ok)[0]])
    return float(table.steps[np.flatnonzero(finite)[-1]]) if finite.any() else float(table.steps[0])
