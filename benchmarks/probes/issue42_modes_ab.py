#!/usr/bin/env python
"""Before/after of a budget mode (issue 42), interleaved in one run: ``issue42_modes_steps.py``
run alternately on a BEFORE pipeline (a ``pipeline/`` folder of another commit, first on
PYTHONPATH: ``git archive <commit> pipeline plugin | tar -x -C DIR``) and on this worktree's,
``--rounds`` times each, then per version the median wall and CPU (process + children) of the
whole compress and of each step, and the peak RSS; the after/before ratios beside them.

    nice -n 10 .venv/bin/python benchmarks/probes/issue42_modes_ab.py BEFORE_DIR INPUT --rounds 2 -- --max-bytes 3418164
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py

import argparse
import os
import re
import statistics
import subprocess
import sys
from pathlib import Path

from common import format_machine, machine_info

STEPS = Path(__file__).with_name("issue42_modes_steps.py")
_TOTAL = re.compile(r"total: rc (\d+), wall ([\d.]+) s, CPU ([\d.]+) s in process \+ ([\d.]+) s in children; "
                    r"peak RSS (\d+) MB")
_ROW = re.compile(r"^(\S+)\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)(?:\s+\d+)?$")


def run_once(pipeline: str | None, inp: str, args: list) -> dict:
    env = dict(os.environ)
    if pipeline:
        env["PYTHONPATH"] = str(Path(pipeline) / "pipeline")
    out = subprocess.run([sys.executable, str(STEPS), inp, *args], env=env, capture_output=True, text=True)
    m = _TOTAL.search(out.stdout)
    if not m or m.group(1) != "0":
        raise SystemExit(f"run failed ({'before' if pipeline else 'after'}):\n{out.stdout[-2000:]}\n{out.stderr[-2000:]}")
    steps = {r.group(1): (float(r.group(3)), float(r.group(4)) + float(r.group(5)))
             for r in map(_ROW.match, out.stdout.splitlines()) if r}
    return {"wall": float(m.group(2)), "cpu": float(m.group(3)) + float(m.group(4)), "rss": int(m.group(5)),
            "steps": steps, "load": os.getloadavg()[0]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("before", help="folder holding the before version's pipeline/ (and plugin/)")
    ap.add_argument("input")
    ap.add_argument("--rounds", type=int, default=2)
    argv = sys.argv[1:] if argv is None else list(argv)
    cut = argv.index("--") if "--" in argv else len(argv)
    a = ap.parse_args(argv[:cut])
    args = argv[cut + 1:]                     # compress's options, after "--"
    print(format_machine(machine_info()))
    print(f"input {a.input}; compress {' '.join(args)}; before = {a.before}/pipeline, after = this worktree; "
          f"{a.rounds} round(s), interleaved (before, after)\n", flush=True)
    runs = {"before": [], "after": []}
    for i in range(a.rounds):
        for name, path in (("before", a.before), ("after", None)):
            r = run_once(path, a.input, args)
            runs[name].append(r)
            print(f"round {i + 1} {name:6s}: wall {r['wall']:.2f} s, CPU {r['cpu']:.2f} s, peak RSS {r['rss']} MB, "
                  f"load {r['load']:.2f}", flush=True)
    med = {n: {key: statistics.median(r[key] for r in rs) for key in ("wall", "cpu", "rss")} for n, rs in runs.items()}
    print(f"\n{'':24s} {'before':>10s} {'after':>10s} {'after/before':>12s}")
    for key, label in (("wall", "wall s (median)"), ("cpu", "CPU s (median)"), ("rss", "peak RSS MB (median)")):
        b, f = med["before"][key], med["after"][key]
        print(f"{label:24s} {b:10.2f} {f:10.2f} {f / b:12.3f}")
    print(f"\nper step, medians: wall s / CPU s (process + children)")
    names = list(runs["before"][0]["steps"])
    print(f"{'step':34s} {'before wall':>11s} {'before CPU':>10s} {'after wall':>10s} {'after CPU':>9s}")
    for s in names:
        cells = []
        for n in ("before", "after"):
            cells += [statistics.median(r["steps"].get(s, (0, 0))[j] for r in runs[n]) for j in (0, 1)]
        print(f"{s:34s} {cells[0]:11.2f} {cells[1]:10.2f} {cells[2]:10.2f} {cells[3]:9.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
