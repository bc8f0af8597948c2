#!/usr/bin/env python
"""Issue 16 in the product: ``usdbtf compress`` (default options) against the paper's method at
the paper's bytes, on the encoded values and in scene-linear, every preset.

Per preset (tuning presets first, then the held-out presets no tuning run used):

1. the paper's method as the paper ran it, on the 8-bit values (``research/methods.paper_method``,
   cached per dataset under ``benchmarks/out/research/paper``): its stored bytes are the budget;
2. ``usdbtf compress IN -o OUT --max-bytes <budget>`` with every other option at its default
   (``--domain auto``: the working-domain curve chosen per material; since issue 39 the budget
   counts the packaged asset's full lod, ``--budget-for asset``), as a subprocess, timed; and the
   same with ``--budget-for folder`` (the compressed folder's textures: the figures before
   issue 39); each folder then packaged (``usdbtf package``), its bytes the files the full lod
   loads (package's summary) and its error computed from the asset's own files
   (``usdbtf.usd.read.load_btf``), beside the folder's bytes and error;
3. with ``--target-error``: ``usdbtf compress IN -o OUT --target-error <the paper's % on the
   8-bit values>`` (the other side of the comparison: at the paper's error, the asset's bytes
   as a fraction of the paper's), packaged and measured as in 2;
4. optionally ``--domain linear`` (the default before issue 16) and ``--solver paper`` (the
   product's paper solver, k = 150, on the input's encoding curve) under no budget;

percent error over every sample (``--stride`` subsamples), texel and channel, on the 8-bit
sRGB file values (exact encoder) and in scene-linear ACEScg (``research/rlib.evaluate``).
With ``--heldout-directions``, 10 % of the light directions (every view) are removed, the
product compresses the rest under the paper's budget for that subset, and the held-out images
are predicted the way the renderer does (4 nearest stored directions, rows blended in the
working domain, the inverse curve, the foreshortening after it).  An asset's "basis" bytes are
the basis codes its full lod loads: ``gpu/basis.png`` (schema 4), else the tables' basis
block (``packs.shipped_basis_bytes``); they are part of its bytes.  Usage::

    .venv/bin/python benchmarks/bench_issue16.py [--presets a,b] [--stride 1] [--linear] [--paper-solver]
        [--heldout-directions] [--size 128] [--target-error] [--no-folder-budget]

The issue-39 table (at the paper's bytes and at the paper's error, asset and folder, one run)::

    .venv/bin/python benchmarks/bench_issue16.py --target-error
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "research"))

from rlib import (DATA, OUT, REPO, Timer, evaluate, header, load, paper_budget_inputs, preset_list, say,  # noqa: E402
                  stride_rows)
from methods import direction_split, heldout_errors, paper_cached, paper_method  # noqa: E402

PRODUCT = OUT.parent / "issue16"


class Product:
    """A ``usdbtf compress`` folder as the research evaluation reads it: ``recon_rows(rows)``
    -> linear Rec.709 images, through the folder's working-domain inverse curve (in ACEScg)."""

    def __init__(self, folder, data, bytes_=None):
        """folder: a compressed folder, or a CompressedBTF (an asset's, ``load_btf``) whose
        ``bytes_`` ({"payload", "basis"}) are given."""
        from usdbtf.compress import read_compressed
        from usdbtf.compress.format import working_coefficients

        self.cbtf = read_compressed(folder) if isinstance(folder, Path) else folder
        c = self.cbtf
        self.basis = c.basis_values()
        self.coeff = working_coefficients(c).reshape(c.k, -1)
        self.to_709 = np.linalg.inv(data.to_aces.astype(np.float64)).astype(np.float32)
        self.bytes = dict(c.info["bytes"]) if bytes_ is None else dict(bytes_)
        self.dom = type("NoGamma", (), {"gamma": None, "name": c.domain.name})()   # gain after the curve
        self.k = c.k

    def recon_rows(self, rows: np.ndarray, gain=None) -> np.ndarray:
        from usdbtf.color import mix_rgb

        lin = self.cbtf.domain.inverse(rows.astype(np.float32) @ self.coeff)
        if gain is not None:
            lin *= np.asarray(gain, np.float32)[:, None]
        return mix_rgb(lin.reshape(len(rows), -1, 3), self.to_709)

    def recon(self, sel) -> np.ndarray:
        return self.recon_rows(self.basis[sel])


def compress_cli(folder: Path, out: Path, *args) -> float:
    """``usdbtf compress folder -o out ARGS`` (reused when out exists); returns wall seconds."""
    if (out / "btf-compressed.json").is_file():
        return float(json.loads((out.parent / f"{out.name}.seconds").read_text()))
    t = time.perf_counter()
    subprocess.run([str(REPO / ".venv/bin/usdbtf"), "compress", str(folder), "-o", str(out), *map(str, args), "-q"],
                   check=True)
    secs = time.perf_counter() - t
    (out.parent / f"{out.name}.seconds").write_text(f"{secs:.1f}")
    return secs


