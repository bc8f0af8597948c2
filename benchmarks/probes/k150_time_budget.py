#!/usr/bin/env python
"""Where ``compress --k 150`` spends its CPU time above its floor (issue 42), in one process.

Prints, in this order and all measured in this run:

floor     a decode-only pass (``bench_scale.decode_pass``: every file read by OpenImageIO in
          ``--workers`` forked processes, values discarded) and one float32 GEMM with a
          150-column basis (``bench_scale.gemm_pass``): CPU seconds of each.
compress  ``compress(INPUT, k=150)`` in process: CPU and wall seconds of each step (this
          process, all threads, between the step's entry and exit; held_out_errors and
          error_curve run side by side inside ``_side_by_side`` and share the process's clock)
          and of its child processes (the decode workers, the encode workers; reaped children); CPU / wall per step says how well a step
          uses the cores on a quiet machine (2 = both); the projection's
          per-tile work split by thread CPU time into the curve conversion (stored codes ->
          working-domain floats: table, primaries matrix, domain curve), the colour mix, and
          the rest (the GEMMs and the accumulation).
memo      whether converting each distinct (r, g, b) code triple of a projection tile once and
          gathering gives the same float32 bits as converting the tile (the "float conversion
          per value" lever of issue 42): distinct triples per tile, differing values, ulps; and
          whether converting the tile in cache-sized pieces of 16 rows does (and its thread CPU).

    .venv/bin/python benchmarks/probes/k150_time_budget.py INPUT [--workers 2] [--no-memo | --memo-only]

Nothing is kept (the output folder is written to a temporary folder, timed, and removed).  On a shared machine read the CPU columns, not wall time.
"""
from __future__ import annotations

import sys as _sys
from pathlib import Path as _Path

_sys.path.insert(0, str(_Path(__file__).resolve().parents[1]))   # benchmarks/: common.py and bench_scale

import argparse
import collections
import functools
import os
import resource
import sys
import tempfile
import threading
import time
from pathlib import Path

import usdbtf  # noqa: F401,E402  (before numpy: pins the numeric platform, usdbtf.numeric)
import numpy as np

from bench_scale import decode_pass, gemm_pass
from common import format_machine, machine_info
from usdbtf import color
from usdbtf.compress import core, domain_choice, ratecontrol
from usdbtf.compress import convert, projection
from usdbtf.compress.domain import parse_domain
from usdbtf.compress.options import CompressOptions
from usdbtf.compress.source import _Source
from usdbtf.io import open_btf

_STEPS = [(core, "load_source"), (core, "choose_domain"), (core, "fit_source"), (core, "held_out_set"),
          (core, "sampled_coefficients"), (core, "step_for_k"), (core, "project"), (core, "rate_control"),
          (core, "held_out_errors"), (core, "error_curve"), (core, "_side_by_side")]
#: Steps that run inside another timed step (their CPU is already in it).
_NESTED = ("held_out_errors", "error_curve")


def children_cpu() -> float:
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return kids.ru_utime + kids.ru_stime


