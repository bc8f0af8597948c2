"""Section ``compress``: run time, peak memory, stored bytes and error of every solver x codec
x k of ``usdbtf compress`` and of the baselines, on fitted and on held-out samples.

Per dataset (material preset x image size, sampling from the configuration):

1. split the samples (:func:`usdbtf.bench.heldout.split_lights`): the fitted ones become a
   manifest of their own, the held-out ones are never shown to any method;
2. per method (:mod:`usdbtf.bench.methods`), ``repeats`` timed subprocess runs that store
   the fitted samples, each into a new folder of its own (page cache warm; median wall time,
   worst peak memory; the last run's output is evaluated);
3. errors against the synthetic ground truth (the dataset's own files, decoded to the
   scene-linear working space): on fitted samples (what was stored), and on held-out
   samples predicted from the nearest fitted directions.  Percent error (the paper's
   metric), RMSE and PSNR (peak 1 = diffuse white).  ``eval_samples`` caps how many of
   each are evaluated (evenly spread).
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from . import Context, Section, SectionResult
from ..report import Column, markdown_table, pareto_mask, plot_tradeoffs

ROW_KEYS = ["preset", "sampling", "size", "n_fit", "n_heldout", "family", "method", "codec", "param_name", "param",
            "k_stored", "baseline", "repeats", "wall_s", "wall_s_min", "wall_s_max", "cpu_s", "peak_mem_bytes",
            "stored_bytes", "raw_bytes", "ratio", "fit_percent", "fit_rmse", "fit_psnr_db", "fit_psnr_enc_db",
            "held_percent", "held_rmse", "held_psnr_db", "eval_fit", "eval_held", "pareto_time", "pareto_bytes",
            "status", "command"]

COLUMNS = [Column("method", "method"), Column("param_name", "param"), Column("param", "value"),
           Column("k_stored", "k kept"), Column("wall_s", "time s (median)", ".2f"),
           Column("peak_mem_mb", "peak MB", ".0f"), Column("stored_bytes", "stored B", "bytes"),
           Column("ratio", "raw : stored", ".0f"), Column("fit_percent", "% err fit", ".3f"),
           Column("fit_rmse", "RMSE fit", ".5f"), Column("fit_psnr_db", "PSNR fit dB", ".2f"),
           Column("held_percent", "% err held-out", ".3f"), Column("held_rmse", "RMSE held-out", ".5f"),
           Column("held_psnr_db", "PSNR held-out dB", ".2f"), Column("pareto", "Pareto (time, bytes)"),
           Column("status", "status")]


def spread(n: int, count: int | None) -> np.ndarray:
    """``count`` indices evenly spread over range(n) (all of them when count is None or >= n)."""
    if count is None or count >= n:
        return np.arange(n)
    return np.unique(np.linspace(0, n - 1, count).round().astype(int))


def _compare_chunk(width: int, height: int, neighbours: int) -> int:
    """Samples per comparison chunk: about 64 MB of float32 images, neighbours included."""
    return max(1, int(64e6 // (width * height * 3 * 4 * (neighbours + 1))))


class Dataset:
    """One benchmark input: the full synthetic BTF, its fitted/held-out split, the weights
    that predict held-out samples, and the evaluation subsets."""

    def __init__(self, ctx: Context, preset: str, size: int):
        from ...io import open_btf
        from ..datasets import ensure_dataset, write_subset
        from ..heldout import neighbour_weights, split_lights

        cfg = ctx.config
        self.preset, self.size, self.sampling_name = preset, size, cfg.sampling
        self.name = f"{preset}-{cfg.sampling}-{size}"
        info = ensure_dataset(ctx.workdir, preset, cfg.sampling, size, cfg.seed, say=ctx.say)
        self.folder = Path(info["folder"])
        self.full = open_btf(self.folder)
        self.fit_idx, self.held_idx = split_lights(self.full.sampling, cfg.holdout, cfg.seed)
        self.fitted_dir = write_subset(self.folder, self.fit_idx, ctx.out / "inputs" / f"{self.name}-fitted",
                                       heldout={"fraction": cfg.holdout, "seed": cfg.seed,
                                                "held_out_samples": [int(i) for i in self.held_idx]})
        self.fitted = open_btf(self.fitted_dir)
        fs, hs = self.full.sampling.subset(self.fit_idx), self.full.sampling.subset(self.held_idx)
        self.nb_idx, self.nb_w = neighbour_weights(fs, hs, cfg.neighbours)
        self.eval_fit = spread(len(self.fit_idx), cfg.eval_samples)        # positions among fitted
        self.eval_held = spread(len(self.held_idx), cfg.eval_samples)      # positions among held-out
        self.needed = np.union1d(self.eval_fit, self.nb_idx[self.eval_held].ravel())
        self.fit_pos = np.full(self.full.n_samples, -1)
        self.fit_pos[self.fit_idx] = np.arange(len(self.fit_idx))
        self.held_pos = np.full(self.full.n_samples, -1)
        self.held_pos[self.held_idx] = np.arange(len(self.held_idx))
        self.raw_bytes = len(self.fit_idx) * size * size * 3
        self.chunk = _compare_chunk(size, size, cfg.neighbours)
        ctx.say(f"  {len(self.fit_idx)} fitted samples, {len(self.held_idx)} held out "
                f"(every sample of {len(self.held_idx) // max(1, self._views())} light directions); evaluating "
                f"{len(self.eval_fit)} fitted + {len(self.eval_held)} held-out samples")

    def _views(self) -> int:
        from ...compress.format import cross_layout
        cross = cross_layout(self.full.sampling)
        return cross[0] if cross else 1

    def errors(self, rec) -> dict:
        """Fitted and held-out errors of a Reconstruction against the ground truth."""
        from ...compress.decompress import compare

        out = {}
        fit = compare(self.full, lambda sel: rec.fitted(self.fit_pos[sel]), self.fit_idx[self.eval_fit],
                      chunk=self.chunk)
        out.update(fit_percent=fit["linear"]["percent"], fit_rmse=fit["linear"]["rmse"],
                   fit_psnr_db=fit["linear"]["psnr_db"], fit_psnr_enc_db=fit["encoded"]["psnr_db"],
                   eval_fit=fit["samples"])
        if len(self.held_idx):
            def predict(sel):
                pos = self.held_pos[sel]
                return rec.blend(self.nb_idx[pos], self.nb_w[pos])
            held = compare(self.full, predict, self.held_idx[self.eval_held], chunk=self.chunk)
            out.update(held_percent=held["linear"]["percent"], held_rmse=held["linear"]["rmse"],
                       held_psnr_db=held["linear"]["psnr_db"], eval_held=held["samples"])
        return out


def _methods(cfg) -> list:
    from ..methods import baseline_methods, compress_methods

    if cfg.solver_codecs:
        pairs = cfg.solver_codecs
        methods = [m for s, c in pairs for m in compress_methods([s], [c], cfg.ks)]
    else:
        methods = compress_methods(cfg.solvers, cfg.codecs, cfg.ks)
    return methods + baseline_methods(cfg.jpeg_qualities, cfg.pca_view_ks, cfg.video_crfs)


def measure_method(ctx: Context, ds: Dataset, method, video_ok: tuple) -> dict:
    """One row: time the method's command (each repeat into its own folder), then read the
    last run's output back and evaluate it.  ``repeats`` in the row: the runs made."""
    from ..measure import failure_reason, run_repeated_apart

    cfg = ctx.config
    row = {"preset": ds.preset, "sampling": ds.sampling_name, "size": ds.size, "n_fit": len(ds.fit_idx),
           "n_heldout": len(ds.held_idx), "family": method.family, "method": method.label, "codec": method.codec,
           "param_name": method.param_name, "param": method.param, "baseline": method.baseline,
           "repeats": 0, "raw_bytes": ds.raw_bytes}
    if method.family == "video" and video_ok[0] is None:
        ctx.say(f"    {method.label} {method.param_name} {method.param}: skipped ({video_ok[1]})")
        return dict(row, status=f"skipped: {video_ok[1]}")
    folder = ctx.out / "stored" / ds.name / method.slug
    res, out = run_repeated_apart(lambda path: method.command(ctx.cli, ds.fitted_dir, path), folder, cfg.repeats,
                                  pss_interval=cfg.pss_interval)
    row.update(command=res["command"], repeats=len(res["runs"]), wall_s=res["wall_s_median"],
               wall_s_min=res["wall_s_min"], wall_s_max=res["wall_s_max"], cpu_s=res["cpu_s_median"],
               peak_mem_bytes=res["peak_memory_bytes"])
    if "error" in res:
        why = failure_reason(res)
        ctx.say(f"    {method.label} {method.param_name} {method.param}: FAILED: {why}")
        return dict(row, status=f"failed: {why}")
    stored = method.stored_bytes(out)
    row.update(method.details(out), stored_bytes=stored, ratio=ds.raw_bytes / stored if stored else None)
    row.update(ds.errors(method.open(out, ds.fitted, ds.needed)))
    row["status"] = "ok"
    if not cfg.keep_outputs:
        shutil.rmtree(folder, ignore_errors=True)
    held = f", held-out {row['held_percent']:.3f} %" if row.get("held_percent") is not None else ""
    ctx.say(f"    {method.label:16s} {method.param_name} {method.param:>4}: {row['wall_s']:7.2f} s, "
            f"{row['peak_mem_bytes'] / 1e6:6.0f} MB, {stored:>11,} B, fit {row['fit_percent']:.3f} %{held}")
    return row


