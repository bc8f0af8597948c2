"""UBO2003 reader (usdbtf.ubo) and the open_btf dispatch (usdbtf.io).

Every dataset here is built on the fly: 3 views x 4 lights at 16 x 16, each sample a
distinct known colour, written as real PNG / JPEG / EXR files through OpenImageIO.
"""
from __future__ import annotations

import os
import pickle
import struct
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from cli_helpers import run
from usdbtf import cli, color
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
    return color.processor(SRGB, "scene_linear").apply(codes.astype(np.float32) / 255.0)


def expected_sampling():
    return cross(np.array(VIEWS, float), np.array(LIGHTS, float))


def data_error_status() -> int:
    """A BTFError's exit status: BTFError.exit_code (65) once the CLI maps exit codes (the
    safety branch); the CLI on this branch still returns EXIT_BAD_INPUT (2) for all."""
    return getattr(cli, "EXIT_BAD_INPUT", BTFError.exit_code)


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
    assert not btf.archive and btf.paths[0].startswith(str(png_folder))
    # PNG is lossless: the values are exactly OCIO's decode of the known codes.
    np.testing.assert_allclose(btf.read_samples(slice(None)), expected_linear(), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(btf.read_rows(3, 7), expected_linear()[:, 3:7], rtol=1e-5, atol=1e-7)


def test_underscore_separators(tmp_path):
    btf = read_ubo(make_dataset(tmp_path / "d", sep="_"))
    np.testing.assert_array_equal(btf.sampling.view, expected_sampling().view)


@pytest.fixture
def private_tmpdir(tmp_path, monkeypatch) -> Path:
    """A fresh, empty temporary directory for this test (``tempfile`` and ``$TMPDIR``)."""
    d = tmp_path / "tmpdir"
    d.mkdir()
    monkeypatch.setenv("TMPDIR", str(d))
    monkeypatch.setattr(tempfile, "tempdir", str(d))
    return d


@pytest.mark.parametrize("top", [None, "UBO_TEST16"])
def test_zip_jpeg_values_read_in_place(jpg_folder, tmp_path, private_tmpdir, top):
    zpath = make_zip(jpg_folder, tmp_path / f"ubojpg{top or ''}.zip", top=top)
    btf = read_ubo(zpath)
    assert isinstance(btf, UBOBTF) and btf.archive
    np.testing.assert_array_equal(btf.sampling.light, expected_sampling().light)
    assert btf.names[1] == (f"{top}/" if top else "") + "tv000_pv000/" + file_name(N - 1 - 3, (0, 0), (15, 0), "jpg")
    got = btf.read_samples(slice(None))
    # Compare in code values: re-encode the decoded linear values to sRGB; JPEG q95 on flat
    # 16x16 patches is within a few codes of the source.
    back = color.processor("scene_linear", SRGB).apply(got) * 255.0
    codes = np.stack([sample_codes(vi, li, "jpg") for vi in range(len(VIEWS)) for li in range(len(LIGHTS))])
    assert np.abs(back - codes).max() <= 3.0
    # Read in place: nothing in $TMPDIR, nothing beside the zip, no descriptor left open.
    assert list(private_tmpdir.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([zpath.name, "tmpdir"])
    fds = len(os.listdir("/proc/self/fd"))
    btf.read_samples([0, 5])
    assert len(os.listdir("/proc/self/fd")) == fds


def test_zip_values_identical_to_folder(png_folder, tmp_path):
    folder = read_ubo(png_folder).read_samples(slice(None))
    btf = read_ubo(make_zip(png_folder, tmp_path / "uboclose.zip"))
    np.testing.assert_array_equal(btf.read_samples(slice(None)), folder)
    np.testing.assert_array_equal(btf.read_rows(3, 7), folder[:, 3:7])
    btf.close()
    btf.close()  # idempotent; a later read reopens the archive
    np.testing.assert_array_equal(btf.read_samples([0, 5]), folder[[0, 5]])
    clone = pickle.loads(pickle.dumps(btf))
    np.testing.assert_array_equal(clone.read_samples([7]), folder[[7]])


def test_float_files_default_to_scene_linear_and_override(tmp_path):
    folder = make_dataset(tmp_path / "hdr", ext="exr", dtype=np.float16)
    btf = read_ubo(folder)
    assert btf.bit_depth == "half"
    assert btf.color_space == color.resolve_space("scene_linear")
    stored = np.stack([sample_codes(vi, li, "exr") for vi in range(len(VIEWS)) for li in range(len(LIGHTS))])
    stored = (stored / 255.0).astype(np.float16).astype(np.float32)
    np.testing.assert_array_equal(btf.read_samples(slice(None)), stored)
    other = read_ubo(folder, color_space="Linear Rec.709 (sRGB)")
    assert other.color_space == "Linear Rec.709 (sRGB)"
    np.testing.assert_allclose(other.read_samples([2])[0],
                               color.processor("Linear Rec.709 (sRGB)", "scene_linear").apply(stored[2]), rtol=1e-6)


def test_non_image_and_hidden_members_are_listed_not_dropped(png_folder, tmp_path, capsys):
    extra = {"readme.txt": b"hello", "__MACOSX/tv000_pv000/._00011 tl000 pl000 tv000 pv000.png": b"junk",
             "preview.png": b"not looked at"}
    z = make_zip(png_folder, tmp_path / "uboextra.zip", extra=extra)
    btf = read_ubo(z)
    assert btf.n_samples == N
    assert sorted(btf.ignored) == sorted(extra)
    code, out, err = run(capsys, "info", z)
    assert code == 0, err
    assert "ignored     3 member(s) that are not samples" in out


@pytest.mark.parametrize("member", ["../evil tl000 pl000 tv075 pv000.png",
                                    "../../../../x/tv000_pv000/00000 tl000 pl000 tv000 pv000.png",
                                    "/abs/tv000_pv000/00000 tl000 pl000 tv000 pv000.png",
                                    "C:\\tv000_pv000\\00000 tl000 pl000 tv000 pv000.png"],
                         ids=["dotdot", "deep dotdot", "absolute", "drive"])
def test_zip_member_outside_archive_is_an_error(png_folder, tmp_path, capsys, member):
    zdir = tmp_path / "z"
    zdir.mkdir()
    z = make_zip(png_folder, zdir / "uboslip.zip", extra={member: b"x"})
    with pytest.raises(BTFError) as exc:
        read_ubo(z)
    assert "uboslip.zip" in str(exc.value) and repr(member) in str(exc.value)
    # Through the CLI: one line naming the member, no output, nothing written anywhere.
    code, out, err = run(capsys, "compress", z, "-o", tmp_path / "c", "--k", "2")
    assert code == data_error_status() and repr(member) in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["z"] and os.listdir(zdir) == ["uboslip.zip"]


def test_folder_links_outside_are_errors_inside_followed(tmp_path):
    folder = make_dataset(tmp_path / "d")
    (tmp_path / "elsewhere").mkdir()
    moved = tmp_path / "elsewhere" / "tv015_pv060"
    (folder / "tv015_pv060").rename(moved)
    (folder / "tv015_pv060").symlink_to(moved)
    with pytest.raises(BTFError, match=r"tv015_pv060 links to .*elsewhere.*outside the folder"):
        read_ubo(folder)
    (folder / "tv015_pv060").unlink()
    (folder / "inner").mkdir()
    moved.rename(folder / "inner" / "tv015_pv060")
    (folder / "tv015_pv060").symlink_to(folder / "inner" / "tv015_pv060")
    btf = read_ubo(folder)  # a link that stays inside is followed (and its target not read twice)
    assert btf.n_samples == N


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
    btf = read_ubo(z)  # members are read in place: the damage shows when the sample is read
    btf.read_samples(slice(0, 4))
    with pytest.raises(BTFError) as exc:
        btf.read_samples(slice(None))
    assert f"ubocrc.zip:{member}" in str(exc.value) and "Bad CRC" in str(exc.value)


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
    assert "/proc/self/fd" not in msg  # the user's names, not the in-memory copy's


def test_member_stored_twice(png_folder, tmp_path):
    z = make_zip(png_folder, tmp_path / "ubotwice.zip")
    member = "tv000_pv000/" + file_name(N - 1, (0, 0), (0, 0), "png")
    with pytest.warns(UserWarning, match="Duplicate name"), zipfile.ZipFile(z, "a") as zf:
        zf.writestr(member, b"second copy")
    with pytest.raises(BTFError, match="stored twice") as exc:
        read_ubo(z)
    assert "ubotwice.zip" in str(exc.value) and member in str(exc.value)


# --------------------------------------------------------------------------- UTIA, ATRIUM


def _write_undeclared(path: Path, pixels: np.ndarray, attributes: dict | None = None) -> None:
    """An image file with no colour-space declaration (write_image always declares one)."""
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], 3, "half")
    for key, value in (attributes or {}).items():
        spec.attribute(key, oiio.TypeDesc("float[8]"), value)
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec) and out.write_image(np.ascontiguousarray(pixels))
    out.close()


