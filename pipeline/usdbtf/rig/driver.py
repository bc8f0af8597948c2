"""Host side of the rig protocol (:mod:`usdbtf.rig.protocol`) over pyserial.

:class:`RigDriver` opens any pyserial port URL -- ``/dev/ttyUSB0``, a pty path,
``socket://host:port``, ``rfc2217://...`` -- and turns protocol exchanges into method
calls that either return the rig's reply fields or raise :class:`~usdbtf.errors.BTFError`
with one line naming the port and the command.

Failure handling (why each case is handled the way it is):

* no reply within the timeout, or a garbled reply: resend with a new seq, up to
  ``retries`` more times (a noisy line or a lost byte should not stop a 10-hour capture);
* a reply carrying another seq: a late answer to an abandoned request; discarded;
* ``ERR CHECKSUM`` / ``ERR BUSY``: resend (after a short pause for BUSY);
* other ``ERR`` codes: final, BTFError with the rig's message;
* the link drops (the port raises, the socket closes, the pty hangs up): reopen the
  same URL every ``reconnect_interval`` seconds for up to ``reconnect_timeout`` seconds,
  greet the rig again and resend.  :attr:`RigDriver.reconnects` counts these, so callers
  can re-check positions a power-cycled controller may have lost;
* the first greeting gets garbage or a foreign protocol: BTFError at once (wrong
  device or wrong baud rate; retrying would not help).
"""
from __future__ import annotations

import logging
import time

from ..errors import BTFError
from . import protocol as P

log = logging.getLogger(__name__)

__all__ = ["RigDriver", "RigRefused", "LinkDropped"]


class RigRefused(BTFError):
    """The rig answered ``ERR <code>`` with a final code (``code`` attribute)."""

    def __init__(self, message: str, code: str):
        super().__init__(message)
        self.code = code


class LinkDropped(Exception):
    """The byte link failed; the driver reconnects."""


def _link_errors() -> tuple:
    """Exceptions meaning the byte link failed.  termios.error (a pty whose other end
    closed, raised by tcdrain) is not an OSError, so it is listed explicitly."""
    import serial
    try:
        import termios
        return (serial.SerialException, OSError, termios.error)
    except ImportError:  # not POSIX
        return (serial.SerialException, OSError)


class _NoReply(Exception):
    pass


