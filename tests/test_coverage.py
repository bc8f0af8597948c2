"""Partial assets (issue 26): ``compress --coverage`` keeps only the listed views x lights,
``--max-texels`` box-filters the texture side, the folder records what it covers.

Real inputs: a synthesised pebbles BTF (13 x 13 directions, 16^2 texels) in memory and as a
manifest folder of PNG files; real folders read back through ``read_compressed``.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from cli_helpers import bad_input, ok
from compress_helpers import compress_into
from usdbtf.compress import CompressOptions, compress, read_compressed
from usdbtf.compress.coverage import box_mean, shaped_input
from usdbtf.compress.format import cross_layout, reconstruct
from usdbtf.sampling import Coverage, coverage_json, read_coverage
from usdbtf.synth import SynthOptions, synth, write_synth

#: Three of the 13 views (the pole and two on the 30 degree ring), three of the 13 lights.
VIEWS = [[0.0, 0.0], [30.0, 0.0], [30.0, 60.0]]
LIGHTS = [[30.0, 30.0], [30.0, 90.0], [60.0, 30.0]]


@pytest.fixture(scope="module")
def pebbles_btf():
    return synth("pebbles", SynthOptions(size=16, sampling="small")).to_btf()


@pytest.fixture(scope="module")
def pebbles_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("coverage") / "pebbles"
    write_synth(synth("pebbles", SynthOptions(size=16, sampling="small")), folder)
    return folder


def covered_indices(sampling, views, lights) -> np.ndarray:
    """Indices of the samples whose view and light are both listed (brute force)."""
    def listed(dirs, wanted):
        return np.array([any(np.allclose(d, w) for w in wanted) for d in dirs])
    return np.flatnonzero(listed(sampling.view, views) & listed(sampling.light, lights))


def test_coverage_keeps_exactly_the_listed_samples_and_reconstructs_them(pebbles_btf):
    # exr (half floats) and k = the kept samples: the basis spans them, so what is left is
    # the codec's rounding, and a full compress (k = every sample) must agree to that.
    cov = Coverage(VIEWS, LIGHTS)
    part = compress(pebbles_btf, CompressOptions(codec="exr", k=9, coverage=cov))
    idx = covered_indices(pebbles_btf.sampling, VIEWS, LIGHTS)
    assert len(idx) == 9 and part.n_samples == 9 and cross_layout(part.sampling) == (3, 3)
    np.testing.assert_array_equal(part.sampling.view, pebbles_btf.sampling.view[idx])
    np.testing.assert_array_equal(part.sampling.light, pebbles_btf.sampling.light[idx])
    full = compress(pebbles_btf, CompressOptions(codec="exr", k=169))
    truth = pebbles_btf.read_samples(idx)
    ours, theirs = reconstruct(part), reconstruct(full, idx)
    scale = float(truth.mean())
    assert np.abs(ours - truth).max() < 0.02 * scale
    assert np.abs(ours - theirs).max() < 0.02 * scale
    rec = part.info["coverage"]
    assert (rec["input_views"], rec["input_lights"], rec["input_samples"]) == (13, 13, 169)
    assert rec["views"] == VIEWS and rec["lights"] == LIGHTS and rec["resolution_factor"] == 1


def test_max_texels_box_filters_in_linear_and_records_the_factor(pebbles_btf):
    # 16 texels, at most 6: factor 3, 6 x 6 boxes, the last column and row one texel wide.
    shaped, rec = shaped_input(pebbles_btf, None, 6)
    assert (shaped.width, shaped.height, rec["resolution_factor"], rec["input_size"]) == (6, 6, 3, [16, 16])
    assert len(rec["views"]) == 13 and len(rec["lights"]) == 13
    src = pebbles_btf.read_samples([0, 50])
    got = shaped.read_samples([0, 50])
    np.testing.assert_allclose(got[:, 0, 0], src[:, :3, :3].mean(axis=(1, 2)), rtol=1e-5)
    np.testing.assert_allclose(got[:, 5, 5], src[:, 15, 15], rtol=1e-5)
    np.testing.assert_allclose(got, box_mean(src, 3), rtol=1e-5)
    # Rows read in pieces give the same values as the whole image.
    np.testing.assert_array_equal(shaped.read_encoded([0, 50], rows=(2, 4)), shaped.read_encoded([0, 50])[:, 2:4])
    out = compress(pebbles_btf, CompressOptions(k=4, max_texels=6))
    assert (out.width, out.height, out.info["coverage"]["resolution_factor"]) == (6, 6, 3)
    assert out.info["provenance"]["options"]["max_texels"] == 6


def test_cli_coverage_folder_records_it_and_is_deterministic(tmp_path, pebbles_folder, capsys):
    path = tmp_path / "cov.json"
    path.write_text(coverage_json(Coverage(np.array(VIEWS) + 0.001, LIGHTS)))    # within the tolerance
    assert read_coverage(path).views.shape == (3, 2)
    for name in ("a", "b"):
        ok(capsys, "compress", pebbles_folder, "-o", tmp_path / name, "--k", "6", "--coverage", path,
           "--max-texels", "8", "-q")
    assert (tmp_path / "a" / "btf-compressed.json").read_bytes() == (tmp_path / "b" / "btf-compressed.json").read_bytes()
    cbtf = read_compressed(tmp_path / "a")
    assert (cbtf.n_samples, cbtf.width, cbtf.height) == (9, 8, 8)
    doc = json.loads((tmp_path / "a" / "btf-compressed.json").read_text())
    assert doc["coverage"]["views"] == VIEWS                   # the input's own directions
    assert doc["coverage"]["resolution_factor"] == 2


def test_cli_coverage_errors_are_one_line(tmp_path, pebbles_folder, capsys):
    bad = tmp_path / "outside.json"
    bad.write_text(json.dumps({"format": "usdbtf-coverage/1", "views": [[0, 0], [45, 0]], "lights": [[30, 30]]}))
    line = bad_input(capsys, "compress", pebbles_folder, "-o", tmp_path / "x", "--coverage", bad, names="outside.json")
    assert "view [45, 0] is not one of the input's 13 view directions" in line
    wrong = tmp_path / "wrong.json"
    wrong.write_text(json.dumps({"format": "usdbtf-coverage/1", "views": [[0, "a"]], "lights": [[30, 30]]}))
    bad_input(capsys, "compress", pebbles_folder, "-o", tmp_path / "x", "--coverage", wrong, names="wrong.json")
    assert not (tmp_path / "x").exists()
