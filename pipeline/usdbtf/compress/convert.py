"""Stored values -> float32 values in the working domain, written into reused buffers.

Every pass over the data converts each stored value once: the decode's table (integer
codes) or its OCIO transform (float files), the 3x3 primaries matrix, then the working
domain's curve (:mod:`.domain`).  Each step as a plain expression returns a fresh array of
the data's size; at UBO2014's size (10^10 values in the projection) the page faults of
those fresh arrays cost more than the arithmetic (5.5 against 2.0 ns per value, measured
on 128 x 3072 tiles).  :class:`Conversion` writes every step into the caller's ``out``
and one scratch array per thread, reused from call to call.

The steps and their array shapes are those of the plain expressions, so the values are
the same bits (OpenCV's SIMD kernels round the last few values of an array differently
from the rest: only the shape of the arrays a step sees decides which).

8-bit codes with a primaries matrix in a curved domain (sRGB files into ACEScg, the common
case) go through :class:`TripleConversion` instead: the converted value of a texel is a
function of its three codes alone, computed once per distinct code triple (a material's
10,800 paper-scale images hold 0.5-45 thousand of the 16.7 million; a projection tile of
524,288 texels about 20 thousand) and gathered from a table (issue 42: the paper-scale
projection's conversion 2.35 -> 1.20 CPU-s, ``benchmarks/probes/k150_ab.py``; what a material
holds: ``benchmarks/probes/distinct_triples.py``).  Its matrix is applied per triple in
float64 (:meth:`TripleConversion.triples`), so a
value's bits never depend on where it sits in an array, on the CPU's SIMD width or on the
BLAS kernel.
"""
from __future__ import annotations

import math
import mmap
import threading

import numpy as np

from .. import color
from .domain import LINEAR

__all__ = ["Conversion", "Scratch", "TripleConversion", "TripleSlots"]

#: Texels a :class:`TripleConversion` converts at a time.
_PIECE = 1 << 16


class Scratch(threading.local):
    """Per-thread reusable arrays, by name: :meth:`get` returns a view of the thread's buffer
    of that name, grown (never shrunk) when a larger array is asked for."""

    def get(self, name: str, shape, dtype=np.float32) -> np.ndarray:
        buffers = self.__dict__.setdefault("buffers", {})
        size = math.prod(shape)                 # (np.prod costs more than a small piece's table lookups)
        buf = buffers.get((name, dtype))
        if buf is None or buf.size < size:
            buf = buffers[(name, dtype)] = np.empty(size, dtype)
        return buf[:size].reshape(shape)


