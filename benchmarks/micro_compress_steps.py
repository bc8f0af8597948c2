"""Minimum-of-N timings of compress's steps after the decode, in one process.

Min-of-N is robust against a shared, busy machine (the noise only adds time), so this is
the tool for before/after comparisons of single steps; whole-run claims still come from
bench_compress.py / ab_compress.sh.

    .venv/bin/python benchmarks/micro_compress_steps.py benchmarks/out/data/pebbles-paper-128-seed0-tif
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from common import format_machine, machine_info
from usdbtf.io import open_btf
from usdbtf.compress import core
from usdbtf.compress.curve import curve_samples, error_curve
from usdbtf.compress.format import write_metadata, write_textures
from usdbtf.compress.source import choose_source


def best(fn, n):
    times = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times), float(np.median(times))


def main(argv):
    path, n = argv[0], int(argv[1]) if len(argv) > 1 else 5
    print(format_machine(machine_info()))
    btf = open_btf(path)
    opts = core.Options()
    with tempfile.TemporaryDirectory() as tmp:
        cbtf = core.compress_to_folder(btf, Path(tmp) / "c", opts)
        fit = core._fit_texels(btf, opts)
        evalt = core._eval_texels(btf, fit, opts)
        data = choose_source(btf, [fit, evalt], curve_samples(btf.n_samples), memory_budget=opts.memory_budget)
        x_fit = data.columns(fit)
        truth = data.to_working(data.columns(evalt)).reshape(btf.n_samples, len(evalt), 3)
        out = Path(tmp) / "w"
        out.mkdir()
        steps = {
            "columns(fit)": lambda: data.columns(fit),
            "fit weights": lambda: core._fit_weights(x_fit),
            "truth (eval texels, working)": lambda: data.to_working(data.columns(evalt)),
            "evaluate (held-out error)": lambda: core._evaluate(cbtf, truth, evalt),
            "error curve": lambda: error_curve(cbtf, data, opts.seed),
            "write metadata": lambda: write_metadata(cbtf, out),
            "write textures": lambda: write_textures(cbtf, out),
        }
        print(f"input: {path} ({btf.n_samples} samples, {btf.width}x{btf.height}); "
              f"{len(fit)} fit texels, {len(evalt)} evaluation texels; {n} runs per step")
        print(f"{'step':32s} {'min s':>8s} {'median s':>9s}")
        for name, fn in steps.items():
            lo, med = best(fn, n)
            print(f"{name:32s} {lo:8.3f} {med:9.3f}")


if __name__ == "__main__":
    main(sys.argv[1:])
