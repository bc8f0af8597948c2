"""Transcoding a UBO2014 DFMF file from its factors (usdbtf.compress.factored, issue 18 part 2).

The files are written by ``tests/bonn_btf_writer.py`` (no usdbtf code) from a synthetic BTF's
own factorisation: pebbles rendered over 13 views x 13 lights, in colour model 11 (UBO2014's
log Y, U/Y, V/Y: a nonlinear decode, coefficients solved on sampled rows) and model 0 (RGB:
a linear decode, basis and coefficients exact from the factors).  The evidence:

* ``usdbtf compress F.btf`` (from the factors) then ``decompress`` matches the file's own
  images, as the reader expands them, within 1.5 x the error of ``--expand-factors`` at the
  same k, sample matched to sample by direction;
* a file whose direction table mislabels two lights fails that check by far;
* the algebra is exact where it claims to be (basis, coefficients, energy against numpy on
  the expanded data), and the sampled solve is exact with every row.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import bonn_btf_writer as w
from cli_helpers import bad_usage, ok
from compress_helpers import compress_into
from usdbtf import color, synth
from usdbtf.compress import CompressOptions, compress, load_source, sample_texels
from usdbtf.compress.factor_algebra import FactorFrame, exact_coefficients, exact_fit, linear_decode
from usdbtf.compress.factored import FactoredSource, uses_factors
from usdbtf.compress.format import reconstruct
from usdbtf.compress.row_sampling import leverage_rows, solve_operators
from usdbtf.imageio import read_image
from usdbtf.sampling import cross, rings
from usdbtf.ubo2014 import read_ubo2014

VIEWS_DEG = rings((0, 30, 60), (1, 6, 6))
LIGHTS_DEG = rings((0, 30, 60), (1, 6, 6), phi_offset=30.0)
W, H = 24, 16                       # not square: a transposed texel order would show
S, T = len(VIEWS_DEG) * len(LIGHTS_DEG), W * H
KS = (12, 4, 4)                     # the file's components (Y, U/Y, V/Y), UBO2014's 3:1:1
K = 6                               # compress's
GEOM = dict(views_rad=np.radians(VIEWS_DEG), lights_rad=np.radians(LIGHTS_DEG), width=W, height=H)


@pytest.fixture(scope="module")
def pebbles() -> np.ndarray:
    """(S, T, 3) float64 linear RGB: pebbles over the 13 x 13 directions, cropped to W x H,
    with a small floor (measured BTFs have no exact zeros; log Y of a zero is -11.5)."""
    img = synth.render_all(synth.make_material("pebbles", W, 3), cross(VIEWS_DEG, LIGHTS_DEG))
    return img[:, :H, :W].astype(np.float64).reshape(S, T, 3) + 0.01


def dfmf(path: Path, rgb: np.ndarray, model: int, **kw) -> Path:
    """The writer's DFMF of ``rgb`` in colour ``model`` (11 or 0): a truncated SVD per channel."""
    values = w.rgb_to_model11(rgb) if model == 11 else rgb
    chans = [w.factorise(values[..., c], k) for c, k in zip(range(3), KS)]
    return w.dfmf_file(path, chans, model=model, **{**GEOM, **kw})


def per_sample_rmse(original: Path, decompressed: Path) -> np.ndarray:
    """(S,) RMSE (working space) of ``usdbtf decompress``'s images against the original file's
    own, per original sample, matched by (view, light) direction as ``usdbtf error`` matches
    them.  The float files are read directly: a reconstruction may dip below zero, which
    usdbtf's BTF readers refuse as input (so ``usdbtf error`` cannot read them)."""
    orig = read_ubo2014(original)
    key = {tuple(np.round(np.r_[v, l], 3)): i for i, (v, l) in enumerate(zip(orig.sampling.view, orig.sampling.light))}
    manifest = json.loads((decompressed / "btf.json").read_text())
    to_working = color.processor(manifest["color_space"], orig.working_space)
    truth = orig.read_samples(slice(None))
    out = np.full(orig.n_samples, np.nan)
    for entry in manifest["samples"]:
        i = key[tuple(np.round(np.r_[entry["view"], entry["light"]], 3))]
        pixels, _ = read_image(decompressed / entry["image"])
        out[i] = np.sqrt(np.mean((to_working.apply(pixels) - truth[i]).astype(np.float64) ** 2))
    assert np.isfinite(out).all()          # every sample reconstructed once
    return out


