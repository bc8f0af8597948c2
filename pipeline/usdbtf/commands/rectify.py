"""``usdbtf rectify``: RAW camera frames -> an N x N rectified BTF (manifest folder)."""
from __future__ import annotations

import logging
from pathlib import Path

from ..argtypes import WORKERS, add_outside_paths_flag, float_in, int_in

log = logging.getLogger(__name__)
ORDER = 6
#: Largest rectified side (texels).
MAX_SIZE = 8192


def add_parser(sub) -> None:
    p = sub.add_parser("rectify", help="fiducial homographies: RAW frames -> rectified N x N BTF",
                       description="Detects the board's ArUco markers in every frame, fits a RANSAC homography "
                                   "on sub-pixel corners, warps the sample window to N x N, converts to "
                                   "scene-linear (OCIO) and writes a manifest folder. Frames with too few markers "
                                   "are reported and, like obstructed samples, filled by interpolation "
                                   "(marked \"interpolated\": true).")
    p.add_argument("raw", type=Path, help="RAW folder from usdbtf capture (or any manifest of board frames)")
    p.add_argument("-o", "--output", required=True, type=Path)
    p.add_argument("--size", type=int_in(8, MAX_SIZE), default=128,
                   help=f"output texels per side, 8..{MAX_SIZE} (default 128)")
    p.add_argument("--board", type=Path, help="board.json (default: recorded by capture, else the standard board)")
    p.add_argument("--min-markers", type=int_in(1, 10000), default=4,
                   help="reject frames with fewer markers (default 4)")
    p.add_argument("--max-residual", type=float_in(0, 1e4, lo_open=True), default=1.0, metavar="PX",
                   help="reject frames whose mean corner residual exceeds this (default 1.0 px)")
    p.add_argument("--no-fill", action="store_true", help="refuse instead of interpolating missing samples")
    p.add_argument("--workers", type=WORKERS, default=1, help="processes (default 1)")
    p.add_argument("--format", default="exr", choices=["exr", "png", "tif"], help="output files (default exr)")
    p.add_argument("--bit-depth", default="half", choices=["half", "float", "uint8", "uint16"])
    p.add_argument("--color-space", help="OCIO space of the output files (default ACEScg for float, sRGB for "
                                         "integer depths)")
    add_outside_paths_flag(p)
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import MANIFEST
    return [(args.output, MANIFEST)]


def run(args) -> int:
    from ..atomic import scratch_dir
    from ..errors import UsageError
    from ..fiducials import load_board
    from ..rectify import RectifyOptions, rectify, write_rectify

    if args.format == "png" and args.bit_depth in ("half", "float"):
        raise UsageError("PNG stores uint8 or uint16; pass --bit-depth uint8/uint16 or --format exr")
    space = args.color_space or ("ACEScg" if args.bit_depth in ("half", "float") else "sRGB Encoded Rec.709 (sRGB)")
    board = load_board(args.board) if args.board else None
    opts = RectifyOptions(size=args.size, min_markers=args.min_markers, max_residual_px=args.max_residual,
                          fill=not args.no_fill, workers=args.workers, color_space=space,
                          bit_depth=args.bit_depth, ext=args.format)
    # The rectified samples wait in a memory-mapped file beside the output (a capture's samples
    # need not fit in memory), removed when the output is written.
    with scratch_dir(args.output) as scratch:
        result = rectify(args.raw, opts, board=board, scratch=scratch)
        write_rectify(result, args.output)
        report = result.report
        del result                      # the scratch file's last mapping
    res = report["mean_corner_residual_px"]
    log.info(f"rectify: {report['rectified']} of {report['frames']} frames rectified to {args.size}x{args.size}, "
             f"{len(report['rejected'])} rejected, {report['interpolated']} samples interpolated, "
             f"{len(report['saturated'])} clipped under the window; mean corner "
             f"residual {res:.3f} px -> {args.output}")
    return 0
