"""Lod bytes vs share: an asset packaged by the base commit and by this branch from one folder."""
import json, sys, platform, os
from pathlib import Path
from usdbtf.usd.asset.inspect import lod_files
from usdbtf.usd.asset.package import budget_of
from usdbtf.usd.read import find_material, open_stage
from usdbtf.compress import read_compressed

folder, *assets = sys.argv[1:]
B = budget_of(read_compressed(folder))
print(f"folder {folder}: k {read_compressed(folder).k}, budget B = {B:,}; machine {platform.node()} "
      f"({os.cpu_count()} CPUs, shared)")
print()
print("| asset | lod | k | files | bytes loaded | share of B | loaded / share | loaded / B |")
print("|---|---|---|---|---|---|---|---|")
for a in assets:
    stage = open_stage(a)
    for lv in lod_files(stage, find_material(stage), B):
        print(f"| {a.split('/')[-2]} | {lv['name']} | {lv['k']} | {len(lv['files'])} | {lv['total']:,} | "
              f"{lv['share']:,} | {lv['total'] / lv['share']:.3f} | {lv['total'] / B:.3f} |")