def rmse(original: Path, decompressed: Path) -> float:
    """RMSE over every sample (see :func:`per_sample_rmse`)."""
    return float(np.sqrt(np.mean(per_sample_rmse(original, decompressed) ** 2)))


def reconstruction_rmse(result, truth: np.ndarray) -> float:
    """RMSE of ``result`` decoded (all samples, working space) against ``truth`` (S, H, W, 3)."""
    rec = np.stack(list(reconstruct(result, np.arange(len(truth)))))
    return float(np.sqrt(np.mean((rec - truth) ** 2)))


def metadata(folder: Path) -> dict:
    return json.loads((folder / "btf-compressed.json").read_text())


# --------------------------------------------------------------------------- the CLI, end to end


@pytest.mark.parametrize("model", [11, 0])
def test_transcoded_matches_the_files_images_by_direction(tmp_path, capsys, pebbles, model):
    path = dfmf(tmp_path / f"pebbles{model}.btf", pebbles, model)
    out = ok(capsys, "info", path)
    assert "13 views x 13 lights = 169 samples of 24x16 texels (signature !DFMF08FCR)" in out
    assert "channel 0: 12, channel 1: 4, channel 2: 4  (half floats)" in out
    errors = {}
    for name, extra in (("factors", ()), ("expanded", ("--expand-factors",))):
        ok(capsys, "compress", path, "-o", tmp_path / name, "--k", K, "-q", *extra)
        ok(capsys, "decompress", tmp_path / name, "-o", tmp_path / f"{name}-images", "-q")
        errors[name] = rmse(path, tmp_path / f"{name}-images")
    assert errors["factors"] <= 1.5 * errors["expanded"], errors
    assert errors["factors"] < 0.15 * np.sqrt(np.mean(pebbles**2))      # and a good reconstruction
    made = metadata(tmp_path / "factors")["provenance"]
    assert made["transcoded"]["from"] == "factors" and made["transcoded"]["color_model"] == model
    assert made["transcoded"]["components"] == list(KS)
    assert made["transcoded"]["decode"] == ("nonlinear" if model == 11 else "linear")
    assert made["transcoded"]["basis"].startswith("rsvd fit" if model == 11 else "exact SVD")
    expanded = metadata(tmp_path / "expanded")["provenance"]
    assert "transcoded" not in expanded and expanded["options"]["expand_factors"] is True


def test_mislabelled_direction_fails_the_check(tmp_path, capsys, pebbles):
    """Two lights swapped in the direction table (the data as before): every sample under
    either light now carries the other's image, and the comparison by direction blows past
    1.5 x the honest error."""
    good = dfmf(tmp_path / "good.btf", pebbles, 11)
    lights = np.radians(LIGHTS_DEG)
    a, b = 1, 10                                   # (30, 30) and (60, 300) deg: far apart
    lights[[a, b]] = lights[[b, a]]
    bad = dfmf(tmp_path / "bad.btf", pebbles, 11, lights_rad=lights)
    for name, path in (("good", good), ("bad", bad)):
        ok(capsys, "compress", path, "-o", tmp_path / name, "--k", K, "-q")
        ok(capsys, "decompress", tmp_path / name, "-o", tmp_path / f"{name}-images", "-q")
    ok(capsys, "compress", good, "-o", tmp_path / "expanded", "--k", K, "-q", "--expand-factors")
    ok(capsys, "decompress", tmp_path / "expanded", "-o", tmp_path / "expanded-images", "-q")
    honest = per_sample_rmse(good, tmp_path / "expanded-images")
    good_err = per_sample_rmse(good, tmp_path / "good-images")
    bad_err = per_sample_rmse(good, tmp_path / "bad-images")
    total = lambda e: float(np.sqrt(np.mean(e ** 2)))            # noqa: E731
    assert total(good_err) <= 1.5 * total(honest)
    assert total(bad_err) > 2 * total(honest)                     # the check fails, over all samples
    swapped = np.isin(np.arange(S) % len(LIGHTS_DEG), [a, b])     # the samples under the two lights
    assert total(bad_err[swapped]) > 5 * total(honest[swapped])   # and by far on those mislabelled
    np.testing.assert_allclose(bad_err[~swapped], good_err[~swapped], rtol=1e-6)   # only labels moved


