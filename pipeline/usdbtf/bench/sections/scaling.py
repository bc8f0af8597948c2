"""Section ``scaling``: how ``usdbtf compress`` time and peak memory grow with samples x texels.

Grid: image sizes ``scaling_sizes`` x the first ``scaling_views`` views of the sampling
``scaling_sampling`` (all lights of each view), plain ``usdbtf compress IN -o OUT --k K``
in two memory modes:

``auto``       the default ``--memory-budget`` (1 GB): the stored values are held in memory
               when they fit, else streamed (the run records which);
``streaming``  ``--memory-budget 0``: always streamed (two decoding passes, one chunk of
               samples held at a time).

Reported per mode: the log-log table, slopes of log time and log memory against log
texels at a fixed sample count and against log samples at a fixed texel count (pooled over
the series, one intercept each), and the affine fit time = t0 + c S P (t0 = fixed cost:
interpreter start, imports, writing).  Linear in texels means a time slope near 1 once
fixed costs are small; bounded memory means the streaming mode's memory does not grow
like S P: only the k coefficient textures (k 3 P floats) and the fitting sample
(S x a few thousand texels) grow.
"""
from __future__ import annotations

import re
import shutil

from . import Context, Section, SectionResult
from ..report import Column, affine_fit, markdown_table, plot_scaling, pooled_loglog_slope

ROW_KEYS = ["sampling", "size", "pixels", "views", "samples", "values", "raw_bytes", "mode", "source", "k",
            "repeats", "wall_s", "wall_s_min", "wall_s_max", "cpu_s", "peak_mem_bytes", "stored_bytes", "status",
            "command"]
MODES = {"auto": [], "streaming": ["--memory-budget", "0"]}
_SOURCE = re.compile(r"\((in-memory|streaming), ")


def _slopes(rows: list, key: str) -> dict:
    """Pooled log-log slopes of ``key`` against texels (series: one per sample count), against
    samples (one per texel count), and against S P over all points; ``*_top``: the same from
    each series' two largest points only (where fixed costs weigh least)."""
    def groups(by, x, top=False):
        out = {}
        for r in sorted(rows, key=lambda r: r[x]):
            out.setdefault(r[by], ([], []))
            out[r[by]][0].append(r[x])
            out[r[by]][1].append(r[key])
        return [(xs[-2:], ys[-2:]) if top else (xs, ys) for xs, ys in out.values()]

    return {"vs_pixels": pooled_loglog_slope(groups("samples", "pixels")),
            "vs_pixels_top": pooled_loglog_slope(groups("samples", "pixels", top=True)),
            "vs_samples": pooled_loglog_slope(groups("pixels", "samples")),
            "vs_samples_top": pooled_loglog_slope(groups("pixels", "samples", top=True)),
            "vs_values": pooled_loglog_slope([([r["values"] for r in rows], [r[key] for r in rows])])}


def _fmt(v) -> str:
    return "\u2014" if v is None else f"{v:.2f}"


def _grid_table(rows: list, mode: str) -> str:
    """Rows = image sizes, columns = sample counts; cells 'wall s / CPU s / peak MB (source)'."""
    mine = [r for r in rows if r["mode"] == mode and r.get("status") == "ok"]
    samples = sorted({r["samples"] for r in mine})
    sizes = sorted({r["size"] for r in mine})
    head = ["texels \\ samples"] + [f"S = {s:,}" for s in samples]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for size in sizes:
        cells = [f"{size}² = {size * size:,}"]
        for s in samples:
            r = next((x for x in mine if x["size"] == size and x["samples"] == s), None)
            cells.append("\u2014" if r is None else
                         f"{r['wall_s']:.2f} s / {r['cpu_s']:.2f} s / {r['peak_mem_bytes'] / 1e6:.0f} MB"
                         + (" (streamed)" if mode == "auto" and r.get("source") == "streaming" else ""))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def measure(ctx: Context) -> list:
    """One row per (size, view count, memory mode): timed ``usdbtf compress`` runs."""
    from ...sampling import preset as sampling_preset
    from ..datasets import ensure_dataset, first_views
    from ..measure import failure_reason, run_repeated_apart, warm_page_cache
    from ..methods import Method

    cfg = ctx.config
    rows = []
    full = sampling_preset(cfg.scaling_sampling)
    ctx.say(f"\n## scaling: {cfg.scaling_sampling} sampling, sizes {list(cfg.scaling_sizes)}, "
            f"views {list(cfg.scaling_views)}, k {cfg.scaling_k}")
    for size in cfg.scaling_sizes:
        for views in cfg.scaling_views:
            S = len(first_views(full, views))
            raw = S * size * size * 3
            if cfg.scaling_max_gb is not None and raw > cfg.scaling_max_gb * 1e9:
                ctx.say(f"  {size}x{size}, S {S}: skipped ({raw / 1e9:.1f} GB raw > --scaling-max-gb "
                        f"{cfg.scaling_max_gb:g})")
                continue
            info = ensure_dataset(ctx.workdir, cfg.presets[0], cfg.scaling_sampling, size, cfg.seed,
                                  views=None if S == len(full) else views, say=ctx.say)
            warm_page_cache(info["folder"])
            for mode, extra in MODES.items():
                folder = ctx.out / "stored" / "scaling" / f"{size}-{S}-{mode}"
                res, out = run_repeated_apart(
                    lambda path: [*ctx.cli, "compress", info["folder"], "-o", path, "--k", str(cfg.scaling_k), *extra],
                    folder, cfg.repeats, pss_interval=cfg.pss_interval)
                row = {"sampling": cfg.scaling_sampling, "size": size, "pixels": size * size, "views": views,
                       "samples": S, "values": S * size * size, "raw_bytes": raw, "mode": mode,
                       "k": cfg.scaling_k, "repeats": len(res["runs"]), "command": res["command"],
                       "wall_s": res["wall_s_median"], "wall_s_min": res["wall_s_min"],
                       "wall_s_max": res["wall_s_max"], "cpu_s": res["cpu_s_median"],
                       "peak_mem_bytes": res["peak_memory_bytes"]}
                if "error" in res:
                    row["status"] = "failed: " + failure_reason(res)
                    ctx.say(f"  {size}x{size}, S {S}, {mode}: {row['status']}")
                else:
                    found = _SOURCE.search(res["stderr"])
                    row.update(status="ok", source=found.group(1) if found else None,
                               stored_bytes=Method("rsvd", "jxl", cfg.scaling_k).stored_bytes(out))
                    ctx.say(f"  {size:4d}x{size:<4d} S {S:6d} {mode:9s}: {row['wall_s']:7.2f} s "
                            f"(CPU {row['cpu_s']:6.2f} s), {row['peak_mem_bytes'] / 1e6:6.0f} MB ({row['source']})")
                shutil.rmtree(folder, ignore_errors=True)
                rows.append(row)
    return rows