class Ledger:
    """CPU seconds by name: process CPU per wrapped step, thread CPU per projection part."""

    def __init__(self):
        self.steps: dict = collections.Counter()
        self.walls: dict = collections.Counter()
        self.kids: dict = collections.Counter()
        self.caller: dict = collections.Counter()
        self.parts: dict = collections.Counter()
        self.lock = threading.Lock()

    def wrap_step(self, module, name: str) -> None:
        fn = getattr(module, name)

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            c, t, k, own = time.process_time(), time.perf_counter(), children_cpu(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                with self.lock:
                    self.steps[name] += time.process_time() - c
                    self.walls[name] += time.perf_counter() - t
                    self.kids[name] += children_cpu() - k
                    self.caller[name] += time.thread_time() - own

        setattr(module, name, wrapper)

    def thread_timed(self, part: str, fn):
        """``fn`` timed in the calling thread's CPU clock while a projection tile runs."""
        local = self._in_tile

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            if not getattr(local, "on", False) or getattr(local, "busy", False):
                return fn(*args, **kwargs)     # outside a tile, or inside a timed part (no double count)
            local.busy = True
            t = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                local.busy = False
                with self.lock:
                    self.parts[part] += time.thread_time() - t

        return wrapper

    _in_tile = threading.local()

    def wrap_tiles(self) -> None:
        accumulate = projection.TileProjector._accumulate
        local = self._in_tile

        def timed(proj, s0, raw, accs):
            local.on = True
            t = time.thread_time()
            try:
                return accumulate(proj, s0, raw, accs)
            finally:
                local.on = False
                with self.lock:
                    self.parts["tile total"] += time.thread_time() - t
                    self.parts["tiles"] += 1

        projection.TileProjector._accumulate = timed
        convert.Conversion.__call__ = self.thread_timed("curve conversion", convert.Conversion.__call__)
        if hasattr(convert, "TripleConversion"):        # issue 42, third session: the memo's own __call__
            convert.TripleConversion.__call__ = self.thread_timed("curve conversion",
                                                                  convert.TripleConversion.__call__)
        # projection.py calls color.mix_rgb / color.mix_channel through the module: patch there.
        color.mix_rgb = self.thread_timed("colour mix", color.mix_rgb)
        color.mix_channel = self.thread_timed("colour mix", color.mix_channel)


def memo_probe(btf, n_tiles: int = 4, tile: int = 512) -> list:
    """Per tile (``tile`` consecutive samples x one 1,024-texel block, as the projection cuts
    them): distinct code triples, and the float32 values where converting each distinct triple
    once (a (1, 3 u) array) and gathering differs from converting the tile."""
    source = _Source(btf)
    curves = source.curves_in(parse_domain("srgb"))
    # The OpenCV chain (table, cv2.transform, curve) that the memo replaced (issue 42, third
    # session): how far the memo's float64-matrix values are from it.
    chain = convert.Conversion(source._decode, source.matrix, parse_domain("srgb"), nonnegative=curves.nonnegative)
    rows = []
    for n in range(n_tiles):
        s0 = (n * btf.n_samples // n_tiles) // tile * tile
        imgs = np.stack([btf.read_one(i) for i in range(s0, min(s0 + tile, btf.n_samples))])
        flat = imgs.reshape(len(imgs), -1)
        blk = (n * 5) % max(1, flat.shape[1] // 3072)
        raw = np.ascontiguousarray(flat[:, blk * 3072:(blk + 1) * 3072])
        whole = curves(raw)
        tri = raw.reshape(-1, 3).astype(np.uint32)
        uniq, inv = np.unique(tri[:, 0] << 16 | tri[:, 1] << 8 | tri[:, 2], return_inverse=True)
        codes = np.stack([uniq >> 16, (uniq >> 8) & 255, uniq & 255], 1).astype(np.uint8).reshape(1, -1)
        memo = curves(codes).reshape(-1, 3)[inv.reshape(-1)].reshape(raw.shape)
        ulps = np.abs(whole.view(np.int32).astype(np.int64) - memo.view(np.int32))
        opencv = chain(raw)
        off = np.abs(whole.view(np.int32).astype(np.int64) - opencv.view(np.int32))
        rel = float(np.max(np.abs(whole - opencv) / np.maximum(np.abs(opencv), 1e-30)))
        # The same tile converted 16 rows at a time (cache-sized pieces): the same bits?  cheaper?
        pieces = np.empty_like(whole)
        t_whole = _thread_cpu(lambda: curves(raw, out=whole))
        t_pieces = _thread_cpu(lambda: [curves(raw[r:r + 16], out=pieces[r:r + 16]) for r in range(0, len(raw), 16)])
        rows.append((s0, blk, len(tri), len(uniq), int(np.count_nonzero(ulps)), int(ulps.max()),
                     int(np.count_nonzero(whole.view(np.int32) != pieces.view(np.int32))),
                     f"{t_whole * 1e3:.2f}", f"{t_pieces * 1e3:.2f}", int(np.count_nonzero(off)), int(off.max()),
                     f"{rel:.1e}"))
    return rows


def _thread_cpu(fn, n: int = 9) -> float:
    """Median thread CPU seconds of ``n`` calls of ``fn`` (after one warm-up)."""
    fn()
    runs = []
    for _ in range(n):
        t = time.thread_time()
        fn()
        runs.append(time.thread_time() - t)
    return float(np.median(runs))


def main(argv=None) -> int:  # noqa: C901 (one report, printed in order)
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("input")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-memo", action="store_true", help="skip the memo table (the last section)")
    ap.add_argument("--memo-only", action="store_true", help="only the memo table")
    args = ap.parse_args(argv)
    print(format_machine(machine_info()))
    btf = open_btf(args.input)
    print(f"\ninput: {args.input} ({btf.n_samples} samples of {btf.width}x{btf.height}, {btf.bit_depth}); "
          f"load {os.getloadavg()[0]:.1f}\n")

    if args.memo_only:
        return print_memo(btf)
    dec_wall, dec_cpu = decode_pass(btf, args.workers)
    gemm_wall, ginfo = gemm_pass(btf.n_samples, btf.n_pixels)
    floor = dec_cpu + ginfo["cpu_s"]
    print(f"floor: decode {dec_cpu:.2f} s CPU ({dec_wall:.2f} s wall) + GEMM {ginfo['cpu_s']:.2f} s CPU "
          f"({gemm_wall:.2f} s wall) = {floor:.2f} s CPU", flush=True)

    ledger = Ledger()
    for module, name in _STEPS:
        if hasattr(module, name):
            ledger.wrap_step(module, name)
    ledger.wrap_tiles()
    kids, c, t = children_cpu(), time.process_time(), time.perf_counter()
    result = core.compress(btf, CompressOptions(k=150, workers=args.workers))
    own, workers, wall = time.process_time() - c, children_cpu() - kids, time.perf_counter() - t
    with tempfile.TemporaryDirectory() as tmp:
        c, t = time.process_time(), time.perf_counter()
        core.write_compress(result, Path(tmp) / "out")
        write_cpu, write_wall = time.process_time() - c, time.perf_counter() - t
    total = own + workers
    print(f"\ncompress --k 150: {total:.2f} s CPU ({own:.2f} in process + {workers:.2f} in child processes: decode and encode workers), "
          f"{wall:.2f} s wall; {total / floor:.2f}x the floor's CPU; load {os.getloadavg()[0]:.1f}\n")
    print("| step | CPU s in process | of which on the calling thread | CPU s in child processes | share of compress CPU "
          "| wall s | CPU / wall | quiet 2-core wall bound s |\n|---|---|---|---|---|---|---|---|")
    bound_total = 0.0
    for name, sec in ledger.steps.items():
        w, k, main = ledger.walls[name], ledger.kids[name], ledger.caller[name]
        # On 2 idle cores a step takes at least max(its calling thread's CPU, all its CPU / 2).
        bound = max(main, (sec + k) / 2)
        bound_total += bound if name not in _NESTED else 0.0
        print(f"| {name} | {sec:.2f} | {main:.2f} | {k:.2f} | {(sec + k) / total:.0%} | {w:.2f} | "
              f"{(sec + k) / max(w, 1e-9):.2f} | {bound:.2f} |")
    rest = own - sum(v for k, v in ledger.steps.items() if k not in _NESTED)
    rest_kids = workers - sum(v for k, v in ledger.kids.items() if k not in _NESTED)
    rest_wall = wall - sum(v for k, v in ledger.walls.items() if k not in _NESTED)
    print(f"| (the rest of compress: colour, timers, ...) | {rest:.2f} | | {rest_kids:.2f} | "
          f"{(rest + rest_kids) / total:.0%} | {rest_wall:.2f} | {(rest + rest_kids) / max(rest_wall, 1e-9):.2f} | "
          f"{rest:.2f} |")
    floor_bound = max(dec_cpu / 2, 0) + ginfo["cpu_s"] / 2
    print(f"\nquiet 2-core wall bounds: compress >= {bound_total + rest:.2f} s, the floor >= {floor_bound:.2f} s "
          f"(its CPU / 2): ratio >= {(bound_total + rest) / floor_bound:.2f} (interpreter start, imports and the "
          f"manifest read not included)")
    print(f"\nwriting the output folder (write_compress, after compress; the CLI does it): {write_cpu:.2f} s CPU, "
          f"{write_wall:.2f} s wall")
    parts = ledger.parts
    tiles = parts.pop("tiles", 0)
    gemm = parts["tile total"] - parts["curve conversion"] - parts["colour mix"]
    print(f"\nprojection tiles ({tiles}), thread CPU s:\n\n| part | CPU s |\n|---|---|")
    for name in ("curve conversion", "colour mix"):
        print(f"| {name} | {parts[name]:.2f} |")
    print(f"| GEMMs and accumulation | {gemm:.2f} |\n| all tiles | {parts['tile total']:.2f} |")

    if args.no_memo:
        return 0
    return print_memo(btf)


def print_memo(btf) -> int:
    print("\nmemo of the conversion per distinct code triple (srgb domain), per tile:\n")
    print("| first sample | block | texels x samples | distinct triples | memo: values that differ | memo: max ulps "
          "| 16-row pieces: values that differ | whole tile ms | 16-row pieces ms | vs the OpenCV chain: values that differ "
          "| max ulps | max relative |\n|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in memo_probe(btf):
        print("| " + " | ".join(str(v) for v in row) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