def utia_folder(root: Path, chromaticities=None) -> tuple[Path, np.ndarray]:
    """UTIA naming (btf.utia.cas.cz: ``tv000_pv000/tl000_pl000_tv000_pv000.exr``), half
    EXR without a colour-space declaration; returns (folder, stored values view-major)."""
    stored = []
    for vi, view in enumerate(VIEWS):
        d = root / f"tv{view[0]:03d}_pv{view[1]:03d}"
        d.mkdir(parents=True, exist_ok=True)
        for li, light in enumerate(LIGHTS):
            img = (sample_codes(vi, li, "exr") / 255.0).astype(np.float16)
            name = f"tl{light[0]:03d}_pl{light[1]:03d}_tv{view[0]:03d}_pv{view[1]:03d}.exr"
            _write_undeclared(d / name, img, {"chromaticities": chromaticities} if chromaticities else None)
            stored.append(img.astype(np.float32))
    return root, np.stack(stored)


@pytest.mark.parametrize("declared", [False, True], ids=["undeclared", "XYZ chromaticities"])
def test_utia_exr_is_xyz_d65_through_ocio(tmp_path, capsys, declared):
    folder, stored = utia_folder(tmp_path / "utia", (1, 0, 0, 1, 0, 0, 1 / 3, 1 / 3) if declared else None)
    btf = open_btf(folder)
    assert btf.color_space == "CIE XYZ-D65 - Scene-referred" and btf.bit_depth == "half"
    np.testing.assert_array_equal(btf.sampling.view, expected_sampling().view)
    want = color.processor("CIE XYZ-D65 - Scene-referred", "scene_linear").apply(stored)
    np.testing.assert_allclose(btf.read_samples(slice(None)), want, rtol=1e-6, atol=1e-7)
    assert not np.allclose(want, stored, atol=1e-3)  # the conversion did something
    code, out, err = run(capsys, "info", folder)
    assert "UTIA (UBO2003 layout) BTF, 3 views x 4 lights = 12 samples of 16x16 texels" in out
    assert "half CIE XYZ-D65 - Scene-referred" in out


