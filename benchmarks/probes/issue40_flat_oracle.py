#!/usr/bin/env python
"""Issue 40: how much of a fallback's error is the mesostructure no per-texel BRDF can hold.

The synthetic presets (``usdbtf.synth``) shade every heightfield point with Lambert + GGX (+ a
Charlie sheen, + velvet's retro-reflection), and ray-march the heightfield for parallax,
masking and cast shadows.  Here each preset is synthesised twice, at the same seed, texture
and sampling: **as is**, and **flat** (the heightfield set to zero: the same albedo, specular,
roughness, sheen and shading normal map per texel, no parallax, masking or shadows, so every
texel's apparent BRDF is one local BRDF about its shading normal).  Both go through what
``benchmarks/bench_fallback.py`` measures (``usdbtf compress --k K --codec png``, the
UsdPreviewSurface and OpenPBR fits as shipped, error at every measured sample against the
synthetic originals, linear and encoded).

What it shows: on a flat variant, the fits meet their lobes (the error is the lobes' own
mismatch, e.g. sheen for the UsdPreviewSurface); the step from flat to as-is is what the
mesostructure adds to each fallback, and the OpenPBR/UPS ratio as is is bounded by how much
of the UPS error that step is.

Usage (repository root)::

    nice .venv/bin/python benchmarks/probes/issue40_flat_oracle.py [--presets satin_weave,metal_flakes,fuzzy_moss] \
        [--sampling paper] [--size 32] [--k 64]

Caches under benchmarks/out/probes/flat_oracle; prints a markdown table.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "benchmarks"))

from bench_fallback import errors, shipped_fallbacks  # noqa: E402
from common import OUT, cli_command, dataset_arguments, print_header  # noqa: E402


def synthesised(preset: str, sampling: str, size: int, seed: int, flat: bool) -> Path:
    """The folder of ``usdbtf synth PRESET`` (as is, or with its heightfield zeroed), cached."""
    from usdbtf.synth import SynthOptions, synth, write_synth

    folder = OUT / "probes" / "flat_oracle" / f"{preset}-{sampling}-{size}-seed{seed}-{'flat' if flat else 'asis'}"
    if not (folder / "btf.json").is_file():
        result = synth(preset, SynthOptions(sampling=sampling, size=size, seed=seed))
        if flat:
            material = dataclasses.replace(result.material, height=np.zeros_like(result.material.height))
            result = dataclasses.replace(result, material=material)
        folder.parent.mkdir(parents=True, exist_ok=True)
        write_synth(result, folder)
    return folder


def main(argv=None) -> int:
    ap = dataset_arguments(argparse.ArgumentParser(description=__doc__.split("\n\n")[0]),
                           "satin_weave,metal_flakes,fuzzy_moss,pebbles", size=32)
    args = ap.parse_args(argv)
    from usdbtf.bench.datasets import compressed
    from usdbtf.io import open_btf
    from usdbtf.photometry import white_level_of

    print_header("# issue 40: fallback error as is and on the flat (no mesostructure) variant")
    cli = cli_command()
    rows = []
    for preset in args.presets.split(","):
        cells = {}
        for flat in (False, True):
            data = synthesised(preset, args.sampling, args.size, args.seed, flat)
            cbtf = compressed(cli, data, data.with_name(data.name + f"-k{args.k}"), args.k)
            orig = open_btf(data)
            white = white_level_of(cbtf.info)
            shipped, _, _ = shipped_fallbacks(cbtf, white)
            res = errors(orig, cbtf, shipped)
            cells[flat] = {name: (res[name]["linear"]["percent"], res[name]["encoded"]["percent"])
                           for name in ("fitted", "openpbr", "reconstruction")}
            print(f"  {preset} {'flat' if flat else 'as is'}: " + "; ".join(
                f"{n} {v[0]:.2f} / {v[1]:.2f} %" for n, v in cells[flat].items()), flush=True)
        a, f = cells[False], cells[True]
        rows.append(f"| {preset} | {a['fitted'][0]:.2f} / {a['fitted'][1]:.2f} | {a['openpbr'][0]:.2f} / {a['openpbr'][1]:.2f} "
                    f"| {a['openpbr'][0] / a['fitted'][0]:.2f} / {a['openpbr'][1] / a['fitted'][1]:.2f} "
                    f"| {f['fitted'][0]:.2f} / {f['fitted'][1]:.2f} | {f['openpbr'][0]:.2f} / {f['openpbr'][1]:.2f} "
                    f"| {f['openpbr'][0] / f['fitted'][0]:.2f} / {f['openpbr'][1] / f['fitted'][1]:.2f} "
                    f"| {a['reconstruction'][0]:.2f} / {f['reconstruction'][0]:.2f} |")
    print("\n| preset | as is: UPS % lin / enc | OpenPBR | OpenPBR / UPS | flat: UPS | OpenPBR | OpenPBR / UPS | BTF k lin % as is / flat |")
    print("|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
