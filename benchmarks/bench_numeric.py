#!/usr/bin/env python
"""Numeric platform benchmark (issue 24): the same bytes with any BLAS thread count and kernel,
and what pinning the reference platform costs.

Every run is a fresh ``usdbtf compress IN -o OUT --k K`` process (OpenBLAS takes its kernel from
``OPENBLAS_CORETYPE`` when it loads, numpy its SIMD level from ``NPY_DISABLE_CPU_FEATURES``):

bytes      per (configuration, BLAS threads): the SHA-256 of every file of the output folder,
           the metadata's ``provenance.numeric`` left out (it names the platform), and the
           platform the run reports.  Configurations: ``pinned`` (no variable set: what
           ``import usdbtf`` pins, x86-64-v3), each OpenBLAS kernel this CPU runs
           (``OPENBLAS_CORETYPE=K``, numpy still pinned), and ``native``
           (``USDBTF_NUMERIC=native``: the libraries' own choices).
cost       ``pinned`` against ``native``, in turn (A B A B ...), ``--repeats`` pairs: wall and
           CPU seconds, the ratio of each pair, medians quoted (the machine is shared).

Inputs (cached under benchmarks/out/data): ``small`` = ``usdbtf synth pebbles --sampling small
--size 64 --seed 1`` at k 48, ``paper`` = ``--sampling paper --size 128`` (90 x 120 samples, 8-bit
PNG) at k 150.

    .venv/bin/python benchmarks/bench_numeric.py                       # both inputs
    .venv/bin/python benchmarks/bench_numeric.py --inputs paper --repeats 3

Prints markdown for RESULTS.md and writes benchmarks/out/numeric_<stamp>.json.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from common import OUT, cli_command, format_machine, machine_info, median, run_measured, timestamp, write_json

from usdbtf import numeric
from usdbtf.compress.format import digest_without_platform

INPUTS = {"small": ("small", 64, 48), "paper": ("paper", 128, 150)}
#: OpenBLAS kernels emulated (Zen runs Haswell's code: left out); those the CPU lacks are skipped.
KERNELS = [k for k in numeric.OPENBLAS_KERNEL_FLAGS if k != "Zen"]
PLATFORM_VARS = (*numeric.PLATFORM_VARIABLES, numeric.OPT_OUT, "OPENBLAS_NUM_THREADS")


def say(msg: str = "") -> None:
    print(msg, flush=True)


def input_folder(name: str) -> Path:
    sampling, size, _ = INPUTS[name]
    folder = OUT / "data" / f"numeric_{name}"
    if not (folder / "btf.json").is_file():
        subprocess.run([*cli_command(), "synth", "-q", "pebbles", "-o", str(folder), "--sampling", sampling,
                        "--size", str(size), "--seed", "1"], check=True)
    return folder


def run_env(config: str, threads: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in PLATFORM_VARS}
    env["OPENBLAS_NUM_THREADS"] = str(threads)
    if config == "native":
        env["USDBTF_NUMERIC"] = "native"
    elif config != "pinned":
        env["OPENBLAS_CORETYPE"] = config
    return env


def compress(src: Path, out: Path, k: int, config: str, threads: int) -> dict:
    res = run_measured([*cli_command(), "compress", "-q", str(src), "-o", str(out), "--k", str(k)],
                       env=run_env(config, threads), pss_interval=0)
    if res.returncode:
        raise SystemExit(f"compress failed ({config}, {threads} threads): {res.stderr.strip()[-400:]}")
    d, platform = digest_without_platform(out)
    return {"config": config, "threads": threads, "wall_s": res.wall_s, "cpu_s": res.user_s + res.sys_s,
            "peak_rss_bytes": res.max_rss_bytes, "digest": d, "platform": platform}


def bytes_section(name: str, work: Path, threads_list: list[int]) -> list[dict]:
    src = input_folder(name)
    _, _, k = INPUTS[name]
    runnable = numeric.runnable_kernels()
    configs = ["pinned"] + [kern for kern in KERNELS if kern in runnable] + ["native"]
    skipped = [kern for kern in KERNELS if kern not in runnable]
    rows = []
    for config in configs:
        for threads in threads_list:
            rows.append(compress(src, work / f"{name}-{config}-{threads}", k, config, threads))
            r = rows[-1]
            say(f"  {name} {config:<11} {threads} thr  {r['wall_s']:7.2f} s  {r['digest'][:12]}  "
                f"{numeric.platform_label(r['platform'])}")
    say()
    say(f"#### Bytes: `{name}` (k {k}); kernels this CPU cannot run: {', '.join(skipped) or 'none'}")
    say()
    say("| configuration | BLAS threads | platform (BLAS kernel, numpy SIMD) | digest | same as pinned |")
    say("|---|---|---|---|---|")
    pinned = next(r["digest"] for r in rows if r["config"] == "pinned")
    for r in rows:
        p = r["platform"]
        say(f"| {r['config']} | {r['threads']} | {p.get('blas_kernel')}, {p.get('numpy_simd')} | "
            f"`{r['digest'][:12]}` | {'yes' if r['digest'] == pinned else 'no'} |")
    by_platform: dict = {}
    for r in rows:
        by_platform.setdefault(json.dumps(r["platform"], sort_keys=True), set()).add(r["digest"])
    ok = all(len(v) == 1 for v in by_platform.values())
    say()
    say(f"{len(by_platform)} platform(s), {len({r['digest'] for r in rows})} distinct output(s); "
        f"{'one output per platform (thread counts change no byte)' if ok else 'A PLATFORM GAVE TWO OUTPUTS'}")
    return rows


def cost_section(name: str, work: Path, repeats: int) -> list[dict]:
    src = input_folder(name)
    _, _, k = INPUTS[name]
    compress(src, work / f"cost-{name}-warm", k, "pinned", 2)          # warm-up: page cache, imports
    pairs = []
    for i in range(repeats):
        a = compress(src, work / f"cost-{name}-a", k, "pinned", 2)
        b = compress(src, work / f"cost-{name}-b", k, "native", 2)
        pairs.append({"pinned": a, "native": b})
        say(f"  {name} pair {i + 1}: pinned {a['wall_s']:.2f} s ({a['cpu_s']:.2f} cpu), "
            f"native {b['wall_s']:.2f} s ({b['cpu_s']:.2f} cpu)")
    say()
    say(f"#### Cost of the pin: `{name}` (k {k}), {repeats} pairs, medians")
    say()
    say("| | pinned (x86-64-v3) | native | pinned / native (median of pairs) |")
    say("|---|---|---|---|")
    for key, label in (("wall_s", "wall s"), ("cpu_s", "CPU s"), ("peak_rss_bytes", "peak RSS MB")):
        scale = 1e-6 if key == "peak_rss_bytes" else 1
        a = median(p["pinned"][key] * scale for p in pairs)
        b = median(p["native"][key] * scale for p in pairs)
        ratio = median(p["pinned"][key] / p["native"][key] for p in pairs)
        say(f"| {label} | {a:.2f} | {b:.2f} | {ratio:.3f} |")
    return pairs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--inputs", default="small,paper", help="comma list of small, paper")
    ap.add_argument("--threads", default="1,2,4", help="BLAS thread counts for the bytes section")
    ap.add_argument("--repeats", type=int, default=3, help="pinned/native pairs for the cost section (0: none)")
    args = ap.parse_args()
    names = [n for n in args.inputs.split(",") if n]
    threads = [int(t) for t in args.threads.split(",")]
    info = machine_info()
    say("### Numeric platform (issue 24)")
    say()
    say(format_machine(info))
    say(f"- command: `{' '.join([Path(sys.executable).name, *sys.argv])}`")
    say()
    result = {"machine": info, "bytes": {}, "cost": {}}
    work = Path(tempfile.mkdtemp(prefix="usdbtf-numeric-"))
    try:
        for name in names:
            result["bytes"][name] = bytes_section(name, work, threads)
            say()
        for name in names if args.repeats > 0 else []:
            result["cost"][name] = cost_section(name, work, args.repeats)
            say()
    finally:
        shutil.rmtree(work, ignore_errors=True)
    path = OUT / f"numeric_{timestamp()}.json"
    write_json(path, result)
    say(f"(raw: {path.relative_to(OUT.parent.parent) if OUT.parent.parent in path.parents else path})")


if __name__ == "__main__":
    main()
