#!/usr/bin/env python
"""Compression benchmark: default (rsvd) solver vs the paper's solver on paper-scale synthetic BTFs.

Measures, in one run, the acceptance criteria of the compression issue:

quality  per preset: ``usdbtf compress --solver paper --k 150`` (Koudelka et al. 2003), then the
         default solver at the paper solver's payload (``--max-bytes``).  Full-data errors of both
         (every sample, every texel, via ``usdbtf.compress.decompress.compare``): percent error
         (paper metric 100 * sum|orig - recon| / sum orig), RMSE, PSNR, in scene-linear and on
         the stored 8-bit encoding.  Target: default/paper percent error <= 0.7, in both.
         Presets are reported in two groups: the tuning presets and the held-out ones
         (``usdbtf.bench.datasets.HELDOUT_PRESETS``), which no tuning run may look at.
speed    median wall time of the ``usdbtf compress`` subprocess (default solver; interpreter
         start and PNG decoding included) / median time of one float32 GEMM ``U.T @ X`` with
         X (S, H*W*3) and U (S, 150), timed in this process.  Target <= 3.
memory   peak memory of the compress subprocess tree.  Target <= 2 GB (2e9 bytes).

Usage (from the repository root)::

    .venv/bin/python benchmarks/bench_compress.py            # paper scale, all presets (many minutes)
    .venv/bin/python benchmarks/bench_compress.py --quick    # small sampling, 64^2, 1 repeat (< 2 min)

Writes ``benchmarks/out/compress_<timestamp>.json`` and ``..._error_curves.png`` and prints a
markdown table for ``benchmarks/RESULTS.md``.  Generated datasets are cached in ``--workdir``.
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import (OUT, REPO, cli_command, fmt_bytes, folder_bytes, format_machine, machine_info, run_repeated,
                    time_call, timestamp, warm_page_cache, write_json)

from usdbtf.bench.datasets import HELDOUT_PRESETS, TUNING_PRESETS, preset_split, split_presets

PRESETS = TUNING_PRESETS + HELDOUT_PRESETS
TARGETS = {"quality_ratio": 0.7, "speed_ratio": 3.0, "memory_bytes": 2e9}
PAPER_SCALE = {"sampling": "paper", "size": 128}
GEMM_REPEATS = 5


def say(msg: str = "") -> None:
    print(msg, flush=True)


# -- inputs ------------------------------------------------------------------------------------
def ensure_dataset(workdir, preset, sampling, size, seed, n_samples, fmt="png") -> dict:
    """The cached synthetic input (generated as `usdbtf synth` would; see usdbtf.bench.datasets)."""
    from usdbtf.bench.datasets import ensure_dataset as ensure

    info = ensure(workdir, preset, sampling, size, seed, fmt, say=say)
    if info["n_samples"] != n_samples:
        raise SystemExit(f"{info['folder']}: {info['n_samples']} samples, expected {n_samples}")
    info["synth_command"] = (f"usdbtf synth {preset} -o {info['folder']} --sampling {sampling} --size {size} "
                             f"--seed {seed} --format {fmt}")
    return info


# -- baseline ----------------------------------------------------------------------------------
def gemm_baseline(n_samples: int, n_pixels: int, k: int) -> dict:
    """Median time of one float32 U.T @ X, X (S, P*3) random, U (S, k); after one warm-up."""
    rng = np.random.default_rng(0)
    x = rng.random((n_samples, n_pixels * 3), dtype=np.float32)
    u = rng.standard_normal((n_samples, k), dtype=np.float32)
    res = time_call(lambda: u.T @ x, repeats=GEMM_REPEATS, warmup=1)
    flops = 2.0 * n_samples * k * n_pixels * 3
    res.update(shape_x=list(x.shape), shape_u=list(u.shape), dtype="float32", expression="U.T @ X",
               gflops_per_s=flops / res["median_s"] / 1e9, x_bytes=int(x.nbytes))
    return res


# -- one solver --------------------------------------------------------------------------------
def run_solver(cli, data: Path, out: Path, extra_args: list, repeats: int, pss_interval: float) -> dict:
    cmd = [*cli, "compress", data, "-o", out, *extra_args]
    say(f"    $ {' '.join(map(str, cmd))}")
    outputs = []

    def after(i, r):
        doc = json.loads((out / "btf-compressed.json").read_text())
        outputs.append((doc["k"], doc["bytes"]["payload"]))
        say(f"    run {i + 1}/{repeats}: {r.wall_s:.2f} s wall, peak RSS {fmt_bytes(r.max_rss_bytes)}, "
            f"tree PSS {fmt_bytes(r.peak_tree_pss_bytes)}; k {doc['k']}, {doc['bytes']['payload']:,} B")

    res = run_repeated(cmd, repeats, pss_interval=pss_interval, on_run=after)
    res.pop("stderr")
    if "error" in res:
        say(f"    run {len(res['runs'])}: FAILED\n" + res["error"])
        return {key: res[key] for key in ("command", "error", "runs")}
    if len(set(outputs)) > 1:
        say("    WARNING: repeats gave different (k, payload); the last run's output is evaluated")
    doc = json.loads((out / "btf-compressed.json").read_text())
    res.update({
        "k": doc["k"], "codec": doc["codec"], "solver": doc.get("solver"),
        "bytes": {key: doc["bytes"][key] for key in ("payload", "basis", "coefficients")},
        "metadata_bytes": (out / "btf-compressed.json").stat().st_size,
        "folder_bytes": folder_bytes(out),
        "choice": doc.get("choice"),
        "held_out_estimate": doc.get("estimated_error"),
        "output": str(out),
        "error_curve": read_curve(out / "error_curve.csv"),
    })
    return res


def read_curve(path: Path) -> dict:
    ks, pct = [], []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            ks.append(int(row["k"]))
            pct.append(float(row["percent_error"]))
    return {"file": str(path), "k": ks, "percent": pct}


def full_error(orig, folder: Path) -> dict:
    """Full-data errors of the stored representation (every sample, every texel)."""
    from usdbtf.bench.methods import CompressedReconstruction
    from usdbtf.compress.decompress import compare

    t = time.perf_counter()
    rec = CompressedReconstruction(folder)   # de-quantises (and colour-transforms) once, reused per chunk
    rep = compare(orig, rec.fitted, None)
    rep["seconds"] = time.perf_counter() - t
    return rep


# -- report ------------------------------------------------------------------------------------
def verdict(values, limit, fmt, failed=()) -> str:
    vals = [v for v in values if v is not None and np.isfinite(v)]
    worst = f"worst {fmt(max(vals))}" if vals else "no data"
    if failed:
        return f"≤ {fmt(limit)}: **FAIL** (no result for {', '.join(failed)}; {worst} of the rest)"
    if not vals:
        return "n/a"
    return f"≤ {fmt(limit)}: **{'PASS' if max(vals) <= limit else 'FAIL'}** ({worst})"


def failed_presets(results: dict) -> list:
    return [p for p, r in results.items() if any("error" in r.get(k, {"error": "not run"}) for k in ("paper", "default"))]


def _ratio(x: float) -> str:
    return f"{x:.1f} : 1" if x < 100 else f"{x:.0f} : 1"


def _num(value, fmt: str) -> str:
    """A table cell: the number, or an em dash where it was not measured (speed-only rows)."""
    return "\u2014" if value is None else format(value, fmt)


def markdown_table(results: dict, gemm: dict) -> str:
    """One table: the tuning presets' rows, then the held-out presets' (marked), then the
    targets row of each group."""
    tuning, held = split_presets(results)
    lines = []
    for group, label in ((tuning, "tuning presets"), (held, "held-out presets")):
        if group:
            part = _table_rows({p: results[p] for p in group}, gemm, label)
            lines += part if not lines else part[2:]
    return "\n".join(lines)


def _preset_label(preset: str) -> str:
    return preset if preset_split(preset) == "tuning" else f"{preset} (held out)"


def _table_rows(results: dict, gemm: dict, group: str) -> list:
    head = ["preset", "solver", "k", "payload", "raw : payload", "% err lin", "% err enc", "RMSE lin",
            "PSNR lin dB", "PSNR enc dB", "err ratio rsvd/paper (lin, enc)", "compress s (median)",
            "time / GEMM", "peak RSS / tree PSS"]
    rows = []
    q_all, s_all, m_all = [], [], []
    for preset, r in results.items():
        name = _preset_label(preset)
        for key in ("paper", "default", "plain"):
            s = r.get(key)
            if s is None:
                continue
            if "error" in s:
                lines = [x for x in s["error"].strip().splitlines() if x.strip()] or ["?"]
                why = lines[-1].replace("|", "\\|")
                rows.append([name, key, f"FAILED: {why}"] + [""] * (len(head) - 3))
                continue
            fe = s.get("full_error", {})
            lin, enc = fe.get("linear", {}), fe.get("encoded", {})
            ratio = ""
            if key == "default" and r.get("quality_ratio_linear") is not None:
                ratio = f"{r['quality_ratio_linear']:.3f}, {r['quality_ratio_encoded']:.3f}"
                q_all.append(max(r["quality_ratio_linear"], r["quality_ratio_encoded"]))
            tr = s["wall_s_median"] / r.get("gemm", gemm)["median_s"]
            if key in ("default", "plain"):
                s_all.append(tr)
                m_all.append(s["peak_memory_bytes"])
            label = {"plain": "rsvd, plain k=150"}.get(key, s.get("solver") or key)
            rows.append([
                name, f"{label} ({s['codec']})", str(s["k"]), f"{s['bytes']['payload']:,} B",
                _ratio(r["input"]["raw_bytes"] / s["bytes"]["payload"]),
                _num(lin.get("percent"), ".3f"), _num(enc.get("percent"), ".3f"),
                _num(lin.get("rmse"), ".5f"), _num(lin.get("psnr_db"), ".2f"),
                _num(enc.get("psnr_db"), ".2f"), ratio, f"{s['wall_s_median']:.2f}", f"{tr:.1f}",
                f"{fmt_bytes(s['max_rss_bytes'])} / {fmt_bytes(s['peak_tree_pss_bytes'])}"])
    failed = failed_presets(results)
    tgt = [f"**targets, {group}**", "rsvd", "", "", "", "", "", "", "", "",
           verdict(q_all, TARGETS["quality_ratio"], lambda v: f"{v:.2f}", failed), "",
           verdict(s_all, TARGETS["speed_ratio"], lambda v: f"{v:.1f}", failed),
           verdict(m_all, TARGETS["memory_bytes"], fmt_bytes, failed)]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    return lines + ["| " + " | ".join(row) + " |" for row in rows + [tgt]]


def target_summary(results: dict) -> dict:
    """Worst value and pass/fail per criterion; a preset whose compress failed fails every criterion."""
    failed = failed_presets(results)
    ok = [r for p, r in results.items() if p not in failed]

    def one(vals, limit):
        vals = [v for v in vals if v is not None]
        worst = max(vals) if vals else None
        return {"limit": limit, "worst": worst, "pass": bool(vals) and not failed and worst <= limit}

    tuning, held = split_presets(p for p in results if p not in failed)
    by_split = {f"quality_ratio_{domain}_{name}": one([results[p].get(f"quality_ratio_{domain}") for p in group],
                                                      TARGETS["quality_ratio"])
                for name, group in (("tuning", tuning), ("heldout", held)) for domain in ("linear", "encoded")}
    return {**by_split,
            "quality_ratio_linear": one([r.get("quality_ratio_linear") for r in ok], TARGETS["quality_ratio"]),
            "quality_ratio_encoded": one([r.get("quality_ratio_encoded") for r in ok], TARGETS["quality_ratio"]),
            "speed_ratio": one([r.get("speed_ratio") for r in ok], TARGETS["speed_ratio"]),
            "speed_ratio_plain": one([r.get("plain", {}).get("time_over_gemm") for r in ok], TARGETS["speed_ratio"]),
            "peak_memory_bytes": one([r["default"]["peak_memory_bytes"] for r in ok], TARGETS["memory_bytes"]),
            "failed_presets": failed}


def plot_curves(results: dict, path: Path) -> Path | None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    presets = [p for p, r in results.items() if any("error_curve" in r.get(k, {}) for k in ("paper", "default"))]
    if not presets:
        return None
    fig, axes = plt.subplots(1, len(presets), figsize=(4.2 * len(presets), 3.4), dpi=110, squeeze=False)
    for ax, preset in zip(axes[0], presets):
        for key, style in (("paper", "-"), ("default", "-")):
            s = results[preset].get(key, {})
            if "error_curve" not in s:
                continue
            c = s["error_curve"]
            label = (f"{s.get('solver') or key} ({s['codec']}), {s['bytes']['payload'] / 1e3:.0f} kB")
            ax.plot(c["k"], c["percent"], style, lw=1.4, label=label)
        ax.set_title(preset, fontsize=9)
        ax.set_xlabel("number of basis vectors k")
        ax.set_ylabel("percent error (scene-linear)")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle("error vs k (error_curve.csv: 16 samples spread over the sampling, all texels)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


# -- main --------------------------------------------------------------------------------------
def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--presets", default=",".join(PRESETS),
                   help=f"comma-separated material presets (default {','.join(PRESETS)})")
    p.add_argument("--sampling", default=None, help="sampling preset (default paper; --quick: small)")
    p.add_argument("--size", type=int, default=None, help="texels per side (default 128; --quick: 64)")
    p.add_argument("--repeats", type=int, default=None, help="timed compress runs per solver (default 3; --quick: 1)")
    p.add_argument("--workdir", type=Path, default=OUT / "data",
                   help="where generated datasets are cached and reused (default benchmarks/out/data)")
    p.add_argument("--quick", action="store_true", help="= --sampling small --size 64 --repeats 1 (explicit flags win)")
    p.add_argument("--seed", type=int, default=0, help="synth seed (default 0)")
    p.add_argument("--format", default="png", choices=["png", "tif"],
                   help="input image files: png (default) or tif (uncompressed: ~5x cheaper to decode)")
    p.add_argument("--k", type=int, default=150, help="paper solver's k, and the GEMM basis width (default 150)")
    p.add_argument("--pss-interval", type=float, default=0.2,
                   help="seconds between /proc samples of the compress process tree's PSS (0: off)")
    args = p.parse_args(argv)
    quick = {"sampling": "small", "size": 64, "repeats": 1}
    full = {"sampling": "paper", "size": 128, "repeats": 3}
    for key, val in (quick if args.quick else full).items():
        if getattr(args, key) is None:
            setattr(args, key, val)
    args.presets = [s.strip() for s in args.presets.split(",") if s.strip()]
    unknown = [s for s in args.presets if s not in PRESETS]
    if unknown:
        p.error(f"unknown preset(s) {unknown}; choose from {', '.join(PRESETS)}")
    if args.repeats < 1:
        p.error("--repeats must be at least 1")
    args.workdir = args.workdir.resolve()
    return args


def main(argv=None) -> int:
    args = parse_args(argv)
    from usdbtf.io import open_btf
    from usdbtf.sampling import preset as sampling_preset

    t_start = time.perf_counter()
    stamp = timestamp()
    OUT.mkdir(parents=True, exist_ok=True)
    json_path = OUT / f"compress_{stamp}.json"
    plot_path = OUT / f"compress_{stamp}_error_curves.png"
    cli = cli_command()
    n_samples = len(sampling_preset(args.sampling))
    size = args.size
    raw_bytes = n_samples * size * size * 3
    paper_scale = args.sampling == PAPER_SCALE["sampling"] and size == PAPER_SCALE["size"]
    k_gemm = min(args.k, n_samples)

    say(f"# usdbtf compression benchmark ({stamp})")
    say(f"command: {' '.join([sys.executable, *sys.argv])}")
    say("")
    say("## machine")
    machine = machine_info()
    say(format_machine(machine))
    say("")
    say("## inputs")
    say(f"- sampling '{args.sampling}' = {n_samples} samples, {size}x{size} texels, 8-bit sRGB {args.format.upper()}, synth seed "
        f"{args.seed}; presets {', '.join(args.presets)}")
    say(f"- raw size S*H*W*3 bytes at 8 bit = {n_samples}*{size}*{size}*3 = {raw_bytes:,} B ({fmt_bytes(raw_bytes)});"
        f" compression ratio = raw / payload (payload = basis + coefficient texture files; metadata JSON not counted)")
    say(f"- timed compress runs per solver: {args.repeats} (median quoted); CLI: {' '.join(cli)}")
    if not paper_scale:
        say("- NOTE: not paper scale (= sampling paper, size 128): the targets row is indicative only")

    say("")
    say("## baseline: float32 GEMM in this process")
    gemm = gemm_baseline(n_samples, size * size, k_gemm)
    say(f"- U.T @ X, X float32 {tuple(gemm['shape_x'])} ({fmt_bytes(gemm['x_bytes'])}), U {tuple(gemm['shape_u'])}: "
        f"median {gemm['median_s'] * 1e3:.2f} ms of {GEMM_REPEATS} after 1 warm-up "
        f"(min {gemm['min_s'] * 1e3:.2f}, max {gemm['max_s'] * 1e3:.2f}), {gemm['gflops_per_s']:.1f} GFLOP/s")

    doc = {"benchmark": "compress", "timestamp": stamp, "command": [sys.executable, *sys.argv],
           "options": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
           "paper_scale": paper_scale, "machine": machine,
           "definitions": {
               "percent_error": "100 * sum|orig - recon| / sum(orig) over every sample, texel and channel "
                                "(paper metric); 'linear' in the scene-linear working space, 'encoded' on the "
                                "8-bit sRGB file values / 255 with the reconstruction encoded and rounded to 8 bit",
               "psnr_db": "20 log10(1 / RMSE); peak 1 = diffuse white (linear) or 255 (encoded)",
               "quality_ratio": "default-solver percent error / paper-solver percent error, default solver "
                                "given the paper solver's payload as --max-bytes",
               "speed_ratio": "median wall time of the default-solver compress subprocess (interpreter start, "
                              "PNG decode, fit, projection, encoding, error curve) / median time of one "
                              "float32 U.T @ X in the benchmark process",
               "peak_memory": "max(peak RSS, sampled peak tree PSS) of the compress subprocess, worst over "
                              "repeats; peak RSS = ru_maxrss from wait4 (max over the process and its reaped "
                              "decode workers); tree PSS = sum of Pss over the live process tree, sampled",
               "raw_bytes": "S*H*W*3 (8-bit RGB without any container)",
               "payload_bytes": "btf-compressed.json bytes.payload (basis + coefficient textures)",
               "GB": "1e9 bytes"},
           "targets": TARGETS, "baselines": {"gemm": gemm}, "results": {}}
    results = doc["results"]
    out_root = OUT / "compressed"

    for preset in args.presets:
        say("")
        say(f"## {preset}")
        inp = ensure_dataset(args.workdir, preset, args.sampling, size, args.seed, n_samples, args.format)
        data = Path(inp["folder"])
        inp.update(raw_bytes=raw_bytes, png_bytes=folder_bytes(data), n_samples=n_samples, width=size, height=size)
        warm = warm_page_cache(data)
        inp["page_cache_warmup"] = warm
        say(f"  page cache warm-up (untimed): read {warm['files']} files, {fmt_bytes(warm['bytes'])} in "
            f"{warm['seconds']:.2f} s; PNG input {fmt_bytes(inp['png_bytes'])}")
        r = results[preset] = {"input": inp}
        name = data.name
        # The baseline again, next to this preset's timed runs: a machine shared with other
        # work drifts, and a ratio is only honest when both sides saw the same machine.
        gemm_p = r["gemm"] = gemm_baseline(n_samples, size * size, k_gemm)
        say(f"  GEMM baseline for this preset: median {gemm_p['median_s'] * 1e3:.2f} ms "
            f"(min {gemm_p['min_s'] * 1e3:.2f}, max {gemm_p['max_s'] * 1e3:.2f})")

        say("  paper solver:")
        paper = r["paper"] = run_solver(cli, data, out_root / name / "paper", ["--solver", "paper", "--k", str(args.k)],
                                        args.repeats, args.pss_interval)
        write_json(json_path, doc)
        if "error" in paper:
            continue
        budget = paper["bytes"]["payload"]
        say(f"    -> k {paper['k']}, payload {budget:,} B; budget for the default solver: --max-bytes {budget}")

        say("  default solver:")
        default = r["default"] = run_solver(cli, data, out_root / name / "default", ["--max-bytes", str(budget)],
                                            args.repeats, args.pss_interval)
        write_json(json_path, doc)
        if "error" not in default:
            say(f"    -> k {default['k']}, payload {default['bytes']['payload']:,} B")

        say("  default solver, plain `usdbtf compress IN -o OUT` (k = 150, speed row):")
        plain = r["plain"] = run_solver(cli, data, out_root / name / "plain", [], args.repeats, args.pss_interval)
        if "error" not in plain:
            plain["time_over_gemm"] = plain["wall_s_median"] / gemm_p["median_s"]
            say(f"    -> k {plain['k']}, payload {plain['bytes']['payload']:,} B, {plain['wall_s_median']:.2f} s "
                f"= {plain['time_over_gemm']:.1f} x GEMM")
        write_json(json_path, doc)

        orig = open_btf(data)
        for key, s in (("paper", paper), ("default", default)):
            if "error" in s:
                continue
            s["full_error"] = full_error(orig, Path(s["output"]))
            lin, enc = s["full_error"]["linear"], s["full_error"]["encoded"]
            say(f"  full-data error {key:7s}: {lin['percent']:.3f} % lin, {enc['percent']:.3f} % enc, "
                f"PSNR {lin['psnr_db']:.2f} / {enc['psnr_db']:.2f} dB ({s['full_error']['seconds']:.1f} s)")
            s["compression_ratio_raw"] = raw_bytes / s["bytes"]["payload"]
            s["compression_ratio_png"] = inp["png_bytes"] / s["bytes"]["payload"]
            s["time_over_gemm"] = s["wall_s_median"] / gemm_p["median_s"]
        if "error" in default:
            say("  => default solver FAILED: no ratios for this preset")
            write_json(json_path, doc)
            continue
        r["quality_ratio_linear"] = default["full_error"]["linear"]["percent"] / paper["full_error"]["linear"]["percent"]
        r["quality_ratio_encoded"] = (default["full_error"]["encoded"]["percent"]
                                      / paper["full_error"]["encoded"]["percent"])
        r["speed_ratio"] = default["time_over_gemm"]
        r["paper_over_default_time"] = paper["wall_s_median"] / default["wall_s_median"]
        say(f"  => error ratio rsvd/paper {r['quality_ratio_linear']:.3f} (lin), {r['quality_ratio_encoded']:.3f} (enc);"
            f" compress {default['wall_s_median']:.2f} s = {r['speed_ratio']:.1f} x GEMM; peak memory "
            f"{fmt_bytes(default['peak_memory_bytes'])}")
        write_json(json_path, doc)

    doc["target_summary"] = target_summary(results)
    table = markdown_table(results, gemm)
    doc["table_markdown"] = table
    plot = plot_curves(results, plot_path)
    doc["plot"] = str(plot) if plot else None
    doc["total_seconds"] = time.perf_counter() - t_start
    write_json(json_path, doc)

    cpu = machine["cpu"]
    say("")
    say("## results (markdown for benchmarks/RESULTS.md)")
    say("")
    say(f"### compress, {stamp}: sampling {args.sampling} ({n_samples} samples), {size}x{size}, "
        f"{args.repeats} repeat(s){'' if paper_scale else ' (NOT paper scale)'}")
    say("")
    say(f"`{' '.join(['.venv/bin/python', 'benchmarks/bench_compress.py', *sys.argv[1:]])}`, "
        f"on {cpu.get('model')}, {cpu.get('usable_cpus')} CPUs, {fmt_bytes(machine['memory'].get('total_bytes'))} RAM")
    say("")
    say(format_machine(machine))
    say(f"- GEMM baseline: float32 U.T @ X, X {tuple(gemm['shape_x'])}, U {tuple(gemm['shape_u'])}: median "
        f"{gemm['median_s'] * 1e3:.2f} ms ({gemm['gflops_per_s']:.1f} GFLOP/s)")
    say(f"- raw = S*H*W*3 bytes = {fmt_bytes(raw_bytes)}; payload = basis + coefficient textures; errors over all "
        f"samples and texels; 'compress s' = median wall time of the `usdbtf compress` subprocess "
        f"(PNG decode included, page cache warm); peak RSS = ru_maxrss (max over the process and its decode "
        f"workers), tree PSS = sampled sum over the process tree")
    say("")
    say(table)
    say("")
    tsum = doc["target_summary"]
    if tsum["failed_presets"]:
        say(f"FAILED presets: {', '.join(tsum['failed_presets'])}")
    say(f"JSON:  {json_path.relative_to(REPO) if json_path.is_relative_to(REPO) else json_path}")
    if plot:
        say(f"plot:  {plot.relative_to(REPO) if plot.is_relative_to(REPO) else plot}")
    say(f"total: {doc['total_seconds']:.1f} s")
    return 1 if tsum["failed_presets"] else 0


if __name__ == "__main__":
    sys.exit(main())
