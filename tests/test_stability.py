"""Stability stress tests for ``usdbtf.compress``: HDR input, rank-deficient data, float32
versus float64 arithmetic, determinism (runs, chunk sizes, streaming), bad pixels, and
property-based round trips over random small BTFs.

Every compression here runs with RuntimeWarning raised as an error ("no warnings").
Sizes are 8-32 texels with the tiny (24) and small (169) samplings; the module takes
well under a minute on two cores.

Error bounds used below (derived here; the library documents the ingredients)
---------------------------------------------------------------------------------
The stored representation is ``rec = M (U^ c^)``: U^ the de-quantised basis (S x k),
c^ the de-quantised coefficients in decorrelated colour channels, M the colour matrix
(``format.py``).  The compressor computed ``x ~= M (U c)`` in float32 and then rounded U
and c for storage.  With element-wise rounding errors |U - U^| <= dU and |c - c^| <= dc:

    |U^ c^ - U c| <= |U^| dc + dU |c^| + dU dc,   so   |rec - M U c| <= |M| (that)      (B1)

* jxl / png (``rsvd``), png (``paper``): values are ``code * scale + bias`` with codes
  from ``rint``, so dU = basis scale_i / 2 and dc = coefficient scale / 2 (the recorded
  scales; for jxl the coefficient scale is the rate-distortion step, metadata
  ``choice.step``; the basis scale is step / sigma_i unless widened to fit 16 bits).
* exr: half floats, unit roundoff 2^-11 for normal values and absolute spacing 2^-24
  below 2^-14 (subnormals): dv = 2^-11 (1 + 2^-10) |v^| + 2^-25 for every stored v.

Float32 arithmetic (projection U^T x, de-quantisation, reconstruction, colour matrix)
adds at most a few dot products of <= S terms, each within gamma_S = S 2^-24 of the
sum of |terms| (Higham, Accuracy and Stability, 2002, sec. 3.1); every such sum is
bounded by the texel's norm ||x_t|| (over samples and channels, Cauchy-Schwarz with
orthonormal U and M), so we allow

    2 gamma_S ||x_t||                                                              (B2)

At full k (k = min(S, 3 H W)) or k >= the data's rank, U U^T x = x up to float32 rounding
of x itself, so |rec - x| <= B1 + B2.  (``fit.py`` drops directions with sigma <= 1e-6
sigma_1 of the fit, whose texels get weights ||x_t||^-1/2 when their norms span > 1e6; in
the data used here the dropped directions carry only float32 rounding noise -- see
test_hdr_dark_region_with_its_own_brdf.)
"""
from __future__ import annotations

import dataclasses
import json
import math
import shutil
import time
import warnings
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from usdbtf import color, synth
from usdbtf.compress import CompressOptions, read_compressed, reconstruct
from usdbtf.compress import codecs as codecs_mod
from usdbtf.compress.linalg import exact_basis, randomized_basis
from usdbtf.compress.source import InMemorySource, StreamingSource, tile_samples
from usdbtf.errors import BTFError
from usdbtf.manifest import read_manifest, write_manifest
from usdbtf.model import ArrayBTF
from usdbtf.sampling import cross, preset, rings

from compress_helpers import compress_into

SRGB = "sRGB Encoded Rec.709 (sRGB)"
LIN709 = "Linear Rec.709 (sRGB)"
U32 = 2.0 ** -24          # float32 unit roundoff
U16 = 2.0 ** -11          # half unit roundoff
SUB16 = 2.0 ** -25        # half rounding error below the normal range (spacing 2^-24)
FIXED_DATE = "2000:01:01 00:00:00"

pytestmark = pytest.mark.filterwarnings("error::RuntimeWarning")


# ---------------------------------------------------------------- helpers


def quant_bound(cbtf) -> np.ndarray:
    """(S, H, W, 3) bound B1 on |reconstruct(cbtf) - M U c| from the storage rounding."""
    k, P = cbtf.k, cbtf.width * cbtf.height
    ub = np.abs(cbtf.basis_values().astype(np.float64))                     # (S, k)
    cv = np.abs(cbtf.coefficient_values().astype(np.float64)).reshape(k, -1)  # (k, 3P)
    if cbtf.codec == "exr":
        du = U16 * (1 + 2.0 ** -10) * ub + SUB16
        dc = U16 * (1 + 2.0 ** -10) * cv + SUB16
    else:
        assert cbtf.codec in ("jxlp", "jxl", "png"), "lossy codecs have no rounding bound"
        du = np.broadcast_to(np.asarray(cbtf.basis.scale, np.float64)[:k] / 2, ub.shape)
        cs = np.stack([np.asarray(st_.scale, np.float64) for st_ in cbtf.coefficients])  # (k, 3)
        dc = np.repeat(cs[:, None, :] / 2, P, axis=1).reshape(k, -1)
    e = ub @ dc + du @ cv + du @ dc                                          # (S, 3P)
    e = e.reshape(-1, 3) @ np.abs(np.asarray(cbtf.color_matrix, np.float64)).T
    return e.reshape(cbtf.n_samples, cbtf.height, cbtf.width, 3)


def texel_norm(x) -> np.ndarray:
    """(H, W) Euclidean norm of each texel over samples and channels."""
    return np.sqrt((np.asarray(x, np.float64) ** 2).sum(axis=(0, 3)))


def float32_slack(x) -> np.ndarray:
    """B2 broadcastable to (S, H, W, 3)."""
    return (2 * len(x) * U32 * texel_norm(x))[None, :, :, None]


def assert_within(rec, x, bound, what=""):
    err = np.abs(np.asarray(rec, np.float64) - np.asarray(x, np.float64))
    bad = err > bound
    if bad.any():
        i = np.unravel_index(np.argmax(err - bound), err.shape)
        pytest.fail(f"{what}: {int(bad.sum())} values exceed the bound; worst at {i}: "
                    f"|err| {err[i]:.4g} > bound {bound[i]:.4g} (value {np.asarray(x)[i]:.4g})")


