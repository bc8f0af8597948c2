"""Every stage has one shape: ``<stage>(inputs, <Stage>Options) -> result`` in memory (no file
written) and ``write_<stage>(result, path)``, whose output is byte for byte what the command
writes.  Also the command line's messages: -q, -v and progress bars (docs/architecture.md)."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from cli_helpers import ok, run
from rig_helpers import ENV, tree_bytes
from usdbtf.compress import read_compressed, reconstruct


def _nothing_written(folder, before):
    assert sorted(p.name for p in folder.iterdir()) == before


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A tiny synthetic BTF and its compression (k = 6, PNG codes) through the command line."""
    work = tmp_path_factory.mktemp("stages")
    main_ok = lambda *argv: subprocess.run([sys.executable, "-m", "usdbtf.cli", *map(str, argv)], env=ENV,  # noqa: E731
                                           capture_output=True, text=True, check=True)
    main_ok("synth", "pebbles", "-o", work / "raw", "--sampling", "tiny", "--size", 16, "--seed", 2, "-q")
    main_ok("compress", work / "raw", "-o", work / "c", "--k", 6, "--codec", "png", "-q")
    return work


def test_synth_stage(small, tmp_path, capsys):
    from usdbtf.synth import SynthOptions, synth, write_synth

    before = sorted(p.name for p in tmp_path.iterdir())
    result = synth("pebbles", SynthOptions(size=16, seed=2, sampling="tiny"))
    _nothing_written(tmp_path, before)
    write_synth(result, tmp_path / "lib")
    assert tree_bytes(tmp_path / "lib") == tree_bytes(small / "raw")
    btf = result.to_btf()
    from usdbtf.manifest import read_manifest

    written = read_manifest(small / "raw")
    assert btf.n_samples == written.n_samples and btf.metadata["synthetic"]["seed"] == 2
    np.testing.assert_allclose(btf.read_samples([3]), written.read_samples([3]), atol=3e-3)   # 8-bit files


def test_decompress_stage(small, tmp_path, capsys):
    from usdbtf.decompress import DecompressOptions, decompress, write_decompress

    cbtf = read_compressed(small / "c")
    result = decompress(cbtf, DecompressOptions(samples="1-3,7", k=4))
    assert result.indices.tolist() == [1, 2, 3, 7]
    np.testing.assert_array_equal(result.btf.read_samples([1, 3]), reconstruct(cbtf, [2, 7], k=4))
    write_decompress(result, tmp_path / "lib")
    ok(capsys, "decompress", small / "c", "-o", tmp_path / "cli", "--samples", "1-3,7", "--k", 4, "-q")
    assert tree_bytes(tmp_path / "lib") == tree_bytes(tmp_path / "cli")
    from usdbtf.errors import UsageError

    with pytest.raises(UsageError, match="--k"):
        decompress(cbtf, DecompressOptions(k=7))


def test_quilt_stage(small, tmp_path, capsys):
    from usdbtf.quilt import QuiltOptions, quilt, quilted_btf, write_quilt

    before = sorted(p.name for p in tmp_path.iterdir())
    result = quilt(small / "c", QuiltOptions(size=(24, 20), block=8, seed=3))
    _nothing_written(tmp_path, before)
    assert result.positions.shape == (20, 24) and result.source_folder == small / "c"
    write_quilt(result, tmp_path / "lib")
    ok(capsys, "quilt", small / "c", "-o", tmp_path / "cli", "--size", 24, 20, "--block", 8, "--seed", 3, "-q")
    assert tree_bytes(tmp_path / "lib") == tree_bytes(tmp_path / "cli")
    np.testing.assert_array_equal(reconstruct(quilted_btf(result), [4]), reconstruct(read_compressed(tmp_path / "cli"),
                                                                                      [4]))


def test_board_stage(tmp_path, capsys):
    from usdbtf.board import BoardOptions, board, write_board

    result = board(BoardOptions(grid=6, window=2, cell_px=40))
    assert result.image.shape == (280, 280) and len(result.board.ids) == 32
    write_board(result, tmp_path / "lib.png", tmp_path / "lib.json")
    ok(capsys, "board", "-o", tmp_path / "cli.png", "--json", tmp_path / "cli.json", "--grid", 6, "--window", 2,
       "--cell-px", 40, "-q")
    assert (tmp_path / "lib.png").read_bytes() == (tmp_path / "cli.png").read_bytes()
    assert (tmp_path / "lib.json").read_bytes() == (tmp_path / "cli.json").read_bytes()


