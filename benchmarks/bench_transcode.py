"""Transcoding a UBO2014 DFMF file from its factors against expanding its images (issue 18 part 2).

Two parts, every number measured in this run:

**Quality** (realistic data, moderate size).  Pebbles (``usdbtf.synth``) rendered over the
``ubo81`` sampling (81 views x 81 lights = 6561 samples) at 32^2 texels, plus a 0.01 floor
(measured radiance has no exact zeros), factorised per channel by the *test writer*
(``tests/bonn_btf_writer.py``: numpy SVD, half floats; no usdbtf code) with 48 / 16 / 16
components, in colour model 11 (UBO2014's log Y, U/Y, V/Y: a nonlinear decode) and model 0
(RGB: linear).  ``compress --k K`` from the factors (default rows = 16 k, 8 k rows, every
row) against ``--expand-factors``; RMSE and percent error of the decoded result against the
reader's own images (all samples, all texels), and the ratio to the expanded path.  Then the
row-sampling choice itself: on the expanded path's basis, coefficients solved on m
leverage-sampled rows vs m uniformly sampled rows vs the exact projection.

**Time** (UBO2014's size).  A synthetic DFMF of UBO2014's shape -- 151 x 151 samples, 400^2,
150 / 50 / 50 half-float components, model 11; random factors with a decaying spectrum, the
file ``bench_ubo2014.py`` times the expansion of -- compressed from its factors at k = 150,
per step.  The expanded path cannot run at this size in a benchmark (~16 min of expansion
alone on this machine, see RESULTS), so it runs on a crop of the same file: the same 22,801
samples, the top 25 of the 400 rows (1/16 of the texels), with the steps that pass over every
value (load, project: two expansions, the streaming source's, and the projection) and the
ones proportional to the texels (encode, evaluate) scaled by 16, fit and colour (a fixed
sample of texels) as measured.  The scaled figure is a lower bound: at full size the
streaming source reads 32-sample chunks, each of which makes the reader multiply out its
whole 128-sample tile (4x the products of the crop's 512-sample chunks).  The factor path is
timed on the crop too, like for like.  Then the same for a model-0 (RGB, linear) file of that
shape, channels around 0.5: the exact path.

Run: ``.venv/bin/python benchmarks/bench_transcode.py [--quick] [--k 16]``
(``--quick``: the quality part only, ~3 min on 2 cores; the whole run ~15 min).
"""
from __future__ import annotations

import argparse
import logging
import re
import sys
import tempfile
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from common import REPO, format_machine, machine_info

sys.path.insert(0, str(REPO / "tests"))
import bonn_btf_writer as writer  # noqa: E402
from bench_ubo2014 import N_LIGHTS, N_VIEWS, SIZE, synthetic_dfmf  # noqa: E402

from usdbtf import synth  # noqa: E402
from usdbtf.bench.measure import cpu_seconds  # noqa: E402
from usdbtf.compress import CompressOptions, compress  # noqa: E402
from usdbtf.compress.format import reconstruct  # noqa: E402
from usdbtf.compress.row_sampling import leverage_rows, solve_operators  # noqa: E402
from usdbtf.sampling import preset  # noqa: E402
from usdbtf.ubo2014 import read_ubo2014  # noqa: E402

QUALITY_SIZE = 32
QUALITY_KS = (48, 16, 16)
CROP_ROWS = 25


def quality_file(folder: Path, model: int) -> tuple[Path, float]:
    """The writer's DFMF of pebbles over ubo81 at 32^2 in colour ``model``; seconds to write."""
    t = time.perf_counter()
    samp = preset("ubo81")
    views = np.unique(samp.view, axis=0)
    lights = np.unique(samp.light, axis=0)
    from usdbtf.sampling import cross
    full = cross(views, lights)
    rgb = synth.render_all(synth.make_material("pebbles", QUALITY_SIZE, 0), full).astype(np.float64) + 0.01
    S, T = len(full), QUALITY_SIZE ** 2
    values = (writer.rgb_to_model11(rgb) if model == 11 else rgb).reshape(S, T, 3)
    chans = [writer.factorise(values[..., c], k) for c, k in zip(range(3), QUALITY_KS)]
    path = writer.dfmf_file(folder / f"pebbles_model{model}.btf", chans, model=model, views_rad=np.radians(views),
                            lights_rad=np.radians(lights), width=QUALITY_SIZE, height=QUALITY_SIZE)
    return path, time.perf_counter() - t


