"""Progress bars of long work (captures, rectification, synthesis, writing samples): one helper.

Messages go through :mod:`logging` (one logger per module, ``logging.getLogger(__name__)``;
the command line sets the level with ``-q``/``-v``).  A progress bar is not a message: it is
one line with rate and ETA, drawn on stderr by :func:`bar` (or :func:`track` over an
iterable) only when stderr is a terminal or when asked (``usdbtf --progress``), and only
while the caller's logger shows info messages (``-q`` hides it).  Stdout is never touched,
so ``--json`` output stays one document.

On a terminal the line is redrawn in place; in a log (not a tty, ``--progress``) a line is
printed at most every ``log_interval`` seconds, so a 10-hour capture does not write 10^4
lines.  The rate counts only work done in this run (a resumed capture's earlier samples are
not "fast"), and the ETA is the remaining count over that rate.
"""
from __future__ import annotations

import logging
import sys
import time
from typing import Iterable, Iterator

__all__ = ["Progress", "bar", "track", "show_progress", "format_duration"]

#: Draw bars even when stderr is not a terminal (``usdbtf --progress``).
_forced = False


def show_progress(force: bool) -> None:
    """Draw progress bars on a stderr that is not a terminal too (``True``), or only on a
    terminal (``False``, the default)."""
    global _forced
    _forced = bool(force)


def bar(label: str, total: int, done: int = 0, *, logger: logging.Logger | None = None) -> "Progress":
    """The progress bar of ``total`` items (``done`` of them finished before this run).

    Drawn on stderr when it is a terminal or when :func:`show_progress` asked for it, and
    when ``logger`` (default ``usdbtf``) shows info messages; otherwise a silent
    :class:`Progress`.  Call :meth:`Progress.update` per item and :meth:`Progress.finish`."""
    logger = logger or logging.getLogger("usdbtf")
    stream = sys.stderr
    on_terminal = bool(getattr(stream, "isatty", lambda: False)())
    return Progress(label, total, done, stream=stream,
                    enabled=logger.isEnabledFor(logging.INFO) and (_forced or on_terminal))


def track(items: Iterable, label: str, total: int, *, logger: logging.Logger | None = None) -> Iterator:
    """``items`` with a :func:`bar` advanced per item (finished when they run out)."""
    progress = bar(label, total, logger=logger)
    try:
        for item in items:
            yield item
            progress.update()
    finally:
        progress.finish()


def format_duration(seconds: float) -> str:
    """3725 -> '1h02m', 75 -> '1m15s', 4.2 -> '4s'."""
    s = int(round(max(seconds, 0.0)))
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


class Progress:
    """``Progress(label, total, done)``; call :meth:`update` per item and :meth:`finish` at the end."""

    def __init__(self, label: str, total: int, done: int = 0, *, stream=None, enabled: bool = True,
                 width: int = 24, redraw_interval: float = 0.2, log_interval: float = 10.0, clock=time.monotonic):
        self.label, self.total, self.done = label, int(total), int(done)
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled and self.total > 0
        self.width = width
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = redraw_interval if self.tty else log_interval
        self.clock = clock
        self.start_done = self.done
        self.start = clock()
        self.last = -float("inf")

    def text(self) -> str:
        frac = self.done / self.total if self.total else 1.0
        bar = "#" * int(round(frac * self.width))
        elapsed = self.clock() - self.start
        fresh = self.done - self.start_done
        # Too early for a rate: the first item says nothing about the pace.
        rate = fresh / elapsed if elapsed >= 0.5 and fresh > 0 else 0.0
        eta = format_duration((self.total - self.done) / rate) if rate > 0 else "--"
        pace = f"{rate:.2f}/s" if rate > 0 else "--/s"
        return f"{self.label} [{bar:<{self.width}}] {self.done}/{self.total} {100 * frac:3.0f}% {pace} ETA {eta}"

    def update(self, n: int = 1) -> None:
        self.done += n
        if not self.enabled:
            return
        now = self.clock()
        if now - self.last >= self.interval or self.done >= self.total:
            self.last = now
            self._emit(self.text())

    def _emit(self, line: str) -> None:
        if self.tty:
            self.stream.write("\r" + line + "\x1b[K")
        else:
            self.stream.write(line + "\n")
        self.stream.flush()

    def finish(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()