class Conversion:
    """callable(raw stored values, out=None) -> float32 values of ``raw``'s shape.

    Parameters
    ----------
    decode : callable(stored, out=None) -> float32 of the same shape (a decode table's
        ``decode_curves``, or the full OCIO decode wrapped to accept ``out``).
    matrix : (3, 3) float32 applied per texel after ``decode`` (``rgb @ matrix.T``), or None.
    domain : the working domain whose ``forward`` curve comes last (:data:`.domain.LINEAR`:
        none).
    """

    def __init__(self, decode, matrix=None, domain=LINEAR, *, nonnegative: bool = False):
        self.decode, self.matrix, self.domain = decode, matrix, domain
        #: The decode and matrix never give a negative value (a table >= 0, a matrix >= 0,
        #: as for sRGB files into ACEScg): the curve's clamp is skipped, with the same values.
        self.nonnegative = nonnegative
        self._scratch = Scratch()

    def __call__(self, raw: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Convert ``raw`` (rows may be strided; texels contiguous RGB within a row) into
        ``out`` (contiguous float32 of ``raw``'s shape; new when None)."""
        if out is None:
            out = np.empty(raw.shape, np.float32)
        if self.matrix is None:
            x = self.decode(raw, out=out)
        else:
            x = color.mix_rgb(self.decode(raw, out=self._scratch.get("decoded", raw.shape)), self.matrix, out=out)
        self.domain.forward(x, out=x, nonnegative=self.nonnegative)     # x: a view of out
        return out


def _lazy_zeros(shape, dtype) -> np.ndarray:
    """Zeros in a private anonymous memory map: pages cost memory only once written (a
    2^24-entry table of which a material writes a few thousand pages); private, so a forked
    worker's writes stay its own."""
    nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
    area = mmap.mmap(-1, max(nbytes, 1), flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    return np.frombuffer(area, dtype, int(np.prod(shape))).reshape(shape)


class TripleSlots:
    """The distinct 8-bit code triples met so far, numbered 1, 2, ... in the order met.

    Shared by the conversions of one source (each keeps its own values per number,
    :class:`TripleConversion`).  A triple (r, g, b) is packed as r + 256 g + 65536 b.

    Attributes
    ----------
    table : (2^24,) int32, the number of each packed triple (0: not met).  64 MiB of address
        space, of which only the written pages take memory (paper-scale materials: 1-17 MB).
    codes : (cap + 1, 3) uint8, triple number -> its codes (row 0 unused).
    count : triples numbered so far (at most ``cap``; later ones are converted where met).
    """

    def __init__(self, cap: int = 1 << 22):
        self.cap = cap
        self.table = _lazy_zeros(1 << 24, np.int32)
        self.codes = _lazy_zeros((cap + 1, 3), np.uint8)
        self.count = 0
        self.lock = threading.Lock()

    def learn(self, key: np.ndarray, slot: np.ndarray) -> np.ndarray | None:
        """Number the triples ``key`` holds where ``slot`` is 0, and write their numbers there.

        key : (...) intp packed triples; slot : int32 of the same shape (contiguous), their
        numbers as looked up (0 where unknown), completed in place.

        Returns the flat positions still 0 (met after ``cap`` triples were numbered), or None.
        """
        flat_slot = slot.reshape(-1)
        with self.lock:
            miss = np.flatnonzero(flat_slot == 0)
            keys = key.reshape(-1)[miss]
            new = np.unique(keys[self.table[keys] == 0])[:self.cap - self.count]
            if len(new):
                first = self.count + 1
                self.codes[first:first + len(new)] = np.stack([new & 255, (new >> 8) & 255, new >> 16], axis=1)
                self.count += len(new)          # before the table names them (lock-free readers)
                self.table[new] = np.arange(first, first + len(new), dtype=np.int32)
            found = self.table[keys]
        flat_slot[miss] = found
        left = miss[found == 0]
        return left if len(left) else None


class TripleConversion(Conversion):
    """:class:`Conversion` of 8-bit codes through a decode table, a primaries matrix and a
    curve, each distinct code triple converted once (:meth:`triples`) and gathered.

    The values are those of :meth:`triples` on each texel's codes, whatever the array: a
    texel's bits do not depend on its position, the array's shape or the CPU.

    Parameters
    ----------
    decode, matrix, domain, nonnegative : as :class:`Conversion` (``decode``: an 8-bit
        decode table's ``decode_curves``; ``matrix`` not None).
    slots : the source's :class:`TripleSlots` (new when None).
    """

    def __init__(self, decode, matrix, domain=LINEAR, *, nonnegative: bool = False, slots: TripleSlots | None = None):
        super().__init__(decode, matrix, domain, nonnegative=nonnegative)
        self.slots = slots if slots is not None else TripleSlots()
        self._m64 = np.asarray(matrix, np.float32).astype(np.float64)
        # Values per triple number, 4 floats a row (r, g, b, unused): a 16-byte row is one
        # element of a complex128 view, which numpy's take gathers fast (12-byte rows take its slow path).
        self._values = _lazy_zeros((self.slots.cap + 1, 4), np.float32)
        self._rows = self._values.view(np.complex128).reshape(-1)
        self._filled = 1                        # values known for triple numbers < _filled
        self._lock = threading.Lock()

    def triples(self, codes: np.ndarray) -> np.ndarray:
        """(m, 3) uint8 codes -> (m, 3) float32 domain values: the decode table, then the
        matrix with float64 products and sums (exact products; y_c = (m_c0 x_0 + m_c1 x_1) +
        m_c2 x_2, rounded once to float32), then the curve."""
        out = np.empty(codes.shape, np.float32)
        for a in range(0, len(codes), _PIECE):          # cache-sized pieces (a whole array unmemoised)
            x = self.decode(np.ascontiguousarray(codes[a:a + _PIECE])).astype(np.float64)
            m = self._m64
            y = x[:, 0:1] * m[:, 0] + x[:, 1:2] * m[:, 1] + x[:, 2:3] * m[:, 2]
            out[a:a + len(x)] = y
        return self.domain.forward(out, out=out, nonnegative=self.nonnegative)

    def __call__(self, raw: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        if out is None:
            out = np.empty(raw.shape, np.float32)
        if not out.flags.c_contiguous:     # the pieces write through reshaped views of out
            out[...] = self(raw)
            return out
        result = out
        if raw.size == 0:
            return result
        if raw.ndim != 2:              # (n, m, 3) images or columns, (3,) one texel: as rows of texels
            raw = raw.reshape(raw.shape[0] if raw.ndim > 2 else 1, -1)
            out = out.reshape(raw.shape)
        if raw.dtype != np.uint8 or raw.shape[1] % 3 or raw.strides[1] != 1:
            out.reshape(-1, 3)[...] = self.triples(np.asarray(raw).reshape(-1, 3))
            return result
        # Pieces of about _PIECE texels: the piece's keys, numbers and gathered rows stay in
        # the core's cache between the steps (a whole 512 x 1024-texel tile at once is slower).
        # Each texel's value is its triple's, so the cut changes no bit.
        n = raw.shape[1] // 3
        step = min(raw.shape[0], max(1, _PIECE // n))
        scratch = self._scratch
        buffers = (scratch.get("rgba", (step, n, 4), np.uint8), scratch.get("key", (step, n), np.intp),
                   scratch.get("slot", (step, n), np.int32), scratch.get("rows", (step, n), np.complex128))
        for a in range(0, raw.shape[0], step):
            t = min(step, raw.shape[0] - a)
            self._piece(raw[a:a + t], out[a:a + t], *(b[:t] for b in buffers))
        return result

    def _piece(self, raw: np.ndarray, out: np.ndarray, rgba, key, slot, rows) -> None:
        """Convert the rows ``raw`` (t, 3 n) uint8 into ``out`` (t, 3 n) contiguous float32,
        through the given (t, n, ...) scratch arrays."""
        import cv2          # as color.decode_curves: SIMD channel shuffles

        t, n = raw.shape[0], raw.shape[1] // 3
        # Packed triples: RGB -> RGBA bytes (one SIMD pass), read as little-endian uint32.
        rgba = cv2.cvtColor(raw.reshape(t, n, 3), cv2.COLOR_RGB2RGBA, dst=rgba)
        np.bitwise_and(rgba.view("<u4").reshape(t, n), np.uint32(0xFFFFFF), out=key)
        np.take(self.slots.table, key, out=slot, mode="clip")
        left = self.slots.learn(key, slot) if slot.min() == 0 else None
        if self.slots.count >= self._filled:
            self._fill()
        np.take(self._rows, slot, out=rows, mode="clip")
        dst = out.reshape(t, n, 3)
        got = cv2.cvtColor(rows.view(np.float32).reshape(t, n, 4), cv2.COLOR_RGBA2RGB, dst=dst)
        if got is not dst and not np.shares_memory(got, dst):
            dst[...] = got
        if left is not None:            # more distinct triples than the table numbers: converted here
            r, c = np.divmod(left, n)
            dst[r, c] = self.triples(raw.reshape(t, n, 3)[r, c])

    def _fill(self) -> None:
        """Values for the triples numbered since the last fill."""
        with self._lock:
            count = self.slots.count
            if count >= self._filled:
                self._values[self._filled:count + 1, :3] = self.triples(self.slots.codes[self._filled:count + 1])
                self._filled = count + 1