def non_finite_json(path: Path) -> dict:
    """{dotted key: value} of every NaN / Infinity in a JSON file (Python writes them as the
    bare tokens NaN / Infinity, which are not JSON)."""
    found = {}

    def walk(v, key):
        if isinstance(v, dict):
            for k, x in v.items():
                walk(x, f"{key}.{k}" if key else k)
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(x, f"{key}[{i}]")
        elif isinstance(v, float) and not math.isfinite(v):
            found[key] = v

    walk(json.loads(path.read_text()), "")
    return found


def check_output_finite(out: Path) -> None:
    """Finite metadata (but see test_metadata_is_strict_json_for_exact_reconstructions),
    a finite error curve, finite stored values."""
    bad = non_finite_json(out / "btf-compressed.json")
    assert bad.pop("estimated_error.linear.psnr_db", 0.0) in (0.0, math.inf)   # +inf: exact, tested there
    assert bad == {}
    rows = (out / "error_curve.csv").read_text().splitlines()[1:]
    assert rows and all(math.isfinite(float(v)) for r in rows for v in r.split(","))
    r = read_compressed(out)
    assert np.isfinite(r.basis_values()).all() and np.isfinite(r.coefficient_values()).all()


def folder_files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def differing(a: dict, b: dict) -> list:
    return sorted(n for n in a.keys() | b.keys() if a.get(n) != b.get(n))


def no_leftovers(parent: Path, name: str) -> bool:
    return not any(p.name.startswith(f".{name}.") for p in parent.iterdir())


def sampling_of(n: int):
    return preset("tiny").subset(np.arange(n))


def pebbles(sampling_name: str, size: int, material="pebbles") -> ArrayBTF:
    s = preset(sampling_name)
    return ArrayBTF.from_linear(s, synth.render_all(synth.make_material(material, size, 0), s))


@pytest.fixture
def fixed_exr_dates(monkeypatch):
    """OpenImageIO stamps EXR and TIFF files with the current DateTime (see
    test_two_runs_byte_identical); pin it so a test can look at everything else."""
    for name in ("exr", "jpeg"):
        c = codecs_mod.CODECS[name]
        monkeypatch.setitem(codecs_mod.CODECS, name, dataclasses.replace(
            c, attributes=dict(c.attributes, DateTime=FIXED_DATE),
            basis_attributes=dict(c.basis_attributes, DateTime=FIXED_DATE)))


# ---------------------------------------------------------------- HDR input


def hdr_btf(n: int = 16, *, dark_own_brdf: bool = False) -> np.ndarray:
    """(24, n, n, 3) float32 spanning exactly 1e-4 .. 1e4, exact rank 3.

    x[s, t] = sum_j A_j(s) B_j(t) col_j: BRDF lobes (diffuse, glossy, a specular peak at
    sample 7) times per-texel weights spread log-uniformly over 5 decades.  With
    ``dark_own_brdf`` the bright half of the texels (~1e3 .. 1e4) uses the first three lobes
    and the dark half (1e-4 .. 2e-4) a fourth, diffuse-like lobe that the bright half lacks:
    a shadowed region of a different material.
    """
    S = 24
    rng = np.random.default_rng(7)
    lobes = np.stack([rng.uniform(0.3, 1.0, S),                        # diffuse
                      rng.uniform(0.05, 1.0, S) ** 3,                   # glossy
                      np.where(np.arange(S) == 7, 1.0, 0.01),           # specular peak
                      rng.uniform(0.5, 1.0, S)], axis=1)                # the dark region's own
    cols = rng.uniform(0.3, 1.0, (4, 3))
    w = np.zeros((n * n, 4))
    w[:, :3] = 10 ** rng.uniform(-5, 0, (n * n, 3))
    if dark_own_brdf:
        dark = np.arange(n * n) >= n * n // 2
        w[~dark] = [1.0, 0.0, 0.5, 0.0]
        w[dark] = [0.0, 0.0, 0.0, 1e-8]
    x = np.einsum("sj,tj,jc->stc", lobes, w, cols)
    x *= 1e4 / x.max()
    lo = x.min(axis=(0, 2))                                             # per texel
    x *= np.where(lo < 1e-4, 1e-4 / lo, 1.0)[None, :, None]            # lift texels below 1e-4
    x[:, int(np.argmin(x.min(axis=(0, 2))))] *= 1e-4 / x.min()          # the darkest pins 1e-4
    return x.reshape(S, n, n, 3).astype(np.float32)


def texel_relative_bound(cbtf, x) -> np.ndarray:
    """(H, W) bound on max_{s,c} |rec - x| / ||x_t|| for codec exr (from B1 + B2):
    sum_i |U^_si| |c^_it| <= ||x_t|| per channel (Cauchy-Schwarz, orthonormal U), |M| rows sum to
    <= sqrt(3), the subnormal floors add <= 2^-25 (sqrt(k) + sqrt(k) ||x_t||) per channel."""
    k, tn = cbtf.k, texel_norm(x)
    rel = 2 * U16 * (1 + 2.0 ** -10) + SUB16 * np.sqrt(k) * (1 + 1 / tn)
    return np.sqrt(3) * rel * (1 + 1e-3) + 2 * len(x) * U32


def test_hdr_exr_error_relative_to_each_texel(tmp_path):
    """HDR input spanning 1e-4..1e4, codec exr (half floats, no quantisation step): the error
    is bounded per pixel by B1 + B2, i.e. relative to the magnitudes involved, not to the
    dataset's maximum.  Dark texels keep half-float relative accuracy: max over a texel's
    samples of |rec - x| <= ~2 sqrt(3) 2^-11 ||x_t|| (texel_relative_bound).

    Precondition (see test_hdr_exr_bright_texels_overflow_half): every texel's norm stays
    below the half range 65504, so no coefficient can overflow.
    """
    x = hdr_btf()
    assert x.min() == pytest.approx(1e-4, rel=1e-6) and x.max() == pytest.approx(1e4, rel=1e-6)
    assert texel_norm(x).max() < 65504
    btf = ArrayBTF.from_linear(preset("tiny"), x)
    c = compress_into(btf, tmp_path / "c", CompressOptions(codec="exr"))
    assert c.k == 3                                   # the data's rank
    check_output_finite(tmp_path / "c")
    r = read_compressed(tmp_path / "c")
    rec = reconstruct(r)
    assert_within(rec, x, quant_bound(r) + float32_slack(x), "pixel bound B1 + B2")
    rel = np.abs(rec.astype(np.float64) - x).max(axis=(0, 3)) / texel_norm(x)
    assert (rel <= texel_relative_bound(r, x)).all(), rel.max()


