#!/usr/bin/env python
"""``compress --k 150`` against its floor, two code trees interleaved (issue 42).

Runs ``k150_time_budget.py --no-memo`` (each run measures its own floor -- a decode-only
pass and one 150-column float32 GEMM -- and then ``compress(k=150)`` in the same process)
alternately with ``PYTHONPATH=<old tree>/pipeline`` and this working tree, ``--rounds``
times, and prints per run and as medians: the floor's CPU, compress's CPU (with its decode
and encode workers), their ratio, compress's wall time, the projection tiles' conversion and
total thread CPU (peak RSS is not: the floor's GEMM operands dominate the probe process's;
measure it on the CLI).  On a loaded machine read the CPU ratio: floor and compress see the
same load within one run.

    .venv/bin/python benchmarks/probes/k150_ab.py OLD_COMMIT INPUT [--rounds 5]

The old commit's code is a ``git archive`` in a temporary folder (nothing in the repository
is touched), run by the same interpreter.
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from common import REPO, format_machine, machine_info, median, run_measured

PROBE = Path(__file__).resolve().parent / "k150_time_budget.py"
_FIELDS = {
    "floor": r"= ([\d.]+) s CPU\n",
    "compress": r"compress --k 150: ([\d.]+) s CPU",
    "ratio": r"([\d.]+)x the floor's CPU",
    "wall": r"in child processes: decode and encode workers\), ([\d.]+) s wall",
    "conversion": r"\| curve conversion \| ([\d.]+) \|",
    "tiles": r"\| all tiles \| ([\d.]+) \|",
}


def parse(text: str) -> dict:
    out = {}
    for name, pattern in _FIELDS.items():
        m = re.search(pattern, text)
        out[name] = float(m.group(1)) if m else float("nan")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("old")
    ap.add_argument("input")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args(argv)
    old = subprocess.run(["git", "rev-parse", "--short", args.old], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout.strip()
    new = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                         check=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=REPO, capture_output=True,
                           text=True).stdout.strip()
    print(format_machine(machine_info()))
    print(f"\nold: {old} (git archive); new: {new}{' + uncommitted changes' if dirty else ''} (working tree); "
          f"input {args.input}; {args.rounds} rounds, old first in each\n")
    rows = {"old": [], "new": []}
    with tempfile.TemporaryDirectory() as tree:
        archive = subprocess.run(["git", "archive", args.old], cwd=REPO, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", tree], input=archive, check=True)
        print("| round | tree | floor CPU s | compress CPU s | CPU ratio | compress wall s | tile conversion CPU s "
              "| all tiles CPU s | load |\n|---|---|---|---|---|---|---|---|---|")
        for r in range(1, args.rounds + 1):
            for side in ("old", "new"):
                env = dict(os.environ, PYTHONPATH=str(Path(tree) / "pipeline") if side == "old" else
                           str(REPO / "pipeline"))
                res = run_measured([sys.executable, str(PROBE), args.input, "--no-memo"], env=env, pss_interval=0)
                if res.returncode:
                    print(res.stdout[-2000:], res.stderr[-2000:])
                    return 1
                got = parse(res.stdout)
                rows[side].append(got)
                print(f"| {r} | {side} | {got['floor']:.2f} | {got['compress']:.2f} | {got['ratio']:.2f} | "
                      f"{got['wall']:.2f} | {got['conversion']:.2f} | {got['tiles']:.2f} | "
                      f"{os.getloadavg()[0]:.1f} |", flush=True)
    print("\nmedians:\n\n| tree | floor CPU s | compress CPU s | CPU ratio | compress wall s | tile conversion CPU s "
          "| all tiles CPU s |\n|---|---|---|---|---|---|---|")
    for side in ("old", "new"):
        m = {k: median([row[k] for row in rows[side]]) for k in rows[side][0]}
        print(f"| {side} | {m['floor']:.2f} | {m['compress']:.2f} | {m['ratio']:.2f} | {m['wall']:.2f} | "
              f"{m['conversion']:.2f} | {m['tiles']:.2f} |")
    pairs = [n["compress"] / o["compress"] for o, n in zip(rows["old"], rows["new"])]
    print(f"\ncompress CPU new / old, pair by pair: {', '.join(f'{p:.3f}' for p in pairs)}; median {median(pairs):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
