"""Issue 39 probe: compress's error estimate vs the exact error of what it wrote.

For each compressed folder given: the ``choice`` record (k, step, bytes, estimated percent)
and the exact paper metric, 100 sum|x - x'| / sum x over every sample and texel, on the input
files' 8-bit values ("encoded") and in scene-linear ACEScg ("linear"), of the folder's
reconstruction (``usdbtf.compress.decompress.compare``: the same encoder a file write uses).
With ``--ks`` the folder is also cut to those k (estimate of the cut is not recorded, only
the exact error).

    .venv/bin/python benchmarks/probes/issue39_target_error.py INPUT FOLDER [FOLDER ...] [--ks 10,20]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "pipeline"))


def main() -> None:
    from usdbtf.compress.decompress import compare
    from usdbtf.compress.format import read_compressed, reconstruct, truncate
    from usdbtf.io import open_btf

    ap = argparse.ArgumentParser()
    ap.add_argument("input")
    ap.add_argument("folders", nargs="+")
    ap.add_argument("--ks", default="")
    a = ap.parse_args()
    print(f"machine: {platform.node()} {platform.machine()} {os.cpu_count()} cpus, load {os.getloadavg()[0]:.2f}")
    orig = open_btf(a.input)
    print(f"input: {a.input} ({orig.width}x{orig.height}, {orig.n_samples} samples, {orig.bit_depth})")
    for folder in a.folders:
        cbtf = read_compressed(folder)
        meta = json.loads((Path(folder) / "btf-compressed.json").read_text())
        ch = meta.get("choice", {})
        est = meta.get("estimated_error", {})
        ks = [cbtf.k] + [int(x) for x in a.ks.split(",") if x and int(x) < cbtf.k]
        print(f"{folder}: domain {meta['domain']}, choice k {ch.get('k')} step {ch.get('step', 0):.4g} "
              f"bytes {ch.get('bytes')} (folder {ch.get('folder_bytes')}), attempts {ch.get('attempts')}, "
              f"target {ch.get('model', {}).get('target_percent')}")
        print(f"  estimate ({est.get('texels')} texels, {est.get('note')}): "
              f"enc {est.get('encoded', {}).get('percent', float('nan')):.4f} % "
              f"lin {est.get('linear', {}).get('percent', float('nan')):.4f} %")
        for k in ks:
            c = cbtf if k == cbtf.k else truncate(cbtf, k)
            r = compare(orig, lambda sel, c=c: reconstruct(c, sel))
            print(f"  exact all texels, k {k}: enc {r['encoded']['percent']:.4f} % lin {r['linear']['percent']:.4f} %")


if __name__ == "__main__":
    main()
