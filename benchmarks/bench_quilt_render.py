#!/usr/bin/env python
"""Quilting, unwrapping and rendering benchmark (issue 5).

Measures, in one run:

quilt speed    ``quilt()`` of a 1024^2 output from a paper-scale k = 150 compressed BTF (synthesis:
               features, FFT block matching, cuts -> position map), the gather of all k coefficient
               textures through the position map (in memory), and the whole ``usdbtf quilt`` CLI
               (which also encodes the k textures with the input's codec).  Target: 1024^2 at
               k = 150 in <= 10 s.  Baseline in the same run: the gather alone (the memory traffic
               any position-map quilter has to pay).
m trade-off    block matching on the leading m coefficients, m in --m-sweep: synthesis time and
               seam error (all samples) of a 512^2 quilt, median over seeds; picks DEFAULT_M.
seam error     per preset (sampling "small", 128^2, all 169 samples reconstructed): mean squared
               difference across quilting seams, averaged over every (view, light) image, for
               (1) coefficient-space quilting, (2) one image quilted on its own intensities with
               the same blocks (block, overlap, grid, tolerance, seed) and that layout applied to
               every image, averaged over the reference images, (3) every image quilted on its own,
               each measured in its own image.  (3) is not a BTF -- each image has its own
               mesostructure -- which "BRDF mismatch" quantifies: the distance of each output
               texel's apparent BRDF (its values over all samples) to the nearest measured one,
               relative to the mean BRDF energy (0 for (1) and (2) by construction).
render speed   a 1024^2 frame of an unwrapped sphere (atlas at the sample's texel density, quilted
               from the k = 150 BTF), one point light with a cast-shadow map, 2 shading threads,
               median of --repeats frames with a warm renderer; plus the whole ``usdbtf render``
               CLI.  Target <= 5 s.  Baseline: plain equation 2 (one basis row . k coefficients per
               covered pixel, no interpolation or filtering), timed in this process.

Usage (repository root)::

    .venv/bin/python benchmarks/bench_quilt_render.py            # paper-scale input, ~6 min on 2 cores
    .venv/bin/python benchmarks/bench_quilt_render.py --quick    # small input and sizes, ~1 min (a check)

Writes benchmarks/out/quilt_render_<timestamp>.json and prints a markdown block for RESULTS.md.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import OUT, cli_command, format_machine, machine_info, run_repeated, time_call, timestamp, write_json

TARGETS = {"quilt_s": 10.0, "render_s": 5.0}


def say(msg: str = "") -> None:
    print(msg, flush=True)


def command(*parts) -> list:
    """A subprocess argument list (numbers and paths as strings)."""
    return [str(p) for p in parts]


# -- inputs ------------------------------------------------------------------------------------
def compressed_input(workdir: Path, preset: str, sampling: str, size: int, k: int, cli) -> Path:
    """A cached synthetic dataset (usdbtf.bench.datasets) compressed with ``usdbtf compress --k k``."""
    from usdbtf.bench.datasets import ensure_dataset
    from usdbtf.compress.format import METADATA

    data = ensure_dataset(workdir, preset, sampling, size, 0, say=say)
    out = OUT / "quilt_render" / f"{Path(data['folder']).name}-k{k}"
    if not (out / METADATA).is_file():
        cmd = command(*cli, "compress", data["folder"], "-o", out, "--k", k, "-q")
        say(f"  $ {' '.join(cmd)}")
        res = run_repeated(cmd, 1, pss_interval=0)
        if "error" in res:
            raise SystemExit(res["error"])
    else:
        say(f"  compressed: cached {out}")
    return out


# -- quilt speed -------------------------------------------------------------------------------
def cpu_timed(fn, repeats: int, warmup: int) -> dict:
    """:func:`time_call` plus the median CPU seconds of this process per call (all threads):
    less sensitive than wall time to other work on a shared machine."""
    cpu = []

    def once():
        c = time.process_time()
        fn()
        cpu.append(time.process_time() - c)

    res = time_call(once, repeats=repeats, warmup=warmup)
    res["cpu_s_median"] = float(np.median(cpu[warmup:]))
    return res


def quilt_speed(folder: Path, size: int, repeats: int, cli) -> dict:
    from usdbtf.compress import read_compressed
    from usdbtf.quilt import QuiltOptions, quilt, write_quilt

    cbtf = read_compressed(folder)
    opts = QuiltOptions(size=(size, size), seed=1)
    holder = {}

    def synth():
        holder["q"] = quilt(cbtf, opts)

    t_synth = cpu_timed(synth, repeats=repeats, warmup=0)
    q = holder["q"]
    flat = q.positions.ravel()

    def gather():
        return [np.take(st.pixels.reshape(-1, 3), flat, axis=0) for st in cbtf.coefficients]

    t_gather = time_call(gather, repeats=repeats, warmup=1)
    out = OUT / "quilt_render" / f"quilt{size}"
    t = time.perf_counter()
    sizes = write_quilt(replace(q, source_folder=folder), out)
    write_s = time.perf_counter() - t
    cmd = command(*cli, "quilt", folder, "-o", OUT / "quilt_render" / f"quilt{size}_cli", "--size", size, size,
                  "--seed", 1, "-q")
    say(f"  $ {' '.join(cmd)}")
    run = run_repeated(cmd, repeats, pss_interval=0)
    res = {"size": size, "k": cbtf.k, "source": [cbtf.width, cbtf.height], "samples": cbtf.n_samples,
           "options": q.record["options"], "blocks": q.record["blocks"], "synthesis": t_synth,
           "gather_all_k": t_gather, "write_s": write_s, "payload_bytes": sizes["payload"],
           "codec": cbtf.codec, "cli": {k: run[k] for k in ("command", "wall_s_samples", "wall_s_median",
                                                            "cpu_s_median", "peak_memory_bytes") if k in run},
           "seam_error": q.record["seam_error"]["all_samples_mean"]}
    res["in_memory_s"] = t_synth["median_s"] + t_gather["median_s"]
    say(f"  synthesis (position map) median {t_synth['median_s']:.2f} s of {repeats}, "
        f"CPU {t_synth['cpu_s_median']:.2f} s "
        f"({q.record['blocks']} blocks of {q.options.block}, overlap {q.options.overlap}, m = {q.options.m})")
    say(f"  gather all {cbtf.k} textures (baseline) median {t_gather['median_s']:.2f} s; "
        f"synthesis + gather = {res['in_memory_s']:.2f} s")
    say(f"  write_quilt ({cbtf.codec}, {cbtf.k} textures) {write_s:.2f} s; CLI median "
        f"{run['wall_s_median']:.2f} s (runs {', '.join(f'{x:.2f}' for x in run['wall_s_samples'])})")
    return res


# -- m trade-off -------------------------------------------------------------------------------
def m_sweep(folder: Path, ms: list, size: int, seeds: list) -> list:
    from usdbtf.compress import read_compressed
    from usdbtf.quilt import QuiltOptions, quilt

    cbtf = read_compressed(folder)
    rows = []
    for m in ms:
        m = min(m, cbtf.k)
        times, errs = [], []
        for seed in seeds:
            t = time.perf_counter()
            q = quilt(cbtf, QuiltOptions(size=(size, size), m=m, seed=seed))
            times.append(time.perf_counter() - t)
            errs.append(q.record["seam_error"]["all_samples_mean"])
        rows.append({"m": m, "time_s_median": float(np.median(times)), "seam_error_mean": float(np.mean(errs)),
                     "times_s": times, "seam_errors": errs})
        say(f"  m = {m:3d}: {np.median(times):.2f} s, seam error {np.mean(errs):.5g} (seeds {seeds})")
    return rows


# -- seam comparison ---------------------------------------------------------------------------
def seam_comparison(folder: Path, size: int, every: int, seed: int) -> dict:
    from usdbtf.compress import read_compressed, reconstruct
    from usdbtf.quilt import QuiltOptions, quilt
    from usdbtf.quilt.engine import Source, grid_for, place_blocks
    from usdbtf.quilt.seams import seam_error_images

    cbtf = read_compressed(folder)
    images = reconstruct(cbtf)                                     # (S, H, W, 3) working space
    opts = QuiltOptions(seed=seed).resolved(cbtf)
    t = time.perf_counter()
    coeff = quilt(cbtf, replace(opts, size=(size, size)))
    coeff_s = time.perf_counter() - t
    per_sample = seam_error_images(coeff.positions, images)
    grid = grid_for(size, size, opts.block, opts.overlap)
    refs = np.arange(0, cbtf.n_samples, every)
    own, one_for_all, layouts = [], [], []
    t = time.perf_counter()
    for s in refs:
        img = images[s]
        canvas = np.full(grid.shape, -1, np.int32)
        place_blocks(canvas, grid, Source.build(img, img.reshape(-1, 3), opts.block), tolerance=opts.tolerance,
                     rng=np.random.default_rng(opts.seed))
        layout = canvas[:size, :size]
        layouts.append(layout)
        own.append(float(seam_error_images(layout, images[s:s + 1])[0]))
        one_for_all.append(float(seam_error_images(layout, images).mean()))
    image_s = (time.perf_counter() - t) / len(refs)
    mismatch = brdf_mismatch(images, refs, layouts)
    res = {"samples": cbtf.n_samples, "k": cbtf.k, "size": size, "options": coeff.record["options"],
           "reference_images": refs.tolist(),
           "coefficient_all_samples": float(per_sample.mean()),
           "coefficient_on_reference_images": float(per_sample[refs].mean()),
           "one_image_layout_all_samples": float(np.mean(one_for_all)),
           "one_image_layout_best": float(np.min(one_for_all)),
           "independent_own_image": float(np.mean(own)),
           "independent_brdf_mismatch": mismatch,
           "natural_neighbour": float(np.mean(np.diff(images, axis=2) ** 2)),
           "coefficient_quilt_s": coeff_s, "image_quilt_s": image_s}
    say(f"  coefficient space: {res['coefficient_all_samples']:.5g} (all {cbtf.n_samples} samples); "
        f"one image's layout for all: {res['one_image_layout_all_samples']:.5g} (mean over {len(refs)} reference "
        f"images, best {res['one_image_layout_best']:.5g}); each image on its own: {res['independent_own_image']:.5g} "
        f"(coefficient space on the same images {res['coefficient_on_reference_images']:.5g}), BRDF mismatch "
        f"{mismatch:.3f}; natural neighbour difference {res['natural_neighbour']:.5g}")
    return res


def brdf_mismatch(images: np.ndarray, refs: np.ndarray, layouts: list, n_texels: int = 1500) -> float:
    """Independent per-image quilts as one BTF: each output texel's values over the reference
    samples vs the nearest source texel's, squared distance over the mean squared BRDF norm."""
    S, H, W, _ = images.shape
    src = images[refs].reshape(len(refs), H * W, 3).transpose(1, 0, 2).reshape(H * W, -1)     # (P, R*3)
    rng = np.random.default_rng(0)
    pick = rng.choice(layouts[0].size, size=min(n_texels, layouts[0].size), replace=False)
    out = np.stack([images[s].reshape(-1, 3)[layouts[i].ravel()[pick]] for i, s in enumerate(refs)], axis=1)
    out = out.reshape(len(pick), -1)                                                          # (n, R*3)
    d2 = (out ** 2).sum(1)[:, None] + (src ** 2).sum(1)[None, :] - 2.0 * out @ src.T
    return float(np.maximum(d2.min(axis=1), 0).mean() / (src ** 2).sum(1).mean())


