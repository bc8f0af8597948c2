"""A simulated rig controller: speaks :mod:`usdbtf.rig.protocol` and photographs a
synthetic BTF sample.

Three parts, each usable alone:

* :class:`RigState` + :class:`RigSimulator` -- the controller: parses requests,
  moves (instantly, or at ``speed_deg_s``), answers, and on ``TRIG`` asks a renderer
  for the frame.  Faults are injected from a seeded RNG: with probability
  ``fault_rate`` a reply is dropped or garbled; ``drop_every`` cuts the link after
  every n-th request (after executing it, before answering: the worst moment), and
  ``reset_on_drop`` makes the controller forget its positions when that happens (a
  power cycle).
* :class:`SceneRenderer` -- the camera: renders the board with the sample for the
  head/arm position (:mod:`usdbtf.rig.scene`), with the light arm drawn where it passes
  in front of the sample (the obstruction the capture plan avoids), adds vignetting and
  sensor noise, and
  writes ``<frames>/<tag>.tif`` (16-bit, sRGB-encoded, colour space declared) plus a
  ``latest.tif`` link to it.  Noise is seeded by (seed, tag), so a frame re-shot under
  the same tag is byte-identical: a resumed capture equals an uninterrupted one.
* :func:`serve_pty` / :func:`serve_socket` -- the link: a pseudo-terminal (optionally
  reachable through a fixed symlink, re-pointed when the link is cut) or a TCP socket
  (``socket://host:port`` for pyserial).
"""
from __future__ import annotations

import logging
import math
import os
import select
import socket
import time
import tty
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import color
from ..errors import BTFError
from ..imageio import write_image
from . import kinematics as K
from . import protocol as P

__all__ = ["RigState", "RigSimulator", "SceneRenderer", "serve_pty", "serve_socket", "CAMERA_SPACE"]

CAMERA_SPACE = "sRGB Encoded Rec.709 (sRGB)"
log = logging.getLogger(__name__)
#: Radiance of the flat-field target (a diffuser lit from behind): uniform, below clipping.
FLAT_RADIANCE = 0.8


@dataclass
class RigState:
    """Where the simulated hardware is.  Angles in degrees (protocol conventions)."""

    arm: tuple = (0.0, 0.0)
    head: tuple = (0.0, 0.0)
    flat: bool = False
    frames: int = 0


