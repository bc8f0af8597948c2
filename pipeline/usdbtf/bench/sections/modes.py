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
   metric this table reports); both budget modes budget the packaged asset, the CLI's
   default (issue 42; ``--budget-for folder`` before);

each timed as a subprocess (median of ``repeats``), with its CPU time, peak memory, stored
bytes (and for a budget the packaged asset's bytes compress recorded), error on fitted and
held-out samples, the wall time over the floor and the error over the paper's.  Each mode also
gets its own floor (issue 42): the same decode, one GEMM with as many columns as the k it
kept, and one encode of exactly the textures and basis it wrote, at its codec and effort
(timed in this process on the folder it wrote).  The table and a plot of time (and bytes)
against error are the trade a user picks from.
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
from ..measure import cpu_seconds
from .compress import ROW_KEYS, Dataset, add_dataset, measure_method

MODE_KEYS = ROW_KEYS + ["mode", "floor_s", "x_floor", "vs_paper", "gemm_k_s", "encode_s", "own_floor_s", "x_own_floor",
                        "asset_bytes", "own_floor_cpu_s", "x_own_floor_cpu"]

COLUMNS = [Column("method", "mode"), Column("wall_s", "time s (median)", ".2f"), Column("cpu_s", "CPU s", ".1f"),
           Column("x_floor", "x floor", ".2f"), Column("own_floor_s", "own floor s", ".2f"),
           Column("x_own_floor", "x own floor", ".2f"), Column("own_floor_cpu_s", "own floor CPU s", ".1f"),
           Column("x_own_floor_cpu", "x own floor CPU", ".2f"),
           Column("peak_mem_mb", "peak MB", ".0f"), Column("k_stored", "k kept"),
           Column("stored_bytes", "stored B", "bytes"), Column("asset_bytes", "asset B", "bytes"), Column("fit_percent", "% err fit", ".3f"),
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

    def details(self, out) -> dict:
        """k kept, the packaged asset's bytes compress recorded (a budget of the asset), and
        ``encode_s`` (``encode_cpu_s``: its CPU seconds, the codec workers' included): one encode of exactly the textures and basis in ``out`` at the codec and
        effort compress wrote them with (the encode part of this mode's own floor)."""
        return {**super().details(out), **encode_floor(out)}


def modes(paper_bytes: int, paper_percent: float) -> list:
    """The modes a user asks for, the byte and error requests at the paper's values (the
    budget modes budget the packaged asset, the CLI's default)."""
    asked = [("--k", "150"), ("--k", "150", "--effort", "full"), ("--max-bytes", str(int(paper_bytes))),
             ("--target-error", f"{paper_percent:.4g}", "--error-domain", "linear")]
    return [Mode("rsvd", "jxlp", n, args) for n, args in enumerate(asked)]


def encode_floor(out) -> dict:
    """{"encode_s": seconds of one encode of every texture of the compressed folder ``out``
    (:func:`usdbtf.compress.format.encode_files`, the codec pool compress uses) at the effort
    its run used, "asset_bytes": the packaged asset's bytes it recorded, or :func:`packaged_bytes`
    where it left them to ``usdbtf package`` (None unless it budgeted the asset)}."""
    from dataclasses import replace

    from ...compress.format import encode_files, read_compressed

    cbtf = read_compressed(out)
    opts = (cbtf.info.get("provenance") or {}).get("options") or {}
    budgeted = opts.get("max_bytes") is not None or opts.get("target_error") is not None
    quick = opts.get("effort") == "quick" or (opts.get("effort", "auto") == "auto" and not budgeted)
    cbtf = replace(cbtf, quick_encode=quick, encoded=None)
    t, c = time.perf_counter(), cpu_seconds()
    encode_files(cbtf)
    encode_s, encode_cpu_s = time.perf_counter() - t, cpu_seconds() - c
    choice = cbtf.info.get("choice") or {}
    asset = None
    if choice.get("budget_for") == "asset":
        # --target-error leaves the asset's count to `usdbtf package` (issue 42): packaged here.
        asset = packaged_bytes(out, cbtf) if (choice.get("asset") or {}).get("counted_by") else choice.get("bytes")
    return {"encode_s": encode_s, "encode_cpu_s": encode_cpu_s, "asset_bytes": asset}


def packaged_bytes(out, cbtf) -> int:
    """Bytes of every file the full lod loads of the asset ``usdbtf package`` writes from the
    compressed folder ``out`` (``cbtf``: it, as read; default options, no validation; a 1 m
    swatch where no physical size is recorded: the size changes no texture), written to a
    temporary folder."""
    import tempfile
    from pathlib import Path

    from ...usd.asset.package import PackageOptions, package, physical_size_of, write_package

    size = physical_size_of(cbtf) or (1.0, 1.0)
    result = package(Path(out), PackageOptions(physical_size=size, validate=False))
    with tempfile.TemporaryDirectory(prefix="usdbtf-bench-asset-") as tmp:
        return int(write_package(result, Path(tmp) / "asset.usda")["bytes"]["full"])


def gemm_seconds(n_samples: int, n_pixels: int, k: int, *, cpu: bool = False):
    """Seconds of one float32 (k, S) x (S, 3P) product on all BLAS threads (random data);
    ``cpu``: (wall, CPU) seconds, the CPU of every BLAS thread."""
    rng = np.random.default_rng(0)
    x = rng.random((n_samples, 3 * n_pixels), dtype=np.float32)
    u = rng.standard_normal((n_samples, k), dtype=np.float32)
    u.T @ x[:, :1024]                                   # warm-up (threads, page faults)
    t, c = time.perf_counter(), cpu_seconds()
    u.T @ x
    wall, used = time.perf_counter() - t, cpu_seconds() - c
    return (wall, used) if cpu else wall


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


def floor_seconds(fitted_dir, n_samples: int, n_pixels: int, *, cpu: bool = False) -> tuple:
    """(decode s, GEMM s): every file of ``fitted_dir`` decoded once in one forked process per
    CPU, and one float32 (FLOOR_K, S) x (S, 3P) product on all BLAS threads (random data).
    ``cpu``: also the decode's CPU seconds (its workers', reaped when the pool closes)."""
    import OpenImageIO as oiio

    workers = max(1, len(os.sched_getaffinity(0)))
    _FILES[:] = [fitted_dir]
    _OPEN.clear()
    oiio.attribute("threads", 1)
    bounds = np.linspace(0, n_samples, workers * 8 + 1).astype(int)
    t, c = time.perf_counter(), cpu_seconds()
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork")) as pool:
        done = sum(pool.map(_decode, list(zip(bounds[:-1], bounds[1:]))))
    decode, decode_cpu = time.perf_counter() - t, cpu_seconds() - c
    assert done == n_samples
    gemm = gemm_seconds(n_samples, n_pixels, FLOOR_K)
    return (decode, gemm, decode_cpu) if cpu else (decode, gemm)


def _measure_mode(ctx: Context, ds, mode: Mode) -> dict:
    """``mode``'s row; a budget of the asset that cannot hold what packaging alone adds (the
    paper's bytes at small samplings and sizes: 73 KB of fallback maps, thumbnail and layers
    against 27 KB at tiny 32²) is measured again budgeting the folder, and its label says so."""
    row = measure_method(ctx, ds, mode, (None, "not used"))
    if "packaging alone adds" in str(row.get("status")):
        ctx.say(f"    {mode.label}: the asset cannot hold the paper's bytes; measured with --budget-for folder")
        row = measure_method(ctx, ds, Mode(mode.family, mode.codec, mode.param, (*mode.args, "--budget-for", "folder")),
                             (None, "not used"))
    return row


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
        decode, gemm, decode_cpu = floor_seconds(ds.fitted_dir, len(ds.fit_idx), size * size, cpu=True)
        floor = decode + gemm
        ctx.say(f"  floor: decode {decode:.2f} s + GEMM {gemm:.2f} s = {floor:.2f} s (load {os.getloadavg()[0]:.1f})")
        paper = measure_method(ctx, ds, Method("paper", "jpeg", 150), (None, "not used"))
        rows = [paper]
        if paper.get("status") == "ok":
            rows += [_measure_mode(ctx, ds, m) for m in modes(paper["stored_bytes"], paper["fit_percent"])]
        for r in rows:
            r.update(mode=r["method"], floor_s=floor)
            if r.get("status") == "ok":
                r["x_floor"] = r["wall_s"] / floor
                r["vs_paper"] = r["fit_percent"] / paper["fit_percent"]
                if r.get("encode_s") is not None:
                    # This mode's own floor (issue 42): the decode, a GEMM as wide as the k it
                    # kept, one encode of what it wrote.
                    r["gemm_k_s"], gemm_cpu = gemm_seconds(len(ds.fit_idx), size * size, int(r["k_stored"]), cpu=True)
                    r["own_floor_s"] = decode + r["gemm_k_s"] + r["encode_s"]
                    r["x_own_floor"] = r["wall_s"] / r["own_floor_s"]
                    # The same floor in CPU seconds (a shared machine's wall times vary with its
                    # load; CPU seconds much less): what a mode's CPU is compared with.
                    r["own_floor_cpu_s"] = decode_cpu + gemm_cpu + r["encode_cpu_s"]
                    r["x_own_floor_cpu"] = r["cpu_s"] / r["own_floor_cpu_s"]
                    ctx.say(f"    {r['method']}: own floor {r['own_floor_s']:.2f} s (decode {decode:.2f} + GEMM "
                            f"k={r['k_stored']} {r['gemm_k_s']:.2f} + encode {r['encode_s']:.2f}); "
                            f"{r['wall_s']:.2f} s wall = {r['x_own_floor']:.2f}x; CPU {r['cpu_s']:.1f} s against "
                            f"its floor's {r['own_floor_cpu_s']:.1f} s (decode {decode_cpu:.1f} + GEMM {gemm_cpu:.1f} "
                            f"+ encode {r['encode_cpu_s']:.1f}) = {r['x_own_floor_cpu']:.2f}x; "
                            f"{r['x_floor']:.2f}x the decode + 150-column floor")
        title = (f"{preset}, sampling {cfg.sampling} ({len(ds.fit_idx)} fitted + {len(ds.held_idx)} held-out samples), "
                 f"{size}x{size}; floor {floor:.2f} s (decode {decode:.2f} + GEMM {gemm:.2f})")
        add_dataset(result, rows, COLUMNS, title, plots_dir / f"{ds.name}.png",
                    f"usdbtf bench modes: {title}; {cfg.repeats} repeat(s)")
    result.notes.append(
        "mode = how compress was asked (the paper baseline: --solver paper --k 150); --max-bytes and --target-error "
        "take the paper row's stored bytes and fitted error (scene-linear); time = median wall time of the "
        "subprocess; x floor = time / (decode + GEMM) measured in the same run; own floor = decode + a GEMM with "
        "as many columns as the k kept + one encode of the folder's textures and basis at the codec and effort "
        "written (issue 42), x own floor = time / it; own floor CPU = the same three steps' CPU seconds (decode workers, "
        "BLAS threads and codec workers included), x own floor CPU = the mode's CPU / it; asset B = the packaged asset's full lod (budget modes, "
        "which budget the asset: --max-bytes's as compress recorded them, --target-error's as usdbtf package "
        "writes it, since compress leaves that count to package); err / paper's = fitted error over the paper row's; errors as in "
        "the compress section.")
    return result


SECTION = Section(name="modes", title="Compression modes: run time against error, and the paper baseline",
                  order=12, run=run, requires=("usdbtf.compress",))
