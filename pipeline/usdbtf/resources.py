"""Memory and disk estimates before large allocations.

A command that is about to allocate (or write) something large asks :func:`require_memory`
or :func:`require_disk` first; past what the machine has it stops at once with a message
saying how much is needed, instead of failing with a MemoryError minutes later or
filling the disk.  ``USDBTF_MEMORY_LIMIT`` (bytes, e.g. ``4e9``) caps what the estimate
may use, for shared farm machines.  :func:`release_free_heap` hands memory a finished step
freed back to the system (glibc keeps it otherwise).
"""
from __future__ import annotations

import os
import shutil

from .errors import BTFError, IOFailure

__all__ = ["available_memory", "require_memory", "require_disk", "human_bytes", "release_free_heap"]

#: Fraction of the available memory one command may plan to use.
_USABLE = 0.8


def human_bytes(n: float) -> str:
    for unit, size in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:.1f} {unit}"
    return f"{int(n)} bytes"


def _meminfo_available() -> int | None:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room() -> int | None:
    """What the cgroup (v2 or v1) limit leaves, when there is one."""
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        try:
            with open(limit_file) as fh:
                limit = fh.read().strip()
            if limit == "max":
                return None
            with open(usage_file) as fh:
                usage = int(fh.read().strip())
            limit_n = int(limit)
            if limit_n >= 1 << 60:
                return None
            return max(limit_n - usage, 0)
        except (OSError, ValueError):
            continue
    return None


def available_memory() -> int:
    """Bytes this process can still allocate without swapping (best estimate)."""
    candidates = [v for v in (_meminfo_available(), _cgroup_room()) if v is not None]
    if not candidates:
        try:
            candidates.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (ValueError, OSError):     # pragma: no cover - not on Linux
            candidates.append(1 << 40)
    env = os.environ.get("USDBTF_MEMORY_LIMIT")
    if env:
        try:
            candidates.append(int(float(env)))
        except ValueError:
            pass
    return min(candidates)


def require_memory(nbytes: float, what: str, *, error=BTFError) -> None:
    """Raise ``error`` (``BTFError`` for sizes an input file declares, ``UsageError`` for
    sizes the command line asks for) when ``nbytes`` will not fit in memory."""
    room = available_memory() * _USABLE
    if nbytes > room:
        raise error(f"{what} needs about {human_bytes(nbytes)} of memory; {human_bytes(room)} is available "
                    "(use a smaller size, or a machine with more memory)")


def require_disk(nbytes: float, folder, what: str) -> None:
    """Raise :class:`IOFailure` when ``folder``'s file system has less than ``nbytes`` free."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return
    if nbytes > free:
        raise IOFailure(f"{folder}: {what} needs about {human_bytes(nbytes)} of disk; {human_bytes(free)} is free")


def release_free_heap() -> bool:
    """Return the C heap's free pages to the system (glibc ``malloc_trim(0)``); False where the
    C library is not glibc (musl, macOS, Windows: nothing to do, nothing done).

    Why: glibc keeps what a step freed in its arenas -- one per thread that allocated (the
    packaging's threaded encoders and fits), and below a mmap threshold glibc raises as large
    blocks are freed -- so the process's resident memory stays at the step's peak and the next
    step's peak lands on top of it.  Issue 42: compress's asset budget packages a choice 2-3
    times; metal_flakes 32², paper sampling, ``--max-bytes 600000``: RSS 528 MB before the first
    packaging, 671 MB after it without a trim, 531 MB with one.  Only free pages are returned:
    no value, and so no output byte, changes.
    """
    import ctypes

    try:
        # The process's own symbols: glibc's malloc_trim where the C library is glibc.
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError, TypeError):
        return False
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    trim(0)
    return True
