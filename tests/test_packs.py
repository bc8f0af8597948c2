"""Issue 39: the coefficient packs' layout lives in ``compress`` (``compress.packs``), and its
shipped-bytes probe measures what the packaged asset's GPU pages and tables cost.

A small synthetic material is compressed and packaged for real (PNG codec, k 12); the probe's
per-pack bytes must add up to the asset's PNG pages, group by group, and the layout must hold
each coefficient's colour channel where the shader reads it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import usdbtf  # noqa: F401  (registers the schema plugin first)
from usdbtf.cli import main
from usdbtf.compress import packs
from usdbtf.compress.format import read_compressed
from basis_helpers import schema3_tables

K = 12


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> tuple[Path, Path]:
    work = tmp_path_factory.mktemp("packs")
    assert main(["synth", "pebbles", "-o", str(work / "src"), "--sampling", "small", "--size", "48", "-q"]) == 0
    assert main(["compress", str(work / "src"), "-o", str(work / "c"), "--k", str(K), "--codec", "png", "-q"]) == 0
    assert main(["package", str(work / "c"), "-o", str(work / "a" / "p.usda"), "-q"]) == 0
    return work / "c", work / "a" / "p_textures" / "gpu"


def test_pack_layout_is_the_codes_by_colour_channel(made):
    cbtf = read_compressed(made[0])
    k = 6                                           # a partial second group: layers 6, 7 are zero
    tiles, scales, biases = packs.coefficient_packs(cbtf, k, [])
    assert len(tiles) == packs.pack_count(k) == 6
    for g in range(2):
        for c in range(3):
            for j in range(4):
                layer = 4 * g + j
                want = cbtf.coefficients[layer].pixels[:, :, c] if layer < k else 0
                np.testing.assert_array_equal(tiles[3 * g + c][:, :, j], want)
                if layer < k:
                    assert scales[3 * g + c, j] == pytest.approx(float(cbtf.coefficients[layer].scale[c]) * 255.0)
    # gpu.tables re-uses this layout rather than keeping its own copy
    from usdbtf.gpu import tables
    assert tables._pack is packs.coefficient_packs and tables.pack_count is packs.pack_count


def test_probe_matches_the_asset_pages(made):
    compressed, gpu = made
    cbtf = read_compressed(compressed)
    per_pack = packs.shipped_pack_bytes(cbtf)
    assert len(per_pack) == packs.pack_count(K) == 9
    assert per_pack == packs.shipped_pack_bytes(cbtf)       # deterministic
    pages = sum(p.stat().st_size for p in gpu.glob("page*.png"))
    # one PNG stream per page against one per pack: 0.1 % apart here, 2.4..3.5 % at paper scale
    assert abs(sum(per_pack) - pages) <= 0.05 * pages, (sum(per_pack), pages)
    # a group of four layers shares its three packs: k 5..8 all ship six packs, the first
    # group's three unchanged; k 8 ships exactly the first six packs of k 12
    five, eight = packs.shipped_pack_bytes(cbtf, 5), packs.shipped_pack_bytes(cbtf, 8)
    assert len(five) == len(eight) == 6 and five[:3] == eight[:3] == per_pack[:3]
    assert eight == per_pack[:6]
    by_k = packs.pack_bytes_by_k(per_pack, K)
    assert by_k.tolist() == [sum(per_pack[:3])] * 4 + [sum(per_pack[:6])] * 4 + [sum(per_pack)] * 4
    with pytest.raises(ValueError):
        packs.pack_bytes_by_k(per_pack[:6], 9)
    # the basis codes alone are part of tables.exr (header, hemisphere tables, directory beside them)
    tables = (gpu / "tables.exr").stat().st_size
    basis = packs.shipped_basis_bytes(cbtf)
    assert 0 < packs.shipped_basis_bytes(cbtf, 4) < basis < tables
    assert basis == packs.shipped_basis_bytes(cbtf, K)


def test_shipped_packs_follow_the_assets_page_breaks(made):
    """``ShippedPacks`` (what rate control fits k on under a budget of the asset): the packs of
    the first k layers as the asset with its default lods ships them.  With every code 8-bit no
    page break changes a storage type, so it equals the per-pack probe at every k, partial groups
    included; its lods are the ones package writes (usd.asset.lod re-uses them)."""
    compressed, gpu = made
    cbtf = read_compressed(compressed)
    assert {st.pixels.dtype for st in cbtf.coefficients} == {np.dtype(np.uint8)}
    shipped = packs.ShippedPacks(cbtf)
    for k in range(1, K + 1):
        assert shipped(k) == sum(packs.shipped_pack_bytes(cbtf, k)), k
    pages = sum(p.stat().st_size for p in gpu.glob("page*.png"))
    assert abs(shipped(K) - pages) <= 0.05 * pages
    from usdbtf.gpu import tables
    from usdbtf.usd.asset import lod
    assert lod.default_lods is packs.default_lods and tables.page_breaks is packs.page_breaks
    assert packs.default_lods(12) == [6] and packs.page_breaks(12, [6]) == [6]


def test_tables_point_at_the_basis_page_and_older_tables_still_read(made):
    """Schema 4 (issue 39, basis8): integer basis codes live in gpu/basis.png (8-bit high / low
    planes), the tables keep their de-quantisation and say so (basis block .w = BASIS_IN_PAGE);
    ``unpack`` reads the codes from the page bit for bit, and refuses in one line without it.
    Schema-3 tables (2^23 + code in the tables) and older ones (offset 0, the bare codes) read
    the same codes; any other offset is refused in one line."""
    from usdbtf.errors import BTFError
    from usdbtf.gpu.tables import BASIS_IN_PAGE, basis_in_page, gpu_layout, unpack
    from usdbtf.imageio import read_rgba

    compressed, gpu = made
    cbtf = read_compressed(compressed)
    shipped = read_rgba(gpu / "tables.exr")
    flat = shipped.reshape(-1, 4)
    basis_at, groups = int(flat[1, 1]), int(flat[0, 3])
    assert flat[basis_at, 3] == BASIS_IN_PAGE and basis_in_page(shipped)
    assert len(flat) < basis_at + 1 + 2 * groups + packs.TABLE_WIDTH   # no codes after the de-quantisation
    pages = [read_rgba(p) for p in sorted(gpu.glob("page*.png"))]
    page = read_rgba(gpu / "basis.png")
    basis, _ = unpack(shipped, pages, basis_page=page)
    assert basis.dtype == cbtf.basis.pixels.dtype
    np.testing.assert_array_equal(basis, cbtf.basis.pixels)
    np.testing.assert_array_equal(page, gpu_layout(cbtf).basis_page)      # the file holds the layout's page
    with pytest.raises(BTFError, match="basis page, and none was given"):
        unpack(shipped, pages)
    old = schema3_tables(shipped, cbtf)
    assert not basis_in_page(old)
    np.testing.assert_array_equal(unpack(old, pages)[0], cbtf.basis.pixels)
    at = basis_at + 1 + 2 * groups
    old.reshape(-1, 4)[at:at + groups * cbtf.n_samples] -= np.float32(2.0 ** 23)
    old.reshape(-1, 4)[basis_at, 3] = 0.0
    np.testing.assert_array_equal(unpack(old, pages)[0], cbtf.basis.pixels)
    old.reshape(-1, 4)[basis_at, 3] = 5.0
    with pytest.raises(BTFError, match="basis code offset"):
        unpack(old, pages)


def test_basis_page_round_trips_the_codes_bit_for_bit_through_png(tmp_path):
    """Issue 39 (basis8): the 8-bit hi / lo basis page, written as the asset writes PNG pages
    and read back through OIIO as Storm's readers see it (8 bits per channel), gives every
    code back, also codes >= 256 and a group split over two columns."""
    from usdbtf.errors import BTFError
    from usdbtf.imageio import read_rgba

    rng = np.random.default_rng(3)
    views, lights = 3, 5
    rows = packs.BASIS_PAGE_ROWS
    packs.BASIS_PAGE_ROWS = 12                   # 2 groups (2 V rows each) per column: 18 vectors, 3 columns
    try:
        codes = rng.integers(0, 2**16, (views * lights, 18))
        codes[:, 0] = 65535                          # largest code: both bytes 255
        codes[:, 1] = np.arange(views * lights)      # sample order: view-major
        image = packs.basis_page(codes, views, lights)
        assert image.shape == (12, 3 * lights, 4) and image.dtype == np.uint8    # 5 groups, 2 per column
        # view 1, light 2 of vector 1 (sample 7): group 0, high byte row 1, low byte row V + 1
        assert image[1, 2, 1] == 0 and image[views + 1, 2, 1] == 7
        path = tmp_path / "basis.png"
        path.write_bytes(packs.encode_png_page(image))
        back = read_rgba(path)
        assert back.dtype == np.uint8 and np.array_equal(back, image)
        assert np.array_equal(packs.basis_page_codes(back, views, lights, 18), codes)
        assert np.array_equal(packs.basis_page_codes(back, views, lights, 5, groups=5), codes[:, :5])
        assert packs.basis_page_column(3, views) == 2 and packs.basis_page_column(4, views) == 2
        packs.BASIS_PAGE_ROWS = 18                   # at most 3 groups a column: 4 groups as 2 + 2, not 3 + 1
        assert packs.basis_page_column(4, views) == 2 and packs.basis_page(codes[:, :16], views, lights).shape == \
            (12, 2 * lights, 4)
        assert np.array_equal(packs.basis_page_codes(packs.basis_page(codes[:, :16], views, lights), views, lights,
                                                     16), codes[:, :16])
        with pytest.raises(BTFError, match="does not hold group"):
            packs.basis_page_codes(back[:, :lights], views, lights, 18)
    finally:
        packs.BASIS_PAGE_ROWS = rows


def test_shipped_basis_bytes_are_the_basis_page_file(made):
    """Rate control's basis bytes (``shipped_basis_bytes``) are the asset's gpu/basis.png,
    byte for byte, and fewer than the schema-3 EXR block of the same codes."""
    cbtf = read_compressed(made[0])
    shipped = packs.shipped_basis_bytes(cbtf)
    assert shipped == packs.basis_page_bytes(cbtf) == (made[1] / "basis.png").stat().st_size
    assert shipped < packs.basis_block_bytes(packs.basis_codes_group_major(cbtf, cbtf.k))


def test_asset_pages_are_smaller_than_libpng_level_6_with_the_same_pixels(made):
    """The asset's page encoder (``encode_png_page``: adaptive rows, zlib run-length; issue 39)
    against the one it replaced (OIIO/libpng level 6, the smaller of adaptive and no filter) on
    the asset's own pages and basis page: fewer bytes in all, the pages' pixels read back."""
    from usdbtf.imageio import encode_png_smallest, read_rgba
    from usdbtf.usd.asset.textures import png_as_data

    new = old = 0
    for path in sorted(made[1].glob("page*.png")) + [made[1] / "basis.png"]:
        pixels = read_rgba(path)
        data = packs.encode_png_page(pixels)
        # byte for byte what the packager wrote (in its worker processes): deterministic, and the
        # file rate control measures
        assert png_as_data(data) == path.read_bytes(), path.name
        assert len(data) + packs.PNG_DATA_CHUNK_BYTES == path.stat().st_size
        new += len(data)
        old += len(encode_png_smallest(pixels, color_space="data", level=6, attributes={"oiio:UnassociatedAlpha": 1}))
    assert new < 0.97 * old, (new, old)
