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

from .codecs import uniform_codes
from .parallel import cpu_count, in_threads

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

    def column(self, step: float) -> int:
        """j, the column of candidate step ``step`` (one of :attr:`steps`)."""
        return list(self.steps).index(step)

    def curves(self, factor: float, basis_factor: float | None = None):
        """bytes (k+1, J) and sqerr (k+1, J) of keeping the first 0..k components.

        ``factor`` (and ``basis_factor``, default the same) scale the entropy estimates to
        what the codec really writes (measured on a probe encode by :mod:`.ratecontrol`)."""
        basis_factor = factor if basis_factor is None else basis_factor
        per_bytes = factor * self.coeff_bytes + basis_factor * self.basis_bytes + FILE_OVERHEAD_BYTES
        per_err = self.coeff_sqerr + self.basis_sqerr[None, :]
        k, J = per_bytes.shape
        bytes_ = np.vstack([np.full((1, J), FILE_OVERHEAD_BYTES), FILE_OVERHEAD_BYTES + np.cumsum(per_bytes, 0)])
        dropped = np.concatenate([np.cumsum(self.energy[::-1])[::-1], [0.0]])  # energy of components >= k
        err = np.vstack([np.zeros((1, J)), np.cumsum(per_err, 0)]) + dropped[:, None] + self.residual
        return bytes_, err


_HIGH_RATE_BITS = 6.0  # past this entropy a uniform quantiser follows H = h - log2(step), err = step^2/12
_MAX_BINS = 2**24      # histogram bins counted at once; rows with wider spans are counted one by one


def _entropy_rows(q: np.ndarray) -> np.ndarray:
    """Zero-order entropy (bits, whole row) of each row of integer symbols ``q`` (r, n):
    one bincount over all rows, each shifted into its own range of bins."""
    r, n = q.shape
    shifted = q - q.min(axis=1, keepdims=True)
    span = shifted.max(axis=1) + 1
    if int(span.sum()) > _MAX_BINS:
        return np.array([_entropy_bits(row) for row in q])
    offsets = np.concatenate([[0], np.cumsum(span)[:-1]])
    counts = np.bincount((shifted + offsets[:, None]).ravel(), minlength=int(span.sum()))
    row = np.repeat(np.arange(r), span)
    used = counts > 0
    p = counts[used] / n
    return np.bincount(row[used], weights=-p * np.log2(p), minlength=r) * n