def package_cli(folder: Path) -> tuple[dict, Path]:
    """``usdbtf package folder`` (a 5 cm swatch, reused when written): (its --json summary, the root layer)."""
    root = folder.parent / f"{folder.name}-asset" / "m.usda"
    record = root.parent.parent / f"{folder.name}-asset.json"
    if not record.is_file() or not root.is_file():
        t = time.perf_counter()
        out = subprocess.run([str(REPO / ".venv/bin/usdbtf"), "package", str(folder), "-o", str(root), "--force",
                              "--physical-size", "0.05", "0.05", "--json", "-q"], check=True, capture_output=True,
                             text=True).stdout
        summary = json.loads(out)
        summary["seconds"] = time.perf_counter() - t
        record.write_text(json.dumps(summary, default=str))
    return json.loads(record.read_text()), root


def asset_basis_bytes(root: Path, cbtf) -> int:
    """Bytes of the basis codes the full lod of the asset ``root`` loads: its basis page
    (``gpu/basis.png``, schema 4) when it has one, else the basis block of its GPU tables
    (``packs.shipped_basis_bytes`` of ``cbtf``, the asset's own codes)."""
    from usdbtf.compress.packs import shipped_basis_bytes
    from usdbtf.usd.asset.package import shipped_levels

    full = shipped_levels(root, shares=False)[0]
    pages = [f["bytes"] for f in full["files"] if f["path"].replace("\\", "/").endswith("gpu/basis.png")]
    return int(pages[0]) if pages else int(shipped_basis_bytes(cbtf))


def asset_product(folder: Path, data) -> tuple["Product", dict]:
    """The packaged asset of ``folder`` as the evaluation reads it: its codes from the asset's
    own files (``load_btf``), its bytes the files its full lod loads, of which "basis" the
    basis codes (:func:`asset_basis_bytes`)."""
    from usdbtf.usd.read import load_btf

    summary, root = package_cli(folder)
    full = int(summary["bytes"]["full"])
    cbtf = load_btf(root)
    return Product(cbtf, data, {"payload": full, "basis": asset_basis_bytes(root, cbtf)}), summary


def directions(data, stride: int) -> dict:
    """Held-out-direction errors of the paper and the product default (module docstring)."""
    split = direction_split(data)
    paper = paper_method(split.sub)
    budget = paper.bytes["payload"]
    out_dir = PRODUCT / f"{data.name}-fit90-auto-{budget}"
    # The subset manifest lists the dataset's images by relative path outside its own folder.
    compress_cli(split.manifest(), out_dir, "--max-bytes", budget, "--allow-outside-paths")
    return heldout_errors(data, split, split.held[::stride], {"paper": paper, "product": Product(out_dir, split.sub)})