def test_hdr_jxl_absolute_error_within_step_bound(tmp_path):
    """The default codec quantises every coefficient with ONE uniform step (README): on
    HDR input the error is bounded in absolute terms by the recorded step (B1 + B2), and
    at full rank ``ratedist.choose_for_k`` keeps the quantisation error 60 dB below the
    signal energy (allowed = 0.1 * 1e-6 of the total; asserted with that factor 10 spare).
    No relative bound for dark texels is documented (they may round to zero)."""
    x = hdr_btf()
    btf = ArrayBTF.from_linear(preset("tiny"), x)
    c = compress_into(btf, tmp_path / "c", CompressOptions())
    assert c.codec == "jxlp" and c.k == 3
    check_output_finite(tmp_path / "c")
    r = read_compressed(tmp_path / "c")
    step = r.info["choice"]["step"]
    assert all(np.all(np.asarray(s.scale) == step) for s in r.coefficients)
    rec = reconstruct(r).astype(np.float64)
    assert_within(rec, x, quant_bound(r) + float32_slack(x), "pixel bound B1 + B2")
    snr = 10 * np.log10((x.astype(np.float64) ** 2).sum() / ((rec - x) ** 2).sum())
    assert snr >= 60.0


def compress_within_bound_or_refuse(btf, x, folder, opts):
    """Compress; either the result is finite and within the pixel bound B1 + B2 of ``x``
    (returns it), or a BTFError was raised and nothing was left behind (returns None)."""
    try:
        c = compress_into(btf, folder, opts)
    except BTFError:
        assert not folder.exists() and no_leftovers(folder.parent, folder.name)
        return None
    check_output_finite(folder)
    r = read_compressed(folder)
    assert_within(reconstruct(r), x, quant_bound(r) + float32_slack(x), "pixel bound B1 + B2")
    return c


def test_hdr_exr_bright_texels_overflow_half(tmp_path):
    """HDR 1e-4..1e4 where the bright texels are bright in every sample (a diffuse light
    region).  Expected: no warning, finite output within B1 + B2 (or a clear BTFError)."""
    s = preset("tiny")
    x = np.full((len(s), 8, 8, 3), 1e4, np.float32)
    x[:, :4] = 1e-4
    c = compress_within_bound_or_refuse(ArrayBTF.from_linear(s, x), x, tmp_path / "c",
                                        CompressOptions(codec="exr", domain="linear"))   # B1 + B2: linear bounds
    assert c is None or c.k == 1


def test_hdr_dark_region_with_its_own_brdf(tmp_path):
    """Relative error bounded per texel (as in test_hdr_exr_error_relative_to_each_texel)
    when dark and bright texels have different BRDFs.  The dark region's lobe has sigma
    ~2e-8 sigma_1: an energy-weighted float32 fit drops it (k = 2, 11 % texel-relative
    error); the fit's HDR weights (||x_t||^-1/2 when texel norms span > 1e6) keep it."""
    x = hdr_btf(dark_own_brdf=True)
    assert x.min() == pytest.approx(1e-4, rel=1e-6) and x.max() == pytest.approx(1e4, rel=1e-6)
    btf = ArrayBTF.from_linear(preset("tiny"), x)
    compress_into(btf, tmp_path / "c", CompressOptions(codec="exr"))
    r = read_compressed(tmp_path / "c")
    rel = np.abs(reconstruct(r).astype(np.float64) - x).max(axis=(0, 3)) / texel_norm(x)
    assert (rel <= texel_relative_bound(r, x)).all(), f"k = {r.k}, worst texel-relative error {rel.max():.3g}"


@pytest.mark.parametrize("exponent", [
    -120,
    64,
])
def test_extreme_finite_magnitudes(tmp_path, exponent):
    """Finite float32 input scaled by 2^exponent (7.5e-37 / 1.8e19): the linear model is
    scale-free, so the result must be as good as at scale 1 (B1 + B2), without warnings,
    or a clear BTFError.  Inf must never be produced internally from finite input."""
    s = preset("tiny")
    x = (np.random.default_rng(0).uniform(0, 1, (len(s), 8, 8, 3)) * 2.0 ** exponent).astype(np.float32)
    compress_within_bound_or_refuse(ArrayBTF.from_linear(s, x), x, tmp_path / "c", CompressOptions())


# ---------------------------------------------------------------- rank-deficient data


