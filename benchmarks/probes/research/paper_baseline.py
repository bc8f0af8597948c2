#!/usr/bin/env python
"""The honest baseline of issue 16: the paper's method as the paper ran it, and today's default.

Per preset (paper sampling 90 x 120, 128², 8-bit sRGB PNG from ``usdbtf synth``):

paper    Koudelka et al. 2003 on the 8-bit camera values (no linearisation): exact SVD of the
         central 32² texels, k = 150, coefficient textures min-max scaled to 8-bit JPEG q90
         (4:4:4), basis min-max scaled per vector into one uncompressed 8-bit TIFF
         (``methods.paper_method``).  Its stored bytes (basis + coefficient files) are the budget.
usdbtf   today's ``usdbtf compress IN -o OUT --max-bytes <paper bytes>`` (default solver, which
         fits in scene-linear), run as a subprocess.

Percent error on the 8-bit encoded values and in scene-linear (ACEScg), every sample, texel
and channel (``--stride N`` evaluates every N-th sample only).  Usage::

    .venv/bin/python benchmarks/probes/research/paper_baseline.py [--presets a,b] [--stride 1]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[2] / "research"))   # rlib, methods: issue 16's library

import argparse
import json
import subprocess
import sys

import numpy as np

from rlib import DATA, OUT, REPO, Timer, evaluate, header, load, preset_list, say, stride_rows
from methods import Factorised, paper_method


def usdbtf_default(data, budget: int, folder=None, tag: str = "") -> Factorised:
    """``usdbtf compress --max-bytes budget`` on the dataset's folder (or ``folder``, a manifest
    of a subset of it), read back (cached under benchmarks/out/research/cli)."""
    from usdbtf.color import mix_rgb
    from usdbtf.compress import read_compressed
    from usdbtf.compress.format import working_coefficients
    from rlib import domain

    folder = folder or DATA / f"{data.name}-paper-{data.size}-seed0"
    out = OUT / "cli" / f"{data.name}{'-' + tag if tag else ''}-default-{budget}"
    if not (out / "btf-compressed.json").is_file():
        subprocess.run([str(REPO / ".venv/bin/usdbtf"), "compress", str(folder), "-o", str(out),
                        "--max-bytes", str(budget), "-q"], check=True)
    c = read_compressed(out)
    # working space (ACEScg) -> linear Rec.709 coefficients: the evaluation's domain
    to_709 = np.linalg.inv(data.to_aces.astype(np.float64)).astype(np.float32)
    coeff = mix_rgb(working_coefficients(c).reshape(c.k, -1, 3), to_709).reshape(c.k, -1)
    doc = json.loads((out / "btf-compressed.json").read_text())
    return Factorised(c.basis_values(), coeff, domain("linear"), dict(doc["bytes"]),
                      {"method": "usdbtf default", "k": c.k})


def main(argv=None) -> int:
    from usdbtf.bench.datasets import HELDOUT_PRESETS, TUNING_PRESETS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", default=",".join(TUNING_PRESETS + HELDOUT_PRESETS))
    p.add_argument("--stride", type=int, default=1, help="evaluate every N-th sample (default 1: all)")
    args = p.parse_args(argv)
    presets = preset_list(args.presets, tuning_only=False)
    header("issue 16 baseline: the paper's method on the encoded values vs today's default",
           [f"presets {', '.join(presets)} (held out: {', '.join(x for x in presets if x in HELDOUT_PRESETS) or '-'})",
            "sampling paper (90 views x 120 lights = 10,800 samples), 128x128, 8-bit sRGB PNG, synth seed 0",
            f"errors over every {args.stride}-th sample, all texels and channels"])
    rows = []
    for preset in presets:
        say(f"## {preset}")
        data = load(preset)
        with Timer() as t:
            paper = paper_method(data)
        budget = paper.bytes["payload"]
        say(f"  paper: {budget:,} B (basis {paper.bytes['basis']:,}, coefficients {paper.bytes['coefficients']:,}) "
            f"in {t.s:.1f} s")
        with Timer() as t:
            default = usdbtf_default(data, budget)
        say(f"  usdbtf default --max-bytes {budget}: k {default.k}, {default.bytes['payload']:,} B in {t.s:.1f} s")
        sel = stride_rows(data, args.stride)
        ep, ed = evaluate(data, paper.recon, sel), evaluate(data, default.recon, sel)
        say(f"  paper   {ep.row()}\n  default {ed.row()}\n  ratio   {ed.encoded / ep.encoded:.3f} enc, "
            f"{ed.linear / ep.linear:.3f} lin")
        rows.append((preset, budget, ep, default, ed))
    say("\n| preset | paper bytes | paper % err enc | paper % err lin | default k | default bytes | default % err enc "
        "| default % err lin | ratio enc | ratio lin |")
    say("|---|---|---|---|---|---|---|---|---|---|")
    for preset, budget, ep, default, ed in rows:
        name = preset + (" (held out)" if preset in HELDOUT_PRESETS else "")
        say(f"| {name} | {budget:,} | {ep.encoded:.2f} | {ep.linear:.2f} | {default.k} | "
            f"{default.bytes['payload']:,} | {ed.encoded:.2f} | {ed.linear:.2f} | "
            f"{ed.encoded / ep.encoded:.3f} | {ed.linear / ep.linear:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
