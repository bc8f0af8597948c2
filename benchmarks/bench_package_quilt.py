#!/usr/bin/env python
"""``usdbtf package --mesh`` of quilted atlases against atlas size (issue 32).

The manual mesh route of docs/meshes-quilting-and-rendering.md at several sizes: a 5 cm swatch (pebbles, sampling "small",
64², ``--k 48 --codec png``); icospheres (4 subdivisions) of radius ``--radii`` metres,
``usdbtf unwrap --btf`` (atlases at the swatch's texel density), ``usdbtf quilt --atlas``;
then ``usdbtf package Q --mesh mesh.usda``.  Inputs are cached under ``--workdir``.

Measured in the same run, each a subprocess (wall time, peak RSS; median of ``--repeats``,
interleaved: each repeat runs the swatch, then every atlas and its write baseline, and the
ratio is the median of the repeats' ratios, each from runs minutes apart at most):

swatch       ``package`` of the source swatch (the fixed cost every asset pays);
quilt        ``package Q --mesh`` of each quilted atlas, with its steps timed (read the folder,
             the quilt's distinct source texels, the fallback fit, the fallback maps encoded, the
             GPU tables and packs, the thumbnail, the texture folder written, validation) --
             the command's own ``usdbtf.cli.main`` run in a child with each step's function
             wrapped by a timer;
write        the time to write the atlas's textures (baseline): every atlas-sized file the asset
             holds (the GPU pages: atlas-sized packs as tiles), decoded once, then encoded again
             with the writer and settings ``package`` uses (GPU pages PNG level 6, fallback maps
             PNG level 9) or, for the BTF's
             coefficient textures (which ``package`` copies), their bytes written; in a child,
             one file after another ("serial") and a file per thread on every CPU, as
             ``package`` encodes them ("threaded");
per-texel    the path before issue 32, on atlases up to ``--per-texel-max`` texels: the same
             quilt folder without ``quilt_positions.exr`` (an older quilt), which ``package``
             fits and packs texel by texel; its fit seconds per texel give the estimate printed
             for the larger atlases (an extrapolation, marked as such);
tx           with ``--tx``: the largest atlas packaged with ``--texture-format tx`` once (maketx of
             every texture);
before       with ``--before PIPELINE``: the atlases up to ``--before-max`` texels packaged once by
             an older usdbtf (its ``pipeline/`` folder on PYTHONPATH), e.g. the commit before
             issue 32.

Must show (issue 32): the largest (the 0.3 m sphere) <= 2 x (swatch + write) in time and
<= 1.5 GB peak RSS.

Usage (repository root)::

    .venv/bin/python benchmarks/bench_package_quilt.py --tx          # radii 0.05 0.1 0.2 0.3, ~15 min on 2 cores
    .venv/bin/python benchmarks/bench_package_quilt.py --quick       # radii 0.03 0.06, one repeat (a check)

Writes benchmarks/out/package_quilt_<timestamp>.json and prints a markdown block for RESULTS.md.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

from common import OUT, cli_command, format_machine, machine_info, median, run_measured, timestamp, write_json

TARGET_RATIO, TARGET_RSS = 2.0, 1.5e9
#: The steps a child times: (module, attribute, label); module "TextureSet" is the class.
STEPS = (("usdbtf.usd.asset.package", "read_input", "read"), ("usdbtf.quilt.texels", "quilt_texels", "source texels"),
         ("usdbtf.svbrdf", "fit_svbrdf", "fallback fit"), ("usdbtf.usd.asset.fallback", "add_maps", "fallback maps"),
         ("usdbtf.usd.asset.storm", "add_gpu_textures", "GPU tables+pages"),
         ("usdbtf.usd.asset.thumbnail", "thumbnail_jpeg", "thumbnail"),
         ("usdbtf.usd.asset.textures:TextureSet", "write", "texture folder"),
         ("usdbtf.usd.asset.package", "_check_published", "validation"))
#: Writer settings of the atlas-sized textures ``package`` encodes, by folder (see usd.asset.storm, usd.asset.fallback).
ENCODE = {"gpu": {"png:compressionLevel": 6, "oiio:UnassociatedAlpha": 1}, "fallback": {"png:compressionLevel": 9}}


def say(msg: str = "") -> None:
    print(msg, flush=True)


# ------------------------------------------------------------------ children
def child_steps(out_json: str, argv: list) -> int:
    """Run ``usdbtf`` ``argv`` in this process with STEPS timed; write {label: seconds} to ``out_json``."""
    import importlib

    times: dict = {}

    def timed(fn, label):
        def run(*a, **kw):
            t = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                times[label] = times.get(label, 0.0) + time.perf_counter() - t
        return run

    for where, name, label in STEPS:
        module, _, cls = where.partition(":")
        try:
            owner = importlib.import_module(module)
        except ImportError:                   # --before: code older than the step
            continue
        owner = getattr(owner, cls) if cls else owner
        setattr(owner, name, timed(getattr(owner, name), label))
    from usdbtf.cli import main

    t = time.perf_counter()
    code = main(argv)
    times["total in process"] = time.perf_counter() - t
    Path(out_json).write_text(json.dumps(times))
    return code


def child_write(textures: str, width: int, height: int, scratch: str, out_json: str) -> int:
    """Time writing the asset's atlas-sized textures (module docstring, "write")."""
    import OpenImageIO as oiio

    from usdbtf.imageio import encode_image, write_encoded
    from usdbtf.usd.asset.textures import encode_in_workers

    jobs = []
    for path in sorted(Path(textures).rglob("*.png")):
        inp = oiio.ImageInput.open(str(path))
        spec = inp.spec()
        inp.close()
        folder = path.relative_to(textures).parts[0]
        # Atlas-sized files, and the GPU pages: tiles of atlas-sized packs (usd.asset.storm).
        tiles = spec.width % width == 0 and spec.height % height == 0 and folder == "gpu"
        if (spec.width, spec.height) != (width, height) and not tiles:
            continue
        config = oiio.ImageSpec()
        config.attribute("oiio:UnassociatedAlpha", 1)
        inp = oiio.ImageInput.open(str(path), config)
        pixels = inp.read_image(0, 0, 0, spec.nchannels, spec.format)
        inp.close()
        jobs.append((path, folder, pixels))
    Path(scratch).mkdir(parents=True, exist_ok=True)

    def write(job):
        i, (path, folder, pixels) = job
        data = encode_image(pixels, "png", color_space="data", attributes=ENCODE[folder]) if folder in ENCODE \
            else path.read_bytes()
        write_encoded(Path(scratch) / f"{i:03d}.png", data)

    t = time.perf_counter()
    for job in enumerate(jobs):                             # one file after another
        write(job)
    serial = time.perf_counter() - t
    t = time.perf_counter()
    encode_in_workers(write, enumerate(jobs), "write")      # a file per worker on every CPU, as package encodes
    threaded = time.perf_counter() - t
    shutil.rmtree(scratch)
    Path(out_json).write_text(json.dumps({"serial": serial, "threaded": threaded, "files": len(jobs),
                                          "encoded": sum(f in ENCODE for _, f, _ in jobs)}))
    return 0


