"""Compression on a Dask cluster (issue 17): byte-identical to in-process, killed workers
retried, unreachable schedulers and junk addresses refused in one line.

The data spans several shards (2,160 samples: shards of 1,024, so three partial sums whose
order matters) and two texel blocks (33^2 = 1,089 texels: blocks of 1,024, the second short),
so the distributed reduction has real work to order.  One 2-worker LocalCluster (worker
processes) serves the module; ``--dask local:2`` starts its own.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from usdbtf import cluster, synth
from usdbtf.compress import CompressOptions, compress, write_compress
from usdbtf.compress import distributed
from usdbtf.errors import BTFError, EXIT_DATA, EXIT_IO, UsageError
from usdbtf.manifest import read_manifest, write_manifest
from usdbtf.model import ArrayBTF
from usdbtf.sampling import cross, rings

from cli_helpers import bad_usage

ROOT = Path(__file__).resolve().parents[1]
SRGB = "sRGB Encoded Rec.709 (sRGB)"
LIN709 = "Linear Rec.709 (sRGB)"


def folder_files(folder: Path) -> dict:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def manifest(tmp_path_factory) -> Path:
    """2,160 samples (45 views x 48 lights) of 33x33 pebbles, 8-bit sRGB PNG (the smallest
    square of two texel blocks: every compress of the module does two thirds of a 40x40's work)."""
    s = cross(rings((0, 20, 40, 60), (1, 12, 16, 16)), rings((10, 30, 50, 70), (12, 12, 12, 12)))
    imgs = synth.render_all(synth.make_material("pebbles", 33, 3), s)
    return write_manifest(tmp_path_factory.mktemp("dask") / "m", s, imgs, color_space=SRGB, bit_depth="uint8",
                          ext="png", array_space=LIN709)


@pytest.fixture(scope="module")
def scheduler():
    """The address of a LocalCluster of 2 single-threaded worker processes."""
    from distributed import LocalCluster

    with cluster.environ_kept():     # a LocalCluster sets OMP_NUM_THREADS=1 etc. for later subprocesses too
        lc = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                          silence_logs=logging.ERROR)
    with lc:
        yield lc.scheduler_address


@pytest.fixture(scope="module")
def in_process(manifest, tmp_path_factory):
    """The in-process reference outputs: {name: (options, folder files)}."""
    btf = read_manifest(manifest)
    root = tmp_path_factory.mktemp("ref")
    runs = {"k": dict(k=40), "max-bytes": dict(max_bytes=60000), "paper": dict(solver="paper", k=20)}
    out = {}
    for name, kw in runs.items():
        write_compress(compress(btf, CompressOptions(**kw)), root / name)
        out[name] = (kw, folder_files(root / name))
    return out


_THREADS_PROBE = """
import hashlib, sys
import cv2, numpy as np
from usdbtf.compress.projection import TileProjector
cv2.setNumThreads(int(sys.argv[1]))
rng = np.random.default_rng(0)
h = hashlib.sha256()
lut = rng.random(256).astype(np.float32)
for S, k, n, t, ks, s0 in [(2160, 150, 1024, 128, (150,) * 3, 128), (2160, 150, 1024, 112, (150,) * 3, 2048),
                          (500, 150, 576, 128, (150, 43, 0), 128), (300, 300, 1024, 128, (300,) * 3, 128),
                          (300, 20, 100, 44, (20, 5, 2), 256), (22801, 150, 1024, 17, (150, 60, 0), 22784)]:
    u = rng.standard_normal((S, k)).astype(np.float32)
    raw = rng.integers(0, 256, (t, 3 * n), dtype=np.uint8)
    part = TileProjector(u, rng.standard_normal((3, 3)), ks, lambda r, out=None: lut[r], 128, energy=True).partial(s0, raw)
    for p in part.products:
        h.update(b"" if p is None else p.tobytes())
    h.update(np.float64(part.energy).tobytes())
print(h.hexdigest())
"""


def test_projection_tiles_do_not_depend_on_thread_counts():
    """Dask workers run with one BLAS thread (its nannies set OPENBLAS_NUM_THREADS=1), this
    process with several: a tile's products and energy are the same bytes with 1, 2 or 4
    BLAS threads and 1 or 2 OpenCV threads, at full and short tiles and blocks, planar and
    interleaved (what makes the distributed projection byte-identical)."""
    digests = set()
    for blas in ("1", "2", "4"):
        for cv in ("1", "2"):
            env = dict(os.environ, OPENBLAS_NUM_THREADS=blas, OMP_NUM_THREADS=blas)
            proc = subprocess.run([sys.executable, "-c", _THREADS_PROBE, cv], capture_output=True, text=True, env=env)
            assert proc.returncode == 0, proc.stderr
            digests.add(proc.stdout.strip())
    assert len(digests) == 1


def test_plan_spans_several_shards_and_blocks(manifest):
    from usdbtf.compress.source import work_plan

    plan = work_plan(read_manifest(manifest))
    assert len(plan.shards()) == 3 and plan.shards()[-1] == (2048, 2160)
    assert plan.blocks() == [(0, 1024), (1024, 1089)]


