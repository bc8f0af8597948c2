#!/usr/bin/env python
"""Issue 16 final comparison: the paper, today's default and the proposal, every preset, at the paper's bytes.

Per preset (tuning presets first, then the held-out presets, which no tuning run used):

1. the paper's method on the encoded values (``methods.paper_method``): its stored bytes are the
   budget;
2. today's ``usdbtf compress --max-bytes <budget>`` (subprocess);
3. the proposal (``methods.proposed``) under the same budget;

percent error on the 8-bit encoded values and in scene-linear over every sample, texel and
channel (``--stride`` to subsample), bytes, and compress time.  Then held-out directions: 10 %
of the light directions (every view) are removed, each method stores the rest under the paper's
budget for that subset, and the held-out images are predicted from the 4 nearest stored
directions (basis rows blended in each method's working domain, ``methods.heldout_predictor``);
the "floor" row predicts them from the original images.  Usage::

    .venv/bin/python benchmarks/probes/research/final.py [--presets a,b] [--stride 1] [--no-heldout-directions]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[2] / "research"))   # rlib, methods: issue 16's library

import argparse
import json
import sys
import time

import numpy as np

from rlib import OUT, Timer, evaluate, header, load, paper_budget_inputs, preset_list, say, stride_rows
from methods import direction_split, heldout_errors, paper_cached, paper_method, proposed
from paper_baseline import usdbtf_default


def directions(data, stride: int) -> dict:
    """Held-out-direction errors of paper, default and proposal (see the module docstring)."""
    split = direction_split(data)
    paper = paper_method(split.sub)
    budget = paper.bytes["payload"]
    default = usdbtf_default(split.sub, budget, folder=split.manifest(), tag="fit90")
    ours = proposed(split.sub, budget)
    return heldout_errors(data, split, split.held[::stride], {"paper": paper, "default": default, "proposal": ours})


def main(argv=None) -> int:
    from usdbtf.bench.datasets import HELDOUT_PRESETS, TUNING_PRESETS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", default=",".join(TUNING_PRESETS + HELDOUT_PRESETS))
    p.add_argument("--stride", type=int, default=1)
    p.add_argument("--no-heldout-directions", action="store_true")
    args = p.parse_args(argv)
    presets = preset_list(args.presets, tuning_only=False)
    header("issue 16: paper vs today's default vs the proposal at the paper's bytes",
           paper_budget_inputs(presets, args.stride))
    results = {}
    for preset in presets:
        say(f"## {preset}{' (held out)' if preset in HELDOUT_PRESETS else ''}")
        data = load(preset)
        sel = stride_rows(data, args.stride)
        r = results[preset] = {}
        with Timer() as t:
            paper = paper_cached(data)
        budget = paper.bytes["payload"]
        with Timer() as td:
            default = usdbtf_default(data, budget)
        with Timer() as tp:
            ours = proposed(data, budget)
        for name, f, secs in (("paper", paper, None), ("default", default, td.s), ("proposal", ours, tp.s)):
            e = evaluate(data, f.recon, sel)
            r[name] = {"k": f.k, "bytes": f.bytes, "encoded": e.encoded, "linear": e.linear, "seconds": secs,
                       "domain": f.dom.name, "info": {k: v for k, v in f.info.items() if k != "singular_values"}}
            say(f"  {name:8s}: k {f.k:3d}, {f.bytes['payload']:,} B (basis {f.bytes['basis']:,}), domain "
                f"{f.dom.name}: {e.row()}" + ("" if secs is None else f", {secs:.0f} s"))
        for name in ("default", "proposal"):
            r[name]["ratio"] = [r[name]["encoded"] / r["paper"]["encoded"], r[name]["linear"] / r["paper"]["linear"]]
            say(f"  {name} / paper: {r[name]['ratio'][0]:.3f} enc, {r[name]['ratio'][1]:.3f} lin")
        if not args.no_heldout_directions:
            with Timer() as t:
                r["directions"] = directions(data, args.stride)
            say("  held-out directions (% enc / % lin): " + ", ".join(
                f"{k} {v['encoded']:.2f} / {v['linear']:.2f}" for k, v in r["directions"].items()) + f" ({t.s:.0f} s)")
        (OUT / "final.json").write_text(json.dumps(results, indent=1, default=float))
    say("\n| preset | paper bytes | paper % enc | paper % lin | default k | default % enc | default % lin | default ratio "
        "enc / lin | proposal domain | proposal k | proposal bytes | proposal % enc | proposal % lin | proposal ratio "
        "enc / lin | held-out dirs % enc / lin: floor, paper, default, proposal |")
    say("|" + "---|" * 15)
    for group in (TUNING_PRESETS, HELDOUT_PRESETS):
        for preset in [x for x in presets if x in group]:
            r = results[preset]
            pa, de, pr = r["paper"], r["default"], r["proposal"]
            dirs = r.get("directions")
            dtxt = ("; ".join(f"{dirs[k]['encoded']:.2f} / {dirs[k]['linear']:.2f}"
                              for k in ("floor", "paper", "default", "proposal")) if dirs else "")
            name = preset + (" (held out)" if preset in HELDOUT_PRESETS else "")
            say(f"| {name} | {pa['bytes']['payload']:,} | {pa['encoded']:.2f} | {pa['linear']:.2f} | {de['k']} | "
                f"{de['encoded']:.2f} | {de['linear']:.2f} | {de['ratio'][0]:.3f} / {de['ratio'][1]:.3f} | "
                f"{pr['domain']} | {pr['k']} | {pr['bytes']['payload']:,} | {pr['encoded']:.2f} | {pr['linear']:.2f} | "
                f"**{pr['ratio'][0]:.3f} / {pr['ratio'][1]:.3f}** | {dtxt} |")
    say(f"\nfinished {time.strftime('%Y-%m-%d %H:%M:%S')}; results: {OUT / 'final.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