# --------------------------------------------------------------------------- the algebra


def expanded_unclamped(btf) -> np.ndarray:
    """(S, 3 T) float64 working-space data matrix of the factor product without the clamp."""
    f = btf.factors
    planes = np.stack([f.float32(c, "samples").astype(np.float64) @ f.float32(c, "texels").astype(np.float64).T
                       for c in range(3)]).astype(np.float32)
    rgb = btf.channels_to_rgb(planes, np.arange(btf.n_samples), clamp=False)
    lin = linear_decode(btf)
    return (np.einsum("ij,jst->sti", lin.to_working, rgb.astype(np.float64)) + lin.working_offset).reshape(S, -1)


@pytest.mark.parametrize("model, cosine", [(0, 0), (3, 1), (1, 0), (4, 1)])
def test_linear_models_exact_basis_and_coefficients(tmp_path, pebbles, model, cosine):
    """Models 0, 1, 3 (a matrix and a mean: an offset channel), 4, with and without the
    cosine flag (a scale per sample): the basis is the top-k SVD of the expanded product and
    the coefficients its projection, to float32 rounding."""
    rng = np.random.default_rng(model)
    chans = [w.factorise(pebbles[..., c], k) for c, k in zip(range(3), KS)]
    path = w.dfmf_file(tmp_path / "lin.btf", chans, model=model, cosine_flag=cosine,
                       mean=rng.random(3), matrix=np.eye(3) + 0.1 * rng.random((3, 3)), **GEOM)
    btf = read_ubo2014(path)
    lin = linear_decode(btf)
    assert lin is not None and lin.mix.shape[1] == (4 if model == 3 else 3)
    x = expanded_unclamped(btf)
    u_ref, sv_ref, _ = np.linalg.svd(x, full_matrices=False)
    frame = FactorFrame(lin)
    fit = exact_fit(frame, K, T, np.arange(0, T, 7))
    np.testing.assert_allclose(fit.singular_values, sv_ref[:K], rtol=1e-6)
    np.testing.assert_allclose(np.abs(fit.basis.T @ u_ref[:, :K]), np.eye(K), atol=1e-4)
    mix = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    coeff, energy = exact_coefficients(frame, fit.basis, mix, (K, 3, 0), n_texels=T, energy=True)
    y = (x.reshape(S, T, 3) @ mix.T)
    want = np.einsum("sk,stj->ktj", fit.basis.astype(np.float64), y)
    scale = np.abs(want).max()
    np.testing.assert_allclose(coeff[:, :, 0], want[:, :, 0], atol=1e-5 * scale)
    np.testing.assert_allclose(coeff[:3, :, 1], want[:3, :, 1], atol=1e-5 * scale)
    assert not coeff[3:, :, 1].any() and not coeff[:, :, 2].any()
    assert energy == pytest.approx(float(np.sum(y * y)), rel=1e-6)
    fitted = fit.coefficients.reshape(K, -1, 3)
    np.testing.assert_allclose(fitted, np.einsum("sk,stj->ktj", fit.basis, x.reshape(S, T, 3)[:, ::7]),
                               atol=1e-5 * scale)


