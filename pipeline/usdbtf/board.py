"""``board``: a printable fiducial board (:mod:`usdbtf.fiducials`) and its JSON description.

    >>> from usdbtf.board import BoardOptions, board, write_board
    >>> result = board(BoardOptions(grid=10, window=6, cell_px=100))
    >>> write_board(result, "board.png", "board.json")
"""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from .fiducials import Board, board_image, make_board

__all__ = ["BoardOptions", "BoardResult", "board", "write_board", "BOARD_COLOR_SPACE"]

#: The printed image's encoding.
BOARD_COLOR_SPACE = "sRGB Encoded Rec.709 (sRGB)"


@dataclass(frozen=True)
class BoardOptions:
    """grid : cells per side; window : cells per side of the central sample window;
    cell_px : pixels per cell; dictionary : ArUco predefined dictionary; physical_size_m :
    printed edge length of the whole board in metres (see :func:`usdbtf.fiducials.make_board`)."""

    grid: int = 10
    window: int = 6
    cell_px: int = 100
    dictionary: str = "DICT_4X4_100"
    physical_size_m: float = 0.12


@dataclass
class BoardResult:
    """board : the :class:`~usdbtf.fiducials.Board` (markers, sample window, sizes);
    image : (H, W) uint8 printable image (white paper, black markers, grey window)."""

    board: Board
    image: np.ndarray


def board(options: BoardOptions | None = None) -> BoardResult:
    """The board ``options`` describe and its image, in memory.  BTFError for a board that
    cannot exist (unknown dictionary, too few markers in it, cells too small)."""
    o = options or BoardOptions()
    made = make_board(grid=o.grid, window=o.window, cell_px=o.cell_px, dictionary=o.dictionary,
                      physical_size_m=o.physical_size_m)
    return BoardResult(made, board_image(made))


def write_board(result: BoardResult, image_path, json_path) -> None:
    """The image (8-bit sRGB, marked as a usdbtf board) and the ``usdbtf-board/1`` JSON,
    each written atomically."""
    from .atomic import atomic_file
    from .imageio import write_image
    from .outputs import BOARD, BOARD_IMAGE, IMAGE_ATTRIBUTE

    with atomic_file(image_path, kind=BOARD_IMAGE) as tmp:
        write_image(tmp, result.image[..., None], color_space=BOARD_COLOR_SPACE,
                    attributes={IMAGE_ATTRIBUTE: BOARD_IMAGE})
    with atomic_file(json_path, kind=BOARD) as tmp:
        tmp.write_text(json.dumps(result.board.to_json(), indent=1) + "\n")
