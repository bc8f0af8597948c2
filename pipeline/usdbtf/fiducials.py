"""Fiducial boards: a ring of ArUco markers around a central sample window.

The material sample is mounted in the board's window; the markers around it give a
board-to-frame homography for every camera frame (Koudelka et al. 2003 used coloured
squares and hand-marked points; this is the automated equivalent).

Coordinates
-----------
*Board pixels* are continuous coordinates on the board image with (0, 0) at the
top-left **corner** of pixel (0, 0) (so pixel (row i, col j) covers [j, j+1] x
[i, i+1]).  Marker corners, ``sample_rect`` and homographies here use them; the same
convention is used for camera frames ("frame pixels").  OpenCV puts pixel centres at
integers, so values are shifted by 0.5 at every OpenCV call (:func:`to_cv`,
:func:`from_cv`).

board.json (``usdbtf-board/1``)::

    {"format": "usdbtf-board/1", "dictionary": "DICT_4X4_100",
     "image_size": [W, H], "physical_size_m": [w, h],
     "sample_rect": [x0, y0, x1, y1],
     "markers": [{"id": 0, "corners": [[x, y], [x, y], [x, y], [x, y]]}, ...]}

Marker corners are listed clockwise from the marker's top-left (ArUco's order).
``physical_size_m`` is the printed size of the whole board image.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import BTFError

__all__ = ["FORMAT", "Board", "make_board", "load_board", "parse_board", "board_image", "Detection",
           "detection_grey", "detect_markers", "refine_corners", "fit_homography", "apply_homography", "to_cv", "from_cv", "marker_corner_points"]

FORMAT = "usdbtf-board/1"


@dataclass(frozen=True)
class Board:
    """A fiducial board.

    Attributes
    ----------
    dictionary : ArUco predefined dictionary name, e.g. "DICT_4X4_100".
    image_size : (W, H) board pixels.
    physical_size_m : (w, h) metres, the printed size of the board image.
    sample_rect : (x0, y0, x1, y1) board pixels, the window the sample shows through.
    ids : (M,) int marker ids.
    corners : (M, 4, 2) float64 board pixels, clockwise from each marker's top-left.
    """

    dictionary: str
    image_size: tuple
    physical_size_m: tuple
    sample_rect: tuple
    ids: np.ndarray
    corners: np.ndarray

    @property
    def window_size_m(self) -> tuple[float, float]:
        """(w, h) of the sample window in metres."""
        x0, y0, x1, y1 = self.sample_rect
        return ((x1 - x0) * self.physical_size_m[0] / self.image_size[0],
                (y1 - y0) * self.physical_size_m[1] / self.image_size[1])

    def aruco_dictionary(self):
        import cv2
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))

    def to_json(self) -> dict:
        return {"format": FORMAT, "dictionary": self.dictionary, "image_size": list(self.image_size),
                "physical_size_m": list(self.physical_size_m), "sample_rect": [float(v) for v in self.sample_rect],
                "markers": [{"id": int(i), "corners": [[float(x), float(y)] for x, y in c]}
                            for i, c in zip(self.ids, self.corners)]}


def _dictionary_size(name: str) -> tuple[int, int] | None:
    """(bits per side, marker count) of an ArUco predefined dictionary, None if unknown."""
    import cv2
    if not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        return None
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
    return d.markerSize, d.bytesList.shape[0]


def make_board(*, grid: int = 10, window: int = 6, cell_px: int = 100, marker_fraction: float = 0.8,
               dictionary: str = "DICT_4X4_100", physical_size_m: float = 0.12) -> Board:
    """A square board of ``grid`` x ``grid`` cells; the central ``window`` x ``window``
    cells are the sample window, every other cell holds one marker.

    A white margin of half a cell surrounds the grid (markers need a light border to be
    found).  The marker side is ``marker_fraction`` of a cell, rounded down to a whole
    number of pixels per marker bit so printed modules are crisp.
    """
    size = _dictionary_size(dictionary)
    if size is None:
        raise BTFError(f"unknown ArUco dictionary {dictionary!r}")
    bits, count = size
    if not (1 <= window < grid and (grid - window) % 2 == 0):
        raise BTFError(f"window of {window} cells must be smaller than the grid of {grid} and centred "
                       "(grid - window even)")
    n_markers = grid * grid - window * window
    if n_markers > count:
        raise BTFError(f"{dictionary} has {count} markers, the board needs {n_markers}")
    module = int(marker_fraction * cell_px) // (bits + 2)
    if module < 2:
        raise BTFError(f"cells of {cell_px} px are too small for {dictionary} markers")
    marker = module * (bits + 2)
    margin = cell_px // 2
    side = grid * cell_px + 2 * margin
    lo = (grid - window) // 2
    ids, corners = [], []
    for r in range(grid):
        for c in range(grid):
            if lo <= r < lo + window and lo <= c < lo + window:
                continue
            x = margin + c * cell_px + (cell_px - marker) / 2
            y = margin + r * cell_px + (cell_px - marker) / 2
            x, y = math.floor(x), math.floor(y)
            ids.append(len(ids))
            corners.append([[x, y], [x + marker, y], [x + marker, y + marker], [x, y + marker]])
    w0 = margin + lo * cell_px
    w1 = w0 + window * cell_px
    return Board(dictionary, (side, side), (physical_size_m, physical_size_m), (w0, w0, w1, w1),
                 np.array(ids, np.int64), np.array(corners, np.float64))


def board_image(board: Board, window_grey: int = 128) -> np.ndarray:
    """The printable board, (H, W) uint8: white paper, black markers, a grey window."""
    import cv2
    w, h = board.image_size
    img = np.full((h, w), 255, np.uint8)
    d = board.aruco_dictionary()
    for i, c in zip(board.ids, board.corners):
        x0, y0 = int(c[0, 0]), int(c[0, 1])
        side = int(round(c[1, 0] - c[0, 0]))
        img[y0:y0 + side, x0:x0 + side] = cv2.aruco.generateImageMarker(d, int(i), side, borderBits=1)
    x0, y0, x1, y1 = (int(round(v)) for v in board.sample_rect)
    img[y0:y1, x0:x1] = window_grey
    return img


def _number(value, what: str, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise BTFError(f"{where}: {what} must be a finite number, got {value!r}")
    return float(value)


def _pair(value, what: str, where: str, positive: bool = True) -> tuple[float, float]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise BTFError(f"{where}: {what} must be a [w, h] pair, got {value!r}")
    out = tuple(_number(v, what, where) for v in value)
    if positive and min(out) <= 0:
        raise BTFError(f"{where}: {what} must be positive, got {value!r}")
    return out


def parse_board(doc, where: str = "board") -> Board:
    """Validate a board.json document; BTFError naming ``where`` and the bad key."""
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise BTFError(f"{where}: \"format\" must be {FORMAT!r}, got {got!r}")
    name = doc.get("dictionary")
    size = _dictionary_size(name) if isinstance(name, str) else None
    if size is None:
        raise BTFError(f"{where}: \"dictionary\" must name an ArUco dictionary (e.g. DICT_4X4_100), got {name!r}")
    w, h = _pair(doc.get("image_size"), "\"image_size\"", where)
    if w != int(w) or h != int(h):
        raise BTFError(f"{where}: \"image_size\" must be whole pixels, got {doc.get('image_size')!r}")
    phys = _pair(doc.get("physical_size_m"), "\"physical_size_m\"", where)
    rect = doc.get("sample_rect")
    if not isinstance(rect, (list, tuple)) or len(rect) != 4:
        raise BTFError(f"{where}: \"sample_rect\" must be [x0, y0, x1, y1], got {rect!r}")
    x0, y0, x1, y1 = (_number(v, "\"sample_rect\"", where) for v in rect)
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise BTFError(f"{where}: \"sample_rect\" {list(rect)} is empty or outside the {int(w)}x{int(h)} board")
    markers = doc.get("markers")
    if not isinstance(markers, list) or len(markers) < 4:
        raise BTFError(f"{where}: \"markers\" must list at least 4 markers")
    ids, corners = [], []
    for k, m in enumerate(markers):
        label = f"marker #{k}"
        if not isinstance(m, dict):
            raise BTFError(f"{where}: {label} must be an object with \"id\" and \"corners\"")
        mid = m.get("id")
        if isinstance(mid, bool) or not isinstance(mid, int) or not 0 <= mid < size[1]:
            raise BTFError(f"{where}: {label}: \"id\" must be an integer in [0, {size[1]}) for {name}, got {mid!r}")
        c = m.get("corners")
        if (not isinstance(c, list) or len(c) != 4
                or not all(isinstance(p, (list, tuple)) and len(p) == 2 for p in c)):
            raise BTFError(f"{where}: {label} (id {mid}): \"corners\" must be four [x, y] points")
        pts = [[_number(v, f"{label} corner", where) for v in p] for p in c]
        ids.append(mid)
        corners.append(pts)
    if len(set(ids)) != len(ids):
        dup = next(i for i in ids if ids.count(i) > 1)
        raise BTFError(f"{where}: marker id {dup} is listed twice")
    corners = np.array(corners, np.float64)
    # Clockwise in image coordinates (y down) means a positive shoelace area.
    area = 0.5 * np.sum(corners[:, :, 0] * np.roll(corners[:, :, 1], -1, 1)
                        - np.roll(corners[:, :, 0], -1, 1) * corners[:, :, 1], axis=1)
    if (area <= 0).any():
        k = int(np.argmax(area <= 0))
        raise BTFError(f"{where}: marker id {ids[k]}: corners must go clockwise from the top-left and enclose an area")
    return Board(name, (int(w), int(h)), phys, (x0, y0, x1, y1), np.array(ids, np.int64), corners)


def load_board(path) -> Board:
    """Read and validate a board.json file."""
    from .jsontext import load

    path = Path(path)
    return parse_board(load(path, "board JSON"), str(path))


# ------------------------------------------------------------------ geometry helpers


def to_cv(h: np.ndarray) -> np.ndarray:
    """A homography between corner-origin pixel coordinates -> the same map in OpenCV's
    centre-origin coordinates (both sides shifted by half a pixel)."""
    shift = np.array([[1.0, 0, 0.5], [0, 1.0, 0.5], [0, 0, 1.0]])
    unshift = np.array([[1.0, 0, -0.5], [0, 1.0, -0.5], [0, 0, 1.0]])
    return unshift @ h @ shift


def from_cv(points: np.ndarray) -> np.ndarray:
    """OpenCV pixel coordinates (centre origin) -> corner-origin coordinates."""
    return np.asarray(points, np.float64) + 0.5


def apply_homography(h: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(..., 2) points -> (..., 2) mapped by the 3x3 homography ``h``."""
    p = np.asarray(points, np.float64)
    q = p @ h[:, :2].T + h[:, 2]
    return q[..., :2] / q[..., 2:3]


