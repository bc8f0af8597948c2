"""compress's own parallelism (usdbtf.compress.parallel): the same bytes on any number of CPUs.

A product cut into one piece per CPU rounded its rows by where the cut fell (OpenBLAS rounds a
row by its place in the kernel's row blocking), so a compress confined to one CPU, as on a
small farm slot or a Dask worker pinned to a core, wrote another ``btf-compressed.json`` than
on two.  The pieces now depend on the product's shape alone.  Checked in process, under every
OpenBLAS kernel this CPU runs (a fresh process each: the kernel is chosen when OpenBLAS loads),
and through the CLI with the process's CPU affinity cut to one core.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: the pinned platform, usdbtf.numeric)
import numpy as np
import pytest

from usdbtf import numeric
from usdbtf.cli import main
from usdbtf.compress import parallel
from usdbtf.compress.format import digest_without_platform
from usdbtf.compress.parallel import GEMM_ROW_UNIT, gemm_row_cuts, rows_gemm

#: (rows, inner, columns, dtype): the fit's, the projection's and the evaluation's products at
#: paper scale and below, with row counts that are not multiples of anything.
SHAPES = [(2048, 1080, 166, np.float32), (517, 150, 150, np.float32), (150, 1080, 700, np.float32),
          (1000, 333, 77, np.float64), (166, 1080, 166, np.float64), (64, 40, 9, np.float32)]
CPU_COUNTS = (1, 2, 3, 8)


def operands(rows, inner, cols, dtype, transposed=False):
    rng = np.random.default_rng(rows * 7 + inner)
    a = rng.standard_normal((rows, inner)).astype(dtype)
    if transposed:                       # a transposed view, as rows_gemm(x.T, q) passes
        a = np.ascontiguousarray(a.T).T
    return a, rng.standard_normal((inner, cols)).astype(dtype)


@pytest.mark.parametrize("n", [1, 31, 64, 100, 150, 166, 500, 2048, 10800])
def test_cuts_follow_the_shape_not_the_cpus(n, monkeypatch):
    cuts = {}
    for cpus in CPU_COUNTS:
        monkeypatch.setattr(parallel, "cpu_count", lambda c=cpus: c)
        cuts[cpus] = gemm_row_cuts(n)
    assert len({tuple(c) for c in cuts.values()}) == 1
    c = cuts[1]
    assert c[0] == 0 and c[-1] == n and all(b > a for a, b in zip(c, c[1:]))
    assert all(x % GEMM_ROW_UNIT == 0 for x in c[1:-1])
    assert len(c) - 1 <= parallel.GEMM_MAX_PIECES
    if n >= 150:   # enough pieces for two CPUs to share the work within ~10 %
        assert max(np.diff(c)) <= 0.6 * n


@pytest.mark.parametrize("transposed", [False, True], ids=["rows", "transposed"])
@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: "x".join(map(str, s[:3])) + f"-{np.dtype(s[3]).name}")
def test_rows_gemm_same_bytes_on_any_cpu_count(shape, transposed, monkeypatch):
    """The same bits with 1, 2, 3 and 8 CPUs; on the reference platform also those of the whole
    product on one BLAS thread (pieces start where Haswell's row blocks do)."""
    a, b = operands(*shape, transposed=transposed)
    results = []
    for cpus in CPU_COUNTS:
        monkeypatch.setattr(parallel, "cpu_count", lambda c=cpus: c)
        results.append(rows_gemm(a, b))
    for r in results[1:]:
        assert np.array_equal(r, results[0])
    with numeric.one_blas_thread():
        whole = a @ b
    # A wrong piece (a row written twice, one left empty) would be far off, whatever the kernel.
    np.testing.assert_allclose(results[0], whole, rtol=1e-4 if a.dtype == np.float32 else 1e-12,
                               atol=1e-3 if a.dtype == np.float32 else 1e-10)
    if numeric.is_reference():
        assert np.array_equal(results[0], whole)


_PROBE = r"""
import hashlib, json, sys
import usdbtf, numpy as np
from usdbtf.compress import parallel
shapes = json.loads(sys.argv[1])
out = {}
for cpus in (1, 2, 3, 8):
    parallel.cpu_count = lambda c=cpus: c
    h = hashlib.sha256()
    for rows, inner, cols, dt in shapes:
        rng = np.random.default_rng(rows * 7 + inner)
        a = rng.standard_normal((rows, inner)).astype(dt)
        b = rng.standard_normal((inner, cols)).astype(dt)
        h.update(parallel.rows_gemm(a, b).tobytes())
        h.update(parallel.rows_gemm(np.ascontiguousarray(a.T).T, b).tobytes())
    out[cpus] = h.hexdigest()
print(json.dumps(out))
"""


@pytest.mark.parametrize("kernel", numeric.runnable_kernels())
def test_rows_gemm_any_cpu_count_under_every_kernel(kernel):
    """Each OpenBLAS kernel this CPU runs (a process each) rounds its own way, but never by CPU
    count: one digest per kernel for 1, 2, 3 and 8 CPUs."""
    shapes = [[r, i, c, np.dtype(d).name] for r, i, c, d in SHAPES]
    env = {**os.environ, "OPENBLAS_CORETYPE": kernel}
    proc = subprocess.run([sys.executable, "-c", _PROBE, json.dumps(shapes)], capture_output=True, text=True,
                          env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    digests = json.loads(proc.stdout)
    assert len(set(digests.values())) == 1, digests


@pytest.fixture(scope="module")
def ubo81_btf(tmp_path_factory) -> Path:
    """6,561 samples of 12x12: enough rows for the fit's products to be cut (the 169-sample
    preset's are not, and passed before the fix too)."""
    out = tmp_path_factory.mktemp("parallel") / "raw"
    assert main(["synth", "-q", "pebbles", "-o", str(out), "--sampling", "ubo81", "--size", "12", "--seed", "5"]) == 0
    return out


def compress_on(cpus: set, src: Path, out: Path, *options) -> str:
    proc = subprocess.run([sys.executable, "-m", "usdbtf.cli", "compress", "-q", str(src), "-o", str(out), *options],
                          capture_output=True, text=True, timeout=300,
                          preexec_fn=lambda: os.sched_setaffinity(0, cpus))
    assert proc.returncode == 0, proc.stderr
    return digest_without_platform(out)[0]


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: nothing to compare")
@pytest.mark.parametrize("options", [["--k", "48"], ["--max-bytes", "40000", "--budget-for", "folder"]], ids=["k", "max-bytes"])
def test_compress_on_one_cpu_writes_the_bytes_of_two(ubo81_btf, tmp_path, options):
    """The CLI confined to one CPU (as ``taskset -c 0`` would) and on two: the same folder
    (before the fix, ``--k 48`` differed in the basis, two coefficient textures and the metadata)."""
    cpus = sorted(os.sched_getaffinity(0))
    one = compress_on({cpus[0]}, ubo81_btf, tmp_path / "one", *options)
    two = compress_on(set(cpus[:2]), ubo81_btf, tmp_path / "two", *options)
    assert one == two


# -- image codecs in forked processes --------------------------------------------------------------
_PIDS_PROBE = r"""
import json, os, time, usdbtf
from usdbtf.compress.parallel import forks_safely, in_processes

def pid(x):
    time.sleep(0.2)      # long enough that both workers take items, however loaded the machine
    return os.getpid()

print(json.dumps([os.getpid(), forks_safely(), in_processes(pid, range(8), processes=2)]))
"""


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="one CPU: in_processes runs in this process")
def test_in_processes_runs_in_forked_children():
    """In a fresh interpreter (this one may hold threads from earlier tests, which rightly
    keep it from forking): the items run in other processes (at most two)."""
    proc = subprocess.run([sys.executable, "-c", _PIDS_PROBE], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    parent, safe, pids = json.loads(proc.stdout)
    # Two workers; on a loaded machine one may take every item before the other starts.
    assert safe and parent not in pids and 1 <= len(set(pids)) <= 2


def test_in_processes_closures_order_and_errors():
    from usdbtf.compress.parallel import in_processes
    from usdbtf.errors import BTFError

    data = np.arange(1000.0).reshape(10, 100)          # reaches the workers through the fork
    assert in_processes(lambda i: float(data[i].sum()), range(10), processes=2) == [float(data[i].sum())
                                                                                   for i in range(10)]

    def fail_on_three(i):
        if i == 3:
            raise BTFError("texture 3: too many levels")
        return i

    with pytest.raises(BTFError, match="texture 3: too many levels"):
        in_processes(fail_on_three, range(6), processes=2)


def test_in_processes_stays_in_process_beside_a_thread_or_in_a_daemon():
    """Another Python thread running (a Dask client's loop), or a daemonic process (a Dask
    worker): no fork, every item in the calling process."""
    import threading

    from usdbtf.compress.parallel import in_processes

    stop = threading.Event()
    thread = threading.Thread(target=stop.wait)
    thread.start()
    try:
        assert set(in_processes(lambda x: os.getpid(), range(6), processes=2)) == {os.getpid()}
    finally:
        stop.set()
        thread.join()

    import multiprocessing as mp

    ctx = mp.get_context("fork")
    queue = ctx.Queue()

    def in_daemon():
        queue.put((os.getpid(), in_processes(lambda x: os.getpid(), range(6), processes=2)))

    daemon = ctx.Process(target=in_daemon, daemon=True)
    daemon.start()
    pid, pids = queue.get(timeout=60)
    daemon.join(60)
    assert set(pids) == {pid}


@pytest.mark.parametrize("name", ["jxlp", "jxl", "png", "exr", "jpeg"])
def test_codec_bytes_do_not_depend_on_where_they_were_encoded(name):
    """codec_map (forked processes, threads for OpenEXR) against one encode after another in
    this process: the same bytes, file for file, and the same codes decoded back."""
    from usdbtf.compress.codecs import CODECS, Codec, codec_map, quantize_half, quantize_uniform

    codec = CODECS[name]
    rng = np.random.default_rng(3)
    values = [rng.standard_normal((24, 20, 3)).astype(np.float32) * (40 / (i + 1)) for i in range(7)]
    stored = [quantize_half(v) if name == "exr" else quantize_uniform(v, 0.5) for v in values]
    serial = [codec.encode(st, "data") for st in stored]
    assert codec_map(codec, lambda st: codec.encode(st, "data"), stored) == serial
    assert codec.forkable == (name != "exr")
    decoded = codec_map(codec, Codec.decode, serial)
    assert all(np.array_equal(a, Codec.decode(d)) for a, d in zip(decoded, serial))
    if codec.lossless and not codec.planar:
        assert all(np.array_equal(a, st.pixels) for a, st in zip(decoded, stored))
