#!/usr/bin/env python
"""Held-out light directions: where to blend when the working domain is a curve.

Per preset: 10 % of the light directions held out (every view), the proposal
(``methods.proposed``) and today's default store the rest under the paper's budget for that
subset, and the held-out images are predicted from the 4 nearest stored directions, either
by blending basis rows in the working domain before the dot product and the inverse curve
("rows": one dot product per texel, what ``final.py`` reports) or by blending the
neighbours' linear reconstructions ("images": 4 dot products per texel).  Usage::

    .venv/bin/python benchmarks/probes/research/heldout_blend.py --presets velvet [--stride 1]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[2] / "research"))   # rlib, methods: issue 16's library

import argparse
import sys

from rlib import OUT, evaluate, header, load, preset_list, say
from methods import direction_split, heldout_predictor, paper_method, proposed, restore, save
from paper_baseline import usdbtf_default


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", default="velvet")
    p.add_argument("--stride", type=int, default=1)
    args = p.parse_args(argv)
    presets = preset_list(args.presets, tuning_only=False)
    header("issue 16: held-out directions, blending basis rows before the curve vs linear images after it",
           [f"presets {', '.join(presets)}; 10 % of the lights held out (seed 0), 4 nearest neighbours",
            "sampling paper, 128x128, 8-bit sRGB PNG; budget = the paper's bytes for the fitted subset",
            f"errors over every {args.stride}-th held-out sample"])
    for preset in presets:
        data = load(preset)
        split = direction_split(data)
        sel = split.held[::args.stride]
        budget = paper_method(split.sub).bytes["payload"]
        default = usdbtf_default(split.sub, budget, folder=split.manifest(), tag="fit90")
        cache = OUT / "proposal" / f"{data.name}-fit90-{budget}.npz"
        ours = restore(cache)
        if ours is None:
            ours = proposed(split.sub, budget)
            save(ours, cache)
        for name, f in (("default", default), ("proposal", ours)):
            for mode in ("rows", "images"):
                predict = heldout_predictor(f, split.fitted, split.query, mode=mode)
                e = evaluate(data, lambda s: predict(split.position[s]), sel, chunk=64)
                say(f"{preset:15s} {name:8s} ({f.dom.name:8s}, k {f.k}) blend {mode:6s}: {e.row()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
