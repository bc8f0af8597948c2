"""Error versus number of basis vectors (the paper's Fig. 3), from the stored representation."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

__all__ = ["error_curve", "write_curve", "plot_curve", "curve_samples"]


def curve_samples(n_samples: int, count: int = 16) -> np.ndarray:
    """Sample indices the curve is measured on: ``count`` spread evenly over the sampling."""
    return np.unique(np.linspace(0, n_samples - 1, min(count, n_samples)).round().astype(int))


def error_curve(cbtf, data, seed: int = 0) -> dict:
    """Percent error (paper's metric, working space) vs k for every k = 1..cbtf.k.

    Measured over all texels of ``curve_samples`` (the paper plots one view/light pair;
    a spread of samples is more representative).  Returns {"k": [...], "percent": [...],
    "rmse": [...], "samples": [...]}.
    """
    rows = curve_samples(cbtf.n_samples)
    truth = _rows_working(data, rows)                                    # (r, P, 3)
    basis = cbtf.basis_values()[rows]                                    # (r, k)
    m = np.asarray(cbtf.color_matrix, np.float32)
    acc = np.zeros_like(truth)
    total = float(truth.sum(dtype=np.float64))
    ks, pct, rmse = [], [], []
    for i in range(cbtf.k):
        c = cbtf.coefficients[i].values().reshape(-1, 3)                 # (P, 3)
        acc += basis[:, i, None, None] * c[None]
        diff = truth - acc @ m.T
        ks.append(i + 1)
        pct.append(100.0 * float(np.abs(diff).sum(dtype=np.float64)) / total if total > 0 else float("nan"))
        rmse.append(float(np.sqrt(np.mean(diff.astype(np.float64) ** 2))))
    return {"k": ks, "percent": pct, "rmse": rmse, "samples": rows.tolist()}


def _rows_working(data, rows):
    enc = data.enc[rows]                                                 # (r, P, 3)
    x = data.curves(enc)
    return x @ data.matrix.T if data.matrix is not None else x


def write_curve(curve: dict, folder: Path) -> None:
    """error_curve.csv (k, percent, rmse) and error_curve.png."""
    with open(folder / "error_curve.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["k", "percent_error", "rmse_linear"])
        for row in zip(curve["k"], curve["percent"], curve["rmse"]):
            w.writerow([row[0], f"{row[1]:.6g}", f"{row[2]:.6g}"])
    plot_curve({"this BTF": curve}, folder / "error_curve.png")


def plot_curve(curves: dict, path, title: str = "Percent error vs number of basis vectors") -> None:
    """One line per entry of ``curves`` (label -> curve dict), like the paper's Fig. 3."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.4), dpi=110)
    for label, c in curves.items():
        ax.plot(c["k"], c["percent"], label=label, lw=1.4)
    ax.set_xlabel("number of basis vectors k")
    ax.set_ylabel("percent error")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.set_ylim(bottom=0)
    if len(curves) > 1:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