def marker_corner_points(board: Board, ids) -> np.ndarray:
    """(n, 4, 2) board-pixel corners of markers ``ids`` (each must be on the board)."""
    index = {int(i): k for k, i in enumerate(board.ids)}
    return board.corners[[index[int(i)] for i in ids]]


# ------------------------------------------------------------------ detection


@dataclass(frozen=True)
class Detection:
    """Markers found in one frame.

    ids : (n,) int, only ids that belong to the board.
    corners : (n, 4, 2) float64 frame pixels (corner origin), sub-pixel refined.
    """

    ids: np.ndarray
    corners: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)


def _detector(board: Board):
    import cv2
    params = cv2.aruco.DetectorParameters()
    # ArUco's sub-pixel pass (cornerSubPix) gives refine_corners a start within ~1 px
    # even at grazing views; without it ~10% of corners there start too far off.
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementMaxIterations = 50
    params.cornerRefinementMinAccuracy = 0.01
    refine = cv2.aruco.RefineParameters()
    return cv2.aruco.ArucoDetector(board.aruco_dictionary(), params, refine)


def _cv_board(board: Board):
    import cv2
    obj = np.concatenate([board.corners, np.zeros(board.corners.shape[:2] + (1,))], axis=2).astype(np.float32)
    return cv2.aruco.Board(list(obj), board.aruco_dictionary(), board.ids.astype(np.int32))


