"""Threads for compression's CPU work: numpy's GEMMs, OpenCV's table lookups and colour
transforms, and OpenImageIO's encoders all release the GIL, so plain threads use every core.

* :func:`in_threads` maps a function over items on one thread per CPU, results in order.
* :func:`one_blas_thread` makes BLAS single-threaded inside its block.  ``compress`` runs in
  one (:func:`~.core.compress`) and parallelises itself: over texel blocks in the projection,
  over row blocks of the large products (:func:`rows_gemm`).  That is faster on a shared
  machine (a single-threaded GEMM never spin-waits for a core another process holds) and
  makes the output independent of thread counts: OpenBLAS rounds some products differently
  on one thread than on several, but a product cut by rows, each piece on one thread,
  gives the bytes of the whole product on one thread (``tests/test_stability.py`` checks
  the output with 1, 2 and 4 BLAS threads).
"""
from __future__ import annotations

import contextlib
import os

from ..numeric import one_blas_thread

__all__ = ["cpu_count", "in_threads", "thread_map", "one_blas_thread", "rows_gemm", "rows_apply"]


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


def rows_gemm(a, b):
    """``a @ b`` with the rows of ``a`` cut into one block per CPU, each block's product on one
    BLAS thread in a thread of its own: the same bytes as ``a @ b`` on one BLAS thread."""
    import numpy as np

    n = a.shape[0]
    parts = min(cpu_count(), max(1, n // 64))
    if parts <= 1:
        with one_blas_thread():
            return a @ b
    out = np.empty((n, b.shape[1]), np.result_type(a.dtype, b.dtype))
    cuts = np.linspace(0, n, parts + 1).astype(int)

    def piece(i):
        np.matmul(a[cuts[i]:cuts[i + 1]], b, out=out[cuts[i]:cuts[i + 1]])

    with one_blas_thread():
        in_threads(piece, range(parts))
    return out


def rows_apply(fn, x, out, *, rows: int = 256):
    """``out[...] = fn(x)`` for a row-wise ``fn`` (elementwise curves, colour transforms,
    encoders: row i of the result depends on row i of ``x`` only), with the rows cut into
    block of ``rows`` rows mapped over the CPUs' threads: the same values as one call.  The
    blocks do not depend on the number of CPUs (a vectorised kernel's remainder loop sits at
    the same places on every machine).  ``out`` has ``fn(x)``'s shape and dtype; it may be
    ``x`` itself (each block reads its rows before it writes them).  Returns ``out``."""
    n = x.shape[0]
    if n <= rows:
        out[...] = fn(x)
        return out

    def piece(a):
        out[a:a + rows] = fn(x[a:a + rows])

    in_threads(piece, range(0, n, rows))
    return out
