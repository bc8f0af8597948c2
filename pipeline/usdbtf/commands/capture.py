"""``usdbtf capture``: drive the rig through a capture plan into a RAW manifest folder."""
from __future__ import annotations

import logging
from pathlib import Path

from ..argtypes import float_in, int_in

log = logging.getLogger(__name__)

ORDER = 5


def add_parser(sub) -> None:
    from ..rig import ORDERS
    from ..sampling import PRESETS as SAMPLINGS
    p = sub.add_parser("capture", help="capture frames over the rig's serial link (resumable)",
                       description="Shoots every (view, light) sample of the plan the arm does not obstruct, "
                                   "storing camera frames in a btf-manifest/1 folder with a journal. Re-run the "
                                   "same command to resume after an interruption.")
    p.add_argument("--port", required=True, help="rig port: /dev/ttyUSB0, a pty path, socket://host:port, ...")
    p.add_argument("-o", "--output", required=True, type=Path,
                   help="RAW folder (created, or resumed when it holds a capture; --force starts over)")
    p.add_argument("--sampling", default="paper", choices=sorted(SAMPLINGS),
                   help="direction set (default paper: 90 views at 20 deg x 120 lights at 15 deg)")
    p.add_argument("--order", default="travel", choices=ORDERS,
                   help="travel (default): minimise head and arm travel; sampling: the sampling's own order")
    p.add_argument("--no-obstruction", action="store_true", help="shoot every sample (no arm obstruction model)")
    cam = p.add_mutually_exclusive_group(required=True)
    cam.add_argument("--camera", metavar="SRC", help="cv2.VideoCapture source: device index, URL or image file")
    cam.add_argument("--camera-cmd", metavar="CMD", help="command that writes one frame to {out} "
                                                         "(fields {out}, {tag}, {frame})")
    p.add_argument("--camera-space", help="OCIO colour space of the frames (default: the file's, else sRGB)")
    p.add_argument("--camera-ext", default="tif", help="--camera-cmd: file type of {out} (default tif)")
    p.add_argument("--flat-frames", type=int_in(0, 1000), default=4,
                   help="flat-field frames to average (0 = none; default 4)")
    p.add_argument("--board", type=Path, help="board.json to record for rectification")
    p.add_argument("--frame-compression", default="none", choices=["none", "zip"],
                   help="stored frames: none (default, fastest) or zip (lossless, ~20%% smaller, slower)")
    p.add_argument("--timeout", type=float_in(0, 3600, lo_open=True), default=5.0,
                   help="seconds to wait for a reply (default 5)")
    p.add_argument("--move-timeout", type=float_in(0, 86400, lo_open=True), default=120.0,
                   help="seconds to wait for a move (default 120)")
    p.add_argument("--retries", type=int_in(0, 100), default=3, help="resends per command (default 3)")
    p.add_argument("--reconnect-timeout", type=float_in(0, 86400), default=30.0,
                   help="seconds to keep reopening a dropped link (default 30)")
    p.add_argument("--baud", type=int_in(50, 10_000_000), default=115200)
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import CAPTURE
    return [(args.output, CAPTURE)]


def run(args) -> int:
    import contextlib

    from ..atomic import atomic_dir
    from ..fiducials import load_board
    from ..outputs import CAPTURE, is_kind
    from ..rig.plan import ArmGeometry, make_plan
    from ..sampling import preset

    board = load_board(args.board).to_json() if args.board else None
    plan = make_plan(preset(args.sampling), ordering=args.order,
                     geometry=None if args.no_obstruction else ArmGeometry())
    log.info(f"capture: plan {args.sampling}: {len(plan.sampling)} samples, {int(plan.obstructed.sum())} obstructed, "
        f"{len(plan.order)} to shoot; arm travel {plan.arm_travel_deg():.0f} deg, head travel "
        f"{plan.head_travel_deg():.0f} deg ({args.order} order)")
    # --force over a previous capture starts over: the new capture is written beside it and
    # replaces it when complete.  Otherwise an existing capture folder is resumed.
    fresh = args.force and is_kind(args.output, CAPTURE)
    new_folder = not args.output.exists()
    with (atomic_dir(args.output, kind=CAPTURE) if fresh else contextlib.nullcontext(args.output)) as raw:
        raw.mkdir(parents=True, exist_ok=True)
        try:
            summary = _capture(args, raw, plan, board)
        except BaseException:
            if not fresh and not _shot_anything(raw):
                _undo_start(raw, remove_folder=new_folder)   # nothing to resume: leave no trace
            raise
    log.info(f"capture: {summary['shots']} frames, {summary['missing']} missing (obstructed) -> {summary['manifest']}"
        f" ({summary['reconnects']} reconnects, {summary['resends']} resends)")
    return 0


def _capture(args, raw, plan, board) -> dict:
    from ..rig.camera import CommandCamera, OpenCVCamera
    from ..rig.capture import capture
    from ..rig.driver import RigDriver

    if args.camera is not None:
        camera = OpenCVCamera(args.camera, color_space=args.camera_space)
    else:
        camera = CommandCamera(args.camera_cmd, raw, color_space=args.camera_space, ext=args.camera_ext)
    driver = RigDriver(args.port, timeout=args.timeout, move_timeout=args.move_timeout, retries=args.retries,
                       reconnect_timeout=args.reconnect_timeout, baudrate=args.baud)
    return capture(driver, camera, raw, plan, flat_frames=args.flat_frames, board=board,
                   extra={"sampling": args.sampling}, frame_compression=args.frame_compression)


def _shot_anything(raw: Path) -> bool:
    """Whether a capture folder holds a frame or a flat field worth resuming from."""
    from ..rig.capture import FLAT_FILE, FRAMES
    frames = raw / FRAMES
    return (raw / FLAT_FILE).exists() or (frames.is_dir() and any(not p.name.startswith(".")
                                                                  for p in frames.iterdir()))


def _undo_start(raw: Path, *, remove_folder: bool) -> None:
    """Remove what a capture that shot nothing created (journal, lock, empty frames folder)."""
    import contextlib
    import shutil

    from ..rig.capture import FRAMES, JOURNAL
    for name in (JOURNAL, ".lock"):
        with contextlib.suppress(FileNotFoundError):
            (raw / name).unlink()
    shutil.rmtree(raw / FRAMES, ignore_errors=True)
    for stale in raw.glob(".hook-*"):
        stale.unlink(missing_ok=True)
    if remove_folder:
        with contextlib.suppress(OSError):
            raw.rmdir()
