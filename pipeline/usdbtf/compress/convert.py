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
"""
from __future__ import annotations

import threading

import numpy as np

from .. import color
from .domain import LINEAR

__all__ = ["Conversion", "Scratch"]


class Scratch(threading.local):
    """Per-thread reusable arrays, by name: :meth:`get` returns a view of the thread's buffer
    of that name, grown (never shrunk) when a larger array is asked for."""

    def get(self, name: str, shape, dtype=np.float32) -> np.ndarray:
        buffers = self.__dict__.setdefault("buffers", {})
        size = int(np.prod(shape))
        buf = buffers.get((name, np.dtype(dtype)))
        if buf is None or buf.size < size:
            buf = buffers[(name, np.dtype(dtype))] = np.empty(size, dtype)
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
