"""Benchmark output: tables (markdown, CSV), Pareto fronts, log-log fits and plots.

A table is a list of row dicts plus a list of :class:`Column` (key, header, format); a
missing or None value prints as an em dash in markdown and an empty CSV cell.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..atomic import atomic_file

__all__ = ["Column", "markdown_table", "write_csv", "pareto_mask", "loglog_slope", "pooled_loglog_slope",
           "affine_fit", "plot_tradeoffs", "plot_scaling", "plot_sweep"]

DASH = "\u2014"


@dataclass(frozen=True)
class Column:
    key: str
    header: str
    fmt: str = ""          # format spec, e.g. ".3f"; "bytes" = thousands separators; "" = str()

    def cell(self, row: dict) -> str:
        v = row.get(self.key)
        if v is None or (isinstance(v, float) and not math.isfinite(v)):
            return DASH
        if self.fmt == "bytes":
            return f"{int(v):,}"
        if self.fmt and isinstance(v, (int, float)) and not isinstance(v, bool):
            return format(v, self.fmt)
        return str(v).replace("|", "\\|")


def markdown_table(rows: list, columns: list) -> str:
    lines = ["| " + " | ".join(c.header for c in columns) + " |", "|" + "|".join("---" for _ in columns) + "|"]
    lines += ["| " + " | ".join(c.cell(r) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def write_csv(rows: list, path: Path, keys: list) -> Path:
    """Every key of ``keys`` as a column, full precision; written atomically."""
    with atomic_file(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(keys)
            for r in rows:
                w.writerow(["" if r.get(k) is None else r.get(k) for k in keys])
    return Path(path)


def pareto_mask(x, y) -> np.ndarray:
    """True for points no other point beats: another with x' <= x and y' <= y, one strictly.
    Points with a non-finite coordinate are never on the front."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    mask = np.zeros(len(x), bool)
    for i in np.flatnonzero(ok):
        dominated = ok & (x <= x[i]) & (y <= y[i]) & ((x < x[i]) | (y < y[i]))
        mask[i] = not dominated.any()
    return mask


def loglog_slope(x, y) -> float | None:
    """Least-squares slope of log y against log x (None with fewer than two distinct x)."""
    x, y = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    if len(np.unique(x)) < 2:
        return None
    return float(np.polyfit(x, y, 1)[0])


def pooled_loglog_slope(groups) -> float | None:
    """One slope b for log y = a_g + b log x over several series ``groups`` [(x, y), ...],
    each with its own intercept a_g (e.g. time against pixels, one series per sample count)."""
    xs, ys = [], []
    for x, y in groups:
        lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
        if len(np.unique(lx)) >= 2:
            xs.append(lx - lx.mean())
            ys.append(ly - ly.mean())
    if not xs:
        return None
    x, y = np.concatenate(xs), np.concatenate(ys)
    return float(x @ y / (x @ x))


def affine_fit(x, y) -> tuple[float, float]:
    """(intercept, slope) of the least-squares line y = a + b x."""
    b, a = np.polyfit(np.asarray(x, float), np.asarray(y, float), 1)
    return float(a), float(b)


# -- plots ----------------------------------------------------------------------------------
_MARKERS = {"rsvd": "o", "paper": "s", "jpeg": "^", "pca-view": "D", "video": "v"}


def _pyplot():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _log_axes(ax, plain_x: bool = True) -> None:
    """Log-log axes labelled with plain numbers (0.5, 20) rather than powers of ten (x too
    unless ``plain_x`` is False, e.g. for byte counts spanning decades)."""
    from matplotlib.ticker import FormatStrFormatter

    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis, name in ((ax.yaxis, "y"), (ax.xaxis, "x") if plain_x else (None, None)):
        if axis is not None:
            axis.set_major_formatter(FormatStrFormatter("%g"))
            axis.set_minor_formatter(FormatStrFormatter("%g"))
            ax.tick_params(axis=name, which="minor", labelsize=7)
    ax.grid(alpha=0.3, which="both")


def _save(fig, path: Path) -> Path:
    with atomic_file(path) as tmp:
        fig.savefig(tmp, format="png")
    return Path(path)


