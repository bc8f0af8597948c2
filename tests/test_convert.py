"""The projection's value conversion (issue 17): the same bits as the plain expressions, in
reused buffers, without the slow paths it avoids; the spill's piecewise writes."""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from usdbtf import color
from usdbtf.compress import spill as spill_module
from usdbtf.compress.convert import Conversion, Scratch
from usdbtf.compress.domain import Domain
from usdbtf.compress.spill import Spill

SRGB = "sRGB Encoded Rec.709 (sRGB)"
CURVES = [Domain("power", 1.6), Domain("power", 2.2), Domain("srgb")]


def _pow(x: np.ndarray, e) -> np.ndarray:
    """The curves' power as a plain expression, exp(e log x) in float32 (position-independent
    bits: usdbtf.compress.domain._power)."""
    a = np.ascontiguousarray(x, np.float32)
    with np.errstate(divide="ignore"):
        return np.exp(np.float32(e) * np.log(a))


def _plain_forward(d: Domain, x: np.ndarray) -> np.ndarray:
    """The curve as plain expressions (what Domain.forward computed before issue 17, with
    the power that issue 24 made platform-independent)."""
    x = np.maximum(np.asarray(x, np.float32), np.float32(0))
    if d.curve == "power":
        return _pow(x, np.float32(1 / d.gamma))
    toe = x <= np.float32(0.0031308)
    low = x[toe] * np.float32(12.92)
    x = _pow(x, np.float32(1 / 2.4))
    x *= np.float32(1.055)
    x -= np.float32(0.055)
    x[toe] = low
    return x


def _plain_inverse(d: Domain, v: np.ndarray) -> np.ndarray:
    v = np.maximum(np.asarray(v, np.float32), np.float32(0))
    if d.curve == "power":
        return _pow(v, np.float32(d.gamma))
    toe = v <= np.float32(0.04045)
    low = v[toe] * np.float32(1 / 12.92)
    v = (v + np.float32(0.055)) * np.float32(1 / 1.055)
    v = _pow(v, np.float32(2.4))
    v[toe] = low
    return v


def _bits(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, np.float32).view(np.uint32)


@pytest.fixture(scope="module")
def values() -> np.ndarray:
    """Scene-linear-like values with a third exact zeros, some -0.0 and negatives."""
    rng = np.random.default_rng(3)
    x = (rng.random(200_003, dtype=np.float32) ** 2.2) * 1.5
    x[rng.random(x.size) < 0.33] = 0.0
    x[::97] = -0.0
    x[::101] = -0.25
    return x


@pytest.mark.parametrize("d", CURVES, ids=lambda d: d.name)
def test_curves_are_bit_identical_to_the_plain_expressions_with_zeros(d, values):
    """Zeros go around SVML's slow path (issue 17): the bits, signs of zero included, do not change."""
    assert np.array_equal(_bits(d.forward(values.copy())), _bits(_plain_forward(d, values)))
    assert np.array_equal(_bits(d.inverse(values.copy())), _bits(_plain_inverse(d, values)))
    out = np.empty_like(values)
    assert d.forward(values, out=out) is out and np.array_equal(_bits(out), _bits(_plain_forward(d, values)))
    pos = np.abs(values)
    assert np.array_equal(_bits(d.forward(pos, nonnegative=True)), _bits(_plain_forward(d, pos)))
    assert np.array_equal(pos, np.abs(values)), "forward(nonnegative=True) without out must not write its input"