# ------------------------------------------------------------------ inputs
def run_cli(cli, *args) -> None:
    r = run_measured([*cli, *map(str, args)], pss_interval=0)
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(map(str, args))} failed:\n{r.stderr[-2000:]}")


def inputs(workdir: Path, radii: list, cli) -> dict:
    """The swatch folder and {radius: (mesh layer, quilt folder, atlas (w, h), quilt seconds)}."""
    workdir.mkdir(parents=True, exist_ok=True)
    swatch = workdir / "pebbles64_k48"
    if not (swatch / "btf-compressed.json").is_file():
        run_cli(cli, "synth", "pebbles", "-o", workdir / "pebbles64", "--size", 64, "-q")
        run_cli(cli, "compress", workdir / "pebbles64", "-o", swatch, "--k", 48, "--codec", "png", "-q")
    quilts = {}
    for radius in radii:
        name = f"sphere_r{radius:g}"
        mesh, quilt = workdir / name / "mesh.usda", workdir / f"{name}_Q"
        if not mesh.is_file():
            import trimesh

            obj = workdir / f"{name}.obj"
            trimesh.creation.icosphere(subdivisions=4, radius=radius).export(str(obj))
            run_cli(cli, "unwrap", obj, "-o", workdir / name, "--btf", swatch, "-q")
        seconds = None
        if not (quilt / "btf-compressed.json").is_file():
            t = time.perf_counter()
            run_cli(cli, "quilt", swatch, "--atlas", mesh, "-o", quilt, "-q")
            seconds = time.perf_counter() - t
        atlas = json.loads((workdir / name / "unwrap.json").read_text())["atlas"]
        quilts[radius] = (mesh, quilt, (atlas["width"], atlas["height"]), seconds)
    return {"swatch": swatch, "quilts": quilts}


