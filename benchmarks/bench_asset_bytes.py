#!/usr/bin/env python
"""What a packaged asset ships, file kind by file kind, and what single-copy layouts would ship (issue 39).

For one synthetic material (``usdbtf synth``, cached) compressed twice (``usdbtf compress --max-bytes B`` and
``--k K``, cached), ``usdbtf package`` (this checkout's code) writes the asset; its files are counted by kind:
``tables.exr`` (split into the basis block and the rest: hemisphere tables, de-quantisation, directory; the
rest measured by encoding the same tables with the basis block zeroed), the coefficient pages, ``coeff/``,
``basis.*``, the fallback maps, the thumbnail, the MaterialX document and the USD layers.

Then, from the same codes (the compressed folder's, read with ``read_compressed``), the bytes of candidate
single-copy layouts, every one PNG at compression level 6 for 8-bit codes (what ``package`` writes) and the
same page breaks at the default ``lod`` levels:

coefficients
  (a) RGBA packs: pack 3g+c = colour channel c of coefficients 4g..4g+3 (today's ``gpu/pageNN.png``);
  (b) single-channel pages, each coefficient's three colour planes side by side in one tile (planar);
  (c) RGB pages, one coefficient per tile.
basis
  (1) float32 de-quantised values inside ``tables.exr`` (today's GPU copy);
  (2) the integer codes as float32 inside ``tables.exr`` (the shader de-quantises, scale and bias per vector);
  (3) the codes in a separate half-float EXR (exact for 8-bit codes; one more sampler) + tables without basis;
  (4) the codes as an RGBA8 PNG in the shader's order (4 vectors per texel; 8-bit codes only; one more sampler);
  (5) ``basis.png``, the codec's tiled basis image as the asset holds it today.

Shader cost per pixel and light, per coefficient: texel fetches of the coefficient pages (bilinear = 4 fetches
per tile read) and of the de-quantisation (2 per tile), from the layout.

Usage (repository root)::

    .venv/bin/python benchmarks/bench_asset_bytes.py                       # paper sampling, 128^2
    .venv/bin/python benchmarks/bench_asset_bytes.py --size 64 --k 48      # quicker

Writes benchmarks/out/asset_bytes_<timestamp>.json and prints a markdown block for RESULTS.md.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import usdbtf  # noqa: F401  (before numpy: pins the numeric platform)
import numpy as np

from common import OUT, cli_command, format_machine, machine_info, timestamp, write_json


def run(cmd: list) -> float:
    t0 = time.perf_counter()
    subprocess.run([str(c) for c in cmd], check=True)
    return time.perf_counter() - t0


def kind_of(rel: str) -> str:
    """The file kind of a path relative to the asset's folder."""
    parts = Path(rel).parts
    name = parts[-1]
    if name.endswith((".usda", ".usdc", ".usd")):
        return "layers"
    if "gpu" in parts and name.startswith("tables"):
        return "tables"
    if "gpu" in parts and name.startswith("page"):
        return "pages"
    if "gpu" in parts and name.endswith(".mtlx"):
        return "materialx"
    if "coeff" in parts:
        return "coeff/"
    if name.startswith("basis"):
        return "basis file"
    if "fallback" in parts:
        return "fallback"
    if name.startswith("thumbnail"):
        return "thumbnail"
    return "other"


def asset_breakdown(folder: Path) -> dict:
    out: dict = {}
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            kind = kind_of(str(path.relative_to(folder)))
            out[kind] = out.get(kind, 0) + path.stat().st_size
    return out


def png(pixels) -> int:
    from usdbtf.imageio import encode_image

    return len(encode_image(pixels, "png", color_space="data",
                            attributes={"png:compressionLevel": 6, "oiio:UnassociatedAlpha": 1}))


def exr(pixels) -> int:
    from usdbtf.imageio import encode_image

    return len(encode_image(pixels, "exr", color_space="data", attributes={"compression": "zip"}))


