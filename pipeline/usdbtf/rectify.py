"""Rectification: camera frames of a sample in a fiducial board -> an N x N BTF.

Per frame (pure core, :func:`rectify_frame`):

1. decode the frame to scene-linear (OCIO, the RAW manifest's declared colour space ->
   the working space) and divide by the flat field when the capture recorded one;
2. find the board's ArUco markers, refine their corners to sub-pixel accuracy and fit a
   board -> frame homography with RANSAC (:mod:`usdbtf.fiducials`);
3. warp the board's sample window to an N x N fronto-parallel image: each output texel
   is the mean of the frame over the texel's footprint (a pixel pre-filter, supersampled
   Lanczos lookups, then a box filter), so a frame finer than the output is not aliased;
4. flag the texels the sensor did not record: those within a pixel of a clipped sensor
   pixel (an integer frame at its top code), whose values the frame does not hold
   (:func:`clipped_texels`).  The stage reports each sample's flagged share, and writes the
   flags as a mask image beside the sample (``"mask"`` in the manifest,
   :func:`usdbtf.manifest.read_masks`).

A frame is *rejected* (reported, and treated as missing rather than guessed) when it
shows fewer than ``min_markers`` board markers, when the RANSAC fit leaves a mean inlier
residual above ``max_residual_px``, or when the window is not entirely inside the frame.

The stage (:func:`rectify` -> :class:`RectifyResult`, :func:`write_rectify`): every sample of
the capture plan ends up in the output manifest, in plan order; obstructed and rejected
samples are filled from their neighbours (:mod:`usdbtf.fill`) when read and marked
``"interpolated": true``.  The rectified texels are held in memory, or (``scratch``: what the
CLI does, beside the output) in a memory-mapped scratch file, so memory stays at a few
frames whatever the sampling.
"""
from __future__ import annotations

import json
import logging
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from . import color
from .errors import BTFError
from .fiducials import Board, apply_homography, detect_markers, fit_homography, make_board, parse_board, to_cv
from .fill import combine, plan_fill
from .imageio import read_image
from .lifetime import stop_pool
from .manifest import MANIFEST, read_manifest, write_manifest
from .model import BTF
from .progress import track
from .resources import require_disk, require_memory
from .sampling import Sampling
from .numeric import single_blas_thread

log = logging.getLogger(__name__)

__all__ = ["FrameResult", "rectify_frame", "warp_window", "window_homography", "luminance", "clipped_pixels",
           "clipped_texels", "CLIP_REACH_PX", "RectifyOptions", "RectifyResult", "RectifiedBTF", "rectify",
           "write_rectify", "read_raw_plan", "RawPlan"]


@dataclass
class FrameResult:
    """Outcome of one frame.

    image : (N, N, 3) float32 working space, or None when rejected.
    homography : (3, 3) board -> frame pixels, or None.
    markers : number of board markers found.
    residual_px : mean distance of inlier corners from the fitted homography, frame pixels.
    reason : why the frame was rejected ("" when it was not).
    saturated : (N, N) bool, texels the sensor clipped (:func:`clipped_texels`), or None when
        the frame's clipped pixels were not given (a float frame has no clip level).
    """

    image: np.ndarray | None
    homography: np.ndarray | None
    markers: int
    residual_px: float
    reason: str = ""
    saturated: np.ndarray | None = None

    @property
    def saturated_share(self) -> float:
        """Fraction of the N x N texels flagged in :attr:`saturated` (0 when unknown)."""
        return 0.0 if self.saturated is None else float(self.saturated.mean())


def luminance(linear: np.ndarray) -> np.ndarray:
    """(H, W, 3) -> (H, W) float32 mean of the channels (enough to find black-on-white markers)."""
    return np.asarray(linear, np.float32).mean(axis=2)


def window_homography(h_board: np.ndarray, board: Board, size: int) -> np.ndarray:
    """3x3: output texel coordinates (corner origin, N x N) -> frame pixels."""
    x0, y0, x1, y1 = board.sample_rect
    tex = np.array([[(x1 - x0) / size, 0.0, x0], [0.0, (y1 - y0) / size, y0], [0.0, 0.0, 1.0]])
    return h_board @ tex


