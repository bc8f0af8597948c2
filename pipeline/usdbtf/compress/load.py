"""Bring a BTF's stored values into memory once, in parallel, as compactly as they are stored.

Compression makes two passes over the data (fit a basis, then project every
pixel).  Decoding ~10,000 image files is as expensive as one of those passes,
so the stored values (uint8/uint16/half) are decoded once -- 0.53 GB for the
paper's 90 x 120 x 128^2 8-bit set, a quarter of its float32 size -- and turned
into scene-linear float32 block by block as each pass needs it.

Layout: texels are cut into blocks of ``block`` consecutive texels, and the data
is stored block-major, (n_blocks, S, 3 * block).  A pass over a block of the data
matrix (all samples x a range of texels) then reads one contiguous region instead
of S strided rows, which on 4 KiB-page shared memory costs a TLB miss per row.
"""
from __future__ import annotations

import mmap
import os
from dataclasses import dataclass

import numpy as np

from ..atomic import raise_if_interrupted
from ..errors import BTFError
from ..lifetime import forked_pool
from ..model import BTF, FileBTF

__all__ = ["BlockedData", "load_encoded", "default_workers", "texel_blocks", "stored_dtype", "DEFAULT_BLOCK",
           "decodes_in_workers"]

DEFAULT_BLOCK = 1024
_STATE: dict = {}  # per-worker-process handles (set by the pool initializer in the forked child)


def texel_blocks(n_pixels: int, block: int = DEFAULT_BLOCK) -> list[tuple[int, int]]:
    """(a, b) texel ranges of the storage blocks: ``block`` texels each (all of them when the
    image is smaller), the last one short."""
    block = max(1, min(block, n_pixels))
    return [(a, min(a + block, n_pixels)) for a in range(0, n_pixels, block)]


def stored_dtype(btf: BTF) -> np.dtype:
    """The numpy type of ``btf``'s stored values."""
    return np.dtype({"uint8": np.uint8, "uint16": np.uint16, "half": np.float16, "float": np.float32}[btf.bit_depth])


def default_workers() -> int:
    return max(1, min(8, len(os.sched_getaffinity(0))))


@dataclass
class BlockedData:
    """Stored values of a whole BTF, block-major.

    blocks : (n_blocks, S, 3 * block) array in the storage dtype; the last block is
             zero-padded past texel P.
    n_pixels : P, texels per image.
    """

    blocks: np.ndarray
    n_pixels: int
    block: int

    @property
    def n_samples(self) -> int:
        return self.blocks.shape[1]

    @property
    def nbytes(self) -> int:
        return self.blocks.nbytes

    def put(self, i: int, image: np.ndarray) -> None:
        """Store sample i from an (H, W, 3) image."""
        flat = image.reshape(-1)
        nb, _, B3 = self.blocks.shape
        full = min(nb, flat.size // B3)
        self.blocks[:full, i, :] = flat[:full * B3].reshape(full, B3)   # one copy, not one per block
        if full < nb:
            tail = flat[full * B3:]
            self.blocks[full, i, :tail.size] = tail

    def span(self, a: int, b: int) -> np.ndarray:
        """Stored values of texels a..b (within one block): (S, 3 (b - a)) view."""
        blk, off = divmod(a, self.block)
        if b - 1 >= (blk + 1) * self.block:
            raise ValueError(f"texels {a}..{b} cross a block boundary")
        return self.blocks[blk, :, 3 * off:3 * (b - blk * self.block)]

    def samples(self, rows) -> np.ndarray:
        """Stored values of whole samples: (n, P, 3)."""
        view = self.blocks.reshape(self.blocks.shape[0], self.n_samples, self.block, 3)[:, rows]
        n = view.shape[1]
        return np.ascontiguousarray(view.transpose(1, 0, 2, 3)).reshape(n, -1, 3)[:, :self.n_pixels]


def _init(btf, out):
    import OpenImageIO as oiio

    oiio.attribute("threads", 1)  # OIIO's pool threads do not exist in a forked child
    _STATE.update(btf=btf, out=out)


# OpenEXR keeps a process-wide thread pool that a forked child inherits without its
# threads: reading EXR in a forked worker can deadlock.  Those formats decode serially.
_NO_FORK_EXTENSIONS = (".exr", ".sxr", ".mxr")


def _forkable(btf: BTF) -> bool:
    return not any(str(p).lower().endswith(_NO_FORK_EXTENSIONS) for p in btf.paths)


def decodes_in_workers(btf: BTF) -> bool:
    """True when forked workers can read ``btf``'s samples by index (``read_one``): image
    files, or a view of them that says so by naming them (``files``: the box-filtered input of
    a partial compress, :class:`.coverage.BoxFilteredBTF`), in formats safe to read after fork."""
    files = getattr(btf, "files", btf)
    return isinstance(files, FileBTF) and _forkable(files)


def _read_range(start: int, stop: int):
    btf, out = _STATE["btf"], _STATE["out"]
    try:
        for i in range(start, stop):
            out.put(i, btf.read_one(i))
    except BTFError as exc:
        return str(exc)
    return None


def load_encoded(btf: BTF, *, workers: int | None = None, block: int = DEFAULT_BLOCK) -> BlockedData:
    """All stored values of ``btf`` (uint8, uint16, float16 or float32), block-major.

    File-backed BTFs are read by ``workers`` forked processes (OpenImageIO's Python
    binding holds the GIL while decoding, so threads do not help) straight into an
    anonymous shared mapping that the returned arrays own: no copy, nothing to clean up.
    """
    dtype = stored_dtype(btf)
    S, P = btf.n_samples, btf.n_pixels
    block = max(1, min(block, P))
    shape = (-(-P // block), S, 3 * block)
    workers = workers or default_workers()
    parallel = decodes_in_workers(btf) and workers > 1 and S >= 64
    if not parallel:
        data = BlockedData(np.zeros(shape, dtype), P, block)
        for start in range(0, S, 256):
            chunk = btf.read_encoded(slice(start, min(start + 256, S)))
            for n, img in enumerate(chunk):
                data.put(start + n, img)
        return data
    nbytes = int(np.prod(shape)) * dtype.itemsize
    # No MAP_POPULATE: the decode workers fault their own pages in, in parallel, instead of
    # this process faulting all of them before any decoding starts.
    flags = mmap.MAP_SHARED | mmap.MAP_ANONYMOUS
    data = BlockedData(np.frombuffer(mmap.mmap(-1, nbytes, flags=flags), dtype).reshape(shape), P, block)
    bounds = np.linspace(0, S, workers * 8 + 1).astype(int)
    # fork: the workers inherit ``btf`` and the mapping; nothing is pickled but the index ranges.
    with forked_pool(workers, initializer=_init, initargs=(btf, data)) as pool:
        for err in pool.map(_read_range, bounds[:-1], bounds[1:]):
            raise_if_interrupted()
            if err:
                raise BTFError(err)
    return data