def test_package_stage(small, tmp_path, capsys):
    """package() writes nothing; write_package writes what the command writes; asset_layers
    authors the same layers in memory."""
    from usdbtf.usd.asset.package import PackageOptions, asset_layers, package, read_input, write_package

    before = sorted(p.name for p in tmp_path.iterdir())
    result = package(small / "c", PackageOptions(lods=[3], payload_format="usda"))
    _nothing_written(tmp_path, before)
    summary = write_package(result, tmp_path / "lib" / "p.usda")
    assert summary["k"] == 6 and summary["lods"] == [["full", 6], ["k3", 3]]
    ok(capsys, "package", small / "c", "-o", tmp_path / "cli" / "p.usda", "--lod", 3, "--payload-format", "usda",
       "-q")
    assert tree_bytes(tmp_path / "lib") == tree_bytes(tmp_path / "cli")
    layers = asset_layers(result, tmp_path / "cli" / "p.usda")
    for name in ("p.usda", "p_payload.usda"):
        assert layers[name].ExportToString() == (tmp_path / "cli" / name).read_text()
    # From an in-memory CompressedBTF: the texture bytes are those of its folder.
    again = package(read_input(small / "c"), PackageOptions(lods=[3], payload_format="usda", thumbnail=False))
    assert again.textures.files[again.coefficients[0]].data == result.textures.files[result.coefficients[0]].data


def _usdbtf(*argv, **kw):
    return subprocess.run([sys.executable, "-m", "usdbtf.cli", *map(str, argv)], env=ENV, capture_output=True,
                          text=True, **kw)


def test_quiet_verbose_and_progress(tmp_path):
    """Info by default, nothing with -q (before or after the command), debug with -v; a
    progress bar only when asked off a terminal, and never on stdout."""
    args = ["pebbles", "--sampling", "tiny", "--size", 8]
    default = _usdbtf("synth", *args, "-o", tmp_path / "a")
    assert default.returncode == 0 and default.stdout == ""
    assert default.stderr.startswith("wrote 24 samples of pebbles") and "synth [" not in default.stderr
    for quiet in (["-q", "synth"], ["synth", "-q"]):
        done = _usdbtf(*quiet, *args, "-o", tmp_path / "b", "--force")
        assert done.returncode == 0 and done.stdout == "" and done.stderr == ""
    verbose = _usdbtf("-v", "synth", *args, "-o", tmp_path / "c")
    assert verbose.stderr.splitlines()[0].startswith("usdbtf 0.") and "wrote 24 samples" in verbose.stderr
    shown = _usdbtf("synth", *args, "-o", tmp_path / "d", "--progress")
    assert shown.stdout == "" and "synth [########################] 24/24 100%" in shown.stderr
    assert _usdbtf("synth", *args, "-o", tmp_path / "e", "--progress", "-q").stderr == ""
    assert tree_bytes(tmp_path / "a") == tree_bytes(tmp_path / "d")


def test_messages_reach_a_swapped_stderr(tmp_path, capsys):
    """In-process runs (tests, embedding) get the messages on whatever sys.stderr is now."""
    code, out, err = run(capsys, "synth", "pebbles", "--sampling", "tiny", "--size", 8, "-o", tmp_path / "a")
    assert code == 0 and out == "" and "wrote 24 samples of pebbles" in err
    code, out, err = run(capsys, "-q", "synth", "pebbles", "--sampling", "tiny", "--size", 8, "-o", tmp_path / "b")
    assert code == 0 and out == "" and err == ""


@pytest.mark.parametrize("fmt", ["tx", "exr"])
def test_tiled_textures_are_reproducible(tmp_path, fmt):
    """maketx output is the same bytes whenever it is made (no time stamp on any MIP level)."""
    import time

    from usdbtf.imageio import encode_image
    from usdbtf.usd.asset.textures import TextureSet

    pixels = (np.arange(64 * 48 * 3) % 251).astype(np.uint8).reshape(48, 64, 3)
    made = []
    for n in range(2):
        textures = TextureSet(fmt)
        name = textures.add("coeff/c000.png", encode_image(pixels, "png", color_space="data"), "codes")
        textures.write(tmp_path / f"t{n}")
        made.append((tmp_path / f"t{n}" / name).read_bytes())
        time.sleep(1.1)                    # the clock's seconds move on between the two
    assert made[0] == made[1]
