#!/usr/bin/env python
"""Working-domain scores of any curves, as ``--domain auto`` scores its own (issue 39).

For each input folder, prints the coarse and the fine pass of
``usdbtf.compress.domain_choice.score_domains`` over the curves given: the unquantised
held-out error of each curve's basis on the encoded values and in scene-linear (%), and the
score auto ranks by (log enc + log lin; lower is better), with the seconds each pass took.
The options are a budgeted compress's (``--max-bytes``: 500 vectors fitted; the scores use the
first min(300, S/4) of them, as compress does), so the numbers are the ones a budget run logs.

    PYTHONPATH=<tree>/pipeline .venv/bin/python benchmarks/probes/domain_curves.py \\
        benchmarks/out/data/metal_flakes-paper-128-seed0 [...] --curves linear,1.6,2.2,srgb,3

Nothing is written.  A curve is ``linear``, ``srgb`` or a gamma G (x^(1/G), 1 <= G <= 4).
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1] / "research"))   # benchmarks/research/rlib.py

import argparse
import time

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform)
from rlib import header, say  # noqa: E402


def _curve(text: str):
    from usdbtf.compress.domain import LINEAR, Domain

    if text == "linear":
        return LINEAR
    if text == "srgb":
        return Domain("srgb")
    return Domain("power", float(text))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("inputs", nargs="+", help="BTF folders (rectified, or a synth output)")
    p.add_argument("--curves", default="linear,1.6,2.2,srgb,3", help="comma-separated curves to score")
    args = p.parse_args()

    from usdbtf.compress import CompressOptions
    from usdbtf.compress import domain_choice
    from usdbtf.compress.select_source import load_source
    from usdbtf.compress.texels import sample_texels
    from usdbtf.io import open_btf

    curves = [_curve(c.strip()) for c in args.curves.split(",") if c.strip()]
    header("domain curves scored as --domain auto scores them",
           [f"input: {folder}" for folder in args.inputs] + [f"curves: {args.curves}"])
    for folder in args.inputs:
        btf = open_btf(folder)
        opts = CompressOptions(max_bytes=1_000_000)            # a budget run's fit (500 vectors)
        texels = sample_texels(btf, opts)
        k = opts.fit_k(btf.n_samples, btf.n_pixels)
        say(f"\n## {folder}: {btf.n_samples} samples, {btf.width}x{btf.height}, fit k {k}")
        say("| pass | curve | encoded % | linear % | score | pass s |")
        say("|---|---|---|---|---|---|")
        with load_source(btf, texels, opts) as source:
            for name, strides in (("coarse", domain_choice.COARSE), ("fine", domain_choice.FINE)):
                t0 = time.perf_counter()
                scores, _ = domain_choice.score_domains(source, texels, k, opts, curves, strides=strides)
                seconds = time.perf_counter() - t0
                best = min(scores, key=lambda n: scores[n]["score"])
                for curve, s in scores.items():
                    mark = " (best)" if curve == best else ""
                    say(f"| {name} | {curve}{mark} | {s['encoded']:.3f} | {s['linear']:.3f} | {s['score']:.4f} "
                        f"| {seconds:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