def page_bytes(tiles: list, breaks: list) -> tuple[int, int]:
    """(bytes, pages) of ``tiles`` (same-shape arrays) laid out by usdbtf.gpu.tables.page_plan."""
    from usdbtf.gpu.tables import page_plan

    h, w = tiles[0].shape[:2]
    plan, directory = page_plan(len(tiles), w, h, breaks, [t.dtype for t in tiles])
    total = 0
    for first, end, cols, rows in plan:
        page = np.zeros((rows * h, cols * w) + tiles[0].shape[2:], tiles[0].dtype)
        for p in range(first, end):
            _, x0, y0, _ = (int(v) for v in directory[p])
            page[y0:y0 + h, x0:x0 + w] = tiles[p]
        if page.dtype == np.uint8:
            total += png(page)
        else:
            total += exr((page.astype(np.float64) / 65535.0).astype(np.float32) if page.dtype == np.uint16 else page)
    return total, len(plan)


def candidates(folder: Path) -> dict:
    """Bytes of the candidate layouts from the codes of compressed folder ``folder``."""
    from usdbtf.compress.format import read_compressed
    from usdbtf.gpu.tables import gpu_layout, page_breaks
    from usdbtf.usd.lod import default_lods

    cbtf = read_compressed(folder)
    k = cbtf.k
    lods = default_lods(k)
    out = {"k": k, "coefficient_dtype": sorted({str(st.pixels.dtype) for st in cbtf.coefficients}),
           "basis_dtype": str(cbtf.basis.pixels.dtype)}
    layout = gpu_layout(cbtf, lods=lods)
    breaks = page_breaks(k, lods)
    packs = [layout.pages[i] for i in range(len(layout.pages))]
    out["a_rgba_packs"] = {"bytes": sum(png(p) if p.dtype == np.uint8 else exr(p) for p in packs),
                           "pages": len(packs), "page_fetches_per_coeff": 3.0, "dequant_fetches_per_coeff": 1.5}
    planar = [np.concatenate([st.pixels[:, :, c] for c in range(3)], axis=1) for st in cbtf.coefficients]
    # per-coefficient breaks: the lod's first coefficient begins a page
    cbreaks = sorted({n for n in lods if 0 < n < k})
    b, n = page_bytes(planar, cbreaks)
    out["b_planar_single"] = {"bytes": b, "pages": n, "page_fetches_per_coeff": 12.0, "dequant_fetches_per_coeff": 2.0}
    b, n = page_bytes([st.pixels for st in cbtf.coefficients], cbreaks)
    out["c_rgb_tiles"] = {"bytes": b, "pages": n, "page_fetches_per_coeff": 4.0, "dequant_fetches_per_coeff": 2.0}

    flat = layout.tables.reshape(-1, 4)
    V, L, groups = int(flat[0][1]), int(flat[0][2]), int(flat[0][3])
    basis_at = int(flat[1][1])
    S = V * L
    codes = np.zeros((S, groups * 4), np.float32)
    codes[:, :k] = cbtf.basis.pixels[:, :k, 0].astype(np.float32)
    tables_today = exr(layout.tables)
    zeroed = layout.tables.copy()
    zeroed.reshape(-1, 4)[basis_at:basis_at + S * groups] = 0
    rest = exr(zeroed)
    with_codes = layout.tables.copy()
    with_codes.reshape(-1, 4)[basis_at:basis_at + S * groups] = codes.reshape(-1, 4)
    rows = -(-S * groups // 512)
    block = np.zeros((rows * 512, 4), np.float32)
    block[:S * groups] = codes.reshape(-1, 4)
    out["tables_today"] = tables_today
    out["tables_rest"] = rest
    out["basis_1_float32_values"] = tables_today - rest
    out["basis_2_float32_codes"] = exr(with_codes) - rest
    out["basis_3_half_codes_exr"] = exr(block.reshape(rows, 512, 4).astype(np.float16))
    out["basis_4_rgba8_png"] = (png(block.reshape(rows, 512, 4).astype(np.uint8))
                                if cbtf.basis.pixels.dtype == np.uint8 else None)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default="metal_flakes")
    ap.add_argument("--sampling", default="paper")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--k", type=int, default=150)
    ap.add_argument("--max-bytes", type=int, default=2901868, help="the paper's bytes at k 150 (issue 39)")
    ap.add_argument("--work", type=Path, default=OUT / "asset_bytes")
    args = ap.parse_args(argv)
    cli = cli_command()
    machine = machine_info()
    print(format_machine(machine))
    work = args.work / f"{args.preset}_{args.sampling}{args.size}"
    work.mkdir(parents=True, exist_ok=True)
    src = work / "btf"
    if not (src / "btf.json").is_file():
        run(cli + ["synth", args.preset, "-o", src, "--sampling", args.sampling, "--size", args.size, "-q"])
    print(f"inputs: {args.preset}, {args.sampling} sampling, {args.size}^2 texels; compress --max-bytes "
          f"{args.max_bytes} and --k {args.k} (jxlp, the default codec); package (this checkout)")
    report = {"machine": machine, "args": {k: str(v) for k, v in vars(args).items()}, "runs": {}}
    for label, flags in (("max-bytes", ["--max-bytes", args.max_bytes]), ("k", ["--k", args.k])):
        comp = work / f"c_{label}"
        if not (comp / "btf-compressed.json").is_file():
            run(cli + ["compress", src, "-o", comp, "-q"] + flags)
        asset = work / f"a_{label}"
        seconds = run(cli + ["package", comp, "-o", asset / "m.usda", "-q"])
        kinds = asset_breakdown(asset)
        cand = candidates(comp)
        import json

        folder_payload = json.loads((comp / "btf-compressed.json").read_text())["bytes"]["payload"]
        report["runs"][label] = {"kinds": kinds, "total": sum(kinds.values()), "package_s": seconds,
                                 "folder_payload": folder_payload, "candidates": cand}
    write_json(OUT / f"asset_bytes_{timestamp()}.json", report)

    print("\n| run | k | folder payload (basis + coeff) | asset total | " +
          " | ".join(sorted({k for r in report["runs"].values() for k in r["kinds"]})) + " |")
    cols = sorted({k for r in report["runs"].values() for k in r["kinds"]})
    print("|" + "---|" * (4 + len(cols)))
    for label, r in report["runs"].items():
        print(f"| {label} | {r['candidates']['k']} | {r['folder_payload']:,} | {r['total']:,} | "
              + " | ".join(f"{r['kinds'].get(c, 0):,}" for c in cols) + " |")
    print("\ntables.exr split (bytes): basis block = tables - tables with the basis zeroed")
    for label, r in report["runs"].items():
        c = r["candidates"]
        print(f"- {label}: tables {c['tables_today']:,} = basis {c['basis_1_float32_values']:,} + rest "
              f"{c['tables_rest']:,}; codes {c['coefficient_dtype']}, basis {c['basis_dtype']}")
    print("\n| run | coefficients layout | bytes | pages | page fetches / coeff | dequant fetches / coeff |")
    print("|---|---|---|---|---|---|")
    for label, r in report["runs"].items():
        for key in ("a_rgba_packs", "b_planar_single", "c_rgb_tiles"):
            c = r["candidates"][key]
            print(f"| {label} | {key} | {c['bytes']:,} | {c['pages']} | {c['page_fetches_per_coeff']} | "
                  f"{c['dequant_fetches_per_coeff']} |")
    print("\n| run | basis as | bytes |")
    print("|---|---|---|")
    for label, r in report["runs"].items():
        c = r["candidates"]
        for key in ("basis_1_float32_values", "basis_2_float32_codes", "basis_3_half_codes_exr",
                    "basis_4_rgba8_png"):
            print(f"| {label} | {key} | {c[key] if c[key] is None else format(c[key], ',')} |")
        print(f"| {label} | basis_5_png (the asset's basis file today) | {r['kinds'].get('basis file', 0):,} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
