#!/usr/bin/env python
"""Issues 39 and 43: what fallback maps at half the BTF's resolution would free, and cost.

The packaged asset's fallback maps (UsdPreviewSurface and OpenPBR, 11 files) are lossless PNGs
at the BTF's texel resolution: 0.04-0.08 of the paper's bytes at paper scale, all of them inside
``--max-bytes``.  This probe measures, per preset, the one storage a studio could choose instead
without a lossy codec: every map box-filtered to half its width and height (2 x 2 texels, on the
stored codes), as a renderer then magnifies it 2x (bilinear, wrapping: the swatch tiles).

For each preset (the bench's own data and ``compress --k K --codec png`` folder, as
``bench_fallback.py`` makes them):

- the maps' bytes as shipped and at half resolution (``encode_png_smallest``, level 9: the
  shipped encoder);
- both fallbacks' error against the measured samples (paper's metric, scene-linear and on the
  8-bit file values), read back from the shipped maps and from the half-resolution maps.

Usage (repository root)::

    .venv/bin/python benchmarks/probes/fallback_half_res.py --presets metal_flakes,satin_weave
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform)
import numpy as np  # noqa: E402

from bench_fallback import PRESETS, errors  # noqa: E402
from common import OUT, cli_command, dataset_arguments, print_header, print_table  # noqa: E402


def half_then_magnified(pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the (H/2, W/2, C) codes of ``pixels`` box-filtered 2 x 2 and rounded, the (H, W, C)
    float codes a bilinear 2x magnification of them reads at the texel centres, wrapping)."""
    dtype = pixels.dtype
    h, w = pixels.shape[:2]
    half = np.rint(pixels.reshape(h // 2, 2, w // 2, 2, -1).astype(np.float64).mean(axis=(1, 3))).astype(dtype)

    def up(a: np.ndarray, axis: int) -> np.ndarray:
        # Texel 2j sits at j - 1/4 in the half grid, 2j + 1 at j + 1/4.
        even = 0.75 * a + 0.25 * np.roll(a, 1, axis=axis)
        odd = 0.75 * a + 0.25 * np.roll(a, -1, axis=axis)
        return np.stack([even, odd], axis=axis + 1).reshape(
            *a.shape[:axis], 2 * a.shape[axis], *a.shape[axis + 1:])

    return half, up(up(half.astype(np.float64), 0), 1).astype(np.float32)


def main(argv=None) -> int:
    args = dataset_arguments(argparse.ArgumentParser(description=__doc__.split("\n\n")[0]), ",".join(PRESETS)
                             ).parse_args(argv)

    from usdbtf.bench.datasets import compressed, ensure_dataset
    from usdbtf.imageio import encode_png_smallest
    from usdbtf.io import open_btf
    from usdbtf.photometry import white_level_of
    from usdbtf.usd.asset import fallback as ups, openpbr as op
    from usdbtf.usd.asset.fallback_count import fit_fallbacks

    print_header("# fallback maps at half resolution: bytes freed, error added")
    cli = cli_command()
    rows = []
    for preset in args.presets.split(","):
        data = ensure_dataset(OUT / "data", preset, args.sampling, args.size, args.seed, say=print)
        folder = OUT / "fallback" / f"{preset}-{args.sampling}-{args.size}-seed{args.seed}-k{args.k}"
        cbtf = compressed(cli, Path(data["folder"]), folder, args.k)
        white = white_level_of(cbtf.info)
        fitted, fitted_op, _ = fit_fallbacks(cbtf, white)          # the fits every asset ships
        shipped, full_bytes, half_bytes = {}, 0, 0
        for name, module, maps in (("UsdPreviewSurface", ups, fitted), ("OpenPBR", op, fitted_op)):
            pixels = module.encode_maps(maps, cbtf.ocio_config)
            magnified = {}
            for key, px in pixels.items():
                full_bytes += len(encode_png_smallest(np.ascontiguousarray(px), color_space="data", level=9))
                half, magnified[key] = half_then_magnified(px)
                half_bytes += len(encode_png_smallest(np.ascontiguousarray(half), color_space="data", level=9))
            decode = lambda p: module.decode_maps(p, cbtf.working_space, ocio_config=cbtf.ocio_config,  # noqa: E731
                                                  white_level=white)
            shipped[name] = decode(pixels)
            shipped[f"{name}, half"] = decode(magnified)
        res = errors(open_btf(data["folder"]), cbtf, shipped)
        pct = {name: (r["linear"]["percent"], r["encoded"]["percent"]) for name, r in res.items()}
        row = f"| {preset} | {full_bytes:,} | {half_bytes:,} ({half_bytes / full_bytes:.3f}) |"
        for name in ("UsdPreviewSurface", "OpenPBR"):
            (fl, fe), (hl, he) = pct[name], pct[f"{name}, half"]
            row += f" {fl:.2f} -> {hl:.2f} ({hl / fl - 1:+.1%}) | {fe:.2f} -> {he:.2f} ({he / fe - 1:+.1%}) |"
        print(row, flush=True)
        rows.append(row)
    print_table(["preset", "maps' bytes", "at half resolution", "UPS % lin", "UPS % enc", "OpenPBR % lin",
                 "OpenPBR % enc"], rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
