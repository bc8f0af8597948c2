"""Tests for usdbtf.compress.ratedist's table (rd_table and its helpers).

The blocked, threaded measurement must give the numbers of the plain row-by-row one bit for
bit: a verbatim copy of that one (``_ref_*``, as of commit f80ac15) is kept here and every
field of the table is compared with ``np.array_equal`` on inputs that reach each of its
branches (all-zero rows, spans past the histogram limit and past 16 bits, rates on and off,
texel scaling), on 1 and 3 threads.  A few value checks do not lean on the copy.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from usdbtf.compress import ratedist
from usdbtf.compress.ratedist import RDTable

FIELDS = ["steps", "coeff_bytes", "basis_bytes", "coeff_sqerr", "basis_sqerr", "energy", "residual"]

# ---- reference: the row-by-row implementation, verbatim (names prefixed _ref) ----

_HIGH_RATE_BITS = 6.0  # past this entropy a uniform quantiser follows H = h - log2(step), err = step^2/12
_MAX_BINS = 2**24      # histogram bins counted at once; rows with wider spans are counted one by one


def _ref_entropy_bits(q: np.ndarray) -> float:
    """Zero-order entropy of integer symbols, in bits for the whole array."""
    q = q.ravel()
    counts = np.bincount(q - q.min())
    p = counts[counts > 0] / q.size
    return float(-(p * np.log2(p)).sum() * q.size)


def _ref_entropy_rows(q: np.ndarray) -> np.ndarray:
    """Zero-order entropy (bits, whole row) of each row of integer symbols ``q`` (r, n):
    one bincount over all rows, each shifted into its own range of bins."""
    r, n = q.shape
    shifted = q - q.min(axis=1, keepdims=True)
    span = shifted.max(axis=1) + 1
    if int(span.sum()) > _MAX_BINS:
        return np.array([_ref_entropy_bits(row) for row in q])
    offsets = np.concatenate([[0], np.cumsum(span)[:-1]])
    counts = np.bincount((shifted + offsets[:, None]).ravel(), minlength=int(span.sum()))
    row = np.repeat(np.arange(r), span)
    used = counts > 0
    p = counts[used] / n
    return np.bincount(row[used], weights=-p * np.log2(p), minlength=r) * n


def _ref_rate_and_error(values: np.ndarray, steps: np.ndarray, rates: bool = True) -> tuple[np.ndarray, np.ndarray]:
    r, n = values.shape
    J = len(steps)
    bits, err = np.zeros((r, J)), np.zeros((r, J))
    last = np.full(r, -1)                                   # each row's last exactly measured step
    active = np.arange(r)
    for j, d in enumerate(steps):
        if active.size == 0:
            break
        v = values[active]
        q = np.rint(v / d).astype(np.int64)
        err[active, j] = ((v - q * d) ** 2).sum(axis=1)
        last[active] = j
        if rates:
            bits[active, j] = _ref_entropy_rows(q)
            active = active[bits[active, j] <= _HIGH_RATE_BITS * n]
        else:
            active = active[q.max(axis=1) - q.min(axis=1) <= 2**_HIGH_RATE_BITS]
    ref = np.maximum(last, 0)
    finer = np.arange(J)[None, :] > last[:, None]
    if rates:
        bits = np.where(finer, bits[np.arange(r), ref][:, None] + n * np.log2(steps[ref][:, None] / steps[None, :]), bits)
    err = np.where(finer, n * steps[None, :] ** 2 / 12.0, err)
    if n:
        span = (values.max(axis=1) - values.min(axis=1))[:, None] / steps[None, :]
        bits[span >= 2**16 - 1] = np.inf          # would need more than 16 bits per sample
    return bits, err


def _ref_rd_table(coeff: np.ndarray, basis: np.ndarray, total_energy: float | None, *, n_texels: int | None = None,
                  n_steps: int = 40, subsample: int = 2048, seed: int = 0, rates: bool = True) -> RDTable:
    k, n, _ = coeff.shape
    n_texels = n if n_texels is None else n_texels
    S = basis.shape[0]
    energy = np.einsum("kpc,kpc->k", coeff, coeff, dtype=np.float64) * (n_texels / max(n, 1))
    rms0 = np.sqrt(energy[0] / (3 * n_texels)) if k else 1.0
    steps = rms0 * 2.0 ** (-np.arange(n_steps) / 2.0 - 1.0)
    rng = np.random.default_rng(seed)
    sub = np.sort(rng.choice(n, size=min(n, subsample), replace=False))
    scale = n_texels / len(sub)
    rows = coeff[:, sub].astype(np.float64).transpose(0, 2, 1).reshape(3 * k, len(sub))
    b, e = _ref_rate_and_error(rows, steps, rates)
    cb = scale * b.reshape(k, 3, n_steps).sum(axis=1) / 8
    ce = scale * e.reshape(k, 3, n_steps).sum(axis=1)
    # Basis column i is quantised with step / sigma_i: the same table, rescaled.
    sigma = np.sqrt(energy)
    scaled = (basis.astype(np.float64) * sigma[None, :]).T                 # (k, S)
    span = (scaled.max(axis=1) - scaled.min(axis=1))[:, None] / steps[None, :]
    bb = np.where(span >= 2**16 - 1, np.inf, 0.0)                          # a column must fit 16 bits
    if rates:
        rows_b = np.sort(rng.choice(S, size=min(S, subsample), replace=False))
        bb = bb + _ref_rate_and_error(scaled[:, rows_b], steps)[0] * (S / len(rows_b)) / 8
    basis_err = S * steps**2 / 12.0                                 # per component, independent of i
    residual = 0.0 if total_energy is None else max(float(total_energy - energy.sum()), 0.0)
    return RDTable(steps, cb, bb, ce, basis_err, energy, residual)

# ---- helpers ----


def _inputs(k, n, S, seed=0, decay=1.5):
    """Coefficients with energy falling like 1/i^decay (Gaussian values) and an orthonormal basis."""
    rng = np.random.default_rng(seed)
    sig = (1.0 + np.arange(k)) ** (-decay / 2)
    coeff = (rng.standard_normal((k, n, 3)) * sig[:, None, None] * 10).astype(np.float32)
    basis = np.linalg.qr(rng.standard_normal((S, k)))[0].astype(np.float32)
    return coeff, basis


def _assert_same(a, b):
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert np.array_equal(x, y), f
        if isinstance(x, np.ndarray):
            assert x.shape == y.shape and x.dtype == y.dtype, f


def _check(coeff, basis, total=None, threads=(1, 3), **kw):
    want = _ref_rd_table(coeff, basis, total, **kw)
    for t in threads:
        _assert_same(ratedist.rd_table(coeff, basis, total, threads=t, **kw), want)
    return want


def _check_rows(values, steps, rates=True, threads=(1, 3)):
    want = _ref_rate_and_error(values, steps, rates)
    for t in threads:
        got = ratedist._rate_and_error(values, steps, rates, threads=t)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    return want


def _check_rows_or_raise(values, steps, rates=True):
    """Like _check_rows where the reference may fail: then the module fails the same way."""
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        try:
            want = _ref_rate_and_error(values, steps, rates)
        except Exception as exc:  # noqa: BLE001 - whatever the reference raises, the module must too
            with pytest.raises(type(exc)):
                ratedist._rate_and_error(values, steps, rates)
            return
        got = ratedist._rate_and_error(values, steps, rates)
    assert np.array_equal(got[0], want[0], equal_nan=True)
    assert np.array_equal(got[1], want[1], equal_nan=True)


# ---- the same numbers as the reference ----


@pytest.mark.parametrize("k,n,S,sub", [(5, 700, 300, 256), (40, 3000, 2000, 2048), (70, 1500, 900, 512), (1, 1, 1, 2048)])
@pytest.mark.parametrize("rates", [True, False])
def test_same_as_reference(k, n, S, sub, rates):
    coeff, basis = _inputs(k, n, S, seed=k)
    _check(coeff, basis, 1e9, subsample=sub, rates=rates)
    _check(coeff, basis, None, n_texels=4 * n, subsample=sub, rates=rates, seed=3)


def test_zero_rows_and_channels():
    coeff, basis = _inputs(12, 900, 400, seed=2)
    coeff[3] = 0                    # a whole component
    coeff[5, :, 1] = 0              # one channel
    coeff[7, :, 2] = -0.0
    coeff[11] = 0                   # the last one
    for rates in (True, False):
        _check(coeff, basis, 1e9, subsample=512, rates=rates)
    b, e = _check_rows(np.zeros((4, 64)), np.array([1.0, 0.5, 0.25]))
    assert not b.any() and not e.any()


def test_huge_spans_past_16_bits():
    """Spikes: rows that stay low-entropy while their span passes 2^16 steps (inf bits)."""
    coeff, basis = _inputs(10, 1200, 500, seed=4)
    coeff[2, 7, 0] = 5e4
    coeff[6, 100, 1] = -3e5
    basis[13, 4] = 40.0
    for rates in (True, False):
        t = _check(coeff, basis, None, subsample=1200, rates=rates)
        assert np.isinf(t.coeff_bytes).any() and np.isinf(t.basis_bytes).any()


def test_histogram_limit_fallback(monkeypatch):
    """Steps whose histograms need more than _MAX_BINS bins are counted row by row (the limit
    lowered here, for the reference and the module alike, so that it is reached cheaply)."""
    for limit in (4000, 20000, 10**5):
        monkeypatch.setattr(ratedist, "_MAX_BINS", limit)
        monkeypatch.setitem(globals(), "_MAX_BINS", limit)
        coeff, basis = _inputs(20, 800, 300, seed=5)
        coeff[9, 3, 2] = 300.0      # one row's span grows past the limit by itself
        _check(coeff, basis, 1e9, subsample=800)
        _check(coeff, basis, 1e9, subsample=800, rates=False)


def test_histogram_limit_real():
    """A spike row whose span just passes 2^24 steps at the finest steps (the real limit)."""
    rng = np.random.default_rng(6)
    v = rng.standard_normal((6, 300))
    steps = 2.0 ** (-np.arange(12) / 2.0 - 1.0)
    v[4] = 0
    v[4, 17] = 1.1 * 2**24 * steps[-1]
    b, _ = _check_rows(v, steps)
    assert np.isinf(b[4, -1])


def test_symbols_past_exact_integers():
    """Rows far from zero (symbols past 2^31 and 2^52) and constant rows."""
    rng = np.random.default_rng(7)
    steps = 2.0 ** (-np.arange(20) / 2.0)
    v = rng.standard_normal((8, 256))
    v[1] += 3e9
    v[2] = 7.25
    v[3] = 2.0**40
    v[4] = 2.0**53 + 2 * rng.integers(-3, 4, 256)   # symbols past 2^52 (int64 still holds them)
    v[5, ::2] = 1e4
    v[7] = 60 - 2.0**31 + 10 * rng.standard_normal(256)   # shifting these into their bins passes int32
    for rates in (True, False):
        _check_rows(np.delete(v, 4, axis=0), steps, rates)
        _check_rows(v[[5, 7]], steps, rates)
        _check_rows(v, steps, rates)
    v[6] = 2.0**70                                   # past int64: whatever the reference does, the same
    for rates in (True, False):
        _check_rows_or_raise(v, steps, rates)


def test_threads_and_cpu_count(monkeypatch):
    coeff, basis = _inputs(45, 2100, 1000, seed=8)
    want = _ref_rd_table(coeff, basis, 1e9, subsample=2048)
    for cpus in (1, 3):
        monkeypatch.setattr(ratedist, "cpu_count", lambda: cpus)
        _assert_same(ratedist.rd_table(coeff, basis, 1e9, subsample=2048), want)


def test_other_layouts_and_types():
    """Non-contiguous coefficients, float64 inputs, Fortran-ordered and float32 rows."""
    coeff, basis = _inputs(40, 600, 250, seed=9)
    _check(np.asfortranarray(coeff), basis, None, subsample=300)
    _check(coeff[:, ::2], basis[::2], None, subsample=200)
    _check(coeff.astype(np.float64), basis.astype(np.float64), None, subsample=300)
    rng = np.random.default_rng(9)
    v = rng.standard_normal((7, 333)) * np.logspace(0, -3, 7)[:, None]
    steps = 2.0 ** (-np.arange(25) / 2.0)
    _check_rows(np.asfortranarray(v), steps)
    _check_rows(v.astype(np.float32), steps)
    _check_rows(v, steps.astype(np.float32))
    _check_rows(v[:, ::3], steps[::-1].copy())


def test_non_finite():
    rng = np.random.default_rng(10)
    v = rng.standard_normal((5, 100))
    steps = 2.0 ** (-np.arange(6) / 2.0)
    v[1, 3] = np.inf
    _check_rows_or_raise(v, steps)
    v[3, 9] = np.nan
    _check_rows_or_raise(v, steps)
    _check_rows_or_raise(v, steps, rates=False)
    _check_rows_or_raise(np.ones((2, 5)), np.array([1.0, 0.0]))


def test_einsum_by_slabs():
    """The energies cut into slabs of components are those of one einsum over all of them."""
    for k, n in [(33, 1), (65, 2731), (100, 8193), (40, 16384)]:
        coeff, _ = _inputs(k, n, 4, seed=k + n)
        energy, rows = ratedist._energy_and_rows(coeff, np.arange(0, n, 3), threads=3)
        assert np.array_equal(energy, np.einsum("kpc,kpc->k", coeff, coeff, dtype=np.float64))
        assert np.array_equal(rows, coeff[:, ::3].astype(np.float64).transpose(0, 2, 1).reshape(3 * k, -1))


# ---- values, independently of the reference ----


def test_entropy_values():
    n = 400
    rows = np.stack([np.full(n, 3.0),                       # constant: 0 bits
                     np.tile([0.0, 1.0, 2.0, 3.0], n // 4),  # uniform over 4 levels: 2 bits a symbol
                     np.tile([-5.0, 9.0], n // 2)])          # 2 levels: 1 bit a symbol
    bits, err = ratedist._rate_and_error(rows, np.array([1.0]))
    assert bits[0, 0] == 0 and bits[1, 0] == 2 * n and bits[2, 0] == n
    assert not err.any()                                    # integers at step 1 are exact
    bits, err = ratedist._rate_and_error(rows, np.array([1.0, 0.5]), rates=False)
    assert not bits.any() and not err.any()


def test_error_and_high_rate_values():
    rng = np.random.default_rng(11)
    v = rng.uniform(-1, 1, (2, 4000)) * np.array([[1.0], [1e-3]])
    steps = 0.5 * 2.0 ** (-np.arange(24) / 2.0)
    bits, err = ratedist._rate_and_error(v, steps)
    q = np.rint(v[1] / steps[3]) * steps[3]
    assert err[1, 3] == pytest.approx(((v[1] - q) ** 2).sum(), rel=1e-12)
    # the wide row goes high-rate: error n d^2 / 12 and one bit a symbol per halving
    assert err[0, -1] == pytest.approx(4000 * steps[-1] ** 2 / 12)
    assert bits[0, -1] - bits[0, -3] == pytest.approx(4000.0)
    assert np.all(np.diff(bits, axis=1) >= -1e-9)           # finer steps never need fewer bits


def test_empty():
    """No components: an empty table like the reference's; no texels: the reference's error."""
    coeff, basis = np.zeros((0, 50, 3), np.float32), np.zeros((20, 0), np.float32)
    _check(coeff, basis, 5.0, subsample=16)
    _check(coeff, basis, None, subsample=16, rates=False)
    coeff, basis = _inputs(40, 1, 30)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        for rates in (True, False):
            with pytest.raises(Exception) as want:
                _ref_rd_table(coeff[:, :0], basis, None, rates=rates)
            with pytest.raises(want.type):
                ratedist.rd_table(coeff[:, :0], basis, None, rates=rates)
