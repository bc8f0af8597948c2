"""``usdbtf quilt``: Efros-Freeman quilting in coefficient space.

The FFT overlap error against direct summation, the boundary cut against exhaustive search,
the output folder (an ordinary compressed BTF whose texels are source texels), determinism,
tileability, the paper's consistency claim in the form that holds (see the benchmark for the
full comparison), and bad input.
"""
from __future__ import annotations

import itertools
import json
import shutil
from dataclasses import replace

import numpy as np
import pytest

from quilt_render_data import pebbles, work  # noqa: F401 (fixtures)
from cli_helpers import bad_input, bad_usage, ok
from usdbtf.compress import read_compressed, reconstruct
from usdbtf.compress.format import METADATA
from usdbtf.imageio import read_image
from usdbtf.io import open_btf
from usdbtf.quilt import POSITION_MAP, QuiltOptions, quilt
from usdbtf.quilt.cut import keep_old_mask, min_cut_columns
from usdbtf.quilt.engine import Source, grid_for, place_blocks
from usdbtf.quilt.features import image_features
from usdbtf.quilt.matcher import Matcher
from usdbtf.quilt.seams import pair_error, seam_error_images


# ------------------------------------------------------------------ building blocks


def test_fft_overlap_error_equals_direct_summation():
    rng = np.random.default_rng(0)
    feats = rng.normal(size=(20, 23, 5)).astype(np.float32)
    B = 7
    matcher = Matcher(feats, B)
    template = rng.normal(size=(B, B, 5)).astype(np.float32)
    mask = np.zeros((B, B), bool)
    mask[:, :2] = True                      # an L-shaped overlap
    mask[:3, :] = True
    got = matcher.errors(template, mask)
    want = np.empty((20 - B + 1, 23 - B + 1))
    for y, x in itertools.product(range(want.shape[0]), range(want.shape[1])):
        d = feats[y:y + B, x:x + B] - template
        want[y, x] = (d[mask] ** 2).sum()
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-3)
    # A template cut from the source at (4, 9) matches exactly there.
    exact = feats[4:4 + B, 9:9 + B]
    err = matcher.errors(exact, mask)
    assert np.unravel_index(np.argmin(err), err.shape) == (4, 9)
    assert err[4, 9] < 1e-3 * err.mean()


def test_min_cut_is_the_cheapest_connected_path():
    rng = np.random.default_rng(1)
    for _ in range(20):
        err = rng.random((5, 3))
        path = min_cut_columns(err)
        assert np.all(np.abs(np.diff(path)) <= 1)
        best = min(sum(err[y, c] for y, c in enumerate(p))
                   for p in itertools.product(range(3), repeat=5) if np.all(np.abs(np.diff(p)) <= 1))
        assert err[np.arange(5), path].sum() == pytest.approx(best)


def test_keep_old_mask_follows_the_cheap_columns():
    B = 8
    err = np.ones((B, B))
    err[:, 2] = 0.0                          # the only free path through the left strip: column 2
    keep = keep_old_mask(err, (3, 0, 0, 0))
    assert keep[:, :2].all() and not keep[:, 2:].any()
    err = np.ones((B, B))
    err[5, :] = 0.0                          # through the bottom strip (rows 4..7): row 5
    keep = keep_old_mask(err, (0, 0, 0, 4))
    assert keep[6:].all() and not keep[:6].any()
    err = np.ones((B, B))
    err[:, 6] = 0.0                          # right strip (columns 5..7): column 6
    keep = keep_old_mask(err, (0, 0, 3, 0))
    assert keep[:, 7:].all() and not keep[:, :7].any()


# ------------------------------------------------------------------ quilting


def test_quilted_folder_copies_source_texels(work, pebbles, capsys):
    out = work / "q80"
    ok(capsys, "quilt", pebbles, "-o", out, "--size", 80, 72, "--seed", 5, "--block", 16, "-q")
    src, dst = read_compressed(pebbles), read_compressed(out)
    assert (dst.width, dst.height, dst.k) == (80, 72, src.k)
    np.testing.assert_array_equal(dst.basis_values(), src.basis_values())
    px, _ = read_image(out / POSITION_MAP)
    x, y = px[..., 0].astype(int), px[..., 1].astype(int)
    assert px.dtype == np.float32 and (px[..., 2] == 1).all()
    assert x.min() >= 0 and x.max() < src.width and y.min() >= 0 and y.max() < src.height
    # Every output texel of every sample is the source texel the position map names.
    samples = [0, 40, 168]
    np.testing.assert_array_equal(reconstruct(dst, samples), reconstruct(src, samples)[:, y, x])
    # It is a real quilt: many distinct source blocks, not one stretched copy.
    assert len(np.unique(y * src.width + x)) > 0.5 * src.width * src.height
    doc = json.loads((out / METADATA).read_text())
    size = doc["source_metadata"]["physical_size_m"]
    assert size == pytest.approx([0.05 * 80 / 48, 0.05 * 72 / 48])
    assert doc["quilt"]["options"]["block"] == 16 and doc["quilt"]["position_map"]["file"] == POSITION_MAP
    assert doc["quilt"]["seam_error"]["all_samples_mean"] > 0
    # The other stages take it unchanged.
    assert "80x72 texels" in ok(capsys, "info", out)
    ok(capsys, "decompress", out, "-o", work / "q80_recon", "--samples", "0-3", "-q")
    recon = open_btf(work / "q80_recon")
    assert (recon.width, recon.height) == (80, 72)