def _rate_and_error(values: np.ndarray, steps: np.ndarray, rates: bool = True, *,
                    threads: int | None = None, dead_zone: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Entropy (bits, whole row) and squared error of quantising each row of ``values``
    (r, n) at each step: two (r, J) arrays.

    Steps run coarse -> fine.  A row's exact histograms are taken until its entropy passes
    ``_HIGH_RATE_BITS`` per symbol; finer steps use the high-rate laws (each halving of the
    step adds one bit per symbol, error = n step^2 / 12), which are accurate there and keep
    this table cheap.  Without ``rates`` only the errors are measured (bits are 0, or inf
    past 16 bits), and a row goes high-rate once it spans more than 2^6 steps.

    The rows are measured in blocks of ``_BLOCK_ROWS`` (each block's values stay in cache
    over all the steps), the blocks on ``threads`` threads (default :func:`cpu_count`); the
    numbers are those of measuring all rows at once, step by step (:func:`_stepwise`), bit
    for bit, on any number of threads.  Where that would count a step's histograms row by
    row (more than ``_MAX_BINS`` bins in all) or a row's symbols leave the exactly
    representable integers, the blocks stop and :func:`_stepwise` measures the rest.

    ``dead_zone``: the rows are quantised as the coefficients are under a budget
    (:func:`.codecs.uniform_codes`: a row rint leaves mostly zero is rounded towards zero),
    measured by :func:`_stepwise` alone (the blocks round to nearest).  Rows past
    ``_HIGH_RATE_BITS`` are dense, rounded to nearest, so the high-rate laws still hold.
    """
    r, n = values.shape
    J = len(steps)
    bits, err = np.zeros((r, J)), np.zeros((r, J))
    last = np.full(r, -1)                                   # each row's last exactly measured step
    start, active = 0, np.arange(r)
    if (not dead_zone and r and n and J and values.dtype == np.float64 and steps.dtype == np.float64 and steps.ndim == 1
            and np.all(np.isfinite(steps) & (steps > 0))):
        start, active = _blocked(values, steps, rates, bits, err, last, threads)
    _stepwise(values, steps, rates, bits, err, last, active, start, dead_zone)
    ref = np.maximum(last, 0)
    finer = np.arange(J)[None, :] > last[:, None]
    if rates:
        bits = np.where(finer, bits[np.arange(r), ref][:, None] + n * np.log2(steps[ref][:, None] / steps[None, :]), bits)
    err = np.where(finer, n * steps[None, :] ** 2 / 12.0, err)
    if n:
        span = (values.max(axis=1) - values.min(axis=1))[:, None] / steps[None, :]
        bits[span >= 2**16 - 1] = np.inf          # would need more than 16 bits per sample
    return bits, err


def _stepwise(values, steps, rates, bits, err, last, active, start, dead_zone=False):
    """Measure steps ``start``.. of the rows ``active`` (those still measured exactly at step
    ``start``), all rows at once per step, into ``bits``, ``err`` and ``last``; each row
    quantised as :func:`.codecs.uniform_codes` quantises a channel (``dead_zone``)."""
    n = values.shape[1]
    for j in range(start, len(steps)):
        if active.size == 0:
            break
        d = steps[j]
        v = values[active]
        q = (uniform_codes((v / d).T, True).T if dead_zone else np.rint(v / d)).astype(np.int64)
        err[active, j] = ((v - q * d) ** 2).sum(axis=1)
        last[active] = j
        if rates:
            bits[active, j] = _entropy_rows(q)
            active = active[bits[active, j] <= _HIGH_RATE_BITS * n]
        else:
            active = active[q.max(axis=1) - q.min(axis=1) <= 2**_HIGH_RATE_BITS]


_BLOCK_ROWS = 64     # rows per block of _blocked (fixed: the numbers do not depend on it)
_EXACT = 2.0**52     # symbols below this size are the same as floats and as int64
_INT32 = 2.0**30     # symbols below this size are cast to int32 before they are shifted (by < 2^31)


def _blocked(values, steps, rates, bits, err, last, threads):
    """:func:`_stepwise` from step 0 in blocks of rows; fills ``bits``, ``err``, ``last`` up to
    the first step the blocks cannot do like it, and returns that step and its active rows.

    The quantised values are kept as floats (integers, the same numbers as the int64 ones
    below ``_EXACT``).  Each row's symbols at step d span rint(min / d) .. rint(max / d)
    (division by d > 0 and rounding are monotone), so the spans are known without looking
    at the quantised row.  A row's entropy is the sum over its histogram's bins, in bin
    order, of -p log2 p (looked up by count: the same products as for the used bins alone,
    and the empty bins add +0.0), accumulated by ``bincount`` one term after the other like
    :func:`_entropy_rows`; the squared error is ``sum`` over the same contiguous row.
    """
    r, n = values.shape
    J = len(steps)
    vmin, vmax = values.min(axis=1), values.max(axis=1)
    if not (np.all(np.isfinite(vmin)) and np.all(np.isfinite(vmax))):
        return 0, np.arange(r)
    lo = np.rint(vmin[:, None] / steps[None, :])            # (r, J): each row's symbol range per step
    hi = np.rint(vmax[:, None] / steps[None, :])
    size = np.maximum(np.abs(lo), np.abs(hi))
    exact = size < _EXACT
    span = np.where(exact, hi - lo + 1, 1).astype(np.int64)
    wide = hi - lo > 2**_HIGH_RATE_BITS                     # rates=False: past this a row goes high-rate
    # the first step each row's symbols leave the exact integers / int32
    inexact = np.where(exact.all(axis=1), J, np.argmin(exact, axis=1))
    small = size < _INT32
    large = np.where(small.all(axis=1), J, np.argmin(small, axis=1))
    zero = (vmin == 0) & (vmax == 0)                        # error and entropy 0 at every step
    last[zero] = J - 1
    # Up to step flat[i] row i quantises to one symbol: entropy 0, no need to divide.  Rows
    # are grouped by it (most such steps first), so that in a block those rows lead.
    one = span == 1
    flat = np.where(one.all(axis=1), J, np.argmin(one, axis=1))
    rows = np.flatnonzero(~zero)
    rows = rows[np.argsort(-flat[rows], kind="stable")]
    term = np.zeros(n + 1)                                  # -p log2 p of a bin counting c symbols
    p = np.arange(1, n + 1) / n
    term[1:] = -p * np.log2(p)
    limit = _HIGH_RATE_BITS * n

    def block(ids):
        m = len(ids)
        v = values[ids]
        t = np.empty((m, n))
        sym = np.empty((m, n), np.int32)
        b, er = np.zeros((J, m)), np.zeros((J, m))          # per step: one row of the block's numbers
        until = np.full(m, J)                               # each row's first step not measured exactly
        spans = np.zeros(J, np.int64)
        act = np.arange(m)
        sp_b, lo_b, wide_b, flat_b = span[ids], lo[ids], wide[ids], flat[ids]
        stop_at, int32_at = inexact[ids].min(), large[ids].min()
        stop = J
        for j in range(J):
            a = len(act)
            if a == 0:
                break
            sp = sp_b[:, j]
            total = int(sp.sum())
            if j >= stop_at or (rates and total > _MAX_BINS):
                stop = j
                break
            spans[j] = total
            d = steps[j]
            f = int(np.count_nonzero(flat_b > j))           # rows 0..f-1: one symbol (lo * d)
            if f:
                ee = np.subtract(v[:f], (lo_b[:f, j] * d)[:, None], out=t[:f])
                np.multiply(ee, ee, out=ee)
                er[j, act[:f]] = ee.sum(axis=1)
            if f == a:
                continue                                    # entropies 0, every row kept
            vr, sr = v[f:], sp[f:]
            tq = np.divide(vr, d, out=t[f:a])
            np.rint(tq, out=tq)
            if rates:
                shift = np.cumsum(sr) - sr - lo_b[f:, j]    # row i's symbols go to bins offset_i..
                s = sym[f:a]
                if j < int32_at:
                    np.copyto(s, tq, casting="unsafe")
                    np.add(s, shift.astype(np.int32)[:, None], out=s)
                else:
                    np.copyto(s, tq + shift[:, None], casting="unsafe")
                counts = np.bincount(s.ravel(), minlength=int(sr.sum()))
            np.multiply(tq, d, out=tq)
            np.subtract(vr, tq, out=tq)
            np.multiply(tq, tq, out=tq)
            er[j, act[f:]] = tq.sum(axis=1)
            if rates:
                h = np.bincount(np.repeat(np.arange(a - f), sr), weights=term[counts], minlength=a - f) * n
                b[j, act[f:]] = h
                keep = h <= limit
            else:
                keep = ~wide_b[f:, j]
            if not keep.all():
                keep = np.concatenate([np.ones(f, bool), keep])
                until[act[~keep]] = j + 1
                act, v = act[keep], v[keep]
                sp_b, lo_b, wide_b, flat_b = sp_b[keep], lo_b[keep], wide_b[keep], flat_b[keep]
                if act.size:
                    stop_at, int32_at = inexact[ids[act]].min(), large[ids[act]].min()
        return b.T, er.T, np.minimum(until, stop) - 1, until, spans, stop

    blocks = [rows[i:i + _BLOCK_ROWS] for i in range(0, len(rows), _BLOCK_ROWS)]
    threads = cpu_count() if threads is None else threads
    out = in_threads(block, blocks, threads=threads) if blocks else []
    start = min([o[5] for o in out], default=J)
    if rates:
        total = sum((o[4] for o in out), np.zeros(J, np.int64)) + int(zero.sum())
        over = np.flatnonzero(total[:start] > _MAX_BINS)
        start = int(over[0]) if over.size else start
    until = np.full(r, J)
    for ids, (b, er, lst, unt, _, _) in zip(blocks, out):
        bits[ids], err[ids], last[ids], until[ids] = b, er, lst, unt
    active = np.flatnonzero(until > start)                  # the rows measured exactly at step start
    if start < J:                                           # forget what the blocks measured from here on
        bits[:, start:] = 0
        err[:, start:] = 0
        np.minimum(last, start - 1, out=last)
    return start, active


_SLAB = 32  # components per slab of _energy_and_rows


def _energy_and_rows(coeff, sub, threads):
    """Each component's energy (sum of squares of its coefficients, in float64) and the
    sampled texels' coefficients as float64 rows (3 k, len(sub)), component by component
    (channel-major within a component), on threads over slabs of ``_SLAB`` components.
    ``einsum`` sums each component's squares the same way whichever components it is given
    (the tests check it against one call over all), so only a C-contiguous array is cut."""
    k, n, _ = coeff.shape
    rows = np.empty((k, 3, len(sub)))
    dense = coeff.flags.c_contiguous
    cut = dense and k > _SLAB
    if not cut:
        energy = np.einsum("kpc,kpc->k", coeff, coeff, dtype=np.float64)
    else:
        energy = np.empty(k)

    flat = (3 * sub[None, :] + np.arange(3)[:, None]).ravel()  # the sampled (texel, channel)s, channel-major

    def slab(i):
        part = coeff[i:i + _SLAB]
        if cut:
            energy[i:i + _SLAB] = np.einsum("kpc,kpc->k", part, part, dtype=np.float64)
        if dense:
            rows[i:i + _SLAB] = np.take(part.reshape(len(part), -1), flat, axis=1).reshape(len(part), 3, len(sub))
        else:
            rows[i:i + _SLAB] = part[:, sub].transpose(0, 2, 1)

    in_threads(slab, range(0, k, _SLAB), threads=cpu_count() if threads is None else threads)
    return energy, rows.reshape(3 * k, len(sub))


def rd_table(coeff: np.ndarray, basis: np.ndarray, total_energy: float | None, *, n_texels: int | None = None,
             n_steps: int = 40, subsample: int = 2048, seed: int = 0, rates: bool = True,
             threads: int | None = None, dead_zone: bool = False) -> RDTable:
    """Build the table.

    coeff : (k, n, 3) float32 coefficients (decorrelated channels), energy-ordered, of all
        ``n_texels`` texels (default) or of a sample of them (energies and bytes are scaled
        up by n_texels / n).
    basis : (S, k) float32 orthonormal basis.
    total_energy : sum of squares of the whole data matrix, for the out-of-basis residual;
        None when unknown (the residual is then 0: a constant offset that does not change
        which (k, step) a byte budget or a fixed k picks).
    rates : estimate bytes (entropies); without, only errors (enough for :func:`choose_for_k`).
    threads : threads measuring the rows (default :func:`cpu_count`); the table does not depend on it.
    dead_zone : the coefficients' rows quantised with the dead zone of sparse planes
        (:func:`.codecs.uniform_codes`, as :func:`.quantise.quantise` does under a budget); the
        basis columns are rounded to nearest either way.
    """
    k, n, _ = coeff.shape
    n_texels = n if n_texels is None else n_texels
    S = basis.shape[0]
    rng = np.random.default_rng(seed)
    sub = np.sort(rng.choice(n, size=min(n, subsample), replace=False))
    scale = n_texels / len(sub)
    energy, rows = _energy_and_rows(coeff, sub, threads)
    energy = energy * (n_texels / max(n, 1))
    rms0 = np.sqrt(energy[0] / (3 * n_texels)) if k else 1.0
    steps = rms0 * 2.0 ** (-np.arange(n_steps) / 2.0 - 1.0)
    b, e = _rate_and_error(rows, steps, rates, threads=threads, dead_zone=dead_zone)
    cb = scale * b.reshape(k, 3, n_steps).sum(axis=1) / 8
    ce = scale * e.reshape(k, 3, n_steps).sum(axis=1)
    # Basis column i is quantised with step / sigma_i: the same table, rescaled.
    sigma = np.sqrt(energy)
    # Scaling by sigma_i >= 0 is monotone: the scaled columns' extremes are the scaled extremes,
    # and only the sampled rows of the scaled basis are formed (the same numbers as scaling all).
    cheap = basis.dtype.kind == "f" and bool(np.all(np.isfinite(sigma)))
    if cheap:
        top, bottom = basis.max(axis=0).astype(np.float64) * sigma, basis.min(axis=0).astype(np.float64) * sigma
    else:
        scaled = (basis.astype(np.float64) * sigma[None, :]).T             # (k, S)
        top, bottom = scaled.max(axis=1), scaled.min(axis=1)
    span = (top - bottom)[:, None] / steps[None, :]
    bb = np.where(span >= 2**16 - 1, np.inf, 0.0)                          # a column must fit 16 bits
    if rates:
        # The columns' entropies on a subsample of ``subsample`` rows, like the coefficients'
        # (all S rows: 2.5 s of CPU per table for k = 500 at paper scale; the codec factor
        # calibrated on a probe encode absorbs what the estimate misses).
        rows_b = np.sort(rng.choice(S, size=min(S, subsample), replace=False))
        if cheap:
            cols = np.ascontiguousarray((basis[rows_b].astype(np.float64) * sigma[None, :]).T)
        else:
            cols = scaled[:, rows_b]
        bb = bb + _rate_and_error(cols, steps, threads=threads)[0] * (S / len(rows_b)) / 8
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
        # Between grid steps: the added error grows as step^2 (high rate), so scale the
        # coarsest passing step up to the budget, without passing the next coarser grid step.
        j = int(np.flatnonzero(ok)[0])
        step = float(table.steps[j])
        if added[j] > 0 and j > 0:
            step = min(step * float(np.sqrt(allowed[j] / added[j])), float(table.steps[j - 1]))
        return step
    return float(table.steps[np.flatnonzero(finite)[-1]]) if finite.any() else float(table.steps[0])