def reference_row(ctx: Context, ds: Dataset) -> dict:
    """The input images themselves: no fitted error, and the held-out error that predicting
    from the nearest fitted directions costs even without any compression (a floor)."""
    from ..methods import ManifestReconstruction

    row = {"preset": ds.preset, "sampling": ds.sampling_name, "size": ds.size, "n_fit": len(ds.fit_idx),
           "n_heldout": len(ds.held_idx), "family": "original", "method": "original images (reference)",
           "codec": "input", "param_name": "", "param": None, "baseline": True, "raw_bytes": ds.raw_bytes,
           "status": "reference"}
    row.update(ds.errors(ManifestReconstruction(ds.fitted_dir)))
    if row.get("held_percent") is not None:
        ctx.say(f"    reference: predicting held-out samples from the original fitted images: "
                f"{row['held_percent']:.3f} % (the floor for every method)")
    return row


def mark_pareto(rows: list) -> None:
    """pareto_time / pareto_bytes: on the front of (time, fitted error) / (bytes, fitted error)
    among the rows of one dataset."""
    ok = [r for r in rows if r.get("status") == "ok"]
    for key, x in (("pareto_time", "wall_s"), ("pareto_bytes", "stored_bytes")):
        mask = pareto_mask([r[x] for r in ok], [r["fit_percent"] for r in ok])
        for r, m in zip(ok, mask):
            r[key] = bool(m)
    for r in rows:
        r["pareto"] = ", ".join(n for n, k in (("time", "pareto_time"), ("bytes", "pareto_bytes")) if r.get(k)) or ""
        if r.get("peak_mem_bytes"):
            r["peak_mem_mb"] = r["peak_mem_bytes"] / 1e6


