"""``usdbtf board``: write a printable fiducial board and its JSON description."""
from __future__ import annotations

from pathlib import Path

from . import log

ORDER = 3


def add_parser(sub) -> None:
    p = sub.add_parser("board", help="printable ArUco board with a central sample window (+ JSON layout)")
    p.add_argument("-o", "--output", required=True, type=Path, help="board image (PNG recommended)")
    p.add_argument("--json", required=True, type=Path, help="board description: marker ids, corners, sample_rect")
    p.add_argument("--grid", type=int, default=10, help="cells per side (default 10)")
    p.add_argument("--window", type=int, default=6, help="cells per side of the central sample window (default 6)")
    p.add_argument("--cell-px", type=int, default=100, help="pixels per cell (default 100)")
    p.add_argument("--dictionary", default="DICT_4X4_100", help="ArUco dictionary (default DICT_4X4_100)")
    p.add_argument("--physical-size", type=float, default=0.12, metavar="M",
                   help="printed edge length of the whole board in metres (default 0.12)")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=run)


def run(args) -> int:
    import json

    from ..atomic import atomic_file
    from ..errors import BTFError
    from ..fiducials import board_image, make_board
    from ..imageio import write_image

    if args.physical_size <= 0:
        raise BTFError(f"--physical-size must be positive, got {args.physical_size}")
    board = make_board(grid=args.grid, window=args.window, cell_px=args.cell_px, dictionary=args.dictionary,
                       physical_size_m=args.physical_size)
    img = board_image(board)
    with atomic_file(args.output) as tmp:
        write_image(tmp, img[..., None], color_space="sRGB Encoded Rec.709 (sRGB)")
    with atomic_file(args.json) as tmp:
        tmp.write_text(json.dumps(board.to_json(), indent=1) + "\n")
    w, h = board.image_size
    log(args.quiet)(f"wrote {args.output} ({w}x{h} px, {len(board.ids)} markers, {board.dictionary}; print at "
                    f"{board.physical_size_m[0] * 100:g} cm, sample window {board.window_size_m[0] * 100:.2f} cm) "
                    f"and {args.json}")
    return 0
