"""The rig line protocol (``usdbtf-rig/1``): how the host talks to the rig controller.

The controller moves a light arm and a pan/tilt sample head, swings a flat-field target
in front of the lens, and triggers the camera.  It speaks ASCII lines over any byte
link (RS-232/USB serial, a pty, TCP); :mod:`usdbtf.rig.driver` is the host side and
:mod:`usdbtf.rig.sim` a simulated controller.  docs/rig-protocol.md has the same text
for people writing controller firmware.

Framing
-------
One message per line, ``\\n``-terminated (a ``\\r`` before it is ignored), at most
:data:`MAX_LINE` bytes, 7-bit ASCII.  Every line ends in ``*HH``: two upper-case hex
digits, the XOR of all bytes before the ``*`` (as in NMEA 0183).  A line that fails the
checksum or does not parse is *garbled*.

Requests (host -> rig)::

    <seq> <COMMAND> [<arg> ...]*HH

``seq`` is a decimal 1..65535 chosen by the host, a new one per transmission (retries
included); the reply echoes it, so the host can tell a late reply to an earlier,
abandoned request from the one it is waiting for.

Replies (rig -> host), exactly one per request, sent when the command has *finished*
(a move has stopped, an exposure has ended)::

    <seq> OK [<key>=<value> ...]*HH
    <seq> ERR <CODE> <message ...>*HH

A rig that receives a garbled request replies ``0 ERR CHECKSUM ...`` (seq 0: it cannot
trust the seq it read).

Commands
--------
=========================  =======================================================
``HELLO``                  identify: ``OK proto=1 model=<name> serial=<id>``
``STATUS``                 ``OK arm=<t>,<p> head=<tilt>,<pan> flat=<0|1> frames=<n>``
``HEAD <tilt> <pan>``      move the head; ``OK head=<tilt>,<pan>``
``ARM <theta> <phi>``      move the light arm; ``OK arm=<theta>,<phi>``
``FLAT <0|1>``             flat-field target out / in front of the lens; ``OK flat=<0|1>``
``TRIG <tag>``             expose one frame; ``OK frame=<n> tag=<tag> arm=.. head=.. flat=..``
``HOME``                   arm and head to 0; ``OK arm=0,0 head=0,0``
=========================  =======================================================

Angles are degrees, decimal with up to 3 fractional digits.  ``tilt`` is in [0, 90],
``pan`` any value (the rig reports it in [0, 360)); the arm's ``theta`` (from the camera
axis) is in [0, 180], ``phi`` any value.  Geometry: :mod:`usdbtf.rig.kinematics`.
``tag`` is 1-32 characters from ``[A-Za-z0-9_.-]``; the rig attaches it to the frame
(the simulator names its frame file after it), which lets the host match frames to
samples across retries and restarts.  Replies report the positions the rig actually
has, so the host can check a frame was taken where it asked.

Error codes
-----------
``SYNTAX`` bad arguments; ``UNKNOWN`` unknown command; ``RANGE`` outside the travel;
``CHECKSUM`` the request arrived garbled (resend); ``BUSY`` try again shortly;
``FAULT`` a hardware fault that needs a person.  The host resends on ``CHECKSUM`` and
``BUSY`` and treats the others as final.

Host behaviour (what :class:`usdbtf.rig.driver.RigDriver` does): a request with no
reply within the timeout, or with a garbled reply, is resent with a new seq, up to a
retry limit; replies with another seq are discarded; a dropped link (the port errors or
closes) is reopened, re-greeted with ``HELLO`` and the request resent.  Every command is
idempotent except ``TRIG``, whose repeat only costs an extra exposure.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field

__all__ = ["PROTOCOL", "MAX_LINE", "COMMANDS", "ERROR_CODES", "RETRYABLE", "Garbled", "Request", "Reply",
           "checksum", "frame", "unframe", "encode_request", "parse_request", "encode_reply", "parse_reply",
           "format_angle", "parse_pair", "valid_tag"]

PROTOCOL = "1"
MAX_LINE = 256
COMMANDS = ("HELLO", "STATUS", "HEAD", "ARM", "FLAT", "TRIG", "HOME")
ERROR_CODES = ("SYNTAX", "UNKNOWN", "RANGE", "CHECKSUM", "BUSY", "FAULT")
RETRYABLE = ("CHECKSUM", "BUSY")
MAX_SEQ = 65535

_TAG = re.compile(r"^[A-Za-z0-9_.-]{1,32}$")
_TOKEN = re.compile(r"^[\x21-\x7e]+$")  # printable, no spaces


class Garbled(ValueError):
    """A line that fails the checksum or does not parse (a transmission error)."""


def checksum(payload: bytes) -> str:
    """Two upper-case hex digits: XOR of the payload bytes."""
    x = 0
    for b in payload:
        x ^= b
    return f"{x:02X}"


def frame(payload: str) -> bytes:
    """``payload`` -> ``payload*HH\\n`` bytes."""
    raw = payload.encode("ascii")
    line = raw + b"*" + checksum(raw).encode("ascii") + b"\n"
    if len(line) > MAX_LINE:
        raise ValueError(f"line longer than {MAX_LINE} bytes: {payload[:40]}...")
    return line


def unframe(line: bytes) -> str:
    """A received line (with or without its newline) -> payload; Garbled if the checksum fails."""
    line = line.rstrip(b"\n").rstrip(b"\r")
    if len(line) > MAX_LINE or len(line) < 4 or line[-3:-2] != b"*":
        raise Garbled(f"not a protocol line: {line[:60]!r}")
    payload, ck = line[:-3], line[-2:]
    try:
        text = payload.decode("ascii")
    except UnicodeDecodeError:
        raise Garbled(f"non-ASCII bytes in {line[:60]!r}") from None
    if checksum(payload).encode("ascii") != ck:
        raise Garbled(f"checksum mismatch in {line[:60]!r}")
    return text


def format_angle(x: float) -> str:
    """Degrees as sent on the wire: up to 3 decimals, no exponent, no '-0'."""
    s = f"{float(x):.3f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def parse_pair(text: str) -> tuple[float, float]:
    """``"12.5,30"`` -> (12.5, 30.0); ValueError if malformed."""
    a, b = text.split(",")
    return float(a), float(b)


def valid_tag(tag: str) -> bool:
    return bool(_TAG.match(tag))


@dataclass(frozen=True)
class Request:
    seq: int
    command: str
    args: tuple = ()

    def text(self) -> str:
        return " ".join([self.command, *self.args])


@dataclass(frozen=True)
class Reply:
    """A parsed reply: ``ok`` with ``fields``, or an error ``code`` with ``message``."""

    seq: int
    ok: bool
    fields: dict = field(default_factory=dict)
    code: str = ""
    message: str = ""


def _seq(token: str) -> int:
    if not token.isdigit() or len(token) > 5 or int(token) > MAX_SEQ:
        raise Garbled(f"bad sequence number {token!r}")
    return int(token)


def encode_request(seq: int, command: str, *args) -> bytes:
    if not 1 <= seq <= MAX_SEQ:
        raise ValueError(f"seq must be in 1..{MAX_SEQ}")
    if command not in COMMANDS:
        raise ValueError(f"unknown command {command!r}")
    words = [str(seq), command, *(str(a) for a in args)]
    if not all(_TOKEN.match(w) for w in words):
        raise ValueError(f"request words must be printable ASCII without spaces: {words}")
    return frame(" ".join(words))


def parse_request(line: bytes) -> Request:
    """Rig side: a received request line -> Request (Garbled when it fails framing)."""
    words = unframe(line).split(" ")
    if len(words) < 2:
        raise Garbled(f"request without a command: {line[:60]!r}")
    return Request(_seq(words[0]), words[1], tuple(words[2:]))


def encode_reply(seq: int, ok: bool, fields: dict | None = None, code: str = "", message: str = "") -> bytes:
    if ok:
        words = [str(seq), "OK", *(f"{k}={v}" for k, v in (fields or {}).items())]
    else:
        if code not in ERROR_CODES:
            raise ValueError(f"unknown error code {code!r}")
        # Keep replies one printable line whatever the message says.
        clean = "".join(ch if 32 <= ord(ch) < 127 and ch != "*" else "?" for ch in message)
        words = [str(seq), "ERR", code] + ([" ".join(clean.split())] if clean.strip() else [])
    return frame(" ".join(words))


def parse_reply(line: bytes) -> Reply:
    """Host side: a received reply line -> Reply (Garbled when it fails framing or syntax)."""
    words = unframe(line).split(" ")
    if len(words) < 2:
        raise Garbled(f"reply without a status: {line[:60]!r}")
    seq = _seq(words[0])
    if words[1] == "OK":
        fields = {}
        for w in words[2:]:
            key, eq, value = w.partition("=")
            if not eq or not key:
                raise Garbled(f"reply field {w!r} is not key=value")
            fields[key] = value
        return Reply(seq, True, fields)
    if words[1] == "ERR" and len(words) >= 3 and words[2] in ERROR_CODES:
        return Reply(seq, False, code=words[2], message=" ".join(words[3:]))
    raise Garbled(f"reply status must be OK or ERR <code>: {line[:60]!r}")