# ------------------------------------------------------------------ measurements
def package_once(source: Path, out: Path, *extra, pipeline: Path | None = None) -> dict:
    """One ``package`` of ``source`` as ``out`` in a child (steps timed): wall, peak RSS, steps.
    ``pipeline``: run the ``usdbtf`` package in that folder instead (``--before``)."""
    times = out.parent / "steps.json"
    env = None if pipeline is None else dict(os.environ, PYTHONPATH=str(pipeline))
    r = run_measured([sys.executable, __file__, "--child-steps", times, "--", "--force", "package", source,
                      "-o", out, "-q", *extra], env=env)
    if r.returncode != 0:
        raise SystemExit(f"package {source} failed:\n{r.stderr[-3000:]}")
    return {"wall_s": r.wall_s, "max_rss_bytes": r.max_rss_bytes, "steps_s": json.loads(times.read_text())}


def summary(runs: list) -> dict:
    """Median wall and steps, the worst peak RSS of ``package_once`` runs."""
    labels = [label for _, _, label in STEPS] + ["total in process"]
    return {"wall_s": median(r["wall_s"] for r in runs), "wall_s_samples": [r["wall_s"] for r in runs],
            "max_rss_bytes": max(r["max_rss_bytes"] for r in runs),
            "steps_s": {label: median(r["steps_s"].get(label, 0.0) for r in runs) for label in labels}}


def write_once(textures: Path, atlas: tuple) -> dict:
    """The "write" child's serial and threaded seconds for the asset's texture folder ``textures``."""
    result = textures.parent / "write.json"
    r = run_measured([sys.executable, __file__, "--child-write", textures, *map(str, atlas),
                      textures.parent / "scratch", result], pss_interval=0)
    if r.returncode != 0:
        raise SystemExit(f"write baseline failed:\n{r.stderr[-3000:]}")
    return json.loads(result.read_text())


def distinct_source_texels(quilt: Path) -> int:
    from usdbtf.compress.format import read_compressed
    from usdbtf.quilt.texels import quilt_texels

    texels = quilt_texels(read_compressed(quilt), quilt)
    return texels.compact.width if texels is not None else -1


