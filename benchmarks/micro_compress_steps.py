"""Where plain ``usdbtf compress`` spends its time, step by step, against the GEMM baseline.

Each step of a default compress (rsvd, jxl, k = 150) is timed on its own in one process:
minimum and median of N runs, wall and CPU seconds (this process + its decode workers).
The float32 GEMM U^T X of issue 2's speed target is timed the same way, so every row also
reads as a fraction of it.  Min-of-N is robust on a shared, busy machine (noise only adds
time): use this for before/after comparisons of single steps; whole-run claims come from
bench_compress.py and ab_compress.sh.

    .venv/bin/python benchmarks/micro_compress_steps.py benchmarks/out/data/pebbles-paper-128-seed0-tif [N]

The rows in the "floor" group are what any compressor of this design must do (decode every
file, fit a basis, project every texel); the others are this tool's own work after that.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from bench_compress import gemm_baseline
from common import format_machine, machine_info, time_call
from usdbtf.compress import core
from usdbtf.compress.curve import curve_samples, error_curve
from usdbtf.compress.format import write_metadata, write_textures
from usdbtf.compress.linalg import randomized_basis
from usdbtf.compress.source import choose_source
from usdbtf.io import open_btf


def main(argv):
    path, n = argv[0], int(argv[1]) if len(argv) > 1 else 5
    print(format_machine(machine_info()))
    btf = open_btf(path)
    opts = core.Options()
    with tempfile.TemporaryDirectory() as tmp:
        cbtf = core.compress_to_folder(btf, Path(tmp) / "c", opts)
        fit = core._fit_texels(btf, opts)
        evalt = core._eval_texels(btf, fit, opts)
        rows = curve_samples(btf.n_samples)

        def load():
            return choose_source(btf, [fit, evalt], rows, memory_budget=opts.memory_budget)

        data = load()
        x_fit = data.columns(fit)
        truth = data.to_working(data.columns(evalt)).reshape(btf.n_samples, len(evalt), 3)
        k = cbtf.k
        u = cbtf.basis_values(k)
        mix = data.working_mix(np.asarray(cbtf.color_matrix).T)
        planes = cbtf.info["choice"]["planes"]
        out = Path(tmp) / "w"
        out.mkdir()
        floor = {
            f"load: decode {btf.n_samples} files ({data.kind})": load,
            "columns(fit texels)": lambda: data.columns(fit),
            f"fit: randomized basis, {x_fit.shape[1]} columns": lambda: randomized_basis(
                x_fit, k, oversample=opts.oversample, power_iterations=opts.power_iterations, seed=opts.seed,
                return_coefficients=True),
            f"project: planes {planes}": lambda: data.project(u, mix, planes),
        }
        rest = {
            "fit weights": lambda: core._fit_weights(x_fit),
            "truth (evaluation texels, working)": lambda: data.to_working(data.columns(evalt)),
            "evaluate (held-out error)": lambda: core._evaluate(cbtf, truth, evalt),
            "error curve": lambda: error_curve(cbtf, data, opts.seed),
            "write textures (jxl)": lambda: write_textures(cbtf, out),
            "write metadata": lambda: write_metadata(cbtf, out),
        }
        gemm = gemm_baseline(btf.n_samples, btf.n_pixels, 150)
        print(f"input: {path} ({btf.n_samples} samples, {btf.width}x{btf.height}); {len(fit)} fit texels, "
              f"{len(evalt)} evaluation texels; k {k}; {n} runs per step after one warm-up")
        print(f"baseline: float32 U.T @ X, X {tuple(gemm['shape_x'])}, U {tuple(gemm['shape_u'])}: "
              f"min {gemm['min_s']:.3f} s, median {gemm['median_s']:.3f} s")
        print("\n| step | min s | median s | CPU s (median) | min / GEMM min |\n|---|---|---|---|---|")
        for group, steps in (("floor", floor), ("rest", rest)):
            total = 0.0
            for name, fn in steps.items():
                m = time_call(fn, repeats=n, warmup=1)
                total += m["min_s"]
                print(f"| {name} | {m['min_s']:.3f} | {m['median_s']:.3f} | {m['cpu_median_s']:.2f} | "
                      f"{m['min_s'] / gemm['min_s']:.2f} |")
            print(f"| **sum of the {group} steps** | {total:.3f} | | | {total / gemm['min_s']:.2f} |")


if __name__ == "__main__":
    main(sys.argv[1:])