@pytest.mark.parametrize("d", CURVES, ids=lambda d: d.name)
def test_conversion_matches_the_plain_chain_on_strided_rows_and_reused_buffers(d):
    """8-bit codes through the decode table, the primaries matrix and the curve: the bits of
    the step-by-step expression, on a column block of a larger array (strided rows), and
    again into the same out buffer with other data (nothing left over from the first call)."""
    dec = color.integer_decoder(SRGB, 8)
    assert dec.matrix is not None, "sRGB into the working space mixes primaries"
    rng = np.random.default_rng(5)
    data = rng.integers(0, 256, (96, 3 * 700), dtype=np.uint8)
    data[:, :300] = 0                                              # black texels: zeros in the curve
    conv = Conversion(dec.decode_curves, dec.matrix, d,
                      nonnegative=bool(np.all(dec.lut >= 0) and np.all(dec.matrix >= 0)))
    out = np.empty((96, 3 * 256), np.float32)
    for cols in (slice(0, 768), slice(768, 1536)):
        raw = data[:, cols]
        want = _plain_forward(d, color.mix_rgb(dec.decode_curves(raw), dec.matrix))
        got = conv(raw, out=out)
        assert got is out
        assert np.array_equal(_bits(got), _bits(want))
        assert np.array_equal(_bits(conv(raw)), _bits(want))


@pytest.mark.parametrize("d", CURVES, ids=lambda d: d.name)
def test_a_decode_without_matrix_fuses_into_one_table(d):
    """Without a primaries matrix the code -> domain value map is one table per channel
    (what the sources build, :meth:`usdbtf.compress.source._Source.curves_in`): its values
    are those of decoding first and applying the curve after."""
    dec = dataclasses.replace(color.integer_decoder(SRGB, 8), matrix=None)
    fused = dataclasses.replace(dec, lut=d.forward(dec.lut))
    raw = np.random.default_rng(7).integers(0, 256, (64, 3 * 333), dtype=np.uint8)
    assert np.array_equal(_bits(Conversion(fused.decode_curves)(raw)), _bits(d.forward(dec.decode_curves(raw))))


def test_scratch_is_per_thread_and_grows():
    from concurrent.futures import ThreadPoolExecutor

    scratch = Scratch()
    a = scratch.get("x", (4, 6))
    b = scratch.get("x", (2, 3))
    assert np.shares_memory(a, b) and b.shape == (2, 3)
    c = scratch.get("x", (10, 10))
    assert c.shape == (10, 10) and c.dtype == np.float32
    with ThreadPoolExecutor(1) as pool:
        other = pool.submit(scratch.get, "x", (10, 10)).result()
    assert not np.shares_memory(c, other)


def test_spill_writes_slots_through_a_small_staging_buffer(monkeypatch, tmp_path):
    """A slot larger than the staging buffer is written piece by piece (aligned offsets, a
    short last piece) and reads back byte for byte, next to its neighbours."""
    monkeypatch.setattr(spill_module, "STAGING_BYTES", 2 * spill_module.ALIGN)
    monkeypatch.setitem(spill_module._STAGING, os.getpid(), None)
    slot_bytes = 5 * spill_module.ALIGN + 123
    spill = Spill.create(3, slot_bytes, folder=str(tmp_path))
    if spill is None:
        pytest.skip("no room for a spill file here")
    try:
        rng = np.random.default_rng(9)
        slots = [rng.integers(0, 256, slot_bytes - d, dtype=np.uint8) for d in (0, 7, 4096)]
        for n in (2, 0, 1):
            spill.write(n, slots[n])
        got = [raw.copy() for _, raw in spill.read_ahead([(n, len(s)) for n, s in enumerate(slots)])]
        assert all(np.array_equal(g, s) for g, s in zip(got, slots))
    finally:
        spill.close()


def test_read_encoded_into_a_given_array(tmp_path):
    """FileBTF.read_encoded(out=) fills the caller's array (real PNG files through OIIO) with
    what a plain read returns: the streaming first pass reuses one such array per worker."""
    from usdbtf import synth
    from usdbtf.manifest import read_manifest, write_manifest
    from usdbtf.sampling import preset

    s = preset("small")
    imgs = synth.render_all(synth.make_material("pebbles", 12, 2), s)
    btf = read_manifest(write_manifest(tmp_path / "m", s, imgs, color_space=SRGB, bit_depth="uint8", ext="png"))
    want = btf.read_encoded(slice(3, 11))
    out = np.full((8, btf.height, btf.width, 3), 7, np.uint8)
    got = btf.read_encoded(slice(3, 11), out=out)
    assert got is out and np.array_equal(out, want) and want.dtype == np.uint8 and want.any()
