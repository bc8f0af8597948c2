"""How well a part of the basis image calibrates the basis's entropy model (``--max-bytes``' probe).

Issue 27 (fifth session): under ``--max-bytes`` rate control calibrates the rate-distortion
model on probe encodes: a dozen coefficient textures, and the basis image.  The whole basis
image at effort 7 was the probe's longest encode (~1 s of 1.3 s at paper scale); the product
now encodes every 2nd vector's (``ratecontrol._basis_factor``).  This script runs
``compress`` in process with ``--max-bytes`` on each INPUT and, at the basis probe's
(k, step), encodes the basis image of all k vectors and of every 2nd, 3rd, 4th and 6th of them.  For each
it prints the codec factor (measured bytes / modelled bytes of the vectors encoded), its
difference from the whole basis's, and the encode's seconds.  The run itself goes on with the
product's own probe, so its log also shows the basis bytes the calibrated model predicted
for the final k against the encode.

Usage::

    .venv/bin/python benchmarks/probes/bench_basis_probe.py benchmarks/out/data/metal_flakes-paper-128-seed0:3418156 \\
        benchmarks/out/data/velvet-paper-128-seed0:3416429
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py and the benchmarks a probe reuses

import argparse
import dataclasses
import logging
import time

import usdbtf  # noqa: F401  (first: it pins the numeric platform before numpy loads, as the CLI runs)
import numpy as np

from common import format_machine, machine_info
from usdbtf.compress import core, ratecontrol
from usdbtf.compress.codecs import Stored
from usdbtf.compress.format import encode_basis
from usdbtf.compress.options import CompressOptions
from usdbtf.compress.quantise import quantise
from usdbtf.io import open_btf

STRIDES = (1, 2, 3, 4, 6)


def _basis_factors(table, f, k: int, step: float, options) -> list[tuple[int, float, float]]:
    """(stride, codec factor, encode seconds) of the basis image of every stride-th of the
    first k vectors, quantised at ``step``."""
    j = table.column(step)
    whole = quantise(f, k, step, options)
    rows = []
    for stride in STRIDES:
        idx = np.arange(0, k, stride)
        b = whole.basis
        part = dataclasses.replace(whole, basis=Stored(np.ascontiguousarray(b.pixels[:, idx]), b.scale[idx], b.bias[idx]),
                                   coefficients=[whole.coefficients[i] for i in idx], encoded=None)
        t = time.perf_counter()
        n = len(encode_basis(part))
        rows.append((stride, n / float(table.basis_bytes[idx, j].sum()), time.perf_counter() - t))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("inputs", nargs="+", help="FOLDER:MAX_BYTES")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="    %(message)s")
    logging.getLogger("usdbtf.compress.core").setLevel(logging.WARNING)      # the rate control's lines only
    print("# basis probe: codec factor of every n-th basis vector against the whole basis")
    print("(the run's own log: the calibrated model's basis bytes for the final k against its encode)")
    print(format_machine(machine_info()))
    probe = ratecontrol._basis_factor
    for item in args.inputs:
        folder, budget = item.rsplit(":", 1)
        found = []

        def measured(table, f, k, step, options):
            found.extend(_basis_factors(table, f, k, step, options))
            found.insert(0, (k, step))
            return probe(table, f, k, step, options)

        ratecontrol._basis_factor = measured
        try:
            print(f"\n## {folder}, --max-bytes {budget}")
            core.compress(open_btf(folder), CompressOptions(max_bytes=int(budget)))
        finally:
            ratecontrol._basis_factor = probe
        (k, step), rows = found[0], found[1:]
        whole = rows[0][1]
        print(f"\nprobe at k = {k}, step = {step:.4g}")
        print("| vectors encoded | codec factor | vs the whole basis | encode s |")
        print("|---|---|---|---|")
        for stride, factor, seconds in rows:
            print(f"| every {stride} ({len(range(0, k, stride))}) | {factor:.4f} | {100 * (factor / whole - 1):+.2f} % | {seconds:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
