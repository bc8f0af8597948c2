#!/usr/bin/env python
"""What a packaged asset ships, file kind by file kind, and what single-copy layouts would ship (issue 39).

For one synthetic material (``usdbtf synth``, cached) compressed twice (``usdbtf compress --max-bytes B`` and
``--k K``, cached), ``usdbtf package`` (this checkout's code) writes the asset; its files are counted by kind
(:func:`kind_of`):
the full lod's ``gpu/tables.exr`` (split into the basis block and the rest: hemisphere tables,
de-quantisation, directory; the rest measured by encoding the same tables with the basis block zeroed; under
schema 4 the block holds only the basis's de-quantisation, the codes being in the basis page), the coefficient
pages, the basis page ``gpu/basis.png`` (schema 4), the lower lods' own files (``tables_k<n>.exr``,
``basis_k<n>.png``, ``usdbtf_k<n>.mtlx``: not loaded by the full lod), the MaterialX document, the fallback
maps, the thumbnail (``thumbnail.jpg``, a PNG before issue 39), the USD layers, and of older assets
``coeff/`` and ``basis.*``: every file the asset folder holds, and the files the full lod loads as
``inspect`` lists them (``usd.asset.package.shipped_levels``; what ``--max-bytes`` budgets), by kind.

Then, from the same codes (the compressed folder's, read with ``read_compressed``), the bytes of candidate
single-copy layouts, every one PNG at compression level 6 for 8-bit codes (what ``package`` writes) and the
same page breaks at the default ``lod`` levels:

coefficients
  (a) RGBA packs: pack 3g+c = colour channel c of coefficients 4g..4g+3 (today's ``gpu/pageNN.png``);
  (b) single-channel pages, each coefficient's three colour planes side by side in one tile (planar);
  (c) RGB pages, one coefficient per tile.
basis
  each as a standalone float/PNG image of 512-texel rows, 4 vectors per texel:
  (1) float32 de-quantised values, sample-major (the GPU copy before issue 39);
  (2) the stored codes as float32, sample-major; (3) the same, group-major (one group of 4 vectors'
  samples after the other: what the tables hold after issue 39, the shader de-quantises);
  (4) the codes as half floats (exact only for codes <= 2048; a sampler of its own);
  (5) the codes' high and low bytes as two RGBA8 PNGs (what Storm can read exactly; two samplers);
  (6) the codec's tiled basis image as 16-bit PNG (``basis.png`` of the asset before issue 39).

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


#: Kinds of files the full lod does not load (a lower lod's own tables, basis page, MaterialX document).
LOWER_LODS = "lower lods' own files"


def kind_of(rel: str) -> str:
    """The file kind of a path relative to the asset's folder (a schema-4 asset's, or an older one's)."""
    import re

    parts = Path(rel).parts
    name = parts[-1]
    if name.endswith((".usda", ".usdc", ".usd")):
        return "layers"
    if "gpu" in parts and re.fullmatch(r"(tables|basis|usdbtf)_k\d+\.\w+", name):
        return LOWER_LODS
    if "gpu" in parts and name.startswith("tables"):
        return "tables"
    if "gpu" in parts and name.startswith("page"):
        return "pages"
    if "gpu" in parts and name.startswith("basis"):
        return "basis page"
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
    """{kind: bytes} of every file under the asset's folder ``folder`` (:func:`kind_of`)."""
    out: dict = {}
    for path in sorted(folder.rglob("*")):
        if path.is_file():
            kind = kind_of(str(path.relative_to(folder)))
            out[kind] = out.get(kind, 0) + path.stat().st_size
    return out


def full_lod_breakdown(root: Path) -> dict:
    """{kind: bytes} of the files the full lod of the asset ``root`` loads (``inspect``'s list)."""
    from usdbtf.usd.asset.package import shipped_levels

    out: dict = {}
    for f in shipped_levels(root, shares=False)[0]["files"]:
        kind = kind_of(f["path"])
        out[kind] = out.get(kind, 0) + int(f["bytes"])
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


