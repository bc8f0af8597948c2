#!/usr/bin/env python
"""The benchmark suite, ``usdbtf bench``, as a script of this folder (same options).

    .venv/bin/python benchmarks/bench_suite.py --quick        # = .venv/bin/usdbtf bench --quick

See ``benchmarks/README.md`` and :mod:`usdbtf.bench`.
"""
import sys

from usdbtf.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
