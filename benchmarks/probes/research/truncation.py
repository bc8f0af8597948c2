#!/usr/bin/env python
"""How far can more components go?  Unquantised error vs k, per working domain.

Per tuning preset and domain: a randomized SVD (k up to --k-max) on sampled texels, every
texel projected, NO quantisation; percent error (encoded, linear) of the first k components
for each k in --ks.  This is the floor any storage of a k-component basis reaches; the gap
to the quantised result at the paper's bytes is what storage costs.  Usage::

    .venv/bin/python benchmarks/probes/research/truncation.py [--presets a,b] [--domains linear,srgb] [--ks 150,300]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[2] / "research"))   # rlib, methods: issue 16's library

import argparse
import sys

import numpy as np

from rlib import domain, evaluate, header, load, preset_list, say, stride_rows
from methods import Factorised, fit_texels, project


def main(argv=None) -> int:
    from usdbtf.compress.linalg import randomized_basis

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", default="fuzzy_moss")
    p.add_argument("--domains", default="linear,gamma2,srgb")
    p.add_argument("--ks", default="100,150,200,300,400,600,800")
    p.add_argument("--fit", type=int, default=4096)
    p.add_argument("--stride", type=int, default=8)
    args = p.parse_args(argv)
    presets = preset_list(args.presets, tuning_only=True)
    ks = [int(x) for x in args.ks.split(",")]
    header("issue 16: unquantised error vs k (truncation floor)",
           [f"tuning presets {', '.join(presets)}; domains {args.domains}; k {args.ks}; fit texels {args.fit}",
            f"sampling paper, 128x128, 8-bit sRGB PNG; errors over every {args.stride}-th sample"])
    for preset in presets:
        data = load(preset)
        sel = stride_rows(data, args.stride)
        for name in args.domains.split(","):
            dom = domain(name)
            table = dom.code_table(data.lut)
            fit = fit_texels(data, args.fit)
            x = table[np.asarray(data.codes[:, fit, :])].reshape(data.S, -1)
            u, sv = randomized_basis(x, min(max(ks), x.shape[1] - 16), power_iterations=1)
            coeff = project(data, u, table)[0].reshape(u.shape[1], -1)
            out = []
            for k in ks:
                f = Factorised(u[:, :k], coeff[:k], dom, {})
                e = evaluate(data, f.recon, sel)
                out.append(f"k {k}: {e.encoded:.2f} / {e.linear:.2f}")
            say(f"{preset:13s} {name:8s} (enc / lin %)  " + "  ".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