@pytest.mark.parametrize("name", ["k", "max-bytes", "paper"])
def test_two_workers_byte_identical_to_in_process(manifest, scheduler, in_process, tmp_path, name):
    kw, want = in_process[name]
    btf = read_manifest(manifest)
    write_compress(compress(btf, CompressOptions(dask=scheduler, **kw)), tmp_path / "d")
    assert folder_files(tmp_path / "d") == want


def test_tasks_split_by_texel_rows_byte_identical(manifest, scheduler, in_process, tmp_path, monkeypatch):
    """One block per projection task: each task decodes only the image rows of its block."""
    monkeypatch.setattr(distributed, "TASK_SUM_BYTES", 1.0)
    kw, want = in_process["k"]
    btf = read_manifest(manifest)
    assert len(distributed.texel_groups(distributed.WorkPlan.for_shape(btf.n_samples, btf.n_pixels, 1), 40)) == 2
    write_compress(compress(btf, CompressOptions(dask=scheduler, **kw)), tmp_path / "d")
    assert folder_files(tmp_path / "d") == want


def test_killed_worker_is_retried_and_output_identical(manifest, scheduler, in_process, tmp_path):
    """The first projection task to start kills its worker process (SIGKILL); Dask runs its
    tasks again on the survivor (and on the restarted worker): the same bytes."""
    from distributed import Client

    import dask_helpers

    marker = tmp_path / "killed"
    kw, want = in_process["k"]
    with Client(scheduler, timeout=10) as client:
        client.register_plugin(dask_helpers.KillOnce(str(marker), "usdbtf-project"), name="kill-once")
        try:
            btf = read_manifest(manifest)
            write_compress(compress(btf, CompressOptions(dask=scheduler, **kw)), tmp_path / "d")
        finally:
            client.unregister_worker_plugin("kill-once")
        assert marker.is_file(), "no worker was killed"
        client.wait_for_workers(2, timeout=30)
    assert folder_files(tmp_path / "d") == want


def test_cli_local_cluster_byte_identical_with_progress(manifest, in_process, tmp_path):
    """``usdbtf compress --dask local:2`` (its own LocalCluster, torn down after): the same
    folder as the in-process run; stderr shows the cluster and a progress bar.

    The reference is the module's in-process ``compress`` + ``write_compress`` folder (what
    the CLI calls, with the same options) rather than a second CLI run of the same work: every
    file byte for byte but the metadata record, which is equal once what only the CLI records
    is set aside (the input as its command line names it, the source's own metadata, and so
    the record's own size): nothing the cluster computes.

    At ``--k`` (the same two cluster passes as a budget mode, without the client's rate-control
    trials: ``--max-bytes`` on a cluster is test_two_workers_byte_identical_to_in_process's)."""
    kw, want = in_process["k"]
    argv = [sys.executable, "-m", "usdbtf.cli", "compress", str(manifest), "--k", str(kw["k"])]
    # --progress: stderr is a pipe here, where bars are drawn only when asked.
    proc = subprocess.run(argv + ["-o", str(tmp_path / "d"), "--dask", "local:2", "--progress"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    got, record = folder_files(tmp_path / "d"), "btf-compressed.json"
    assert record in got and {n: b for n, b in got.items() if n != record} == {n: b for n, b in want.items()
                                                                               if n != record}
    cli, api = json.loads(got[record]), json.loads(want[record])
    assert cli["source"].pop("path") == cli["provenance"].pop("source") == str(manifest)
    assert api["source"].pop("path") == api["provenance"].pop("source") == ""
    cli.pop("source_metadata", None)
    cli["bytes"].pop("metadata"), api["bytes"].pop("metadata")
    assert cli == api
    assert "dask: local:2: 2 worker(s)" in proc.stderr
    assert "dask pass 2/2 (projection) [" in proc.stderr and "100%" in proc.stderr


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_scheduler_is_one_line_within_seconds(manifest, tmp_path):
    address = f"tcp://127.0.0.1:{_closed_port()}"
    t = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "usdbtf.cli", "compress", str(manifest), "-o", str(tmp_path / "d"),
                           "--dask", address], capture_output=True, text=True)
    seconds = time.monotonic() - t
    assert proc.returncode == EXIT_IO, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("usdbtf compress: error: --dask " + address), proc.stderr
    assert "no Dask scheduler answered within 5 s" in lines[0]
    assert seconds < cluster.CONNECT_TIMEOUT + 15
    assert not (tmp_path / "d").exists() and not list(tmp_path.glob(".d*"))


@pytest.mark.parametrize("text", [
    "", "local", "local:0", "local:257", "local:x", "local:2 ", "tcp://", "tcp://host", "tcp://host:", "tcp://host:0",
    "tcp://host:65536", "tcp://host:123456", "http://host:8786", "TCP://host:8786", "tcp://host:8786/path",
    "tcp://user@host:8786", "tcp://$(touch x):8786", "tcp://a;b:8786", "tcp://a`b`:8786", "tcp://-bad:8786",
    "tcp://1.2.3.4.5:8786", "tcp://[::1:8786", "tcp://[zz::1]:8786", "tcp://h\u00e9:8786", "tcp://a b:8786",
    "tcp://host:8786\n", "inproc://x", "ucx://host:8786", "tcp://" + "a" * 300 + ":1",
])
def test_address_parser_refuses_junk(text):
    with pytest.raises(argparse.ArgumentTypeError):
        cluster.parse_address(text)


