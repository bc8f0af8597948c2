#!/usr/bin/env python
"""Issue 40: the fallback fit on metal_flakes' flakes against the synthetic material's own truth.

For a compressed metal_flakes BTF (``usdbtf synth metal_flakes --size N --seed S`` compressed, e.g.
by ``benchmarks/probes/issue40_flat_oracle.py``), fits the UsdPreviewSurface fallback
(``svbrdf.fit_svbrdf``) and compares it with ``synth.make_material``'s per-texel truth: the
flakes' shading normals (from the material's slopes: n = (-dh/dx, -dh/dy, 1), x = image right,
y = image up) and roughness (sqrt of the generator's GGX alpha), and splits the fallback's
error over every measured sample (linear, against the BTF's own samples) between flake texels
(F0 > 0.5) and the base coat.  ``--oracle`` also fits with the generator's normals given to the
flakes as the peak candidate (what the fit reaches with exact normals).

Usage (repository root)::

    .venv/bin/python benchmarks/probes/flake_normals.py COMPRESSED_FOLDER SOURCE_FOLDER [--seed 0] [--oracle]
"""
from __future__ import annotations

import argparse
import sys

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("compressed")
    ap.add_argument("source")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--oracle", action="store_true")
    args = ap.parse_args(argv)
    from usdbtf import svbrdf
    from usdbtf.compress import read_compressed
    from usdbtf.io import open_btf
    from usdbtf.synth import make_material

    cbtf, orig = read_compressed(args.compressed), open_btf(args.source)
    n = cbtf.width
    material = make_material("metal_flakes", n, args.seed)
    flake = material.specular > 0.5
    truth = np.dstack([-material.slope[..., 0], -material.slope[..., 1], np.ones((n, n))])
    truth /= np.linalg.norm(truth, axis=-1, keepdims=True)
    runs = [("as fitted", None)]
    if args.oracle:
        runs.append(("generator's normals on the flakes", truth))
    for label, given in runs:
        patched = svbrdf._peak_normals
        if given is not None:
            flat_truth, flat_flake, pos = given.reshape(-1, 3), flake.ravel(), [0]

            def oracle(y, luma, h):
                t = y.shape[2]
                a = pos[0]
                pos[0] += t
                out = np.full((t, 3), np.nan, np.float32)
                out[flat_flake[a:a + t]] = flat_truth[a:a + t][flat_flake[a:a + t]]
                return out

            svbrdf._peak_normals = oracle
        try:
            maps = svbrdf.fit_svbrdf(cbtf)
        finally:
            svbrdf._peak_normals = patched
        off = np.degrees(np.arccos(np.clip((maps.normal * truth).sum(axis=-1), -1.0, 1.0)))
        err, total = np.zeros((n, n)), np.zeros((n, n))
        for a in range(0, orig.n_samples, 512):
            idx = np.arange(a, min(a + 512, orig.n_samples))
            measured = orig.decode(orig.read_encoded(idx))
            pred = svbrdf.evaluate(maps, cbtf.sampling.view[idx], cbtf.sampling.light[idx]).reshape(len(idx), n, n, 3)
            err += np.abs(measured - pred).sum(axis=(0, 3))
            total += measured.sum(axis=(0, 3))
        print(f"{label}: {int(flake.sum())} flake texels; normals off {np.median(off[flake]):.2f} deg (median), "
              f"roughness {np.median(maps.roughness[flake]):.2f} (generator {np.median(np.sqrt(material.roughness[flake])):.2f}); "
              f"flakes hold {err[flake].sum() / err.sum():.2f} of the error and {total[flake].sum() / total.sum():.2f} of "
              f"the signal; error on flakes {100 * err[flake].sum() / total[flake].sum():.1f} %, base coat "
              f"{100 * err[~flake].sum() / total[~flake].sum():.1f} %, all {100 * err.sum() / total.sum():.2f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
