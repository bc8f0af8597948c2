"""The projection's value conversion (issue 17): the same bits as the plain expressions, in
reused buffers, without the slow paths it avoids; the memo per code triple (issue 42):
every texel the bits of its triple's plain conversion, wherever it sits; the spill's
piecewise writes."""
from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from usdbtf import color
from usdbtf.compress import spill as spill_module
from usdbtf.compress import convert as convert_module
from usdbtf.compress.convert import Conversion, Scratch, TripleConversion, TripleSlots
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


def _plain_triples(dec, d: Domain, codes: np.ndarray) -> np.ndarray:
    """(m, 3) uint8 codes -> the memo's values as plain expressions: the table per channel,
    the matrix in float64 (exact products, y_c = (m_c0 x_0 + m_c1 x_1) + m_c2 x_2, one rounding
    to float32), then the plain curve."""
    x = np.stack([dec.lut[c][codes[:, c]] for c in range(3)], axis=1).astype(np.float64)
    m = dec.matrix.astype(np.float64)
    y = np.stack([(m[c, 0] * x[:, 0] + m[c, 1] * x[:, 1]) + m[c, 2] * x[:, 2] for c in range(3)], axis=1)
    return _plain_forward(d, y.astype(np.float32))


def _triple_conversion(d: Domain, **kw) -> tuple:
    dec = color.integer_decoder(SRGB, 8)
    return dec, TripleConversion(dec.decode_curves, dec.matrix, d, nonnegative=True, **kw)


@pytest.mark.parametrize("d", CURVES, ids=lambda d: d.name)
def test_memo_per_code_triple_gives_each_texel_its_triples_plain_value(d, monkeypatch):
    """Every texel gets the bits of its own triple's plain conversion: on strided column
    blocks of a larger array, cut in pieces (a piece of 1,000 texels here, so a row is split
    and the last piece is short), with new triples met call after call (learned between calls
    and inside one), into a reused buffer; and within a few float32 ulps (1e-6 relative) of the
    OpenCV chain it replaces (whose rounding depends on where a texel sits)."""
    monkeypatch.setattr(convert_module, "_PIECE", 1000)
    dec, conv = _triple_conversion(d)
    rng = np.random.default_rng(11)
    data = rng.integers(0, 256, (70, 3 * 900), dtype=np.uint8)
    data[:, :150] = rng.integers(0, 8, (70, 150))                    # dark texels: the sRGB toe, zeros
    data[5:40, 600:1200] = data[0, 600:1200]                         # repeats: most texels found, not learned
    out = np.empty((70, 3 * 300), np.float32)
    for cols in (slice(0, 900), slice(900, 1800), slice(1800, 2700), slice(0, 900)):
        raw = data[:, cols]
        want = _plain_triples(dec, d, np.ascontiguousarray(raw).reshape(-1, 3)).reshape(raw.shape)
        got = conv(raw, out=out)
        assert got is out and np.array_equal(_bits(got), _bits(want))
        old = Conversion(dec.decode_curves, dec.matrix, d, nonnegative=True)(raw)
        np.testing.assert_allclose(got, old, rtol=1e-6, atol=1e-9)
    assert conv.slots.count == len(np.unique(data.reshape(-1, 3), axis=0))
    assert np.array_equal(_bits(conv.triples(data[:9, :30].reshape(-1, 3))),
                          _bits(_plain_triples(dec, d, data[:9, :30].reshape(-1, 3))))