@pytest.mark.parametrize("text,want", [
    ("tcp://127.0.0.1:8786", ("tcp", "127.0.0.1", 8786, None)),
    ("tls://scheduler.example.org:443", ("tls", "scheduler.example.org", 443, None)),
    ("tcp://[::1]:8786", ("tcp", "::1", 8786, None)),
    ("tcp://node-7:1", ("tcp", "node-7", 1, None)),
    ("local:4", ("local", None, None, 4)),
])
def test_address_parser_accepts_and_rebuilds(text, want):
    a = cluster.parse_address(text)
    assert (a.scheme, a.host, a.port, a.workers) == want
    assert str(a) == text


def test_cli_refuses_junk_address_as_usage(capsys, manifest, tmp_path):
    bad_usage(capsys, "compress", manifest, "-o", tmp_path / "d", "--dask", "tcp://$(touch x):1", names="--dask")
    assert not (tmp_path / "d").exists()


def test_scene_options_may_not_name_a_cluster():
    from usdbtf.usd.scenes.build import parse_options

    with pytest.raises(BTFError, match="--dask is not allowed in a scene"):
        parse_options("--k 8 --dask local:2", "scene.usda: /M: btf:build:options")


def test_worker_with_other_code_is_refused(manifest, scheduler, tmp_path, monkeypatch):
    """A worker whose usdbtf (or libraries) differ from this process: refused by name, before
    any work; and a task refuses it too (for workers that join later)."""
    real = cluster.environment()
    monkeypatch.setattr(cluster, "environment", lambda: dict(real, usdbtf="9.9.9"))
    with pytest.raises(BTFError, match=r"worker tcp://127\.0\.0\.1:\d+ differs from this process: usdbtf "
                                       r"0\.1\.0 \(here 9\.9\.9\)"):
        compress(read_manifest(manifest), CompressOptions(dask=scheduler, k=8))
    monkeypatch.undo()
    with pytest.raises(BTFError, match="usdbtf 0.1.0 .here 9.9.9."):
        cluster.require_environment(dict(real, usdbtf="9.9.9"), "w1")


def test_bad_file_on_a_worker_is_bad_data(manifest, scheduler, tmp_path):
    """A damaged image is found by a worker: the same one-line error (exit 65) as in-process."""
    bad = tmp_path / "m"
    shutil.copytree(manifest, bad)
    victim = sorted(bad.glob("*.png"))[1500]
    victim.write_bytes(victim.read_bytes()[:200])
    with pytest.raises(BTFError, match=victim.name) as info:
        compress(read_manifest(bad), CompressOptions(dask=scheduler, k=8))
    assert info.value.exit_code == EXIT_DATA


def test_in_memory_btf_cannot_go_to_a_cluster():
    s = cross(rings((0,), (1,)), rings((0, 30), (1, 4)))
    btf = ArrayBTF.from_linear(s, np.ones((len(s), 4, 4, 3), np.float32))
    with pytest.raises(UsageError, match="in-memory BTF"):
        compress(btf, CompressOptions(dask="local:1", k=2))


@pytest.mark.slow
def test_real_scheduler_and_two_workers_on_localhost(manifest, in_process, tmp_path):
    """The issue's must-show check: ``dask scheduler`` and two ``dask worker`` processes from
    the project's environment on 127.0.0.1, and ``usdbtf compress --dask tcp://127.0.0.1:PORT``
    gives the in-process folder byte for byte."""
    bindir = Path(sys.executable).parent
    port = _closed_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT / "pipeline"))
    procs = [subprocess.Popen([str(bindir / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen([str(bindir / "dask"), "worker", f"tcp://127.0.0.1:{port}", "--nthreads",
                                           "1", "--host", "127.0.0.1", "--no-dashboard"], env=env,
                                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        kw, _ = in_process["k"]
        argv = [str(bindir / "usdbtf"), "compress", str(manifest), "--k", str(kw["k"])]
        ref = subprocess.run(argv + ["-o", str(tmp_path / "ref"), "-q"], capture_output=True, text=True)
        assert ref.returncode == 0, ref.stderr
        from distributed import Client

        deadline = time.monotonic() + 60
        while True:
            try:
                with Client(f"tcp://127.0.0.1:{port}", timeout=5) as c:
                    c.wait_for_workers(2, timeout=max(1, deadline - time.monotonic()))
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        proc = subprocess.run(argv + ["-o", str(tmp_path / "d"), "--dask", f"tcp://127.0.0.1:{port}"],
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        assert "2 worker(s)" in proc.stderr
        assert folder_files(tmp_path / "d") == folder_files(tmp_path / "ref")
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            p.wait(timeout=30)