def _rgbe(pixels: np.ndarray) -> bytes:
    """Flat (not run-length encoded) Radiance RGBE pixels."""
    m = pixels.max(axis=-1)
    e = np.floor(np.log2(np.maximum(m, 1e-30))) + 1
    scale = np.ldexp(1.0, (8 - e).astype(int))
    mant = np.clip(np.floor(pixels * scale[..., None]), 0, 255).astype(np.uint8)
    return np.concatenate([mant, (e + 128).astype(np.uint8)[..., None]], axis=-1).tobytes()


def test_atrium_hdr_column_major_header_is_reoriented(tmp_path):
    """ATRIUM's HDRs carry ``+X N -Y N`` (btf-extractor's AtriumHdr): per the Radiance format
    a column-major image, which OIIO flags as orientation 5 and usdbtf turns upright."""
    w, h = 6, 4   # not square: a missed transpose changes the shape
    folder = tmp_path / "CEILING_HDR"
    truth = []
    for vi, view in enumerate(VIEWS):
        d = folder / f"tv{view[0]:03d}_pv{view[1]:03d}"
        d.mkdir(parents=True)
        for li, light in enumerate(LIGHTS):
            img = 0.2 + 0.05 * (vi * len(LIGHTS) + li) + 0.1 * np.arange(h)[:, None, None] + 0.01 * np.arange(w)[:, None]
            img = np.broadcast_to(img, (h, w, 3)) * np.array([1.0, 0.8, 0.6])
            header = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n+X {w} -Y {h}\n".encode()
            (d / f"tl{light[0]:03d} pl{light[1]:03d} tv{view[0]:03d} pv{view[1]:03d}.hdr").write_bytes(
                header + _rgbe(img.transpose(1, 0, 2)))       # X the slow axis: columns, each top to bottom
            truth.append(img)
    z = make_zip(folder, tmp_path / "CEILING_HDR.zip", top="CEILING_HDR")
    for src in (folder, z):
        btf = read_ubo(src)
        assert (btf.width, btf.height, btf.orientation) == (w, h, 5)
        assert btf.color_space == "Linear Rec.709 (sRGB)" and btf.metadata["format"] == "ATRIUM (UBO2003 layout)"
        got = btf.read_encoded(slice(None))
        np.testing.assert_allclose(got, np.stack(truth), rtol=0.02)
        np.testing.assert_array_equal(btf.read_encoded([3], rows=(1, 3)), got[[3], 1:3])


# --------------------------------------------------------------------------- kill -9


def test_kill_during_zip_input_leaves_tmpdir_empty(png_folder, tmp_path):
    import signal
    import subprocess
    import sys

    z = make_zip(png_folder, tmp_path / "ubokill.zip")
    tmpdir = tmp_path / "tmpdir"
    tmpdir.mkdir()
    script = ("import sys\nfrom usdbtf.ubo import read_ubo\nb = read_ubo(sys.argv[1])\nfirst = True\n"
              "while True:\n    b.read_samples(slice(None))\n    if first:\n        print('ready', flush=True)\n"
              "        first = False\n")
    env = dict(os.environ, TMPDIR=str(tmpdir))
    proc = subprocess.Popen([sys.executable, "-c", script, str(z)], stdout=subprocess.PIPE, env=env)
    try:
        assert proc.stdout.readline().strip() == b"ready"
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait(10)
    assert proc.returncode == -signal.SIGKILL
    assert list(tmpdir.iterdir()) == []