def test_memo_values_do_not_depend_on_position_shape_or_threads():
    """The same texels in another order, another array shape, one (m, 3) list, or converted by
    four threads at once through one fresh memo: the same bits per texel."""
    from concurrent.futures import ThreadPoolExecutor

    d = Domain("srgb")
    rng = np.random.default_rng(12)
    texels = rng.integers(0, 256, (4096, 3), dtype=np.uint8)
    texels[rng.random(4096) < 0.5] = texels[0]
    want = _triple_conversion(d)[1](texels.reshape(64, 3 * 64)).reshape(-1, 3)
    perm = rng.permutation(4096)
    _, conv = _triple_conversion(d)
    assert np.array_equal(_bits(conv(texels[perm].reshape(16, 3 * 256)).reshape(-1, 3)), _bits(want[perm]))
    assert np.array_equal(_bits(conv(texels[perm][:, None, :].reshape(4096, 3))), _bits(want[perm]))
    assert np.array_equal(_bits(conv(texels.reshape(8, 512, 3))), _bits(want.reshape(8, 512, 3)))   # not 2-D
    wide = np.zeros((64, 2 * 3 * 64), np.float32)
    assert conv(texels.reshape(64, 3 * 64), out=wide[:, ::2]) is not None          # a strided out is written
    assert np.array_equal(_bits(wide[:, ::2].reshape(-1, 3)), _bits(want))
    _, fresh = _triple_conversion(d)
    blocks = [texels[a:a + 512].reshape(8, 3 * 64) for a in range(0, 4096, 512)]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(fresh, blocks))
    assert np.array_equal(_bits(np.concatenate(got).reshape(-1, 3)), _bits(want))


def test_memo_beyond_its_capacity_and_shared_between_domains():
    """A memo full after 5 triples converts the others where it meets them (the same bits);
    two domains sharing one numbering of the triples each keep their own values."""
    rng = np.random.default_rng(13)
    raw = rng.integers(0, 256, (12, 3 * 40), dtype=np.uint8)
    slots = TripleSlots(cap=5)
    dec, srgb = _triple_conversion(Domain("srgb"), slots=slots)
    _, power = _triple_conversion(Domain("power", 2.2), slots=slots)
    for conv, d in ((srgb, Domain("srgb")), (power, Domain("power", 2.2)), (srgb, Domain("srgb"))):
        want = _plain_triples(dec, d, raw.reshape(-1, 3)).reshape(raw.shape)
        assert np.array_equal(_bits(conv(raw)), _bits(want))
    assert slots.count == 5


def test_memo_learned_in_a_forked_worker_stays_the_workers():
    """The memo's tables are private maps: triples a forked worker numbers do not appear in
    the parent's table (a shared map would give the parent numbers its own count never made)."""
    _, conv = _triple_conversion(Domain("srgb"))
    conv(np.zeros((1, 3), np.uint8))
    pid = os.fork()
    if pid == 0:                                   # the child: learn 200 more triples, exit
        conv(np.arange(600, dtype=np.uint16).astype(np.uint8).reshape(1, 600))
        os._exit(0)
    os.waitpid(pid, 0)
    assert conv.slots.count == 1 and np.count_nonzero(conv.slots.table) == 1


def test_sources_memoise_8_bit_codes_with_a_matrix_in_a_curved_domain(tmp_path):
    """An 8-bit sRGB input (primaries matrix into ACEScg) converts through the memo in every
    curved domain, with one numbering shared by the candidates; the linear domain keeps the
    table-and-matrix chain (no curve to save); columns, samples and tiles agree texel for texel."""
    from usdbtf import synth
    from usdbtf.compress.source import InMemorySource
    from usdbtf.compress.domain import LINEAR
    from usdbtf.manifest import read_manifest, write_manifest
    from usdbtf.sampling import preset

    s = preset("small")
    imgs = synth.render_all(synth.make_material("metal_flakes", 12, 2), s)
    btf = read_manifest(write_manifest(tmp_path / "m", s, imgs, color_space=SRGB, bit_depth="uint8", ext="png"))
    src = InMemorySource(btf, workers=1)
    convs = [src.curves_in(d) for d in CURVES]
    assert all(isinstance(c, TripleConversion) for c in convs)
    assert len({id(c.slots) for c in convs}) == 1
    assert type(src.curves_in(LINEAR)) is Conversion
    src.set_domain(Domain("srgb"))
    texels = np.array([0, 5, 77, 143])
    cols = src.columns(texels).reshape(btf.n_samples, len(texels), 3)
    samples = src.working_samples(np.arange(btf.n_samples))
    assert np.array_equal(_bits(cols), _bits(samples[:, texels]))
    dec = color.integer_decoder(SRGB, 8)
    want = _plain_triples(dec, Domain("srgb"), src.raw_columns(texels).reshape(-1, 3))
    assert np.array_equal(_bits(cols.reshape(-1, 3)), _bits(want))


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
