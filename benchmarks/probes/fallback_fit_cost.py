#!/usr/bin/env python
"""Issue 40/42: CPU seconds of the two fallback fits on one compressed BTF, and how many texels
the UsdPreviewSurface fit's specular-peak candidate (``svbrdf._peak_normals``) runs on.

Usage (repository root; compare trees with PYTHONPATH=<git archive>/pipeline)::

    .venv/bin/python benchmarks/probes/fallback_fit_cost.py COMPRESSED_FOLDER
"""
from __future__ import annotations

import sys
import time

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np


def main(argv=None) -> int:
    from usdbtf import openpbr, svbrdf
    from usdbtf.compress import read_compressed

    cbtf = read_compressed((argv or sys.argv[1:])[0])
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
    t = time.process_time()
    maps = svbrdf.fit_svbrdf(cbtf)
    ups = time.process_time() - t
    t = time.process_time()
    openpbr.fit_openpbr(cbtf, svbrdf=maps)
    op = time.process_time() - t
    print(f"{cbtf.width}x{cbtf.height} texels, k {cbtf.k}: UsdPreviewSurface fit {ups:.1f} CPU-s, OpenPBR fit {op:.1f} "
          f"CPU-s; peak candidate on {count[0]} of {count[1] or cbtf.width * cbtf.height} texels")
    return 0


if __name__ == "__main__":
    sys.exit(main())
