#!/usr/bin/env python
"""Scale benchmark (issue 17): compress against its floor, real sizes in bounded memory,
time against samples x texels, and 1 vs 2 Dask workers.

Every number is measured in this run, on this machine (printed first, with its load):

floor      per input: a decode-only pass (every image file decoded by OpenImageIO, as
           compress's loader reads them: ``FileBTF.read_one`` in ``--workers`` forked
           processes, page cache warm, values discarded) + one float32 GEMM of the data with
           a 150-column basis (``U.T @ X``, X = S x 3P; past 2 GB of X the same FLOPs over
           column blocks of X, one buffer reused).  Both in this process, no interpreter start.
compress   the wall time of ``usdbtf compress IN -o OUT`` (plain: k = 150, default options;
           interpreter start, imports and the manifest read included), its peak RSS and the
           per-process peaks of its tree.
ratio      compress wall / (decode + GEMM), per round (a floor measured right before each
           compress run); the median of the rounds is quoted.
scaling    compress wall at subsets (the first V views, all lights) of the UBO-sized inputs at
           two sizes; the exponent is the least-squares slope of log(time) on log(S x P).
workers    ``--dask local:1`` and ``--dask local:2`` at the UBO size: wall time and each
           worker process's peak RSS (sampled every 0.2 s).

Inputs (cached under benchmarks/out/data): the paper-scale pebbles PNG set (``usdbtf synth
pebbles --sampling paper --size 128``) and UBO2014-sized sets of 151 x 151 samples made by
``scale_data.py`` (rendered at half the side with full tracing quality, tiled 2 x 2).

    .venv/bin/python benchmarks/bench_scale.py --sections floor --inputs paper,ubo400
    .venv/bin/python benchmarks/bench_scale.py --sections floor --inputs paper:metal_flakes \
        --modes '--k 150;--max-bytes 3418156;--target-error 11.396'
    .venv/bin/python benchmarks/bench_scale.py --sections scaling,workers

Writes benchmarks/out/scale_<stamp>.json and prints markdown for RESULTS.md.
"""
from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import resource
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import OUT, cli_command, fmt_bytes, format_machine, machine_info, median, run_measured, timestamp, \
    warm_page_cache, write_json
from scale_data import ensure_tiled

GEMM_K = 150
GEMM_MAX_BYTES = 2e9
_STATE: dict = {}


def say(msg: str = "") -> None:
    print(msg, flush=True)


# -- inputs ---------------------------------------------------------------------------------------
def input_folder(name: str, workdir: Path) -> tuple[Path, str]:
    """(folder, how it was made) for 'paper' (pebbles), 'paper:PRESET' or 'uboNNN'."""
    if name.split(":")[0] == "paper":
        from usdbtf.bench.datasets import ensure_dataset

        preset = name.split(":")[1] if ":" in name else "pebbles"
        info = ensure_dataset(workdir, preset, "paper", 128, 0, "png", say=say)
        return Path(info["folder"]), f"usdbtf synth {preset} --sampling paper --size 128 --seed 0 (PNG)"
    size = int(name[3:])
    info = ensure_tiled(workdir, "pebbles", "ubo151", size, 0, say=say)
    return Path(info["folder"]), info["how"]


# -- floor ----------------------------------------------------------------------------------------
def _init(btf):
    import OpenImageIO as oiio

    oiio.attribute("threads", 1)
    _STATE["btf"] = btf


def _decode(bounds):
    btf = _STATE["btf"]
    for i in range(*bounds):
        btf.read_one(i)
    return bounds[1] - bounds[0]


