"""Issue 43: under a byte budget a coefficient channel a little over 8 bits at the step is stored
at a coarser step of its own that fits 8 bits (one 16-bit layer makes its level's pages float32
OpenEXR in the asset); how far, and which runs do it."""
from __future__ import annotations

import numpy as np

from usdbtf.compress.codecs import quantize_uniform
from usdbtf.compress.options import EIGHT_BIT_STEP_FACTOR, CompressOptions


def _values(spans, step, seed=7):
    """(32, 32, C) float32 whose channel c spans about spans[c] steps (Laplacian inside)."""
    rng = np.random.default_rng(seed)
    chans = []
    for span in spans:
        half = span * step / 2.0
        v = np.clip(rng.laplace(0.0, span * step / 12.0, 32 * 32), -half, half)
        v[0], v[1] = -half, half                                   # the span itself
        chans.append(v.reshape(32, 32))
    return np.stack(chans, axis=-1).astype(np.float32)


def test_a_channel_just_over_8_bits_fits_at_a_slightly_coarser_step_of_its_own():
    step = 0.01
    values = _values([263.0, 40.0, 0.0], step)
    plain = quantize_uniform(values, step)
    fitted = quantize_uniform(values, step, eight_bit_factor=EIGHT_BIT_STEP_FACTOR)
    assert plain.pixels.dtype == np.uint16 and int(plain.pixels[..., 0].max()) == 264     # rint(+-131.5)
    assert fitted.pixels.dtype == np.uint8 and int(fitted.pixels[..., 0].max()) <= 255
    # channel 0's own step: the smallest of the (1 + 1/256)^n growths of 264/255 that fits
    assert 264 / 255 * step <= fitted.scale[0] <= 264 / 255 * step * (1 + 1 / 256) ** 3
    # its values within half its own step; the other channels stored exactly as before
    err = np.abs(fitted.values() - values)
    assert err[..., 0].max() <= fitted.scale[0] / 2 + 1e-6
    assert fitted.scale[1] == step and fitted.scale[2] == step
    assert np.array_equal(fitted.values()[..., 1:], plain.values()[..., 1:])


def test_channels_far_over_8_bits_stay_16_bit_and_8_bit_ones_are_unchanged():
    step = 0.01
    far = _values([600.0, 10.0, 0.0], step)                      # 600 > 255 * 2: not fitted
    st = quantize_uniform(far, step, eight_bit_factor=EIGHT_BIT_STEP_FACTOR)
    assert st.pixels.dtype == np.uint16 and np.all(st.scale == step)
    assert np.array_equal(st.pixels, quantize_uniform(far, step).pixels)
    small = _values([200.0, 10.0, 3.0], step)
    a, b = quantize_uniform(small, step), quantize_uniform(small, step, eight_bit_factor=EIGHT_BIT_STEP_FACTOR)
    assert a.pixels.dtype == b.pixels.dtype == np.uint8
    assert np.array_equal(a.pixels, b.pixels) and np.array_equal(a.scale, b.scale) and np.array_equal(a.bias, b.bias)


def test_with_the_dead_zone_the_fitted_channel_keeps_its_rounding():
    step = 0.01
    values = _values([300.0, 5.0, 0.0], step)
    st = quantize_uniform(values, step, dead_zone=True, eight_bit_factor=EIGHT_BIT_STEP_FACTOR)
    assert st.pixels.dtype == np.uint8
    # dense channel 0 keeps round-to-nearest at its own step
    assert np.abs(st.values()[..., 0] - values[..., 0]).max() <= st.scale[0] / 2 + 1e-6


def test_only_byte_budgets_fit_channels_to_8_bits():
    assert CompressOptions(max_bytes=10**6).eight_bit_factor == EIGHT_BIT_STEP_FACTOR == 2.0
    assert CompressOptions(target_error=5.0).eight_bit_factor == 1.0
    assert CompressOptions(k=16).eight_bit_factor == 1.0
    assert CompressOptions(max_bytes=10**6, codec="exr").eight_bit_factor == 1.0          # halves
