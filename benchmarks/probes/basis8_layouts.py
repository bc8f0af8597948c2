#!/usr/bin/env python
"""Bytes of lossless 8-bit PNG layouts of the basis codes against the GPU tables' float32 EXR block (issue 39).

Storm (bpy builds, no OIIO plugin) reads a 16-bit PNG as 8 bits, so a PNG basis Storm can read holds each
integer code as two bytes (high, low) in RGBA8 texels.  For one compressed folder (paper sampling, every light
at every view), the same codes, this prints the bytes of:

* the schema-3 basis block: float32 ``2^23 + code`` group-major in 512-texel rows, OpenEXR zip
  (``packs.basis_block_bytes``, the baseline);
* hi / lo planes, group-major 512-texel rows (4 vectors per texel), as two PNGs and as one (hi rows then lo);
* each group's S = V x L samples as a V x L (or L x V) image, hi and lo side by side or stacked;
* two vectors per texel (hi a, lo a, hi b, lo b), a group as two V x L images side by side;

each with ``packs.encode_png_page`` (level 6, the smaller of adaptive / no filter) and with OIIO's default PNG
settings; and per level of detail of the folder's default lods, the bytes of the first n vectors alone.

Usage (repository root)::

    nice .venv/bin/python benchmarks/probes/basis8_layouts.py FOLDER [FOLDER ...]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py

import argparse
import os
import time

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

from common import format_machine, machine_info
from usdbtf.compress.format import cross_layout, read_compressed
from usdbtf.compress.packs import (TABLE_WIDTH, basis_block_bytes, basis_codes_group_major, default_lods,
                                   encode_png_page)
from usdbtf.imageio import encode_image


def _rows(block: np.ndarray) -> np.ndarray:
    rows = -(-len(block) // TABLE_WIDTH)
    out = np.zeros((rows * TABLE_WIDTH, 4), block.dtype)
    out[:len(block)] = block
    return out.reshape(rows, TABLE_WIDTH, 4)


def _png_default(image: np.ndarray) -> int:
    return len(encode_image(image, "png", color_space="data", attributes={"oiio:UnassociatedAlpha": 1}))


def _png_best(image: np.ndarray) -> int:
    return len(encode_png_page(image))


def candidates(codes: np.ndarray, V: int, L: int) -> dict:
    """{name: (N, M, 4) uint8 images (one or more files)} of the (S, n) integer codes."""
    S, n = codes.shape
    groups = -(-n // 4)
    padded = np.zeros((S, groups * 4), np.int64)
    padded[:, :n] = codes
    gm = padded.reshape(S, groups, 4).transpose(1, 0, 2)          # (G, S, 4)
    hi, lo = (gm >> 8).astype(np.uint8), (gm & 255).astype(np.uint8)
    out = {}
    out["rows 512: hi.png + lo.png"] = [_rows(hi.reshape(-1, 4)), _rows(lo.reshape(-1, 4))]
    out["rows 512: one png, hi rows then lo rows"] = [np.concatenate([_rows(hi.reshape(-1, 4)), _rows(lo.reshape(-1, 4))])]
    vl_hi, vl_lo = hi.reshape(groups * V, L, 4), lo.reshape(groups * V, L, 4)
    out["V x L per group: hi, lo side by side (G V, 2 L)"] = [np.concatenate([vl_hi, vl_lo], axis=1)]
    out["V x L per group: hi, lo stacked per group (2 G V, L)"] = [
        np.stack([hi.reshape(groups, V, L, 4), lo.reshape(groups, V, L, 4)], axis=1).reshape(2 * groups * V, L, 4)]
    lv_hi = hi.reshape(groups, V, L, 4).transpose(0, 2, 1, 3).reshape(groups * L, V, 4)
    lv_lo = lo.reshape(groups, V, L, 4).transpose(0, 2, 1, 3).reshape(groups * L, V, 4)
    out["L x V per group: hi, lo side by side (G L, 2 V)"] = [np.concatenate([lv_hi, lv_lo], axis=1)]
    # Two vectors per texel: (hi a, lo a, hi b, lo b); group g -> two V x L images side by side.
    pair = np.stack([hi, lo], axis=-1).reshape(groups, S, 2, 4)        # (G, S, pair, [hi a, lo a, hi b, lo b])
    out["V x L per group: 2 vectors/texel (hi a lo a hi b lo b), pairs side by side (G V, 2 L)"] = [
        pair.reshape(groups, V, L, 2, 4).transpose(0, 1, 3, 2, 4).reshape(groups * V, 2 * L, 4)]
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folders", nargs="+")
    args = parser.parse_args(argv)
    print(format_machine(machine_info()))
    print(f"load average {os.getloadavg()}")
    for folder in args.folders:
        cbtf = read_compressed(folder)
        V, L = cross_layout(cbtf.sampling)
        codes = cbtf.basis.pixels[:, :, 0]
        print(f"\ninput: {folder}: {cbtf.width}x{cbtf.height}, k {cbtf.k}, {cbtf.n_samples} samples ({V} x {L}), "
              f"basis {codes.dtype} codes {int(codes.min())}..{int(codes.max())}")
        for n in [cbtf.k, *default_lods(cbtf.k)]:
            base = basis_block_bytes(basis_codes_group_major(cbtf, n))
            print(f"\n| k {n}: basis block candidate | encode_png_page | OIIO default png | vs EXR (best) | encode s |")
            print("|---|---:|---:|---:|---:|")
            print(f"| float32 2^23 + code, 512-texel rows, EXR zip (schema 3, baseline) | {base:,} | | 1.000 | |")
            for name, images in candidates(codes[:, :n].astype(np.int64), V, L).items():
                t = time.perf_counter()
                best = sum(_png_best(im) for im in images)
                dt = time.perf_counter() - t
                default = sum(_png_default(im) for im in images)
                print(f"| {name} | {best:,} | {default:,} | {best / base:.3f} | {dt:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
