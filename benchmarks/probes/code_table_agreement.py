#!/usr/bin/env python
"""Issue 42: how closely the 8-bit code table (``usdbtf.compress.code_table``) gives
OpenColorIO's codes, and at what cost.

Two transforms: the per-channel curve of sRGB files from a Rec.709 working space, and the
transform of an input's files (``--input FOLDER``: its working space and decode matrix; default
the sRGB files of the default working space, a primaries matrix then the curve).

* every float32 bit pattern in [0, 1.01] through the per-channel curve (``--every``: 1.07e9
  values, about a minute): how many codes differ from OpenColorIO's, and by how much;
* 786,432 smooth colours (one evaluation block: 256 samples x 1024 texels x 3) through each:
  the same counts, and the median time of each encoder over 15 calls.

Usage (repository root)::

    .venv/bin/python benchmarks/probes/code_table_agreement.py [--input FOLDER] [--every]
"""
from __future__ import annotations

import argparse
import time

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

from usdbtf import color
from usdbtf.compress.code_table import CodeTable
from usdbtf.manifest import encode_for_file

SRGB = "sRGB Encoded Rec.709 (sRGB)"
LIN709 = "Linear Rec.709 (sRGB)"


def _median_ms(fn, runs: int = 15) -> float:
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)) * 1000


def _differences(table: CodeTable, proc, values: np.ndarray) -> tuple[int, int]:
    off = table(values).astype(np.int16) - encode_for_file(values, proc, "uint8").astype(np.int16)
    return int(np.count_nonzero(off)), int(np.abs(off).max()) if off.size else 0


def every_float(table: CodeTable, proc, top: float = 1.01, chunk: int = 1 << 24) -> tuple[int, int, int]:
    """(values, differing codes, largest difference) over every float32 in [0, top]."""
    end = int(np.float32(top).view(np.int32))
    total = bad = worst = 0
    for a in range(0, end, chunk):
        bits = np.arange(a, min(a + chunk, end), dtype=np.int32)
        bits = bits[: len(bits) // 3 * 3]
        v = bits.view(np.float32).reshape(-1, 3)
        n, w = _differences(table, proc, v)
        total, bad, worst = total + v.size, bad + n, max(worst, w)
    return total, bad, worst


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--input", help="a BTF folder: its files' transform (default: sRGB files, default working space)")
    ap.add_argument("--every", action="store_true", help="also every float32 in [0, 1.01] (about a minute)")
    args = ap.parse_args()
    cases = {"per-channel sRGB curve (Rec.709 working space)": (color.processor(LIN709, SRGB), None)}
    if args.input:
        from usdbtf.io import open_btf

        btf = open_btf(args.input)
        dec = btf.integer_decoder
        cases[f"{args.input}: {btf.working_space} -> {btf.color_space}"] = (
            color.processor(btf.working_space, btf.color_space, btf.ocio_config), None if dec is None else dec.matrix)
    else:
        cases[f"{color.WORKING_SPACE} -> {SRGB} (decode matrix)"] = (
            color.processor(color.WORKING_SPACE, SRGB), color.integer_decoder(SRGB, 8).matrix)
    rng = np.random.default_rng(0)
    block = ((rng.random((256, 1024, 3), dtype=np.float32) ** 3) * 1.1 - 0.01).astype(np.float32)
    print(f"# code table against OpenColorIO ({block.size:,} smooth values per block)")
    for name, (proc, matrix) in cases.items():
        t = time.perf_counter()
        table = CodeTable.build(proc, "uint8", matrix)
        built = time.perf_counter() - t
        if table is None:
            print(f"{name}: no table (OpenColorIO used)")
            continue
        n, worst = _differences(table, proc, block)
        print(f"{name}: built in {built:.3f} s (buckets of bits >> {table.shift}, {table.base.shape[1]:,}, "
              f"shared curve {table.shared}); smooth block: {n} of {block.size:,} codes differ (at most {worst}); "
              f"table {_median_ms(lambda: table(block)):.2f} ms, OpenColorIO "
              f"{_median_ms(lambda: encode_for_file(block, proc, 'uint8')):.2f} ms (medians of 15)")
        if args.every and matrix is None:
            total, bad, worst = every_float(table, proc)
            print(f"  every float32 in [0, 1.01]: {bad} of {total:,} codes differ (at most {worst})")


if __name__ == "__main__":
    main()
