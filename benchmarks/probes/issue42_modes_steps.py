#!/usr/bin/env python
"""Where ``usdbtf compress --max-bytes`` / ``--target-error`` (asset budget, the CLI's default)
spend their time (issue 42, the budget modes), in one process.

Runs ``usdbtf compress INPUT -o <temporary folder> ARGS...`` through the CLI in process, with
the steps compress calls (the load, the domain choice and basis fit, the projection, rate
control and inside it the packagings that measure what the asset adds, the fallback fits, the
shipped-bytes probes, the final encode, the evaluations) wrapped by timers.  Prints per step:
calls, wall seconds, CPU seconds of this process (all threads) and of reaped child processes
(decode and encode workers), and the process's peak RSS so far at the step's exit; nested
steps' time is also in their caller's.  Then the totals and
the peak RSS.  The output folder is removed.

    nice -n 10 .venv/bin/python benchmarks/probes/issue42_modes_steps.py INPUT --max-bytes 3418164
    nice -n 10 .venv/bin/python benchmarks/probes/issue42_modes_steps.py INPUT --target-error 11.396
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py

import collections
import functools
import importlib
import os
import resource
import sys
import tempfile
import time

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform, usdbtf.numeric)

from common import format_machine, machine_info

#: (module, function) wrapped; the order is the order printed.
STEPS = [("usdbtf.compress.core", "load_source"), ("usdbtf.compress.core", "choose_domain"),
         ("usdbtf.compress.core", "fit_source"), ("usdbtf.compress.core", "held_out_set"),
         ("usdbtf.compress.core", "sampled_coefficients"), ("usdbtf.compress.core", "step_for_k"),
         ("usdbtf.compress.core", "project"), ("usdbtf.compress.core", "rate_control"),
         ("usdbtf.compress.ratedist", "rd_table"),
         ("usdbtf.compress.ratecontrol", "_pack_factor"), ("usdbtf.compress.ratecontrol", "_shipped_basis_factor"),
         ("usdbtf.compress.ratecontrol", "_packaged"), ("usdbtf.svbrdf", "fit_svbrdf"),
         ("usdbtf.openpbr", "fit_openpbr"), ("usdbtf.compress.ratecontrol", "_asset_fit_planned"),
         ("usdbtf.compress.ratecontrol", "_asset_fit"), ("usdbtf.compress.ratecontrol", "quantise"),
         ("usdbtf.compress.ratecontrol", "held_out_error"), ("usdbtf.compress.ratecontrol", "encode"),
         ("usdbtf.compress.core", "held_out_errors"), ("usdbtf.compress.core", "error_curve"),
         ("usdbtf.compress.core", "write_compress")]


def _kids() -> float:
    k = resource.getrusage(resource.RUSAGE_CHILDREN)
    return k.ru_utime + k.ru_stime


def _peak_mb() -> float:
    """This process's peak RSS so far (MiB): per step, at its last exit (the step that first
    shows the run's peak is where it happened)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    inp, args = argv[0], argv[1:]
    calls, wall, cpu, kids, peak = (collections.Counter() for _ in range(5))

    def wrap(module, name):
        fn = getattr(module, name)

        @functools.wraps(fn)
        def wrapper(*a, **kw):
            t, c, k = time.perf_counter(), time.process_time(), _kids()
            try:
                return fn(*a, **kw)
            finally:
                key = f"{module.__name__.split('.')[-1]}.{name}"
                calls[key] += 1
                wall[key] += time.perf_counter() - t
                cpu[key] += time.process_time() - c
                kids[key] += _kids() - k
                peak[key] = max(peak[key], _peak_mb())

        setattr(module, name, wrapper)

    for mod, name in STEPS:
        wrap(importlib.import_module(mod), name)
    # package.py imports the fits inside its functions (from the modules: patched above); the
    # commands module imports compress/write_compress at call time from usdbtf.compress.
    import usdbtf.compress as uc
    from usdbtf.compress import core
    uc.write_compress = core.write_compress
    from usdbtf.cli import main as cli

    print(format_machine(machine_info()))
    print(f"input {inp}; args {' '.join(args)}; load {os.getloadavg()[0]:.2f}", flush=True)
    with tempfile.TemporaryDirectory(prefix="issue42-steps-") as tmp:
        t, c = time.perf_counter(), time.process_time()
        rc = cli(["compress", inp, "-o", str(_Path(tmp) / "out"), "--quiet", *args])
        total_wall, total_cpu = time.perf_counter() - t, time.process_time() - c
    print(f"{'step':34s} {'calls':>5s} {'wall s':>8s} {'CPU s':>8s} {'child CPU s':>11s} {'peak MB':>8s}")
    for key in wall:
        print(f"{key:34s} {calls[key]:5d} {wall[key]:8.2f} {cpu[key]:8.2f} {kids[key]:11.2f} {peak[key]:8.0f}")
    peak = _peak_mb()
    print(f"total: rc {rc}, wall {total_wall:.2f} s, CPU {total_cpu:.2f} s in process + {_kids():.2f} s in children; "
          f"peak RSS {peak:.0f} MB; load {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
