"""Helpers shared by the benchmark scripts in this folder.

They live in the package (:mod:`usdbtf.bench.measure`, :mod:`usdbtf.bench.machine`), so that
``usdbtf bench`` and these scripts measure the same way; this module re-exports them for
``from common import ...`` in a script here (``python benchmarks/bench_x.py`` puts this
folder on ``sys.path``).  Definitions (wall time, peak RSS, tree PSS, MB/GB) are in
:mod:`usdbtf.bench.measure`.
"""
from __future__ import annotations

import sys
from pathlib import Path

from usdbtf.bench.machine import format_machine, machine_info
from usdbtf.compress.format import folder_bytes
from usdbtf.bench.measure import (REPO, RunResult, cli_command, default_out, fmt_bytes, median,
                                  run_measured, run_repeated, time_call, timestamp, warm_page_cache, write_json)

OUT = default_out()


def print_header(title: str) -> None:
    """Print a probe's report header: ``title``, the machine (:func:`format_machine`) and the
    command line it was run with."""
    print(title)
    print(format_machine(machine_info()))
    print(f"- command: {' '.join([Path(sys.executable).name, *sys.argv])}")


def dataset_arguments(parser, presets: str, *, size: int = 128, k: int = 64):
    """Add the synthetic-data options the fallback benchmarks share to ``parser`` (an
    ``argparse.ArgumentParser``): ``--presets`` (comma-separated, default ``presets``),
    ``--sampling`` (paper), ``--size`` (texels a side), ``--k`` (the compressed folder's
    components), ``--seed``.  Returns ``parser``."""
    parser.add_argument("--presets", default=presets)
    parser.add_argument("--sampling", default="paper")
    parser.add_argument("--size", type=int, default=size)
    parser.add_argument("--k", type=int, default=k)
    parser.add_argument("--seed", type=int, default=0)
    return parser


def print_table(columns: list[str], rows: list[str]) -> None:
    """Print a Markdown table after a blank line: the ``columns`` header, its rule, then
    ``rows`` (each already a ``| a | b |`` line, as the probes print them while they run)."""
    print("\n| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for row in rows:
        print(row)

__all__ = ["REPO", "OUT", "median", "time_call", "run_measured", "run_repeated", "RunResult", "machine_info",
           "format_machine", "warm_page_cache", "folder_bytes", "timestamp", "write_json", "fmt_bytes", "cli_command",
           "dataset_arguments", "print_header", "print_table"]