def detection_grey(luminance: np.ndarray) -> np.ndarray:
    """Linear luminance (H, W) -> 8-bit grey for the marker detector.

    Auto-exposed (the 99th percentile maps to 255) and gamma 1/2.2 encoded, so frames lit
    from grazing angles, which are dim, still give the detector full contrast.
    """
    lum = np.asarray(luminance, np.float32)
    top = float(np.percentile(lum, 99.0))
    if not np.isfinite(top) or top <= 0:
        return np.zeros(lum.shape, np.uint8)
    return (255.0 * np.power(np.clip(lum / top, 0.0, 1.0), 1.0 / 2.2) + 0.5).astype(np.uint8)


def detect_markers(luminance: np.ndarray, board: Board, *, refine: bool = True) -> Detection:
    """Find the board's markers in a frame given as linear luminance (H, W) float32.

    ArUco detection (with its sub-pixel corner pass) on an auto-exposed 8-bit copy, a
    second look for board markers the first pass missed near where the layout predicts
    them, then edge-fit corner refinement on the linear image (:func:`refine_corners`).
    Ids not on the board, and ids seen twice, are dropped.
    """
    lum = np.asarray(luminance, np.float32)
    if lum.ndim != 2:
        raise ValueError(f"expected an (H, W) luminance image, got shape {lum.shape}")
    grey = detection_grey(lum)
    det = _detector(board)
    corners, ids, rejected = det.detectMarkers(grey)
    if ids is not None and len(ids) >= 4 and len(rejected):
        corners, ids, rejected, _ = det.refineDetectedMarkers(grey, _cv_board(board), corners, ids, rejected)
    if ids is None or len(ids) == 0:
        return Detection(np.zeros(0, np.int64), np.zeros((0, 4, 2)))
    ids = np.asarray(ids, np.int64).reshape(-1)
    corners = np.asarray(corners, np.float64).reshape(-1, 4, 2)
    keep = np.isin(ids, board.ids)
    # A marker id seen twice (a reflection, a stray print) is ambiguous: drop every copy.
    uniq, counts = np.unique(ids[keep], return_counts=True)
    keep &= ~np.isin(ids, uniq[counts > 1])
    order = np.argsort(ids[keep], kind="stable")
    found = from_cv(corners[keep][order])
    if refine:
        found = refine_corners(lum, found)
    return Detection(ids[keep][order], found)


