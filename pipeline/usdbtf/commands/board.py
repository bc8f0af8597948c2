"""``usdbtf board``: write a printable fiducial board and its JSON description."""
from __future__ import annotations

from pathlib import Path

from . import log
from ..argtypes import float_in, int_in

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
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import BOARD, BOARD_IMAGE
    return [(args.output, BOARD_IMAGE), (args.json, BOARD)]


def run(args) -> int:
    import json

    from ..atomic import atomic_file
    from ..errors import BTFError, UsageError
    from ..fiducials import board_image, make_board
    from ..imageio import write_image
    from ..outputs import BOARD, BOARD_IMAGE, IMAGE_ATTRIBUTE

    if args.output.resolve() == args.json.resolve():
        raise UsageError("-o and --json must be different files")
    side = args.grid * args.cell_px + 2 * (args.cell_px // 2)
    if side > MAX_SIDE:
        raise UsageError(f"--grid {args.grid} x --cell-px {args.cell_px} makes a {side}-pixel board; at most "
                         f"{MAX_SIDE}")
    try:
        board = make_board(grid=args.grid, window=args.window, cell_px=args.cell_px, dictionary=args.dictionary,
                           physical_size_m=args.physical_size)
    except BTFError as exc:        # every value came from the command line
        raise UsageError(str(exc)) from None
    img = board_image(board)
    with atomic_file(args.output, kind=BOARD_IMAGE) as tmp:
        write_image(tmp, img[..., None], color_space="sRGB Encoded Rec.709 (sRGB)",
                    attributes={IMAGE_ATTRIBUTE: BOARD_IMAGE})
    with atomic_file(args.json, kind=BOARD) as tmp:
        tmp.write_text(json.dumps(board.to_json(), indent=1) + "\n")
    w, h = board.image_size
    log(args.quiet)(f"wrote {args.output} ({w}x{h} px, {len(board.ids)} markers, {board.dictionary}; print at "
                    f"{board.physical_size_m[0] * 100:g} cm, sample window {board.window_size_m[0] * 100:.2f} cm) "
                    f"and {args.json}")
    return 0