def main(argv=None) -> int:
    args = parse_args(argv)
    os.environ.setdefault("OCIO", "ocio://default")
    info = machine_info()
    say(f"# bench_package_quilt\n{format_machine(info)}")
    cli = cli_command()
    radii = [0.03, 0.06] if args.quick else [float(r) for r in args.radii]
    repeats = 1 if args.quick else args.repeats
    data = inputs(args.workdir, radii, cli)
    work = OUT / "package_quilt"
    results = {"machine": info, "args": {k: str(v) for k, v in vars(args).items()}, "radii": radii}
    # Repeats interleaved (swatch, then each atlas and its write baseline), so that each ratio
    # compares runs of the same minutes on a shared machine; the ratio is the median of the repeats'.
    swatch_runs, package_runs, write_runs = [], {r: [] for r in radii}, {r: [] for r in radii}
    for rep in range(repeats):
        say(f"\n## repeat {rep + 1}/{repeats}")
        swatch_runs.append(package_once(data["swatch"], work / "swatch" / "swatch.usda"))
        say(f"- swatch {swatch_runs[-1]['wall_s']:.1f} s")
        for radius in radii:
            mesh, quilt, atlas, _ = data["quilts"][radius]
            out = work / f"r{radius:g}" / "sphere.usda"
            package_runs[radius].append(package_once(quilt, out, "--mesh", mesh))
            write_runs[radius].append(write_once(out.parent / "sphere_textures", atlas))
            say(f"- r {radius:g}: package {package_runs[radius][-1]['wall_s']:.1f} s, "
                f"{package_runs[radius][-1]['max_rss_bytes'] / 1e9:.2f} GB; write "
                f"{write_runs[radius][-1]['serial']:.1f} s serial, {write_runs[radius][-1]['threaded']:.1f} s threaded")
    results["swatch"] = summary(swatch_runs)
    rows = []
    fit_per_texel = None
    for radius in radii:
        mesh, quilt, atlas, quilt_s = data["quilts"][radius]
        texels = atlas[0] * atlas[1]
        writes = write_runs[radius]
        row = {"radius": radius, "atlas": atlas, "texels": texels, "quilt_s": quilt_s,
               "distinct": distinct_source_texels(quilt), "package": summary(package_runs[radius]),
               "write": {way: median(w[way] for w in writes) for way in ("serial", "threaded")} | {
                   "samples": writes, "files": writes[-1]["files"], "encoded": writes[-1]["encoded"]},
               "ratio": {way: median(p["wall_s"] / (s["wall_s"] + w[way]) for p, s, w in
                                     zip(package_runs[radius], swatch_runs, writes)) for way in ("serial", "threaded")}}
        if texels <= args.per_texel_max:
            say(f"\n## per-texel path, r = {radius:g} m")
            old = work / f"r{radius:g}_no_map"
            shutil.rmtree(old, ignore_errors=True)
            shutil.copytree(quilt, old)
            (old / "quilt_positions.exr").unlink()
            row["per_texel"] = summary([package_once(old, work / f"r{radius:g}_per_texel" / "sphere.usda",
                                                     "--mesh", mesh)])
            fit_per_texel = row["per_texel"]["steps_s"]["fallback fit"] / texels
            say(f"- {row['per_texel']['wall_s']:.1f} s, {row['per_texel']['max_rss_bytes'] / 1e9:.2f} GB")
        if args.before is not None and texels <= args.before_max:
            say(f"\n## before (--before {args.before}), r = {radius:g} m")
            row["before"] = summary([package_once(quilt, work / f"r{radius:g}_before" / "sphere.usda", "--mesh", mesh,
                                                  pipeline=args.before)])
            say(f"- {row['before']['wall_s']:.1f} s, {row['before']['max_rss_bytes'] / 1e9:.2f} GB")
        rows.append(row)
    for row in rows:
        if "per_texel" not in row and fit_per_texel is not None:
            row["per_texel_fit_estimate_s"] = fit_per_texel * row["texels"]
    if args.tx:
        mesh, quilt, atlas, _ = data["quilts"][radii[-1]]
        say(f"\n## --texture-format tx, r = {radii[-1]:g} m")
        results["tx"] = summary([package_once(quilt, work / "tx" / "sphere.usda", "--mesh", mesh,
                                              "--texture-format", "tx")])
        say(f"- {results['tx']['wall_s']:.1f} s, {results['tx']['max_rss_bytes'] / 1e9:.2f} GB")
    results["rows"] = rows
    path = write_json(OUT / f"package_quilt_{timestamp()}.json", results)
    note = "(--quick: NOT the issue's sphere)\n" if args.quick else ""
    say(f"\n## markdown (for benchmarks/RESULTS.md)\n\n{note}{markdown(results)}\n\nwrote {path}")
    return 0


