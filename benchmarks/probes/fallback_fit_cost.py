#!/usr/bin/env python
"""Issue 40/42: CPU seconds of the two fallback fits on one compressed BTF, and how many texels
the UsdPreviewSurface fit's specular-peak candidate (``svbrdf._peak_normals``) runs on.

Usage (repository root; compare trees with PYTHONPATH=<git archive>/pipeline)::

    .venv/bin/python benchmarks/probes/fallback_fit_cost.py COMPRESSED_FOLDER [--save A.npz] [--compare B.npz]

``--save`` writes every map of both fits to an npz; ``--compare`` checks this run's maps against
one so saved, bit for bit (a change meant to keep the bits, measured on two trees).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np


def main(argv=None) -> int:
    from usdbtf import openpbr, svbrdf
    from usdbtf.compress import read_compressed

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--save", help="write both fits' maps to this npz")
    parser.add_argument("--compare", help="check both fits' maps against this npz, bit for bit")
    args = parser.parse_args(argv)
    cbtf = read_compressed(args.folder)
    count = [0, 0]
    peak = getattr(svbrdf, "_peak_normals", None)
    if peak is not None:                 # an older tree has no peak candidate
        def counted(*args):
            out = peak(*args)
            normals = out[0] if isinstance(out, tuple) else out      # c61beea returned a 1-tuple
            count[0] += int(np.isfinite(normals[:, 0]).sum())
            count[1] += len(normals)
            return out
        svbrdf._peak_normals = counted
    t, w = time.process_time(), time.perf_counter()
    maps = svbrdf.fit_svbrdf(cbtf)
    ups, ups_wall = time.process_time() - t, time.perf_counter() - w
    t, w = time.process_time(), time.perf_counter()
    pbr = openpbr.fit_openpbr(cbtf, svbrdf=maps)
    op, op_wall = time.process_time() - t, time.perf_counter() - w
    print(f"{cbtf.width}x{cbtf.height} texels, k {cbtf.k}: UsdPreviewSurface fit {ups:.1f} CPU-s ({ups_wall:.1f} s), "
          f"OpenPBR fit {op:.1f} CPU-s ({op_wall:.1f} s); peak candidate on {count[0]} of "
          f"{count[1] or cbtf.width * cbtf.height} texels")
    arrays = {f"{prefix}_{f.name}": getattr(fit, f.name) for prefix, fit in (("ups", maps), ("openpbr", pbr))
              for f in dataclasses.fields(fit) if isinstance(getattr(fit, f.name), np.ndarray)}
    if args.save:
        np.savez(args.save, **arrays)
    if args.compare:
        with np.load(args.compare) as before:
            differ = sorted(name for name in set(before.files) | set(arrays)
                            if name not in arrays or name not in before.files
                            or not np.array_equal(before[name].view(np.uint8), arrays[name].view(np.uint8)))
        print(f"against {args.compare}: " + (f"{len(differ)} maps differ: {', '.join(differ)}" if differ
                                              else f"all {len(arrays)} maps bit-identical"))
        return 1 if differ else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