def main(argv=None) -> int:
    from usdbtf.bench.datasets import HELDOUT_PRESETS, TUNING_PRESETS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--presets", default=",".join(TUNING_PRESETS + HELDOUT_PRESETS))
    p.add_argument("--stride", type=int, default=1)
    p.add_argument("--linear", action="store_true", help="also --domain linear (the default before issue 16)")
    p.add_argument("--paper-solver", action="store_true", help="also --solver paper (no budget)")
    p.add_argument("--heldout-directions", action="store_true")
    p.add_argument("--size", type=int, default=128, help="texels per side of the synthetic data (paper: 128)")
    p.add_argument("--no-folder-budget", action="store_true",
                   help="skip the --budget-for folder run (the compressed-folder figures before issue 39)")
    p.add_argument("--target-error", action="store_true",
                   help="also compress --target-error <the paper's %% enc> and package it: the asset's bytes at the "
                        "paper's error, as a fraction of the paper's bytes")
    args = p.parse_args(argv)
    presets = preset_list(args.presets, tuning_only=False)
    header("issue 16 in the product: usdbtf compress (defaults) vs the paper's method at the paper's bytes",
           [line.replace("128x128", f"{args.size}x{args.size}") for line in paper_budget_inputs(presets, args.stride)])
    PRODUCT.mkdir(parents=True, exist_ok=True)
    results = {}
    for preset in presets:
        say(f"## {preset}{' (held out)' if preset in HELDOUT_PRESETS else ''}")
        data = load(preset, size=args.size)
        folder = DATA / f"{preset}-paper-{data.size}-seed0"
        sel = stride_rows(data, args.stride)
        r = results[preset] = {}
        paper = paper_cached(data)
        budget = paper.bytes["payload"]
        runs = [("paper", paper, None)]
        # The paper's errors (this run's samples), once: the table's baseline and --target-error's target.
        measured = {"paper": evaluate(data, paper.recon, sel)}
        variants = [("default", ["--max-bytes", budget])]
        if not args.no_folder_budget:
            variants.append(("folder budget", ["--max-bytes", budget, "--budget-for", "folder"]))
        if args.target_error:
            # The paper's error on the 8-bit values (compress's --target-error is on the encoded
            # values by default, measured on its held-out texels).
            target = float(measured["paper"].encoded)
            r["paper target % enc"] = target
            variants.append(("target error", ["--target-error", f"{target:.4f}"]))
        if args.linear:
            variants.append(("linear", ["--max-bytes", budget, "--domain", "linear"]))
        if args.paper_solver:
            variants.append(("paper solver", ["--solver", "paper"]))
        for name, extra in variants:
            # "default" budgets the asset since issue 39: a folder of its own (not an older run's)
            tag = "asset_budget" if name == "default" else name.replace(' ', '_')
            out = PRODUCT / (f"{preset}-{args.size}-{tag}-{budget}" if name != "target error"
                             else f"{preset}-{args.size}-target_error-{extra[1]}")
            secs = compress_cli(folder, out, *extra)
            runs.append((name, Product(out, data), secs))
            if name in ("default", "folder budget", "target error"):
                product, summary = asset_product(out, data)
                runs.append((f"{name} asset", product, summary["seconds"]))
        for name, f, secs in runs:
            e = measured[name] if name in measured else evaluate(data, f.recon, sel)
            r[name] = {"k": f.k, "bytes": f.bytes["payload"], "basis_bytes": f.bytes["basis"],
                       "encoded": e.encoded, "linear": e.linear, "seconds": secs, "domain": f.dom.name}
            r[name]["ratio"] = [e.encoded / r["paper"]["encoded"], e.linear / r["paper"]["linear"]]
            say(f"  {name:12s}: k {f.k:3d}, {f.bytes['payload']:,} B (basis {f.bytes['basis']:,}), domain "
                f"{f.dom.name}: {e.row()}, ratio {r[name]['ratio'][0]:.3f} / {r[name]['ratio'][1]:.3f}"
                + ("" if secs is None else f", {secs:.0f} s"))
        if args.heldout_directions:
            with Timer() as t:
                r["directions"] = directions(data, args.stride)
            say("  held-out directions (% enc / % lin): " + ", ".join(
                f"{k} {v['encoded']:.2f} / {v['linear']:.2f}" for k, v in r["directions"].items()) + f" ({t.s:.0f} s)")
        (PRODUCT / "results.json").write_text(json.dumps(results, indent=1, default=float))
    say("\nbudget = the paper's bytes B; 'asset' = the packaged asset: bytes = every file its full lod loads, "
        "error from the asset's own files; 'folder' = the compressed folder's textures and codes; "
        "'at the paper's error' = compress --target-error <paper % enc> (no budget), its asset bytes x B")
    say("\n| preset | paper bytes B | paper % enc / lin | compress budgets | k | folder bytes | asset bytes (x B) | "
        "folder % enc / lin | asset % enc / lin | **asset ratio enc / lin** | compress s |")
    say("|" + "---|" * 11)
    for group in (TUNING_PRESETS, HELDOUT_PRESETS):
        for preset in [x for x in presets if x in group]:
            r = results[preset]
            pa = r["paper"]
            name = ("**held out:** " if preset in HELDOUT_PRESETS else "") + preset
            for variant, label in (("default", "asset (default)"), ("folder budget", "folder (before issue 39)"),
                                   ("target error", "at the paper's error (--target-error)")):
                if variant not in r:
                    continue
                de, asset = r[variant], r.get(f"{variant} asset")
                atxt = (f"{asset['bytes']:,} ({asset['bytes'] / pa['bytes']:.3f})", f"{asset['encoded']:.2f} / "
                        f"{asset['linear']:.2f}", f"**{asset['ratio'][0]:.3f} / {asset['ratio'][1]:.3f}**") \
                    if asset else ("-", "-", "-")
                say(f"| {name} | {pa['bytes']:,} | {pa['encoded']:.2f} / {pa['linear']:.2f} | {label} | {de['k']} | "
                    f"{de['bytes']:,} | {atxt[0]} | {de['encoded']:.2f} / {de['linear']:.2f} | {atxt[1]} | {atxt[2]} | "
                    f"{de['seconds']:.0f} |")
            dirs = r.get("directions")
            if dirs:
                say(f"| {name} | held-out directions % enc / lin: " + "; ".join(
                    f"{k} {dirs[k]['encoded']:.2f} / {dirs[k]['linear']:.2f}" for k in ("floor", "paper", "product"))
                    + " |" + " |" * 9)
    say(f"\nfinished {time.strftime('%Y-%m-%d %H:%M:%S')}; results: {PRODUCT / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
