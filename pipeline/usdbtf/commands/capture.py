"""``usdbtf capture``: drive the rig through a capture plan into a RAW manifest folder."""
from __future__ import annotations

from pathlib import Path

from . import log

ORDER = 5


def add_parser(sub) -> None:
    from ..rig.plan import ORDERS
    from ..sampling import PRESETS as SAMPLINGS
    p = sub.add_parser("capture", help="capture frames over the rig's serial link (resumable)",
                       description="Shoots every (view, light) sample of the plan the arm does not obstruct, "
                                   "storing camera frames in a btf-manifest/1 folder with a journal. Re-run the "
                                   "same command to resume after an interruption.")
    p.add_argument("--port", required=True, help="rig port: /dev/ttyUSB0, a pty path, socket://host:port, ...")
    p.add_argument("-o", "--output", required=True, type=Path, help="RAW folder (created, or resumed)")
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
    p.add_argument("--flat-frames", type=int, default=4, help="flat-field frames to average (0 = none; default 4)")
    p.add_argument("--board", type=Path, help="board.json to record for rectification")
    p.add_argument("--frame-compression", default="none", choices=["none", "zip"],
                   help="stored frames: none (default, fastest) or zip (lossless, ~20%% smaller, slower)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for a reply (default 5)")
    p.add_argument("--move-timeout", type=float, default=120.0, help="seconds to wait for a move (default 120)")
    p.add_argument("--retries", type=int, default=3, help="resends per command (default 3)")
    p.add_argument("--reconnect-timeout", type=float, default=30.0,
                   help="seconds to keep reopening a dropped link (default 30)")
    p.add_argument("--baud", type=int, default=115200)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import BTFError
    from ..fiducials import load_board
    from ..progress import Progress
    from ..rig.camera import CommandCamera, OpenCVCamera
    from ..rig.capture import capture
    from ..rig.driver import RigDriver
    from ..rig.plan import ArmGeometry, make_plan
    from ..sampling import preset

    say = log(args.quiet)
    if args.flat_frames < 0 or args.retries < 0:
        raise BTFError("--flat-frames and --retries must be >= 0")
    board = load_board(args.board).to_json() if args.board else None
    plan = make_plan(preset(args.sampling), ordering=args.order,
                     geometry=None if args.no_obstruction else ArmGeometry())
    say(f"capture: plan {args.sampling}: {len(plan.sampling)} samples, {int(plan.obstructed.sum())} obstructed, "
        f"{len(plan.order)} to shoot; arm travel {plan.arm_travel_deg():.0f} deg, head travel "
        f"{plan.head_travel_deg():.0f} deg ({args.order} order)")
    args.output.mkdir(parents=True, exist_ok=True)
    if args.camera is not None:
        camera = OpenCVCamera(args.camera, color_space=args.camera_space)
    else:
        camera = CommandCamera(args.camera_cmd, args.output, color_space=args.camera_space, ext=args.camera_ext)
    driver = RigDriver(args.port, timeout=args.timeout, move_timeout=args.move_timeout, retries=args.retries,
                       reconnect_timeout=args.reconnect_timeout, baudrate=args.baud, log=say)
    bar = (lambda done, total: Progress("capture", total, done)) if not args.quiet else None
    summary = capture(driver, camera, args.output, plan, flat_frames=args.flat_frames, board=board,
                      extra={"sampling": args.sampling}, frame_compression=args.frame_compression, log=say,
                      progress=bar)
    say(f"capture: {summary['shots']} frames, {summary['missing']} missing (obstructed) -> {summary['manifest']}"
        f" ({summary['reconnects']} reconnects, {summary['resends']} resends)")
    return 0
