"""The randomized fit of two trees, in one process, alternately: seconds and whether the bits agree.

Issue 27 (fourth session): ``linalg.randomized_basis`` forms only R in the last range's QR and
applies Q as Y (R^-1 Ub). This script times that function from this tree and from another one
(e.g. a ``git archive`` of the base) on the compress's two fit shapes. The inputs are synthetic:
a rank-60 signal plus noise whose level falls over the columns. It also reports whether U,
the singular values and the coefficients are bit-identical, and the largest difference in U.

Usage::

    git archive d6e0080 pipeline | tar -x -C /tmp/base
    PYTHONPATH=pipeline .venv/bin/python benchmarks/probes/bench_fit_qr.py /tmp/base/pipeline [--repeats 4]
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py and the benchmarks a probe reuses

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

from common import format_machine, machine_info, median
from usdbtf.compress.parallel import one_blas_thread

#: (samples, columns, vectors): paper scale, 2,048 fitting texels at --k 150 and 4,096 under a budget.
SHAPES = ((10800, 6144, 150), (10800, 12288, 500))


def _linalg_of(pipeline: Path, name: str):
    """linalg.py of the tree at ``pipeline``, imported as a module of this tree's package (its
    relative imports, .parallel, resolve to this tree's)."""
    spec = importlib.util.spec_from_file_location(f"usdbtf.compress.{name}", pipeline / "usdbtf/compress/linalg.py")
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "usdbtf.compress"
    spec.loader.exec_module(module)
    return module


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path, help="the other tree's pipeline folder")
    ap.add_argument("--repeats", type=int, default=4)
    args = ap.parse_args(argv)
    print("# randomized fit, this tree against", args.other)
    print(format_machine(machine_info()))
    trees = {"this": _linalg_of(Path(__file__).resolve().parents[1] / "pipeline", "linalg_this"),
             "other": _linalg_of(args.other, "linalg_other")}
    rng = np.random.default_rng(1)
    print("| samples x columns, vectors | this s (median) | other s (median) | U bit-identical | max abs U diff | sv, coefficients identical |")
    print("|---|---|---|---|---|---|")
    for S, m, k in SHAPES:
        x = (rng.standard_normal((S, 60), dtype=np.float32) @ rng.standard_normal((60, m), dtype=np.float32) * np.float32(3)
             + rng.standard_normal((S, m), dtype=np.float32) * np.logspace(0, -2, m, dtype=np.float32))
        seconds = {name: [] for name in trees}
        results = {}
        with one_blas_thread():          # as compress runs it
            for _ in range(args.repeats):
                for name, module in trees.items():
                    t = time.perf_counter()
                    results[name] = module.randomized_basis(x, k, return_coefficients=True)
                    seconds[name].append(time.perf_counter() - t)
        (ua, sa, ca), (ub, sb, cb) = results["this"], results["other"]
        print(f"| {S} x {m}, {k} | {median(seconds['this']):.3f} | {median(seconds['other']):.3f} | "
              f"{np.array_equal(ua, ub)} | {float(np.abs(ua - ub).max()):.2e} | "
              f"{np.array_equal(sa, sb) and np.array_equal(ca, cb)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
