#!/usr/bin/env python
"""The fallback fits before/after (issue 42), interleaved in one run: UsdPreviewSurface then
OpenPBR (as ``package`` and rate control's first packaging run them) on a compressed folder,
each in a fresh process on a BEFORE pipeline (a ``pipeline/`` folder of another commit, first
on PYTHONPATH) and on this worktree's, ``--rounds`` times; per version the median wall and
CPU seconds of the two fits, and whether both versions' maps are the same bits.

    nice -n 10 .venv/bin/python benchmarks/probes/issue42_fits_ab.py BEFORE_DIR COMPRESSED_FOLDER --rounds 2
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys

_CHILD = r"""
import dataclasses, hashlib, json, sys, time
import usdbtf
import numpy as np
from usdbtf import openpbr, svbrdf
from usdbtf.compress.format import read_compressed
from usdbtf.photometry import white_level_of
cbtf = read_compressed(sys.argv[1])
white = white_level_of(cbtf.info, "white_level")
t, c = time.perf_counter(), time.process_time()
pre = svbrdf.fit_svbrdf(cbtf, white_level=white)
t1, c1 = time.perf_counter(), time.process_time()
op = openpbr.fit_openpbr(cbtf, svbrdf=pre, white_level=white)
t2, c2 = time.perf_counter(), time.process_time()
h = hashlib.sha256()
for m in (pre, op):
    for f in dataclasses.fields(m):
        a = getattr(m, f.name)
        if isinstance(a, np.ndarray):
            h.update(f.name.encode()); h.update(a.tobytes())
print(json.dumps({"wall": [t1 - t, t2 - t1], "cpu": [c1 - c, c2 - c1], "sha": h.hexdigest(), "src": usdbtf.__file__}))
"""


def main(argv=None) -> int:
    from common import format_machine, machine_info

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("before")
    ap.add_argument("folder")
    ap.add_argument("--rounds", type=int, default=2)
    a = ap.parse_args(argv)
    print(format_machine(machine_info()))
    print(f"input {a.folder}; before = {a.before}/pipeline, after = this worktree; {a.rounds} round(s), "
          f"interleaved\n", flush=True)
    runs = {"before": [], "after": []}
    for i in range(a.rounds):
        for name in ("before", "after"):
            env = dict(os.environ)
            env.pop("PYTHONPATH", None)
            if name == "before":
                env["PYTHONPATH"] = str(_Path(a.before) / "pipeline")
            out = subprocess.run([sys.executable, "-c", _CHILD, a.folder], env=env, capture_output=True, text=True)
            if out.returncode:
                raise SystemExit(out.stderr[-3000:])
            r = json.loads(out.stdout.strip().splitlines()[-1])
            runs[name].append(r)
            print(f"round {i + 1} {name:6s}: UsdPreviewSurface {r['wall'][0]:.2f} s wall / {r['cpu'][0]:.2f} s CPU, "
                  f"OpenPBR {r['wall'][1]:.2f} / {r['cpu'][1]:.2f}; load {os.getloadavg()[0]:.2f}; maps {r['sha'][:12]}",
                  flush=True)
    print(f"\n{'medians':10s} {'UPS wall':>9s} {'UPS CPU':>8s} {'OpenPBR wall':>12s} {'OpenPBR CPU':>11s} {'both CPU':>9s}")
    med = {}
    for name, rs in runs.items():
        cells = [statistics.median(r[key][j] for r in rs) for j in (0, 1) for key in ("wall", "cpu")]
        med[name] = cells[1] + cells[3]
        print(f"{name:10s} {cells[0]:9.2f} {cells[1]:8.2f} {cells[2]:12.2f} {cells[3]:11.2f} {med[name]:9.2f}")
    print(f"CPU after / before: {med['after'] / med['before']:.3f}")
    shas = {r["sha"] for rs in runs.values() for r in rs}
    print(f"maps the same bits in every run and version: {len(shas) == 1}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
