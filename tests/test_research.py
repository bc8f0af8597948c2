"""The compression research prototypes (benchmarks/research, issue 16) on a small dataset:
their error measure is the project's (``usdbtf.compress.decompress.compare``), the 8-bit
encoder is exact, and every method runs, stays within its byte budget and predicts held-out
directions the way the benchmark does.  Seconds, not minutes: 169 samples of 16x16.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

RESEARCH = Path(__file__).resolve().parents[1] / "benchmarks" / "research"


@pytest.fixture(scope="module")
def research(tmp_path_factory):
    sys.path.insert(0, str(RESEARCH))
    try:
        import methods
        import rlib
    finally:
        sys.path.remove(str(RESEARCH))
    root = tmp_path_factory.mktemp("research")
    rlib.DATA, rlib.OUT = root / "data", root / "out"      # nothing lands in the repository
    return rlib, methods


@pytest.fixture(scope="module")
def small(research):
    rlib, _ = research
    return rlib.load("pebbles", sampling="small", size=16, say=lambda msg: None)


def _oetf_codes(x):
    x = np.clip(np.asarray(x, np.float64), 0.0, None)
    enc = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.clip(np.floor(enc * 255 + 0.5), 0, 255).astype(np.uint8)


def test_srgb_encoder_is_exact(research):
    from usdbtf import color
    from usdbtf.manifest import encode_for_file

    rlib, _ = research
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.uniform(-0.1, 1.2, 200_000), rng.uniform(0, 0.004, 50_000)]).astype(np.float32)
    edges = rlib.srgb_decode((np.arange(255) + 0.5) / 255).astype(np.float32)     # code boundaries
    x = np.concatenate([x, edges, np.nextafter(edges, 0), np.nextafter(edges, 2), [np.nan, np.inf, -np.inf]])
    got = rlib.srgb_encode(x)
    finite = np.isfinite(x)
    np.testing.assert_array_equal(got[finite], _oetf_codes(x[finite]))
    assert got[np.isnan(x) | (x == -np.inf)].max() == 0 and got[x == np.inf] == 255
    # OCIO's fast curve rounds a few random values differently, never by more than one code
    lin709 = np.repeat(x[:250_000, None], 3, axis=1)
    to_srgb = color.processor("Linear Rec.709 (sRGB)", "sRGB Encoded Rec.709 (sRGB)")
    ocio = encode_for_file(lin709, to_srgb, "uint8")[:, 0]
    diff = np.abs(ocio.astype(int) - got[:250_000].astype(int))
    assert diff.max() <= 1 and (diff > 0).mean() < 1e-3


def test_evaluate_is_usdbtf_compare(research, small):
    from usdbtf.color import mix_rgb
    from usdbtf.compress.decompress import compare
    from usdbtf.io import open_btf

    rlib, _ = research
    rng = np.random.default_rng(1)

    def recon(sel):                 # a distorted copy: darker, offset, noisy (some values negative)
        lin = small.lut[np.asarray(small.codes[sel])]
        return (0.9 * lin + 0.01 + 0.02 * rng.standard_normal(lin.shape)).astype(np.float32)

    rows = np.arange(0, small.S, 3)
    fixed = {int(s): recon(np.array([s]))[0] for s in rows}
    ours = rlib.evaluate(small, lambda sel: np.stack([fixed[int(s)] for s in sel]), rows, chunk=17)
    btf = open_btf(rlib.DATA / "pebbles-small-16-seed0")
    ref = compare(btf, lambda sel: mix_rgb(np.stack([fixed[int(s)] for s in sel]), small.to_aces).reshape(
        len(sel), 16, 16, 3), rows)
    assert ours.linear == pytest.approx(ref["linear"]["percent"], rel=1e-5)
    assert ours.encoded == pytest.approx(ref["encoded"]["percent"], rel=2e-3)
    assert 1.0 < ours.encoded < 50 and 1.0 < ours.linear < 50


@pytest.mark.parametrize("name", ["linear", "gamma1.8", "srgb", "log1e-2"])
def test_domains_invert(research, name):
    rlib, _ = research
    dom = rlib.domain(name)
    # the sRGB domain is the 8-bit file's own: [0, 1] (its inverse clips there, like a display value)
    x = np.linspace(0, 1.0 if name == "srgb" else 1.5, 1001, dtype=np.float32)
    np.testing.assert_allclose(dom.inverse(dom.forward(x)), x, rtol=2e-4, atol=2e-6)
    if name != "linear":        # curves clamp negative reconstructions (linear keeps them, as usdbtf does)
        assert np.all(dom.inverse(np.float32([-0.5])) >= 0)
    table = dom.code_table(np.linspace(0, 1, 256, dtype=np.float32))
    assert table.shape == (256,) and np.all(np.diff(table) > 0)


def test_methods_run_within_budget_and_predict_held_out_directions(research, small):
    from usdbtf.bench.heldout import blend_rows, neighbour_weights, split_lights

    rlib, methods = research
    paper = methods.paper_method(small, k=8, region=8)
    budget = paper.bytes["payload"]
    assert paper.k == 8 and paper.bytes["basis"] > small.S * 8     # uncompressed 8-bit TIFF
    for kw in ({"dom": "linear"}, {"dom": "gamma2", "storage": methods.Storage("planar", 3, 3)}):
        f = methods.factorise(small, budget, k_max=24, n_fit=128, **kw)
        assert 1 <= f.k <= 24 and f.bytes["payload"] <= budget
        e = rlib.evaluate(small, f.recon)
        assert np.isfinite(e.encoded) and e.encoded < 60
    scores = methods.domain_scores(small, ["gamma1.8", "srgb"], k_probe=8, n_fit=64, n_eval=64)
    assert set(scores) == {"gamma1.8", "srgb"} and all(np.isfinite(v).all() for v in scores.values())

    # held-out lights: in the linear domain the predictor is the benchmark's (rows blended with
    # the foreshortening weights), and a stored direction predicts itself
    fit, held = split_lights(small.sampling, 0.2)
    f = methods.factorise(small.subset(fit), budget, dom="linear", k_max=24, n_fit=128)
    fs, hs = small.sampling.subset(fit), small.sampling.subset(held)
    predict = methods.heldout_predictor(f, fs, hs)
    idx, w = neighbour_weights(fs, hs, 4)
    expect = (blend_rows(f.basis, idx, w) @ f.coeff).reshape(len(held), -1, 3)
    np.testing.assert_allclose(predict(np.arange(len(held))), expect, rtol=1e-4, atol=1e-5)
    same = methods.heldout_predictor(f, fs, fs)(np.arange(5))
    np.testing.assert_allclose(same, f.recon(np.arange(5)), rtol=1e-5, atol=1e-6)
