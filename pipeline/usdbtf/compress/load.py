"""Bring a BTF's stored values into memory once, in parallel, as compactly as they are stored.

Compression makes two passes over the data (fit a basis, then project every
pixel).  Decoding ~10,000 image files is as expensive as one of those passes,
so the stored values (uint8/uint16/half) are decoded once into a shared array
of the file's own type -- 0.53 GB for the paper's 90 x 120 x 128^2 8-bit set,
a quarter of its float32 size -- and converted to scene-linear float32 chunk
by chunk as each pass needs it.
"""
from __future__ import annotations

import mmap
import multiprocessing as mp
import os
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from ..errors import BTFError
from ..model import BTF, FileBTF

__all__ = ["load_encoded", "default_workers"]

_STATE: dict = {}  # per-worker-process handles (set by the pool initializer in the forked child)


def default_workers() -> int:
    return max(1, min(8, len(os.sched_getaffinity(0))))


def _init(btf, out):
    _STATE.update(btf=btf, out=out)


def _read_range(start: int, stop: int):
    btf, out = _STATE["btf"], _STATE["out"]
    try:
        for i in range(start, stop):
            out[i] = btf.read_one(i)
    except BTFError as exc:
        return str(exc)
    return None


def load_encoded(btf: BTF, *, workers: int | None = None) -> np.ndarray:
    """All stored values, (S, H, W, 3) in the storage dtype (uint8, uint16, float16 or float32).

    File-backed BTFs are read by ``workers`` forked processes (OpenImageIO's Python
    binding holds the GIL while decoding, so threads do not help) straight into an
    anonymous shared mapping that the returned array owns: no copy, no named segment
    to clean up.
    """
    dtype = np.dtype({"uint8": np.uint8, "uint16": np.uint16, "half": np.float16, "float": np.float32}[btf.bit_depth])
    shape = btf.shape
    workers = workers or default_workers()
    if not isinstance(btf, FileBTF) or workers == 1 or btf.n_samples < 64:
        out = np.empty(shape, dtype)
        for start in range(0, btf.n_samples, 256):
            sl = slice(start, min(start + 256, btf.n_samples))
            out[sl] = btf.read_encoded(sl)
        return out
    nbytes = int(np.prod(shape)) * dtype.itemsize
    # MAP_POPULATE: fault the pages in now, in bulk; otherwise the parent later takes one
    # ~25 us shared-memory fault per 4 KiB page on first touch (~3 s at paper scale).
    flags = mmap.MAP_SHARED | mmap.MAP_ANONYMOUS | getattr(mmap, "MAP_POPULATE", 0)
    out = np.frombuffer(mmap.mmap(-1, nbytes, flags=flags), dtype).reshape(shape)
    bounds = np.linspace(0, btf.n_samples, workers * 8 + 1).astype(int)
    # fork: the workers inherit ``btf`` and the mapping; nothing is pickled but the index ranges.
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("fork"), initializer=_init,
                             initargs=(btf, out)) as pool:
        for err in pool.map(_read_range, bounds[:-1], bounds[1:]):
            if err:
                raise BTFError(err)
    return out