# -- render speed ------------------------------------------------------------------------------
def render_speed(folder: Path, frame: int, repeats: int, cli) -> dict:
    import trimesh

    from usdbtf.camera import parse_camera
    from usdbtf.compress import read_compressed
    from usdbtf.mesh import load_mesh
    from usdbtf.render import RenderOptions, Renderer, parse_light

    work = OUT / "quilt_render" / "render"
    work.mkdir(parents=True, exist_ok=True)
    sphere = work / "sphere.obj"
    trimesh.creation.icosphere(5, radius=0.08).export(str(sphere))
    steps = [command(*cli, "unwrap", sphere, "-o", work / "sphere_uv", "--btf", folder, "-q"),
             command(*cli, "quilt", folder, "--atlas", work / "sphere_uv" / "mesh.usda", "-o", work / "sphere_q", "-q")]
    for cmd in steps:
        say(f"  $ {' '.join(cmd)}")
        r = run_repeated(cmd, 1, pss_interval=0)
        if "error" in r:
            raise SystemExit(r["error"])
    cbtf = read_compressed(work / "sphere_q")
    mesh = load_mesh(work / "sphere_uv" / "mesh.usda", need_uv=True)
    camera_spec = "eye=0,0.06,0.34 target=0,0,0 fov=30"
    light_spec = "point:0.3,0.3,0.3:0.2"
    camera = parse_camera(camera_spec, frame, frame)
    lights = [parse_light(light_spec)]
    t = time.perf_counter()
    renderer = Renderer(cbtf, RenderOptions(threads=2))
    init_s = time.perf_counter() - t
    holder = {}

    def one():
        holder["img"] = renderer.render(mesh, camera, lights)

    timing = cpu_timed(one, repeats=repeats, warmup=1)
    covered = int((holder["img"][..., 3] > 0).sum())
    # Baseline: equation 2 with one fixed basis row per covered pixel, texel-major coefficients.
    tex = renderer.texture.level(0).reshape(-1, 3, renderer.interp.k)     # level 0 whole, texel-major
    rng = np.random.default_rng(0)
    idx = rng.integers(0, len(tex), covered)
    row = renderer.interp.basis[0]

    def plain():
        for a in range(0, covered, 16384):
            np.einsum("pck,k->pc", np.take(tex, idx[a:a + 16384], axis=0), row)

    base = time_call(plain, repeats=repeats, warmup=1)
    out = work / "frame.exr"
    cmd = command(*cli, "render", work / "sphere_q", "--mesh", work / "sphere_uv" / "mesh.usda", "--camera",
                  camera_spec, "--light", light_spec, "--size", frame, frame, "-o", out, "-q")
    say(f"  $ {' '.join(cmd)}")
    run = run_repeated(cmd, repeats, pss_interval=0)
    res = {"frame_size": frame, "k": cbtf.k, "atlas": [cbtf.width, cbtf.height], "triangles": len(mesh.triangles),
           "covered_pixels": covered, "lights": 1, "shadows": True, "threads": 2, "renderer_init_s": init_s,
           "frame_timing": timing, "plain_eq2_baseline": base,
           "cli": {k: run[k] for k in ("command", "wall_s_samples", "wall_s_median", "cpu_s_median",
                                       "peak_memory_bytes") if k in run}}
    say(f"  {frame}^2 frame, {covered} covered pixels, {len(mesh.triangles)} triangles, "
        f"atlas {cbtf.width}x{cbtf.height}, "
        f"k = {cbtf.k}: median {timing['median_s']:.2f} s of {repeats}, CPU {timing['cpu_s_median']:.2f} s "
        f"(renderer init {init_s:.2f} s, once)")
    say(f"  baseline plain eq. 2 on the same pixels: {base['median_s']:.2f} s -> renderer / baseline = "
        f"{timing['median_s'] / base['median_s']:.1f}; CLI median {run['wall_s_median']:.2f} s")
    return res


