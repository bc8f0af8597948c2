"""Issue 42: the 8-bit code table (``compress.code_table``) against OpenColorIO's encode, the
held-out set's file codes against the files themselves, and the projection's colour mix after
the sums against the mix before them."""
from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest

from usdbtf import color, synth
from usdbtf.compress.code_table import CodeTable, file_code_table
from usdbtf.compress.evaluate import held_out_set
from usdbtf.compress.options import CompressOptions
from usdbtf.compress.projection import TileProjector
from usdbtf.compress.select_source import load_source
from usdbtf.compress.texels import sample_texels
from usdbtf.manifest import encode_for_file, read_manifest, write_manifest
from usdbtf.sampling import preset

SRGB = "sRGB Encoded Rec.709 (sRGB)"
LIN709 = "Linear Rec.709 (sRGB)"


def _sweep(n: int = 3 * 700_001) -> np.ndarray:
    """(n / 3, 3) float32 values densely over [-0.05, 1.1]: every code's edge many times over."""
    return np.linspace(-0.05, 1.1, n, dtype=np.float32).reshape(-1, 3)


def _within_one(got: np.ndarray, want: np.ndarray, share: float) -> None:
    off = got.astype(np.int16) - want.astype(np.int16)
    assert np.abs(off).max() <= 1
    assert np.count_nonzero(off) <= share * off.size, f"{np.count_nonzero(off)} of {off.size} codes differ"


@pytest.mark.parametrize("dst", [SRGB, "Gamma 2.2 Encoded Rec.709", LIN709])
def test_the_table_gives_opencolorio_codes_of_a_per_channel_transform(dst):
    proc = color.processor(LIN709, dst)
    table = CodeTable.build(proc, "uint8")
    assert table is not None and table.unmix is None and table.shared
    x = _sweep()
    want = encode_for_file(x, proc, "uint8")
    assert len(np.unique(want)) == 256                       # the sweep crosses every edge
    # OpenColorIO's float32 curve flickers within a few floats of an edge: one code at most.
    _within_one(table(x), want, 1e-5)
    # Between two edges (a code's middle): exactly OpenColorIO's code.
    steps = np.sort(np.unique(table.step[0][np.isfinite(table.step[0])]))
    middles = np.repeat(((steps[:-1] + steps[1:]) / 2).astype(np.float32)[:, None], 3, axis=1)
    assert np.array_equal(table(middles), encode_for_file(middles, proc, "uint8"))
    # Below zero, zero, far above one (clipped as a file holds them), interleaved rows.
    edge = np.array([[-1.0, 0.0, 1e6], [-0.0, 1.0, 3.0]], np.float32)
    assert np.array_equal(table(edge.reshape(1, -1)).reshape(edge.shape), encode_for_file(edge, proc, "uint8"))


def test_the_table_of_srgb_files_in_the_working_space_goes_through_the_decode_matrix():
    dec = color.integer_decoder(SRGB, 8)
    assert dec.matrix is not None                       # the working space has other primaries
    proc = color.processor(color.WORKING_SPACE, SRGB)
    table = CodeTable.build(proc, "uint8", dec.matrix)
    assert table is not None and table.unmix is not None
    # Colours, not greys: the channels reach the curves mixed.
    rng = np.random.default_rng(3)
    x = (rng.random((400_000, 3), dtype=np.float32) ** 2.2 * 1.05).astype(np.float32)
    _within_one(table(x), encode_for_file(x, proc, "uint8"), 1e-4)
    # The decoded values of every code triple on the diagonal come back as their codes.
    codes = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
    assert np.array_equal(table(dec.decode(codes)), codes)


def test_no_table_where_none_gives_opencolorio_codes():
    proc = color.processor(color.WORKING_SPACE, SRGB)
    assert CodeTable.build(proc, "uint16") is None                  # 65535 edges: no small table
    assert CodeTable.build(proc, "half") is None
    assert CodeTable.build(proc, "uint8") is None                   # its primaries matrix, not given


@pytest.fixture(scope="module")
def tiny_files(tmp_path_factory):
    """24 samples of 32^2 pebbles as 8-bit sRGB PNGs (and the same as half EXRs)."""
    root = tmp_path_factory.mktemp("codes")
    s = preset("tiny")
    imgs = synth.render_all(synth.make_material("pebbles", 32, 0), s)
    png = write_manifest(root / "png", s, imgs, color_space=SRGB, bit_depth="uint8", ext="png", array_space=LIN709)
    exr = write_manifest(root / "exr", s, imgs, color_space=LIN709, bit_depth="half", ext="exr", array_space=LIN709)
    return png, exr


def test_the_held_out_set_keeps_the_files_own_codes(tiny_files):
    btf = read_manifest(tiny_files[0])
    assert file_code_table(btf) is not None
    opts = CompressOptions(k=6)
    texels = sample_texels(btf, opts)
    with load_source(btf, texels, opts) as source:
        held = held_out_set(source, texels)
    assert held.codes is not None and held.codes.dtype == np.uint8
    assert held.codes.shape == held.truth.shape == (btf.n_samples, len(held.texels), 3)
    # The codes are the PNGs' own, read back through OpenImageIO.
    for sample in (0, btf.n_samples // 2, btf.n_samples - 1):
        image = oiio.ImageBuf(str(btf.paths[sample])).get_pixels(oiio.UINT8).reshape(-1, 3)
        assert np.array_equal(held.codes[sample], image[held.texels])
    # The encoded truth from them is what converting the truth back gives.
    from dataclasses import replace

    from usdbtf.compress.domain import LINEAR

    rows = slice(0, btf.n_samples)
    assert np.array_equal(held.truth_block(LINEAR, "encoded", rows),
                          replace(held, codes=None, _codes={}).truth_block(LINEAR, "encoded", rows))


def test_a_float_input_keeps_no_codes(tiny_files):
    btf = read_manifest(tiny_files[1])
    assert file_code_table(btf) is None
    opts = CompressOptions(k=6)
    texels = sample_texels(btf, opts)
    with load_source(btf, texels, opts) as source:
        assert held_out_set(source, texels).codes is None


def test_the_colour_mix_after_the_sums_gives_the_mix_before_them():
    """U^T (X M^T) = (U^T X) M^T per texel: the projector without energy mixes after its sums."""
    rng = np.random.default_rng(5)
    S, n, k = 40, 64, 7
    x = rng.random((S, 3 * n), dtype=np.float32)
    u = np.linalg.qr(rng.standard_normal((S, k)))[0].astype(np.float32)
    mix = np.linalg.qr(rng.standard_normal((3, 3)))[0].astype(np.float32)
    identity = lambda raw, out=None: np.copyto(out, raw) or out
    coeffs = {}
    for energy in (False, True):
        proj = TileProjector(u, mix, (k, k, k), identity, 16, energy=energy)
        assert proj.mix_after is not energy
        accs = proj.zeros(n)
        for s0 in range(0, S, 16):
            proj.accumulate(s0, x[s0:s0 + 16], accs)
        c = accs[0].reshape(k, n, 3)
        coeffs[energy] = color.mix_rgb(c, mix) if proj.mix_after else c
    want = np.einsum("sk,snc,jc->knj", u.astype(np.float64), x.reshape(S, n, 3).astype(np.float64), mix.astype(np.float64))
    for c in coeffs.values():
        assert np.allclose(c, want, rtol=0, atol=1e-5)
