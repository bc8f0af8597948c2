"""A spill file for decoded values that do not fit in memory: written once, read back once.

When a BTF's stored values pass the memory budget, compression still needs them twice
(fit the basis on some texels of every sample, then project every texel).  Decoding every
image file twice costs a second decode pass (PNG: inflate again); writing the decoded
values once to a spill file and reading them back costs disk bandwidth instead, most of
which overlaps with decoding and with the projection (:mod:`.source`).

The file has no name: it is opened with ``O_TMPFILE`` (or created and unlinked at once
where the file system lacks it), so nothing of it survives the process, not even after
``kill -9``; closing it (or the process ending) frees its blocks.  It is only used when
the file system has room for it with a margin (:func:`Spill.create` returns None
otherwise, and the caller decodes twice).
"""
from __future__ import annotations

import os
import shutil
import tempfile
import threading
from collections import deque

import numpy as np

__all__ = ["Spill", "SPILL_MARGIN"]

#: Free space the spill leaves on its file system: a tenth of it, at least 1 GB.
SPILL_MARGIN = (0.1, 1e9)


class Spill:
    """An anonymous file of ``nbytes`` bytes in ``folder`` (default: the temporary folder)."""

    def __init__(self, fd: int, nbytes: int, folder: str):
        self.fd, self.nbytes, self.folder = fd, nbytes, folder

    @classmethod
    def create(cls, nbytes: int, folder: str | None = None) -> "Spill | None":
        """A spill file, or None when ``folder``'s file system cannot hold ``nbytes`` and the
        margin (:data:`SPILL_MARGIN`) or refuses an anonymous file."""
        folder = folder or tempfile.gettempdir()
        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            return None
        if nbytes + max(SPILL_MARGIN[0] * free, SPILL_MARGIN[1]) > free:
            return None
        try:
            handle = tempfile.TemporaryFile(dir=folder)     # O_TMPFILE on Linux: never has a name
        except OSError:
            return None
        fd = os.dup(handle.fileno())
        handle.close()
        return cls(fd, nbytes, folder)

    def write(self, offset: int, data: np.ndarray) -> None:
        """Write the bytes of ``data`` at ``offset`` (any process that shares the descriptor)."""
        view = memoryview(np.ascontiguousarray(data)).cast("B")
        done = 0
        while done < len(view):
            done += os.pwrite(self.fd, view[done:], offset + done)

    def read_into(self, offset: int, out: np.ndarray) -> np.ndarray:
        """Fill the contiguous array ``out`` from ``offset``; returns ``out``."""
        view = memoryview(out).cast("B")
        done = 0
        while done < len(view):
            n = os.preadv(self.fd, [view[done:]], offset + done)
            if n == 0:
                raise OSError(f"spill file in {self.folder}: short read at byte {offset + done}")
            done += n
        return out

    def read_ahead(self, pieces, make_buffer, depth: int = 2):
        """Yield (piece, array) for ``pieces`` = [(offset, key), ...] in order, read by a
        background thread ``depth`` pieces ahead (reads release the GIL, so they overlap
        with the caller's compute); ``make_buffer(key)`` gives the array to fill."""
        pieces = list(pieces)
        slots = threading.Semaphore(depth)
        ready: deque = deque()
        cond = threading.Condition()
        failure: list = []

        def reader():
            try:
                for offset, key in pieces:
                    slots.acquire()
                    if failure:
                        return
                    buf = self.read_into(offset, make_buffer(key))
                    with cond:
                        ready.append((key, buf))
                        cond.notify()
            except BaseException as exc:   # noqa: BLE001 - handed to the consumer
                with cond:
                    failure.append(exc)
                    cond.notify()

        thread = threading.Thread(target=reader, name="usdbtf-spill-reader", daemon=True)
        thread.start()
        try:
            for _ in pieces:
                with cond:
                    while not ready and not failure:
                        cond.wait()
                    if failure and not ready:
                        raise failure[0]
                    item = ready.popleft()
                yield item
                slots.release()
        finally:
            failure.append(None)        # stop the reader if the consumer leaves early
            slots.release()
            thread.join()

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