def _num(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(text)
    return v


class RigSimulator:
    """The controller logic, independent of the link.

    renderer : callable(tag, head, arm, flat) -> None, called on TRIG (may be None).
    handle(line) returns the reply bytes, or None when the reply is (deliberately) lost;
    :attr:`cut_link` is set when the link must be dropped after this request.
    """

    def __init__(self, renderer=None, *, fault_rate: float = 0.0, seed: int = 0, drop_every: int = 0,
                 reset_on_drop: bool = False, speed_deg_s: float = 0.0, model: str = "usdbtf-sim",
                 serial: str = "SIM-0001"):
        if not 0.0 <= fault_rate < 1.0:
            raise ValueError("fault_rate must be in [0, 1)")
        self.renderer = renderer
        self.state = RigState()
        self.fault_rate = float(fault_rate)
        self.rng = np.random.default_rng(seed)
        self.drop_every = int(drop_every)
        self.reset_on_drop = bool(reset_on_drop)
        self.speed = float(speed_deg_s)
        self.model, self.serial = model, serial
        self.requests = 0
        self.cut_link = False

    # -- request handling ---------------------------------------------------------
    def handle(self, line: bytes) -> bytes | None:
        self.cut_link = False
        try:
            req = P.parse_request(line)
        except P.Garbled as exc:
            return P.encode_reply(0, False, code="CHECKSUM", message=str(exc)[:120])
        self.requests += 1
        reply = self._execute(req)
        if self.drop_every and self.requests % self.drop_every == 0:
            self.cut_link = True
            if self.reset_on_drop:
                self.state = RigState(frames=self.state.frames)
            return None
        if self.fault_rate and self.rng.random() < self.fault_rate:
            return self._fault(reply)
        return reply

    def _fault(self, reply: bytes) -> bytes | None:
        kind = self.rng.integers(3)
        if kind == 0:
            return None                                            # lost
        if kind == 1:                                              # a flipped bit
            pos = int(self.rng.integers(len(reply) - 1))
            b = bytearray(reply)
            b[pos] = (b[pos] ^ (1 << int(self.rng.integers(7)))) or 0x3F
            if b[pos] == 0x0A:
                b[pos] = 0x3F
            return bytes(b)
        return reply[: int(self.rng.integers(1, len(reply) - 1))] + b"\n"   # truncated

    def _ok(self, seq, **fields) -> bytes:
        return P.encode_reply(seq, True, {k: v for k, v in fields.items()})

    def _err(self, seq, code, message) -> bytes:
        return P.encode_reply(seq, False, code=code, message=message)

    def _positions(self) -> dict:
        s = self.state
        return {"arm": f"{P.format_angle(s.arm[0])},{P.format_angle(s.arm[1])}",
                "head": f"{P.format_angle(s.head[0])},{P.format_angle(s.head[1])}",
                "flat": "1" if s.flat else "0"}

    def _move_time(self, old, new) -> None:
        if self.speed > 0:
            d = max(abs(new[0] - old[0]), min(abs(new[1] - old[1]) % 360, 360 - abs(new[1] - old[1]) % 360))
            time.sleep(d / self.speed)

    def _execute(self, req: P.Request) -> bytes:
        seq, cmd, args = req.seq, req.command, req.args
        s = self.state
        try:
            if cmd == "HELLO" and not args:
                return self._ok(seq, proto=P.PROTOCOL, model=self.model, serial=self.serial)
            if cmd == "STATUS" and not args:
                return self._ok(seq, **self._positions(), frames=str(s.frames))
            if cmd == "HOME" and not args:
                self._move_time(s.head, (0.0, 0.0))
                s.arm, s.head = (0.0, 0.0), (0.0, 0.0)
                return self._ok(seq, **self._positions())
            if cmd in ("HEAD", "ARM") and len(args) == 2:
                a, b = _num(args[0]), _num(args[1])
                top = 90.0 if cmd == "HEAD" else 180.0
                if not 0.0 <= a <= top:
                    return self._err(seq, "RANGE", f"{cmd} {args[0]} outside 0..{top:g} deg")
                new = (round(a, 3), round(b % 360.0, 3) % 360.0)
                if cmd == "HEAD":
                    self._move_time(s.head, new)
                    s.head = new
                    return self._ok(seq, head=self._positions()["head"])
                self._move_time(s.arm, new)
                s.arm = new
                return self._ok(seq, arm=self._positions()["arm"])
            if cmd == "FLAT" and len(args) == 1 and args[0] in ("0", "1"):
                s.flat = args[0] == "1"
                return self._ok(seq, flat=args[0])
            if cmd == "TRIG" and len(args) == 1:
                if not P.valid_tag(args[0]):
                    return self._err(seq, "SYNTAX", f"bad frame tag {args[0]!r}")
                if self.renderer is not None:
                    self.renderer(args[0], s.head, s.arm, s.flat)
                s.frames += 1
                return self._ok(seq, frame=str(s.frames), tag=args[0], **self._positions())
        except ValueError:
            return self._err(seq, "SYNTAX", f"bad arguments for {cmd}: {' '.join(args)}")
        except Exception as exc:  # a renderer failure is a camera fault, reported, not a crash
            log.info(f"rig-sim: fault during {cmd}: {exc}")
            return self._err(seq, "FAULT", f"{cmd} failed: {type(exc).__name__}: {exc}")
        if cmd not in P.COMMANDS:
            return self._err(seq, "UNKNOWN", f"unknown command {cmd}")
        return self._err(seq, "SYNTAX", f"wrong arguments for {cmd}: {' '.join(args)}")


class SceneRenderer:
    """The simulated camera (see the module docstring).

    material : usdbtf.synth.Material; board : usdbtf.fiducials.Board; camera : scene.Camera.
    frames_dir : where frames are written.  seed : noise seed.
    """

    def __init__(self, material, board, camera, frames_dir, *, seed: int = 0, supersample: int = 2,
                 arm_geometry=None):
        from .. import synth
        from .scene import paper_albedo, vignetting
        self.material, self.board, self.camera = material, board, camera
        self.frames_dir = Path(frames_dir)
        self.frames_dir.mkdir(parents=True, exist_ok=True)
        self.seed = int(seed)
        self.supersample = int(supersample)
        self.cache = synth.RenderCache(material, max_views=2)
        self.albedo = paper_albedo(board)
        self.vignette = vignetting(camera)[..., None]
        self.encode = color.processor(synth.RADIANCE_SPACE, CAMERA_SPACE)
        from .plan import ArmGeometry
        # The arm drawn into the frames is the one the capture plan's obstruction model assumes.
        self.arm_geometry = arm_geometry or ArmGeometry(camera_distance_m=camera.distance_m)

    def radiance(self, head, arm, flat: bool) -> np.ndarray:
        """The noiseless, unvignetted (H, W, 3) radiance for a rig position."""
        from .. import synth
        from .scene import render_frame
        cam = self.camera
        if flat:
            return np.full((cam.height, cam.width, 3), FLAT_RADIANCE, np.float32)
        head = np.asarray(head, np.float64).reshape(1, 2)
        view = K.view_for_head(head)[0]
        light = K.light_for_arm(head, np.asarray(arm, np.float64).reshape(1, 2))[0]
        if light[0] >= 90.0:   # the light is behind the sample: only ambient darkness
            texture = np.zeros((self.material.size,) * 2 + (3,), np.float32)
        else:
            texture = synth.render_sample(self.material, view, light, cache=self.cache)
        return render_frame(self.board, texture, head[0], light, cam, supersample=self.supersample,
                            board_albedo=self.albedo, arm=(arm, self.arm_geometry))

    def __call__(self, tag: str, head, arm, flat: bool) -> Path:
        from .scene import add_sensor_noise
        rng = np.random.default_rng([self.seed, zlib.crc32(tag.encode())])
        signal = add_sensor_noise(self.radiance(head, arm, flat) * self.vignette, self.camera, rng)
        codes = np.rint(np.clip(self.encode.apply(signal), 0.0, 1.0) * 65535.0).astype(np.uint16)
        # Uncompressed TIFF: what a camera's tethering software drops, and 50x faster to
        # write than a 16-bit PNG.
        path = self.frames_dir / f"{tag}.tif"
        tmp = self.frames_dir / f".{tag}.tmp.tif"
        write_image(tmp, codes, color_space=CAMERA_SPACE, attributes={"compression": "none"})
        os.replace(tmp, path)
        latest_tmp = self.frames_dir / ".latest.tmp.tif"
        if latest_tmp.exists():
            latest_tmp.unlink()
        os.link(path, latest_tmp)
        os.replace(latest_tmp, self.frames_dir / "latest.tif")
        return path


# ------------------------------------------------------------------ links


def _announce(url: str, port_file: str | None) -> None:
    """The URL as the first stdout line (and into ``port_file``, atomically)."""
    if port_file:
        tmp = f"{port_file}.tmp"
        with open(tmp, "w") as fh:
            fh.write(url + "\n")
        os.replace(tmp, port_file)
    print(url, flush=True)


def _lines(buf: bytearray):
    """Pop complete lines (with their newline) from ``buf``; overlong garbage is cut into lines."""
    while True:
        nl = buf.find(b"\n")
        if nl < 0:
            if len(buf) > P.MAX_LINE:
                chunk = bytes(buf[:P.MAX_LINE]) + b"\n"
                del buf[:P.MAX_LINE]
                yield chunk
                continue
            return
        line = bytes(buf[:nl + 1])
        del buf[:nl + 1]
        yield line


def _open_pty(link: str | None) -> tuple[int, int, str]:
    if link and os.path.lexists(link) and not os.path.islink(link):
        raise BTFError(f"--link {link}: exists and is not a symlink; refusing to replace it")
    master, slave = os.openpty()
    tty.setraw(slave)     # no echo, no line editing: a byte-clean serial line
    path = os.ttyname(slave)
    if link:
        tmp = f"{link}.tmp-{os.getpid()}"
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(path, tmp)
        os.replace(tmp, link)
    return master, slave, path


def serve_pty(sim: RigSimulator, *, link: str | None = None, port_file: str | None = None) -> None:
    """Serve on a pseudo-terminal until killed.  Prints the port (``link`` if given).

    The simulator keeps the slave end open itself, so a client may close and reopen
    the port freely; cutting the link closes both ends (the client sees a hang-up) and
    opens a fresh pty, re-pointing ``link`` at it.
    """
    master, slave, path = _open_pty(link)
    _announce(link or path, port_file)
    log.info(f"rig-sim: pty {path}" + (f" (link {link})" if link else ""))
    buf = bytearray()
    try:
        while True:
            ready, _, _ = select.select([master], [], [], 1.0)
            if not ready:
                continue
            try:
                data = os.read(master, 4096)
            except OSError:
                data = b""
            if not data:
                continue
            buf.extend(data)
            for line in _lines(buf):
                reply = sim.handle(line)
                if sim.cut_link:
                    log.info("rig-sim: cutting the link")
                    os.close(master)
                    os.close(slave)
                    buf.clear()
                    master, slave, path = _open_pty(link)
                    log.info(f"rig-sim: new pty {path}")
                    break
                if reply is not None:
                    os.write(master, reply)
    finally:
        for fd in (master, slave):
            try:
                os.close(fd)
            except OSError:
                pass
        if link and os.path.islink(link) and os.readlink(link) == path:
            os.unlink(link)      # leave no link to a pty that is gone


def serve_socket(sim: RigSimulator, host: str = "127.0.0.1", port: int = 0, *, port_file: str | None = None) -> None:
    """Serve on TCP until killed, one client at a time.  Prints ``socket://host:port``."""
    server = socket.create_server((host, port))
    _announce(f"socket://{host}:{server.getsockname()[1]}", port_file)
    while True:
        conn, peer = server.accept()
        log.info(f"rig-sim: client {peer[0]}:{peer[1]}")
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        buf = bytearray()
        with conn:
            while True:
                try:
                    data = conn.recv(4096)
                except OSError:
                    break
                if not data:
                    break
                buf.extend(data)
                cut = False
                for line in _lines(buf):
                    reply = sim.handle(line)
                    if sim.cut_link:
                        log.info("rig-sim: cutting the link")
                        cut = True
                        break
                    if reply is not None:
                        try:
                            conn.sendall(reply)
                        except OSError:
                            cut = True
                            break
                if cut:
                    break
        # A cut link: the connection closes and the next client is accepted.