def markdown(results: dict) -> str:
    sw = results["swatch"]
    labels = [label for _, _, label in STEPS]
    lines = [f"Swatch (`package` of the 64² source, k 48): **{sw['wall_s']:.1f} s**, peak RSS "
             f"{sw['max_rss_bytes'] / 1e9:.2f} GB.", "",
             "| sphere r (m) | atlas | atlas texels | distinct source texels | package s | peak RSS GB | "
             "write atlas textures s (serial / threaded) | **package / (swatch + write)** (serial / threaded) | "
             "per-texel path s | before (--before) s |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in results["rows"]:
        old = (f"{row['per_texel']['wall_s']:.1f} (measured; {row['per_texel']['max_rss_bytes'] / 1e9:.2f} GB)"
               if "per_texel" in row else
               f"~{row['per_texel_fit_estimate_s']:.0f} (fit alone, extrapolated)"
               if "per_texel_fit_estimate_s" in row else "-")
        before = (f"{row['before']['wall_s']:.1f} ({row['before']['max_rss_bytes'] / 1e9:.2f} GB)"
                  if "before" in row else "-")
        lines.append(f"| {row['radius']:g} | {row['atlas'][0]}×{row['atlas'][1]} | {row['texels']:,} | "
                     f"{row['distinct']:,} | {row['package']['wall_s']:.1f} | "
                     f"{row['package']['max_rss_bytes'] / 1e9:.2f} | {row['write']['serial']:.1f} / "
                     f"{row['write']['threaded']:.1f} | "
                     f"**{row['ratio']['serial']:.2f} / {row['ratio']['threaded']:.2f}** | {old} | {before} |")
    lines += ["", "Steps (median seconds, in the command's process):", "",
              "| run | " + " | ".join(labels) + " |", "|---|" + "---|" * len(labels)]
    runs = [("swatch", sw)] + [(f"r {row['radius']:g}", row["package"]) for row in results["rows"]]
    runs += [(f"r {row['radius']:g} per-texel", row["per_texel"]) for row in results["rows"] if "per_texel" in row]
    runs += [(f"r {row['radius']:g} before", row["before"]) for row in results["rows"] if "before" in row]
    if "tx" in results:
        runs.append((f"r {results['radii'][-1]:g} tx", results["tx"]))
    for name, run in runs:
        lines.append(f"| {name} | " + " | ".join(f"{run['steps_s'][label]:.2f}" for label in labels) + " |")
    if "tx" in results:
        lines += ["", f"`--texture-format tx` (r {results['radii'][-1]:g}): {results['tx']['wall_s']:.1f} s, "
                      f"peak RSS {results['tx']['max_rss_bytes'] / 1e9:.2f} GB."]
    return "\n".join(lines)


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="two small spheres, one repeat: a check")
    p.add_argument("--radii", nargs="+", default=["0.05", "0.1", "0.2", "0.3"], help="sphere radii, metres")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--per-texel-max", type=int, default=150_000,
                   help="run the per-texel path on atlases up to this many texels")
    p.add_argument("--tx", action="store_true", help="also package the largest atlas with --texture-format tx")
    p.add_argument("--before", type=Path, help="a pipeline/ folder of an older usdbtf (e.g. `git archive REV "
                   "pipeline`): package the atlases up to --before-max texels with it too")
    p.add_argument("--before-max", type=int, default=400_000)
    p.add_argument("--workdir", type=Path, default=OUT / "data" / "package_quilt", help="dataset cache")
    return p.parse_args(argv)


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--child-steps":
        sys.exit(child_steps(sys.argv[2], sys.argv[4:]))
    if len(sys.argv) > 2 and sys.argv[1] == "--child-write":
        sys.exit(child_write(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5], sys.argv[6]))
    sys.exit(main())