def errors(result, truth: np.ndarray) -> dict:
    rec = np.stack(list(reconstruct(result, np.arange(truth.shape[0]))))
    diff = (rec - truth).astype(np.float64)
    return {"rmse": float(np.sqrt(np.mean(diff ** 2))), "percent": float(100 * np.abs(diff).sum() / truth.sum())}


def timed(fn):
    c, t = cpu_seconds(), time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t, cpu_seconds() - c


def quality(folder: Path, k: int) -> None:
    print(f"\n## quality: pebbles, ubo81 (6561 samples), {QUALITY_SIZE}^2, file components {QUALITY_KS}, "
          f"compress --k {k}")
    for model in (11, 0):
        path, wrote = quality_file(folder, model)
        btf = read_ubo2014(path)
        truth = btf.read_samples(slice(None))
        S = btf.n_samples
        print(f"\nmodel {model} ({'nonlinear' if model == 11 else 'linear'} decode), written in {wrote:.1f} s:")
        print("| path | RMSE | percent | RMSE / expanded | wall s | CPU s | coefficients |")
        print("|---|---|---|---|---|---|---|")
        runs = [("expanded (--expand-factors)", CompressOptions(k=k, expand_factors=True)),
                ("factors, default rows (16 k)", CompressOptions(k=k)),
                ("factors, 8 k rows", CompressOptions(k=k, factor_rows=8 * k)),
                ("factors, every row", CompressOptions(k=k, factor_rows=S))]
        base = None
        for name, opts in runs:
            result, wall, cpu = timed(lambda: compress(btf, opts))
            e = errors(result, truth)
            base = base or e["rmse"]
            how = result.info["provenance"].get("transcoded", {}).get("coefficients", "-")
            print(f"| {name} | {e['rmse']:.5f} | {e['percent']:.3f} | {e['rmse'] / base:.3f} | {wall:.1f} | "
                  f"{cpu:.1f} | {how} |")
            if name.startswith("expanded"):
                expanded = result
        if model == 11:
            row_sampling_choice(expanded, truth, k)


def row_sampling_choice(result, truth: np.ndarray, k: int) -> None:
    """Leverage vs uniform rows, on the expanded result's basis (float, before quantisation)."""
    S = truth.shape[0]
    u = result.basis_values(k).astype(np.float64)
    u, _ = np.linalg.qr(u)
    x = truth.reshape(S, -1).astype(np.float64)
    exact = u @ (u.T @ x)
    e0 = np.sqrt(np.mean((exact - x) ** 2))
    print(f"\nrow sampling on the expanded path's basis (k = {k}, unquantised), RMSE / exact projection's "
          f"({e0:.5f}); median of 5 seeds:")
    print("| rows m | leverage (default) | uniform |")
    print("|---|---|---|")
    for m in (4 * k, 8 * k, 16 * k, 32 * k):
        ratios = {"leverage": [], "uniform": []}
        for seed in range(5):
            rows, weights = leverage_rows(u, m, seed)
            draws = np.random.default_rng(seed).choice(S, size=m)
            urows, counts = np.unique(draws, return_counts=True)
            for name, (r, wts) in (("leverage", (rows, weights)), ("uniform", (urows, counts * S / m))):
                op = solve_operators(u, r, wts, (k,))[0].astype(np.float64)
                rec = u @ (op @ x[r])
                ratios[name].append(np.sqrt(np.mean((rec - x) ** 2)) / e0)
        print(f"| {m} ({m / S:.1%} of S) | {np.median(ratios['leverage']):.3f} | {np.median(ratios['uniform']):.3f} |")


# --------------------------------------------------------------------------- time at UBO2014's size


_STEP = re.compile(r"(load|fit|colour|project|encode|evaluate) ([0-9.]+)")


def steps_of(log_lines: list) -> dict:
    """Per-step seconds from compress's last log line ("... (T s: load a, fit b, ...)")."""
    return {name: float(s) for name, s in _STEP.findall(log_lines[-1].split("(", 1)[1])}


