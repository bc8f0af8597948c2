"""Bad input to the manifest reader and the data model: every case raises BTFError naming
the offending file or sample, at open time or (for pixel problems) when pixels are read.
Also: failed writes leave nothing behind (write_manifest, atomic_dir), and atomic_dir replaces
only a previous usdbtf output of the same kind."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from usdbtf.atomic import atomic_dir
from usdbtf.errors import BTFError, OutputRefused
from usdbtf.imageio import write_image
from usdbtf.manifest import MANIFEST, read_manifest, write_manifest
from usdbtf.sampling import Sampling

SRGB = "sRGB Encoded Rec.709 (sRGB)"
SIZE = 8
# One view at the pole, four lights on a ring: (theta, phi) degrees.
VIEW = [0.0, 0.0]
LIGHTS = [[30.0, 0.0], [30.0, 90.0], [30.0, 180.0], [30.0, 270.0]]
NAMES = ["a", "b", "c", "d"]


def write_sample(folder: Path, name: str, dtype=np.uint8, size=(SIZE, SIZE), channels=3, value=0.25, space=SRGB):
    """One image file; integer dtypes hold ``value`` scaled to full range, floats hold ``value``."""
    shape = (size[1], size[0], channels)
    if np.dtype(dtype).kind == "u":
        img = np.full(shape, round(value * np.iinfo(dtype).max), dtype)
    else:
        img = np.full(shape, value, dtype)
    write_image(folder / name, img, color_space=space)


def make_manifest(folder: Path, ext: str = "png", dtype=np.uint8, space: str = SRGB) -> dict:
    """A valid 4-sample manifest folder; returns its document (edit it, then ``dump``)."""
    folder.mkdir(parents=True, exist_ok=True)
    samples = []
    for name, light in zip(NAMES, LIGHTS):
        write_sample(folder, f"{name}.{ext}", dtype, space=space)
        samples.append({"image": f"{name}.{ext}", "view": list(VIEW), "light": list(light)})
    doc = {"format": "btf-manifest/1", "color_space": space, "width": SIZE, "height": SIZE, "samples": samples}
    dump(folder, doc)
    return doc


def dump(folder: Path, doc) -> None:
    (folder / MANIFEST).write_text(json.dumps(doc))


@pytest.fixture
def folder(tmp_path) -> Path:
    return tmp_path / "btf"


def raises_naming(name: str, fn, *args, match: str | None = None) -> BTFError:
    """Call fn(*args); it must raise BTFError whose message contains ``name``."""
    with pytest.raises(BTFError, match=match) as exc:
        fn(*args)
    assert name in str(exc.value), str(exc.value)
    return exc.value


def read_all(btf):
    """Every way of reading pixels, so pixel errors are checked on each path."""
    return [lambda: btf.read_samples(slice(None)), lambda: list(btf.iter_chunks(2)), lambda: btf.read_rows(2, 5)]


def test_valid_manifest_reads(folder):
    make_manifest(folder)
    btf = read_manifest(folder)
    assert btf.shape == (4, SIZE, SIZE, 3)
    assert np.isfinite(btf.read_samples(slice(None))).all()


# --------------------------------------------------------------------------- files


@pytest.mark.parametrize("name", ["a.png", "c.png"], ids=["first", "later"])
def test_missing_image_file(folder, name):
    make_manifest(folder)
    (folder / name).unlink()
    raises_naming(name, read_manifest, folder, match="not found")


def test_corrupt_first_image_fails_at_open(folder):
    make_manifest(folder)
    (folder / "a.png").write_bytes(b"\x00garbage, not a PNG" * 8)
    raises_naming("a.png", read_manifest, folder, match="cannot read image")


@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_corrupt_later_image_fails_at_read(folder, damage):
    make_manifest(folder)
    rng = np.random.default_rng(0)
    # Noise does not compress, so cutting the file in half really removes pixel data.
    write_image(folder / "c.png", rng.integers(0, 256, (SIZE, SIZE, 3)).astype(np.uint8), color_space=SRGB)
    raw = (folder / "c.png").read_bytes()
    (folder / "c.png").write_bytes(b"\x89garbage" * 20 if damage == "garbage" else raw[: len(raw) // 2])
    btf = read_manifest(folder)  # only the first header is read at open
    btf.read_samples([0, 1])
    for read in read_all(btf):
        raises_naming("c.png", read)


def test_mixed_image_sizes(folder):
    make_manifest(folder)
    write_sample(folder, "b.png", size=(SIZE, SIZE + 2))
    btf = read_manifest(folder)
    for read in read_all(btf):
        raises_naming("b.png", read, match=f"expected {SIZE}x{SIZE}")


def test_size_in_manifest_disagrees_with_files(folder):
    # Checked at open, against the first image's header: nothing is allocated for a size
    # the files do not have (a manifest declaring 100000^2 fails at once).
    doc = make_manifest(folder)
    doc["width"] = SIZE * 2
    dump(folder, doc)
    raises_naming("a.png", read_manifest, folder, match=f"declares {2 * SIZE}x{SIZE}")


def test_unsupported_channel_count(folder):
    make_manifest(folder)
    write_sample(folder, "d.png", channels=2)  # grey + alpha
    btf = read_manifest(folder)
    for read in read_all(btf):
        raises_naming("d.png", read, match="channel count 2")


def test_wrong_bit_depth(folder):
    make_manifest(folder)
    write_sample(folder, "c.png", dtype=np.uint16)
    btf = read_manifest(folder)
    assert btf.bit_depth == "uint8"
    for read in read_all(btf):
        raises_naming("c.png", read, match="bit depth uint16")


@pytest.mark.parametrize("dtype", [np.float16, np.float32], ids=["half", "float"])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -0.5], ids=["nan", "inf", "negative"])
def test_non_finite_or_negative_exr_pixels(folder, dtype, bad):
    make_manifest(folder, ext="exr", dtype=dtype, space="ACEScg")
    img = np.full((SIZE, SIZE, 3), 0.25, dtype)
    img[3, 4, 1] = bad  # one texel, in the rows read_rows(2, 5) covers
    write_image(folder / "b.exr", img, color_space="ACEScg", allow_non_finite=True)
    btf = read_manifest(folder)
    assert btf.bit_depth == ("half" if dtype == np.float16 else "float")
    btf.read_samples([0, 2, 3])
    for read in read_all(btf):
        raises_naming("b.exr", read, match="NaN or Inf" if np.isnan(bad) or np.isinf(bad) else "negative")


# --------------------------------------------------------------------------- directions


def test_duplicate_directions(folder):
    doc = make_manifest(folder)
    doc["samples"][2]["light"] = list(LIGHTS[1])
    dump(folder, doc)
    exc = raises_naming("c.png", read_manifest, folder, match="same view and light")
    assert "b.png" in str(exc)


@pytest.mark.parametrize("key", ["view", "light"])
def test_duplicate_directions_at_the_pole(folder, key):
    # theta = 0 with different phi is one direction: the azimuth of the normal is meaningless.
    doc = make_manifest(folder)
    doc["samples"][0][key] = [0.0, 0.0]
    doc["samples"][3][key] = [0.0, 120.0]
    if key == "view":  # make the lights equal too, so the pairs coincide
        doc["samples"][3]["light"] = list(doc["samples"][0]["light"])
    dump(folder, doc)
    exc = raises_naming("d.png", read_manifest, folder, match="same view and light")
    assert "a.png" in str(exc)


def test_phi_wrapping_duplicates(folder):
    doc = make_manifest(folder)
    doc["samples"][1]["light"] = [30.0, 360.0]  # = phi 0, sample a's light
    dump(folder, doc)
    raises_naming("b.png", read_manifest, folder, match="same view and light")


@pytest.mark.parametrize("key", ["view", "light"])
@pytest.mark.parametrize("theta", [95.0, -5.0])
def test_theta_out_of_range(folder, key, theta):
    doc = make_manifest(folder)
    doc["samples"][1][key] = [theta, 10.0]
    dump(folder, doc)
    raises_naming("b.png", read_manifest, folder, match="theta out of range")


# --------------------------------------------------------------------------- manifest keys


@pytest.mark.parametrize("samples", [[], None, "a.png", {}], ids=["empty", "null", "string", "object"])
def test_empty_or_missing_samples(folder, samples):
    doc = make_manifest(folder)
    if samples is None:
        del doc["samples"]
    else:
        doc["samples"] = samples
    dump(folder, doc)
    raises_naming(MANIFEST, read_manifest, folder, match="samples")


@pytest.mark.parametrize("key,value,match", [
    ("format", "btf-manifest/2", "format"),
    ("format", None, "format"),
    ("width", "8", "width"),
    ("width", 8.0, "width"),
    ("height", True, "height"),
    ("height", 0, "height"),
    ("width", None, "width"),
    ("color_space", "No Such Space", "No Such Space"),
    ("color_space", 7, "color_space"),
    ("color_space", None, "color_space"),
])
def test_invalid_top_level_keys(folder, key, value, match):
    doc = make_manifest(folder)
    if value is None:
        del doc[key]
    else:
        doc[key] = value
    dump(folder, doc)
    raises_naming(MANIFEST, read_manifest, folder, match=match)


@pytest.mark.parametrize("key,value", [
    ("view", [10.0]),
    ("view", "10 20"),
    ("view", [10.0, "a"]),
    ("view", [10.0, 20.0, 30.0]),
    ("light", None),
    ("light", [True, 0]),
    ("view", {"theta": 10, "phi": 0}),
])
def test_invalid_direction_keys(folder, key, value):
    doc = make_manifest(folder)
    if value is None:
        del doc["samples"][2][key]
    else:
        doc["samples"][2][key] = value
    dump(folder, doc)
    exc = raises_naming("c.png", read_manifest, folder, match=key)
    assert MANIFEST in str(exc)


@pytest.mark.parametrize("theta", ["nan", "inf"])
def test_non_finite_direction(folder, theta):
    doc = make_manifest(folder)
    doc["samples"][1]["view"] = [float(theta), 0.0]  # json.dumps writes NaN / Infinity, json.loads reads them
    dump(folder, doc)
    raises_naming("b.png", read_manifest, folder, match="finite")


@pytest.mark.parametrize("sample", [{"view": [0, 0], "light": [10, 0]}, {"image": 3, "view": [0, 0], "light": [10, 0]}, "c.png"])
def test_sample_without_image_name(folder, sample):
    doc = make_manifest(folder)
    doc["samples"][2] = sample
    dump(folder, doc)
    exc = raises_naming(MANIFEST, read_manifest, folder, match="image")
    assert "#2" in str(exc)


def test_not_json(folder):
    make_manifest(folder)
    (folder / MANIFEST).write_text("{ not json")
    raises_naming(MANIFEST, read_manifest, folder, match="JSON")


def test_no_manifest(tmp_path):
    raises_naming(MANIFEST, read_manifest, tmp_path, match="not found")


# --------------------------------------------------------------------------- atomic writes


def _images(n_good: int, bad):
    """Yield n_good valid images, then either raise ``bad`` (an exception) or yield it (an array)."""
    for _ in range(n_good):
        yield np.full((SIZE, SIZE, 3), 0.18, np.float32)
    if isinstance(bad, BaseException):
        raise bad
    yield bad


SAMPLING = Sampling(np.array([VIEW] * 4), np.array(LIGHTS))


@pytest.mark.parametrize("bad", [RuntimeError("decoder crashed"), np.full((SIZE, SIZE, 3), np.nan, np.float32),
                                 np.zeros((SIZE + 1, SIZE, 3), np.float32)], ids=["raises", "nan", "size"])
def test_write_manifest_failure_leaves_nothing(tmp_path, bad):
    parent = tmp_path / "out"
    parent.mkdir()
    with pytest.raises((RuntimeError, BTFError)):
        write_manifest(parent / "btf", SAMPLING, _images(2, bad), color_space=SRGB)
    assert list(parent.iterdir()) == []  # no target, no .btf.tmp-* folder


def test_write_manifest_failure_keeps_old_output(tmp_path):
    target = tmp_path / "btf"
    write_manifest(target, SAMPLING, _images(3, np.full((SIZE, SIZE, 3), 0.5, np.float32)), color_space=SRGB)
    before = {p.name: p.read_bytes() for p in target.iterdir()}
    with pytest.raises(RuntimeError):
        write_manifest(target, SAMPLING, _images(1, RuntimeError("midway")), color_space=SRGB)
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["btf"]
    assert read_manifest(target).n_samples == 4


def test_write_manifest_too_few_images(tmp_path):
    with pytest.raises(BTFError, match="3 images for 4 samples"):
        write_manifest(tmp_path / "btf", SAMPLING, _images(2, np.full((SIZE, SIZE, 3), 0.5, np.float32)), color_space=SRGB)
    assert list(tmp_path.iterdir()) == []


def _tiny_manifest(target: Path, value: float = 0.5) -> Path:
    images = (np.full((SIZE, SIZE, 3), value, np.float32) for _ in range(4))
    return write_manifest(target, SAMPLING, images, color_space=SRGB)


def test_atomic_dir_replaces_only_on_success(tmp_path):
    target = tmp_path / "out"
    _tiny_manifest(target, 0.25)
    before = {p.name: p.read_bytes() for p in target.iterdir()}

    with pytest.raises(ValueError):
        with atomic_dir(target) as tmp:
            (tmp / "new.txt").write_text("new")
            raise ValueError("fail midway")
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]

    with atomic_dir(target) as tmp:
        assert tmp.parent.parent.parent == tmp_path and tmp.name == "out" and tmp != target
        _tiny_manifest(tmp / "x", 0.75)          # a manifest of its own, then moved into place
        for p in (tmp / "x").iterdir():
            p.rename(tmp / p.name)
        (tmp / "x").rmdir()
        assert {p.name: p.read_bytes() for p in target.iterdir()} == before  # old until new is complete
    assert {p.name: p.read_bytes() for p in target.iterdir()} != before
    assert read_manifest(target).n_samples == 4
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no staging folder, no lock left

    with pytest.raises(OutputRefused):
        with atomic_dir(target, overwrite=False):
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_atomic_dir_never_replaces_what_usdbtf_did_not_make(tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with pytest.raises(OutputRefused, match="not a usdbtf"):
        with atomic_dir(target) as tmp:
            (tmp / "new.txt").write_text("new")
    assert sorted(p.name for p in target.iterdir()) == ["old.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
