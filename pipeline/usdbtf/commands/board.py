"""``usdbtf board``: write a printable fiducial board and its JSON description."""
from __future__ import annotations

import logging
from pathlib import Path

from ..argtypes import float_in, int_in

log = logging.getLogger(__name__)

ORDER = 3
#: Arguments that name outputs (every other path argument is an input).
OUTPUT_ARGS = ("output", "json")
#: Largest board image side (pixels).
MAX_SIDE = 32768


def add_parser(sub) -> None:
    p = sub.add_parser("board", help="printable ArUco board with a central sample window (+ JSON layout)")
    p.add_argument("-o", "--output", required=True, type=Path, help="board image (PNG recommended)")
    p.add_argument("--json", required=True, type=Path, help="board description: marker ids, corners, sample_rect")
    p.add_argument("--grid", type=int_in(3, 100), default=10, help="cells per side, 3..100 (default 10)")
    p.add_argument("--window", type=int_in(1, 98), default=6,
                   help="cells per side of the central sample window (default 6)")
    p.add_argument("--cell-px", type=int_in(8, 4096), default=100, help="pixels per cell, 8..4096 (default 100)")
    p.add_argument("--dictionary", default="DICT_4X4_100", help="ArUco dictionary (default DICT_4X4_100)")
    p.add_argument("--physical-size", type=float_in(0, 100, lo_open=True), default=0.12, metavar="M",
                   help="printed edge length of the whole board in metres (default 0.12)")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import BOARD, BOARD_IMAGE
    return [(args.output, BOARD_IMAGE), (args.json, BOARD)]


def run(args) -> int:
    from ..board import BoardOptions, board, write_board
    from ..errors import BTFError, UsageError

    if args.output.resolve() == args.json.resolve():
        raise UsageError("-o and --json must be different files")
    side = args.grid * args.cell_px + 2 * (args.cell_px // 2)
    if side > MAX_SIDE:
        raise UsageError(f"--grid {args.grid} x --cell-px {args.cell_px} makes a {side}-pixel board; at most "
                         f"{MAX_SIDE}")
    try:
        result = board(BoardOptions(grid=args.grid, window=args.window, cell_px=args.cell_px,
                                    dictionary=args.dictionary, physical_size_m=args.physical_size))
    except BTFError as exc:        # every value came from the command line
        raise UsageError(str(exc)) from None
    write_board(result, args.output, args.json)
    made = result.board
    w, h = made.image_size
    log.info(f"wrote {args.output} ({w}x{h} px, {len(made.ids)} markers, {made.dictionary}; print at "
             f"{made.physical_size_m[0] * 100:g} cm, sample window {made.window_size_m[0] * 100:.2f} cm) "
             f"and {args.json}")
    return 0
