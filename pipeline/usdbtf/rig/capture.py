"""The capture loop: plan -> rig moves -> frames on disk, resumable at any instant.

RAW folder layout::

    RAW/btf.json        btf-manifest/1 over the captured frames (written when complete)
    RAW/journal.jsonl   what is done (:mod:`usdbtf.rig.journal`)
    RAW/frames/*.tif    unrectified camera frames (EXR for float cameras), colour space declared (OIIO)
    RAW/flat.exr        flat-field gain (1 at the image centre), when the rig has a target
    RAW/.lock           held while a capture runs

``btf.json`` lists the captured frames as samples (with their plan ``index``) and the
samples not shot under ``"missing"`` (with the reason, e.g. ``"obstructed"``); the full
plan and everything rectification needs is under ``"raw_capture"``.  It contains no
timestamps or rig frame counters, so a capture that was interrupted and resumed writes
the same bytes as one that was not.
"""
from __future__ import annotations

import fcntl
import logging
import os
from pathlib import Path

import numpy as np

from .. import color, jsontext
from ..atomic import atomic_file
from ..errors import BTFError
from ..imageio import read_info, write_image
from ..manifest import FORMAT, MANIFEST
from ..progress import bar
from .driver import RigDriver, RigRefused
from .journal import Journal
from .plan import CapturePlan

log = logging.getLogger(__name__)

__all__ = ["capture", "frame_name", "flat_gain", "decode_frame", "FLAT_FILE", "JOURNAL", "FRAMES"]

JOURNAL = "journal.jsonl"
FRAMES = "frames"
FLAT_FILE = "flat.exr"
#: Rig positions are reported to 0.001 deg; anything further off was not where we asked.
POSITION_TOLERANCE_DEG = 0.01


def frame_name(index: int, view, light, ext: str) -> str:
    return (f"{FRAMES}/{index:05d}_tv{view[0]:05.1f}_pv{view[1]:05.1f}_tl{light[0]:05.1f}_pl{light[1]:05.1f}"
            f".{ext}")


def _close(a, b, *, axis_free: bool = False) -> bool:
    """Rig positions equal within tolerance; ``axis_free``: the second angle is ignored when
    the first is 0 (the arm's azimuth on the camera axis; the head's pan always matters)."""
    if abs(a[0] - b[0]) > POSITION_TOLERANCE_DEG:
        return False
    if axis_free and abs(a[0]) < POSITION_TOLERANCE_DEG:
        return True
    d = abs(a[1] - b[1]) % 360.0
    return min(d, 360.0 - d) <= POSITION_TOLERANCE_DEG


def _write_durable(path: Path, pixels: np.ndarray, space: str, compression: str = "none") -> None:
    """Write an image under a temporary name, fsync, rename into place.

    Frames are TIFF (EXR for float cameras), uncompressed by default: deflate saves
    about 20% on noisy 16-bit frames but costs ~40x the write time, which would make the
    disk, not the rig, set the pace of a capture.
    """
    tmp = path.with_name(f".tmp-{path.name}")
    write_image(tmp, pixels, color_space=space, attributes={"compression": compression})
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)


class _Lock:
    def __init__(self, folder: Path):
        self.fh = open(folder / ".lock", "w")
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.fh.close()
            raise BTFError(f"{folder}: another capture is running on this folder") from None

    def release(self) -> None:
        fcntl.flock(self.fh, fcntl.LOCK_UN)
        self.fh.close()


def _fmt(pair) -> str:
    return "(" + ", ".join(f"{float(v):.3f}" for v in pair) + ")"


class _Rig:
    """Moves the rig only when needed and checks each frame was taken where asked."""

    def __init__(self, driver: RigDriver):
        self.driver = driver
        self.head = self.arm = None
        self.seen_reconnects = driver.reconnects

    def shoot(self, tag: str, head, arm) -> dict:
        for _ in range(3):
            if self.driver.reconnects != self.seen_reconnects:
                # The controller may have been power-cycled while the link was down.
                self.head = self.arm = None
                self.seen_reconnects = self.driver.reconnects
            if self.head is None or not _close(self.head, head):
                self.head = self.driver.move_head(*head)
            if self.arm is None or not _close(self.arm, arm, axis_free=True):
                self.arm = self.driver.move_arm(*arm)
            shot = self.driver.trigger(tag)
            if _close(shot["head"], head) and _close(shot["arm"], arm, axis_free=True):
                return shot
            log.info(f"capture: {tag} was exposed at head {_fmt(shot['head'])} arm {_fmt(shot['arm'])}, not head "
                     f"{_fmt(head)} arm {_fmt(arm)}; moving again")
            self.head, self.arm = shot["head"], shot["arm"]
        raise BTFError(f"rig at {self.driver.url}: could not hold head {_fmt(head)} / arm {_fmt(arm)} for {tag}")


