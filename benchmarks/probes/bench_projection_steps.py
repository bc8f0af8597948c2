#!/usr/bin/env python
"""The projection in a working domain and the domain curve per value (issue 27), in process.

Loads INPUT in memory once, switches it to the sRGB working domain (metal_flakes' choice), and
projects every texel on a random orthonormal 150-vector basis with a random colour rotation,
for planes (150, 150, 0) (a plain ``--k 150`` of metal_flakes) and (150, 150, 150) (every plane
on every vector: one interleaved GEMM); then times the sRGB curve (forward and inverse) on
512 x 3,072 values of the input's working-space data.  CPU seconds of this process (all
threads), min and median of N runs.  Run it with ``PYTHONPATH`` at each tree to compare them;
nothing is written.

    .venv/bin/python benchmarks/probes/bench_projection_steps.py INPUT [N]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py and the benchmarks a probe reuses

import statistics
import sys
import time

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import format_machine, machine_info
from usdbtf.compress import core
from usdbtf.compress.domain import Domain
from usdbtf.compress.options import CompressOptions
from usdbtf.compress.parallel import one_blas_thread
from usdbtf.compress.select_source import load_source
from usdbtf.compress.texels import sample_texels
from usdbtf.io import open_btf


def cpu_runs(fn, n: int) -> list:
    """CPU seconds of ``n`` calls of ``fn`` (after one warm-up)."""
    fn()
    out = []
    for _ in range(n):
        c = time.process_time()
        fn()
        out.append(time.process_time() - c)
    return out


def main(argv) -> int:
    path, n = argv[0], int(argv[1]) if len(argv) > 1 else 3
    print(format_machine(machine_info()))
    btf = open_btf(path)
    opts = CompressOptions(k=150)
    rng = np.random.default_rng(0)
    u = np.linalg.qr(rng.standard_normal((btf.n_samples, 150)))[0].astype(np.float32)
    rotation = np.linalg.qr(rng.standard_normal((3, 3)))[0]
    srgb = Domain("srgb")
    with one_blas_thread(), load_source(btf, sample_texels(btf, opts), opts) as source:
        rows = source.working_samples(np.arange(0, btf.n_samples, max(1, btf.n_samples // 512))[:512])
        tile = np.ascontiguousarray(rows.reshape(len(rows), -1)[:, :3072])
        source.set_domain(srgb)
        print(f"\ninput: {path} ({btf.n_samples} samples, {btf.width}x{btf.height}, {source.kind}); {n} runs\n")
        print("| step | CPU s min | CPU s median | check |\n|---|---|---|---|")
        for planes in [(150, 150, 0), (150, 150, 150)]:
            coeff = core.project(source, u, rotation, planes)[0]
            runs = cpu_runs(lambda: core.project(source, u, rotation, planes), n)
            print(f"| project, planes {planes} | {min(runs):.2f} | {statistics.median(runs):.2f} | "
                  f"sum |c| {float(np.abs(coeff).sum(dtype=np.float64)):.6g} |", flush=True)
        for name, fn in (("forward", lambda: srgb.forward(tile)), ("inverse", lambda: srgb.inverse(tile))):
            runs = cpu_runs(lambda: [fn() for _ in range(20)], n)
            print(f"| sRGB {name}, ns a value | {min(runs) / 20 / tile.size * 1e9:.2f} | "
                  f"{statistics.median(runs) / 20 / tile.size * 1e9:.2f} | {np.mean(tile <= 0.0031308):.3f} in the toe |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
