"""A spill file for decoded values that do not fit in memory: written once, read back once.

When a BTF's stored values pass the memory budget, compression still needs them twice
(fit the basis on some texels of every sample, then project every texel).  Decoding every
image file twice costs a second decode pass (PNG: inflate again); writing the decoded
values once to a spill file and reading them back costs disk bandwidth instead, which
overlaps with decoding and with the projection (:mod:`.source`).

* **Nothing survives.**  The file has no name: it is opened with ``O_TMPFILE`` (or created
  and unlinked at once where the file system lacks it), so nothing of it outlives the
  process, not even after ``kill -9``; closing it frees its blocks.
* **Direct I/O.**  Where the file system allows, the file is opened with ``O_DIRECT``: the
  values go between this process's buffers and the disk without the page cache.  On this
  project's VM, buffered writes of 10.9 GB cost ~2 CPU-seconds per GB in the kernel (page
  cache reclaim and writeback) and were throttled to ~250 MB/s; direct writes and reads run
  at ~1.4 GB/s for next to no CPU.  Direct I/O needs aligned buffers, offsets and lengths,
  so the file holds fixed slots of :data:`ALIGN`-rounded size, one per chunk of samples.
* **Only with room.**  It is used only when the file system keeps :data:`SPILL_MARGIN` free
  beside it (:meth:`Spill.create` returns None otherwise, and the caller decodes twice).
"""
from __future__ import annotations

import mmap
import os
import shutil
import tempfile
import threading
from collections import deque

import numpy as np

__all__ = ["Spill", "SPILL_MARGIN", "ALIGN"]

#: Free space the spill leaves on its file system: a tenth of it, at least 1 GB.
SPILL_MARGIN = (0.1, 1e9)
#: Alignment of direct I/O buffers, offsets and lengths (a page; covers 512 and 4096-byte sectors).
ALIGN = 4096
#: Largest staging buffer a direct write copies through (per process).
STAGING_BYTES = 32 * 2**20
#: Bytes of slots read ahead of the consumer (at least one slot).
READ_AHEAD_BYTES = 256e6
_STAGING: dict = {}   # pid -> aligned buffer for writes (each forked decode worker has its own)


def _aligned(nbytes: int) -> int:
    return -(-nbytes // ALIGN) * ALIGN


def _buffer(nbytes: int) -> memoryview:
    """A page-aligned anonymous buffer of at least ``nbytes`` (rounded to :data:`ALIGN`)."""
    return memoryview(mmap.mmap(-1, _aligned(max(nbytes, 1))))


class Spill:
    """An anonymous file of ``slots`` slots of ``slot_bytes`` bytes each (see the module docstring)."""

    def __init__(self, fd: int, slots: int, slot_bytes: int, folder: str, direct: bool):
        self.fd, self.slots, self.slot_bytes, self.folder, self.direct = fd, slots, _aligned(slot_bytes), folder, direct

    @classmethod
    def create(cls, slots: int, slot_bytes: int, folder: str | None = None) -> "Spill | None":
        """A spill file for ``slots`` chunks of at most ``slot_bytes`` bytes, or None when
        ``folder``'s file system (default: the temporary folder) cannot hold it and the
        margin, or refuses an anonymous file."""
        folder = folder or tempfile.gettempdir()
        nbytes = slots * _aligned(slot_bytes)
        try:
            free = shutil.disk_usage(folder).free
        except OSError:
            return None
        if nbytes + max(SPILL_MARGIN[0] * free, SPILL_MARGIN[1]) > free:
            return None
        tmpfile = getattr(os, "O_TMPFILE", 0)
        for direct in (True, False):
            flags = os.O_RDWR | os.O_CLOEXEC | tmpfile | (getattr(os, "O_DIRECT", 0) if direct else 0)
            if direct and not getattr(os, "O_DIRECT", 0) or not tmpfile:
                continue
            try:
                return cls(os.open(folder, flags, 0o600), slots, slot_bytes, folder, direct)
            except OSError:
                continue
        try:
            handle = tempfile.TemporaryFile(dir=folder)     # created and unlinked at once
        except OSError:
            return None
        fd = os.dup(handle.fileno())
        handle.close()
        return cls(fd, slots, slot_bytes, folder, False)

    def write(self, slot: int, data: np.ndarray) -> None:
        """Write the bytes of ``data`` (at most ``slot_bytes``) into slot ``slot``; any process
        sharing the descriptor may write its own slots.  Direct I/O goes through an aligned
        staging buffer of at most :data:`STAGING_BYTES`, piece by piece (a whole slot's copy
        would double a decode worker's memory)."""
        view = memoryview(np.ascontiguousarray(data)).cast("B")
        base = slot * self.slot_bytes
        if not self.direct:
            self._pwrite_all(view, base)
            return
        piece = min(_aligned(len(view)), STAGING_BYTES)
        staging = _STAGING.get(os.getpid())
        if staging is None or len(staging) < piece:
            staging = _STAGING[os.getpid()] = _buffer(piece)
        for start in range(0, len(view), piece):
            n = min(piece, len(view) - start)
            staging[:n] = view[start:start + n]
            self._pwrite_all(staging[:_aligned(n)], base + start)

    def _pwrite_all(self, view: memoryview, offset: int) -> None:
        done = 0
        while done < len(view):
            done += os.pwrite(self.fd, view[done:], offset + done)

    def read_ahead(self, pieces, depth: int | None = None):
        """Yield (slot, uint8 array of nbytes) for ``pieces`` = [(slot, nbytes), ...] in order,
        read by a background thread ``depth`` slots ahead (reads release the GIL, so they
        overlap with the caller's compute; default: 2, or 1 for slots past half of
        :data:`READ_AHEAD_BYTES`).  An array is valid until the next one is asked for."""
        pieces = list(pieces)
        if depth is None:
            depth = max(1, min(2, int(READ_AHEAD_BYTES // self.slot_bytes)))
        buffers = [_buffer(self.slot_bytes) for _ in range(depth + 1)]
        slots = threading.Semaphore(depth)
        ready: deque = deque()
        cond = threading.Condition()
        failure: list = []

        def reader():
            try:
                for n, (slot, nbytes) in enumerate(pieces):
                    slots.acquire()
                    if failure:
                        return
                    buf = buffers[n % len(buffers)]
                    want = _aligned(nbytes) if self.direct else nbytes
                    done = 0
                    while done < want:
                        got = os.preadv(self.fd, [buf[done:want]], slot * self.slot_bytes + done)
                        if got == 0:
                            raise OSError(f"spill file in {self.folder}: short read in slot {slot}")
                        done += got
                    with cond:
                        ready.append((slot, np.frombuffer(buf, np.uint8, nbytes)))
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
