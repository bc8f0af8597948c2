"""Tests for usdbtf.compress: basis fitting, both solvers, the stored format, codecs,
decompression, error metrics, rate control and failure handling.

Inputs are real files (PNG / EXR manifests written through OpenImageIO) except where
an in-memory ArrayBTF is the point (exact-rank data).  Sizes are kept tiny: the whole
module runs in well under a minute on two cores.
"""
from __future__ import annotations

import csv
import json
import os
import tempfile
import warnings
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from usdbtf import synth
from usdbtf.compress import CompressOptions, compress, read_compressed, reconstruct, write_compress
from usdbtf.compress.curve import curve_samples
from usdbtf.compress.decompress import compare, decompress_to_folder, parse_samples
from usdbtf.compress.format import METADATA, truncate
from usdbtf.compress.linalg import exact_basis, fix_signs, randomized_basis
from usdbtf.compress.metrics import ErrorSums
from usdbtf.errors import BTFError, OutputRefused
from usdbtf.manifest import encode_for_file, read_manifest, write_manifest
from usdbtf import color
from usdbtf.model import ArrayBTF
from usdbtf.sampling import preset

from compress_helpers import compress_into

SRGB = "sRGB Encoded Rec.709 (sRGB)"
LIN709 = "Linear Rec.709 (sRGB)"

# ---------------------------------------------------------------- helpers / data


def synth_manifest(folder: Path, sampling: str, size: int, *, material="pebbles", seed=0,
                   bit_depth="uint8", ext="png", space=SRGB) -> Path:
    """A synthetic material written as a manifest of real image files."""
    s = preset(sampling)
    imgs = synth.render_all(synth.make_material(material, size, seed), s)
    return write_manifest(folder, s, imgs, color_space=space, bit_depth=bit_depth, ext=ext, array_space=LIN709)


def rank_r_images(r: int, n_samples: int, size: int, seed: int = 0, noise: float = 0.0) -> np.ndarray:
    """(S, size, size, 3) nonnegative float32 data = sum of r outer products (+ optional noise)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.1, 1.0, (n_samples, r))
    b = rng.uniform(0.0, 1.0, (r, size * size * 3)) / r
    data = a @ b
    if noise:
        data += noise * rng.uniform(0.0, 1.0, data.shape)
    return data.reshape(n_samples, size, size, 3).astype(np.float32)


def full_percent(btf, cbtf) -> float:
    """Paper's percent error over every sample and texel (scene-linear)."""
    return compare(btf, lambda sel: reconstruct(cbtf, sel))["linear"]["percent"]


def folder_files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def image_spec(path: Path):
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, f"{path}: {oiio.geterror()}"
    spec = inp.spec()
    inp.close()
    return spec


def no_leftovers(parent: Path, name: str) -> bool:
    return not any(p.name.startswith(f".{name}.") for p in parent.iterdir()) if parent.exists() else True