def _rank_deficient(kind: str, n: int = 8):
    """(data, rank) for degenerate inputs on the tiny sampling."""
    S = 24
    rng = np.random.default_rng(3)
    x = np.zeros((S, n, n, 3))
    if kind == "identical-samples":
        x[:] = rng.uniform(0, 1, (n, n, 3))
        return x, 1
    if kind == "constant-images":
        x[:] = rng.uniform(0.1, 1, (S, 1, 1, 3))           # one colour per sample
        return x, 3
    if kind == "constant-everywhere":
        x[:] = 0.5
        return x, 1
    if kind == "one-lit-texel":
        x[:, n // 2, n // 2] = rng.uniform(0.1, 1, (S, 3))  # in the paper solver's central region
        return x, 3
    if kind == "one-lit-value":
        x[5, n // 2, n // 2 - 1, 1] = 0.7                   # a single nonzero in the whole BTF
        return x, 1
    raise ValueError(kind)


RANK_KINDS = ["identical-samples", "constant-images", "constant-everywhere", "one-lit-texel", "one-lit-value"]


@pytest.mark.parametrize("k", [1, 10, None], ids=["k=1", "k=10", "k=default"])
@pytest.mark.parametrize("solver,codec", [("rsvd", "jxl"), ("rsvd", "exr"), ("paper", "png")])
@pytest.mark.parametrize("kind", RANK_KINDS)
def test_rank_deficient_inputs(tmp_path, kind, solver, codec, k):
    """Degenerate data, k above the rank and k = 1: no NaN, no warning, k = min(k, rank),
    and the reconstruction is the best rank-k one up to storage rounding: exact within
    B1 + B2 when k >= rank, else within the Eckart-Young truncation error plus B1 + B2."""
    x, rank = _rank_deficient(kind)
    btf = ArrayBTF.from_linear(preset("tiny"), x)
    c = compress_into(btf, tmp_path / "c", CompressOptions(solver=solver, codec=codec, k=k))
    want = rank if k is None else min(k, rank)
    assert c.k == want
    check_output_finite(tmp_path / "c")
    r = read_compressed(tmp_path / "c")
    rec = reconstruct(r)
    assert np.isfinite(rec).all()
    bound = quant_bound(r) + float32_slack(x)
    if c.k >= rank:
        assert_within(rec, x, bound, kind)
    else:
        sv = np.linalg.svd(x.reshape(len(x), -1), compute_uv=False)
        optimum = np.sqrt((sv[c.k:] ** 2).sum())
        assert np.linalg.norm(rec - x) <= optimum * (1 + 1e-4) + np.linalg.norm(bound)


def test_paper_solver_signal_outside_region_message(tmp_path):
    """A lit texel outside the paper solver's central region: a clear error must not claim
    the BTF is all zero (or the compression must succeed with finite output)."""
    x = np.zeros((24, 8, 8, 3), np.float32)
    x[:, 0, 0] = np.random.default_rng(0).uniform(0.1, 1, (24, 3))
    btf = ArrayBTF.from_linear(preset("tiny"), x)
    try:
        compress_into(btf, tmp_path / "c", CompressOptions(solver="paper", codec="png"))
    except BTFError as exc:
        assert not (tmp_path / "c").exists()
        assert "every pixel is zero" not in str(exc), str(exc)
        return
    check_output_finite(tmp_path / "c")


def test_metadata_is_strict_json_for_exact_reconstructions(tmp_path):
    """A single nonzero value, paper solver, lossless png: the stored representation is
    exact (error 0).  The metadata must still be valid JSON (no NaN / Infinity)."""
    x, _ = _rank_deficient("one-lit-value")
    compress_into(ArrayBTF.from_linear(preset("tiny"), x), tmp_path / "c",
                       CompressOptions(solver="paper", codec="png", k=1))
    assert non_finite_json(tmp_path / "c" / "btf-compressed.json") == {}


# ---------------------------------------------------------------- float32 vs float64, accumulation order


def test_float64_input_is_rounded_once(tmp_path):
    """ArrayBTF.from_linear takes float64 data by rounding it to float32 once: both
    precisions of the same data give byte-identical folders."""
    s = preset("tiny")
    x64 = np.random.default_rng(1).uniform(0, 1, (len(s), 12, 12, 3))
    compress_into(ArrayBTF.from_linear(s, x64), tmp_path / "a", CompressOptions(k=6))
    compress_into(ArrayBTF.from_linear(s, x64.astype(np.float32)), tmp_path / "b", CompressOptions(k=6))
    assert differing(folder_files(tmp_path / "a"), folder_files(tmp_path / "b")) == []


@pytest.mark.parametrize("path", ["randomized-float32", "randomized-float64-input", "exact-float32-input"])
def test_basis_float32_vs_float64_reference(path):
    """Basis fit vs a float64 SVD of the same (float32-representable) matrix.

    Bound: the computed factorisation is that of X + E with ||E||_2 <= gamma_m ||X||_F,
    gamma_m = m 2^-24 / (1 - m 2^-24), m the longest GEMM inner dimension (every product
    is a float32 sum of <= m terms).  Weyl: |sigma_i - sigma_i*| <= ||E||_2.  Wedin: the
    i-th singular vector moves by sin(theta) <= ||E||_2 / gap_i, so with the signs fixed
    by the same convention ||u_i - u_i*|| <= sqrt(2) ||E||_2 / gap_i.  The data has rank
    12 <= k + oversample, so the randomized range finder is exact up to rounding.
    """
    rng = np.random.default_rng(5)
    S, m, r, k = 169, 768, 12, 8
    u0, _ = np.linalg.qr(rng.standard_normal((S, r)))
    v0, _ = np.linalg.qr(rng.standard_normal((m, r)))
    x32 = ((u0 * (10 * 0.7 ** np.arange(r))) @ v0.T).astype(np.float32)
    x64 = x32.astype(np.float64)
    ref_u, ref_s, _ = np.linalg.svd(x64, full_matrices=False)
    ref_u = ref_u[:, :k] * np.sign(ref_u[np.argmax(np.abs(ref_u[:, :k]), axis=0), np.arange(k)])
    if path == "randomized-float32":
        u, sv = randomized_basis(x32, k, seed=2)
    elif path == "randomized-float64-input":
        u, sv = randomized_basis(x64, k, seed=2)
    else:
        u, sv = exact_basis(x32, k)
    gamma = m * U32 / (1 - m * U32)
    e = gamma * np.linalg.norm(x64)
    assert u.dtype == np.float32 and u.shape == (S, k)
    assert np.all(np.abs(sv - ref_s[:k]) <= e)
    gaps = np.minimum(np.r_[np.inf, -np.diff(ref_s[:k])], -np.diff(ref_s[:k + 1]))
    assert np.all(np.linalg.norm(u.astype(np.float64) - ref_u, axis=0) <= np.sqrt(2) * e / gaps)


@pytest.fixture(scope="module")
def small_png(tmp_path_factory) -> Path:
    """169 samples of 20x20 pebbles as 8-bit sRGB PNG (integer decode path, colour matrix)."""
    s = preset("small")
    imgs = synth.render_all(synth.make_material("pebbles", 20, 1), s)
    return write_manifest(tmp_path_factory.mktemp("stab") / "small20", s, imgs, color_space=SRGB,
                          bit_depth="uint8", ext="png", array_space=LIN709)


@pytest.fixture
def small_tiles(monkeypatch):
    """Projection tiles of 64 samples (512 in production), so that the small samplings here
    span several tiles and chunks."""
    from usdbtf.compress import projection

    monkeypatch.setattr(projection, "_MAX_TILE_SAMPLES", 64)


@pytest.mark.parametrize("source", ["file-8bit", "array-float"])
def test_projection_is_within_dot_product_bound_and_independent_of_chunks(small_png, source, small_tiles):
    """U^T X in memory and streamed in chunks of 1, 2 and all projection tiles: each result
    is a float32 sum of S products, so within gamma_S |U|^T |X| of the exact (float64)
    product, gamma_S = S 2^-24 / (1 - S 2^-24); and all of them sum the same fixed tiles in
    the same order, so they are bit-identical.  A plane projected on fewer vectors (ks)
    gets the same leading coefficients within the bound (a narrower or planar GEMM may sum in
    another order) and zeros after."""
    file_btf = read_manifest(small_png)
    btf = file_btf if source == "file-8bit" else ArrayBTF.from_linear(file_btf.sampling, file_btf.read_samples(slice(None)))
    P, S = btf.n_pixels, btf.n_samples
    tile = tile_samples(btf)
    assert tile < S
    mem = InMemorySource(btf, workers=1)
    x = mem.columns(np.arange(P)).astype(np.float64)                       # (S, 3P), curve-decoded
    u, _ = randomized_basis(mem.columns(np.arange(P)), 10, seed=0)
    u64 = u.astype(np.float64)
    exact = (u64.T @ x).reshape(10, P, 3)
    gamma = S * U32 / (1 - S * U32)
    bound = gamma * (np.abs(u64).T @ np.abs(x)).reshape(10, P, 3)
    results = {"memory": mem.project(u, np.eye(3), (10, 10, 10))[0]}
    per_tile = tile * P * 3 * np.dtype(btf.read_encoded(0).dtype).itemsize
    for tiles in (1, 2, 1000):
        src = StreamingSource(btf, [np.arange(P)], [0], workers=1, chunk_bytes=tiles * per_tile)
        assert src.chunk == min(tiles, 1000) * tile
        results[f"streaming, {tiles} tile(s) per chunk"] = src.project(u, np.eye(3), (10, 10, 10))[0]
    for name, coeff in results.items():
        assert coeff.dtype == np.float32
        assert np.all(np.abs(coeff - exact) <= bound), name
        assert np.array_equal(coeff, results["memory"]), name
    fewer = mem.project(u, np.eye(3), (10, 4, 0))[0]
    assert np.all(np.abs(fewer[:, :, 0] - exact[:, :, 0]) <= bound[:, :, 0])
    assert np.all(np.abs(fewer[:4, :, 1] - exact[:4, :, 1]) <= bound[:4, :, 1])
    assert not fewer[4:, :, 1].any() and not fewer[:, :, 2].any()


@pytest.fixture(scope="module")
def png_72(tmp_path_factory) -> Path:
    """169 samples of 72x72 pebbles as 8-bit sRGB PNG: 5184 texels, more than a budget's
    4096-texel fitting sample (so the budget modes fit the basis on every texel)."""
    s = preset("small")
    imgs = synth.render_all(synth.make_material("pebbles", 72, 3), s)
    return write_manifest(tmp_path_factory.mktemp("stab72") / "png72", s, imgs, color_space=SRGB,
                          bit_depth="uint8", ext="png", array_space=LIN709)


def test_streamed_fit_is_the_full_fit_from_any_source(png_72, small_tiles):
    """A budget's fit over every texel (fit.streamed_fit: passes over the rows, in cuts of
    texels) in the sRGB domain: bit-identical in memory and streamed in chunks of one tile,
    of all tiles and without a spill file; and, within float32 rounding, the randomized SVD of
    the whole data matrix held at once (the same seeded sketch): the same singular values, the
    same vectors, and the same coefficients of the fitting sample (its B = R Z^T)."""
    from usdbtf.compress.domain import parse_domain
    from usdbtf.compress.fit import fit_basis, fits_every_texel, streamed_fit
    from usdbtf.compress.texels import sample_texels

    btf = read_manifest(png_72)
    P = btf.n_pixels
    opts = CompressOptions(max_bytes=10**6, seed=2, fit_every_texel=True)
    texels = sample_texels(btf, opts)
    assert len(texels.fit) == 4096 < P
    tile = tile_samples(btf)
    assert tile < btf.n_samples
    per_tile = tile * P * 3
    sources = {"memory": InMemorySource(btf, workers=1)}
    for name, kw in {"one tile": dict(chunk_bytes=per_tile), "all": dict(chunk_bytes=1e12),
                     "no spill": dict(chunk_bytes=per_tile, spill=False)}.items():
        sources[name] = StreamingSource(btf, [texels.fit], [0], workers=1, **kw)
    fits = {}
    for name, src in sources.items():
        src.set_domain(parse_domain("srgb"))
        assert fits_every_texel(src, texels.fit, opts)
        fits[name] = streamed_fit(src, texels.fit, 40, opts)
        src.close()
    ref = fits["memory"]
    assert ref.k == 40 and ref.coefficients.shape == (40, 3 * len(texels.fit)) and not ref.weighted
    for name, fit in fits.items():
        assert np.array_equal(fit.basis, ref.basis) and np.array_equal(fit.singular_values, ref.singular_values), name
        assert np.array_equal(fit.coefficients, ref.coefficients), name
    whole = InMemorySource(btf, workers=1)
    whole.set_domain(parse_domain("srgb"))
    x = whole.columns(np.arange(P))
    full = fit_basis(x, 40, opts)
    np.testing.assert_allclose(ref.singular_values, full.singular_values, rtol=1e-5)
    dots = np.abs(np.einsum("sk,sk->k", ref.basis.astype(np.float64), full.basis))
    assert dots.min() > 1 - 1e-5, dots
    cols = (3 * texels.fit[:, None] + np.arange(3)).ravel()
    # The fit's coefficients are its B = R Z^T (not an exact U^T X on the trailing vectors):
    # the held-at-once fit's, on the sample's columns.
    err = np.abs(ref.coefficients - full.coefficients[:, cols])
    assert err.max() <= 1e-4 * np.abs(full.coefficients).max(), err.max(axis=1)
    # Under a plain k, or with --fit-texels, the sample is fitted as before.
    assert not fits_every_texel(whole, texels.fit, CompressOptions(k=40))
    assert not fits_every_texel(whole, texels.fit, CompressOptions(max_bytes=10**6, fit_texels=4096))
    assert not fits_every_texel(whole, texels.fit, CompressOptions(max_bytes=10**6, fit_every_texel=False))
    assert fits_every_texel(whole, texels.fit, CompressOptions(max_bytes=10**6))   # the budget modes' default


def test_streamed_fit_weights_hdr_texels_as_the_full_fit():
    """An HDR input whose texel norms span more than HDR_NORM_RANGE (a 1e-8 dark half): the
    fit over every texel weighs the texels as :func:`.fit.fit_basis` on all their columns
    does (the norms measured in its first pass), and finds the same basis."""
    from usdbtf.compress.fit import fit_basis, streamed_fit
    from usdbtf.compress.texels import sample_texels

    s = preset("tiny")
    x = synth.render_all(synth.make_material("pebbles", 72, 4), s)
    x[:, :36] *= 1e-8
    btf = ArrayBTF.from_linear(s, x)
    opts = CompressOptions(max_bytes=10**6, fit_every_texel=True)
    texels = sample_texels(btf, opts)
    src = InMemorySource(btf, workers=1)
    fit = streamed_fit(src, texels.fit, 12, opts)
    full = fit_basis(src.columns(np.arange(btf.n_pixels)), 12, opts)
    assert fit.weighted and full.weighted
    np.testing.assert_allclose(fit.singular_values, full.singular_values, rtol=1e-5)
    assert np.abs(np.einsum("sk,sk->k", fit.basis.astype(np.float64), full.basis)).min() > 1 - 1e-5


# ---------------------------------------------------------------- sign / order convention, determinism


@pytest.mark.parametrize("solver,codec", [("rsvd", "jxl"), ("rsvd", "exr"), ("paper", "png")])
def test_stored_basis_follows_sign_and_order_convention(tmp_path, solver, codec):
    """Singular values are recorded in decreasing order; every stored basis vector has its
    largest-magnitude entry positive (fix_signs) up to one rounding of the storage
    (quantisation is monotone, so the order of |entries| survives it within a step)."""
    btf = pebbles("tiny", 16)
    c = compress_into(btf, tmp_path / "c", CompressOptions(solver=solver, codec=codec, k=8))
    sv = np.asarray(c.info["singular_values"])
    assert np.all(np.diff(sv) <= 0) and len(sv) >= c.k
    b = read_compressed(tmp_path / "c").basis_values().astype(np.float64)
    tol = 2 * U16 * np.abs(b).max(axis=0) if codec == "exr" else np.asarray(c.basis.scale, np.float64)[:c.k]
    assert np.all(b.max(axis=0) >= -b.min(axis=0) - tol)


def test_sign_convention_is_independent_of_equivalent_inputs(tmp_path):
    """The basis depends only on X X^T, and its signs only on the convention: mirroring the
    image (a permutation of texels), scaling by 2, and the paper solver's exact SVD (region
    = the whole image) all give the same basis vectors, not sign-flipped ones."""
    s = preset("tiny")
    rng = np.random.default_rng(2)
    a = rng.uniform(0.1, 1.0, (len(s), 4)) * np.array([8.0, 4.0, 2.0, 1.0])
    x = (a @ rng.uniform(0, 1, (4, 16 * 16 * 3))).reshape(len(s), 16, 16, 3).astype(np.float32)
    runs = {
        "plain": (x, CompressOptions(k=4, codec="exr")),
        "mirrored": (x[:, :, ::-1].copy(), CompressOptions(k=4, codec="exr")),
        "doubled": (2 * x, CompressOptions(k=4, codec="exr")),
        "paper": (x, CompressOptions(solver="paper", k=4, codec="exr", region=16)),
    }
    bases = {}
    for name, (data, opts) in runs.items():
        compress_into(ArrayBTF.from_linear(s, data), tmp_path / name, opts)
        bases[name] = read_compressed(tmp_path / name).basis_values().astype(np.float64)
    for name, b in bases.items():
        # Half precision on both sides plus the float32 fit: well inside 2^-9 per entry.
        np.testing.assert_allclose(b, bases["plain"], rtol=0, atol=2.0 ** -9, err_msg=name)


def _det_configs():
    # EXR/TIFF headers carry a DateTime: imageio.write_image writes a fixed one.
    return [("rsvd", "jxl", {}), ("rsvd", "png", {}), ("rsvd", "jxl", {"memory_budget": 0}),
            ("rsvd", "exr", {}), ("paper", "jpeg", {}), ("paper", "png", {})]


@pytest.fixture(scope="module")
def two_runs(small_png, tmp_path_factory):
    """Every configuration of _det_configs compressed twice, the second batch started in a
    later wall-clock second than the first ended."""
    btf = read_manifest(small_png)
    root = tmp_path_factory.mktemp("runs")
    configs = [("rsvd", "jxl", {}), ("rsvd", "png", {}), ("rsvd", "jxl", {"memory_budget": 0}),
               ("rsvd", "exr", {}), ("paper", "jpeg", {}), ("paper", "png", {})]
    out = {}
    for batch in ("a", "b"):
        for n, (solver, codec, kw) in enumerate(configs):
            folder = root / f"{batch}{n}"
            compress_into(btf, folder, CompressOptions(solver=solver, codec=codec, k=8, seed=5, **kw))
            out.setdefault((solver, codec, tuple(kw.items())), []).append(folder_files(folder))
        time.sleep(1.05 - time.time() % 1.0)
    return out


@pytest.mark.parametrize("solver,codec,kw", _det_configs())
def test_two_runs_byte_identical(two_runs, solver, codec, kw):
    """README: the same inputs and seed give byte-identical output folders (signs fixed by
    the convention, seeded sampling, no timings in the files)."""
    a, b = two_runs[(solver, codec, tuple(kw.items()))]
    assert differing(a, b) == []


@pytest.mark.parametrize("codec", ["jxl", "exr"])
def test_chunk_sizes_do_not_change_output(tmp_path, fixed_exr_dates, codec, small_tiles):
    """In memory, and streamed in chunks of one projection tile, of two tiles and of all
    samples: byte-identical folders at full k (fine quantisation), metadata included (how
    the data was read is not recorded: it changes nothing)."""
    s = _sampling_312()
    btf = ArrayBTF.from_linear(s, synth.render_all(synth.make_material("pebbles", 8, 0), s))
    tile = tile_samples(btf)
    assert tile < len(s), "the sampling must span several projection tiles"
    per_sample = btf.n_pixels * 3 * 4
    runs = {"mem": {}, "one": {"memory_budget": 0, "chunk_bytes": tile * per_sample},
            "two": {"memory_budget": 0, "chunk_bytes": 2 * tile * per_sample},
            "all": {"memory_budget": 0, "chunk_bytes": 1e12}}
    outs = {}
    for name, kw in runs.items():
        compress_into(btf, tmp_path / name, CompressOptions(codec=codec, **kw))
        outs[name] = folder_files(tmp_path / name)
    assert {name: differing(outs["mem"], f) for name, f in outs.items() if name != "mem"} == \
        {"one": [], "two": [], "all": []}


@pytest.mark.parametrize("options", [[], ["--max-bytes", "40000", "--budget-for", "folder"], ["--solver", "paper", "--k", "12"]],
                         ids=["plain", "max-bytes", "paper"])
def test_output_does_not_depend_on_blas_threads(small_png, tmp_path, options):
    """compress runs BLAS on one thread and parallelises by itself (usdbtf.compress.parallel):
    the same folder with 1, 2 and 4 BLAS threads (OpenBLAS alone rounds some products
    differently on one thread than on several)."""
    import os
    import subprocess
    import sys

    outs = {}
    for n in ("1", "2", "4"):
        env = dict(os.environ, OPENBLAS_NUM_THREADS=n, OMP_NUM_THREADS=n)
        proc = subprocess.run([sys.executable, "-m", "usdbtf.cli", "compress", str(small_png), "-o",
                               str(tmp_path / n), "-q", *options], capture_output=True, text=True, env=env)
        assert proc.returncode == 0, proc.stderr
        outs[n] = folder_files(tmp_path / n)
    assert outs["1"] == outs["2"] == outs["4"]


def _sampling_312():
    """13 views x 24 lights: several projection tiles (of 64 samples, :func:`small_tiles`)."""
    return cross(rings((0, 30, 60), (1, 6, 6)), rings((15, 45, 75), (8, 8, 8)))


@pytest.mark.parametrize("codec", ["jxl", "exr"])
@pytest.mark.parametrize("sampling", [
    "small",
    "312",
])
def test_streaming_matches_in_memory_byte_for_byte(tmp_path, fixed_exr_dates, sampling, codec):
    """memory_budget=0 (streamed: spilled once, or decoded twice) vs in memory, at full k:
    byte-identical folders, metadata included."""
    s = preset("small") if sampling == "small" else _sampling_312()
    size = 16 if sampling == "small" else 8
    btf = ArrayBTF.from_linear(s, synth.render_all(synth.make_material("pebbles", size, 0), s))
    compress_into(btf, tmp_path / "mem", CompressOptions(codec=codec))
    compress_into(btf, tmp_path / "str", CompressOptions(codec=codec, memory_budget=0))
    compress_into(btf, tmp_path / "twice", CompressOptions(codec=codec, memory_budget=0, spill=False))
    mem = folder_files(tmp_path / "mem")
    assert differing(mem, folder_files(tmp_path / "str")) == differing(mem, folder_files(tmp_path / "twice")) == []


# ---------------------------------------------------------------- NaN / Inf / negative pixels

BAD_VALUES = {"nan": np.nan, "+inf": np.inf, "-inf": -np.inf, "negative": -1e-3}
BAD_SAMPLE, BAD_PIXEL = 13, (3, 5, 1)


@pytest.fixture(scope="module", params=["float", "half"])
def exr_manifest(request, tmp_path_factory) -> Path:
    """A clean 24-sample 8x8 EXR manifest (float or half)."""
    s = preset("tiny")
    x = np.random.default_rng(4).uniform(0.05, 1, (len(s), 8, 8, 3))
    return write_manifest(tmp_path_factory.mktemp(f"exr_{request.param}") / "m", s, x, color_space=LIN709,
                          bit_depth=request.param, ext="exr", array_space=LIN709)


def _poison(src: Path, dst: Path, value: float) -> str:
    """Copy the manifest; rewrite one sample through OpenImageIO with one bad value.
    Returns the bad file's name."""
    shutil.copytree(src, dst)
    name = json.loads((dst / "btf.json").read_text())["samples"][BAD_SAMPLE]["image"]
    path = str(dst / name)
    inp = oiio.ImageInput.open(path)
    spec = inp.spec()
    px = inp.read_image(0, 0, 0, 3, spec.format)
    inp.close()
    px = np.array(px)
    px[BAD_PIXEL] = value
    out = oiio.ImageOutput.create(path)
    assert out.open(path, oiio.ImageSpec(spec.width, spec.height, 3, spec.format))
    assert out.write_image(px)
    out.close()
    back = oiio.ImageInput.open(path)
    got = np.array(back.read_image(0, 0, 0, 3, spec.format))[BAD_PIXEL]
    back.close()
    assert np.array_equal(got, np.asarray(value, px.dtype), equal_nan=True)
    return name


@pytest.mark.parametrize("budget", [1e9, 0], ids=["in-memory", "streaming"])
@pytest.mark.parametrize("bad", BAD_VALUES)
def test_bad_pixel_in_file_is_rejected(exr_manifest, tmp_path, bad, budget):
    """A NaN, +-Inf or negative value in one EXR sample file: BTFError naming that file,
    nothing written (no output folder, no temporary leftovers)."""
    name = _poison(exr_manifest, tmp_path / "in", BAD_VALUES[bad])
    btf = read_manifest(tmp_path / "in")
    parent = tmp_path / "outs"
    parent.mkdir()
    with pytest.raises(BTFError, match="negative" if bad == "negative" else "NaN or Inf") as exc:
        compress_into(btf, parent / "c", CompressOptions(k=4, memory_budget=budget))
    assert name in str(exc.value)
    assert list(parent.iterdir()) == []


@pytest.mark.parametrize("bad", BAD_VALUES)
def test_bad_pixel_in_memory_is_rejected(bad):
    """ArrayBTF.from_linear refuses the same values before anything is computed."""
    x = np.full((24, 8, 8, 3), 0.5, np.float32)
    x[(BAD_SAMPLE,) + BAD_PIXEL] = BAD_VALUES[bad]
    with pytest.raises(BTFError, match="negative" if bad == "negative" else "NaN or Inf"):
        ArrayBTF.from_linear(preset("tiny"), x)


@pytest.mark.parametrize("entry", ["from_linear", "compress"])
def test_bad_pixel_in_memory_error_names_the_sample(tmp_path, entry):
    """The in-memory error names the sample (``names`` default "#13") like the file error
    names the file."""
    x = np.full((24, 8, 8, 3), 0.5, np.float32)
    x[(BAD_SAMPLE,) + BAD_PIXEL] = np.nan
    s = preset("tiny")
    with pytest.raises(BTFError) as exc:
        if entry == "from_linear":
            ArrayBTF.from_linear(s, x)
        else:   # an ArrayBTF built directly: the check happens while compressing
            btf = ArrayBTF(sampling=s, width=8, height=8, color_space=color.WORKING_SPACE, bit_depth="float", data=x)
            compress_into(btf, tmp_path / "c", CompressOptions(k=2))
    assert not (tmp_path / "c").exists()
    assert f"#{BAD_SAMPLE}" in str(exc.value), str(exc.value)


# ---------------------------------------------------------------- property-based round trips


@st.composite
def small_btfs(draw):
    """(S, H, W, 3) float32 >= 0: S in [3, 24], H, W in [2, 12], one of several value
    distributions (dense, low rank, sparse, heavy-tailed, constant), max 2^-8 .. 2^4."""
    S = draw(st.integers(3, 24))
    H = draw(st.integers(2, 12))
    W = draw(st.integers(2, 12))
    kind = draw(st.sampled_from(["uniform", "low-rank", "sparse", "lognormal", "constant"]))
    top = 2.0 ** draw(st.integers(-8, 4))
    rng = np.random.default_rng(draw(st.integers(0, 2 ** 32 - 1)))
    shape = (S, H, W, 3)
    if kind == "uniform":
        x = rng.uniform(0, 1, shape)
    elif kind == "low-rank":
        r = draw(st.integers(1, 4))
        x = (rng.uniform(0, 1, (S, r)) @ rng.uniform(0, 1, (r, H * W * 3))).reshape(shape)
    elif kind == "sparse":
        x = rng.uniform(0, 1, shape) * (rng.uniform(0, 1, shape) < draw(st.sampled_from([0.01, 0.1, 0.5])))
    elif kind == "lognormal":
        x = rng.lognormal(0, 2, shape)
    else:
        x = np.full(shape, rng.uniform(0.1, 1))
    if x.max() > 0:
        x = x / x.max() * top
    return x.astype(np.float32)


PROPERTY = settings(max_examples=25, deadline=None, database=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


def _round_trip(x, codec, folder: Path):
    btf = ArrayBTF.from_linear(sampling_of(len(x)), x)
    full_k = min(x.shape[0], 3 * x.shape[1] * x.shape[2])
    if not x.any():
        with pytest.raises(BTFError, match="every pixel is zero"):
            compress_into(btf, folder, CompressOptions(codec=codec, k=full_k, domain="linear"))
        assert not folder.exists() and no_leftovers(folder.parent, folder.name)
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        # The quantisers' bounds are on the linear values (a curve's inverse would stretch them).
        c = compress_into(btf, folder, CompressOptions(codec=codec, k=full_k, domain="linear"))
    assert 1 <= c.k <= full_k
    check_output_finite(folder)
    r = read_compressed(folder)
    rec = reconstruct(r)
    assert rec.shape == x.shape and np.isfinite(rec).all()
    assert_within(rec, x, quant_bound(r) + float32_slack(x), f"{codec} round trip B1 + B2")
    return r, rec


@PROPERTY
@given(x=small_btfs())
def test_property_full_k_exr_round_trip_is_half_precision(tmp_path_factory, x):
    """reconstruct(compress(x)) with full k and codec exr equals x within half-float
    rounding of basis and coefficients (B1 with the half rules) plus float32 (B2)."""
    _round_trip(x, "exr", tmp_path_factory.mktemp("exr") / "c")


@PROPERTY
@given(x=small_btfs())
def test_property_full_k_jxl_round_trip_within_recorded_step(tmp_path_factory, x):
    """Default codec at full k: error within the bound implied by the recorded step
    (coefficients: scale == choice.step, |error| <= step / 2; basis: recorded scale / 2),
    and 60 dB below the signal (ratedist.choose_for_k's floor, with a factor 10 spare)."""
    out = _round_trip(x, "jxl", tmp_path_factory.mktemp("jxl") / "c")
    if out is None:
        return
    r, rec = out
    step = r.info["choice"]["step"]
    assert all(np.all(np.asarray(s.scale) == step) for s in r.coefficients)
    err2 = ((rec.astype(np.float64) - x) ** 2).sum()
    assert err2 <= 1e-6 * (x.astype(np.float64) ** 2).sum()


def test_no_metadata_bloat_in_compact_codecs(tmp_path):
    """The fixed timestamp that keeps EXR/TIFF deterministic must not add an EXIF block to
    JPEG / JPEG XL / PNG textures (it would inflate every stored byte count)."""
    from usdbtf.imageio import write_image
    px = np.random.default_rng(1).integers(0, 255, (32, 32, 3)).astype(np.uint8)
    for ext in ("jpg", "jxl", "png"):
        size = write_image(tmp_path / f"a.{ext}", px, color_space="data")
        spec = oiio.ImageInput.open(str(tmp_path / f"a.{ext}")).spec()
        assert spec.get_string_attribute("DateTime", "") == "", ext
        plain = tmp_path / f"plain.{ext}"           # the same pixels, OIIO with no extra attributes
        out = oiio.ImageOutput.create(str(plain))
        out.open(str(plain), oiio.ImageSpec(32, 32, 3, "uint8"))
        out.write_image(px)
        out.close()
        assert size <= plain.stat().st_size + 64, (ext, size, plain.stat().st_size)
