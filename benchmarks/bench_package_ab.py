#!/usr/bin/env python
"""``usdbtf package`` time, peak memory and asset bytes: older trees against the working tree
(issues 39 and 40, "package time and peak memory ... before/after in one run").

Inputs (cached under ``--workdir``, made by the working tree's ``usdbtf``):

swatch   the paper-scale swatch: ``synth metal_flakes --sampling paper`` (90 x 120 = 10,800
         images of 128²), ``compress --max-bytes B`` (B = ``--max-bytes``, the paper's bytes);
sphere   a quilted icosphere of ``--radius`` metres (default 0.2): the route of
         benchmarks/bench_package_quilt.py (pebbles 64², ``--k 48 --codec png``, ``unwrap --btf``,
         ``quilt --atlas``), packaged with ``--mesh``.

Each side packages the *same* compressed folders.  A side "before" is an older commit's
``pipeline/`` (``git archive REV`` into a temporary folder, on PYTHONPATH, as
benchmarks/ab_compress.sh does), run by the same virtualenv; "after" is the working tree.
Runs are interleaved (each repeat: every input, every side in turn), each a child process
under ``nice``; wall time and peak RSS are the child's (usdbtf.bench.measure.run_measured);
asset bytes are every file the asset folder holds, full lod the files its full lod loads
(``usd.asset.package.shipped_bytes``, the budgeted bytes), and per file kind
(bench_asset_bytes.kind_of) the thumbnail and fallback maps.  Medians of ``--repeats``.
``--swatch`` takes several compressed folders (e.g. the paper-scale issue-16 assets' folders).

Usage (repository root)::

    nice .venv/bin/python benchmarks/bench_package_ab.py --before d4d391a 9dedc99 --repeats 3
    nice .venv/bin/python benchmarks/bench_package_ab.py --before HEAD --only swatch --repeats 1 \
        --swatch /tmp/velvet-128-asset_budget-3416295 /tmp/metal_flakes-128-asset_budget-3418164
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from common import OUT, REPO, cli_command, format_machine, machine_info, median, run_measured, timestamp, write_json

sys.path.insert(0, str(Path(__file__).parent))
from bench_package_quilt import inputs as quilt_inputs, run_cli  # noqa: E402  (the same sphere route)
from bench_asset_bytes import asset_breakdown  # noqa: E402  (file kinds)

PAPER_BYTES = 3418156


def say(msg: str = "") -> None:
    print(msg, flush=True)


def swatch_input(workdir: Path, cli, max_bytes: int) -> Path:
    """The compressed paper-scale metal_flakes swatch (module docstring)."""
    raw, comp = workdir / "metal_flakes_paper128", workdir / f"metal_flakes_paper128_b{max_bytes}"
    if not (comp / "btf-compressed.json").is_file():
        if not raw.is_dir():
            run_cli(cli, "synth", "metal_flakes", "--sampling", "paper", "--size", 128, "-o", raw, "-q")
        run_cli(cli, "compress", raw, "-o", comp, "--max-bytes", max_bytes, "-q")
    return comp


def tree_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def package(side_pipeline: Path | None, source: Path, out: Path, extra: list) -> dict:
    """One ``nice usdbtf package`` in a child: wall s, peak RSS bytes, asset bytes."""
    if out.parent.exists():
        shutil.rmtree(out.parent)
    out.parent.mkdir(parents=True)
    env = dict(os.environ)
    if side_pipeline is not None:
        env["PYTHONPATH"] = str(side_pipeline)
        # Its own schema plugin (this process's usdbtf import set the working tree's in the environment).
        env["PXR_PLUGINPATH_NAME"] = str(Path(side_pipeline).parent / "plugin")
    r = run_measured(["nice", sys.executable, "-m", "usdbtf.cli", "package", str(source), "-o", str(out), "-q",
                      *map(str, extra)], env=env, pss_interval=0)
    if r.returncode != 0:
        raise SystemExit(f"package {source} ({side_pipeline or 'working tree'}) failed:\n{r.stderr[-3000:]}")
    from usdbtf.usd.asset.package import FULL_LOD, shipped_bytes

    kinds = asset_breakdown(out.parent)
    return {"wall_s": r.wall_s, "cpu_s": r.user_s + r.sys_s, "max_rss_bytes": r.max_rss_bytes,
            "asset_bytes": tree_bytes(out.parent), "asset_digest": tree_digest(out.parent),
            "full_lod_bytes": shipped_bytes(out)[FULL_LOD], "thumbnail_bytes": kinds.get("thumbnail", 0),
            "fallback_bytes": kinds.get("fallback", 0)}


def tree_digest(folder: Path) -> str:
    """sha256 over every file's relative path and bytes: equal digests, byte-identical assets."""
    import hashlib
    h = hashlib.sha256()
    for f in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(str(f.relative_to(folder)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()[:16]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--before", nargs="+", default=["d4d391a"], help="older commits (each a side)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--radius", type=float, default=0.2)
    p.add_argument("--max-bytes", type=int, default=PAPER_BYTES)
    p.add_argument("--workdir", type=Path, default=OUT / "data" / "package_ab")
    p.add_argument("--only", choices=["swatch", "sphere"], help="one input only")
    p.add_argument("--swatch", type=Path, nargs="+", help="existing compressed swatch folders (instead of synth + "
                   "compress), each an input")
    args = p.parse_args(argv)
    os.environ.setdefault("OCIO", "ocio://default")
    say(f"# bench_package_ab\n{format_machine(machine_info())}")
    head = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "pipeline"], capture_output=True,
                           text=True).stdout.strip()
    cli = cli_command()
    jobs = {}
    if args.only in (None, "swatch"):
        for folder in args.swatch or [swatch_input(args.workdir, cli, args.max_bytes)]:
            jobs["swatch" if not args.swatch or len(args.swatch) == 1 else f"swatch {folder.name}"] = (folder, [])
    if args.only in (None, "sphere"):
        q = quilt_inputs(args.workdir / "quilt", [args.radius], cli)["quilts"][args.radius]
        jobs["sphere"] = (q[1], ["--mesh", q[0]])
        say(f"- sphere r {args.radius:g} m: atlas {q[2][0]}x{q[2][1]}")
    say(f"- inputs: {', '.join(f'{k} = {v[0]}' for k, v in jobs.items())}; max-bytes {args.max_bytes}")
    tmp = Path(tempfile.mkdtemp(prefix="package_ab_"))
    sides = {}
    try:
        for rev in args.before:
            full = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", rev], capture_output=True,
                                  text=True, check=True).stdout.strip()
            tree = tmp / full
            tree.mkdir()
            archive = subprocess.run(["git", "-C", str(REPO), "archive", rev, "pipeline", "plugin"],
                                     capture_output=True, check=True).stdout
            subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
            sides[f"before {full}"] = tree / "pipeline"
        sides[f"after {head}{' + working tree' if dirty else ''}"] = None
        say(f"- sides: {', '.join(sides)}; {args.repeats} repeats, interleaved, each under nice")
        runs = {(job, side): [] for job in jobs for side in sides}
        for rep in range(args.repeats):
            for job, (source, extra) in jobs.items():
                for side, pipeline in sides.items():
                    r = package(pipeline, source, tmp / "out" / job / "asset.usda", extra)
                    runs[job, side].append(r)
                    say(f"  repeat {rep + 1} {job} {side}: {r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s, "
                        f"{r['max_rss_bytes'] / 1e9:.2f} GB, {r['asset_bytes']:,} B (full lod "
                        f"{r['full_lod_bytes']:,}, thumbnail {r['thumbnail_bytes']:,}, fallback maps "
                        f"{r['fallback_bytes']:,}), digest {r['asset_digest']}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    lines = ["| input | side | package s (median) | CPU s (median) | peak RSS GB (median) | asset bytes | "
             "full lod bytes | thumbnail | fallback maps | s vs first side | CPU vs first side | RSS vs first side |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for job in jobs:
        base = None
        for side in sides:
            rs = runs[job, side]
            wall, rss = median(r["wall_s"] for r in rs), median(r["max_rss_bytes"] for r in rs)
            cpu = median(r["cpu_s"] for r in rs)
            base = base or (wall, rss, cpu)
            last = rs[-1]
            lines.append(f"| {job} | {side} | {wall:.1f} | {cpu:.1f} | {rss / 1e9:.2f} | {last['asset_bytes']:,} | "
                         f"{last['full_lod_bytes']:,} | {last['thumbnail_bytes']:,} | {last['fallback_bytes']:,} | "
                         f"{wall / base[0]:.2f} | {cpu / base[2]:.2f} | {rss / base[1]:.2f} |")
    say("\n" + "\n".join(lines))
    path = write_json(OUT / f"package_ab_{timestamp()}.json",
                      {"args": {k: str(v) for k, v in vars(args).items()}, "sides": list(sides),
                       "runs": {f"{j} | {s}": v for (j, s), v in runs.items()}})
    say(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
