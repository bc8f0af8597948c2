#!/usr/bin/env python
"""Sweep prototype configurations of the default solver at the paper's bytes (tuning presets only).

Per tuning preset: the paper's method on the encoded values (``methods.paper_method``) sets the
byte budget; each configuration of the prototype (``methods.factorise``: randomized SVD in a
working domain, colour PCA, uniform step, lossless JPEG XL, (k, step) by rate-distortion) is run
and evaluated in both error domains; ratios are to the paper.  A configuration is a string of
``key=value`` pairs (``methods.parse_config``): dom (linear, srgb, gammaG, logE), k_max, n_fit,
power_iterations, fit_weight, layout (rgb, planar), effort, basis_effort.  Held-out presets
are refused.  Usage::

    .venv/bin/python benchmarks/probes/research/sweep.py --presets fuzzy_moss \\
        --configs "dom=linear" "dom=gamma2,k_max=450,layout=planar" [--stride 4]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[2] / "research"))   # rlib, methods: issue 16's library

import argparse
import sys

from rlib import Timer, evaluate, header, load, preset_list, say, stride_rows
from methods import paper_cached, run_config


def main(argv=None) -> int:
    from usdbtf.bench.datasets import TUNING_PRESETS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", default=",".join(TUNING_PRESETS))
    p.add_argument("--configs", nargs="+", default=["dom=linear", "dom=srgb"])
    p.add_argument("--stride", type=int, default=4, help="evaluate every N-th sample (default 4)")
    args = p.parse_args(argv)
    presets = preset_list(args.presets, tuning_only=True)
    header("issue 16 sweep: prototype configurations at the paper's bytes",
           [f"tuning presets {', '.join(presets)}", f"configurations: {'; '.join(args.configs)}",
            "sampling paper (10,800 samples), 128x128, 8-bit sRGB PNG, synth seed 0",
            "budget: the paper method's stored bytes (basis + coefficient files) on the same data",
            f"errors over every {args.stride}-th sample (all texels, channels)"])
    table = []
    for preset in presets:
        say(f"## {preset}")
        data = load(preset)
        sel = stride_rows(data, args.stride)
        with Timer() as t:
            paper = paper_cached(data)
        ep = evaluate(data, paper.recon, sel)
        budget = paper.bytes["payload"]
        say(f"  paper: {budget:,} B, {ep.row()} ({t.s:.0f} s)")
        for cfg in args.configs:
            with Timer() as t:
                f = run_config(data, budget, cfg)
            e = evaluate(data, f.recon, sel)
            ratio = (e.encoded / ep.encoded, e.linear / ep.linear)
            say(f"  [{cfg}] k {f.k}, step {f.info['step']:.3g}, {f.bytes['payload']:,} B (basis "
                f"{f.bytes['basis']:,}): {e.row()}, ratio {ratio[0]:.3f} enc {ratio[1]:.3f} lin ({t.s:.0f} s)")
            table.append((preset, cfg, f, e, ratio))
    say("\n| preset | configuration | k | bytes (basis) | % err enc | % err lin | ratio enc | ratio lin |")
    say("|---|---|---|---|---|---|---|---|")
    for preset, cfg, f, e, ratio in table:
        say(f"| {preset} | `{cfg}` | {f.k} | {f.bytes['payload']:,} ({f.bytes['basis']:,}) | {e.encoded:.2f} | "
            f"{e.linear:.2f} | {ratio[0]:.3f} | {ratio[1]:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