def refine_corners(luminance: np.ndarray, corners: np.ndarray, *, samples: int = 12, passes: int = 2) -> np.ndarray:
    """Sub-pixel marker corners from straight-edge fits, (n, 4, 2) frame pixels.

    ArUco's own refinement (cornerSubPix on an L-shaped corner) is biased by a few
    tenths of a pixel once the optics blur the corner.  Here each marker's four outer
    edges are located instead: along ``samples`` normals per edge (the middle 60% of the
    edge, away from the corners) the edge position is the centroid of the intensity
    gradient, which is exact for any symmetric blur of a step; a total-least-squares line
    through those points per edge, and the corner is where adjacent lines meet.

    luminance : (H, W) float32, **linear** in radiance (a gamma-encoded image would move
        the gradient centroid towards the dark side).
    corners : (n, 4, 2) initial corners (corner-origin frame pixels), clockwise.
    A corner whose fit is degenerate or moves more than 1.5 px keeps its initial value.
    ``passes`` repeats the fit from the previous pass's corners (sampling along better
    edges); the second pass matters at grazing views.
    """
    start = np.asarray(corners, np.float64)
    c = start.copy()
    for _ in range(passes):
        c = _refine_pass(luminance, c, samples)
    moved = np.linalg.norm(c - start, axis=2) <= 1.5
    return np.where(moved[..., None], c, start)


