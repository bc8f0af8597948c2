#!/usr/bin/env python
"""Bytes per file kind of packaged assets (issue 39 codec slice): each argument an asset root layer
(``m.usda``); its ``<stem>_textures`` folder is counted by kind: gpu pages, gpu tables (full lod),
the basis page (schema 4, full lod), lower lods' tables and basis pages, fallback maps, thumbnail, MaterialX documents, layers.  Prints a markdown table
with the ratio of each asset to the first."""
import sys
from pathlib import Path


def kinds(root: Path) -> dict:
    lower = "lower lods' tables_k<n>.exr, basis_k<n>.png, usdbtf_k<n>.mtlx"
    out = {"gpu pages": 0, "gpu/tables.exr": 0, "gpu/basis.png": 0, lower: 0, "fallback maps": 0,
           "thumbnail": 0, "MaterialX": 0, "layers": 0}
    for f in root.parent.rglob("*"):
        if not f.is_file():
            continue
        n, size = f.name, f.stat().st_size
        key = ("gpu pages" if n.startswith("page") else "gpu/tables.exr" if n == "tables.exr"
               else "gpu/basis.png" if n == "basis.png" and f.parent.name == "gpu"
               else lower if n.startswith(("tables_k", "usdbtf_k", "basis_k")) else "fallback maps"
               if f.parent.name == "fallback" else "thumbnail" if n.startswith("thumbnail")
               else "MaterialX" if n.endswith(".mtlx") else "layers" if n.endswith((".usda", ".usdc")) else n)
        out[key] = out.get(key, 0) + size
    return out


roots = [Path(a) for a in sys.argv[1:]]
table = [kinds(r) for r in roots]
print("| kind | " + " | ".join(str(r) for r in roots) + " | ratio |")
print("|---|" + "---:|" * (len(roots) + 1))
for key in table[0]:
    ratio = table[-1].get(key, 0) / table[0][key] if table[0][key] else float("nan")
    print(f"| {key} | " + " | ".join(f"{t.get(key, 0):,}" for t in table) + f" | {ratio:.3f} |")
full = [sum(v for k, v in t.items() if not k.startswith("lower")) for t in table]
print("| full lod (all but the lower lods' own files) | " + " | ".join(f"{t:,}" for t in full)
      + f" | {full[-1] / full[0]:.3f} |")
tot = [sum(t.values()) for t in table]
print("| all files | " + " | ".join(f"{t:,}" for t in tot) + f" | {tot[-1] / tot[0]:.3f} |")
