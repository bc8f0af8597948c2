"""Threads for compression's CPU work: numpy's GEMMs, OpenCV's table lookups and colour
transforms, and OpenImageIO's encoders all release the GIL, so plain threads use every core.

* :func:`in_threads` maps a function over items on one thread per CPU, results in order.
* :func:`one_blas_thread` makes BLAS single-threaded inside its block, for code that already
  runs one thread per core over independent pieces (the projection's texel blocks): many
  small GEMMs side by side scale better than each small GEMM split over all cores, and a
  single-threaded GEMM never spin-waits for a core another process holds.  A tile's GEMM
  gives the same bytes with any number of BLAS threads (``tests/test_dask.py`` checks it),
  so this changes speed, never output.
"""
from __future__ import annotations

import contextlib
import functools
import os

__all__ = ["cpu_count", "in_threads", "thread_map", "one_blas_thread"]


def cpu_count() -> int:
    """CPUs this process may run on, at most 8."""
    return max(1, min(8, len(os.sched_getaffinity(0))))


def in_threads(fn, items, *, threads: int | None = None) -> list:
    """``[fn(x) for x in items]`` on up to ``threads`` (default :func:`cpu_count`) threads; the
    results in the order of ``items``, the first exception raised."""
    items = list(items)
    with thread_map(min(len(items), threads or cpu_count())) as tmap:
        return tmap(fn, items)


@contextlib.contextmanager
def thread_map(threads: int | None = None):
    """Yield ``tmap(fn, items) -> list``: :func:`in_threads` on one pool of ``threads``
    threads kept for the block (for many small maps, e.g. one per projection tile)."""
    from concurrent.futures import ThreadPoolExecutor

    workers = threads or cpu_count()
    if workers <= 1:
        yield lambda fn, items: [fn(x) for x in items]
        return
    with ThreadPoolExecutor(workers, thread_name_prefix="usdbtf-compress") as pool:
        yield lambda fn, items: list(pool.map(fn, items))


@contextlib.contextmanager
def one_blas_thread():
    """BLAS on one thread inside the block (threadpoolctl; a no-op where it is missing)."""
    controller = _controller()
    if controller is None:     # pragma: no cover - a declared dependency
        yield
        return
    with controller.limit(limits=1, user_api="blas"):
        yield


@functools.lru_cache(maxsize=1)
def _controller():
    """threadpoolctl's view of the loaded BLAS (scanning the libraries once per process)."""
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:        # pragma: no cover
        return None
    return ThreadpoolController()
