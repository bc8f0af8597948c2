"""Shared by the rig tests: start ``usdbtf rig-sim`` / ``usdbtf capture`` as real processes,
and fake controllers on a real pty for the failure cases."""
from __future__ import annotations

import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
import tty
from pathlib import Path

import numpy as np

USDBTF = [sys.executable, "-m", "usdbtf.cli"]
ENV = dict(os.environ, OCIO="ocio://default", PYTHONUNBUFFERED="1")
ROOT = Path(__file__).resolve().parent.parent
if "PYTHONPATH" not in ENV:
    ENV["PYTHONPATH"] = str(ROOT / "pipeline")


class Sim:
    """A running ``usdbtf rig-sim`` process; ``url`` is the port it announced."""

    def __init__(self, frames: Path, *args, listen: str | None = "127.0.0.1:0", size: str = "160x120",
                 texture: int = 16, timeout: float = 30.0):
        cmd = USDBTF + ["rig-sim", "--frames", str(frames), "--frame-size", size, "--texture-size", str(texture),
                        "-q", *map(str, args)]
        if listen:
            cmd += ["--listen", listen]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=ENV)
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            self.kill()
            raise RuntimeError("rig-sim did not announce its port")
        self.url = self.proc.stdout.readline().decode().strip()
        if not self.url:
            err = self.proc.stderr.read().decode()
            raise RuntimeError(f"rig-sim failed: {err}")

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(10)
        for stream in (self.proc.stdout, self.proc.stderr):
            stream.close()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def capture_cmd(url: str, raw: Path, frames: Path, *extra) -> list:
    return USDBTF + ["capture", "--port", url, "-o", str(raw), "--sampling", "tiny", "--flat-frames", "2",
                     "--camera-cmd", f"cp {frames}/{{tag}}.tif {{out}}", "--timeout", "1", "--move-timeout", "1", "--retries", "5",
                     "--reconnect-timeout", "20", *map(str, extra)]


def run_capture(url: str, raw: Path, frames: Path, *extra, timeout: float = 120.0) -> subprocess.CompletedProcess:
    return subprocess.run(capture_cmd(url, raw, frames, *extra), capture_output=True, text=True, env=ENV,
                          timeout=timeout)


def journal_shots(raw: Path) -> int:
    try:
        return (raw / "journal.jsonl").read_bytes().count(b'"shot"')
    except FileNotFoundError:
        return 0


def wait_for(predicate, timeout: float = 60.0, interval: float = 0.005) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(interval)
    return False


def tree_bytes(folder: Path) -> dict:
    """{relative path: bytes} of every file, hidden files included."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


class FakeController:
    """A controller on a real pty whose replies come from ``respond(line) -> bytes | None``."""

    def __init__(self, respond):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.respond = respond
        self.stop = False
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        buf = b""
        while not self.stop:
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if not ready:
                continue
            try:
                buf += os.read(self.master, 4096)
            except OSError:
                return
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                reply = self.respond(line + b"\n")
                if reply:
                    os.write(self.master, reply)

    def close(self) -> None:
        self.stop = True
        self.thread.join(2)
        os.close(self.master)
        os.close(self.slave)

    def __enter__(self) -> "FakeController":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def garbage(seed: int = 0):
    rng = np.random.default_rng(seed)
    return lambda line: bytes(rng.integers(33, 127, 40, dtype=np.uint8)) + b"\n"