def _footprint(h_tex: np.ndarray, size: int) -> float:
    """Largest frame-pixel length of one texel edge over the window (its corners and centre)."""
    pts = np.array([[0, 0], [size, 0], [0, size], [size, size], [size / 2, size / 2]], np.float64)
    base = apply_homography(h_tex, pts)
    step_x = apply_homography(h_tex, pts + [1.0, 0.0]) - base
    step_y = apply_homography(h_tex, pts + [0.0, 1.0]) - base
    return float(max(np.linalg.norm(step_x, axis=1).max(), np.linalg.norm(step_y, axis=1).max()))


#: Weight a of the separable pre-filter [-a, 1 + 2a, -a] (see :func:`warp_window`); chosen with
#: benchmarks/bench_rectify.py (0.1 and 0.2 each lose 0.5-1 dB on some frames).
PIXEL_DEBLUR = 0.15

_INTERPOLATIONS = {"lanczos": "INTER_LANCZOS4", "cubic": "INTER_CUBIC", "linear": "INTER_LINEAR"}


def warp_window(linear: np.ndarray, h_tex: np.ndarray, size: int, max_supersample: int = 6,
                interpolation: str = "lanczos", deblur: float = PIXEL_DEBLUR) -> np.ndarray:
    """Resample the frame under the window to (N, N, 3) float32 texel means.

    h_tex : texel -> frame homography (:func:`window_homography`).  Each texel is looked up
    on an s x s grid (s = frame pixels per texel, rounded up, at most ``max_supersample``)
    with Lanczos (8 x 8 taps) interpolation and averaged.  At grazing views a texel spans
    barely 1.5 frame pixels across the foreshortened axis, where every blur shows: each
    sensor pixel integrates the radiance over its area (a 1-pixel box), and the lookup
    blurs again.  So the frame under the window is first pre-filtered with the separable
    3-tap kernel [-a, 1 + 2a, -a] (a = ``deblur``), which lifts the box's response at half
    the sampling rate back from 0.64 to about 1 (1 + 4a = 1.6); with Lanczos lookups it is
    worth +2 to +6 dB over plain bicubic at 55-70 degree views (benchmarks/bench_rectify.py).
    Overshoot at edges is clipped at 0 (radiance is not negative).  ``interpolation=
    "cubic"`` / ``"linear"`` and ``deblur=0`` are kept for comparison (the benchmark's
    baselines).
    """
    import cv2
    mode = getattr(cv2, _INTERPOLATIONS[interpolation])
    ss = int(np.clip(np.ceil(_footprint(h_tex, size)), 1, max_supersample))
    sub = h_tex @ np.diag([1.0 / ss, 1.0 / ss, 1.0])
    frame, sub = _window_crop(np.asarray(linear), h_tex, size, sub)
    frame = np.ascontiguousarray(frame, np.float32)
    if deblur:
        taps = np.array([-deblur, 1.0 + 2.0 * deblur, -deblur], np.float32)
        frame = cv2.sepFilter2D(frame, -1, taps, taps, borderType=cv2.BORDER_REPLICATE)
    big = cv2.warpPerspective(frame, to_cv(sub), (size * ss, size * ss),
                              flags=mode | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    if ss > 1:
        big = big.reshape(size, ss, size, ss, 3).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)
    return np.maximum(big, 0.0)


def _window_crop(linear: np.ndarray, h_tex: np.ndarray, size: int, sub: np.ndarray):
    """(the frame's pixels around the window, ``sub`` moved to them): the pre-filter and the
    lookups touch only the window and the interpolation's reach (8 pixels), not the frame."""
    corners = apply_homography(h_tex, np.array([[0, 0], [size, 0], [size, size], [0, size]], np.float64))
    height, width = linear.shape[:2]
    x0, y0 = (int(max(np.floor(corners[:, i].min()) - 8, 0)) for i in (0, 1))
    x1 = int(min(np.ceil(corners[:, 0].max()) + 9, width))
    y1 = int(min(np.ceil(corners[:, 1].max()) + 9, height))
    if x0 >= x1 or y0 >= y1:
        return linear, sub
    shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
    return linear[y0:y1, x0:x1], shift @ sub