def _check_frame(pixels: np.ndarray, space: str, tag: str, first: dict | None) -> dict:
    """The frame's (width, height, dtype, space) must match the capture's first frame."""
    if pixels.ndim != 3 or pixels.shape[2] != 3 or pixels.dtype.kind not in "uf":
        raise BTFError(f"camera frame {tag}: expected an RGB image, got {pixels.shape} {pixels.dtype}")
    if pixels.dtype.kind == "f" and not np.isfinite(pixels).all():
        raise BTFError(f"camera frame {tag}: pixel values include NaN or Inf")
    this = {"width": int(pixels.shape[1]), "height": int(pixels.shape[0]), "dtype": str(pixels.dtype),
            "color_space": space}
    if first is not None and this != first:
        raise BTFError(f"camera frame {tag}: {this['width']}x{this['height']} {this['dtype']} {space} differs "
                       f"from the capture's {first['width']}x{first['height']} {first['dtype']} {first['color_space']}")
    return this


def flat_gain(linear_frames) -> np.ndarray:
    """Flat-field gain (H, W) float32 from frames of a uniform target (each (H, W, 3) linear).

    The frames are averaged, reduced to one channel, smoothed (vignetting is smooth; this
    removes what is left of the sensor noise) and normalised to 1 over the central 10%.
    """
    import cv2
    total, n = None, 0
    for lin in linear_frames:
        total = lin.astype(np.float64) if total is None else total + lin
        n += 1
    gain = (total / n).mean(axis=2).astype(np.float32)
    h, w = gain.shape
    gain = cv2.GaussianBlur(gain, (0, 0), sigmaX=max(1.0, 0.01 * max(h, w)))
    centre = float(gain[int(0.45 * h):int(0.55 * h) + 1, int(0.45 * w):int(0.55 * w) + 1].mean())
    if not np.isfinite(centre) or centre <= 0 or gain.min() <= 0:
        raise BTFError(f"flat-field frames are black or invalid (centre level {centre})")
    return gain / centre


def decode_frame(pixels: np.ndarray, space: str) -> np.ndarray:
    """Camera frame values -> (H, W, 3) float32 scene-linear working space (OCIO)."""
    if pixels.dtype.kind == "u":
        return color.integer_decoder(space, 8 if pixels.dtype == np.uint8 else 16).decode(pixels)
    return color.processor(space).apply(pixels)


def _flat_field(rig: _Rig, camera, frames: int, raw: Path, journal: Journal) -> str | None:
    """Shoot ``frames`` frames of the flat-field target, store the smoothed gain map."""
    if journal.flat is not None:
        return journal.flat["flat"]
    try:
        rig.driver.set_flat(True)
    except RigRefused as exc:
        if exc.code != "UNKNOWN":
            raise
        log.info("capture: the rig has no flat-field target (FLAT unknown); frames will not be flat-fielded")
        return None

    def shots():
        for k in range(frames):
            tag = f"flat{k:02d}"
            shot = rig.driver.trigger(tag)
            pixels, space = camera.grab(tag, shot["frame"])
            _check_frame(pixels, space, tag, None)
            yield decode_frame(pixels, space)

    gain = flat_gain(shots())
    rig.driver.set_flat(False)
    _write_durable(raw / FLAT_FILE, gain[..., None], "Raw", "zip")
    journal.append({"flat": FLAT_FILE, "frames": frames})
    return FLAT_FILE


def capture(driver: RigDriver, camera, raw, plan: CapturePlan, *, flat_frames: int = 4, board: dict | None = None,
            extra: dict | None = None, frame_compression: str = "none") -> dict:
    """Run (or resume) the capture of ``plan`` into folder ``raw``; returns a summary.

    driver : an unopened :class:`RigDriver` (opened here, closed at the end).
    camera : an :class:`~usdbtf.rig.camera.OpenCVCamera` or :class:`~usdbtf.rig.camera.CommandCamera`.
    board : the board JSON to record for rectification (optional).
    frame_compression : "none" or "zip" (lossless deflate) for the stored frames.
    """
    raw = Path(raw)
    if (raw / MANIFEST).exists() and not (raw / JOURNAL).exists():
        raise BTFError(f"{raw}: holds a manifest but no capture journal; not a capture folder (choose a new one)")
    (raw / FRAMES).mkdir(parents=True, exist_ok=True)
    lock = _Lock(raw)
    try:
        for stale in list(raw.glob(".tmp-*")) + list((raw / FRAMES).glob(".tmp-*")) + list(raw.glob(".hook-*")):
            stale.unlink()        # half-written by a killed run; the journal does not know them
        journal = Journal(raw / JOURNAL, plan.fingerprint(), {"samples": len(plan.sampling), "to_shoot": len(plan.order)})
        try:
            return _run(driver, camera, raw, plan, journal, flat_frames, board, extra or {}, frame_compression)
        finally:
            journal.close()
    finally:
        lock.release()


