"""Where plain ``usdbtf compress`` spends its time, step by step, against the GEMM baseline.

Each public step of a default compress (rsvd, jxl, k = 150; see ``usdbtf.compress.compress``)
is timed on its own in one process: minimum and median of N runs, wall and CPU seconds (this
process + its decode workers).  The float32 GEMM U^T X of issue 2's speed target is timed
the same way, so every row also reads as a fraction of it.  Min-of-N is robust on a shared,
busy machine (noise only adds time): use this for before/after comparisons of single steps;
whole-run claims come from bench_compress.py and ab_compress.sh.

    .venv/bin/python benchmarks/micro_compress_steps.py benchmarks/out/data/pebbles-paper-128-seed0-tif [N]

The rows in the "floor" group are what any compressor of this design must do (decode every
file, fit a basis, project every texel); the others are this tool's own work after that.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from bench_compress import gemm_baseline
from common import format_machine, machine_info, time_call
from usdbtf.compress import (CompressOptions, Factorisation, color_decorrelation, compress, error_curve, fit_basis,
                             held_out_error, held_out_set, load_source, project, rate_control, rotate_color,
                             sample_texels, sampled_coefficients, step_for_k, write_compress)
from usdbtf.io import open_btf


def main(argv):
    path, n = argv[0], int(argv[1]) if len(argv) > 1 else 5
    print(format_machine(machine_info()))
    btf = open_btf(path)
    opts = CompressOptions()
    result = compress(btf, opts)
    texels = sample_texels(btf, opts)
    source = load_source(btf, texels, opts)
    x_fit = source.columns(texels.fit)
    k_fit = opts.fit_k(btf.n_samples, btf.n_pixels)
    fit = fit_basis(x_fit, k_fit, opts)
    held = held_out_set(source, texels)

    def color_and_step():
        sampled, outside = sampled_coefficients(fit, source.to_working, held.truth, btf.n_pixels)
        color = color_decorrelation(sampled)
        return color, outside, step_for_k(rotate_color(sampled, color), fit.basis, outside, btf.n_pixels, opts)

    color, outside, (step, planes) = color_and_step()
    coeff, _ = project(source, fit.basis, color, planes)
    energy = float(np.einsum("kpc,kpc->", coeff, coeff, dtype=np.float64)) + outside
    factors = Factorisation(btf, fit.basis, coeff, color, energy, planes, step)
    with tempfile.TemporaryDirectory() as tmp:
        floor = {
            f"load: decode {btf.n_samples} files ({source.kind})": lambda: load_source(btf, texels, opts),
            "columns (fit texels)": lambda: source.columns(texels.fit),
            f"fit_basis: weights + randomized basis, {x_fit.shape[1]} columns": lambda: fit_basis(x_fit, k_fit, opts),
            f"project: planes {list(planes)}": lambda: project(source, fit.basis, color, planes),
        }
        rest = {
            "held_out_set (evaluation texels, working)": lambda: held_out_set(source, texels),
            "colour decorrelation + step_for_k": color_and_step,
            f"rate_control: quantise + encode in memory (k {result.k})": lambda: rate_control(
                factors, opts, held),
            "held_out_error": lambda: held_out_error(result, held),
            "error curve": lambda: error_curve(result, source),
            "write_compress (files: textures, metadata, curve)": lambda: write_compress(
                result, Path(tmp) / "w", force=True),
        }
        gemm = gemm_baseline(btf.n_samples, btf.n_pixels, 150)
        print(f"input: {path} ({btf.n_samples} samples, {btf.width}x{btf.height}); {len(texels.fit)} fit texels, "
              f"{len(texels.evaluation)} evaluation texels; k {result.k}; {n} runs per step after one warm-up")
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