#: How far (frame pixels) a clipped sensor pixel taints the texels around it: the pixels that
#: integrate a texel, and one more on each side, which undoing their box blur reads (the
#: pre-filter of :func:`warp_window` reaches one pixel).
CLIP_REACH_PX = 1


def clipped_pixels(encoded: np.ndarray) -> np.ndarray | None:
    """(H, W) bool: pixels of an integer frame (H, W, 3) at the top code in any channel, where
    the sensor (or its encoding) clipped; None for a float frame, which has no clip level."""
    encoded = np.asarray(encoded)
    if encoded.dtype.kind != "u":
        return None
    return (encoded == np.iinfo(encoded.dtype).max).any(axis=2)


def clipped_texels(clipped: np.ndarray, h_tex: np.ndarray, size: int, reach_px: int = CLIP_REACH_PX,
                   samples: int = 8) -> np.ndarray:
    """(N, N) bool: the texels with a clipped sensor pixel within ``reach_px`` of their footprint.

    clipped : (H, W) bool frame pixels at the clip level (:func:`clipped_pixels`).
    h_tex : texel -> frame homography (:func:`window_homography`).
    A clipped pixel holds the clip level, not the radiance it integrated (a metal flake's
    sparkle is up to 200 times the clip level), so the texels sharing it, or read with it when
    the pixels' blur is undone, are unknown: no resampling gives them back.  Each texel's
    footprint is probed on a ``samples`` x ``samples`` grid (at 70 degree views a texel spans
    about one pixel: the grid steps well under a pixel).
    """
    import cv2
    clipped = np.asarray(clipped, bool)
    if not clipped.any():
        return np.zeros((size, size), bool)
    mask = clipped.astype(np.uint8)
    if reach_px > 0:
        mask = cv2.dilate(mask, np.ones((2 * reach_px + 1,) * 2, np.uint8))
    k = int(samples)
    # Probe j of the k x k grid sits at texel coordinate (j + 0.5) / k and reads the frame pixel
    # that holds its image (to_cv's half-pixel shifts and cv2's rounding: floor of the position).
    probe = h_tex @ np.diag([1.0 / k, 1.0 / k, 1.0])
    hit = cv2.warpPerspective(mask, to_cv(probe), (size * k, size * k),
                              flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT,
                              borderValue=0)
    return hit.reshape(size, k, size, k).any(axis=(1, 3))


def rectify_frame(linear: np.ndarray, board: Board, size: int, *, min_markers: int = 4,
                  max_residual_px: float = 1.0, clipped: np.ndarray | None = None) -> FrameResult:
    """Rectify one scene-linear frame (H, W, 3) float32 (already flat-fielded).

    clipped : optional (H, W) bool, the frame's pixels at the sensor's clip level
        (:func:`clipped_pixels` of the frame as recorded); with it the result flags the
        texels they taint (:attr:`FrameResult.saturated`).
    """
    det = detect_markers(luminance(linear), board)
    if len(det) < min_markers:
        return FrameResult(None, None, len(det), float("nan"),
                           f"too few markers ({len(det)} of {len(board.ids)} found, need {min_markers})")
    h, inliers, resid = fit_homography(board, det)
    if h is None or inliers.sum() < 4 * min_markers:
        return FrameResult(None, None, len(det), float("nan"), "no consistent homography (RANSAC)")
    mean_resid = float(resid[inliers].mean())
    if mean_resid > max_residual_px:
        return FrameResult(None, h, len(det), mean_resid,
                           f"poor fit (mean corner residual {mean_resid:.2f} px > {max_residual_px} px)")
    h_tex = window_homography(h, board, size)
    corners = apply_homography(h_tex, np.array([[0, 0], [size, 0], [size, size], [0, size]], np.float64))
    height, width = linear.shape[:2]
    if (corners < 0).any() or (corners[:, 0] > width).any() or (corners[:, 1] > height).any():
        return FrameResult(None, h, len(det), mean_resid, "sample window not entirely inside the frame")
    saturated = None if clipped is None else clipped_texels(clipped, h_tex, size)
    return FrameResult(warp_window(linear, h_tex, size), h, len(det), mean_resid, saturated=saturated)


# ------------------------------------------------------------------ RAW capture folders


