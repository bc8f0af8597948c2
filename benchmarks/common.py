"""Helpers shared by the benchmark scripts in this folder.

They live in the package (:mod:`usdbtf.bench.measure`, :mod:`usdbtf.bench.machine`), so that
``usdbtf bench`` and these scripts measure the same way; this module re-exports them for
``from common import ...`` in a script here (``python benchmarks/bench_x.py`` puts this
folder on ``sys.path``).  Definitions (wall time, peak RSS, tree PSS, MB/GB) are in
:mod:`usdbtf.bench.measure`.
"""
from __future__ import annotations

from usdbtf.bench.machine import format_machine, machine_info
from usdbtf.compress.format import folder_bytes
from usdbtf.bench.measure import (REPO, RunResult, cli_command, default_out, fmt_bytes, median,
                                  run_measured, run_repeated, time_call, timestamp, warm_page_cache, write_json)

OUT = default_out()

__all__ = ["REPO", "OUT", "median", "time_call", "run_measured", "run_repeated", "RunResult", "machine_info",
           "format_machine", "warm_page_cache", "folder_bytes", "timestamp", "write_json", "fmt_bytes", "cli_command"]