def swatch_check(folder: Path) -> dict:
    from usdbtf.compress import read_compressed, reconstruct
    from usdbtf.render import Renderer

    cbtf = read_compressed(folder)
    r = Renderer(cbtf)
    worst = 0.0
    picks = np.linspace(0, cbtf.n_samples - 1, 6).astype(int)
    for s in picks:
        img = r.swatch(cbtf.sampling.view[s], cbtf.sampling.light[s])
        ref = reconstruct(cbtf, [s])[0]
        worst = max(worst, float(np.abs(img - ref).max() / np.abs(ref).max()))
    say(f"  swatch vs reconstruction at {len(picks)} measured samples: max |diff| / max |value| = {worst:.2e}")
    return {"samples": picks.tolist(), "max_relative": worst}


# -- report ------------------------------------------------------------------------------------
def markdown(results: dict) -> str:
    q, r = results["quilt"], results["render"]
    lines = [f"Inputs: {results['inputs']}",
             f"Load average at start: {results['machine'].get('load_average_at_start')}", "",
             "| measurement | median | target |", "|---|---|---|",
             f"| quilt {q['size']}² at k = {q['k']}: synthesis (position map) | {q['synthesis']['median_s']:.2f} s "
             f"(CPU {q['synthesis']['cpu_s_median']:.2f} s) | |",
             f"| + gather of all {q['k']} textures in memory (baseline alone: {q['gather_all_k']['median_s']:.2f} s) "
             f"| {q['in_memory_s']:.2f} s | ≤ {TARGETS['quilt_s']:.0f} s: "
             f"{'PASS' if q['in_memory_s'] <= TARGETS['quilt_s'] else 'FAIL'} |",
             f"| `usdbtf quilt` CLI incl. encoding {q['k']} {q['codec']} textures | {q['cli']['wall_s_median']:.2f} s "
             f"| {'PASS' if q['cli']['wall_s_median'] <= TARGETS['quilt_s'] else 'FAIL'} (end to end) |",
             f"| render {r['frame_size']}² frame ({r['covered_pixels']} px covered, 1 point light + shadow map, "
             f"2 threads) | {r['frame_timing']['median_s']:.2f} s (CPU {r['frame_timing']['cpu_s_median']:.2f} s, "
             f"both threads) | ≤ {TARGETS['render_s']:.0f} s: "
             f"{'PASS' if r['frame_timing']['median_s'] <= TARGETS['render_s'] else 'FAIL'} |",
             f"| plain eq. 2 on the same pixels (baseline) | {r['plain_eq2_baseline']['median_s']:.2f} s | |",
             f"| renderer set-up, once per BTF (texture build, triangulations) | {r['renderer_init_s']:.2f} s | |",
             f"| `usdbtf render` CLI (decode {r['k']} textures + set-up + frame + EXR/PNG) | "
             f"{r['cli']['wall_s_median']:.2f} s | |",
             "", f"m trade-off ({results['m_sweep_size']}², k = {q['k']}):", "", "| m | synthesis s | seam error (all samples) |", "|---|---|---|"]
    lines += [f"| {row['m']} | {row['time_s_median']:.2f} | {row['seam_error_mean']:.5g} |"
              for row in results["m_sweep"]]
    lines += ["", "Seam error, mean over all (view, light) images (lower is better):", "",
              "| preset | coefficient space | one image's layout for all | each image on its own (own image) "
              "| coefficient space on those images | BRDF mismatch of 'own' | natural neighbours |",
              "|---|---|---|---|---|---|---|"]
    for name, s in results["seams"].items():
        lines.append(f"| {name} | {s['coefficient_all_samples']:.5g} | {s['one_image_layout_all_samples']:.5g} | "
                     f"{s['independent_own_image']:.5g} | {s['coefficient_on_reference_images']:.5g} | "
                     f"{s['independent_brdf_mismatch']:.3f} | {s['natural_neighbour']:.5g} |")
    return "\n".join(lines)


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="small input and sizes: a check, not the targets")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--workdir", type=Path, default=OUT / "data", help="dataset cache")
    p.add_argument("--m-sweep", default="1,2,4,8,16,32,150")
    p.add_argument("--seam-presets", default="pebbles,ridged_fabric,fuzzy_moss")
    p.add_argument("--seam-every", type=int, default=4, help="reference images: every n-th sample")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    os.environ.setdefault("OCIO", "ocio://default")
    cli = cli_command()
    info = machine_info()
    say("# bench_quilt_render")
    say(format_machine(info))
    sampling, size, out_size, frame = ("paper", 128, 1024, 1024) if not args.quick else ("small", 64, 256, 256)
    repeats = args.repeats if not args.quick else 1
    results = {"machine": info, "args": vars(args) | {"workdir": str(args.workdir)}}
    say("\n## inputs")
    main_input = compressed_input(args.workdir, "pebbles", sampling, size, 150, cli)
    results["inputs"] = (f"pebbles, sampling '{sampling}', {size}², compressed `--k 150` (default rsvd/jxl): "
                         f"{main_input}")
    say(f"- {results['inputs']}")
    say("\n## swatch check")
    results["swatch"] = swatch_check(main_input)
    say(f"\n## quilt speed ({out_size}^2)")
    results["quilt"] = quilt_speed(main_input, out_size, repeats, cli)
    say("\n## m trade-off")
    ms = [int(x) for x in args.m_sweep.split(",")]
    sweep_size = 512 if not args.quick else 128
    results["m_sweep_size"] = sweep_size
    results["m_sweep"] = m_sweep(main_input, ms if not args.quick else ms[:3], sweep_size,
                                 [1, 2, 3] if not args.quick else [1])
    say("\n## seam error: coefficient space vs image space")
    results["seams"] = {}
    for preset in args.seam_presets.split(","):
        say(f"- {preset}")
        folder = compressed_input(args.workdir, preset, "small", 128 if not args.quick else 64, 150, cli)
        results["seams"][preset] = seam_comparison(folder, 256 if not args.quick else 128,
                                                   args.seam_every if not args.quick else 12, seed=7)
    say(f"\n## render speed ({frame}^2)")
    results["render"] = render_speed(main_input, frame, repeats, cli)
    path = write_json(OUT / f"quilt_render_{timestamp()}.json", results)
    say("\n## markdown (for benchmarks/RESULTS.md)\n")
    if args.quick:
        say("(--quick: NOT the target scale)")
    say(markdown(results))
    say(f"\nwrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
