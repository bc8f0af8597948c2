#!/usr/bin/env python
"""Bytes of the GPU tables' basis codes and of the coefficient pages at the same codes, by encoding (issue 39).

Reads one compressed folder (``usdbtf compress`` output; paper sampling, every light at every view) and encodes,
without changing a code:

basis block (the stored codes group-major, 512-texel rows, 4 vectors per texel, as the tables hold them)
  * float32 codes, OpenEXR zip (the tables before schema 3) and with zips / piz;
  * float32 ``2^23 + code`` (schema 3, ``usdbtf.compress.packs.BASIS_CODE_OFFSET``: one exponent for every code,
    so the texel's low bytes are the code) with zip / zips / piz;
  * half codes (exact only while the largest code <= 2048; a file and sampler of their own), half high and low
    bytes, and the high and low bytes as two RGBA8 PNGs (what Storm reads exactly; two samplers);
  * the view x light 2-D order (each group's samples as a V x L image) instead of 512-texel rows.
whole ``tables.exr`` as ``package`` writes it (``gpu_layout``, OpenEXR zip), before (offset 0) and after;
coefficient packs (``coefficient_packs``, each encoded alone as ``ShippedPacks`` measures pages): PNG level 6
(``package``) against level 9, and per-pack filter choices, with encode seconds.

Usage (repository root)::

    nice .venv/bin/python benchmarks/bench_basis_codes.py FOLDER

Prints machine, inputs and a markdown table; deterministic bytes (times vary with load).
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

from usdbtf.compress.format import read_compressed
from usdbtf.compress.packs import (BASIS_CODE_OFFSET, TABLE_WIDTH, basis_code_offset, basis_codes_group_major,
                                   coefficient_packs, default_lods, page_breaks)
from usdbtf.gpu.tables import gpu_layout
from usdbtf.imageio import encode_image


def _rows(block: np.ndarray) -> np.ndarray:
    """(N, 4) texels as an image of TABLE_WIDTH-texel rows, the last row padded with zeros."""
    rows = -(-len(block) // TABLE_WIDTH)
    out = np.zeros((rows * TABLE_WIDTH, 4), block.dtype)
    out[:len(block)] = block
    return out.reshape(rows, TABLE_WIDTH, 4)


def _exr(image: np.ndarray, compression: str) -> int:
    return len(encode_image(image, "exr", color_space="data", attributes={"compression": compression}))


def _png(image: np.ndarray, **attributes) -> int:
    return len(encode_image(image, "png", color_space="data", attributes={"oiio:UnassociatedAlpha": 1, **attributes}))


def basis_rows(cbtf, views: int, lights: int) -> list[tuple[str, int]]:
    """(candidate, bytes) of the basis block's encodings (module docstring)."""
    k, S = cbtf.k, cbtf.n_samples
    groups = -(-k // 4)
    stored = basis_codes_group_major(cbtf, k).astype(np.float64) - basis_code_offset(cbtf.basis.pixels.dtype)
    out = []
    for comp in ("zip", "zips", "piz"):
        out.append((f"float32 codes, EXR {comp}", _exr(_rows(stored).astype(np.float32), comp)))
        shifted = _rows(stored + BASIS_CODE_OFFSET).astype(np.float32)
        out.append((f"float32 2^23 + code, EXR {comp}", _exr(shifted, comp)))
    two_d = stored.reshape(groups, views, lights, 4).reshape(groups * views, lights, 4)
    out.append(("float32 2^23 + code, V x L images, EXR zip",
                _exr((two_d + BASIS_CODE_OFFSET).astype(np.float32), "zip")))
    if stored.max() <= 2048:
        for comp in ("zip", "piz"):
            out.append((f"half codes (own file), EXR {comp}", _exr(_rows(stored).astype(np.float16), comp)))
    hi, lo = np.floor(stored / 256), stored % 256
    for comp in ("zip", "piz"):
        out.append((f"half hi|lo bytes (own file), EXR {comp}",
                    _exr(np.concatenate([_rows(hi), _rows(lo)]).astype(np.float16), comp)))
    out.append(("RGBA8 PNG hi + lo (two files)", _png(_rows(hi).astype(np.uint8)) + _png(_rows(lo).astype(np.uint8))))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", help="a compressed folder (usdbtf compress output)")
    args = parser.parse_args(argv)
    cbtf = read_compressed(args.folder)
    from usdbtf.compress.format import cross_layout
    views, lights = cross_layout(cbtf.sampling)
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, "
          f"python {platform.python_version()}")
    print(f"input: {args.folder}: {cbtf.width}x{cbtf.height}, k {cbtf.k}, "
          f"{cbtf.n_samples} samples ({views} x {lights}), basis {cbtf.basis.pixels.dtype} codes {int(cbtf.basis.pixels.min())}..{int(cbtf.basis.pixels.max())}")
    print("\n| basis block candidate | bytes | vs float32 codes zip |\n|---|---:|---:|")
    rows = basis_rows(cbtf, views, lights)
    base = rows[0][1]
    for name, size in rows:
        print(f"| {name} | {size:,} | {size / base:.3f} |")

    layout = gpu_layout(cbtf, lods=default_lods(cbtf.k))
    after = layout.tables.copy()
    flat = after.reshape(-1, 4)
    basis_at, groups, offset = int(flat[1, 1]), int(flat[0, 3]), float(flat[int(flat[1, 1]), 3])
    before = after.copy()
    bflat = before.reshape(-1, 4)
    at = basis_at + 1 + 2 * groups
    bflat[at:at + groups * cbtf.n_samples] -= offset
    bflat[basis_at, 3] = 0.0
    t_before, t_after = _exr(before, "zip"), _exr(after, "zip")
    print(f"\n| whole gpu/tables.exr (package, EXR zip) | bytes |\n|---|---:|\n| codes (schema 2) | {t_before:,} |\n"
          f"| 2^23 + code (schema 3) | {t_after:,} |\n| ratio | {t_after / t_before:.3f} |")

    packs, _, _ = coefficient_packs(cbtf, cbtf.k, page_breaks(cbtf.k, default_lods(cbtf.k)))
    packs = [p for p in packs if p.dtype == np.uint8]
    print(f"\n| {len(packs)} RGBA8 coefficient packs, PNG | bytes | encode s |\n|---|---:|---:|")
    variants = [("level 6, adaptive filter (package)", {"png:compressionLevel": 6}),
                ("level 9, adaptive filter", {"png:compressionLevel": 9}),
                ("level 6, no filter", {"png:compressionLevel": 6, "png:filter": 8})]
    sizes = {}
    for name, attributes in variants:
        start = time.perf_counter()
        sizes[name] = [_png(p, **attributes) for p in packs]
        print(f"| {name} | {sum(sizes[name]):,} | {time.perf_counter() - start:.1f} |")
    best = sum(min(a, b) for a, b in zip(sizes[variants[0][0]], sizes[variants[2][0]]))
    print(f"| level 6, the smaller of adaptive / none per pack | {best:,} | (both) |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
