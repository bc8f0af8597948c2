"""UBO2003 reader (usdbtf.ubo) and the open_btf dispatch (usdbtf.io).

Every dataset here is built on the fly: 3 views x 4 lights at 16 x 16, each sample a
distinct known colour, written as real PNG / JPEG / EXR files through OpenImageIO.
"""
from __future__ import annotations

import gc
import os
import struct
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from usdbtf import colour
from usdbtf.errors import BTFError
from usdbtf.imageio import write_image
from usdbtf.io import open_btf
from usdbtf.manifest import write_manifest
from usdbtf.model import FileBTF
from usdbtf.sampling import cross
from usdbtf.ubo import UBOBTF, is_ubo, parse_name, read_ubo

SRGB = "sRGB Encoded Rec.709 (sRGB)"
VIEWS = [(0, 0), (15, 0), (15, 60)]            # (theta, phi) degrees
LIGHTS = [(0, 0), (15, 0), (15, 60), (30, 0)]
SIZE = 16
N = len(VIEWS) * len(LIGHTS)


def base_codes(vi: int, li: int) -> np.ndarray:
    """The 8-bit RGB colour of sample (view vi, light li): distinct for all 12 samples."""
    k = vi * len(LIGHTS) + li
    return np.array([20 + 15 * k, 200 - 12 * k, 40 + 10 * k], np.int32)


def sample_codes(vi: int, li: int, ext: str) -> np.ndarray:
    """(H, W, 3) uint8 image.  Lossless files get a row ramp (checks orientation and row
    reads); JPEGs stay flat so that the codec's error is small and predictable."""
    img = np.broadcast_to(base_codes(vi, li), (SIZE, SIZE, 3)).copy()
    if ext != "jpg":
        img += np.arange(SIZE)[:, None, None]
    return img.astype(np.uint8)


def file_name(index: int, view, light, ext: str, sep: str = " ") -> str:
    tv, pv = view
    tl, pl = light
    return sep.join([f"{index:05d}", f"tl{tl:03d}", f"pl{pl:03d}", f"tv{tv:03d}", f"pv{pv:03d}"]) + f".{ext}"


def make_dataset(root: Path, ext: str = "png", sep: str = " ", dtype=np.uint8) -> Path:
    """Write the 12-sample UBO-style folder; returns ``root``.

    The numeric prefixes run backwards (light-major) so that sorting by file name would
    give a wrong order: the reader must sort by the parsed angles.
    """
    attrs = {"Compression": "jpeg:95"} if ext == "jpg" else {}
    for vi, view in enumerate(VIEWS):
        d = root / f"tv{view[0]:03d}_pv{view[1]:03d}"
        d.mkdir(parents=True, exist_ok=True)
        for li, light in enumerate(LIGHTS):
            index = N - 1 - (li * len(VIEWS) + vi)
            img = sample_codes(vi, li, ext)
            if np.dtype(dtype).kind == "f":
                img = (img / 255.0).astype(dtype)
                space = "ACEScg"
            else:
                space = SRGB
            write_image(d / file_name(index, view, light, ext, sep), img, color_space=space, attributes=attrs)
    return root


def make_zip(folder: Path, zip_path: Path, top: str | None = None, extra: dict | None = None,
             compression=zipfile.ZIP_DEFLATED) -> Path:
    """Zip ``folder``'s files (optionally under a top-level folder ``top``) plus ``extra`` {arcname: bytes}."""
    with zipfile.ZipFile(zip_path, "w", compression) as zf:
        for f in sorted(folder.rglob("*")):
            if f.is_file():
                arc = f.relative_to(folder).as_posix()
                zf.write(f, f"{top}/{arc}" if top else arc)
        for arc, data in (extra or {}).items():
            zf.writestr(arc, data)
    return zip_path


def expected_linear(ext: str = "png") -> np.ndarray:
    """(S, H, W, 3) float32 scene-linear values in view-major order, decoded by OCIO itself."""
    codes = np.stack([sample_codes(vi, li, ext) for vi in range(len(VIEWS)) for li in range(len(LIGHTS))])
    return colour.processor(SRGB, "scene_linear").apply(codes.astype(np.float32) / 255.0)


def expected_sampling():
    return cross(np.array(VIEWS, float), np.array(LIGHTS, float))


def caches(stem: str):
    """Leftover extraction folders for a zip named ``stem``.zip."""
    return list(Path(tempfile.gettempdir()).glob(f"usdbtf-ubo-{stem}-*"))


