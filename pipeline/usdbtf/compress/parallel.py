"""Threads and processes for compression's CPU work.  numpy's GEMMs and OpenCV's table
lookups and colour transforms release the GIL, so plain threads use every core for them.
OpenImageIO's Python binding holds the GIL while it encodes or decodes an image (a Python
thread spinning beside a JPEG XL encode ran at a fifth of its idle rate, and 24 textures took
as long on two threads as on one), so image codecs run in forked processes.

* :func:`in_threads` maps a function over items on one thread per CPU, results in order.
* :func:`in_processes` maps it over forked processes: for image encodes and decodes.
* :func:`one_blas_thread` makes BLAS single-threaded inside its block.  ``compress`` runs in
  one (:func:`~.core.compress`) and parallelises itself: over texel blocks in the projection,
  over row pieces of the large products (:func:`rows_gemm`).  That is faster on a shared
  machine (a single-threaded GEMM never spin-waits for a core another process holds) and
  makes the output independent of thread counts: OpenBLAS rounds some products differently
  on one thread than on several, and a row by its place in the kernel's row blocking, so
  the pieces are cut by the product's shape alone, never by the CPU count, each on one
  BLAS thread (``tests/test_stability.py`` checks the output with 1, 2 and 4 BLAS threads,
  ``tests/test_parallel.py`` on 1 and 2 CPUs).
"""
from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import threading

from ..atomic import raise_if_interrupted
from ..lifetime import forked_pool
from ..numeric import one_blas_thread

__all__ = ["cpu_count", "in_threads", "in_processes", "iter_processes", "forks_safely", "thread_map",
           "one_blas_thread", "rows_gemm", "gemm_row_cuts", "rows_apply"]


def cpu_count() -> int:
    """CPUs this process may run on, at most 8."""
    return max(1, min(8, len(os.sched_getaffinity(0))))


def in_threads(fn, items, *, threads: int | None = None) -> list:
    """``[fn(x) for x in items]`` on up to ``threads`` (default :func:`cpu_count`) threads; the
    results in the order of ``items``, the first exception raised."""
    items = list(items)
    with thread_map(min(len(items), threads or cpu_count())) as tmap:
        return tmap(fn, items)


#: The job a forked pool's workers run, set just before the fork: workers inherit the function
#: and its items (closures, arrays) through the fork, so only indices and results are pickled.
_FORKED_JOB: dict = {}


def forks_safely() -> bool:
    """True when this process may fork workers: the platform forks, no other Python thread runs
    (a forked child inherits every lock in whatever state another thread left it, e.g. a Dask
    client's event loop or its offload thread), and it is no daemonic process (a Dask worker,
    which may not have children)."""
    return ("fork" in mp.get_all_start_methods() and threading.active_count() == 1
            and not mp.current_process().daemon)


def _forked_init() -> None:
    import OpenImageIO as oiio

    oiio.attribute("threads", 1)  # OIIO's pool threads do not exist in a forked child


def _forked_call(i: int):
    fn, items = _FORKED_JOB["job"]
    return fn(items[i])


def in_processes(fn, items, *, processes: int | None = None) -> list:
    """``[fn(x) for x in items]`` on up to ``processes`` (default :func:`cpu_count`) forked
    processes, results in the order of ``items``, the first exception raised.

    For work that holds the GIL (OpenImageIO's encoders and decoders).  ``fn`` and ``items``
    reach the workers through the fork, not pickled; results must pickle.  Runs in this
    process, item after item, with one CPU or one item, or where :func:`forks_safely` says no.
    Code whose libraries keep threads that a fork loses (OpenEXR's process-wide pool) must
    not come here (:attr:`.codecs.Codec.forkable`).
    """
    return list(iter_processes(fn, items, processes=processes))


