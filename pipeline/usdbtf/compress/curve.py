"""Error versus number of basis vectors (the paper's Fig. 3), from the stored representation."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from .format import working_coefficient_texels
from .metrics import ErrorSums
from .parallel import in_threads, one_blas_thread

__all__ = ["error_curve", "write_curve", "plot_curve", "curve_samples", "curve_ks"]


def curve_samples(n_samples: int, count: int = 16) -> np.ndarray:
    """Sample indices the curve is measured on: ``count`` spread evenly over the sampling."""
    return np.unique(np.linspace(0, n_samples - 1, min(count, n_samples)).round().astype(int))


def curve_ks(k: int, count: int = 48) -> np.ndarray:
    """The k values the curve is evaluated at: every k up to 20, then ~log-spaced to k."""
    head = np.arange(1, min(k, 20) + 1)
    tail = np.unique(np.geomspace(21, k, max(count - 20, 2)).round().astype(int)) if k > 20 else []
    return np.unique(np.r_[head, tail, k]).astype(int)


def curve_truth(data, n_samples: int) -> np.ndarray:
    """(r, P, 3) the working-domain images :func:`error_curve` measures, read from ``data``
    (``working_samples``) for ``n_samples`` samples: a caller may take them before it lets
    the source go."""
    return data.working_samples(curve_samples(n_samples))


def error_curve(cbtf, data, *, texels_per_block: int = 4096, truth: np.ndarray | None = None) -> dict:
    """Percent error vs k, the paper's Fig. 3, of the stored representation.

    Measured over all texels of ``curve_samples`` (the paper plots one view/light pair;
    a spread of samples is more representative), reconstructed by Eq. (2) from the first k
    components at the :func:`curve_ks` points up to cbtf.k.  The residual is updated from
    one curve point to the next by the basis columns in between, so the whole curve costs
    one k-column GEMM plus two sums per point.

    Parameters
    ----------
    cbtf : the stored representation.
    data : the source (``working_samples(rows)`` -> (r, P, 3) truth in the working domain;
        the error is measured after ``cbtf.domain``'s inverse curve, in scene-linear).
    truth : :func:`curve_truth` of ``data``, read before (``data`` is then not used; None).
    texels_per_block : texels decoded from the coefficient textures at a time (a block holds
        ~8 float32 values per texel, channel and component: 4096 texels at k 150 ~20 MB).

    Returns
    -------
    dict : "k" (list of int), "percent" (the paper's metric, working space), "rmse" (linear
    units), "samples" (the sample indices measured).
    """
    rows = curve_samples(cbtf.n_samples)
    truth = curve_truth(data, cbtf.n_samples) if truth is None else truth    # (r, P, 3), working domain
    basis = cbtf.basis_values()[rows]                                    # (r, k)
    dom = cbtf.domain
    total = float(dom.inverse(truth).sum(dtype=np.float64))
    ks = curve_ks(cbtf.k)
    P = cbtf.width * cbtf.height

    def block(t0: int) -> list:
        """Every curve point's sums over texels t0.. (a block of the k coefficient textures
        decoded at a time)."""
        t1 = min(t0 + texels_per_block, P)
        sums = [ErrorSums() for _ in ks]
        coeff = working_coefficient_texels(cbtf, slice(t0, t1)).reshape(cbtf.k, -1)   # (k, 3 n)
        residual = np.array(truth[:, t0:t1].reshape(len(rows), -1))                    # (r, 3 n)
        done = 0
        truth_lin = None if dom.is_linear else dom.inverse(truth[:, t0:t1].reshape(len(rows), -1))
        for k, acc in zip(ks, sums):
            residual -= basis[:, done:k] @ coeff[done:k]
            done = k
            if truth_lin is None:
                acc.add_difference(residual.reshape(-1))
            else:   # the error is scene-linear: truth - inverse(domain truth - domain residual)
                acc.add(truth_lin, dom.inverse(truth[:, t0:t1].reshape(len(rows), -1) - residual))
        return sums

    # The blocks on every core (one BLAS thread each), their sums added in block order: the
    # same numbers on any machine.
    with one_blas_thread():
        parts = in_threads(block, range(0, P, texels_per_block))
    sums = [ErrorSums() for _ in ks]
    for part in parts:
        for acc, p in zip(sums, part):
            acc.merge(p)
    count = truth.size
    pct = [100.0 * acc.abs_err / total if total > 0 else float("nan") for acc in sums]
    rmse = [float(np.sqrt(acc.sq_err / count)) for acc in sums]
    return {"k": ks.tolist(), "percent": pct, "rmse": rmse, "samples": rows.tolist()}


def write_curve(curve: dict, folder: Path) -> None:
    """error_curve.csv (k, percent, rmse) and error_curve.png."""
    with open(folder / "error_curve.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["k", "percent_error", "rmse_linear"])
        for row in zip(curve["k"], curve["percent"], curve["rmse"]):
            w.writerow([row[0], f"{row[1]:.6g}", f"{row[2]:.6g}"])
    plot_curve({"this BTF": curve}, folder / "error_curve.png")


def plot_curve(curves: dict, path, title: str = "Percent error vs number of basis vectors") -> None:
    """A line plot like the paper's Fig. 3, one line per entry of ``curves`` (label -> curve).

    Drawn with OpenCV (already loaded for decoding) and written through OpenImageIO:
    importing matplotlib would cost more than compressing a small BTF.
    """
    import cv2

    from ..imageio import write_image

    W, H, left, right, top, bottom = 640, 420, 70, 20, 40, 55
    img = np.full((H, W, 3), 255, np.uint8)
    kmax = max(max(c["k"]) for c in curves.values())
    ymax = max(max(c["percent"]) for c in curves.values()) * 1.05 or 1.0
    px = lambda k: int(round(left + (W - left - right) * (k - 1) / max(kmax - 1, 1)))
    py = lambda v: int(round(H - bottom - (H - top - bottom) * v / ymax))
    grey, black = (200, 200, 200), (0, 0, 0)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for tick in _ticks(ymax):
        cv2.line(img, (left, py(tick)), (W - right, py(tick)), grey, 1)
        cv2.putText(img, f"{tick:g}", (8, py(tick) + 4), font, 0.4, black, 1, cv2.LINE_AA)
    for tick in _ticks(kmax):
        if tick >= 1:
            cv2.line(img, (px(tick), top), (px(tick), H - bottom), grey, 1)
            cv2.putText(img, f"{tick:g}", (px(tick) - 10, H - bottom + 18), font, 0.4, black, 1, cv2.LINE_AA)
    cv2.rectangle(img, (left, top), (W - right, H - bottom), black, 1)
    colors = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189)]  # RGB
    for n, (label, c) in enumerate(curves.items()):
        pts = np.array([[px(k), py(v)] for k, v in zip(c["k"], c["percent"])], np.int32)
        cv2.polylines(img, [pts], False, colors[n % 4], 2, cv2.LINE_AA)
        if len(curves) > 1:
            cv2.putText(img, label, (W - right - 200, top + 18 + 16 * n), font, 0.45, colors[n % 4], 1, cv2.LINE_AA)
    cv2.putText(img, title, (left, 25), font, 0.5, black, 1, cv2.LINE_AA)
    cv2.putText(img, "number of basis vectors k", (W // 2 - 90, H - 15), font, 0.45, black, 1, cv2.LINE_AA)
    cv2.putText(img, "% error", (8, top - 10), font, 0.45, black, 1, cv2.LINE_AA)
    write_image(path, img, color_space="sRGB Encoded Rec.709 (sRGB)")


def _ticks(top: float) -> list:
    """About five round tick values in [0, top]."""
    if top <= 0:
        return [0.0]
    raw = top / 5
    mag = 10 ** np.floor(np.log10(raw))
    step = min((m * mag for m in (1, 2, 5, 10) if m * mag >= raw), default=raw)
    return [float(v) for v in np.arange(0, top + 1e-9, step)]
