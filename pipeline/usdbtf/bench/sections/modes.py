"""Section ``modes``: run time against error for each way of asking ``usdbtf compress`` for a
result, and for the paper baseline, on the same inputs in one run (issue 27).

Per dataset (material preset, sampling from the configuration, ``modes_size`` texels; the
fitted/held-out split of :mod:`.compress`):

1. the floor, measured right before the runs: every fitted image decoded once (OpenImageIO,
   one process per CPU, values discarded) plus one float32 GEMM of the data's shape with a
   150-column basis (U^T X, X = S x 3P);
2. the paper baseline, ``--solver paper --k 150`` (the 2003 method): its stored bytes and its
   error on the fitted samples set the other modes' requests;
3. ``--k 150`` (defaults: quick entropy coding), ``--k 150 --effort full``, ``--max-bytes``
   the paper's bytes, ``--target-error`` the paper's error (``--error-domain linear``, the
   metric this table reports);

each timed as a subprocess (median of ``repeats``), with its peak memory, stored bytes,
error on fitted and held-out samples, the wall time over the floor and the error over the
paper's.  The table and a plot of time (and bytes) against error are the trade a user picks
from.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from . import Context, Section, SectionResult
from ..methods import Method
from ..report import Column
from .compress import ROW_KEYS, Dataset, add_dataset, measure_method

MODE_KEYS = ROW_KEYS + ["mode", "floor_s", "x_floor", "vs_paper"]

COLUMNS = [Column("method", "mode"), Column("wall_s", "time s (median)", ".2f"), Column("x_floor", "x floor", ".2f"),
           Column("peak_mem_mb", "peak MB", ".0f"), Column("k_stored", "k kept"),
           Column("stored_bytes", "stored B", "bytes"), Column("fit_percent", "% err fit", ".3f"),
           Column("vs_paper", "err / paper's", ".3f"), Column("held_percent", "% err held-out", ".3f"),
           Column("pareto", "Pareto (time, bytes)"), Column("status", "status")]

#: The floor's basis width (the paper's k).
FLOOR_K = 150


@dataclass(frozen=True)
class Mode(Method):
    """``usdbtf compress`` with the default solver, asked one way (``args``)."""

    args: tuple = ()

    @property
    def label(self) -> str:
        return "compress " + " ".join(self.args)

    @property
    def param_name(self) -> str:
        return "mode"

    @property
    def slug(self) -> str:
        return "mode-" + "-".join(a.strip("-").replace(".", "_") for a in self.args)

    def command(self, cli: list, fitted_dir, out) -> list:
        return [*cli, "compress", fitted_dir, "-o", out, *self.args]


def modes(paper_bytes: int, paper_percent: float) -> list:
    """The modes a user asks for, the byte and error requests at the paper's values."""
    asked = [("--k", "150"), ("--k", "150", "--effort", "full"), ("--max-bytes", str(int(paper_bytes)), "--budget-for", "folder"),
             ("--target-error", f"{paper_percent:.4g}", "--error-domain", "linear", "--budget-for", "folder")]
    return [Mode("rsvd", "jxlp", n, args) for n, args in enumerate(asked)]


_FILES: list = []
_OPEN: dict = {}


def _decode(bounds) -> int:
    from ...io import open_btf

    if "btf" not in _OPEN:                    # once per worker process (the manifest read is not decode time)
        _OPEN["btf"] = open_btf(_FILES[0])
    btf = _OPEN["btf"]
    for i in range(*bounds):
        btf.read_one(i)
    return bounds[1] - bounds[0]


def floor_seconds(fitted_dir, n_samples: int, n_pixels: int) -> tuple[float, float]:
    """(decode s, GEMM s): every file of ``fitted_dir`` decoded once in one forked process per
    CPU, and one float32 (FLOOR_K, S) x (S, 3P) product on all BLAS threads (random data)."""
    import OpenImageIO as oiio

    workers = max(1, len(os.sched_getaffinity(0)))
    _FILES[:] = [fitted_dir]
    _OPEN.clear()
    oiio.attribute("threads", 1)
    bounds = np.linspace(0, n_samples, workers * 8 + 1).astype(int)
    t = time.perf_counter()
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
        done = sum(pool.map(_decode, list(zip(bounds[:-1], bounds[1:]))))
    decode = time.perf_counter() - t
    assert done == n_samples
    rng = np.random.default_rng(0)
    x = rng.random((n_samples, 3 * n_pixels), dtype=np.float32)
    u = rng.standard_normal((n_samples, FLOOR_K), dtype=np.float32)
    u.T @ x[:, :1024]                                   # warm-up (threads, page faults)
    t = time.perf_counter()
    u.T @ x
    return decode, time.perf_counter() - t


def run(ctx: Context) -> SectionResult:
    from ..measure import warm_page_cache

    cfg = ctx.config
    result = SectionResult(csv_keys=MODE_KEYS)
    plots_dir = ctx.out / "modes"
    for preset in cfg.presets:
        size = cfg.modes_size
        ctx.say(f"\n## modes: {preset}, sampling {cfg.sampling}, {size}x{size}")
        ds = Dataset(ctx, preset, size)
        warm_page_cache(ds.folder)
        warm_page_cache(ds.fitted_dir)
        decode, gemm = floor_seconds(ds.fitted_dir, len(ds.fit_idx), size * size)
        floor = decode + gemm
        ctx.say(f"  floor: decode {decode:.2f} s + GEMM {gemm:.2f} s = {floor:.2f} s (load {os.getloadavg()[0]:.1f})")
        paper = measure_method(ctx, ds, Method("paper", "jpeg", 150), (None, "not used"))
        rows = [paper]
        if paper.get("status") == "ok":
            rows += [measure_method(ctx, ds, m, (None, "not used"))
                     for m in modes(paper["stored_bytes"], paper["fit_percent"])]
        for r in rows:
            r.update(mode=r["method"], floor_s=floor)
            if r.get("status") == "ok":
                r["x_floor"] = r["wall_s"] / floor
                r["vs_paper"] = r["fit_percent"] / paper["fit_percent"]
        title = (f"{preset}, sampling {cfg.sampling} ({len(ds.fit_idx)} fitted + {len(ds.held_idx)} held-out samples), "
                 f"{size}x{size}; floor {floor:.2f} s (decode {decode:.2f} + GEMM {gemm:.2f})")
        add_dataset(result, rows, COLUMNS, title, plots_dir / f"{ds.name}.png",
                    f"usdbtf bench modes: {title}; {cfg.repeats} repeat(s)")
    result.notes.append(
        "mode = how compress was asked (the paper baseline: --solver paper --k 150); --max-bytes and --target-error "
        "take the paper row's stored bytes and fitted error (scene-linear); time = median wall time of the "
        "subprocess; x floor = time / (decode + GEMM) measured in the same run; err / paper's = fitted error over "
        "the paper row's; errors as in the compress section.")
    return result


SECTION = Section(name="modes", title="Compression modes: run time against error, and the paper baseline",
                  order=12, run=run, requires=("usdbtf.compress",))
