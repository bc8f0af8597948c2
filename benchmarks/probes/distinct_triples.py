#!/usr/bin/env python
"""How many distinct 8-bit (r, g, b) code triples a material holds (issue 42): what the
conversion memo (``usdbtf.compress.convert.TripleConversion``) converts, and the pages of its
2^24-entry number table those triples write (4 KiB pages of int32 numbers, triple packed as
r + 256 g + 65536 b: the memory the table costs).

    .venv/bin/python benchmarks/probes/distinct_triples.py FOLDER [FOLDER ...] [--stride 2]

Every ``--stride``-th sample of each folder is read (OpenImageIO, the stored codes).
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py

import argparse
import sys

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

from common import format_machine, machine_info
from usdbtf.io import open_btf


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--stride", type=int, default=2)
    args = ap.parse_args(argv)
    print(format_machine(machine_info()))
    print(f"\nevery {args.stride}-th sample\n\n| input | samples read | distinct triples | number-table pages "
          "(MB) | primaries matrix |\n|---|---|---|---|---|")
    for folder in args.folders:
        btf = open_btf(folder)
        if btf.bit_depth != "uint8":
            print(f"| {folder} | - | not 8-bit | - | - |")
            continue
        seen = np.zeros(1 << 24, bool)
        rows = range(0, btf.n_samples, args.stride)
        for i in rows:
            im = btf.read_one(i).reshape(-1, 3).astype(np.uint32)
            seen[im[:, 0] | im[:, 1] << 8 | im[:, 2] << 16] = True
        keys = np.flatnonzero(seen)
        pages = len(np.unique(keys >> 10))
        dec = btf.integer_decoder
        print(f"| {folder} | {len(rows)} | {len(keys):,} | {pages:,} ({pages * 4096 / 1e6:.1f}) | "
              f"{'yes' if dec is not None and dec.matrix is not None else 'no'} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