class _Lines(logging.Handler):
    """Collects the messages of compress's logger (its last line has the step times)."""

    def __init__(self):
        super().__init__(logging.INFO)
        self.lines = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def run_compress(btf, opts) -> dict:
    handler, logger = _Lines(), logging.getLogger("usdbtf.compress.core")
    logger.addHandler(handler)
    level, logger.level = logger.level, logging.INFO
    try:
        result, wall, cpu = timed(lambda: compress(btf, opts))
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)
    return {"wall": wall, "cpu": cpu, "steps": steps_of(handler.lines), "result": result}


def crop_of(path: Path, folder: Path, model: int) -> Path:
    """The same factors, texels of the top CROP_ROWS rows only (rows y W + x, y = 0 the top)."""
    btf = read_ubo2014(path)
    f = btf.factors
    T = SIZE * CROP_ROWS
    chans = [(np.asarray(f.channels[c].singular_values, np.float64), f.float32(c, "samples"),
              f.float32(c, "texels")[:T]) for c in range(3)]
    return writer.dfmf_file(folder / f"crop{model}.btf", chans, model=model, views_rad=btf.header.views,
                            lights_rad=btf.header.lights, width=SIZE, height=CROP_ROWS)


def ubo_size(folder: Path, model: int, k: int) -> None:
    # Model 0 (RGB, the linear path): the same kind of factors around 0.5 per channel, so that
    # few values ring below zero (random factors centred on 0 would be half clamped).
    path = synthetic_dfmf(folder / f"ubo_model{model}.btf", [150, 50, 50], model=model,
                          offsets=(-2.0, 0.0, 0.0) if model == 11 else (0.5, 0.5, 0.5))
    crop = crop_of(path, folder, model)
    print(f"\n## time: model {model}, {N_VIEWS} x {N_LIGHTS} samples, {SIZE}^2, components 150 / 50 / 50, "
          f"{path.stat().st_size / 1e6:.1f} MB; compress --k {k}")
    full = run_compress(read_ubo2014(path), CompressOptions(k=k))
    crop_f = run_compress(read_ubo2014(crop), CompressOptions(k=k))
    crop_e = run_compress(read_ubo2014(crop), CompressOptions(k=k, expand_factors=True))
    scale = SIZE / CROP_ROWS
    scaled = {n: s * (1 if n in ("fit", "color") else scale) for n, s in crop_e["steps"].items()}
    print("| run | wall s | CPU s | " + " | ".join(full["steps"]) + " |")
    print("|---|---|---|" + "---|" * len(full["steps"]))
    for name, r in ((f"factors, full {SIZE}x{SIZE}", full), (f"factors, crop {SIZE}x{CROP_ROWS}", crop_f),
                    (f"expanded, crop {SIZE}x{CROP_ROWS}", crop_e)):
        print(f"| {name} | {r['wall']:.1f} | {r['cpu']:.1f} | " +
              " | ".join(f"{r['steps'].get(n, 0):.2f}" for n in full["steps"]) + " |")
    total = sum(scaled.values())
    print(f"| expanded, full size estimated (crop steps x {scale:g}, fit and colour as measured) | {total:.0f} | - | " +
          " | ".join(f"{scaled.get(n, 0):.1f}" for n in full["steps"]) + " |")
    print(f"ratio expanded (estimated, lower bound) / factors at full size: {total / full['wall']:.1f}; "
          f"on the crop, measured: {crop_e['wall'] / crop_f['wall']:.1f}")
    for name, r in (("factors full", full), ("factors crop", crop_f), ("expanded crop", crop_e)):
        info = r["result"].info
        print(f"  {name}: held-out estimated error {info['estimated_error']['linear']['percent']:.3f} %, "
              f"{info['bytes']['payload']} bytes; {info['provenance'].get('transcoded', {}).get('coefficients', '')}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the quality part only")
    ap.add_argument("--k", type=int, default=16, help="compress's k in the quality part (default 16)")
    ap.add_argument("--ubo-k", type=int, default=150, help="compress's k at UBO2014's size (default 150)")
    args = ap.parse_args()
    print("machine (shared with other sessions: read medians and ratios):")
    print(format_machine(machine_info()))
    with tempfile.TemporaryDirectory(prefix="bench-transcode-") as tmp:
        tmp = Path(tmp)
        quality(tmp, args.k)
        if not args.quick:
            for model in (11, 0):
                ubo_size(tmp, model, args.ubo_k)


if __name__ == "__main__":
    main()