@dataclass
class RawPlan:
    """What a RAW capture folder holds.

    sampling : the full capture plan (every sample the rig was asked for), plan order.
    frame_of : dict plan index -> index into the RAW manifest's samples (captured frames).
    missing : dict plan index -> reason ("obstructed", ...).
    flat_field : path of the flat-field gain image, or None.
    board : the board recorded at capture, or None.
    metadata : the RAW manifest's extra top-level keys.
    """

    sampling: Sampling
    frame_of: dict
    missing: dict
    flat_field: Path | None
    board: Board | None
    metadata: dict = field(default_factory=dict)


def read_raw_plan(raw) -> tuple["object", RawPlan]:
    """Open a RAW capture folder: (FileBTF of its frames, RawPlan).

    A plain manifest (no ``raw_capture`` key) is accepted too: its samples are the plan.
    """
    raw = Path(raw)
    frames = read_manifest(raw)
    path = raw / MANIFEST if raw.is_dir() else raw
    doc = json.loads(path.read_text())
    info = doc.get("raw_capture")
    if info is None:
        return frames, RawPlan(frames.sampling, {i: i for i in range(frames.n_samples)}, {}, None, None, {})
    where = f"{path}"
    try:
        view = np.asarray(info["plan"]["view"], np.float64).reshape(-1, 2)
        light = np.asarray(info["plan"]["light"], np.float64).reshape(-1, 2)
        sampling = Sampling(view, light)
    except (KeyError, TypeError, ValueError) as exc:
        raise BTFError(f"{where}: \"raw_capture.plan\" must hold view and light lists ({exc})") from None
    frame_of = {}
    for k, s in enumerate(doc["samples"]):
        idx = s.get("index")
        if isinstance(idx, bool) or not isinstance(idx, int) or not 0 <= idx < len(sampling) or idx in frame_of:
            raise BTFError(f"{where}: sample #{k} ({s.get('image')}) needs a unique plan \"index\" in "
                           f"[0, {len(sampling)}), got {idx!r}")
        frame_of[idx] = k
    missing = {}
    for m in doc.get("missing", []):
        idx = m.get("index") if isinstance(m, dict) else None
        if isinstance(idx, bool) or not isinstance(idx, int) or not 0 <= idx < len(sampling) or idx in frame_of:
            raise BTFError(f"{where}: \"missing\" entry {m!r} needs a plan \"index\" not also captured")
        missing[idx] = str(m.get("reason", "missing"))
    absent = set(range(len(sampling))) - set(frame_of) - set(missing)
    if absent:
        raise BTFError(f"{where}: plan samples {sorted(absent)[:5]} are neither captured nor listed as missing "
                       "(the capture is incomplete; re-run usdbtf capture to finish it)")
    flat = info.get("flat_field")
    flat_path = raw / flat if isinstance(flat, str) else None
    board = parse_board(info["board"], f"{where} raw_capture.board") if isinstance(info.get("board"), dict) else None
    return frames, RawPlan(sampling, frame_of, missing, flat_path, board, info)