def _run(driver, camera, raw, plan, journal, flat_frames, board, extra, frame_compression) -> dict:
    todo = [int(i) for i in plan.order if int(i) not in journal.shots]
    if journal.resumed:
        log.info(f"capture: resuming {raw}: {len(journal.shots)} of {len(plan.order)} samples already shot")
    first = None
    if journal.shots:
        rec = journal.shots[min(journal.shots)]
        info = read_info(raw / rec["image"])
        first = {"width": info.width, "height": info.height,
                 "dtype": str(np.dtype({"uint8": np.uint8, "uint16": np.uint16, "half": np.float16,
                                        "float": np.float32}[info.bit_depth])),
                 "color_space": color.resolve_space(info.color_space)}
    flat = journal.flat["flat"] if journal.flat else None
    progress = bar("capture", len(plan.order), len(journal.shots), logger=log)
    if todo or (flat_frames > 0 and journal.flat is None):
        driver.open()
        try:
            journal.append({"session": {"rig": driver.identity, "port": driver.url, "camera": camera.describe(),
                                        "resumed_with": len(journal.shots)}})
            rig = _Rig(driver)
            if flat_frames > 0:
                flat = _flat_field(rig, camera, flat_frames, raw, journal)
            for i in todo:
                tag = f"s{i:05d}"
                shot = rig.shoot(tag, plan.head[i], plan.arm[i])
                pixels, space = camera.grab(tag, shot["frame"])
                first = _check_frame(pixels, space, tag, first)
                ext = "exr" if pixels.dtype.kind == "f" else "tif"
                name = frame_name(i, plan.sampling.view[i], plan.sampling.light[i], ext)
                _write_durable(raw / name, pixels, space, frame_compression)
                journal.append({"shot": i, "image": name, "frame": shot["frame"]})
                progress.update()
        finally:
            driver.close()
            camera.close()
    progress.finish()
    if first is None:
        raise BTFError(f"{raw}: the plan has no sample to shoot (all {len(plan.sampling)} obstructed?)")
    return _write_manifest(raw, plan, journal, first, flat, board, extra, driver)


def _write_manifest(raw, plan, journal, first, flat, board, extra, driver) -> dict:
    rig_identity = journal.sessions[0]["rig"] if journal.sessions else {}
    samples = []
    for i in sorted(journal.shots):
        samples.append({"image": journal.shots[i]["image"], "view": [float(x) for x in plan.sampling.view[i]],
                        "light": [float(x) for x in plan.sampling.light[i]], "index": i})
    missing = [{"index": int(i), "view": [float(x) for x in plan.sampling.view[i]],
                "light": [float(x) for x in plan.sampling.light[i]], "reason": "obstructed"}
               for i in np.flatnonzero(plan.obstructed)]
    info = {"version": 1, "journal": JOURNAL, "flat_field": flat, "board": board,
            "ordering": plan.ordering, "obstruction": None, "shots": len(samples), "obstructed": len(missing),
            "arm_travel_deg": round(plan.arm_travel_deg(), 3), "head_travel_deg": round(plan.head_travel_deg(), 3),
            "rig": {k: rig_identity[k] for k in sorted(rig_identity) if k in ("model", "serial", "proto")}, **extra,
            "plan": {"view": plan.sampling.view.tolist(), "light": plan.sampling.light.tolist()}}
    if plan.geometry is not None:
        from dataclasses import asdict
        info["obstruction"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(plan.geometry).items()}
    doc = {"format": FORMAT, "color_space": first["color_space"], "width": first["width"], "height": first["height"],
           "raw_capture": info, "missing": missing, "samples": samples}
    with atomic_file(raw / MANIFEST, owner_checked=True) as tmp:
        tmp.write_text(jsontext.dumps(doc) + "\n")
    return {"shots": len(samples), "missing": len(missing), "resumed": journal.resumed, "reconnects": driver.reconnects,
            "resends": driver.resends, "manifest": str(raw / MANIFEST)}