QUANTITIES = (("wall time", "wall_s"), ("CPU time", "cpu_s"), ("peak memory", "peak_mem_bytes"))


def summarise(rows: list, plot_path=None, title: str = "") -> SectionResult:
    """Grid tables, log-log slopes, affine time fits and the plot, from measured ``rows``."""
    result = SectionResult(rows=rows, csv_keys=ROW_KEYS)
    ok = [r for r in rows if r.get("status") == "ok"]
    fits = {}
    for mode in MODES:
        mine = [r for r in ok if r["mode"] == mode]
        if not mine:
            continue
        fits[mode] = {name: _slopes(mine, key) for name, key in QUANTITIES}
        for name, key in QUANTITIES[:2]:
            t0, c = affine_fit([r["values"] for r in mine], [r[key] for r in mine])
            fits[mode][name].update(fixed_s=t0, ns_per_value=c * 1e9)
        result.tables.append(f"#### mode `{mode}`: median wall time / median CPU time (user + sys) / peak memory"
                             f"\n\n{_grid_table(rows, mode)}")
    slope_rows = [{"mode": m, "what": name, **f[name]} for m, f in fits.items() for name, _ in QUANTITIES]
    cols = [Column("mode", "mode"), Column("what", "quantity"), Column("vs_pixels", "slope vs texels (S fixed)", ".2f"),
            Column("vs_pixels_top", "… two largest sizes", ".2f"),
            Column("vs_samples", "slope vs samples (P fixed)", ".2f"),
            Column("vs_samples_top", "… two largest counts", ".2f"), Column("vs_values", "slope vs S·P", ".2f"),
            Column("fixed_s", "affine fit: fixed s", ".2f"), Column("ns_per_value", "affine fit: ns per sample·texel",
                                                                    ".1f")]
    result.tables.append("#### log-log slopes (1 = linear, 0 = flat)\n\n" + markdown_table(slope_rows, cols))
    result.summary = {"fits": fits}
    if ok and plot_path is not None:
        result.plots.append(plot_scaling(ok, plot_path, title))
    result.notes.append(
        "wall = median wall time of `usdbtf compress` (interpreter start and PNG decode included), CPU = median "
        "user + sys of the process and its decode workers (less disturbed by other load on a shared machine); "
        "memory = worst max(peak RSS, sampled tree PSS); `auto` = default --memory-budget 1 GB (\"streamed\" "
        "where the stored values exceed it), `streaming` = --memory-budget 0; slopes are least-squares fits of "
        "log y on log x with one intercept per series; affine fit: y = fixed + c S P over all points of a mode.")
    return result


def run(ctx: Context) -> SectionResult:
    cfg = ctx.config
    return summarise(measure(ctx), ctx.out / "scaling" / "scaling.png",
                     f"usdbtf compress --k {cfg.scaling_k}: {cfg.scaling_sampling} sampling subsets, "
                     f"{cfg.repeats} repeat(s), median")


SECTION = Section(name="scaling", title="Scaling: compress time and memory vs samples x texels", order=20, run=run,
                  requires=("usdbtf.compress",))


if __name__ == "__main__":
    # Tables again from a finished run: python -m usdbtf.bench.sections.scaling OUT/results.json
    import json
    import sys
    from pathlib import Path

    doc = json.loads(Path(sys.argv[1]).read_text())
    res = summarise(doc["sections"]["scaling"]["rows"])
    print("\n\n".join(res.tables + ["- " + n for n in res.notes]))
