#!/usr/bin/env python
"""Issue 42: how well a part of the texel rows counts the fallback maps' bytes
(``usdbtf.usd.asset.fallback_count``), and what fitting only that part saves.

``--maps ASSET.usda ...``: each asset's fallback maps (UsdPreviewSurface and OpenPBR, as
shipped) re-encoded from a part of their rows, the bytes scaled by the rows left out, against
the whole maps' bytes.  Parts: one contiguous block in the middle (a quarter, a half); bands of
16 rows in every 32 (half, shipped), of 8 in every 32 and 16 in every 64 (a quarter), of 32
in every 64 (half), stacked into one image; 2 or 4
evenly spaced blocks, each a file of its own.

``--count FOLDER ...``: ``asset_overhead`` of each compressed folder as rate control runs it
(the bands' fits) and with fits on every texel: the asset's bytes counted and the CPU seconds.

Usage (repository root)::

    .venv/bin/python benchmarks/probes/fallback_band_count.py --maps OUT/*-asset/m.usda
    .venv/bin/python benchmarks/probes/fallback_band_count.py --count OUT/metal_flakes-128-asset_budget-3418164
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

#: name -> ("block", fraction) | ("files", fraction, blocks) | ("bands", rows, period)
PARTS = {"quarter block": ("block", 4), "half block": ("block", 2), "4 files (quarter)": ("files", 4, 4),
         "2 files (quarter)": ("files", 4, 2), "2 files (half)": ("files", 2, 2),
         "bands 8/32 (quarter)": ("bands", 8, 32), "bands 16/64 (quarter)": ("bands", 16, 64),
         "bands 32/64 (half)": ("bands", 32, 64), "bands 16/32 (half, shipped)": ("bands", 16, 32)}


def _encoded_bytes(pixels: np.ndarray) -> int:
    from usdbtf.imageio import encode_png_smallest

    return len(encode_png_smallest(np.ascontiguousarray(pixels), color_space="data", level=9))


def _part_bytes(pixels: np.ndarray, part: tuple) -> float:
    """Bytes of ``pixels`` (H, W, C) estimated from ``part`` of its rows."""
    h = pixels.shape[0]
    if part[0] == "block":
        n = h // part[1]
        start = (h - n) // 2
        return _encoded_bytes(pixels[start:start + n]) * part[1]
    if part[0] == "files":
        fraction, blocks = part[1], part[2]
        n = h // fraction // blocks
        return sum(_encoded_bytes(pixels[int(i * h / blocks):int(i * h / blocks) + n]) for i in range(blocks)) * fraction
    rows = np.flatnonzero(np.arange(h) % part[2] < part[1])
    return _encoded_bytes(pixels[rows]) * h / len(rows)


def maps(assets: list[str]) -> None:
    import OpenImageIO as oiio

    print("asset | maps' bytes | " + " | ".join(PARTS) + "  (estimate / bytes)")
    for asset in assets:
        files = sorted(Path(asset).parent.glob("*_textures/fallback/*.png"))
        total = sum(f.stat().st_size for f in files)
        est = dict.fromkeys(PARTS, 0.0)
        for f in files:
            buf = oiio.ImageBuf(str(f))
            pixels = buf.get_pixels(buf.spec().format)
            for name, part in PARTS.items():
                est[name] += _part_bytes(pixels, part)
        print(f"{Path(asset).parent.name} | {total:,} | " + " | ".join(f"{est[n] / total:.4f}" for n in PARTS),
              flush=True)


def count(folders: list[str]) -> None:
    from usdbtf.compress import read_compressed
    from usdbtf.usd.asset import package

    fit_bands = package.fit_bands          # the shipped count, put back after each "every texel" run
    for folder in folders:
        cbtf = read_compressed(folder)
        got = {}
        for label, bands in (("bands", fit_bands), ("every texel", lambda *args: None)):
            package.fit_bands = bands
            t, w = time.process_time(), time.perf_counter()
            full = package.asset_overhead(cbtf)["full"]
            got[label] = (full, time.process_time() - t, time.perf_counter() - w)
        package.fit_bands = fit_bands
        (b, bc, bw), (e, ec, ew) = got["bands"], got["every texel"]
        print(f"{Path(folder).name}: k {cbtf.k}, full lod counted {b:,} (bands) against {e:,} (every texel), "
              f"{b - e:+,} bytes; {bc:.1f} against {ec:.1f} CPU-s ({bw:.1f} / {ew:.1f} s wall)", flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps", nargs="+", default=[], help="packaged assets (root layers)")
    parser.add_argument("--count", nargs="+", default=[], help="compressed folders")
    args = parser.parse_args(argv)
    if args.maps:
        maps(args.maps)
    if args.count:
        count(args.count)
    return 0


if __name__ == "__main__":
    sys.exit(main())