def _cpu() -> float:
    """CPU seconds of this process and its reaped children (user + system)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def decode_pass(btf, workers: int) -> tuple[float, float]:
    """(wall, CPU) seconds to decode every image file once in ``workers`` forked processes."""
    bounds = np.linspace(0, btf.n_samples, workers * 8 + 1).astype(int)
    t, c = time.perf_counter(), _cpu()
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork"), initializer=_init,
                             initargs=(btf,)) as pool:
        assert sum(pool.map(_decode, list(zip(bounds[:-1], bounds[1:])))) == btf.n_samples
    return time.perf_counter() - t, _cpu() - c


def gemm_pass(n_samples: int, n_pixels: int, k: int = GEMM_K) -> tuple[float, dict]:
    """Seconds for the FLOPs of one float32 U.T @ X, X (S, 3P): one GEMM when X fits 2 GB,
    else column blocks of X (one random buffer reused); BLAS on all its threads."""
    rng = np.random.default_rng(0)
    cols = 3 * n_pixels
    block = min(cols, max(1024, int(GEMM_MAX_BYTES // (4 * n_samples)) // 1024 * 1024))
    x = rng.random((n_samples, block), dtype=np.float32)
    u = rng.standard_normal((n_samples, k), dtype=np.float32)
    (u.T @ x[:, :min(block, 4096)])                 # warm-up (BLAS threads, page faults)
    t, c = time.perf_counter(), _cpu()
    done = 0
    while done < cols:
        w = min(block, cols - done)
        u.T @ (x if w == block else x[:, :w])
        done += w
    seconds = time.perf_counter() - t
    return seconds, {"x_block": [n_samples, block], "blocks": math.ceil(cols / block), "cpu_s": _cpu() - c,
                     "gflops_per_s": 2.0 * n_samples * k * cols / seconds / 1e9}


# -- runs -----------------------------------------------------------------------------------------
def compress_run(cli, folder: Path, out: Path, extra=()) -> dict:
    cmd = [*cli, "compress", str(folder), "-o", str(out), *extra]
    r = run_measured(cmd, pss_interval=0.2)
    res = {"command": " ".join(cmd[:1] + cmd[1:]), "returncode": r.returncode, "wall_s": r.wall_s,
           "cpu_s": r.user_s + r.sys_s, "max_rss_bytes": r.max_rss_bytes, "peak_tree_pss_bytes": r.peak_tree_pss_bytes,
           "processes": r.extra.get("peak_rss_by_process", []), "stderr_tail": r.stderr[-1500:]}
    if r.returncode:
        say(f"    FAILED ({r.returncode}): {r.stderr.strip().splitlines()[-1:]}")
    return res


def _stage_line(stderr: str) -> str:
    lines = [x for x in stderr.splitlines() if x.startswith("k = ")]
    return lines[-1] if lines else ""


def section_floor(inputs, cli, args, doc):
    from usdbtf.io import open_btf

    rows = []
    for name in inputs:
        folder, how = input_folder(name, args.workdir)
        btf = open_btf(folder)
        S, P = btf.n_samples, btf.n_pixels
        say(f"\n### floor ratio: {name} ({S} samples of {btf.width}^2; {how})")
        warm = warm_page_cache(folder)
        say(f"  page cache warm-up: {warm['files']} files, {fmt_bytes(warm['bytes'])} in {warm['seconds']:.1f} s")
        modes = [m.split() for m in args.modes.split(";") if m.strip()]
        rounds = {" ".join(m): [] for m in modes}
        for rnd in range(args.repeats):
            for mode in modes:
                # A floor right before each compress run (the machine is shared: load drifts).
                load = os.getloadavg()[0]
                dec, dec_cpu = decode_pass(btf, args.workers)
                gem, ginfo = gemm_pass(S, P)
                run = compress_run(cli, folder, OUT / "scale" / f"{name.replace(':', '-')}-plain",
                                   ["--workers", str(args.workers), *mode])
                ok = not run["returncode"]
                ratio = run["wall_s"] / (dec + gem) if ok else float("nan")
                ratio_cpu = run["cpu_s"] / (dec_cpu + ginfo["cpu_s"]) if ok else float("nan")
                rounds[" ".join(mode)].append({"load1": load, "decode_s": dec, "decode_cpu_s": dec_cpu, "gemm_s": gem,
                                               "gemm": ginfo, "compress": run, "ratio": ratio, "ratio_cpu": ratio_cpu})
                say(f"  round {rnd + 1}, {' '.join(mode)}: load {load:.1f}; decode {dec:.2f} s + GEMM {gem:.2f} s = "
                    f"floor {dec + gem:.2f} s (CPU {dec_cpu:.1f} + {ginfo['cpu_s']:.1f} s); compress "
                    f"{run['wall_s']:.2f} s (CPU {run['cpu_s']:.1f} s, peak RSS {fmt_bytes(run['max_rss_bytes'])}) "
                    f"-> ratio {ratio:.2f} (CPU {ratio_cpu:.2f})")
                say(f"    {_stage_line(run['stderr_tail'])}")
                write_json(args.json, doc)
        for mode, rs in rounds.items():
            rows.append({"input": name, "mode": mode, "how": how, "samples": S, "texels": P,
                         "stored_bytes": S * P * 3, "decode_s": median(r["decode_s"] for r in rs),
                         "gemm_s": median(r["gemm_s"] for r in rs),
                         "compress_s": median(r["compress"]["wall_s"] for r in rs),
                         "ratio_median": median(r["ratio"] for r in rs),
                         "ratio_cpu_median": median(r["ratio_cpu"] for r in rs),
                         "load1_median": median(r["load1"] for r in rs),
                         "peak_rss_bytes": max(r["compress"]["max_rss_bytes"] for r in rs),
                         "steps": _stage_line(rs[-1]["compress"]["stderr_tail"]), "rounds": rs})
        doc["floor"] = rows
        write_json(args.json, doc)
    say("\n| input | mode | decode s | GEMM s | compress s | wall ratio (median; rounds) | CPU ratio (median) | load "
        "| peak RSS | compress steps (last round) |\n|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        steps = r["steps"].split("(", 1)[-1].rstrip(")") if r["steps"] else ""
        say(f"| {r['input']} | `{r['mode']}` | {r['decode_s']:.2f} | "
            f"{r['gemm_s']:.2f} | {r['compress_s']:.2f} | **{r['ratio_median']:.2f}** "
            f"({', '.join(format(x['ratio'], '.2f') for x in r['rounds'])}) | {r['ratio_cpu_median']:.2f} | "
            f"{r['load1_median']:.1f} | {fmt_bytes(r['peak_rss_bytes'])} | {steps} |")


def section_scaling(cli, args, doc):
    from usdbtf.bench.datasets import first_views, write_subset
    from usdbtf.sampling import preset

    pts = []
    sub_root = OUT / "scale" / "subsets"
    for size in args.scaling_sizes:
        folder, how = input_folder(f"ubo{size}", args.workdir)
        for views in args.scaling_views:
            idx = first_views(preset("ubo151"), views)
            sub = write_subset(folder, idx, sub_root / f"ubo{size}-v{views}")
            run = compress_run(cli, sub, OUT / "scale" / f"scaling-{size}-{views}")
            pts.append({"size": size, "views": views, "samples": len(idx), "texels": size * size,
                        "wall_s": run["wall_s"], "max_rss_bytes": run["max_rss_bytes"], "load1": os.getloadavg()[0],
                        "stages": _stage_line(run["stderr_tail"])})
            say(f"  {size}^2, {views} views ({len(idx)} samples): {run['wall_s']:.1f} s, peak RSS "
                f"{fmt_bytes(run['max_rss_bytes'])}")
            doc["scaling"] = {"points": pts}
            write_json(args.json, doc)
    x = np.log([p["samples"] * p["texels"] for p in pts])
    y = np.log([p["wall_s"] for p in pts])
    slope, icpt = np.polyfit(x, y, 1)
    doc["scaling"].update(exponent=float(slope), fit="log(wall_s) = a log(S P) + b, least squares")
    write_json(args.json, doc)
    say("\n| texels | views | samples | S x P | wall s | peak RSS |\n|---|---|---|---|---|---|")
    for p in pts:
        say(f"| {p['size']}^2 | {p['views']} | {p['samples']} | {p['samples'] * p['texels']:.3g} | {p['wall_s']:.1f} | "
            f"{fmt_bytes(p['max_rss_bytes'])} |")
    say(f"\nexponent of wall time against samples x texels: **{slope:.2f}**")


def section_workers(cli, args, doc):
    rows = []
    folder, how = input_folder(f"ubo{args.workers_size}", args.workdir)
    for n in (1, 2):
        run = compress_run(cli, folder, OUT / "scale" / f"dask-{n}", ["--dask", f"local:{n}"])
        workers = [p for p in run["processes"] if "spawn_main" in p["cmd"]]
        main = [p for p in run["processes"] if " compress " in f" {p['cmd']} "]
        rows.append({"workers": n, "wall_s": run["wall_s"], "cpu_s": run["cpu_s"],
                     "worker_peak_rss_bytes": [w["peak_rss_bytes"] for w in workers],
                     "client_peak_rss_bytes": max((p["peak_rss_bytes"] for p in main), default=None),
                     "returncode": run["returncode"], "stages": _stage_line(run["stderr_tail"]),
                     "load1": os.getloadavg()[0]})
        say(f"  local:{n}: {run['wall_s']:.1f} s; worker peak RSS "
            f"{', '.join(fmt_bytes(w['peak_rss_bytes']) for w in workers)}; client "
            f"{fmt_bytes(rows[-1]['client_peak_rss_bytes'])}")
        doc["workers"] = {"input": how, "rows": rows}
        write_json(args.json, doc)
    say("\n| workers | wall s | each worker's peak RSS | client peak RSS |\n|---|---|---|---|")
    for r in rows:
        say(f"| {r['workers']} | {r['wall_s']:.1f} | {', '.join(fmt_bytes(b) for b in r['worker_peak_rss_bytes'])} | "
            f"{fmt_bytes(r['client_peak_rss_bytes'])} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sections", default="floor,scaling,workers")
    ap.add_argument("--inputs", default="paper,ubo400", help="floor section: paper and/or uboNNN (e.g. ubo256)")
    ap.add_argument("--repeats", type=int, default=3, help="floor rounds per input (median quoted)")
    ap.add_argument("--modes", default="--k 150", help="floor section: compress options per mode, ';'-separated "
                    "(e.g. '--k 150;--max-bytes 3418156;--target-error 11.4'); a floor is measured before each run")
    ap.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)), help="decode processes")
    ap.add_argument("--scaling-sizes", default="256,400")
    ap.add_argument("--scaling-views", default="38,76,151")
    ap.add_argument("--workers-size", type=int, default=400)
    ap.add_argument("--workdir", type=Path, default=OUT / "data")
    args = ap.parse_args(argv)
    args.scaling_sizes = [int(x) for x in args.scaling_sizes.split(",")]
    args.scaling_views = [int(x) for x in args.scaling_views.split(",")]
    stamp = timestamp()
    args.json = OUT / f"scale_{stamp}.json"
    cli = cli_command()
    machine = machine_info()
    say(f"# usdbtf scale benchmark ({stamp})\ncommand: {' '.join([sys.executable, *sys.argv])}\n")
    say("## machine (shared with other sessions: read medians and ratios)")
    say(format_machine(machine))
    doc = {"benchmark": "scale", "timestamp": stamp, "command": [sys.executable, *sys.argv], "machine": machine,
           "options": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}}
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    if "floor" in sections:
        section_floor([s.strip() for s in args.inputs.split(",") if s.strip()], cli, args, doc)
    if "scaling" in sections:
        say("\n### scaling: compress wall time against samples x texels")
        section_scaling(cli, args, doc)
    if "workers" in sections:
        say(f"\n### 1 vs 2 Dask workers (--dask local:N), {args.workers_size}^2 UBO-sized input")
        section_workers(cli, args, doc)
    say(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