def read_flat(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """The flat-field gain (H, W) float32 (1 = no falloff), checked against the frame size."""
    pixels, info = read_image(path, expect=(shape[1], shape[0]))
    gain = np.asarray(pixels, np.float32).mean(axis=2)
    if not np.isfinite(gain).all() or gain.min() <= 0:
        raise BTFError(f"{path}: flat-field gain must be finite and > 0 everywhere")
    return gain


@dataclass
class RectifyOptions:
    """size: output N; min_markers / max_residual_px: rejection rules; fill: interpolate
    missing samples (else refuse when any is missing); workers: processes (1 = in this one);
    color_space / bit_depth / ext: how :func:`write_rectify` stores the output files."""

    size: int = 128
    min_markers: int = 4
    max_residual_px: float = 1.0
    fill: bool = True
    workers: int = 1
    color_space: str = "ACEScg"
    bit_depth: str = "half"
    ext: str = "exr"


# One frame per task.  Worker state is set once per process (the frames' decoder, board,
# flat field) so tasks only carry an index.
_STATE: dict = {}


def _init_worker(frames, board, gain, opts):
    _STATE.update(frames=frames, board=board, gain=gain, opts=opts)


def _rectify_one(k: int) -> FrameResult:
    frames, board, gain, opts = _STATE["frames"], _STATE["board"], _STATE["gain"], _STATE["opts"]
    encoded = frames.read_encoded(np.array([k]))
    linear = frames.decode(encoded, what=f"sample {frames.names[k]}")[0]
    if gain is not None:
        linear = linear / gain[..., None]
    return rectify_frame(linear, board, opts.size, min_markers=opts.min_markers, max_residual_px=opts.max_residual_px,
                         clipped=clipped_pixels(encoded[0]))


@dataclass
class RectifyResult:
    """A rectified capture: every sample of the plan, the measured ones rectified and the
    missing ones filled from their neighbours when read (lazily: :meth:`images`).

    sampling : the capture plan's directions, plan order (S samples).
    texels : (S, N, N, 3) float32 working-space rectified frames (rows of missing samples are
        unset) -- in memory, or a memory-mapped file in the ``scratch`` folder :func:`rectify`
        was given (a capture's samples need not fit in memory).
    available : (S,) bool, the samples rectified from a frame.
    fills : {sample: :class:`usdbtf.fill.Fill`} for the others (barycentric interpolation).
    report : what was done (frames, rejected, interpolated, residuals, board), stored under
        ``"rectify"`` in the output manifest; metadata : the manifest's extra keys.
    options : the :class:`RectifyOptions`.
    masks : {sample: (N, N) bool, the texels not recorded} of the samples whose frame clipped
        under the window (stored bit-packed: :meth:`mask`).
    """

    sampling: Sampling
    texels: np.ndarray
    available: np.ndarray
    fills: dict
    report: dict
    metadata: dict
    options: RectifyOptions
    masks: dict = field(default_factory=dict)

    def mask(self, i: int) -> np.ndarray:
        """(N, N) bool: the texels of sample ``i`` the sensor did not record (all False when
        its frame clipped nowhere under the window)."""
        n = self.options.size
        if i not in self.masks:
            return np.zeros((n, n), bool)
        return np.unpackbits(self.masks[i], count=n * n).reshape(n, n).astype(bool)

    def image(self, i: int) -> np.ndarray:
        """Sample ``i`` (N, N, 3) float32 working space: its rectified frame, or the fill."""
        if self.available[i]:
            return self.texels[i]
        f = self.fills[i]
        return combine(f, self.texels[f.sources])

    def images(self) -> Iterator[np.ndarray]:
        """Every sample in plan order (:meth:`image`)."""
        return (self.image(i) for i in range(len(self.sampling)))

    def to_btf(self) -> BTF:
        """The result as a :class:`usdbtf.model.BTF` (working-space floats, fills made when
        read; ``interpolated`` marks them), e.g. for :func:`usdbtf.compress.compress`."""
        return RectifiedBTF(self.sampling, self.options.size, self.options.size, color_space=color.WORKING_SPACE,
                            interpolated=~self.available, metadata=dict(self.metadata), result=self)


@dataclass
class RectifiedBTF(BTF):
    """:meth:`RectifyResult.to_btf`: samples read from the result, in the working space."""

    result: RectifyResult | None = None

    def read_encoded(self, indices, rows=None) -> np.ndarray:
        idx = np.atleast_1d(np.arange(self.n_samples)[indices])
        out = np.stack([self.result.image(int(i)) for i in idx])
        return out if rows is None else out[:, rows[0]:rows[1]]


@single_blas_thread
def rectify(raw, options: RectifyOptions, *, board: Board | None = None, scratch=None) -> RectifyResult:
    """Rectify the frames of a RAW capture folder (``usdbtf capture``, or any manifest of board
    frames) into every sample of its plan.

    board : the fiducial board; default the one recorded in the capture, else the standard
        board of :func:`usdbtf.fiducials.make_board`.
    scratch : a folder for the rectified samples' memory-mapped file (S x N x N x 12 bytes; its
        disk space is checked first), which the caller removes after writing; None holds them
        in memory (its size checked against the machine's).  The CLI puts it beside the output.
    Rejected frames are logged; BTFError when none could be rectified, or when samples are
    missing and ``options.fill`` is off.
    """
    frames, plan = read_raw_plan(raw)
    board = board or plan.board or make_board()
    gain = read_flat(plan.flat_field, (frames.height, frames.width)) if plan.flat_field else None
    n, size = len(plan.sampling), options.size
    what = f"rectifying {n} samples at {size}x{size}"
    if scratch is not None:
        require_disk(n * size * size * 12, Path(scratch), what)
        texels = np.lib.format.open_memmap(os.path.join(scratch, "texels.npy"), mode="w+", dtype=np.float32,
                                           shape=(n, size, size, 3))
    else:
        require_memory(n * size * size * 12, what)
        texels = np.empty((n, size, size, 3), np.float32)
    rejected, residuals, saturated, masks = {}, [], {}, {}
    order = sorted(plan.frame_of)
    available = np.zeros(n, bool)
    tasks = [plan.frame_of[i] for i in order]
    if options.workers > 1 and len(tasks) > 1:
        pool = ProcessPoolExecutor(options.workers, initializer=_init_worker,
                                   initargs=(frames, board, gain, options))
        results = pool.map(_rectify_one, tasks, chunksize=4)
    else:
        pool = None
        _init_worker(frames, board, gain, options)
        results = map(_rectify_one, tasks)
    try:
        for i, res in zip(order, track(results, "rectify", len(order), logger=log)):
            if res.image is None:
                rejected[i] = res.reason
                log.info(f"rectify: rejected {frames.names[plan.frame_of[i]]}: {res.reason}")
            else:
                texels[i] = res.image
                available[i] = True
                residuals.append(res.residual_px)
                if res.saturated_share > 0:
                    saturated[i] = res.saturated_share
                    masks[i] = np.packbits(res.saturated.ravel())      # 1 bit a texel until written
    except BaseException:
        if pool is not None:
            stop_pool(pool)          # SIGTERM, Ctrl-C, an error: the workers stop now
        raise
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    missing = dict(plan.missing)
    missing.update(rejected)
    if missing and not options.fill:
        raise BTFError(f"{raw}: {len(missing)} samples are missing ({len(rejected)} rejected frames); "
                       "rectify without --no-fill to interpolate them")
    if not available.any():
        raise BTFError(f"{raw}: no frame could be rectified (first problem: {next(iter(rejected.values()), 'none')})")
    if saturated:
        worst = max(saturated, key=saturated.get)
        log.warning(f"rectify: {len(saturated)} of {len(order)} frames clipped under the sample window (worst: "
                    f"{frames.names[plan.frame_of[worst]]}, {100 * saturated[worst]:.1f}% of the texels): texels "
                    "next to clipped pixels are not measured (listed under rectify.saturated); shoot such lights "
                    "with a shorter exposure")
    fills = {f.target: f for f in plan_fill(plan.sampling, available)}
    report = {"size": size, "frames": len(order), "rectified": int(available.sum()),
              "rejected": [{"index": i, "reason": r} for i, r in sorted(rejected.items())],
              "obstructed": sorted(i for i, r in plan.missing.items() if r == "obstructed"),
              "interpolated": int((~available).sum()),
              "mean_corner_residual_px": float(np.mean(residuals)) if residuals else None,
              "max_corner_residual_px": float(np.max(residuals)) if residuals else None,
              # Samples whose frame clipped under the window, with the share of texels the sensor
              # did not record (their output values stand on clipped pixels: not measurements).
              "saturated": [{"index": i, "share": round(share, 6)} for i, share in sorted(saturated.items())],
              "board": board.to_json()}
    metadata = {"physical_size_m": list(board.window_size_m), "rectify": report}
    return RectifyResult(plan.sampling, texels, available, fills, report, metadata, options, masks)


def write_rectify(result: RectifyResult, path) -> None:
    """Write ``result`` as a manifest folder at ``path`` (atomically), its files stored as
    ``result.options`` says, interpolated samples marked."""
    o = result.options
    write_manifest(path, result.sampling, result.images(), color_space=o.color_space, bit_depth=o.bit_depth,
                   ext=o.ext, interpolated=~result.available, metadata=result.metadata,
                   masks={i: result.mask(i) for i in sorted(result.masks)})