def plot_tradeoffs(rows: list, path: Path, title: str, held_floor: float | None = None) -> Path:
    """2 x 2 panels: (fitted, held-out) percent error against (wall time, stored bytes),
    one line per method label through its sweep, Pareto fronts as dashed black steps;
    ``held_floor`` (the held-out error of the original images) as a grey line."""
    plt = _pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5), dpi=100)
    labels = list(dict.fromkeys(r["method"] for r in rows))
    cmap = plt.get_cmap("tab20")
    for ri, (err_key, err_name) in enumerate((("fit_percent", "fitted samples"), ("held_percent", "held-out samples"))):
        for ci, (x_key, x_name) in enumerate((("wall_s", "wall time per run, s (median)"),
                                             ("stored_bytes", "stored bytes"))):
            ax = axes[ri, ci]
            pts = [r for r in rows if r.get(err_key) is not None and r.get(x_key)]
            for n, label in enumerate(labels):
                mine = sorted((r for r in pts if r["method"] == label), key=lambda r: r["param"])
                if not mine:
                    continue
                ax.plot([r[x_key] for r in mine], [r[err_key] for r in mine], marker=_MARKERS.get(mine[0]["family"], "o"),
                        ms=5, lw=1.2, color=cmap(n % 20), label=label)
            if pts:
                x = np.array([r[x_key] for r in pts], float)
                y = np.array([r[err_key] for r in pts], float)
                front = pareto_mask(x, y)
                order = np.argsort(x[front])
                ax.step(x[front][order], y[front][order], where="post", ls="--", color="k", lw=1, label="Pareto front")
                ax.scatter(x[front], y[front], s=90, facecolors="none", edgecolors="k", lw=1)
            if ri == 1 and held_floor is not None:
                ax.axhline(held_floor, color="0.5", lw=1, ls=":", label="held-out floor (original images)")
            _log_axes(ax, plain_x=(x_key == "wall_s"))
            ax.set_xlabel(x_name)
            ax.set_ylabel(f"percent error, {err_name}")
    handles, names = max((ax.get_legend_handles_labels() for ax in axes[:, 0]), key=lambda hn: len(hn[0]))
    fig.legend(handles, names, loc="lower center", ncol=min(6, len(names)), fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 0.97))
    out = _save(fig, path)
    plt.close(fig)
    return out


def plot_scaling(rows: list, path: Path, title: str) -> Path:
    """Log-log wall time and peak memory against samples x texels, one marker per memory
    mode, one line per sample count."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), dpi=100)
    modes = list(dict.fromkeys(r["mode"] for r in rows))
    cmap = plt.get_cmap("tab10")
    for ax, key, name, scale in ((axes[0], "wall_s", "wall time, s (median)", 1.0),
                                 (axes[1], "peak_mem_bytes", "peak memory, MB", 1e-6)):
        for m, mode in enumerate(modes):
            for n, S in enumerate(sorted({r["samples"] for r in rows})):
                mine = sorted((r for r in rows if r["mode"] == mode and r["samples"] == S and r.get(key)),
                              key=lambda r: r["values"])
                if mine:
                    ax.plot([r["values"] for r in mine], [r[key] * scale for r in mine], marker="os^Dv"[m % 5],
                            ls="-" if m == 0 else "--", color=cmap(n % 10), label=f"{mode}, S = {S}")
        _log_axes(ax, plain_x=False)
        ax.set_xlabel("samples x texels (S P)")
        ax.set_ylabel(name)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    out = _save(fig, path)
    plt.close(fig)
    return out


def plot_sweep(rows: list, path: Path, *, x: str, y: str, series: str, point: str, xlabel: str, ylabel: str,
               title: str, references: dict | None = None) -> Path:
    """One log-log panel: a line per value of ``series`` through its points (annotated with
    ``point``), the Pareto front of all rows dashed, ``references`` {label: (x, y)} as crosses."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 5.5), dpi=100)
    cmap = plt.get_cmap("tab10")
    for n, value in enumerate(dict.fromkeys(r[series] for r in rows)):
        mine = [r for r in rows if r[series] == value]
        ax.plot([r[x] for r in mine], [r[y] for r in mine], marker="o", color=cmap(n % 10), label=f"{series} {value}")
        for r in mine:
            ax.annotate(f"{point} {r[point]}", (r[x], r[y]), fontsize=6, xytext=(3, 3), textcoords="offset points")
    for n, (label, (rx, ry)) in enumerate((references or {}).items()):
        ax.scatter([rx], [ry], marker="x", s=50, color=cmap(n % 10), label=label)
    if rows:
        xs, ys = np.array([r[x] for r in rows], float), np.array([r[y] for r in rows], float)
        front = pareto_mask(xs, ys)
        order = np.argsort(xs[front])
        ax.step(xs[front][order], ys[front][order], where="post", ls="--", color="k", lw=1, label="Pareto front")
    _log_axes(ax)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7)
    ax.set_title(title, fontsize=9)
    fig.tight_layout()
    out = _save(fig, path)
    plt.close(fig)
    return out