def add_dataset(result: SectionResult, rows: list, columns: list, title: str, plot, plot_title: str,
                held_floor: float | None = None) -> None:
    """One dataset's rows into ``result``: Pareto marks, its table under ``title`` and, when a
    row succeeded, its time/bytes-against-error plot at ``plot``."""
    mark_pareto(rows)
    result.rows.extend(rows)
    result.tables.append(f"#### {title}\n\n{markdown_table(rows, columns)}")
    ok = [r for r in rows if r.get("status") == "ok"]
    if ok:
        result.plots.append(plot_tradeoffs(ok, plot, plot_title, held_floor=held_floor))


def run(ctx: Context) -> SectionResult:
    from ..baselines import ffmpeg_x265
    from ..datasets import preset_split
    from ..measure import warm_page_cache

    cfg = ctx.config
    result = SectionResult(csv_keys=ROW_KEYS)
    video_ok = ffmpeg_x265() if cfg.video_crfs else (None, "not requested")
    if cfg.video_crfs and video_ok[0] is None:
        ctx.say(f"  video baseline: skipped: {video_ok[1]}")
        result.notes.append(f"H.265 video baseline skipped: {video_ok[1]}.")
    methods = _methods(cfg)
    plots_dir = ctx.out / "compress"
    for preset in cfg.presets:
        for size in cfg.sizes:
            ctx.say(f"\n## compress: {preset}, sampling {cfg.sampling}, {size}x{size}")
            ds = Dataset(ctx, preset, size)
            warm = warm_page_cache(ds.folder)
            ctx.say(f"  page cache warm-up (untimed): {warm['files']} files, {warm['bytes'] / 1e6:.1f} MB")
            rows = [reference_row(ctx, ds)] + [measure_method(ctx, ds, m, video_ok) for m in methods]
            title = (f"{preset}{' (held-out preset)' if preset_split(preset) == 'held-out' else ''}, sampling "
                     f"{cfg.sampling} ({len(ds.fit_idx)} fitted + {len(ds.held_idx)} held-out samples), {size}x{size}")
            add_dataset(result, rows, COLUMNS, title, plots_dir / f"{ds.name}.png",
                        f"usdbtf bench: {title}; {cfg.repeats} repeat(s)", held_floor=rows[0].get("held_percent"))
    result.notes.append(
        "time = median wall time of the storing subprocess (interpreter start and image decode included, page "
        "cache warm); peak MB = worst max(peak RSS, sampled tree PSS) over repeats; stored B = texture/image/video "
        "files (metadata JSON not counted); raw = fitted samples x H x W x 3 bytes (8 bit); errors in "
        "scene-linear ACEScg, percent = 100 sum|orig - recon| / sum orig, PSNR peak 1.0; held-out samples are "
        f"predicted from the {cfg.neighbours} nearest fitted directions (inverse-distance-squared weights times "
        "cos theta_l(held-out) / cos theta_l(neighbour), on basis rows, or on decoded images for image/video "
        "baselines); the reference row predicts them from the "
        "original fitted images, the floor of any method's held-out error; Pareto: not beaten in both time (or "
        "bytes) and fitted error by another row of the same dataset.")
    return result


SECTION = Section(name="compress", title="Compression: time, memory, bytes and error vs k, solver, codec, baselines",
                  order=10, run=run, requires=("usdbtf.compress",))
