"""Section ``quilt``: quilting time against seam error, over the matched coefficients m and
the block size (:mod:`usdbtf.quilt`).

Source: the first material at ``quilt_size``² (configured sampling), compressed once with
``usdbtf compress --k quilt_k`` (untimed).  Each (block, m) quilts a ``quilt_out``² output
``repeats`` times in this process (median wall time: features, matching, cuts, seam error).
Seam error (:mod:`usdbtf.quilt.seams`): mean squared working-space difference across seams,
over every (view, light) sample; shown also relative to the mean squared difference of
naturally adjacent source texels (1.0 = seams no more visible than ordinary texture).
Baseline per block size: random placement (every candidate block equally likely, same cuts).
"""
from __future__ import annotations

import time

import numpy as np

from . import Context, Section, SectionResult
from ..report import Column, markdown_table, pareto_mask, plot_sweep

ROW_KEYS = ["preset", "sampling", "source_size", "out_size", "k", "method", "block", "overlap", "m", "repeats",
            "wall_s", "wall_s_min", "wall_s_max", "seam_error", "seam_relative", "pareto", "status"]
RANDOM_TOLERANCE = 1e9      # every block within 1e9 x the best overlap error: uniform choice


def natural_neighbour_error(features: np.ndarray, height: int, width: int, n_samples: int) -> float:
    """Mean over horizontally and vertically adjacent source texels of the squared image-space
    difference per sample and channel (the seam-error units of :mod:`usdbtf.quilt.seams`)."""
    f = features.reshape(height, width, -1)
    total = count = 0.0
    for d in (f[:, 1:] - f[:, :-1], f[1:] - f[:-1]):
        total += float(np.einsum("ijd,ijd->", d, d, dtype=np.float64))
        count += d.shape[0] * d.shape[1]
    return total / (count * 3 * n_samples)


def compressed_source(ctx: Context, preset: str, size: int, k: int):
    """The dataset compressed once (untimed) with ``usdbtf compress --k k``."""
    from ..datasets import compressed, ensure_dataset

    cfg = ctx.config
    info = ensure_dataset(ctx.workdir, preset, cfg.sampling, size, cfg.seed, say=ctx.say)
    return compressed(ctx.cli, info["folder"], ctx.out / "stored" / f"{preset}-{cfg.sampling}-{size}-k{k}", k)


def run(ctx: Context) -> SectionResult:
    from ...quilt import QuiltOptions, quilt
    from ...quilt.features import image_features

    cfg = ctx.config
    preset = cfg.presets[0]
    ctx.say(f"\n## quilt: {preset}, sampling {cfg.sampling}, {cfg.quilt_size}² -> {cfg.quilt_out}², "
            f"blocks {list(cfg.quilt_blocks)}, m {list(cfg.quilt_ms)}")
    cbtf = compressed_source(ctx, preset, cfg.quilt_size, cfg.quilt_k)
    natural = natural_neighbour_error(image_features(cbtf), cbtf.height, cbtf.width, cbtf.n_samples)
    ctx.say(f"  source k = {cbtf.k}; natural neighbour difference {natural:.4g} (seam-error units)")
    result = SectionResult(csv_keys=ROW_KEYS)
    ms = sorted({min(m, cbtf.k) for m in cfg.quilt_ms})
    base = {"preset": preset, "sampling": cfg.sampling, "source_size": cfg.quilt_size, "out_size": cfg.quilt_out,
            "k": cbtf.k, "repeats": cfg.repeats}
    for block in cfg.quilt_blocks:
        runs = [("matched", m, None) for m in ms] + [("random placement", 1, RANDOM_TOLERANCE)]
        for method, m, tolerance in runs:
            opts = QuiltOptions(size=(cfg.quilt_out, cfg.quilt_out), block=block, m=m, seed=cfg.seed,
                                **({} if tolerance is None else {"tolerance": tolerance}))
            times = []
            for _ in range(cfg.repeats):
                t = time.perf_counter()
                q = quilt(cbtf, opts)
                times.append(time.perf_counter() - t)
            seam = float(q.record["seam_error"]["all_samples_mean"])
            row = dict(base, method=method, block=block, overlap=q.options.overlap, m=m, status="ok",
                       wall_s=float(np.median(times)), wall_s_min=min(times), wall_s_max=max(times),
                       seam_error=seam, seam_relative=seam / natural if natural > 0 else None)
            result.rows.append(row)
            ctx.say(f"  block {block:3d} m {m:3d} {method:16s}: {row['wall_s']:6.2f} s, seam error {seam:.4g} "
                    f"({row['seam_relative']:.2f} x natural)")
    matched = [r for r in result.rows if r["method"] == "matched"]
    for r, on in zip(matched, pareto_mask([r["wall_s"] for r in matched], [r["seam_error"] for r in matched])):
        r["pareto"] = "yes" if on else ""
    cols = [Column("method", "method"), Column("block", "block"), Column("overlap", "overlap"), Column("m", "m"),
            Column("wall_s", "time s (median)", ".2f"), Column("seam_error", "seam error", ".4g"),
            Column("seam_relative", "seam / natural", ".2f"), Column("pareto", "Pareto (time, seam)")]
    result.tables.append(f"#### {preset}: {cfg.quilt_size}² source (k = {cbtf.k}) quilted to {cfg.quilt_out}²\n\n"
                         + markdown_table(result.rows, cols))
    result.plots.append(plot_sweep(matched, ctx.out / "quilt" / "quilt.png", x="wall_s", y="seam_error",
                                   series="block", point="m", xlabel="quilting time, s (median)",
                                   ylabel="seam error (mean squared difference)",
                                   title=f"usdbtf quilt: {cfg.quilt_size}² -> {cfg.quilt_out}², k = {cbtf.k}; "
                                         "one line per block size, points = m",
                                   references={f"random, block {r['block']}": (r["wall_s"], r["seam_error"])
                                               for r in result.rows if r["method"] != "matched"}))
    result.notes.append(
        "time = median wall time of `usdbtf.quilt.quilt` in the benchmark process (features, FFT matching, "
        "minimum-error cuts, seam error); seam error = mean over seam pairs, channels and all (view, light) "
        f"samples of the squared working-space difference; natural = {natural:.4g}, the same for naturally "
        "adjacent source texels; random placement = tolerance 1e9 (any block), same cuts.")
    result.summary = {"natural_neighbour_error": natural}
    return result


SECTION = Section(name="quilt", title="Quilting: time vs seam error against m and block size", order=30, run=run,
                  requires=("usdbtf.quilt",))