class RigDriver:
    """A connection to one rig controller.

    Parameters
    ----------
    url : pyserial port or URL.
    timeout : seconds to wait for the reply to a quick command (HELLO, STATUS, FLAT, TRIG).
    move_timeout : seconds to wait for a move (HEAD, ARM, HOME) to finish and reply.
    retries : resends after a timeout or a garbled reply, per command.
    reconnect_timeout : seconds to keep trying to reopen a dropped link (0: fail at once).
    """

    #: A link that comes back but drops again at once this often is broken, not flaky.
    MAX_DROPS_PER_COMMAND = 10

    def __init__(self, url: str, *, timeout: float = 5.0, move_timeout: float = 120.0, retries: int = 3,
                 reconnect_timeout: float = 30.0, reconnect_interval: float = 0.2, baudrate: int = 115200):
        self.url = str(url)
        self.timeout = float(timeout)
        self.move_timeout = float(move_timeout)
        self.retries = int(retries)
        self.reconnect_timeout = float(reconnect_timeout)
        self.reconnect_interval = float(reconnect_interval)
        self.baudrate = int(baudrate)
        self.reconnects = 0
        self.resends = 0
        self.identity: dict = {}
        self._port = None
        self._seq = 0

    # -- connection ---------------------------------------------------------------
    def __enter__(self) -> "RigDriver":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def open(self) -> dict:
        """Open the port and greet the rig; returns the HELLO fields."""
        self._connect(self.reconnect_timeout)
        return self.identity

    def close(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            except Exception:  # closing a dead link can fail in many ways; it is closed either way
                pass
            self._port = None

    def _open_port(self):
        import serial
        try:
            return serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=self.timeout,
                                         write_timeout=self.timeout)
        except ValueError as exc:  # a malformed URL: no amount of retrying fixes it
            raise BTFError(f"rig port {self.url!r}: {exc}") from None

    def _connect(self, patience: float) -> None:
        deadline = time.monotonic() + max(patience, 0.0)
        while True:
            try:
                self._port = self._open_port()
                self._port.reset_input_buffer()
                self.identity = self._greet()
                return
            except (*_link_errors(), LinkDropped) as exc:
                self.close()
                if time.monotonic() >= deadline:
                    raise BTFError(f"rig port {self.url}: cannot open ({' '.join(str(exc).split())})") from None
                time.sleep(self.reconnect_interval)

    def _greet(self) -> dict:
        """HELLO on a fresh link, resent like any command; persistent garbage or a foreign
        protocol is final (a wrong device or baud rate: retrying would not help)."""
        problems = []
        while len(problems) <= self.retries:
            try:
                reply = self._exchange("HELLO", (), self.timeout)
            except _NoReply:
                problems.append(f"no reply within {self.timeout:g} s")
                continue
            except P.Garbled as exc:
                problems.append(f"garbled reply: {exc}")
                self._drain()
                continue
            if reply.ok and reply.fields.get("proto") == P.PROTOCOL:
                return dict(reply.fields)
            if not reply.ok and reply.code in P.RETRYABLE:
                problems.append(f"{reply.code} {reply.message}".rstrip())
                continue
            self.close()
            raise BTFError(f"rig at {self.url}: HELLO answered with protocol {reply.fields.get('proto')!r}, "
                           f"expected {P.PROTOCOL!r} {reply.code} {reply.message}".rstrip())
        self.close()
        raise BTFError(f"rig at {self.url}: HELLO failed after {len(problems)} tries ({problems[-1]}); is this a "
                       f"usdbtf-rig/{P.PROTOCOL} controller at {self.baudrate} baud?")

    def _reconnect(self, why: str) -> None:
        self.close()
        self.reconnects += 1
        log.info(f"rig link to {self.url} dropped ({why}); reconnecting")
        if self.reconnect_timeout <= 0:
            raise BTFError(f"rig at {self.url}: link dropped ({why})")
        self._connect(self.reconnect_timeout)
        log.info(f"rig link to {self.url} restored")

    # -- one exchange -------------------------------------------------------------
    def _next_seq(self) -> int:
        self._seq = self._seq % P.MAX_SEQ + 1
        return self._seq

    def _exchange(self, command: str, args: tuple, timeout: float) -> P.Reply:
        """Send once, wait for the matching reply.  Raises LinkDropped, _NoReply or Garbled."""
        if self._port is None:
            raise LinkDropped("port closed")
        seq = self._next_seq()
        deadline = time.monotonic() + timeout
        try:
            self._port.write(P.encode_request(seq, command, *args))
            self._port.flush()
            while True:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise _NoReply()
                self._port.timeout = left
                line = self._port.read_until(b"\n", P.MAX_LINE + 1)
                if not line.endswith(b"\n"):
                    if len(line) > P.MAX_LINE:
                        raise P.Garbled(f"line longer than {P.MAX_LINE} bytes: {line[:40]!r}...")
                    if line:
                        raise P.Garbled(f"incomplete line {line[:60]!r}")
                    raise _NoReply()
                reply = P.parse_reply(line)
                if reply.seq == seq or (reply.seq == 0 and not reply.ok and reply.code == "CHECKSUM"):
                    return reply
                # A late reply to an earlier, abandoned request: not ours.
        except _link_errors() as exc:
            raise LinkDropped(" ".join(str(exc).split()) or type(exc).__name__) from None

    def call(self, command: str, *args) -> dict:
        """Send a command until it succeeds; returns the reply fields.  BTFError on failure."""
        args = tuple(str(a) for a in args)
        text = " ".join((command,) + args)
        timeout = self.move_timeout if command in ("HEAD", "ARM", "HOME") else self.timeout
        problems, drops = [], 0
        while len(problems) <= self.retries:
            if self._port is None:
                self._reconnect("port closed")
            try:
                reply = self._exchange(command, args, timeout)
            except LinkDropped as exc:
                drops += 1
                if drops > self.MAX_DROPS_PER_COMMAND:
                    raise BTFError(f"rig at {self.url}: '{text}': the link dropped {drops} times in a row ({exc})")
                self._reconnect(str(exc))
                continue
            except _NoReply:
                problems.append(f"no reply within {timeout:g} s")
            except P.Garbled as exc:
                problems.append(f"garbled reply: {exc}")
                self._drain()
            else:
                if reply.ok:
                    return dict(reply.fields)
                if reply.code not in P.RETRYABLE:
                    raise RigRefused(f"rig at {self.url}: '{text}' refused: {reply.code} {reply.message}".rstrip(),
                                     reply.code)
                problems.append(f"{reply.code} {reply.message}".rstrip())
                if reply.code == "BUSY":
                    time.sleep(min(0.5, self.timeout / 4))
            if len(problems) <= self.retries:
                self.resends += 1
                log.info(f"rig at {self.url}: '{text}': {problems[-1]}; resending")
        raise BTFError(f"rig at {self.url}: '{text}' failed after {len(problems)} tries; last: {problems[-1]}")

    def _drain(self) -> None:
        """Drop whatever else is buffered after a garbled line (the rest of the garbage)."""
        try:
            self._port.reset_input_buffer()
        except (*_link_errors(), AttributeError):
            pass  # a dead link shows up, and is handled, at the next exchange

    # -- commands -----------------------------------------------------------------
    def status(self) -> dict:
        return self.call("STATUS")

    def move_head(self, tilt: float, pan: float) -> tuple[float, float]:
        f = self.call("HEAD", P.format_angle(tilt), P.format_angle(pan))
        return self._pair(f, "head", "HEAD")

    def move_arm(self, theta: float, phi: float) -> tuple[float, float]:
        f = self.call("ARM", P.format_angle(theta), P.format_angle(phi))
        return self._pair(f, "arm", "ARM")

    def set_flat(self, on: bool) -> None:
        self.call("FLAT", "1" if on else "0")

    def trigger(self, tag: str) -> dict:
        """Expose one frame tagged ``tag``; returns {frame, tag, arm, head, flat} parsed."""
        if not P.valid_tag(tag):
            raise ValueError(f"invalid frame tag {tag!r}")
        f = self.call("TRIG", tag)
        if f.get("tag") != tag:
            raise BTFError(f"rig at {self.url}: TRIG {tag} answered for tag {f.get('tag')!r}")
        try:
            return {"frame": int(f["frame"]), "tag": tag, "arm": P.parse_pair(f["arm"]),
                    "head": P.parse_pair(f["head"]), "flat": f.get("flat", "0") == "1"}
        except (KeyError, ValueError):
            raise BTFError(f"rig at {self.url}: TRIG reply lacks frame/arm/head fields: {f}") from None

    def _pair(self, fields: dict, key: str, command: str) -> tuple[float, float]:
        try:
            return P.parse_pair(fields[key])
        except (KeyError, ValueError):
            raise BTFError(f"rig at {self.url}: {command} reply lacks a valid {key}=a,b field: {fields}") from None