@pytest.fixture(scope="module")
def data_root(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("data")


@pytest.fixture(scope="module")
def small32(data_root) -> Path:
    """169 samples (small sampling) of 32x32 pebbles, 8-bit sRGB PNG."""
    return synth_manifest(data_root / "small32", "small", 32)


@pytest.fixture(scope="module")
def tiny32(data_root) -> Path:
    """24 samples (tiny sampling) of 32x32 pebbles, 8-bit sRGB PNG."""
    return synth_manifest(data_root / "tiny32", "tiny", 32)


@pytest.fixture(scope="module")
def tiny64(data_root) -> Path:
    """24 samples of 64x64 (more texels than the fit sample: held-out texels exist)."""
    return synth_manifest(data_root / "tiny64", "tiny", 64, material="ridged_fabric")


@pytest.fixture(scope="module")
def paper_small32(small32, tmp_path_factory):
    out = tmp_path_factory.mktemp("paper") / "paper_k16"
    btf = read_manifest(small32)
    return btf, compress_into(btf, out, CompressOptions(solver="paper", k=16)), out


# ---------------------------------------------------------------- linear algebra


def _known_svd(S, m, sv, seed=0):
    rng = np.random.default_rng(seed)
    u, _ = np.linalg.qr(rng.standard_normal((S, len(sv))))
    v, _ = np.linalg.qr(rng.standard_normal((m, len(sv))))
    return u, np.asarray(sv, float), v, (u * sv) @ v.T


def _check_basis(u_est, u_true, k):
    assert u_est.dtype == np.float32
    # Orthonormal columns.
    np.testing.assert_allclose(u_est.T.astype(np.float64) @ u_est, np.eye(u_est.shape[1]), atol=2e-5)
    # Spans the true top-k subspace: cosines of the principal angles are all ~1.
    cos = np.linalg.svd(u_true[:, :k].T @ u_est.astype(np.float64), compute_uv=False)
    assert cos.min() > 1 - 1e-5, cos
    # Each column is +-(the true singular vector), sign per fix_signs: largest |entry| positive.
    for i in range(u_est.shape[1]):
        col = u_est[:, i]
        assert col[np.argmax(np.abs(col))] > 0
        assert abs(abs(float(col @ u_true[:, i])) - 1) < 1e-4


@pytest.mark.parametrize("S,m", [(40, 300), (60, 25)], ids=["wide-gram-SxS", "tall-gram-mxm"])
def test_exact_basis_recovers_singular_values_and_vectors(S, m):
    sv = 10.0 * 0.6 ** np.arange(12)
    u_true, s, _, x = _known_svd(S, m, sv)
    u, got = exact_basis(x.astype(np.float32), 6)
    assert u.shape == (S, 6) and got.shape == (6,)
    np.testing.assert_allclose(got, s[:6], rtol=1e-5)
    _check_basis(u, u_true, 6)


@pytest.mark.parametrize("S,m", [(30, 200), (60, 25)])
def test_exact_basis_rank_deficient_input(S, m):
    """k above the rank: the first r vectors are the true ones, the rest are finite,
    orthonormal, with ~0 singular values (or dropped)."""
    u_true, s, _, x = _known_svd(S, m, [5.0, 2.0, 1.0])
    u, got = exact_basis(x, 10)
    assert 3 <= u.shape[1] == len(got) <= 10
    assert np.isfinite(u).all() and np.isfinite(got).all()
    np.testing.assert_allclose(got[:3], s, rtol=1e-7)
    assert (got[3:] < 1e-6 * s[0]).all()
    np.testing.assert_allclose(u.T.astype(np.float64) @ u, np.eye(u.shape[1]), atol=2e-5)
    cos = np.linalg.svd(u_true.T @ u[:, :3].astype(np.float64), compute_uv=False)
    assert cos.min() > 1 - 1e-5


@pytest.mark.parametrize("power", [1, 2])
def test_randomized_basis_fast_decaying_spectrum(power):
    sv = 100.0 * 0.25 ** np.arange(20)        # fast decay: top-8 resolved to 1e-3 with a few power passes
    u_true, s, _, x = _known_svd(80, 500, sv, seed=3)
    u, got = randomized_basis(x.astype(np.float32), 8, oversample=8, power_iterations=power, seed=1)
    assert u.shape == (80, 8) and got.shape == (8,)
    np.testing.assert_allclose(got, s[:8], rtol=1e-3)
    _check_basis(u, u_true, 8)


def test_randomized_basis_deterministic_per_seed():
    *_, x = _known_svd(50, 120, 3.0 * 0.5 ** np.arange(30), seed=5)
    x = x.astype(np.float32)
    a = randomized_basis(x, 5, seed=7)
    b = randomized_basis(x, 5, seed=7)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_q_times_applies_householder_q_or_falls_back_for_rank_deficient_data():
    """randomized_basis applies the final Q as Y (R^-1 w) (no Q formed): the same product as
    Householder's Q to float64 rounding where R is well conditioned; for a rank-deficient Y
    (R's diagonal spans more than _R_INVERSE_RANGE) Householder's Q itself."""
    from usdbtf.compress import linalg

    rng = np.random.default_rng(4)
    w = rng.standard_normal((40, 7))
    y = rng.standard_normal((300, 40)) * np.logspace(0, -4, 40)        # condition ~1e4
    q, r = np.linalg.qr(y)
    np.testing.assert_allclose(linalg._q_times(y, np.linalg.qr(y, mode="r"), w), q @ w, atol=1e-11)
    deficient = np.concatenate([y[:, :20], y[:, :20] @ rng.standard_normal((20, 20))], axis=1)
    q, r = np.linalg.qr(deficient)
    assert np.abs(np.diag(r)).min() < np.abs(np.diag(r)).max() / linalg._R_INVERSE_RANGE
    got = linalg._q_times(deficient, np.linalg.qr(deficient, mode="r"), w)
    assert np.isfinite(got).all() and np.array_equal(got, linalg.rows_gemm(q, w))


def test_randomized_basis_of_rank_deficient_data_is_orthonormal_and_finite():
    """Fewer nonzero singular values than vectors asked for (the range finder's R singular):
    the basis stays finite and orthonormal, with the true singular values first."""
    u_true, s, _, x = _known_svd(200, 300, [9.0, 4.0, 1.0], seed=6)
    u, got = randomized_basis(x.astype(np.float32), 10, oversample=6, seed=2)
    assert np.isfinite(u).all() and np.isfinite(got).all()
    np.testing.assert_allclose(got[:3], s, rtol=1e-4)
    np.testing.assert_allclose(u.T.astype(np.float64) @ u, np.eye(u.shape[1]), atol=1e-4)


def test_fix_signs_convention():
    u = np.array([[0.1, -3.0, 0.0, 2.0],
                  [-0.9, 1.0, 0.0, -2.0],
                  [0.5, 2.0, 0.0, 1.0]])
    signs = fix_signs(u)
    np.testing.assert_array_equal(signs, [-1, -1, 1, 1])         # tie in column 3: first entry decides
    np.testing.assert_array_equal(u[:, 0], [-0.1, 0.9, -0.5])
    np.testing.assert_array_equal(u[:, 1], [3.0, -1.0, -2.0])
    np.testing.assert_array_equal(u[:, 2], [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(u[:, 3], [2.0, -2.0, 1.0])


# ---------------------------------------------------------------- metrics / compare / parse_samples


def test_error_sums_formula_over_chunks():
    rng = np.random.default_rng(0)
    o = rng.uniform(0, 1, (5, 7, 3))
    r = o + rng.normal(0, 0.05, o.shape)
    sums = ErrorSums()
    sums.add(o[:2], r[:2])
    sums.add(o[2:], r[2:])
    assert sums.percent == pytest.approx(100 * np.abs(o - r).sum() / o.sum(), rel=1e-12)
    rmse = np.sqrt(np.mean((o - r) ** 2))
    assert sums.rmse == pytest.approx(rmse, rel=1e-12)
    assert sums.psnr() == pytest.approx(20 * np.log10(1 / rmse), rel=1e-12)
    assert ErrorSums().report()["percent"] is None        # undefined when empty: JSON null, not NaN
    assert np.isnan(ErrorSums().percent)


def test_compare_percent_formula_on_scaled_reconstruction():
    s = preset("tiny")
    data = rank_r_images(4, len(s), 8, seed=2)
    btf = ArrayBTF.from_linear(s, data)
    rep = compare(btf, lambda sel: 0.9 * data[sel], chunk=5)
    assert rep["samples"] == 24
    assert rep["linear"]["percent"] == pytest.approx(10.0, rel=1e-6)
    assert rep["linear"]["rmse"] == pytest.approx(0.1 * np.sqrt(np.mean(data.astype(np.float64) ** 2)), rel=1e-5)
    # Float source in the working space: the "encoded" domain is the same numbers.
    assert rep["encoded"]["percent"] == pytest.approx(10.0, rel=1e-6)
    sub = compare(btf, lambda sel: 0.5 * data[sel], indices=[3, 7])
    assert sub["samples"] == 2 and sub["linear"]["percent"] == pytest.approx(50.0, rel=1e-6)


def test_compare_on_8bit_source_encoded_domain(tiny32):
    btf = read_manifest(tiny32)
    exact = compare(btf, lambda sel: btf.read_samples(sel))
    assert exact["linear"]["percent"] == 0.0 and exact["encoded"]["percent"] == 0.0
    # A reconstruction off by exactly one code value in every stored channel (where it can be).
    codes = btf.read_encoded(np.arange(btf.n_samples)).astype(np.int32)
    bumped = np.where(codes < 255, codes + 1, codes - 1).astype(np.uint8)
    rep = compare(btf, lambda sel: btf.decode(bumped[sel]))
    assert rep["encoded"]["rmse"] == pytest.approx(1 / 255, rel=1e-6)
    assert rep["encoded"]["percent"] == pytest.approx(100 * codes.size / codes.sum(), rel=1e-6)


def test_parse_samples():
    assert parse_samples(None, 5).tolist() == [0, 1, 2, 3, 4]
    assert parse_samples("all", 3).tolist() == [0, 1, 2]
    assert parse_samples("0-3,7", 10).tolist() == [0, 1, 2, 3, 7]
    assert parse_samples("8-, 2,2", 10).tolist() == [2, 8, 9]
    for bad in ("x", "10", "3-12", "1.5"):
        with pytest.raises(BTFError, match="--samples"):
            parse_samples(bad, 10)


# ---------------------------------------------------------------- round trips at full rank


@pytest.fixture(scope="module")
def rank4_exr(data_root):
    """Exact rank-4 data written as float EXR (a real file, linear Rec.709)."""
    s = preset("tiny")
    data = rank_r_images(4, len(s), 16, seed=11)
    folder = write_manifest(data_root / "rank4", s, data, color_space=LIN709, bit_depth="float", ext="exr",
                            array_space=LIN709)
    return read_manifest(folder)


@pytest.mark.parametrize("k", [4, 7])
def test_full_rank_exr_codec_is_half_precision(rank4_exr, tmp_path, k):
    btf = rank4_exr
    c = compress_into(btf, tmp_path / "c", CompressOptions(k=k, codec="exr"))
    # k beyond the numerical rank (4) keeps only the vectors that carry signal.
    assert c.k == min(k, 4)
    rec = reconstruct(read_compressed(tmp_path / "c"))
    truth = btf.read_samples(slice(None))
    assert np.isfinite(rec).all()
    # Half floats carry 11 significant bits (~5e-4 relative): errors stay at that level.
    assert np.abs(rec - truth).max() <= 2e-3 * truth.max()
    assert full_percent(btf, c) < 0.1


def test_rank_r_plus_noise_jxl_with_k_r_is_accurate(tmp_path):
    s = preset("tiny")
    data = rank_r_images(5, len(s), 16, seed=4, noise=1e-3)
    btf = ArrayBTF.from_linear(s, data)
    c = compress_into(btf, tmp_path / "c", CompressOptions(k=5))
    assert c.k == 5 and c.codec == "jxlp"
    r = read_compressed(tmp_path / "c")
    assert full_percent(btf, r) < 1.0


def test_exact_rank_jxl_with_k_equal_rank(tmp_path):
    s = preset("tiny")
    for r in range(1, 9):
        data = rank_r_images(r, len(s), 16, seed=r)
        btf = ArrayBTF.from_linear(s, data)
        c = compress_into(btf, tmp_path / f"c{r}", CompressOptions(k=r))
        assert full_percent(btf, read_compressed(tmp_path / f"c{r}")) < 1.0


def test_default_options_on_tiny_sampling(tiny32, tmp_path):
    s = preset("tiny")
    inputs = [read_manifest(tiny32)] + [ArrayBTF.from_linear(s, synth.render_all(synth.make_material(m, 24, 0), s))
                                        for m in ("pebbles", "ridged_fabric", "fuzzy_moss")]
    for n, btf in enumerate(inputs):
        c = compress_into(btf, tmp_path / f"c{n}", CompressOptions())
        assert c.k == 24
        assert full_percent(btf, read_compressed(tmp_path / f"c{n}")) < 1.0


# ---------------------------------------------------------------- the paper solver


def test_paper_solver_folder_layout_and_bit_exact_read(small32, tmp_path):
    btf = read_manifest(small32)
    out = tmp_path / "paper"
    c = compress_into(btf, out, CompressOptions(solver="paper", k=8))
    assert c.k == 8 and c.codec == "jpeg"
    doc = json.loads((out / METADATA).read_text())
    assert doc["solver"] == "paper" and doc["k"] == 8 and doc["codec"] == "jpeg"
    assert doc["basis"]["file"] == "basis.tif"
    assert [e["file"] for e in doc["coefficients"]] == [f"coeff/c{i:03d}.jpg" for i in range(8)]
    assert sorted(p.name for p in (out / "coeff").iterdir()) == [f"c{i:03d}.jpg" for i in range(8)]
    spec = image_spec(out / "basis.tif")
    assert (spec.width, spec.height, spec.nchannels, str(spec.format)) == (8, 169, 1, "uint8")
    assert spec.get_string_attribute("compression") == "none"
    cspec = image_spec(out / "coeff" / "c000.jpg")
    assert (cspec.width, cspec.height, cspec.nchannels, str(cspec.format)) == (32, 32, 3, "uint8")
    assert cspec.get_string_attribute("jpeg:subsampling") == "4:4:4"
    # Shared R, G, B basis: identity colour matrix; min-max scaling: codes span 0..255.
    np.testing.assert_array_equal(c.color_matrix, np.eye(3))
    assert c.basis.pixels.min() == 0 and c.basis.pixels.max() == 255
    r = read_compressed(out)
    assert np.array_equal(reconstruct(r), reconstruct(c))
    # The in-memory result is what was read back from the lossy JPEGs.
    for a, b in zip(r.coefficients, c.coefficients):
        assert np.array_equal(a.pixels, b.pixels)
    pct = full_percent(btf, r)
    assert 1.0 < pct < 25.0
    # More basis vectors: lower error (paper's Fig. 3 behaviour).
    assert full_percent(btf, r) < compare(btf, lambda sel: reconstruct(r, sel, k=2))["linear"]["percent"]


def test_paper_solver_fits_only_the_central_region(tmp_path):
    """The paper fits on a central square; data outside it lies in another subspace and is lost."""
    s = preset("tiny")
    rng = np.random.default_rng(0)
    n = 16
    inner = rng.uniform(0.2, 1, (len(s), 1, 1, 1)) * np.ones((1, n, n, 3))
    outer = rng.uniform(0.2, 1, (len(s), 1, 1, 1)) * np.ones((1, n, n, 3))
    mask = np.zeros((n, n, 1), bool)
    mask[4:12, 4:12] = True
    data = np.where(mask, inner, outer).astype(np.float32)
    btf = ArrayBTF.from_linear(s, data)
    c = compress_into(btf, tmp_path / "p", CompressOptions(solver="paper", k=1, codec="png", region=8))
    rec = reconstruct(c)
    assert np.abs(rec[:, 4:12, 4:12] - data[:, 4:12, 4:12]).max() < 0.01 * data.max()
    assert np.abs(rec[:, :4] - data[:, :4]).mean() > 0.05
    # rsvd samples texels everywhere: rank 2 is exact.
    c2 = compress_into(btf, tmp_path / "r", CompressOptions(k=2, codec="exr"))
    assert np.abs(reconstruct(c2) - data).max() < 2e-3


def test_default_solver_beats_paper_at_equal_bytes(paper_small32, tmp_path):
    btf, paper, paper_out = paper_small32
    budget = paper.info["bytes"]["payload"]
    # Budgets at and just below the paper's bytes: the first one the rate control meets is used
    # (it misses some budgets, see test_max_bytes_rate_control_never_stalls).
    for fraction in (1.0, 0.985, 0.97, 0.95, 0.93):
        try:
            rs = compress_into(btf, tmp_path / "rs", CompressOptions(max_bytes=int(budget * fraction)))
            break
        except BTFError as exc:
            assert "--max-bytes" in str(exc)
    else:
        pytest.fail("rsvd met none of the budgets near the paper's size")
    assert rs.info["bytes"]["payload"] <= budget
    assert rs.info["bytes"]["payload"] > 0.8 * budget
    e_paper = full_percent(btf, read_compressed(paper_out))
    e_rsvd = full_percent(btf, read_compressed(tmp_path / "rs"))
    assert e_rsvd < 0.8 * e_paper, (e_rsvd, e_paper)


def test_max_bytes_rate_control_never_stalls(tiny32, tmp_path):
    """Every reachable budget is met (an earlier rate control repeated the same over-budget
    (k, step) and gave up on ~20 % of budgets with 'cannot meet --max-bytes')."""
    btf = read_manifest(tiny32)
    failed = []
    for budget in (4500, 5500, 7000, 12500, 16000, 17500, 19000):
        try:
            c = compress_into(btf, tmp_path / "c", CompressOptions(max_bytes=budget))
            assert c.info["bytes"]["payload"] <= budget
        except BTFError as exc:
            failed.append((budget, str(exc)))
    assert not failed


def test_paper_max_bytes_and_target_error(paper_small32, tmp_path):
    btf, paper16, _ = paper_small32
    per = paper16.info["bytes"]
    budget = int(per["payload"] * 0.5)
    c = compress_into(btf, tmp_path / "mb", CompressOptions(solver="paper", k=16, max_bytes=budget))
    assert c.k < 16 and c.info["bytes"]["payload"] <= budget
    assert len(list((tmp_path / "mb" / "coeff").iterdir())) == c.k
    # Target: the paper's error at k = 16 (held-out estimate) is reachable with k <= 16.
    est16 = paper16.info["estimated_error"]["linear"]["percent"]
    t = compress_into(btf, tmp_path / "te", CompressOptions(solver="paper", k=16, target_error=est16 * 1.05,
                                                            error_domain="linear"))
    assert t.k <= 16
    assert t.info["estimated_error"]["linear"]["percent"] <= est16 * 1.05
    assert full_percent(btf, t) <= est16 * 1.05 * 1.1


# ---------------------------------------------------------------- rate control (default solver)


def test_max_bytes_respected(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    errs = []
    for budget in (4000, 12000):
        c = compress_into(btf, tmp_path / f"b{budget}", CompressOptions(max_bytes=budget))
        pay = c.info["bytes"]["payload"]
        assert pay <= budget
        assert pay > 0.6 * budget, "budget mostly unused"
        files = sum(p.stat().st_size for p in (tmp_path / f"b{budget}").rglob("*")
                    if p.suffix == ".jxl")
        assert files == pay
        errs.append(full_percent(btf, c))
    assert errs[1] < errs[0]


def test_budget_projects_what_the_model_can_choose_and_records_its_prediction(tiny32, tmp_path):
    """Issue 27: under --max-bytes the sampled model bounds the projection (fewer components
    per colour plane than fitted), the choice stays inside it, and the model's prediction is recorded against
    the verification encode's real bytes."""
    btf = read_manifest(tiny32)
    c = compress_into(btf, tmp_path / "b", CompressOptions(max_bytes=6000))
    choice = c.info["choice"]
    fitted = len(c.info["singular_values"])
    # (few samples here: the first plane keeps every fitted vector, the others fewer)
    assert sum(choice["planes"]) < 3 * fitted and c.k <= max(choice["planes"])
    model = choice["model"]
    measured = model["measured_bytes"]
    assert measured >= c.info["bytes"]["payload"]         # before any trim
    assert model["bytes_error"] == pytest.approx(measured / model["predicted_bytes"] - 1)
    assert abs(model["bytes_error"]) < 0.25


def test_budget_probes_parts_and_encodes_the_basis_once(tiny32, tmp_path, monkeypatch, caplog):
    """Issue 27: under --max-bytes the probes quantise only the components they encode, with
    the integers a quantisation of all k gives them; the coefficient textures are encoded
    once and the basis once for the k their measured bytes leave room for (and once more per
    refill or trim); those bytes are the ones encoding everything at k and truncating gives."""
    import importlib
    import logging

    from usdbtf.compress import ratecontrol
    from usdbtf.compress.encode import encode, encode_coefficients, encode_first, truncate_encoded
    from usdbtf.compress.quantise import quantise

    encode_module = importlib.import_module("usdbtf.compress.encode")   # the package's `encode` is the function
    seen, basis_encodes = {}, []
    probe, encode_basis = ratecontrol._basis_factor, encode_module.encode_basis

    def spied_probe(table, f, k, step, options):
        seen.update(f=f, k=k, step=step, options=options)
        return probe(table, f, k, step, options)

    def counted(cbtf):
        basis_encodes.append(cbtf.k)
        return encode_basis(cbtf)

    monkeypatch.setattr(ratecontrol, "_basis_factor", spied_probe)
    monkeypatch.setattr(encode_module, "encode_basis", counted)
    btf = read_manifest(tiny32)
    with caplog.at_level(logging.INFO, logger="usdbtf.compress"):
        c = compress_into(btf, tmp_path / "b", CompressOptions(max_bytes=9000))
    assert c.info["bytes"]["payload"] <= 9000
    assert len(basis_encodes) == 1 + caplog.text.count("room for k =") + caplog.text.count("trimmed to k")
    assert basis_encodes[-1] == c.k

    f, k, step, options = seen["f"], seen["k"], seen["step"], seen["options"]
    assert k >= 4
    whole = quantise(f, k, step, options)
    idx = np.arange(1, k, 2)
    part = quantise(ratecontrol._part(f, idx), len(idx), step, options)
    for i, st in zip(idx, part.coefficients):
        assert np.array_equal(st.pixels, whole.coefficients[i].pixels)
        assert np.array_equal(st.bias, whole.coefficients[i].bias) and np.array_equal(st.scale, whole.coefficients[i].scale)
    def basis_values(stored):                            # (S, k): code * scale + bias per column
        return stored.pixels[:, :, 0].astype(np.float64) * stored.scale + stored.bias

    assert np.array_equal(basis_values(part.basis), basis_values(whole.basis)[:, idx])

    coefficient_bytes = encode_coefficients(whole)
    everything = encode(whole)
    assert coefficient_bytes == everything.encoded.coefficients
    first = encode_first(whole, k - 2, coefficient_bytes)
    assert first.encoded.basis == truncate_encoded(everything, k - 2).encoded.basis
    assert first.info["bytes"]["payload"] == len(first.encoded.basis) + sum(map(len, coefficient_bytes[:k - 2]))


def test_room_for_keeps_what_the_measured_textures_and_the_modelled_basis_fit():
    """The k a budget keeps once the coefficient textures are encoded: their measured bytes plus
    the modelled basis of that many components and its 1 % margin."""
    from usdbtf.compress.ratecontrol import _room_for

    coefficient_bytes = [b"x" * 100] * 5
    basis = np.array([50.0, 100.0, 150.0, 200.0, 250.0])      # modelled basis of 1..5 components
    # totals with the margin: 150.5, 301, 451.5, 602, 752.5
    assert _room_for(coefficient_bytes, basis, 753) == 5
    assert _room_for(coefficient_bytes, basis, 752) == 4
    assert _room_for(coefficient_bytes, basis, 451) == 2
    assert _room_for(coefficient_bytes, basis, 10) == 1       # the trim loop refuses it


def test_room_after_takes_what_the_encoded_basis_leaves_room_for():
    """Once the basis of k components is encoded, more of the encoded textures are kept where its
    real bytes and the modelled growth of the basis (with the 1 % margin) leave room."""
    from usdbtf.compress.ratecontrol import _room_after

    coefficient_bytes = [b"x" * 100] * 5
    basis = np.array([50.0, 100.0, 150.0, 200.0, 250.0])
    encoded = {"per_coefficient": [100, 100], "basis": 60}     # k = 2: the model had said 100
    # k' = 2..5: textures 200..500 + the encoded 60 + growth 0, 50.5, 101, 151.5
    assert _room_after(encoded, coefficient_bytes, basis, 712) == 5
    assert _room_after(encoded, coefficient_bytes, basis, 711) == 4
    assert _room_after(encoded, coefficient_bytes, basis, 560) == 3
    assert _room_after(encoded, coefficient_bytes, basis, 410) == 2
    assert _room_after(encoded, coefficient_bytes, basis, 100) == 2   # over already: the trim loop's


def test_between_reads_k_off_the_packagings_either_side_of_the_budget():
    """Once a packaged k fits the budget and a larger one did not, the next k tried lies strictly
    between them where the line through their packaged bytes meets the target (paper-scale
    fuzzy_moss: 340 at 3,515,140 bytes fits, 344 at 3,561,838 did not)."""
    from usdbtf.compress.ratecontrol import _between

    assert _between((340, 3_515_140, None), (344, 3_561_838), 3_539_881) == (342, 3_538_489.0)
    assert _between((340, 3_515_140, None), (344, 3_561_838), 3_400_000)[0] == 341   # never k0 again
    assert _between((340, 3_515_140, None), (344, 3_561_838), 3_600_000)[0] == 343   # never k1 again
    assert _between((10, 1_000, None), (20, 1_000), 5_000)[0] == 19      # flat bytes: no division by 0


def test_effort_follows_the_mode_same_values_fewer_bytes_at_full(tiny32, tmp_path):
    """A plain k encodes quickly (JPEG XL effort 2/3), --effort full at 7: the same stored
    values, read back from the files, in fewer bytes; budget modes encode at full effort."""
    from usdbtf.compress import read_compressed

    btf = read_manifest(tiny32)
    quick = compress_into(btf, tmp_path / "q", CompressOptions(k=8))
    full = compress_into(btf, tmp_path / "f", CompressOptions(k=8, effort="full"))
    assert quick.quick_encode and not full.quick_encode
    assert not compress_into(btf, tmp_path / "m", CompressOptions(max_bytes=6000)).quick_encode
    assert quick.info["bytes"]["payload"] > full.info["bytes"]["payload"]
    a, b = read_compressed(tmp_path / "q"), read_compressed(tmp_path / "f")
    assert np.array_equal(a.coefficient_values(), b.coefficient_values())
    assert np.array_equal(a.basis_values(), b.basis_values())


def test_max_bytes_impossible_raises_and_writes_nothing(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    with pytest.raises(BTFError, match="--max-bytes"):
        compress_into(btf, tmp_path / "out", CompressOptions(max_bytes=50))
    assert not (tmp_path / "out").exists()
    assert no_leftovers(tmp_path, "out")


@pytest.mark.parametrize("target", [6.0, 3.0])
def test_target_error_met_on_full_data(tiny64, tmp_path, target):
    btf = read_manifest(tiny64)
    c = compress_into(btf, tmp_path / "t", CompressOptions(target_error=target, error_domain="linear"))
    assert c.info["estimated_error"]["linear"]["percent"] <= target
    assert full_percent(btf, read_compressed(tmp_path / "t")) <= target * 1.1
    # Not absurdly over-delivered either: a looser target never costs more bytes.
    if target == 3.0:
        loose = compress_into(btf, tmp_path / "loose", CompressOptions(target_error=6.0, error_domain="linear"))
        assert loose.info["bytes"]["payload"] < c.info["bytes"]["payload"]


def test_target_error_on_the_encoded_values_by_default(tiny64, tmp_path):
    """--target-error without --error-domain: on the input's 8-bit values (what a user
    comparing images sees), measured on the full data after decompress's encoding."""
    from usdbtf.compress.decompress import compare
    btf = read_manifest(tiny64)
    c = compress_into(btf, tmp_path / "t", CompressOptions(target_error=3.0))
    assert c.info["estimated_error"]["encoded"]["percent"] <= 3.0
    full = compare(btf, lambda sel: reconstruct(read_compressed(tmp_path / "t"), sel))
    assert full["encoded"]["percent"] <= 3.0 * 1.1
    assert c.info["estimated_error"]["linear"]["percent"] > 0


@pytest.mark.parametrize("k", [3, 9])
def test_k_respected(tiny32, tmp_path, k):
    btf = read_manifest(tiny32)
    out = tmp_path / "k"
    c = compress_into(btf, out, CompressOptions(k=k))
    assert c.k == k
    doc = json.loads((out / METADATA).read_text())
    assert doc["k"] == k and len(doc["coefficients"]) == k
    assert len(list((out / "coeff").iterdir())) == k
    assert (out / doc["basis"]["file"]).is_file()
    r = read_compressed(out)
    assert r.k == k and r.basis.pixels.shape == (24, k, 1)
    assert reconstruct(r).shape == (24, 32, 32, 3)


@pytest.mark.parametrize("size,cap", [(16, 24), (2, 12)], ids=["cap=S", "cap=3P"])
@pytest.mark.parametrize("solver", ["rsvd", "paper"])
def test_k_capped_without_nan(tmp_path, size, cap, solver):
    s = preset("tiny")
    data = np.random.default_rng(size).uniform(0.05, 1.0, (len(s), size, size, 3)).astype(np.float32)
    btf = ArrayBTF.from_linear(s, data)
    codec = "exr" if solver == "rsvd" else "png"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # see test_exr_codec_emits_no_warnings
        c = compress_into(btf, tmp_path / "c", CompressOptions(solver=solver, k=1000, codec=codec, region=size))
    assert c.k == cap
    r = read_compressed(tmp_path / "c")
    rec = reconstruct(r)
    assert np.isfinite(rec).all() and np.isfinite(r.basis_values()).all()
    assert np.isfinite(r.info["singular_values"]).all()
    # A complete basis loses nothing but storage precision.
    assert full_percent(btf, r) < (0.2 if solver == "rsvd" else 2.0)


@pytest.mark.parametrize("codec", ["jxl", "png", "exr"])
def test_codec_round_trip(tmp_path, codec):
    from usdbtf.compress.codecs import Codec, Stored, get_codec
    c = get_codec(codec)
    rng = np.random.default_rng(0)
    for shape, dtype in [((32, 32, 3), np.uint8), ((17, 5, 3), np.uint16), ((24, 6, 1), np.uint16)]:
        px = rng.integers(0, np.iinfo(dtype).max, shape).astype(dtype)
        if codec == "exr":
            px = rng.normal(0, 1, shape).astype(np.float16)
        st = Stored(px, np.ones(shape[2]), np.zeros(shape[2]))
        n = c.write(tmp_path / f"t.{c.ext}", st, "data")
        assert n == (tmp_path / f"t.{c.ext}").stat().st_size
        back = Codec.read(tmp_path / f"t.{c.ext}", channels=1 if shape[2] == 1 else None)
        assert back.dtype == px.dtype and np.array_equal(back, px)


def test_jxl_codec_round_trips_constant_textures(tmp_path):
    from usdbtf.compress.codecs import Codec, Stored, get_codec
    c = get_codec("jxl")
    for shape in [(32, 32, 3), (24, 1, 1)]:
        px = np.zeros(shape, np.uint8)
        c.write(tmp_path / "t.jxl", Stored(px, np.ones(shape[2]), np.zeros(shape[2])), "data")
        assert np.array_equal(Codec.read(tmp_path / "t.jxl", channels=1 if shape[2] == 1 else None), px)


def test_k1_on_tiny_sampling_readable(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    c = compress_into(btf, tmp_path / "c", CompressOptions(k=1))
    r = read_compressed(tmp_path / "c")
    assert np.array_equal(reconstruct(r), reconstruct(c))


# ---------------------------------------------------------------- determinism and bit-exact reads


def _json_without_timings(raw: bytes) -> dict:
    doc = json.loads(raw)
    doc.pop("timings", None)
    return doc


def test_deterministic_for_a_seed(small32, tmp_path):
    btf = read_manifest(small32)
    outs = [tmp_path / "a", tmp_path / "b"]
    for out in outs:
        compress_into(btf, out, CompressOptions(k=8, seed=3))
    a, b = folder_files(outs[0]), folder_files(outs[1])
    assert a.keys() == b.keys()
    assert {"btf-compressed.json", "basis.jxl", "coeff/c000.jxl", "error_curve.csv", "error_curve.png"} <= a.keys()
    for name in a:
        if name == METADATA:
            assert _json_without_timings(a[name]) == _json_without_timings(b[name])
        else:
            assert a[name] == b[name], name
    # Another seed samples other fit texels: a different (but equally valid) result.
    compress_into(btf, tmp_path / "c", CompressOptions(k=8, seed=4))
    assert (tmp_path / "c" / "basis.jxl").read_bytes() != a["basis.jxl"]


@pytest.mark.parametrize("codec", ["jxlp", "jxl", "png", "exr"])
def test_read_back_is_bit_exact(tiny32, tmp_path, codec):
    btf = read_manifest(tiny32)
    out = tmp_path / codec
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)   # exr: see test_exr_codec_emits_no_warnings
        c = compress_into(btf, out, CompressOptions(k=6, codec=codec))
    r = read_compressed(out)
    assert r.codec == codec and r.k == 6 and (r.width, r.height, r.n_samples) == (32, 32, 24)
    assert np.array_equal(reconstruct(r), reconstruct(c))
    np.testing.assert_array_equal(r.color_matrix, c.color_matrix)
    assert np.array_equal(r.sampling.view, c.sampling.view) and np.array_equal(r.sampling.light, c.sampling.light)
    assert r.source == {"color_space": SRGB, "bit_depth": "uint8", "path": ""}
    from usdbtf.compress.codecs import get_codec
    assert all(p.suffix == f".{get_codec(codec).ext}" for p in (out / "coeff").iterdir())
    if codec == "jxlp":   # planar files: one H x 3W single-channel image, the channels side by side
        from usdbtf.imageio import read_image
        px = read_image(out / "coeff" / "c001.jxl")[0]
        assert px.shape[:2] == (32, 96)                           # OIIO reads grey back as 3 equal channels
        assert np.array_equal(px[:, 32:64, 0], r.coefficients[1].pixels[:, :, 1])
    # The colour matrix of the default solver is orthonormal (a rotation of RGB).
    np.testing.assert_allclose(r.color_matrix @ r.color_matrix.T, np.eye(3), atol=1e-9)
    # All three codecs store the same approximation: comparable error.
    assert full_percent(btf, r) < 15.0
    # Rewriting what was read gives the same reconstruction again.
    write_compress(r, tmp_path / "again")
    assert np.array_equal(reconstruct(read_compressed(tmp_path / "again")), reconstruct(c))


def test_estimated_error_matches_full_data_when_every_texel_is_evaluated(tiny32, tmp_path):
    btf = read_manifest(tiny32)     # 1024 texels < fit_texels: evaluation covers every texel
    c = compress_into(btf, tmp_path / "c", CompressOptions(k=5))
    est = c.info["estimated_error"]["linear"]
    assert c.info["estimated_error"]["texels"] == 1024
    assert est["percent"] == pytest.approx(full_percent(btf, c), rel=1e-4)


def test_paper_with_exr_codec_reads_back(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    c = compress_into(btf, tmp_path / "c", CompressOptions(solver="paper", k=6, codec="exr"))
    r = read_compressed(tmp_path / "c")
    np.testing.assert_allclose(reconstruct(r), reconstruct(c), rtol=1e-3, atol=1e-4)


def test_rsvd_with_jpeg_codec_is_sane(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    try:
        c = compress_into(btf, tmp_path / "c", CompressOptions(k=6, codec="jpeg"))
    except BTFError:
        return      # refusing the combination would also be fine
    assert full_percent(btf, read_compressed(tmp_path / "c")) < 20.0


def test_exr_codec_emits_no_warnings(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        compress_into(btf, tmp_path / "c", CompressOptions(k=4, codec="exr"))


@pytest.mark.parametrize("solver", ["rsvd", "paper"])
def test_all_black_btf(tmp_path, solver):
    s = preset("tiny")
    btf = ArrayBTF.from_linear(s, np.zeros((len(s), 8, 8, 3), np.float32))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            compress_into(btf, tmp_path / "c", CompressOptions(solver=solver, k=4))
    except BTFError:
        return
    assert np.abs(reconstruct(read_compressed(tmp_path / "c"))).max() == 0


def test_metadata_bytes_recorded(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    compress_into(btf, tmp_path / "c", CompressOptions(k=3))
    doc = json.loads((tmp_path / "c" / METADATA).read_text())
    assert doc["bytes"]["metadata"] > 0


# ---------------------------------------------------------------- decompress


def test_decompress_8bit_source_to_png_manifest(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    out = tmp_path / "c"
    c = compress_into(btf, out, CompressOptions(k=8))
    r = read_compressed(out)
    dec = decompress_to_folder(r, tmp_path / "d")
    d = read_manifest(dec)
    assert (d.n_samples, d.width, d.height, d.bit_depth, d.color_space) == (24, 32, 32, "uint8", SRGB)
    assert all(Path(p).suffix == ".png" for p in d.paths)
    np.testing.assert_array_equal(d.sampling.view, btf.sampling.view)
    np.testing.assert_array_equal(d.sampling.light, btf.sampling.light)
    # The files hold exactly the encoded reconstruction.
    want = encode_for_file(reconstruct(r), color.processor(r.working_space, SRGB), "uint8")
    assert np.array_equal(d.read_encoded(np.arange(24)), want)
    assert json.loads((dec / "btf.json").read_text())["reconstructed_from_k"] == 8
    # Its error vs the original matches the in-memory reconstruction in the encoded domain.
    via_files = compare(btf, lambda sel: d.read_samples(sel))
    direct = compare(btf, lambda sel: reconstruct(r, sel))
    assert via_files["encoded"]["percent"] == pytest.approx(direct["encoded"]["percent"], rel=1e-9)
    # Linear: close, not equal (8-bit files round and clip negative lobes to 0).
    assert via_files["linear"]["percent"] == pytest.approx(direct["linear"]["percent"], rel=0.05)


def test_decompress_samples_subset_and_k_truncation(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    r = compress_into(btf, tmp_path / "c", CompressOptions(k=8))
    idx = parse_samples("0-3,7", r.n_samples)
    d_full = read_manifest(decompress_to_folder(r, tmp_path / "full", samples=idx))
    d_k2 = read_manifest(decompress_to_folder(r, tmp_path / "k2", samples=idx, k=2))
    for d in (d_full, d_k2):
        assert d.n_samples == 5
        np.testing.assert_array_equal(d.sampling.view, btf.sampling.view[idx])
        np.testing.assert_array_equal(d.sampling.light, btf.sampling.light[idx])
    want = encode_for_file(reconstruct(r, idx, k=2), color.processor(r.working_space, SRGB), "uint8")
    assert np.array_equal(d_k2.read_encoded(np.arange(5)), want)
    assert json.loads((tmp_path / "k2" / "btf.json").read_text())["reconstructed_from_k"] == 2
    e_full = compare(btf, lambda sel: d_full.read_samples(np.searchsorted(idx, sel)), idx)["linear"]["percent"]
    e_k2 = compare(btf, lambda sel: d_k2.read_samples(np.searchsorted(idx, sel)), idx)["linear"]["percent"]
    assert e_k2 > 1.2 * e_full


def test_decompress_float_source_to_exr(rank4_exr, tmp_path):
    btf = rank4_exr
    r = compress_into(btf, tmp_path / "c", CompressOptions(k=4, codec="exr"))
    d = read_manifest(decompress_to_folder(read_compressed(tmp_path / "c"), tmp_path / "d", samples=np.array([1, 5])))
    assert (d.bit_depth, d.color_space, d.n_samples) == ("float", LIN709, 2)
    assert all(Path(p).suffix == ".exr" for p in d.paths)
    np.testing.assert_allclose(d.read_samples(slice(None)), reconstruct(r, [1, 5]), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(d.read_samples(slice(None)), btf.read_samples([1, 5]), rtol=0, atol=2e-3)


def test_float_manifest_writer_clamps_ringing_below_zero_so_readers_accept_it(tmp_path):
    """A truncated reconstruction rings below zero; the float files hold 0 there (as integer
    depths clip), so `usdbtf error ORIG DECOMPRESSED` and every other reader can open them."""
    s = preset("tiny")
    data = rank_r_images(4, len(s), 8, seed=3) - 0.05          # some values below zero
    assert (data < 0).any()
    folder = write_manifest(tmp_path / "m", s, data, color_space=LIN709, bit_depth="half", ext="exr",
                            array_space=LIN709)
    back = read_manifest(folder).read_encoded(np.arange(len(s)))     # the file values (Rec.709 linear)
    np.testing.assert_allclose(back, np.maximum(data, 0.0), rtol=2e-3, atol=1e-3)
    assert back.min() == 0.0


# ---------------------------------------------------------------- error curve


def test_error_curve_files(small32, tmp_path):
    btf = read_manifest(small32)
    out = tmp_path / "c"
    c = compress_into(btf, out, CompressOptions(k=10))
    with open(out / "error_curve.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["k"]) for r in rows] == list(range(1, 11))
    pct = np.array([float(r["percent_error"]) for r in rows])
    assert np.isfinite(pct).all() and (pct > 0).all()
    assert pct[-1] < 0.6 * pct[0]
    assert (np.diff(pct) <= 0.05 * pct[:-1]).all(), pct          # decreasing, up to small wiggles
    # Every point is the error of the stored representation cut to its first k components,
    # on the curve's samples (the curve updates its residual incrementally; this does not).
    rows_idx = curve_samples(btf.n_samples)
    rmse = np.array([float(r["rmse_linear"]) for r in rows])
    for k, p, e in zip(range(1, 11), pct, rmse):
        want = compare(btf, lambda sel: reconstruct(truncate(c, k), sel), rows_idx)["linear"]
        assert p == pytest.approx(want["percent"], rel=1e-4), k
        assert e == pytest.approx(want["rmse"], rel=1e-4), k
    spec = image_spec(out / "error_curve.png")
    assert spec.width > 100 and spec.height > 100
    doc = json.loads((out / METADATA).read_text())
    assert doc["error_curve"] == {"file": "error_curve.csv", "plot": "error_curve.png"}


def test_an_in_memory_source_lets_its_values_go_before_rate_control(small32, monkeypatch):
    """Issue 42: after the projection compress reads no stored value but the error curve's
    few samples, so an in-memory source (0.53 GB of a paper-scale run's 1.2 GB) lets them go
    before rate control; a --target-error run keeps them until the end (a capped plan projects
    again).  A released source refuses reads in one line."""
    from usdbtf.compress import core
    from usdbtf.compress.source import InMemorySource

    events = []
    release = InMemorySource.release_values
    choose = core.rate_control
    monkeypatch.setattr(InMemorySource, "release_values", lambda self: (events.append("release"), release(self))[1])
    monkeypatch.setattr(core, "rate_control", lambda *a, **kw: (events.append("rate control"), choose(*a, **kw))[1])
    btf = read_manifest(small32)
    compress(btf, CompressOptions(k=6))
    assert events == ["release", "rate control"]
    events.clear()
    compress(btf, CompressOptions(target_error=8.0))
    assert events == ["rate control", "release"]
    src = InMemorySource(btf, workers=1)
    release(src)
    with pytest.raises(BTFError, match="released"):
        src.working_samples([0])


# ---------------------------------------------------------------- failures


def test_corrupt_input_image_is_atomic(tiny32, tmp_path):
    src = tmp_path / "src"
    src.mkdir()
    for p in tiny32.iterdir():
        (src / p.name).write_bytes(p.read_bytes())
    doc = json.loads((src / "btf.json").read_text())
    bad = doc["samples"][13]["image"]
    (src / bad).write_bytes(b"\x89PNG\r\n\x1a\n" + os.urandom(300))
    btf = read_manifest(src)
    parent = tmp_path / "outs"
    parent.mkdir()
    with pytest.raises(BTFError, match=bad):
        compress_into(btf, parent / "c", CompressOptions(k=4))
    assert list(parent.iterdir()) == []


def test_corrupt_input_image_parallel_loader(small32, tmp_path):
    """169 samples: the forked multi-process loader must report the bad file too."""
    src = tmp_path / "src"
    src.mkdir()
    for p in small32.iterdir():
        (src / p.name).write_bytes(p.read_bytes())
    bad = json.loads((src / "btf.json").read_text())["samples"][150]["image"]
    (src / bad).write_bytes(b"garbage" * 40)
    btf = read_manifest(src)
    with pytest.raises(BTFError, match=bad):
        compress_into(btf, tmp_path / "c", CompressOptions(k=4, workers=2))
    assert not (tmp_path / "c").exists() and no_leftovers(tmp_path, "c")


def test_failed_compress_keeps_previous_output(tiny32, tmp_path):
    btf = read_manifest(tiny32)
    out = tmp_path / "c"
    compress_into(btf, out, CompressOptions(k=3))
    before = folder_files(out)
    with pytest.raises(BTFError):
        compress_into(btf, out, CompressOptions(max_bytes=10))
    assert folder_files(out) == before
    assert no_leftovers(tmp_path, "c")
    # A successful run replaces it completely (no stale coefficient files).
    compress_into(btf, out, CompressOptions(k=2))
    assert sorted(p.name for p in (out / "coeff").iterdir()) == ["c000.jxl", "c001.jxl"]
    assert no_leftovers(tmp_path, "c")


def test_invalid_options():
    s = preset("tiny")
    btf = ArrayBTF.from_linear(s, np.ones((len(s), 4, 4, 3), np.float32))
    for opts, msg in [(CompressOptions(solver="svd"), "unknown solver"), (CompressOptions(k=0), "--k"),
                      (CompressOptions(target_error=0), "--target-error"), (CompressOptions(max_bytes=-1), "--max-bytes"),
                      (CompressOptions(codec="webp"), "unknown codec")]:
        with pytest.raises(BTFError, match=msg):
            compress_into(btf, "/nonexistent/never/written", opts)


@pytest.fixture(scope="module")
def good_folder(tiny32, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("good") / "c"
    compress_into(read_manifest(tiny32), out, CompressOptions(k=3, codec="png"))
    return out


def _copy(src: Path, dst: Path) -> Path:
    for p in src.rglob("*"):
        if p.is_file():
            (dst / p.relative_to(src)).parent.mkdir(parents=True, exist_ok=True)
            (dst / p.relative_to(src)).write_bytes(p.read_bytes())
    return dst


def test_read_compressed_missing_texture(good_folder, tmp_path):
    f = _copy(good_folder, tmp_path / "f")
    (f / "coeff" / "c001.png").unlink()
    with pytest.raises(BTFError, match="c001.png"):
        read_compressed(f)


def test_read_compressed_wrong_format(good_folder, tmp_path):
    f = _copy(good_folder, tmp_path / "f")
    doc = json.loads((f / METADATA).read_text())
    doc["format"] = "btf-compressed/99"
    (f / METADATA).write_text(json.dumps(doc))
    with pytest.raises(BTFError, match=f"{METADATA}.*btf-compressed/99"):
        read_compressed(f)


def test_read_compressed_basis_wrong_size(good_folder, tmp_path):
    from usdbtf.imageio import write_image
    f = _copy(good_folder, tmp_path / "f")
    write_image(f / "basis.png", np.zeros((24, 2, 1), np.uint16), color_space="data")
    with pytest.raises(BTFError, match="basis.png"):
        read_compressed(f)
    write_image(f / "basis.png", np.zeros((20, 3, 1), np.uint16), color_space="data")
    with pytest.raises(BTFError, match="basis.png"):
        read_compressed(f)


def test_read_compressed_texture_wrong_size_and_k_mismatch(good_folder, tmp_path):
    from usdbtf.imageio import write_image
    f = _copy(good_folder, tmp_path / "f")
    write_image(f / "coeff" / "c002.png", np.zeros((16, 32, 3), np.uint8), color_space="data")
    with pytest.raises(BTFError, match="c002.png"):
        read_compressed(f)
    g = _copy(good_folder, tmp_path / "g")
    doc = json.loads((g / METADATA).read_text())
    doc["coefficients"] = doc["coefficients"][:2]
    (g / METADATA).write_text(json.dumps(doc))
    with pytest.raises(BTFError, match=METADATA):
        read_compressed(g)


def test_read_compressed_not_a_folder_or_bad_json(good_folder, tmp_path):
    with pytest.raises(BTFError, match="metadata file missing"):
        read_compressed(tmp_path)
    f = _copy(good_folder, tmp_path / "f")
    (f / METADATA).write_text("{not json")
    with pytest.raises(BTFError, match=METADATA):
        read_compressed(f)


def test_read_compressed_missing_key(good_folder, tmp_path):
    f = _copy(good_folder, tmp_path / "f")
    doc = json.loads((f / METADATA).read_text())
    del doc["width"]
    (f / METADATA).write_text(json.dumps(doc))
    with pytest.raises(BTFError, match=METADATA):
        read_compressed(f)


# ---------------------------------------------------------------- compress in memory, write_compress


@pytest.mark.parametrize("kw", [dict(k=6), dict(max_bytes=9000), dict(solver="paper", k=8, max_bytes=8000),
                                dict(codec="jpeg", k=8), dict(codec="exr", target_error=8.0),
                                dict(k=6, memory_budget=0, workers=2)],
                         ids=["k", "max-bytes", "paper-max-bytes", "jpeg", "exr-target", "streamed"])
def test_compress_creates_no_file(tiny32, tmp_path, monkeypatch, kw):
    """compress() is pure: no file appears where it could write one ($TMPDIR, the working
    folder, the input's folder and its parent) and no descriptor stays open, whatever the
    solver, codec, budget or source; the result carries its encoded bytes."""
    scratch, work = tmp_path / "tmpdir", tmp_path / "cwd"
    scratch.mkdir()
    work.mkdir()
    monkeypatch.setenv("TMPDIR", str(scratch))
    monkeypatch.setattr(tempfile, "tempdir", None)      # tempfile reads $TMPDIR again
    monkeypatch.chdir(work)
    before = folder_files(tiny32), sorted(p.name for p in tiny32.parent.iterdir())
    fds = sorted(os.listdir("/proc/self/fd"))
    result = compress(read_manifest(tiny32), CompressOptions(**kw))
    assert list(scratch.iterdir()) == [] and list(work.iterdir()) == []
    assert (folder_files(tiny32), sorted(p.name for p in tiny32.parent.iterdir())) == before
    assert sorted(os.listdir("/proc/self/fd")) == fds
    assert result.encoded is not None and result.encoded.describes(result)
    assert result.info["bytes"] == result.encoded.sizes()


def test_write_compress_writes_the_carried_bytes_and_changes_nothing(tiny32, tmp_path):
    """The folder holds exactly the bytes the result carries (a lossy codec is not encoded a
    second time); writing leaves the result as it was; an existing folder is replaced only
    with force; a truncated result (no bytes of its own) is encoded when written."""
    result = compress(read_manifest(tiny32), CompressOptions(solver="paper", k=6))        # JPEG: lossy
    info = json.dumps(result.info, sort_keys=True)
    pixels = [st.pixels for st in result.coefficients]
    out = tmp_path / "c"
    sizes = write_compress(result, out)
    assert json.dumps(result.info, sort_keys=True) == info
    assert all(a is st.pixels for a, st in zip(pixels, result.coefficients))
    files = folder_files(out)
    assert [files[f"coeff/c{i:03d}.jpg"] for i in range(6)] == list(result.encoded.coefficients)
    assert files["basis.tif"] == result.encoded.basis
    assert sizes == dict(result.info["bytes"], metadata=len(files[METADATA]))
    assert json.loads(files[METADATA])["bytes"] == sizes
    assert {"error_curve.csv", "error_curve.png"} <= files.keys()
    r = read_compressed(out)
    assert all(np.array_equal(a.pixels, b.pixels) for a, b in zip(r.coefficients, result.coefficients))
    with pytest.raises((FileExistsError, OutputRefused)):
        write_compress(result, out)
    assert folder_files(out) == files
    write_compress(result, out, force=True)
    assert folder_files(out) == files and no_leftovers(tmp_path, "c")
    cut = truncate(result, 3)
    assert cut.encoded is None
    write_compress(cut, tmp_path / "t")
    assert read_compressed(tmp_path / "t").k == 3


@pytest.mark.parametrize("tiles_per_shard", [1, 8])
@pytest.mark.parametrize("ks", [(8, 8, 8), (8, 5, 0)], ids=["interleaved", "planar"])
def test_projection_reduces_tiles_then_shards_in_order(small32, ks, tiles_per_shard, monkeypatch):
    """The reduction :mod:`usdbtf.compress.projection` documents, written out by hand: every
    tile's partial, computed in any order (as distributed workers would), summed from zero
    in sample order within its shard, the shards' sums added from zero in shard order, per
    texel block -- bit-identical to the in-process projection; the energy summed in float64
    tiles-in-shard, then block by block over the shards."""
    from usdbtf.compress import projection
    from usdbtf.compress.projection import TileProjector
    from usdbtf.compress.source import InMemorySource, work_plan
    monkeypatch.setattr(projection, "TILES_PER_SHARD", tiles_per_shard)
    monkeypatch.setattr(projection, "_MAX_TILE_SAMPLES", 128)     # two tiles of the small sampling
    btf = read_manifest(small32)
    src = InMemorySource(btf, workers=1)
    u = randomized_basis(src.columns(np.arange(btf.n_pixels)), 8, seed=0)[0]
    mix = src.working_mix(np.linalg.qr(np.random.default_rng(0).normal(size=(3, 3)))[0])
    want, energy = src.project(u, mix, ks, energy=True)
    plan = work_plan(btf)
    assert plan.tile < btf.n_samples, "the sampling must span several tiles"
    assert len(plan.shards()) == (2 if tiles_per_shard == 1 else 1)
    proj = TileProjector(u, mix, ks, src.curves, plan.tile, energy=True)
    stored = btf.read_encoded(slice(None)).reshape(btf.n_samples, -1)
    got = np.zeros_like(want)
    energies = {}
    for a, b in plan.blocks():
        starts = list(range(0, btf.n_samples, plan.tile))
        partials = {s0: proj.partial(s0, stored[s0:s0 + plan.tile, 3 * a:3 * b]) for s0 in reversed(starts)}
        total = [np.zeros_like(z) for z in proj.zeros(b - a)]
        for n, (s0, s1) in enumerate(plan.shards()):
            shard = [np.zeros_like(z) for z in proj.zeros(b - a)]
            energies[a, n] = 0.0
            for t0 in range(s0, s1, plan.tile):
                for acc, p in zip(shard, partials[t0].products):
                    if p is not None:
                        acc += p
                energies[a, n] += partials[t0].energy
            for acc, part in zip(total, shard):
                acc += part
        if proj.interleaved:
            got[:, a:b, :] = total[0].reshape(-1, b - a, 3)
        else:
            for j, kj in enumerate(proj.ks):
                got[:kj, a:b, j] = total[j][:kj]
    assert np.array_equal(got, want)
    assert proj.energy and energy == sum(energies[key] for key in sorted(energies))


def test_projection_refuses_shards_out_of_order(small32, monkeypatch):
    from usdbtf.compress import projection
    from usdbtf.compress.projection import ProjectionTotal, ShardSums, TileProjector
    from usdbtf.compress.source import work_plan
    monkeypatch.setattr(projection, "TILES_PER_SHARD", 1)
    monkeypatch.setattr(projection, "_MAX_TILE_SAMPLES", 128)     # two shards of the small sampling
    btf = read_manifest(small32)
    plan = work_plan(btf)
    proj = TileProjector(np.ones((btf.n_samples, 2), np.float32), np.eye(3), (2, 2, 2), lambda x: x.astype(np.float32),
                         plan.tile)
    total = ProjectionTotal(proj, plan)
    with pytest.raises(RuntimeError, match="expected shard 0"):
        total.add(1, ShardSums(proj, plan.blocks()))
    total.add(0, ShardSums(proj, plan.blocks()))
    with pytest.raises(RuntimeError, match="not every shard"):
        total.result()


# ---------------------------------------------------------------- streaming (memory-bounded) path


@pytest.mark.parametrize("solver", ["rsvd", "paper"])
def test_streaming_source_matches_in_memory(small32, tmp_path, solver, monkeypatch):
    """memory_budget=0 streams the files instead of holding them -- decoded once into an
    anonymous spill file and read back, or (spill=False) decoded twice -- by forked decode
    workers or serially: byte-identical folders.  The spill file never has a name: the
    temporary folder stays empty throughout."""
    spill_dir = tmp_path / "tmp"
    spill_dir.mkdir()
    monkeypatch.setenv("TMPDIR", str(spill_dir))
    monkeypatch.setattr(tempfile, "tempdir", None)
    btf = read_manifest(small32)
    runs = {"mem": {}, "spilled": dict(memory_budget=0, workers=2, chunk_bytes=1),
            "spilled-serial": dict(memory_budget=0, workers=1), "twice": dict(memory_budget=0, spill=False, workers=2)}
    out = {}
    for name, kw in runs.items():
        compress_into(btf, tmp_path / name, CompressOptions(solver=solver, k=12, **kw))
        out[name] = folder_files(tmp_path / name)
    assert all(out[name] == out["mem"] for name in runs), [n for n in runs if out[n] != out["mem"]]
    assert list(spill_dir.iterdir()) == []


@pytest.mark.parametrize("direct", [True, False], ids=["direct", "buffered"])
def test_spill_file_is_anonymous_and_sized_by_free_space(tmp_path, monkeypatch, direct):
    """Slots written from any offset, read back in order (direct I/O: aligned buffers, padded
    slots; buffered where the file system refuses O_DIRECT); no name in the folder."""
    import os

    from usdbtf.compress import spill as spill_mod
    if not direct:
        monkeypatch.setattr(os, "O_DIRECT", 0, raising=False)
    sp = spill_mod.Spill.create(3, 100_000, str(tmp_path))
    assert sp is not None and list(tmp_path.iterdir()) == []
    if not direct:
        assert sp.direct is False                           # else O_DIRECT where the file system has it
    data = np.arange(250_000, dtype=np.int64).astype(np.uint8)
    pieces = [data[:100_000], data[100_000:200_000], data[200_000:]]
    for n in (2, 0, 1):
        sp.write(n, pieces[n])
    got = [(slot, arr.copy()) for slot, arr in sp.read_ahead([(n, len(p)) for n, p in enumerate(pieces)], depth=1)]
    assert [slot for slot, _ in got] == [0, 1, 2]
    assert all(np.array_equal(arr, p) for (_, arr), p in zip(got, pieces))
    sp.close()
    assert spill_mod.Spill.create(1, 1 << 62, str(tmp_path)) is None      # more than the disk: decode twice


def test_streaming_source_holds_only_requested_columns(small32):
    from usdbtf.compress.source import StreamingSource, stored_bytes
    btf = read_manifest(small32)
    texels = np.arange(64, 128)
    src = StreamingSource(btf, [texels], [0, 5], workers=1, chunk_bytes=1)
    assert src.nbytes < stored_bytes(btf)
    want = btf.decode(btf.read_encoded(slice(None))).reshape(btf.n_samples, -1, 3)[:, texels]
    got = src.to_working(src.columns(texels)).reshape(btf.n_samples, -1, 3)
    assert np.allclose(got, want, atol=1e-6)
    with pytest.raises(ValueError):
        src.columns(np.arange(3))


def test_memory_budget_counts_the_fit_columns_and_streams_a_budget_run(small32, tmp_path, caplog):
    """Issue 27: the memory budget holds the stored values *and* the fit's working set (its
    float32 columns and panels): room for the values alone streams them, and the files are
    those of a streamed run either way."""
    import logging

    from usdbtf.compress.source import choose_source, stored_bytes
    btf = read_manifest(small32)
    stored = stored_bytes(btf)
    with choose_source(btf, [np.arange(64)], [0], memory_budget=stored + 100, workers=1) as src:
        assert src.kind == "in-memory"
    with choose_source(btf, [np.arange(64)], [0], memory_budget=stored + 100, workers=1, beside=101) as src:
        assert src.kind.startswith("streaming")
    # Room for the stored values alone: the fit's working set no longer fits, the input streams.
    for budget, kind in ((1e9, "in-memory"), (stored + 1, "streaming")):
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="usdbtf.compress"):
            compress_into(btf, tmp_path / "a", CompressOptions(max_bytes=6000, memory_budget=budget))
        assert f"({kind}" in caplog.text
        compress_into(btf, tmp_path / "s", CompressOptions(max_bytes=6000, memory_budget=0))
        jxl = [{k: v for k, v in folder_files(tmp_path / d).items() if k.endswith(".jxl")} for d in ("a", "s")]
        assert jxl[0] == jxl[1] and jxl[0]


def test_streaming_source_hands_over_sets_from_threads_at_once(small32, monkeypatch):
    """compress takes the fitting and the held-out columns from two threads at once: each
    thread gets its own set and every set is handed over once (before the lock, a deletion
    between another thread's search and its own raised IndexError or removed the wrong set).
    The comparison is slowed down so that the threads interleave inside the search."""
    import threading
    import time

    from usdbtf.compress import source as source_module
    from usdbtf.compress.source import StreamingSource
    btf = read_manifest(small32)
    sets = [np.arange(a, a + 4) for a in range(0, 64, 8)]
    src = StreamingSource(btf, sets, [0], workers=1, chunk_bytes=1)
    want = {int(t[0]): raw for t, raw in src._kept}
    real = np.array_equal

    def slow_equal(a, b):
        time.sleep(0.002)
        return real(a, b)

    monkeypatch.setattr(source_module.np, "array_equal", slow_equal)
    got, errors = {}, []
    start = threading.Barrier(len(sets))

    def take(texels):
        start.wait()
        try:
            got[int(texels[0])] = src._kept_set(texels, hand_over=True)
        except Exception as exc:       # noqa: BLE001 - collected, asserted below
            errors.append(exc)

    threads = [threading.Thread(target=take, args=(t,)) for t in reversed(sets)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and not src._kept
    assert all(got[a] is want[a] for a in want)


def test_curve_points():
    from usdbtf.compress.curve import curve_ks
    assert curve_ks(5).tolist() == [1, 2, 3, 4, 5]
    ks = curve_ks(300)
    assert ks[0] == 1 and ks[-1] == 300 and (np.diff(ks) > 0).all() and len(ks) <= 50
    assert ks[:20].tolist() == list(range(1, 21))


@pytest.mark.parametrize("shape", [(7, 3), (4, 5, 3), (6, 3 * 11), (0, 3)])
def test_mix_rgb_matches_matmul(shape):
    # The OpenCV transform behind to_working and the colour rotation: rgb @ M^T per colour,
    # for (..., 3) colours and (rows, 3 n) interleaved blocks alike.
    rng = np.random.default_rng(1)
    x = rng.uniform(-2, 5, shape).astype(np.float32)
    m = rng.normal(0, 1, (3, 3))
    got = color.mix_rgb(x, m)
    want = (x.reshape(-1, 3).astype(np.float64) @ m.T).reshape(shape)
    assert got.shape == shape and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * max(1.0, float(np.abs(want).max(initial=0))))


def test_asset_budget_chooses_the_step_on_measured_bytes_and_error(monkeypatch):
    """Issue 39: under an asset budget the step is chosen with k fitted on the measured packs
    at each step and the held-out error of what that stores (here stand-ins: finer steps fit
    fewer components, the error is the table's at that k and step): the walk leaves the
    model's step for the neighbour with the least error, goes on while the error falls,
    keeps the k the measured bytes allow there, and does not try the coarser side once the
    finer side has helped."""
    from usdbtf.compress import ratecontrol, ratedist

    rng = np.random.default_rng(3)
    scale = (0.8 ** np.arange(40))[:, None, None]
    coeff = (rng.standard_normal((40, 512, 3)) * scale).astype(np.float32)
    basis = np.linalg.qr(rng.standard_normal((64, 40)))[0].astype(np.float32)
    table = ratedist.rd_table(coeff, basis, None)
    _, err = table.curves(1.0)
    # measured k per step index: the model's step (10) gets 36 components, finer steps fewer
    measured_k = {8: 38, 9: 37, 10: 36, 11: 31, 12: 27, 13: 22, 14: 18}
    step_of_k = {k: j for j, k in measured_k.items()}
    calls = []

    def fit(f, options, step, k, k_cap, ratio, rest, aim):
        j = table.column(step)
        calls.append(j)
        return measured_k[j], 0.0, None

    monkeypatch.setattr(ratecontrol, "_asset_fit_planned", fit)
    monkeypatch.setattr(ratecontrol, "_held_out_score", lambda q, held, k: float(err[k, step_of_k[k]]))
    k, step = ratecontrol._measured_step(None, None, table, None, float(table.steps[10]), 36, 40, 1.0, 0.0, 1.0)
    walked = sorted(set(calls))
    errors = {j: err[measured_k[j], j] for j in walked}
    best = min(errors, key=errors.get)
    assert (k, step) == (measured_k[best], float(table.steps[best]))
    # two steps finer (k 27) beat the model's step (k 36); one more (k 22) did not
    assert best == 12 and walked == [10, 11, 12, 13]
    assert errors[12] < errors[11] < errors[10] < errors[13] * 3


def test_held_out_score_is_the_geometric_mean_of_both_domains(tiny32, tmp_path):
    """The step search's score: sqrt(encoded % x linear %) of the held-out texels, from the
    same sums `held_out_errors` gives each domain."""
    from usdbtf.compress import ratecontrol
    from usdbtf.compress.evaluate import held_out_errors, held_out_set
    from usdbtf.compress.select_source import load_source
    from usdbtf.compress.texels import sample_texels

    btf = read_manifest(tiny32)
    opts = CompressOptions(k=6)
    c = compress_into(btf, tmp_path / "c", opts)
    texels = sample_texels(btf, opts)
    with load_source(btf, texels, opts) as source:
        held = held_out_set(source, texels)
    enc, lin = held_out_errors(c, held, 4, ("encoded", "linear"))
    assert enc.percent > 0 and lin.percent > 0 and enc.percent != lin.percent
    assert ratecontrol._held_out_score(c, held, 4) == pytest.approx(np.sqrt(enc.percent * lin.percent), rel=1e-12)