@pytest.fixture(scope="module")
def png_folder(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("ubo_png") / "UBO_TEST16")


@pytest.fixture(scope="module")
def jpg_folder(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("ubo_jpg") / "UBO_TEST16", ext="jpg")


# --------------------------------------------------------------------------- reading


def test_parse_name():
    assert parse_name("00008 tl000 pl000 tv030 pv030.jpg") == ((30.0, 30.0), (0.0, 0.0))
    assert parse_name("x_tl075_pl345_tv015_pv060.exr") == ((15.0, 60.0), (75.0, 345.0))
    assert parse_name("preview.jpg") is None


def test_folder_angles_order_and_exact_values(png_folder):
    btf = read_ubo(png_folder)
    assert isinstance(btf, FileBTF)
    assert btf.shape == (N, SIZE, SIZE, 3)
    assert btf.bit_depth == "uint8" and btf.color_space == SRGB
    want = expected_sampling()
    np.testing.assert_array_equal(btf.sampling.view, want.view)  # view-major
    np.testing.assert_array_equal(btf.sampling.light, want.light)
    assert btf.names[0] == "tv000_pv000/" + file_name(N - 1, (0, 0), (0, 0), "png")
    assert btf.cache_dir is None and btf.paths[0].startswith(str(png_folder))
    # PNG is lossless: the values are exactly OCIO's decode of the known codes.
    np.testing.assert_allclose(btf.read_samples(slice(None)), expected_linear(), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(btf.read_rows(3, 7), expected_linear()[:, 3:7], rtol=1e-5, atol=1e-7)


def test_underscore_separators(tmp_path):
    btf = read_ubo(make_dataset(tmp_path / "d", sep="_"))
    np.testing.assert_array_equal(btf.sampling.view, expected_sampling().view)


@pytest.mark.parametrize("top", [None, "UBO_TEST16"])
def test_zip_jpeg_values_and_cache_lifetime(jpg_folder, tmp_path, top):
    zpath = make_zip(jpg_folder, tmp_path / f"ubojpg{top or ''}.zip", top=top)
    btf = read_ubo(zpath)
    assert isinstance(btf, UBOBTF)
    np.testing.assert_array_equal(btf.sampling.light, expected_sampling().light)
    assert btf.names[1] == (f"{top}/" if top else "") + "tv000_pv000/" + file_name(N - 1 - 3, (0, 0), (15, 0), "jpg")
    got = btf.read_samples(slice(None))
    # Compare in code values: re-encode the decoded linear values to sRGB; JPEG q95 on flat
    # 16x16 patches is within a few codes of the source.
    back = colour.processor("scene_linear", SRGB).apply(got) * 255.0
    codes = np.stack([sample_codes(vi, li, "jpg") for vi in range(len(VIEWS)) for li in range(len(LIGHTS))])
    assert np.abs(back - codes).max() <= 3.0
    # The extraction cache is a private temp folder, and nothing lands beside the zip.
    cache = btf.cache_dir
    assert os.path.isdir(cache) and Path(cache).parent == Path(tempfile.gettempdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == [zpath.name]
    del btf, got
    gc.collect()
    assert not os.path.exists(cache)


def test_zip_close_removes_cache(png_folder, tmp_path):
    btf = read_ubo(make_zip(png_folder, tmp_path / "uboclose.zip"))
    cache = btf.cache_dir
    np.testing.assert_allclose(btf.read_samples([0, 5]), expected_linear()[[0, 5]], rtol=1e-5, atol=1e-7)
    btf.close()
    btf.close()  # idempotent
    assert not os.path.exists(cache)


def test_float_files_default_to_scene_linear_and_override(tmp_path):
    folder = make_dataset(tmp_path / "hdr", ext="exr", dtype=np.float16)
    btf = read_ubo(folder)
    assert btf.bit_depth == "half"
    assert btf.color_space == colour.resolve_space("scene_linear")
    stored = np.stack([sample_codes(vi, li, "exr") for vi in range(len(VIEWS)) for li in range(len(LIGHTS))])
    stored = (stored / 255.0).astype(np.float16).astype(np.float32)
    np.testing.assert_array_equal(btf.read_samples(slice(None)), stored)
    other = read_ubo(folder, color_space="Linear Rec.709 (sRGB)")
    assert other.color_space == "Linear Rec.709 (sRGB)"
    np.testing.assert_allclose(other.read_samples([2])[0],
                               colour.processor("Linear Rec.709 (sRGB)", "scene_linear").apply(stored[2]), rtol=1e-6)


def test_non_image_and_hidden_members_are_ignored(png_folder, tmp_path):
    extra = {"readme.txt": b"hello", "__MACOSX/tv000_pv000/._00011 tl000 pl000 tv000 pv000.png": b"junk",
             "preview.png": b"not looked at"}
    btf = read_ubo(make_zip(png_folder, tmp_path / "uboextra.zip", extra=extra))
    assert btf.n_samples == N


def test_zip_slip_member_is_not_written_outside(png_folder, tmp_path):
    zdir = tmp_path / "z"
    zdir.mkdir()
    extra = {"../evil tl000 pl000 tv075 pv000.png": b"x"}
    btf = read_ubo(make_zip(png_folder, zdir / "uboslip.zip", extra=extra))
    assert btf.n_samples == N
    assert sorted(p.name for p in tmp_path.iterdir()) == ["z"]


# --------------------------------------------------------------------------- dispatch


def test_open_btf_dispatch(png_folder, tmp_path):
    zpath = make_zip(png_folder, tmp_path / "ubodispatch.zip", top="UBO_TEST16")
    assert isinstance(open_btf(png_folder), UBOBTF)
    assert isinstance(open_btf(png_folder.parent), UBOBTF)  # one top-level folder above the views
    assert isinstance(open_btf(zpath), UBOBTF)
    assert open_btf(png_folder, color_space="Linear Rec.709 (sRGB)").color_space == "Linear Rec.709 (sRGB)"

    sampling = expected_sampling()
    man = write_manifest(tmp_path / "man", sampling, list(expected_linear()), color_space=SRGB)
    for p in (man, man / "btf.json"):
        btf = open_btf(p)
        assert type(btf) is FileBTF and btf.n_samples == N
    with pytest.raises(BTFError, match="declares its own"):
        open_btf(man, color_space=SRGB)


def test_is_ubo(png_folder, tmp_path):
    assert is_ubo(png_folder) and is_ubo(png_folder.parent)
    assert is_ubo(make_zip(png_folder, tmp_path / "ubosniff.zip"))
    (tmp_path / "empty").mkdir()
    (tmp_path / "notes.txt").write_text("x")
    assert not is_ubo(tmp_path / "empty")
    assert not is_ubo(tmp_path / "notes.txt")
    assert not is_ubo(tmp_path / "missing")


@pytest.mark.parametrize("what", ["empty folder", "text file", "missing"])
def test_open_btf_rejects_unknown_input(tmp_path, what):
    p = tmp_path / {"empty folder": "plain", "text file": "plain.txt", "missing": "nothing"}[what]
    if what == "empty folder":
        p.mkdir()
    elif what == "text file":
        p.write_text("x")
    with pytest.raises(BTFError) as exc:
        open_btf(p)
    assert p.name in str(exc.value)
    if what != "missing":
        assert "btf-manifest/1" in str(exc.value) and "UBO2003" in str(exc.value)


# --------------------------------------------------------------------------- errors


def test_not_a_zip(tmp_path):
    bad = tmp_path / "garbage.zip"
    bad.write_bytes(b"this is not a zip archive" * 10)
    with pytest.raises(BTFError, match="garbage.zip: not a zip"):
        read_ubo(bad)
    with pytest.raises(BTFError, match="garbage.zip"):
        open_btf(bad)


def test_truncated_zip(png_folder, tmp_path):
    z = make_zip(png_folder, tmp_path / "ubotrunc.zip")
    z.write_bytes(z.read_bytes()[: z.stat().st_size // 2])  # central directory gone
    with pytest.raises(BTFError, match="ubotrunc.zip"):
        read_ubo(z)


def test_corrupt_zip_member(png_folder, tmp_path):
    z = make_zip(png_folder, tmp_path / "ubocrc.zip", compression=zipfile.ZIP_STORED)
    member = "tv015_pv060/" + file_name(N - 1 - (2 * len(VIEWS) + 2), (15, 60), (15, 60), "png")
    with zipfile.ZipFile(z) as zf:
        info = zf.getinfo(member)
    raw = bytearray(z.read_bytes())
    name_len, extra_len = struct.unpack("<HH", raw[info.header_offset + 26: info.header_offset + 30])
    start = info.header_offset + 30 + name_len + extra_len
    raw[start + info.compress_size // 2] ^= 0xFF  # the CRC no longer matches
    z.write_bytes(bytes(raw))
    with pytest.raises(BTFError) as exc:
        read_ubo(z)
    assert "ubocrc.zip" in str(exc.value) and member in str(exc.value)
    assert caches("ubocrc") == []  # the partial extraction was removed


def test_no_matching_images(tmp_path):
    z = tmp_path / "ubonone.zip"
    with zipfile.ZipFile(z, "w") as zf:
        zf.writestr("UBO_X/readme.txt", "nothing here")
        zf.writestr("UBO_X/preview.jpg", "not an image either")
    with pytest.raises(BTFError, match="ubonone.zip: no UBO2003 images") as exc:
        read_ubo(z)
    assert "preview.jpg" in str(exc.value)
    (tmp_path / "views" / "tv000_pv000").mkdir(parents=True)
    with pytest.raises(BTFError, match="views: no UBO2003 images"):
        read_ubo(tmp_path / "views")


def test_unparseable_name_in_view_folder(png_folder, tmp_path):
    z = make_zip(png_folder, tmp_path / "ubobadname.zip", extra={"tv015_pv000/image7.png": b"x"})
    with pytest.raises(BTFError) as exc:
        read_ubo(z)
    assert "ubobadname.zip" in str(exc.value) and "tv015_pv000/image7.png" in str(exc.value)
    assert "cannot parse" in str(exc.value)


def test_folder_disagrees_with_name(tmp_path):
    folder = make_dataset(tmp_path / "d")
    src = folder / "tv015_pv060" / file_name(N - 1 - (3 * len(VIEWS) + 2), (15, 60), (30, 0), "png")
    dst = folder / "tv015_pv000" / src.name  # name says tv015 pv060, folder says pv000
    src.rename(dst)
    with pytest.raises(BTFError) as exc:
        read_ubo(folder)
    assert str(folder) in str(exc.value) and f"tv015_pv000/{src.name}" in str(exc.value)
    assert "disagrees" in str(exc.value)


@pytest.mark.parametrize("light", [(15, 0), (0, 90)], ids=["same name", "pole, other phi"])
def test_duplicate_pairs(tmp_path, light):
    folder = make_dataset(tmp_path / "d")
    dup = folder / "tv015_pv000" / file_name(99, (15, 0), light, "png")
    write_image(dup, sample_codes(0, 0, "png"), color_space=SRGB)
    with pytest.raises(BTFError, match="same view and light") as exc:
        read_ubo(folder)
    assert dup.name in str(exc.value) and str(folder) in str(exc.value)


def test_theta_out_of_range(tmp_path):
    folder = make_dataset(tmp_path / "d")
    bad = folder / "tv015_pv000" / file_name(99, (15, 0), (95, 0), "png")
    write_image(bad, sample_codes(0, 0, "png"), color_space=SRGB)
    with pytest.raises(BTFError, match="theta out of range") as exc:
        read_ubo(folder)
    assert bad.name in str(exc.value)


def test_bad_color_space_override(png_folder):
    with pytest.raises(BTFError, match="NoSuchSpace") as exc:
        read_ubo(png_folder, color_space="NoSuchSpace")
    assert str(png_folder) in str(exc.value)


def test_mixed_sizes_raise_on_read_naming_zip_member(tmp_path):
    folder = make_dataset(tmp_path / "d")
    small = folder / "tv015_pv060" / file_name(N - 1 - (1 * len(VIEWS) + 2), (15, 60), (15, 0), "png")
    write_image(small, np.zeros((8, 8, 3), np.uint8), color_space=SRGB)
    btf = read_ubo(make_zip(folder, tmp_path / "ubosizes.zip"))
    btf.read_samples(slice(0, 4))  # the well-sized samples read fine
    with pytest.raises(BTFError) as exc:
        btf.read_samples(slice(None))
    msg = str(exc.value)
    assert f"ubosizes.zip:tv015_pv060/{small.name}" in msg and "expected 16x16" in msg
    assert btf.cache_dir not in msg  # the user's names, not the cache's


def test_member_stored_twice(png_folder, tmp_path):
    z = make_zip(png_folder, tmp_path / "ubotwice.zip")
    member = "tv000_pv000/" + file_name(N - 1, (0, 0), (0, 0), "png")
    with pytest.warns(UserWarning, match="Duplicate name"), zipfile.ZipFile(z, "a") as zf:
        zf.writestr(member, b"second copy")
    with pytest.raises(BTFError, match="stored twice") as exc:
        read_ubo(z)
    assert "ubotwice.zip" in str(exc.value) and member in str(exc.value)