def probe(folder: Path) -> dict:
    """The shipped-bytes probe rate control can use (issue 39): sum of the per-pack bytes and the
    basis codes' bytes of compressed folder ``folder``, and the seconds both took."""
    from usdbtf.compress.format import read_compressed
    from usdbtf.compress.packs import shipped_basis_bytes, shipped_pack_bytes

    cbtf = read_compressed(folder)
    t0 = time.perf_counter()
    packs = sum(shipped_pack_bytes(cbtf))
    basis = shipped_basis_bytes(cbtf)
    return {"packs": packs, "basis": basis, "seconds": time.perf_counter() - t0}


def candidates(folder: Path) -> dict:
    """Bytes of the candidate layouts from the codes of compressed folder ``folder``."""
    from usdbtf.compress.format import read_compressed
    from usdbtf.compress.packs import encode_png_page
    from usdbtf.gpu.tables import gpu_layout, page_breaks
    from usdbtf.usd.asset.lod import default_lods

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
    S = V * L
    # The basis block is the tables' last block (schema 3 and 4): from its offset to the end.
    basis_at = int(flat[1][1])
    zeroed = layout.tables.copy()
    zeroed.reshape(-1, 4)[basis_at:] = 0
    out["tables_this_checkout"] = exr(layout.tables)
    out["tables_rest"] = exr(zeroed)
    out["basis_page"] = None if layout.basis_page is None else len(encode_png_page(layout.basis_page))

    def rows512(texels: np.ndarray) -> np.ndarray:
        rows = -(-len(texels) // 512)
        block = np.zeros((rows * 512, 4), texels.dtype)
        block[:len(texels)] = texels
        return block.reshape(rows, 512, 4)

    codes = np.zeros((S, groups * 4), np.float32)
    codes[:, :k] = cbtf.basis.pixels[:, :k, 0].astype(np.float32)
    values = np.zeros((S, groups * 4), np.float32)
    values[:, :k] = cbtf.basis_values(k)
    group_major = codes.reshape(S, groups, 4).transpose(1, 0, 2).reshape(-1, 4)
    out["basis_1_float32_values_sample_major"] = exr(rows512(values.reshape(-1, 4)))
    out["basis_2_float32_codes_sample_major"] = exr(rows512(codes.reshape(-1, 4)))
    out["basis_3_float32_codes_group_major"] = exr(rows512(group_major))
    half_exact = bool(np.array_equal(codes.astype(np.float16).astype(np.float32), codes))
    out["basis_4_half_codes_group_major"] = exr(rows512(group_major.astype(np.float16)))
    out["basis_4_exact"] = half_exact
    ints = group_major.astype(np.uint16)
    out["basis_5_hi_lo_rgba8_png_group_major"] = png(rows512((ints >> 8).astype(np.uint8))) + \
        png(rows512((ints & 255).astype(np.uint8)))
    from usdbtf.compress.format import basis_layout, basis_to_image
    from usdbtf.imageio import encode_image

    image = basis_to_image(cbtf.basis.pixels, basis_layout(cbtf.sampling, k, "png"))
    out["basis_6_png_tiles"] = len(encode_image(image, "png", color_space="data",
                                                attributes={"png:compressionLevel": 6}))
    out["coeff_files_rgb_png"] = sum(len(encode_image(st.pixels, "png", color_space="data",
                                                      attributes={"png:compressionLevel": 6}))
                                     for st in cbtf.coefficients)
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
        seconds = run(cli + ["package", comp, "-o", asset / "m.usda", "-q", "--force"])
        kinds = asset_breakdown(asset)
        full_kinds = full_lod_breakdown(asset / "m.usda")
        cand = candidates(comp)
        import json

        folder_payload = json.loads((comp / "btf-compressed.json").read_text())["bytes"]["payload"]
        report["runs"][label] = {"kinds": kinds, "total": sum(kinds.values()), "full_kinds": full_kinds,
                                 "full_lod": sum(full_kinds.values()), "package_s": seconds,
                                 "folder_payload": folder_payload, "candidates": cand, "probe": probe(comp)}
    write_json(OUT / f"asset_bytes_{timestamp()}.json", report)

    cols = sorted({k for r in report["runs"].values() for k in r["kinds"]})
    print("\nper kind: bytes the full lod loads (inspect's lod_files: what --max-bytes budgets) / bytes the folder "
          "holds (with the lower lods' own files and what no lod loads)\n")
    print("| run | k | folder payload (basis + coeff) | full lod | all files | " + " | ".join(cols) + " |")
    print("|" + "---|" * (5 + len(cols)))
    for label, r in report["runs"].items():
        print(f"| {label} | {r['candidates']['k']} | {r['folder_payload']:,} | {r['full_lod']:,} | {r['total']:,} | "
              + " | ".join(f"{r['full_kinds'].get(c, 0):,} / {r['kinds'].get(c, 0):,}" for c in cols) + " |")
    print("\ntables.exr (this checkout): the basis block = tables - the same tables with the block zeroed; "
          "basis page = gpu/basis.png re-encoded from the layout (schema 4; - when the codes are in the tables)")
    for label, r in report["runs"].items():
        c = r["candidates"]
        page = "-" if c["basis_page"] is None else f"{c['basis_page']:,}"
        print(f"- {label}: tables {c['tables_this_checkout']:,} = basis block "
              f"{c['tables_this_checkout'] - c['tables_rest']:,} + rest {c['tables_rest']:,}; basis page {page}; "
              f"coefficient codes {c['coefficient_dtype']}, basis codes {c['basis_dtype']}")
    print("\nshipped-bytes probe (usdbtf.compress.packs: each pack on its own, the basis codes alone) "
          "against the asset's files")
    print("\n| run | probe packs | pages | probe / pages | probe basis codes | asset's basis codes | probe s |")
    print("|---|---|---|---|---|---|---|")
    for label, r in report["runs"].items():
        pr, c, pages = r["probe"], r["candidates"], r["kinds"].get("pages", 0)
        # schema 4: the basis page file; else the tables' basis block
        shipped = r["kinds"].get("basis page") or c["tables_this_checkout"] - c["tables_rest"]
        print(f"| {label} | {pr['packs']:,} | {pages:,} | {pr['packs'] / max(1, pages):.4f} | {pr['basis']:,} | "
              f"{shipped:,} | {pr['seconds']:.2f} |")
    print("\n| run | coefficients layout | bytes | pages | page fetches / coeff | dequant fetches / coeff |")
    print("|---|---|---|---|---|---|")
    for label, r in report["runs"].items():
        for key in ("a_rgba_packs", "b_planar_single", "c_rgb_tiles"):
            c = r["candidates"][key]
            print(f"| {label} | {key} | {c['bytes']:,} | {c['pages']} | {c['page_fetches_per_coeff']} | "
                  f"{c['dequant_fetches_per_coeff']} |")
        print(f"| {label} | coeff/ files (RGB PNG, one per coefficient; not a GPU layout) | "
              f"{r['candidates']['coeff_files_rgb_png']:,} | - | - | - |")
    print("\n| run | basis as (standalone files, 512-texel rows) | bytes | sampler of its own |")
    print("|---|---|---|---|")
    for label, r in report["runs"].items():
        c = r["candidates"]
        for key, own in (("basis_1_float32_values_sample_major", "no (in tables)"),
                         ("basis_2_float32_codes_sample_major", "no (in tables)"),
                         ("basis_3_float32_codes_group_major", "no (in tables)"),
                         ("basis_4_half_codes_group_major", "yes" + ("" if c["basis_4_exact"] else ", NOT exact")),
                         ("basis_5_hi_lo_rgba8_png_group_major", "yes (two)"),
                         ("basis_6_png_tiles", "yes (16-bit PNG: Storm reads 8 bits)")):
            print(f"| {label} | {key} | {c[key]:,} | {own} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