@pytest.mark.parametrize("model, drr", [(11, 0), (9, 0), (12, 0), (0, 1)])
def test_nonlinear_decodes_are_detected(tmp_path, pebbles, model, drr):
    """Logarithmic colour models and FMF's dynamic-range restore are not linear: the probe
    must see it (the sampled solve then runs on the reader's own values)."""
    if drr:
        flat = np.log(pebbles + w.EPS).transpose(0, 2, 1).reshape(S * 3, T)      # rows c + 3 s
        path = w.fmf_file(tmp_path / "f.btf", *w.factorise(flat, 12), drr=1, **GEOM)
    else:   # model 11's factors, relabelled: any finite channel values decode
        path = dfmf(tmp_path / "n.btf", pebbles, 11)
        data = bytearray(path.read_bytes())
        marker = data.index(b"\x0b\x00\x00\x00", len(b"!DFMF08FCR"))   # the int32 colour model 11
        data[marker:marker + 4] = model.to_bytes(4, "little")
        path.write_bytes(bytes(data))
    btf = read_ubo2014(path)
    assert uses_factors(btf, CompressOptions())
    assert linear_decode(btf) is None
    assert not uses_factors(btf, CompressOptions(expand_factors=True))


def test_sampled_solve_with_every_row_is_the_projection(tmp_path, pebbles):
    btf = read_ubo2014(dfmf(tmp_path / "m.btf", pebbles, 11))
    opts = CompressOptions(k=K, factor_rows=S)
    src = load_source(btf, sample_texels(btf, opts), opts)
    assert isinstance(src, FactoredSource) and src.linear is None
    truth = btf.read_samples(slice(None)).reshape(S, T, 3)
    u = np.linalg.qr(np.random.default_rng(0).standard_normal((S, K)))[0].astype(np.float32)
    coeff, energy = src.project(u, np.eye(3), (K, K, 2), energy=True)
    want = np.einsum("sk,stj->ktj", u.astype(np.float64), truth)
    np.testing.assert_allclose(coeff[:, :, :2], want[:, :, :2], atol=2e-5 * np.abs(want).max())
    np.testing.assert_allclose(coeff[:2, :, 2], want[:2, :, 2], atol=2e-5 * np.abs(want).max())
    assert energy == pytest.approx(float(np.sum(truth.astype(np.float64) ** 2)), rel=1e-5)
    # The columns and sample images the source hands out are the reader's.
    cols = src.columns(np.array([0, 5, 6, T - 1]))
    np.testing.assert_allclose(cols.reshape(S, 4, 3), truth[:, [0, 5, 6, T - 1]], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(src.working_samples([3, 100]), truth[[3, 100]], rtol=1e-5, atol=1e-7)


def test_leverage_rows_deterministic_and_weighted():
    u = np.linalg.qr(np.random.default_rng(1).standard_normal((500, 8)))[0]
    rows, weights = leverage_rows(u, 64, seed=3)
    again = leverage_rows(u, 64, seed=3)
    np.testing.assert_array_equal(rows, again[0])
    np.testing.assert_array_equal(weights, again[1])
    assert len(rows) <= 64 and np.all(np.diff(rows) > 0) and np.all(weights > 0)
    # Unbiased: the weighted Gram of the drawn rows estimates U^T U = I.
    gram = (u[rows] * weights[:, None]).T @ u[rows]
    assert np.abs(gram - np.eye(8)).max() < 0.6
    all_rows, ones = leverage_rows(u, 500, seed=3)
    np.testing.assert_array_equal(all_rows, np.arange(500))
    op = solve_operators(u, all_rows, ones, (8, 3, 0))
    np.testing.assert_allclose(op[0], u.T, atol=1e-6)
    np.testing.assert_allclose(op[1], u[:, :3].T, atol=1e-6)
    assert op[2] is None


# --------------------------------------------------------------------------- the compress contract


def test_transcoding_is_deterministic_and_honours_targets(tmp_path, pebbles):
    btf = read_ubo2014(dfmf(tmp_path / "m.btf", pebbles, 11))
    for name in ("first", "second"):
        compress_into(btf, tmp_path / name, CompressOptions(k=K))
    files = sorted(p.relative_to(tmp_path / "first") for p in (tmp_path / "first").rglob("*") if p.is_file())
    assert files and files == sorted(p.relative_to(tmp_path / "second") for p in (tmp_path / "second").rglob("*")
                                     if p.is_file())
    for f in files:
        assert (tmp_path / "first" / f).read_bytes() == (tmp_path / "second" / f).read_bytes(), f
    budget = compress(btf, CompressOptions(max_bytes=6000))
    assert budget.info["bytes"]["payload"] <= 6000
    target = compress(btf, CompressOptions(target_error=8.0))
    assert target.info["estimated_error"]["linear"]["percent"] <= 8.0
    for result in (budget, target):
        assert result.info["provenance"]["transcoded"]["from"] == "factors"


def test_fmf_linear_transcodes_exactly(tmp_path, pebbles):
    """FMF without dynamic-range reduction (one factorisation shared by the channels) is a
    linear decode: transcoded on the exact path, and as good as the expansion."""
    flat = pebbles.transpose(0, 2, 1).reshape(S * 3, T)
    s, u, sxv = w.factorise(flat, 16)
    btf = read_ubo2014(w.fmf_file(tmp_path / "f.btf", s, u, sxv, **GEOM))
    assert linear_decode(btf) is not None
    truth = btf.read_samples(slice(None))
    errs = {name: reconstruction_rmse(compress(btf, CompressOptions(k=K, expand_factors=expand)), truth)
            for name, expand in (("factors", False), ("expanded", True))}
    assert errs["factors"] <= 1.1 * errs["expanded"], errs


def test_ordinary_inputs_record_no_factor_options():
    assert "expand_factors" not in CompressOptions().recorded()
    assert "factor_rows" not in CompressOptions().recorded()
    assert CompressOptions(factor_rows=100).recorded()["factor_rows"] == 100


def test_paper_solver_fits_on_the_region_and_projects_from_the_factors(tmp_path, pebbles):
    btf = read_ubo2014(dfmf(tmp_path / "m.btf", pebbles, 0))
    result = compress(btf, CompressOptions(solver="paper", k=K))
    made = result.info["provenance"]["transcoded"]
    assert made["basis"].startswith("paper fit on the decoded values of")
    assert made["coefficients"]["product"] == "exact from the factors"


def test_factor_rows_bounded_on_the_command_line(tmp_path, capsys, pebbles):
    path = dfmf(tmp_path / "m.btf", pebbles, 11)
    bad_usage(capsys, "compress", path, "-o", tmp_path / "c", "--factor-rows", "0", names="--factor-rows")


@pytest.mark.parametrize("shift", [-0.12, 0.3])
def test_clamp_handled_by_how_much_it_changes(tmp_path, pebbles, shift):
    """Model 0, the data shifted down (the product negative in many places: its SVD would be
    the basis of values the reader never shows, so the basis is fitted on the decoded ones) or
    up (nothing to clamp: no sampled correction, nothing decoded beyond the fitting texels).
    Both as good as the expansion."""
    btf = read_ubo2014(dfmf(tmp_path / "shifted.btf", pebbles + shift, 0))
    truth = btf.read_samples(slice(None))
    assert ((truth == 0).mean() > 0.2) == (shift < 0)
    results = {name: compress(btf, CompressOptions(k=K, expand_factors=expand))
               for name, expand in (("factors", False), ("expanded", True))}
    errs = {name: reconstruction_rmse(c, truth) for name, c in results.items()}
    made = results["factors"].info["provenance"]["transcoded"]
    if shift < 0:
        assert made["clamp_energy_share_on_fit_texels"] > 1e-3 and made["basis"].startswith("rsvd fit")
        assert made["coefficients"]["clamp"]["solved_on"]["sampling"] == "leverage"
    else:
        assert made["clamp_energy_share_on_fit_texels"] == 0 and made["basis"].startswith("exact SVD")
        assert made["coefficients"]["clamp"].startswith("negligible")
    assert errs["factors"] <= 1.5 * errs["expanded"], errs
