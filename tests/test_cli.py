"""The ``usdbtf`` command line: synth -> compress -> decompress -> error -> info, the
options that steer compression, and bad input (exit status 65 for bad data, 2 for a wrong
command line; one stderr line naming the file, nothing written).

Most tests call :func:`usdbtf.cli.main` in-process (fast); one smoke test runs the
installed console script in a subprocess.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from usdbtf import color, synth
from usdbtf.cli import main

from cli_helpers import bad_input, bad_usage, ok, refused, run  # noqa: E402
from usdbtf.compress import read_compressed, reconstruct
from usdbtf.compress.decompress import compare
from usdbtf.compress.format import METADATA
from usdbtf.manifest import encode_for_file, read_manifest
from usdbtf.sampling import preset

SRGB = "sRGB Encoded Rec.709 (sRGB)"
LIN709 = "Linear Rec.709 (sRGB)"
ROOT = Path(__file__).resolve().parent.parent


def copy_tree(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def sample_file(folder: Path, i: int) -> Path:
    doc = json.loads((folder / "btf.json").read_text())
    return folder / doc["samples"][i]["image"]


def percent(btf, fn, indices=None) -> dict:
    return compare(btf, fn, indices)


# ---------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("cli")


@pytest.fixture(scope="module")
def src(work) -> Path:
    """`usdbtf synth`: 24 samples (tiny) of 32x32 pebbles, 8-bit sRGB PNG."""
    folder = work / "src"
    assert main(["synth", "pebbles", "-o", str(folder), "--sampling", "tiny", "--size", "32", "-q"]) == 0
    return folder


@pytest.fixture(scope="module")
def compressed(src, work) -> Path:
    out = work / "c8"
    assert main(["compress", str(src), "-o", str(out), "--k", "8", "-q"]) == 0
    return out


# ---------------------------------------------------------------- synth


def test_synth_writes_the_rendered_material(src):
    btf = read_manifest(src)
    assert (btf.n_samples, btf.width, btf.height, btf.bit_depth, btf.color_space) == (24, 32, 32, "uint8", SRGB)
    s = preset("tiny")
    np.testing.assert_array_equal(btf.sampling.view, s.view)
    np.testing.assert_array_equal(btf.sampling.light, s.light)
    want = encode_for_file(synth.render_all(synth.make_material("pebbles", 32, 0), s),
                           color.processor(LIN709, SRGB), "uint8")
    assert np.array_equal(btf.read_encoded(np.arange(24)), want)
    assert btf.metadata["physical_size_m"] == [0.05, 0.05]
    assert btf.metadata["synthetic"]["preset"] == "pebbles"


def test_synth_float_exr(capsys, tmp_path):
    ok(capsys, "synth", "ridged_fabric", "-o", tmp_path / "f", "--sampling", "tiny", "--size", "16",
       "--bit-depth", "float", "--format", "exr", "--seed", "3", "-q")
    btf = read_manifest(tmp_path / "f")
    assert (btf.bit_depth, btf.color_space) == ("float", LIN709)
    assert all(p.endswith(".exr") for p in btf.paths)
    want = synth.render_all(synth.make_material("ridged_fabric", 16, 3), preset("tiny"))
    assert np.array_equal(btf.read_encoded(np.arange(24)), want)


# ---------------------------------------------------------------- the whole chain


def test_compress_decompress_error_info_chain(capsys, src, compressed, work):
    orig = read_manifest(src)
    c = read_compressed(compressed)
    assert c.k == 8 and c.codec == "jxlp" and c.info["solver"] == "rsvd"
    assert (compressed / "basis.jxl").is_file() and len(list((compressed / "coeff").iterdir())) == 8
    assert (compressed / "error_curve.csv").is_file() and (compressed / "error_curve.png").is_file()
    # The source manifest's extra keys travel into the compressed metadata.
    assert c.info["source_metadata"]["physical_size_m"] == [0.05, 0.05]
    assert c.info["provenance"]["source"] == str(src)

    dec = work / "dec"
    ok(capsys, "decompress", compressed, "-o", dec, "-q")
    d = read_manifest(dec)
    assert (d.n_samples, d.width, d.height, d.bit_depth, d.color_space) == (24, 32, 32, "uint8", SRGB)

    report = json.loads(ok(capsys, "error", src, dec))
    assert set(report) >= {"linear", "encoded"} and report["samples"] == 24
    for dom in ("linear", "encoded"):
        assert set(report[dom]) == {"percent", "rmse", "psnr_db"}
    files = percent(orig, lambda sel: d.read_samples(sel))
    assert report["linear"]["percent"] == pytest.approx(files["linear"]["percent"], rel=1e-12)
    assert report["encoded"]["percent"] == pytest.approx(files["encoded"]["percent"], rel=1e-12)
    # The files are the encoded reconstruction, so the encoded error is that of the compressed BTF.
    direct = percent(orig, lambda sel: reconstruct(c, sel))
    assert report["encoded"]["percent"] == pytest.approx(direct["encoded"]["percent"], rel=1e-9)
    assert report["linear"]["percent"] == pytest.approx(direct["linear"]["percent"], rel=0.05)
    assert 0.5 < report["linear"]["percent"] < 20

    info = ok(capsys, "info", compressed)
    assert "compressed BTF (rsvd solver, jxlp codec)" in info
    assert "samples     24  (32x32 texels)" in info
    assert "k           8" in info
    assert f"payload {c.info['bytes']['payload']} " in info
    assert f"{c.info['estimated_error']['linear']['percent']:.3f} %" in info
    assert SRGB in info
    info_src = ok(capsys, "info", src)
    assert "btf-manifest/1 BTF, 4 views x 6 lights = 24 samples of 32x32 texels" in info_src
    assert "colour      uint8 " + SRGB in info_src and "interpolated 0" in info_src


def test_progress_goes_to_stderr_and_quiet_silences_it(capsys, src, tmp_path):
    code, out, err = run(capsys, "compress", src, "-o", tmp_path / "c", "--k", "2")
    assert code == 0 and out == ""
    assert "loaded 24 samples of 32x32" in err and "k = 2" in err
    code, out, err = run(capsys, "compress", src, "-o", tmp_path / "c", "--k", "2", "-q", "--force")
    assert code == 0 and out == "" and err == ""


def test_decompress_samples_and_k(capsys, src, compressed, work):
    orig = read_manifest(src)
    c = read_compressed(compressed)
    sub = work / "dec_sub"
    ok(capsys, "decompress", compressed, "-o", sub, "--samples", "0-3,7", "-q")
    d = read_manifest(sub)
    idx = np.array([0, 1, 2, 3, 7])
    assert d.n_samples == 5
    np.testing.assert_array_equal(d.sampling.view, orig.sampling.view[idx])
    np.testing.assert_array_equal(d.sampling.light, orig.sampling.light[idx])
    want = encode_for_file(reconstruct(c, idx), color.processor(c.working_space, SRGB), "uint8")
    assert np.array_equal(d.read_encoded(np.arange(5)), want)
    # `error` matches the partial reconstruction to the right original samples.
    report = json.loads(ok(capsys, "error", src, sub))
    assert report["samples"] == 5
    expect = percent(orig, lambda sel: d.read_samples(np.searchsorted(idx, sel)), idx)
    assert report["linear"]["percent"] == pytest.approx(expect["linear"]["percent"], rel=1e-12)
    # ... and --samples restricts it further.
    one = json.loads(ok(capsys, "error", src, sub, "--samples", "7"))
    assert one["samples"] == 1
    assert one["linear"]["percent"] == pytest.approx(
        percent(orig, lambda sel: d.read_samples([4]), [7])["linear"]["percent"], rel=1e-12)
    # Fewer basis vectors: larger error.
    k2 = work / "dec_k2"
    ok(capsys, "decompress", compressed, "-o", k2, "--samples", "0-3,7", "--k", "2", "-q")
    e2 = json.loads(ok(capsys, "error", src, k2))["linear"]["percent"]
    assert e2 > 1.2 * report["linear"]["percent"]
    assert json.loads((k2 / "btf.json").read_text())["reconstructed_from_k"] == 2


# ---------------------------------------------------------------- compress options


def test_solver_paper(capsys, src, tmp_path):
    out = tmp_path / "p"
    ok(capsys, "compress", src, "-o", out, "--solver", "paper", "--k", "6", "-q")
    assert (out / "basis.tif").is_file()
    assert sorted(p.name for p in (out / "coeff").iterdir()) == [f"c{i:03d}.jpg" for i in range(6)]
    doc = json.loads((out / METADATA).read_text())
    assert doc["solver"] == "paper" and doc["codec"] == "jpeg" and doc["k"] == 6
    assert doc["color_matrix"] == [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    assert "paper solver, jpeg codec" in ok(capsys, "info", out)


def test_codec_png(capsys, src, tmp_path):
    out = tmp_path / "png"
    ok(capsys, "compress", src, "-o", out, "--codec", "png", "--k", "4", "-q")
    assert (out / "basis.png").is_file()
    assert sorted(p.name for p in (out / "coeff").iterdir()) == [f"c{i:03d}.png" for i in range(4)]
    c = read_compressed(out)
    assert c.codec == "png"
    assert percent(read_manifest(src), lambda sel: reconstruct(c, sel))["linear"]["percent"] < 20


def test_max_bytes(capsys, src, tmp_path):
    out = tmp_path / "mb"
    ok(capsys, "compress", src, "-o", out, "--max-bytes", "9000", "--budget-for", "folder", "-q")
    c = read_compressed(out)
    payload = sum(p.stat().st_size for p in out.rglob("*.jxl"))
    assert c.info["bytes"]["payload"] == payload
    assert 0.6 * 9000 < payload <= 9000


def test_target_error(capsys, src, tmp_path):
    out = tmp_path / "te"
    ok(capsys, "compress", src, "-o", out, "--target-error", "4", "--error-domain", "linear", "-q")
    c = read_compressed(out)
    full = percent(read_manifest(src), lambda sel: reconstruct(c, sel))["linear"]["percent"]
    assert full <= 4 * 1.1
    assert c.k < 24
    # Issue 42: compress does not package an error target's choice only to count it (its
    # fallback fits were half the mode's time): the bytes it records are the folder's, and
    # `usdbtf package` counts the asset (the CLI's default --budget-for asset).
    choice = c.info["choice"]
    assert choice["budget_for"] == "asset" and choice["asset"] == {"counted_by": "usdbtf package"}
    assert choice["bytes"] == choice["folder_bytes"] == c.info["bytes"]["payload"]


def test_same_seed_same_output_other_seed_differs(capsys, src, tmp_path):
    for name, seed in (("a", 5), ("b", 5), ("c", 6)):
        ok(capsys, "compress", src, "-o", tmp_path / name, "--k", "5", "--seed", str(seed), "--fit-texels", "256", "-q")
    a, b, c = ((tmp_path / n / "basis.jxl").read_bytes() for n in "abc")
    assert a == b and a != c
    for i in range(5):
        assert (tmp_path / "a" / "coeff" / f"c{i:03d}.jxl").read_bytes() == \
            (tmp_path / "b" / "coeff" / f"c{i:03d}.jxl").read_bytes()


def test_output_is_replaced_with_force_only(capsys, src, tmp_path):
    out = tmp_path / "c"
    ok(capsys, "compress", src, "-o", out, "--k", "4", "-q")
    refused(capsys, "compress", src, "-o", out, "--k", "2", "-q", names="--force")
    assert len(list((out / "coeff").iterdir())) == 4
    ok(capsys, "compress", src, "-o", out, "--k", "2", "-q", "--force")
    assert sorted(p.name for p in (out / "coeff").iterdir()) == ["c000.jxl", "c001.jxl"]
    assert [p.name for p in tmp_path.iterdir()] == ["c"]


# ---------------------------------------------------------------- bad input


def test_missing_input_folder(capsys, tmp_path):
    bad_input(capsys, "compress", tmp_path / "nope", "-o", tmp_path / "out", names=str(tmp_path / "nope"))
    assert not (tmp_path / "out").exists()
    bad_input(capsys, "info", tmp_path / "nope", names=str(tmp_path / "nope"))
    bad_input(capsys, "decompress", tmp_path / "nope", "-o", tmp_path / "out", names=str(tmp_path / "nope"))
    assert list(tmp_path.iterdir()) == []


def test_manifest_with_missing_image(capsys, src, tmp_path):
    folder = copy_tree(src, tmp_path / "src")
    gone = sample_file(folder, 9)
    gone.unlink()
    bad_input(capsys, "compress", folder, "-o", tmp_path / "out", names=gone.name)
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src"]


def test_corrupt_image(capsys, src, tmp_path):
    folder = copy_tree(src, tmp_path / "src")
    broken = sample_file(folder, 17)
    broken.write_bytes(b"this is not a png" * 20)
    bad_input(capsys, "compress", folder, "-o", tmp_path / "out", names=broken.name)   # no -q: still one line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src"]


def test_truncated_image_one_line(capsys, src, tmp_path):
    folder = copy_tree(src, tmp_path / "src")
    broken = sample_file(folder, 5)
    broken.write_bytes(broken.read_bytes()[:200])
    bad_input(capsys, "compress", folder, "-o", tmp_path / "out", names=broken.name)


def test_truncated_image_exit_status(capsys, src, tmp_path):
    folder = copy_tree(src, tmp_path / "src")
    broken = sample_file(folder, 5)
    broken.write_bytes(broken.read_bytes()[:200])
    code, _, err = run(capsys, "compress", folder, "-o", tmp_path / "out", "-q")
    assert code == 65 and broken.name in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src"]


def test_bad_compressed_folder(capsys, compressed, tmp_path):
    folder = copy_tree(compressed, tmp_path / "c")
    (folder / "coeff" / "c003.jxl").unlink()
    bad_input(capsys, "decompress", folder, "-o", tmp_path / "d", names="c003.jxl")
    bad_input(capsys, "info", folder, names="c003.jxl")
    assert not (tmp_path / "d").exists()


def test_bad_options(capsys, src, compressed, tmp_path):
    bad_usage(capsys, "compress", src, "-o", tmp_path / "o", "--k", "0", names="--k")
    bad_input(capsys, "compress", src, "-o", tmp_path / "o", "--max-bytes", "40", "-q", names="--max-bytes")
    bad_usage(capsys, "decompress", compressed, "-o", tmp_path / "o", "--k", "9", names="--k")
    bad_usage(capsys, "decompress", compressed, "-o", tmp_path / "o", "--samples", "0-30", names="--samples")
    bad_usage(capsys, "decompress", compressed, "-o", tmp_path / "o", "--samples", "a-b", names="--samples")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(SystemExit) as exc:
        main(["compress", str(src), "-o", str(tmp_path / "o"), "--solver", "svd"])
    assert exc.value.code == 2
    capsys.readouterr()


def test_error_size_mismatch(capsys, src, tmp_path):
    ok(capsys, "synth", "pebbles", "-o", tmp_path / "s16", "--sampling", "tiny", "--size", "16", "-q")
    bad_input(capsys, "error", src, tmp_path / "s16", names=str(tmp_path / "s16"))


def test_error_sampling_mismatch(capsys, src, tmp_path):
    ok(capsys, "synth", "pebbles", "-o", tmp_path / "other", "--sampling", "small", "--size", "32", "-q")
    bad_input(capsys, "error", src, tmp_path / "other", names=str(tmp_path / "other"))


def test_error_samples_not_in_reconstruction(capsys, src, compressed, tmp_path):
    ok(capsys, "decompress", compressed, "-o", tmp_path / "sub", "--samples", "0-3", "-q")
    bad_input(capsys, "error", src, tmp_path / "sub", "--samples", "0-5", names="sample")


def test_info_reports_metadata_bytes(capsys, compressed):
    info = ok(capsys, "info", compressed)
    size = (compressed / METADATA).stat().st_size
    assert f"metadata {size}," in info


# ---------------------------------------------------------------- the real console script


def _script() -> list[str]:
    exe = ROOT / ".venv" / "bin" / "usdbtf"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "usdbtf.cli"]


def test_console_script_smoke(tmp_path):
    env = dict(os.environ, OCIO="ocio://default", PYTHONPATH=str(ROOT / "pipeline"))

    def sh(*argv):
        return subprocess.run(_script() + [str(a) for a in argv], capture_output=True, text=True, env=env,
                              timeout=120)

    r = sh("--version")
    assert r.returncode == 0 and r.stdout.startswith("usdbtf ")
    r = sh("synth", "fuzzy_moss", "-o", tmp_path / "s", "--sampling", "tiny", "--size", "16", "-q")
    assert r.returncode == 0, r.stderr
    r = sh("compress", tmp_path / "s", "-o", tmp_path / "c", "--k", "3", "--codec", "png", "-q")
    assert r.returncode == 0, r.stderr
    assert read_compressed(tmp_path / "c").k == 3
    r = sh("compress", tmp_path / "missing", "-o", tmp_path / "x")
    assert r.returncode == 65
    assert r.stderr.strip().splitlines() == [f"usdbtf compress: error: {tmp_path / 'missing'}: no such file or folder"]
    assert not (tmp_path / "x").exists()


def test_fit_every_texel_needs_a_budget(src, tmp_path, capsys):
    """--fit-every-texel (the streamed every-texel basis fit, the budget modes' default) asked
    for explicitly is refused in one usage line without --max-bytes/--target-error or beside
    --fit-texels, and writes nothing; the options default to it only where it applies."""
    from usdbtf.cli import main

    for extra in (["--k", "8"], ["--max-bytes", "100000", "--fit-texels", "256"]):
        assert main(["compress", str(src), "-o", str(tmp_path / "out"), "--fit-every-texel", *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--fit-every-texel needs" in err[0], err
    assert not (tmp_path / "out").exists()
    from usdbtf.compress.fit import every_texel
    from usdbtf.compress.options import CompressOptions

    S = 10800                                        # paper sampling
    assert every_texel(CompressOptions(max_bytes=10**6), 4096, 128**2, S)
    assert every_texel(CompressOptions(target_error=5.0), 4096, 128**2, S)
    assert not every_texel(CompressOptions(max_bytes=10**6, fit_every_texel=False), 4096, 128**2, S)
    assert not every_texel(CompressOptions(k=8), 4096, 128**2, S)
    assert not every_texel(CompressOptions(max_bytes=10**6, fit_texels=256), 256, 128**2, S)
    assert not every_texel(CompressOptions(max_bytes=10**6), 4096, 4096, S)      # the sample is the image
    # by default only where its panels fit the memory budget (0.61 GB at 128², 2.4 GB at 256²);
    # asked for, at any size
    assert not every_texel(CompressOptions(max_bytes=10**6), 4096, 256**2, S)
    assert every_texel(CompressOptions(max_bytes=10**6, memory_budget=3e9), 4096, 256**2, S)
    assert every_texel(CompressOptions(max_bytes=10**6, fit_every_texel=True), 4096, 256**2, S)