def _refine_pass(luminance: np.ndarray, c: np.ndarray, samples: int) -> np.ndarray:
    import cv2
    if len(c) == 0:
        return c.copy()
    nxt = np.roll(c, -1, axis=1)
    edge = nxt - c                                              # (n, 4, 2)
    length = np.linalg.norm(edge, axis=2, keepdims=True)
    tangent = edge / np.maximum(length, 1e-9)
    normal = np.stack([-tangent[..., 1], tangent[..., 0]], axis=-1)
    # Search no further than the black border reaches inwards: the border of a 4x4..6x6
    # marker is 1/6..1/8 of its height across that edge (area / edge length), and a grazing
    # view shrinks that height.
    area = 0.5 * np.abs(np.sum(c[..., 0] * nxt[..., 1] - nxt[..., 0] * c[..., 1], axis=1))
    height = area[:, None, None] / np.maximum(length, 1e-9)
    reach = np.clip(0.1 * height, 0.6, 3.0)                     # (n, 4, 1) px
    t = np.linspace(0.2, 0.8, samples)
    base = c[:, :, None, :] + t[None, None, :, None] * edge[:, :, None, :]        # (n, 4, m, 2)
    steps = np.linspace(-1.0, 1.0, 17)
    offs = reach[..., None] * steps                                               # (n, 4, 1, 17)
    pts = base[..., None, :] + offs[..., None] * normal[:, :, None, None, :]      # (n, 4, m, 17, 2)
    # Corner-origin -> OpenCV pixel centres for remap.
    mx = (pts[..., 0] - 0.5).astype(np.float32).reshape(-1, steps.size)
    my = (pts[..., 1] - 0.5).astype(np.float32).reshape(-1, steps.size)
    prof = cv2.remap(np.ascontiguousarray(luminance, np.float32), mx, my, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE).reshape(pts.shape[:-1]).astype(np.float64)
    grad = np.abs(np.diff(prof, axis=-1))
    mid = 0.5 * (offs[..., 1:] + offs[..., :-1])
    # Only the strongest edge along each normal: +-1.6 px around the gradient peak (a
    # blurred step is about 2 px wide; further out lie the marker's inner bits).
    peak = np.take_along_axis(np.broadcast_to(mid, grad.shape), np.argmax(grad, axis=-1)[..., None], axis=-1)
    near = np.abs(mid - peak) <= 1.6
    grad = np.where(near & (grad >= 0.2 * grad.max(axis=-1, keepdims=True)), grad, 0.0)
    wsum = grad.sum(axis=-1)
    d = (grad * mid).sum(axis=-1) / np.maximum(wsum, 1e-12)                       # (n, 4, m)
    edge_pts = base + d[..., None] * normal[:, :, None, :]
    good = wsum > 0
    # Total-least-squares line per edge: centroid + principal direction.
    w = good[..., None].astype(np.float64)
    count = np.maximum(w.sum(axis=2), 1.0)
    centre = (edge_pts * w).sum(axis=2) / count                                   # (n, 4, 2)
    dev = (edge_pts - centre[:, :, None, :]) * w
    cov = np.einsum("nkmi,nkmj->nkij", dev, dev)
    _, vecs = np.linalg.eigh(cov)
    direction = vecs[..., :, 1]                                                   # largest eigenvalue
    # Corner k is where edge k-1 (ending there) meets edge k (starting there).
    p1, d1 = np.roll(centre, 1, axis=1), np.roll(direction, 1, axis=1)
    p2, d2 = centre, direction
    cross = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]
    diff = p2 - p1
    s = (diff[..., 0] * d2[..., 1] - diff[..., 1] * d2[..., 0]) / np.where(np.abs(cross) < 1e-6, np.nan, cross)
    refined = p1 + s[..., None] * d1
    enough = (good.sum(axis=2) >= samples // 2)
    ok = (np.isfinite(refined).all(axis=2) & (np.linalg.norm(refined - c, axis=2) <= 1.5)
          & enough & np.roll(enough, 1, axis=1))
    return np.where(ok[..., None], refined, c)


def fit_homography(board: Board, detection: Detection, *, threshold_px: float = 2.0):
    """Robust board -> frame homography from detected marker corners.

    RANSAC over all 4n corner correspondences (threshold ``threshold_px`` frame pixels),
    then a Levenberg-Marquardt refinement on the inliers (OpenCV's findHomography).

    Returns (H (3, 3) float64 mapping board pixels -> frame pixels, inlier mask (4n,) bool,
    residuals (4n,) float64 frame pixels).  H is None when there are too few points.
    """
    import cv2
    if len(detection) == 0:
        return None, np.zeros(0, bool), np.zeros(0)
    src = marker_corner_points(board, detection.ids).reshape(-1, 2)
    dst = detection.corners.reshape(-1, 2)
    if len(src) < 8:
        return None, np.zeros(len(src), bool), np.full(len(src), np.inf)
    h, mask = cv2.findHomography(src, dst, cv2.RANSAC, threshold_px, maxIters=2000, confidence=0.9995)
    if h is None:
        return None, np.zeros(len(src), bool), np.full(len(src), np.inf)
    h = h / h[2, 2]
    resid = np.linalg.norm(apply_homography(h, src) - dst, axis=1)
    return h, mask.reshape(-1).astype(bool), resid
