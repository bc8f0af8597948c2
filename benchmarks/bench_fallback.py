#!/usr/bin/env python
"""The fallbacks against the BTF they stand in for (issue 15 part 3, issue 40 part 2).

For each preset: the synthetic BTF (``usdbtf synth``, cached), compressed (``usdbtf compress
--k K --codec png``, cached), then

fitted   ``usdbtf.svbrdf.fit_svbrdf`` on the compressed BTF (timed, in this process), written
         and read back exactly as the asset ships it (``usd.asset.fallback.encode_maps`` /
         ``shipped_pixels`` / ``decode_maps``: 8-bit sRGB colour maps, 8-bit roughness and
         normal maps, a lossy file decoded back): the UsdPreviewSurface on
         ``outputs:surface``;
openpbr  ``usdbtf.openpbr.fit_openpbr`` (timed; it starts from the fitted UsdPreviewSurface's
         normals), written and read back as shipped (``usd.asset.openpbr.encode_maps`` /
         ``decode_maps``): the OpenPBR Surface on ``outputs:mtlx:surface``, evaluated with
         ``openpbr.evaluate`` (MaterialX's open_pbr_surface, checked against MaterialX's
         generated GLSL by tests/test_openpbr.py);
flat     the fallback usdbtf shipped before (the baseline, same run): per-texel median albedo
         as an 8-bit sRGB texture, one fitted roughness, no normal map, metallic 0
         (``svbrdf.flat_fallback``).

The UsdPreviewSurface fits are evaluated with its direct lighting (``svbrdf.evaluate``, the model of
previewSurface.glslfx) at every measured (view, light) sample and compared, texel by texel,
with (a) the measured samples (the synthetic originals) in the scene-linear working space
("lin") and on the 8-bit file values with the prediction encoded the same way ("enc"), and
(b) the compressed BTF's reconstruction (what the fit sees) in the working space.  Percent
error is the paper's metric, 100 * sum|orig - pred| / sum(orig); RMSE and PSNR in the same
run.  The compressed BTF's own error against the originals is printed for context.

``--png-baseline`` also evaluates both fits read back from every map as PNG (the storage
before issue 39's JPEG maps: same fits, same run) and prints each storage's error relative to
it; ``--what-if Q:MAPS`` (repeatable) adds a storage not shipped: the maps named (both
fallbacks' map names, comma-separated) as JPEG at quality Q, the others PNG.

Usage (repository root)::

    .venv/bin/python benchmarks/bench_fallback.py                 # all seven presets, paper sampling, 128^2, k 64
    .venv/bin/python benchmarks/bench_fallback.py --quick         # small sampling, 64^2 (a check)
    .venv/bin/python benchmarks/bench_fallback.py --quick --png-baseline --what-if 95:diffuse,base

Writes benchmarks/out/fallback_<timestamp>.json and prints a markdown block for RESULTS.md
(the held-out presets, ``usdbtf.bench.datasets.HELDOUT_PRESETS``, in a table of their own).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import OUT, cli_command, dataset_arguments, format_machine, machine_info, timestamp, write_json

PRESETS = ("pebbles", "ridged_fabric", "fuzzy_moss", "metal_flakes", "satin_weave", "crevice_stones", "velvet")


def say(msg: str = "") -> None:
    print(msg, flush=True)


#: --ablation: fits with one choice of fit_svbrdf undone (name -> keyword arguments).
ABLATIONS = {"fitted, no normal map": {"normals": False}, "fitted, 512 fit samples": {"max_samples": 512}}
#: --before-brightness: the fits without their brightness step (svbrdf.keep_brightness,
#: openpbr.keep_brightness; the OpenPBR fit from the UsdPreviewSurface fit without it), same run.
BEFORE_BRIGHTNESS = ("fitted, brightness not kept", "openpbr, brightness not kept")


#: --png-baseline: the storage before issue 39's JPEG maps (every map PNG).
PNG_BASELINE = "all maps PNG"


def storage(jpeg_maps: str | None, quality: int | None) -> tuple[dict, dict, dict]:
    """(UsdPreviewSurface files, OpenPBR files, JPEG options) of a storage: the shipped
    ``MAP_FILES`` with the maps named in ``jpeg_maps`` (comma-separated; "none": no map;
    None: as shipped) as ".jpg" and the others ".png", at JPEG ``quality`` (None: as shipped)."""
    from usdbtf.usd.asset import fallback as ups, openpbr as op

    jpeg = dict(ups.MAP_JPEG) if quality is None else {**ups.MAP_JPEG, "Compression": f"jpeg:{quality}"}
    if jpeg_maps is None:
        return ups.MAP_FILES, op.MAP_FILES, jpeg
    chosen = set() if jpeg_maps == "none" else set(jpeg_maps.split(","))

    def files(table):
        return {m: (f"{Path(f).stem}{'.jpg' if m in chosen else '.png'}", kind) for m, (f, kind) in table.items()}

    return files(ups.MAP_FILES), files(op.MAP_FILES), jpeg


def read_back(maps, cbtf, white: float, files: dict, jpeg: dict):
    """``maps`` (a UsdPreviewSurface or OpenPBR fit) as a renderer reads them from ``files``."""
    from usdbtf import openpbr
    from usdbtf.usd.asset import fallback as ups, openpbr as op

    module = op if isinstance(maps, openpbr.OpenPbrMaps) else ups
    pixels = ups.shipped_pixels(module.encode_maps(maps, cbtf.ocio_config), files, jpeg)
    return module.decode_maps(pixels, cbtf.working_space, ocio_config=cbtf.ocio_config, white_level=white)


def shipped_fallbacks(cbtf, white: float, ablation: bool = False, before_brightness: bool = False,
                      storages: dict | None = None) -> tuple[dict, float, float]:
    """({"fitted": maps, "openpbr": maps, "flat": maps, ablations...} as a renderer reads them
    from the asset, seconds of the UsdPreviewSurface fit, seconds of the OpenPBR fit).
    ``storages``: {label: :func:`storage`} of storages not shipped: both fits read back from
    each too, as "fitted, <label>" and "openpbr, <label>"."""
    from usdbtf import openpbr, svbrdf

    ups_files, op_files, jpeg = storage(None, None)

    t = time.perf_counter()
    fitted = svbrdf.fit_svbrdf(cbtf, white_level=white)
    seconds = time.perf_counter() - t
    t = time.perf_counter()
    op = openpbr.fit_openpbr(cbtf, svbrdf=fitted, white_level=white)
    op_seconds = time.perf_counter() - t
    flat = svbrdf.flat_fallback(cbtf, white_level=white)
    maps = [("fitted", fitted), ("flat", flat)]
    if ablation:
        maps += [(name, svbrdf.fit_svbrdf(cbtf, white_level=white, **kw)) for name, kw in ABLATIONS.items()]
    unkept_op = None
    if before_brightness:
        unkept = svbrdf.fit_svbrdf(cbtf, white_level=white, brightness=False)
        maps.append(("fitted, brightness not kept", unkept))
        unkept_op = openpbr.fit_openpbr(cbtf, svbrdf=unkept, white_level=white, brightness=False)
    shipped = {name: read_back(m, cbtf, white, ups_files, jpeg) for name, m in maps}
    # The old asset had no normal map and constant inputs: only its albedo went through a file.
    old = shipped["flat"]
    old.normal[:] = (0.0, 0.0, 1.0)
    old.specular[:] = 0.04
    old.roughness[:] = flat.roughness
    for name, fitted_op in (("openpbr", op), ("openpbr, brightness not kept", unkept_op)):
        if fitted_op is not None:
            shipped[name] = read_back(fitted_op, cbtf, white, op_files, jpeg)
    for label, (other_ups, other_op, other_jpeg) in (storages or {}).items():
        shipped[f"fitted, {label}"] = read_back(fitted, cbtf, white, other_ups, other_jpeg)
        shipped[f"openpbr, {label}"] = read_back(op, cbtf, white, other_op, other_jpeg)
    return shipped, seconds, op_seconds


def errors(orig, cbtf, fallbacks: dict, chunk: int = 128) -> dict:
    """{name: {"linear", "encoded", "vs_reconstruction"}} for each fallback, and "reconstruction"
    (the compressed BTF against the originals): one pass over the measured samples."""
    from usdbtf import color
    from usdbtf.compress.format import reconstruct, working_coefficients
    from usdbtf.compress.metrics import ErrorSums
    from usdbtf.manifest import encode_for_file
    from usdbtf import openpbr, svbrdf

    to_file = color.processor(orig.working_space, orig.color_space, orig.ocio_config)
    top = {"uint8": 255.0, "uint16": 65535.0}.get(orig.bit_depth, 1.0)
    coeff = working_coefficients(cbtf)
    sums = {name: {"linear": ErrorSums(), "encoded": ErrorSums(), "vs_reconstruction": ErrorSums()}
            for name in [*fallbacks, "reconstruction"]}
    shape = (cbtf.height, cbtf.width, 3)
    for a in range(0, orig.n_samples, chunk):
        idx = np.arange(a, min(a + chunk, orig.n_samples))
        stored = orig.read_encoded(idx)
        truth = orig.decode(stored)
        stored = stored.astype(np.float32) / top
        recon = reconstruct(cbtf, idx, coefficients=coeff)
        preds = {"reconstruction": recon}
        for name, maps in fallbacks.items():
            evaluate = openpbr.evaluate if isinstance(maps, openpbr.OpenPbrMaps) else svbrdf.evaluate
            preds[name] = evaluate(maps, cbtf.sampling.view[idx], cbtf.sampling.light[idx]).reshape(len(idx), *shape)
        for name, pred in preds.items():
            sums[name]["linear"].add(truth, pred)
            sums[name]["encoded"].add(stored, encode_for_file(pred, to_file, orig.bit_depth).astype(np.float32) / top)
            if name != "reconstruction":
                sums[name]["vs_reconstruction"].add(recon, pred)
    return {name: {domain: s.report() for domain, s in by.items() if s.count} for name, by in sums.items()}


def main(argv=None) -> int:
    ap = dataset_arguments(argparse.ArgumentParser(description=__doc__.split("\n\n")[0]), ",".join(PRESETS))
    ap.add_argument("--quick", action="store_true", help="small sampling, 64^2 (a check, not a measurement)")
    ap.add_argument("--ablation", action="store_true", help="also fit without the normal map and with 512 fit "
                    "samples (the choices fit_svbrdf makes by default)")
    ap.add_argument("--before-brightness", action="store_true", help="also the UsdPreviewSurface fit without its "
                    "brightness step (svbrdf.keep_brightness), the before of issue 40")
    ap.add_argument("--png-baseline", action="store_true", help="also both fits read back from all-PNG maps (before "
                    "issue 39's JPEG maps), and each storage's error relative to it")
    ap.add_argument("--what-if", action="append", default=[], metavar="Q:MAPS", help="also both fits read back from "
                    "the maps MAPS (comma-separated) as JPEG at quality Q, the others PNG (repeatable)")
    args = ap.parse_args(argv)
    if args.quick:
        args.sampling, args.size = "small", 64

    from usdbtf.bench.datasets import compressed, ensure_dataset, preset_split
    from usdbtf.io import open_btf
    from usdbtf.photometry import white_level_of

    info = machine_info()
    say("# bench_fallback: flat / fitted UsdPreviewSurface / fitted OpenPBR, against the BTF")
    say(format_machine(info))
    say(f"- inputs: presets {args.presets}; sampling {args.sampling}, {args.size}x{args.size} texels, 8-bit sRGB "
        f"PNG, synth seed {args.seed}; compressed with `usdbtf compress --k {args.k} --codec png` (rsvd)")
    say(f"- command: {' '.join([Path(sys.executable).name, *sys.argv])}")
    cli = cli_command()
    storages = {PNG_BASELINE: storage("none", None)} if args.png_baseline else {}
    for spec in args.what_if:
        quality, _, names = spec.partition(":")
        storages[f"JPEG q{quality} {names}"] = storage(names, int(quality))
    storage_rows = []
    rows, ablation_rows, doc = {"tuning": [], "held-out": []}, [], {"machine": info, "args": vars(args), "presets": {}}
    for preset in args.presets.split(","):
        say(f"\n## {preset}")
        data = ensure_dataset(OUT / "data", preset, args.sampling, args.size, args.seed, say=say)
        folder = OUT / "fallback" / f"{preset}-{args.sampling}-{args.size}-seed{args.seed}-k{args.k}"
        cbtf = compressed(cli, Path(data["folder"]), folder, args.k)
        orig = open_btf(data["folder"])
        white = white_level_of(cbtf.info)
        shipped, fit_s, op_s = shipped_fallbacks(cbtf, white, args.ablation, args.before_brightness, storages)
        say(f"  fits: UsdPreviewSurface {fit_s:.1f} s, OpenPBR {op_s:.1f} s for {cbtf.width}x{cbtf.height} texels, "
            f"{cbtf.n_samples} samples, k {cbtf.k}")
        t = time.perf_counter()
        res = errors(orig, cbtf, shipped)
        say(f"  evaluation over {orig.n_samples} samples: {time.perf_counter() - t:.1f} s")
        for name, r in res.items():
            parts = [f"{dom} {v['percent']:.2f} % (RMSE {v['rmse']:.4f}, PSNR {v['psnr_db']:.1f} dB)"
                     for dom, v in r.items()]
            say(f"  {name:15s} " + "; ".join(parts))
            if name in ABLATIONS or name in BEFORE_BRIGHTNESS:
                ablation_rows.append(f"| {preset} | {name} | {r['linear']['percent']:.2f} | {r['linear']['rmse']:.4f} | "
                                     f"{r['encoded']['percent']:.2f} | {r['encoded']['rmse']:.4f} |")
        doc["presets"][preset] = {"fit_seconds": fit_s, "openpbr_fit_seconds": op_s, "errors": res,
                                  "samples": orig.n_samples, "texels": cbtf.width * cbtf.height, "k": cbtf.k,
                                  "split": preset_split(preset)}
        f, o, fl, rc = res["fitted"], res["openpbr"], res["flat"], res["reconstruction"]
        for name in ("fitted", "flat") + (("openpbr",) if args.before_brightness else ()):
            ablation_rows.append(f"| {preset} | {name} | {res[name]['linear']['percent']:.2f} | "
                                 f"{res[name]['linear']['rmse']:.4f} | {res[name]['encoded']['percent']:.2f} | "
                                 f"{res[name]['encoded']['rmse']:.4f} |")
        pct = lambda r, d: r[d]["percent"]  # noqa: E731
        if args.png_baseline:
            base = (res[f"fitted, {PNG_BASELINE}"], res[f"openpbr, {PNG_BASELINE}"])
            for label in ["as shipped", *storages]:
                pair = (f, o) if label == "as shipped" else (res[f"fitted, {label}"], res[f"openpbr, {label}"])
                storage_rows.append(f"| {preset} | {label} | " + " | ".join(
                    f"{pct(x, d):.3f} ({pct(x, d) / pct(b, d) - 1:+.2%})"
                    for x, b in zip(pair, base) for d in ("linear", "encoded")) + " |")
        rows[preset_split(preset)].append(
            f"| {preset} | {pct(fl, 'linear'):.2f} | {pct(f, 'linear'):.2f} | {pct(o, 'linear'):.2f} | "
            f"{pct(o, 'linear') / pct(f, 'linear'):.2f}x | {pct(fl, 'encoded'):.2f} | {pct(f, 'encoded'):.2f} | "
            f"{pct(o, 'encoded'):.2f} | {pct(o, 'encoded') / pct(f, 'encoded'):.2f}x | "
            f"{pct(f, 'vs_reconstruction'):.2f} | {pct(o, 'vs_reconstruction'):.2f} | {pct(rc, 'linear'):.2f} | "
            f"{fit_s:.1f} | {op_s:.1f} |")
    say("\n## results (markdown for benchmarks/RESULTS.md)")
    for split, title in (("tuning", "tuning presets"), ("held-out", "held-out presets (no tuning run looked at them)")):
        if not rows[split]:
            continue
        say(f"\n{title}:\n")
        say("| preset | flat % lin | UsdPreviewSurface % lin | OpenPBR % lin | OpenPBR / UPS lin | flat % enc | "
            "UPS % enc | OpenPBR % enc | OpenPBR / UPS enc | UPS % vs recon | OpenPBR % vs recon | BTF (k) % lin | "
            "UPS fit s | OpenPBR fit s |")
        say("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for row in rows[split]:
            say(row)
    if args.ablation or args.before_brightness:
        say("\n| preset | fallback | % lin | RMSE lin | % enc | RMSE enc |\n|---|---|---|---|---|---|")
        for row in sorted(ablation_rows):
            say(row)
    if storage_rows:
        say("\nmap storage (each fit read back from its files; in brackets: relative to every map PNG, same fit):\n")
        say("| preset | storage | UPS % lin | UPS % enc | OpenPBR % lin | OpenPBR % enc |\n|---|---|---|---|---|---|")
        for row in storage_rows:
            say(row)
    path = write_json(OUT / f"fallback_{timestamp()}.json", doc)
    say(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