def test_same_seed_same_bytes_other_seed_other_quilt(work, pebbles, capsys):
    for name in ("a", "b"):
        ok(capsys, "quilt", pebbles, "-o", work / f"det_{name}", "--size", 64, 64, "--seed", 9, "--block", 16, "-q")
    ok(capsys, "quilt", pebbles, "-o", work / "det_c", "--size", 64, 64, "--seed", 10, "--block", 16, "-q")
    files = sorted(p.relative_to(work / "det_a") for p in (work / "det_a").rglob("*") if p.is_file())
    assert files
    for rel in files:
        assert (work / "det_a" / rel).read_bytes() == (work / "det_b" / rel).read_bytes(), rel
    assert (work / "det_a" / POSITION_MAP).read_bytes() != (work / "det_c" / POSITION_MAP).read_bytes()


def test_tileable_output_wraps_without_a_seam(pebbles):
    cbtf = read_compressed(pebbles)
    feats = image_features(cbtf)
    errors = {}
    for tileable in (True, False):
        p = quilt(cbtf, QuiltOptions(size=(96, 80), block=16, seed=2, tileable=tileable)).positions
        wrap = pair_error(feats, np.r_[p[:, -1], p[-1]], np.r_[p[:, 0], p[0]], cbtf.n_samples)
        inner = pair_error(feats, np.r_[p[:, 47], p[39]], np.r_[p[:, 48], p[40]], cbtf.n_samples)
        errors[tileable] = (wrap, inner)
    wrap_t, inner_t = errors[True]
    wrap_p, _ = errors[False]
    assert wrap_t < 2.0 * inner_t            # across the wrap: like any column inside
    assert wrap_p > 2.0 * wrap_t             # a plain quilt has a real seam there


def test_coefficient_matching_beats_one_images_layout_over_all_samples(pebbles):
    """The paper's point: matching coefficients keeps seams low in every (view, light) image at
    once; a layout quilted from one image's intensities (same blocks, grid, seed) is worse
    averaged over all samples, whichever image it came from."""
    cbtf = read_compressed(pebbles)
    images = reconstruct(cbtf)                                   # (S, H, W, 3)
    opts = QuiltOptions(block=16, seed=7).resolved(cbtf)
    coeff = quilt(cbtf, replace(opts, size=(96, 96))).positions
    coeff_err = seam_error_images(coeff, images).mean()
    grid = grid_for(96, 96, opts.block, opts.overlap)
    for s in (0, 84, 150):                                       # frontal, mid, grazing samples
        img = images[s]
        canvas = np.full(grid.shape, -1, np.int32)
        place_blocks(canvas, grid, Source.build(img, img.reshape(-1, 3), opts.block), tolerance=opts.tolerance,
                     rng=np.random.default_rng(opts.seed))
        one_err = seam_error_images(canvas[:96, :96], images).mean()
        assert coeff_err < one_err, (s, coeff_err, one_err)


# ------------------------------------------------------------------ bad input


def test_bad_input_exits_65_bad_options_2_and_writes_nothing(work, pebbles, capsys):
    out = work / "bad_out"
    bad_usage(capsys, "quilt", pebbles, "-o", out, "--size", 64, 64, "--block", 60, names="--block 60")
    bad_usage(capsys, "quilt", pebbles, "-o", out, "--size", 0, 64, names="--size")
    bad_usage(capsys, "quilt", pebbles, "-o", out, "--size", 64, 64, "--m", 99, names="--m")
    bad_usage(capsys, "quilt", pebbles, "-o", out, "--size", 20, 20, "--tileable", names="--tileable")
    bad_input(capsys, "quilt", pebbles, "-o", out, "--atlas", work / "nope.usda", names="nope.usda")
    broken = work / "broken_c"
    shutil.copytree(pebbles, broken)
    (broken / "coeff" / "c003.jxl").write_bytes(b"not an image")
    bad_input(capsys, "quilt", broken, "-o", out, "--size", 64, 64, names="c003.jxl")
    bad_input(capsys, "quilt", work / "missing", "-o", out, "--size", 64, 64, names="missing")
    assert not out.exists()
    assert not [p for p in work.iterdir() if p.name.startswith(".bad_out")]
