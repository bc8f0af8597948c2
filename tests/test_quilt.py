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
from usdbtf.quilt.cut import keep_old_mask, pair_cut_columns
from usdbtf.quilt.engine import Source, grid_for, place_blocks
from usdbtf.quilt.features import image_features
from usdbtf.quilt.matcher import Matcher
from usdbtf.quilt.seams import natural_neighbour_error, pair_error, seam_error_all_samples, seam_error_images


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


def _pair_cost(old, new, cut):
    """Summed squared difference over the neighbour pairs (one old, one new) of a left strip
    composited by ``cut`` (row y takes new from column cut[y] on), counted directly."""
    n, w1 = new.shape[:2]
    is_old = np.arange(w1)[None, :] < np.asarray(cut)[:, None]
    comp = np.where(is_old[..., None], np.pad(old, ((0, 0), (0, 1), (0, 0))), new)
    total = 0.0
    for (a, b), (c, d) in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                           ((slice(None, -1), slice(None)), (slice(1, None), slice(None)))):
        seam = is_old[a, b] != is_old[c, d]
        total += float((((comp[a, b] - comp[c, d]) ** 2).sum(-1) * seam).sum())
    return total


def test_pair_cut_is_the_cheapest_cut_of_the_pairs_it_makes():
    """Against exhaustive search over every cut (any column per row) of the pair cost counted on
    the composited strip, the quantity the seam metric measures."""
    rng = np.random.default_rng(1)
    n, w = 4, 3
    for _ in range(10):
        old = rng.random((n, w, 2))
        new = rng.random((n, w + 1, 2))
        cut = pair_cut_columns(old[None], new[None], np.ones((1, n, w), bool))[0]
        assert cut.min() >= 1 and cut.max() <= w
        best = min(_pair_cost(old, new, c) for c in itertools.product(range(1, w + 1), repeat=n))
        assert _pair_cost(old, new, cut) == pytest.approx(best)


def test_keep_old_mask_cuts_where_the_blocks_continue_each_other():
    """Old texels are 0 in columns 0-1 and the new block's 0 from column 2 on (everything else a
    distinct random feature): the only free cut of a left strip runs between columns 1 and 2."""
    B = 8
    rng = np.random.default_rng(2)
    image = np.vstack([np.zeros((1, 3)), 1.0 + rng.random((2 * B * B, 3))])
    ids = 1 + np.arange(2 * B * B).reshape(2, B, B)
    old, new = ids[0].copy(), ids[1].copy()
    old[:, :2] = 0
    new[:, 2:] = 0
    placed = np.ones((B, B), bool)
    keep = keep_old_mask(image, old, new, placed, (3, 0, 0, 0))
    assert keep[:, :2].all() and not keep[:, 2:].any()
    # The same pattern turned to the bottom (rows 7..4) and the right strip (columns 7..5).
    keep = keep_old_mask(image, old.T[::-1], new.T[::-1], placed, (0, 0, 0, 4))
    assert keep[6:].all() and not keep[:6].any()
    keep = keep_old_mask(image, old[:, ::-1], new[:, ::-1], placed, (0, 0, 3, 0))
    assert keep[:, 6:].all() and not keep[:, :6].any()


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
    """Pair errors across the wrap (last column/row to the first) against one column and row
    inside, each summed over seeds 2 and 3: one line of ~180 pairs is noisy, one seed may put a
    seam's worst stretch on it."""
    cbtf = read_compressed(pebbles)
    feats = image_features(cbtf)
    errors = {}
    for tileable in (True, False):
        wrap = inner = 0.0
        for seed in (2, 3):
            p = quilt(cbtf, QuiltOptions(size=(96, 80), block=16, seed=seed, tileable=tileable)).positions
            wrap += pair_error(feats, np.r_[p[:, -1], p[-1]], np.r_[p[:, 0], p[0]], cbtf.n_samples)
            inner += pair_error(feats, np.r_[p[:, 47], p[39]], np.r_[p[:, 48], p[40]], cbtf.n_samples)
        errors[tileable] = (wrap, inner)
    wrap_t, inner_t = errors[True]
    wrap_p, _ = errors[False]
    assert wrap_t < 2.0 * inner_t            # across the wrap: like any column inside
    assert wrap_p > 2.0 * wrap_t             # a plain quilt has a real seam there


def test_seams_stay_near_the_materials_own_neighbour_difference(pebbles):
    """Seam quality with the default options: across the quilting seams of a 96^2 plane the mean
    squared difference over every (view, light) image is within 1.2x of the sample's own neighbour
    difference (seeds 0-2, blocks of 12 overlapping by 3: 1.15, 1.13, 1.14 with the pair cut; the
    Efros-Freeman cut gave 1.31, 1.27, 1.37).  Issue 31 asks for <= 1.5 on
    meshes; this is the cheap guard against a regression of the cut or the defaults."""
    cbtf = read_compressed(pebbles)
    feats = image_features(cbtf)
    natural = natural_neighbour_error(feats, cbtf.width, cbtf.height, cbtf.n_samples)
    ratios = [seam_error_all_samples(quilt(cbtf, QuiltOptions(size=(96, 96), seed=seed)).positions, feats,
                                     cbtf.width, cbtf.n_samples) / natural for seed in range(3)]
    assert max(ratios) < 1.2, ratios


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
