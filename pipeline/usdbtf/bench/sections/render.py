"""Section ``render``: rendering time against image error, over k (:mod:`usdbtf.render`).

The first material at ``render_size``² is split as in the ``compress`` section (held-out
light directions), its fitted samples compressed once with ``usdbtf compress --k max(k)``
(untimed).  For each k the CPU renderer draws the flat swatch (one pixel per texel, one
distant light: ``Renderer.swatch``) at up to ``render_directions`` fitted and held-out
(view, light) pairs; each image is compared with the synthetic ground truth (the dataset's
file, scene-linear working space).  Time = median over directions of one swatch, in this
process; renderer setup (basis triangulations, coefficient mip maps) is timed separately.

Reference rows, same directions and k: ``reconstruct`` (equation 2 with the stored basis row:
exact at fitted directions, no interpolation) and, for held-out ones, the benchmark's own
prediction (inverse-distance-weighted basis rows of the nearest fitted directions).
"""
from __future__ import annotations

import time

import numpy as np

from . import Context, Section, SectionResult
from ..report import Column, markdown_table, plot_sweep

ROW_KEYS = ["preset", "sampling", "size", "k", "method", "directions", "n", "repeats", "setup_s", "wall_s",
            "percent", "rmse", "psnr_db", "status"]


def _errors(truth: np.ndarray, images: np.ndarray) -> dict:
    from ...compress.metrics import ErrorSums

    sums = ErrorSums()
    sums.add(truth, images)
    rep = sums.report()
    return {"percent": rep["percent"], "rmse": rep["rmse"], "psnr_db": rep["psnr_db"]}


def _timed(fn, items) -> tuple[np.ndarray, float]:
    """Images fn(item) for every item, and the median seconds of one call."""
    images, times = [], []
    for item in items:
        t = time.perf_counter()
        images.append(fn(item))
        times.append(time.perf_counter() - t)
    return np.stack(images), float(np.median(times))


def run(ctx: Context) -> SectionResult:
    from ...compress import reconstruct
    from ...compress.format import working_coefficients
    from ...render import RenderOptions, Renderer
    from ..datasets import compressed
    from ..heldout import blend_compressed
    from .compress import Dataset, spread

    cfg = ctx.config
    preset = cfg.presets[0]
    ctx.say(f"\n## render: {preset}, sampling {cfg.sampling}, {cfg.render_size}², k {list(cfg.render_ks)}")
    ds = Dataset(ctx, preset, cfg.render_size)
    k_max = max(cfg.render_ks)
    cbtf = compressed(ctx.cli, ds.fitted_dir, ctx.out / "stored" / f"{ds.name}-render-k{k_max}", k_max)
    fit_pos = spread(len(ds.fit_idx), cfg.render_directions)
    held_pos = spread(len(ds.held_idx), cfg.render_directions) if len(ds.held_idx) else np.zeros(0, int)
    sets = {"fitted": (ds.fit_idx[fit_pos], fit_pos), "held-out": (ds.held_idx[held_pos], held_pos)}
    truth = {name: ds.full.read_samples(idx) for name, (idx, _) in sets.items() if len(idx)}
    sampling = ds.full.sampling
    result = SectionResult(csv_keys=ROW_KEYS)
    base = {"preset": preset, "sampling": cfg.sampling, "size": cfg.render_size, "repeats": 1, "status": "ok"}
    for k in sorted({min(k, cbtf.k) for k in cfg.render_ks}):
        t = time.perf_counter()
        renderer = Renderer(cbtf, RenderOptions(k=k))
        setup = time.perf_counter() - t
        coeff = working_coefficients(cbtf, k)
        for name, (idx, pos) in sets.items():
            if not len(idx):
                continue
            images, seconds = _timed(lambda i: renderer.swatch(sampling.view[i], sampling.light[i]), idx)
            rows = [dict(base, k=k, method="render swatch", directions=name, n=len(idx), setup_s=setup,
                         wall_s=seconds, **_errors(truth[name], images))]
            if name == "fitted":
                images, seconds = _timed(lambda p: reconstruct(cbtf, [p], k=k, coefficients=coeff)[0], pos)
                rows.append(dict(base, k=k, method="reconstruct (stored row)", directions=name, n=len(idx),
                                 wall_s=seconds, **_errors(truth[name], images)))
            else:
                def predict(p):
                    return blend_compressed(cbtf, coeff, ds.nb_idx[[p]], ds.nb_w[[p]])[0]
                images, seconds = _timed(predict, pos)
                rows.append(dict(base, k=k, method="nearest-direction rows (bench)", directions=name, n=len(idx),
                                 wall_s=seconds, **_errors(truth[name], images)))
            for r in rows:
                ctx.say(f"  k {k:4d} {r['directions']:8s} {r['method']:31s}: {r['wall_s'] * 1e3:8.1f} ms/image, "
                        f"{r['percent']:.3f} %, PSNR {r['psnr_db']:.2f} dB")
            result.rows.extend(rows)
    cols = [Column("directions", "directions"), Column("method", "method"), Column("k", "k"), Column("n", "images"),
            Column("setup_s", "setup s", ".2f"), Column("wall_s", "s per image (median)", ".4f"),
            Column("percent", "% err", ".3f"), Column("rmse", "RMSE", ".5f"), Column("psnr_db", "PSNR dB", ".2f")]
    result.tables.append(f"#### {preset}, {cfg.render_size}², {len(ds.fit_idx)} fitted samples (k up to {cbtf.k})\n\n"
                         + markdown_table(result.rows, cols))
    swatches = [dict(r, series=f"{r['directions']}") for r in result.rows if r["method"] == "render swatch"]
    if swatches:
        result.plots.append(plot_sweep(swatches, ctx.out / "render" / "render.png", x="wall_s", y="percent",
                                       series="series", point="k", xlabel="seconds per swatch (median)",
                                       ylabel="percent error vs ground truth",
                                       title=f"usdbtf render swatch, {cfg.render_size}²: one line per direction set, "
                                             "points = k"))
    result.notes.append(
        "swatch = `usdbtf.render.Renderer(cbtf, RenderOptions(k)).swatch(view, light)` (flat patch, one pixel per "
        "texel, basis rows interpolated over the view and light triangulations); errors against the dataset's "
        "own images in scene-linear ACEScg; held-out directions were not in the compressed fit.")
    return result


SECTION = Section(name="render", title="Rendering: time vs image error against k", order=40, run=run,
                  requires=("usdbtf.render",))
