"""The dead-zone quantiser of sparse coefficient planes (issue 39): its codes, that rate
control's table models exactly what the product stores, and which runs use it."""
from __future__ import annotations

import numpy as np

from usdbtf.compress import ratedist
from usdbtf.compress.codecs import DEAD_ZONE_OFFSET, quantize_uniform, uniform_codes
from usdbtf.compress.options import CompressOptions


def test_codes_round_sparse_channels_towards_zero_and_dense_ones_to_nearest():
    assert DEAD_ZONE_OFFSET == 0.25
    # channel 0: rint leaves 6 of 10 codes zero (sparse); channel 1: 2 of 10 (dense)
    sparse = [0.1, -0.2, 0.3, 0.0, -0.4, 0.49, 0.74, -0.76, 1.74, -2.5]
    dense = [0.1, -0.2, 3.3, 2.0, -1.4, 0.74, 0.76, -0.76, 1.74, -2.5]
    t = np.array([sparse, dense], np.float64).T.reshape(2, 5, 2)
    q = uniform_codes(t, dead_zone=True).reshape(10, 2)
    # sign(t) floor(|t| + 0.25): 0.74 -> 0, -0.76 -> -1, 1.74 -> 1, -2.5 -> -2
    assert q[:, 0].tolist() == [0, 0, 0, 0, 0, 0, 0, -1, 1, -2]
    assert q[:, 1].tolist() == np.rint(dense).tolist()
    assert np.array_equal(uniform_codes(t, dead_zone=False), np.rint(t))


def test_quantize_uniform_dead_zone_stores_code_times_step_plus_bias():
    rng = np.random.default_rng(3)
    step = 0.5
    values = np.stack([rng.laplace(0, 0.2, (16, 16)), rng.laplace(0, 5.0, (16, 16)), np.zeros((16, 16))],
                      axis=-1).astype(np.float32)
    plain = quantize_uniform(values, step)
    dz = quantize_uniform(values, step, dead_zone=True)
    err = np.abs(dz.values() - values)
    # sparse channel 0: error below (1 - 0.25) step, more zeros than rint; dense channel 1 unchanged
    assert err[..., 0].max() <= 0.75 * step + 1e-6 and err[..., 0].max() > 0.5 * step
    assert np.count_nonzero(dz.values()[..., 0]) < np.count_nonzero(plain.values()[..., 0])
    assert np.array_equal(dz.values()[..., 1], plain.values()[..., 1])
    assert np.array_equal(dz.values()[..., 2], np.zeros((16, 16)))


def test_table_measures_the_stored_codes():
    """rd_table(dead_zone=True) on every texel gives, per component and step, the entropy and
    squared error of what quantize_uniform(dead_zone=True) stores; without the dead zone the
    table's sparse components cost more bytes and less error."""
    rng = np.random.default_rng(5)
    H = W = 24
    scales = [2.0, 0.6, 0.25, 0.1]
    coeff = np.stack([rng.laplace(0, s, (H * W, 3)) for s in scales]).astype(np.float32)   # (k, P, 3)
    basis = np.linalg.qr(rng.standard_normal((40, len(scales))))[0].astype(np.float32)
    table = ratedist.rd_table(coeff, basis, None, subsample=H * W, n_steps=12, dead_zone=True)
    plain = ratedist.rd_table(coeff, basis, None, subsample=H * W, n_steps=12)
    checked = 0
    for j, d in enumerate(table.steps):
        for i in range(len(scales)):
            st = quantize_uniform(coeff[i].reshape(H, W, 3), d, dead_zone=True)
            codes = st.pixels.reshape(-1, 3).astype(np.int64)
            per = []
            for c in range(3):
                p = np.bincount(codes[:, c]) / len(codes)
                p = p[p > 0]
                per.append(-(p * np.log2(p)).sum() * len(codes))
            if max(per) > 5 * len(codes):
                continue                       # near high rate: the table extrapolates (rint's laws)
            bits = sum(per)
            err = float(((st.values().reshape(-1, 3).astype(np.float64) - coeff[i]) ** 2).sum())
            assert np.isclose(table.coeff_bytes[i, j], bits / 8, rtol=1e-9, atol=1e-9), (i, j)
            assert np.isclose(table.coeff_sqerr[i, j], err, rtol=1e-4), (i, j)
            checked += 1
    assert checked >= 30
    # a step where component 3 is sparse: the dead zone saves bytes and costs error
    j = int(np.argmin(np.abs(table.steps - 0.3)))
    assert table.coeff_bytes[3, j] < 0.9 * plain.coeff_bytes[3, j]
    assert table.coeff_sqerr[3, j] > plain.coeff_sqerr[3, j]


def test_only_byte_budgets_of_the_uniform_quantiser_use_the_dead_zone():
    assert CompressOptions(max_bytes=10**6).dead_zone
    assert not CompressOptions(target_error=5.0).dead_zone          # its search needs rint's finer error steps
    assert not CompressOptions(k=8).dead_zone                       # a plain k keeps rint (its bytes unchanged)
    assert not CompressOptions(max_bytes=10**6, codec="exr").dead_zone
    assert not CompressOptions(max_bytes=10**6, solver="paper").dead_zone
