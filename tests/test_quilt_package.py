"""Packaging a quilt (issue 32): per-texel work once per source texel, gathered through the
position map, gives what the per-texel path gives -- the fallback maps within 1e-6 of a fit of
every quilt texel, and the same texture files byte for byte (fallback maps, GPU packs,
thumbnail) -- and a quilt whose map is missing or does not describe its codes takes the
per-texel path and says why."""
from __future__ import annotations

import logging
import shutil

import numpy as np
import pytest

from quilt_render_data import pebbles, work  # noqa: F401 (fixtures)
from usdbtf.compress.format import read_compressed
from usdbtf.imageio import write_image
from usdbtf.quilt import POSITION_MAP, QuiltOptions, quilt, write_quilt
from usdbtf.quilt.texels import distinct_texels, quilt_texels
from usdbtf.render.texture import CoefficientTexture
from usdbtf.svbrdf import fit_svbrdf
from usdbtf.usd.asset.package import PackageOptions, package

MAPS = ("diffuse", "specular", "roughness", "normal")


@pytest.fixture(scope="module")
def quilted(work, pebbles):
    """A 64 x 56 quilt of the 48 x 48 pebbles, written with its position map."""
    folder = work / "q64"
    write_quilt(quilt(pebbles, QuiltOptions(size=(64, 56), seed=5, block=16)), folder)
    return folder


def _package(folder, caplog):
    caplog.clear()
    with caplog.at_level(logging.DEBUG, logger="usdbtf"):
        return package(folder, PackageOptions(usdz_ar=True))


def test_quilt_fallback_and_textures_equal_the_per_texel_path(work, quilted, caplog):
    gathered = _package(quilted, caplog)
    texels = quilt_texels(read_compressed(quilted), quilted)
    assert texels is not None and texels.shape == (56, 64)
    assert f"once per source texel: {texels.compact.width} of them" in caplog.text
    assert texels.compact.width < 0.6 * 64 * 56          # a real saving: a fraction of the texels

    # The maps equal a fit of every quilt texel, within 1e-6.
    per_texel = fit_svbrdf(read_compressed(quilted))
    for name in MAPS:
        got, want = getattr(gathered.maps, name), getattr(per_texel, name)
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6, err_msg=name)
    assert np.ptp(per_texel.roughness) > 0 and np.ptp(per_texel.diffuse) > 0.05      # not a flat answer

    # A copy without the map (an older quilt) takes the per-texel path, says so, and writes
    # the same files: fallback maps, GPU tables and packs, thumbnail, BTF textures.
    old = work / "q64_no_map"
    shutil.copytree(quilted, old)
    (old / POSITION_MAP).unlink()
    reference = _package(old, caplog)
    assert "a quilt without a position map" in caplog.text and "once per source texel" not in caplog.text
    assert set(gathered.textures.files) == set(reference.textures.files)
    assert gathered.gpu is not None and gathered.thumbnail is not None
    for name, f in reference.textures.files.items():
        assert gathered.textures.files[name].data == f.data, name
    for name, f in reference.ar[0].files.items():                      # the AR package's maps too
        assert gathered.ar[0].files[name].data == f.data, name


def test_a_map_that_does_not_describe_the_codes_is_not_trusted(work, quilted, caplog):
    # A map that pairs up texels whose codes differ: gathering through it would be wrong.
    bad = work / "q64_edited"
    shutil.copytree(quilted, bad)
    index = quilt_texels(read_compressed(quilted), quilted).index
    merged = np.stack([index // 2, np.zeros_like(index), np.ones_like(index)], -1).astype(np.float32)
    write_image(bad / POSITION_MAP, merged, color_space="data")
    with caplog.at_level(logging.WARNING, logger="usdbtf"):
        assert quilt_texels(read_compressed(bad), bad) is None
    assert "not copies of the texels this map names" in caplog.text
    write_image(bad / POSITION_MAP, np.zeros((5, 5, 3), np.float32), color_space="data")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="usdbtf"):
        assert quilt_texels(read_compressed(bad), bad) is None
    assert "not a position map of this 64x56 quilt" in caplog.text
    (bad / POSITION_MAP).write_bytes(b"not an image")
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="usdbtf"):
        assert quilt_texels(read_compressed(bad), bad) is None
    assert POSITION_MAP in caplog.text and "per-texel work runs on every texel" in caplog.text


def test_distinct_texels_dense_and_sparse_keys_agree_with_unique():
    keys = np.random.default_rng(0).integers(0, 300, (40, 50))
    for k in (keys, keys * 10**9 + 7):
        first, index = distinct_texels(k)
        _, want = np.unique(k, return_inverse=True)
        np.testing.assert_array_equal(index, want.reshape(k.shape))
        np.testing.assert_array_equal(k.ravel()[first], np.unique(k))


def test_gathered_texture_shades_as_the_whole_texture(quilted):
    # Every filter level -- level 0's taps gathered, mip levels streamed in bands -- equals the
    # texture built from the full quilt, bit for bit.
    cbtf = read_compressed(quilted)
    texels = quilt_texels(cbtf, quilted)
    whole = CoefficientTexture(cbtf, cbtf.k, "repeat")
    gathered = CoefficientTexture(texels.compact, cbtf.k, "repeat", texels.index)
    assert (gathered.height, gathered.width) == (56, 64) and 0 not in gathered.levels
    rng = np.random.default_rng(1)
    n = 4000
    rows = rng.standard_normal((n, cbtf.k)).astype(np.float32)
    st = rng.uniform(-0.2, 1.2, (n, 2))
    lod = rng.uniform(-1.0, whole.max_level + 1.0, n)
    np.testing.assert_array_equal(gathered.shade(rows, st, lod), whole.shade(rows, st, lod))
    assert 0 not in gathered.levels                       # level 0 was never held
