"""Command-line numbers with bounds: argparse types that refuse out-of-range, NaN and
infinite values with a usage error (exit status 2) naming the option.

    p.add_argument("--size", type=int_in(8, MAX_TEXTURE_SIDE), default=128)
    p.add_argument("--tolerance", type=float_in(0, 100), default=0.1)
"""
from __future__ import annotations

import argparse
import math

__all__ = ["int_in", "float_in", "SEED", "MAX_TEXTURE_SIDE", "MAX_FRAME_SIDE", "WORKERS", "add_outside_paths_flag",
           "OUTSIDE_PATHS_HELP"]

OUTSIDE_PATHS_HELP = ("read manifest images that lie outside the manifest's folder (absolute paths, '..', "
                      "symbolic links out); refused by default")

#: Largest texture or sample side any command makes (texels).
MAX_TEXTURE_SIDE = 16384
#: Largest rendered frame side (pixels).
MAX_FRAME_SIDE = 16384


def _range_text(lo, hi, lo_open=False, hi_open=False) -> str:
    if lo is not None and hi is not None:
        return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {hi:g}"
    return "a finite number"


def int_in(lo: int | None = None, hi: int | None = None):
    """An argparse type: an integer with ``lo <= value <= hi`` (None: unbounded)."""
    def parse(text: str) -> int:
        try:
            value = int(text, 10)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected an integer {_range_text(lo, hi)}, got {text!r}") from None
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"must be an integer {_range_text(lo, hi)}, got {value}")
        return value

    parse.__name__ = "integer"
    return parse


def float_in(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False):
    """An argparse type: a finite float within the bounds (open or closed at each end)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"expected a number {_range_text(lo, hi, lo_open, hi_open)}, "
                                             f"got {text!r}") from None
        bad = not math.isfinite(value)
        bad |= lo is not None and (value <= lo if lo_open else value < lo)
        bad |= hi is not None and (value >= hi if hi_open else value > hi)
        if bad:
            raise argparse.ArgumentTypeError(f"must be a number {_range_text(lo, hi, lo_open, hi_open)}, "
                                             f"got {text}")
        return value

    parse.__name__ = "number"
    return parse


SEED = int_in(0, 2**63 - 1)
WORKERS = int_in(1, 256)


def add_outside_paths_flag(p) -> None:
    """``--allow-outside-paths`` on a command that reads manifests (also accepted before the
    command name, ``usdbtf --allow-outside-paths CMD``, hence no default here)."""
    p.add_argument("--allow-outside-paths", action="store_true", default=argparse.SUPPRESS, help=OUTSIDE_PATHS_HELP)