def iter_processes(fn, items, *, processes: int | None = None):
    """:func:`in_processes` as an iterator: each result as soon as it and those before it are
    done (for a progress bar); the workers end when it is exhausted or closed."""
    items = list(items)
    workers = min(len(items), processes or cpu_count())
    if workers <= 1 or not forks_safely():
        yield from (fn(x) for x in items)
        return
    _FORKED_JOB["job"] = (fn, items)
    try:
        # The pool forks all its workers at the first submit, before it starts any thread.
        # The workers die with this process, and at once when the iteration is stopped
        # (:mod:`usdbtf.lifetime`).
        with forked_pool(workers, initializer=_forked_init) as pool:
            for result in pool.map(_forked_call, range(len(items))):
                raise_if_interrupted()
                yield result
    finally:
        _FORKED_JOB.pop("job", None)


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


#: Row pieces of :func:`rows_gemm` start at multiples of this: OpenBLAS's Haswell SGEMM (the
#: reference platform's, :mod:`usdbtf.numeric`) rounds a row by where it falls in a block of
#: 24 rows, so pieces cut there give the whole product's bits (8 or 16 do not).
GEMM_ROW_UNIT = 24
#: At most this many pieces, however many CPUs: the pieces depend on the shape alone.
GEMM_MAX_PIECES = 8


def gemm_row_cuts(n: int) -> list[int]:
    """Where :func:`rows_gemm` cuts ``n`` rows: ``[0, ..., n]``, a function of ``n`` alone.

    Not of the CPU count: a piece's bits depend on its rows (OpenBLAS kernels round a row by
    its place in their row blocking; some switch to a small-matrix kernel below a size), so a
    cut that followed the CPUs made a one-CPU machine, or a Dask worker pinned to one core,
    write other bytes than a two-CPU one.  Up to :data:`GEMM_MAX_PIECES` pieces of about
    ``n / pieces`` >= 32 rows (small enough that two CPUs share a 150-row product within a
    few percent), each starting at a multiple of :data:`GEMM_ROW_UNIT`.
    """
    pieces = min(GEMM_MAX_PIECES, max(1, n // 32))
    inner = {round(n * i / pieces / GEMM_ROW_UNIT) * GEMM_ROW_UNIT for i in range(1, pieces)}
    return [0, *sorted(c for c in inner if 0 < c < n), n]


def rows_gemm(a, b):
    """``a @ b`` with the rows of ``a`` cut into pieces by shape (:func:`gemm_row_cuts`), each
    piece's product on one BLAS thread, the pieces over the CPUs' threads: the same bytes on
    any number of CPUs, and on the reference platform those of ``a @ b`` on one BLAS thread."""
    import numpy as np

    cuts = gemm_row_cuts(a.shape[0])
    if len(cuts) <= 2:
        with one_blas_thread():
            return a @ b
    out = np.empty((a.shape[0], b.shape[1]), np.result_type(a.dtype, b.dtype))

    def piece(i):
        np.matmul(a[cuts[i]:cuts[i + 1]], b, out=out[cuts[i]:cuts[i + 1]])

    with one_blas_thread():
        in_threads(piece, range(len(cuts) - 1))
    return out


def rows_apply(fn, x, out, *, rows: int = 256, into: bool = False):
    """``out[...] = fn(x)`` for a row-wise ``fn`` (elementwise curves, colour transforms,
    encoders: row i of the result depends on row i of ``x`` only), with the rows cut into
    block of ``rows`` rows mapped over the CPUs' threads: the same values as one call.  The
    blocks do not depend on the number of CPUs (a vectorised kernel's remainder loop sits at
    the same places on every machine).  ``out`` has ``fn(x)``'s shape and dtype; it may be
    ``x`` itself (each block reads its rows before it writes them).  ``into``: ``fn`` writes
    its rows itself, called as ``fn(rows of x, out=rows of out)`` (no fresh array per block
    to fault in and copy).  Returns ``out``."""
    n = x.shape[0]
    if n <= rows:
        if into:
            fn(x, out=out)
        else:
            out[...] = fn(x)
        return out

    def piece(a):
        if into:
            fn(x[a:a + rows], out=out[a:a + rows])
        else:
            out[a:a + rows] = fn(x[a:a + rows])

    in_threads(piece, range(0, n, rows))
    return out
