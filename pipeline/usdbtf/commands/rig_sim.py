"""``usdbtf rig-sim``: a simulated rig controller on a pty or a TCP socket."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from ..argtypes import SEED, float_in, int_in

log = logging.getLogger(__name__)
ORDER = 4
#: Arguments that name outputs (every other path argument is an input).
OUTPUT_ARGS = ("frames", "port_file", "link")
#: Largest simulated frame side (pixels).
MAX_FRAME = 8192


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if not (64 <= w <= MAX_FRAME and 64 <= h <= MAX_FRAME):
        raise argparse.ArgumentTypeError(f"frames must be 64x64 to {MAX_FRAME}x{MAX_FRAME}, got {w}x{h}")
    return w, h


def _listen(text: str) -> tuple[str, int]:
    """HOST:PORT (HOST may be empty: 127.0.0.1) with a port in 0..65535."""
    host, sep, port = text.rpartition(":")
    try:
        number = int(port, 10)
    except ValueError:
        number = -1
    if not sep or not 0 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT with a port in 0..65535, got {text!r}")
    return host or "127.0.0.1", number


def add_parser(sub) -> None:
    p = sub.add_parser("rig-sim", help="simulated rig: serves the rig protocol, photographs a synthetic sample",
                       description="Serves the usdbtf-rig/1 protocol (docs/rig-protocol.md). Prints the port "
                                   "(a pty path or socket://host:port) as the first line on stdout, then runs "
                                   "until killed. Frames go to --frames as <tag>.tif (16-bit sRGB) and latest.tif.")
    link = p.add_mutually_exclusive_group()
    link.add_argument("--pty", action="store_true", help="serve on a pseudo-terminal (the default)")
    link.add_argument("--listen", metavar="HOST:PORT", type=_listen,
                      help="serve on TCP instead (port 0 picks a free one)")
    p.add_argument("--link", metavar="PATH", type=Path, help="pty only: a symlink to the pty, kept pointing at it when the "
                                                   "link is cut and a new pty opens")
    p.add_argument("--port-file", metavar="PATH", type=Path, help="also write the port to this file")
    p.add_argument("--frames", type=Path, required=True, help="folder for the rendered frames")
    p.add_argument("--material", default="pebbles", help="synth material (a `usdbtf synth` preset, e.g. pebbles)")
    p.add_argument("--texture-size", type=int_in(8, 4096), default=128,
                   help="texels per side of the sample (default 128)")
    p.add_argument("--seed", type=SEED, default=0, help="material, noise and fault seed")
    p.add_argument("--board", type=Path, help="board.json (default: the standard board of `usdbtf board`)")
    p.add_argument("--frame-size", type=_size, default=(1600, 1200), metavar="WxH", help="default 1600x1200")
    p.add_argument("--fill", type=float_in(0, 1, lo_open=True), default=0.62,
                   help="board height / frame height head-on (default 0.62)")
    p.add_argument("--vignetting", type=float_in(0, 10), default=1.0,
                   help="lens falloff strength, 0 = none (default 1)")
    p.add_argument("--read-noise", type=float_in(0, 1), default=0.001,
                   help="sensor read noise, std dev (default 0.001)")
    p.add_argument("--shot-noise", type=float_in(0, 1), default=1e-4,
                   help="sensor shot-noise variance per unit signal")
    p.add_argument("--fault-rate", type=float_in(0, 1, hi_open=True), default=0.0,
                   help="probability a reply is lost or garbled (default 0)")
    p.add_argument("--drop-every", type=int_in(0), default=0, metavar="N",
                   help="cut the link after every N-th request")
    p.add_argument("--reset-on-drop", action="store_true", help="forget positions when the link is cut")
    p.add_argument("--speed", type=float_in(0, 1e6), default=0.0, metavar="DEG_S", help="motion speed, 0 = instant")
    p.set_defaults(func=run)


def outputs(args):
    from ..outputs import PORT, PTY_LINK, SIM_FRAMES
    return ([(args.frames, SIM_FRAMES)] + ([(args.port_file, PORT)] if args.port_file else [])
            + ([(args.link, PTY_LINK)] if args.link else []))


def run(args) -> int:
    from .. import synth
    from ..errors import UsageError
    from ..fiducials import load_board, make_board
    from ..rig import sim
    from ..camera import Camera

    if args.link and args.listen:
        raise UsageError("--link applies to --pty only")
    board = load_board(args.board) if args.board else make_board()
    try:
        material = synth.make_material(args.material, args.texture_size, args.seed)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    w, h = args.frame_size
    camera = Camera.framing(board, w, h, fill=args.fill, vignetting=args.vignetting, read_noise=args.read_noise,
                            shot_noise=args.shot_noise)
    renderer = sim.SceneRenderer(material, board, camera, args.frames, seed=args.seed)
    rig = sim.RigSimulator(renderer, fault_rate=args.fault_rate, seed=args.seed, drop_every=args.drop_every,
                           reset_on_drop=args.reset_on_drop, speed_deg_s=args.speed)
    import signal
    import sys
    # Killed politely (SIGTERM), clean up as on Ctrl-C: close the link, remove the --link symlink.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    log.info(f"rig-sim: {args.material} {args.texture_size}^2 in a {len(board.ids)}-marker board, frames "
             f"{w}x{h} -> {args.frames}")
    port_file = str(args.port_file) if args.port_file else None
    if args.listen:
        host, port = args.listen
        try:
            sim.serve_socket(rig, host, port, port_file=port_file)
        except OSError as exc:
            from ..errors import IOFailure
            raise IOFailure(f"--listen {host}:{port}: {' '.join((exc.strerror or str(exc)).split())}") from None
    else:
        sim.serve_pty(rig, link=str(args.link) if args.link else None, port_file=port_file)
    return 0
