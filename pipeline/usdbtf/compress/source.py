"""Where compression gets its data: all stored values in memory, or streamed from disk.

Both sources answer the same three questions, so the solver does not care which it has:

* ``columns(texels)``      -> (S, 3 n) float32, curve-decoded values of some texels (the fit,
                              the held-out evaluation set);
* ``project(u, energy)``   -> coefficients (k, P, 3) = U^T X for every texel (+ ||X||^2);
* ``working_samples(rows)``-> (r, P, 3) float32 working-space images (the error curve).

Values are "curve-decoded": integer codes through the per-channel curve of the OCIO
decode; the 3x3 primaries matrix (``matrix``) is left to the caller, who applies it to the
k coefficient textures (exact: it commutes with the projection) instead of to S x P pixels.

:class:`InMemorySource` decodes every file once into a block-major array of the stored
type (0.53 GB for 90 x 120 samples at 128^2, 8 bit) and makes passes over it.
:class:`StreamingSource` never holds more than a chunk of samples: it decodes the files
twice (pass 1 keeps only the requested texel columns and sample rows; pass 2 accumulates
U^T X chunk by chunk).  ``choose_source`` picks by a memory budget.
"""
from __future__ import annotations

import collections
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from ..errors import BTFError
from ..model import BTF, FileBTF
from .load import BlockedData, _forkable, _init, default_workers, load_encoded

#: Bytes of decoded float32 samples the streaming source holds per chunk.
CHUNK_BYTES = 128e6
_TEXELS_PER_GEMM = 16384

__all__ = ["InMemorySource", "StreamingSource", "choose_source", "stored_bytes", "colour_gram"]


def stored_bytes(btf: BTF) -> int:
    """Bytes the stored values of ``btf`` take in their own type."""
    item = {"uint8": 1, "uint16": 2, "half": 2, "float": 4}[btf.bit_depth]
    return btf.n_samples * btf.n_pixels * 3 * item


def colour_gram(x: np.ndarray, group: int = 8) -> np.ndarray:
    """3x3 sum of x x^T over all RGB triples of ``x`` (..., 3 n), float64.

    BLAS is slow at 3 x 3 outputs; grouping ``group`` texels per row gives a 24 x 24
    Gram (4x faster), whose diagonal 3 x 3 blocks sum to the answer.
    """
    flat = x.reshape(-1)
    n = flat.size // (3 * group) * (3 * group)
    y = flat[:n].reshape(-1, 3 * group).astype(np.float64)   # float32 sums overflow on HDR data
    g = y.T @ y
    out = sum(g[3 * i:3 * i + 3, 3 * i:3 * i + 3] for i in range(group))
    rest = flat[n:].reshape(-1, 3).astype(np.float64)
    return out + rest.T @ rest


class _Source:
    """Shared decode plumbing: per-channel curves now, the 3x3 matrix later."""

    def __init__(self, btf: BTF):
        self.btf = btf
        dec = btf.integer_decoder
        if dec is not None and dec.exact:
            self.curves = dec.decode_curves
            self.matrix = dec.matrix
        else:
            self.curves = lambda block: btf.decode(block.reshape(block.shape[0], -1, 3)).reshape(block.shape)
            self.matrix = None

    def to_working(self, x: np.ndarray) -> np.ndarray:
        """(..., 3 n) or (..., 3) curve-decoded values -> working space."""
        if self.matrix is None:
            return x
        return (x.reshape(-1, 3) @ self.matrix.T).reshape(x.shape)

    def _energy(self, gram: np.ndarray) -> float:
        m = self.matrix.astype(np.float64) if self.matrix is not None else np.eye(3)
        return float(np.trace(m @ gram @ m.T))


class InMemorySource(_Source):
    """Every stored value in memory, block-major (see :mod:`.load`)."""

    kind = "in-memory"

    def __init__(self, btf: BTF, *, workers: int | None = None):
        super().__init__(btf)
        self.stored: BlockedData = load_encoded(btf, workers=workers)
        self.nbytes = self.stored.nbytes

    def columns(self, texels: np.ndarray) -> np.ndarray:
        """(S, 3 n) float32 after the curves for sorted ``texels``: runs of consecutive texels
        (split at storage-block edges) are copied as stored values, then decoded in one call."""
        texels = np.asarray(texels)
        breaks = np.flatnonzero((np.diff(texels) != 1) | (texels[1:] % self.stored.block == 0)) + 1
        starts, ends = np.r_[0, breaks], np.r_[breaks, len(texels)]
        raw = np.empty((self.stored.n_samples, 3 * len(texels)), self.stored.blocks.dtype)
        for s0, e0 in zip(starts, ends):
            raw[:, 3 * s0:3 * e0] = self.stored.span(int(texels[s0]), int(texels[e0 - 1]) + 1)
        return self.curves(raw)

    def _ranges(self, chunk: int):
        """(a, b) texel ranges covering every texel, none crossing a storage block."""
        P, B = self.stored.n_pixels, self.stored.block
        for start in range(0, P, B):
            end = min(start + B, P)
            for a in range(start, end, chunk):
                yield a, min(a + chunk, end)

    def project(self, u: np.ndarray, *, chunk: int = 1024, energy: bool = False):
        """Coefficients (k, P, 3) = U^T X over texel blocks, and ||X||^2 in the working space
        (None unless ``energy``).  The energy comes from the 3x3 colour Gram of the curve-
        decoded data, so the matrix A applies exactly: ||X A^T||^2 = trace(A G A^T)."""
        k, P = u.shape[1], self.stored.n_pixels
        coeff = np.empty((k, P, 3), np.float32)
        gram = np.zeros((3, 3))
        ut = np.ascontiguousarray(u.T)
        for a, b in self._ranges(chunk):
            x = self.curves(self.stored.span(a, b))
            coeff[:, a:b, :] = (ut @ x).reshape(k, b - a, 3)
            if energy:
                gram += colour_gram(x)
        return coeff, (self._energy(gram) if energy else None)

    def working_samples(self, rows) -> np.ndarray:
        """(n, P, 3) float32 working-space images of samples ``rows``."""
        return self.to_working(self.curves(self.stored.samples(rows)))


def _read_chunk(bounds):
    from .load import _STATE

    btf, (start, stop) = _STATE["btf"], bounds
    try:
        return np.stack([btf.read_one(i) for i in range(start, stop)])
    except BTFError as exc:
        return str(exc)


class StreamingSource(_Source):
    """Decode the files twice, holding one chunk of samples at a time.

    ``keep_texels`` (lists of sorted texel arrays) and ``keep_rows`` (sample indices) are
    collected during the first pass; ``columns`` and ``working_samples`` answer only those.
    Memory: the kept columns (S x 3 n float32) + one chunk + the coefficients (k x 3P).
    """

    kind = "streaming"

    def __init__(self, btf: BTF, keep_texels: list, keep_rows, *, workers: int | None = None,
                 chunk: int | None = None, chunk_bytes: float = CHUNK_BYTES):
        super().__init__(btf)
        # Samples per chunk from a byte size, not a count: 256 samples are 0.8 GB of float32 at 512^2.
        self.chunk = chunk or int(max(1, min(256, chunk_bytes // (btf.n_pixels * 3 * 4))))
        self.workers = workers or default_workers()
        S = btf.n_samples
        self._kept = [(np.asarray(t), np.empty((S, 3 * len(t)), np.float32)) for t in keep_texels]
        rows = np.asarray(keep_rows)
        self._rows = {int(r): n for n, r in enumerate(rows)}
        self._row_data = np.empty((len(rows), btf.n_pixels, 3), np.float32)
        self.nbytes = sum(d.nbytes for _, d in self._kept) + self._row_data.nbytes
        for s0, block in self._chunks():
            flat = block.reshape(len(block), -1, 3)
            for t, dest in self._kept:
                dest[s0:s0 + len(block)] = self.curves(np.ascontiguousarray(flat[:, t, :])).reshape(len(block), -1)
            for i in range(s0, s0 + len(block)):
                if i in self._rows:
                    self._row_data[self._rows[i]] = self.to_working(self.curves(flat[i - s0]))

    def _chunks(self):
        """Yield (first sample, (n, H, W, 3) stored values) over all samples, in order."""
        btf, S = self.btf, self.btf.n_samples
        bounds = [(a, min(a + self.chunk, S)) for a in range(0, S, self.chunk)]
        if isinstance(btf, FileBTF) and self.workers > 1 and _forkable(btf) and len(bounds) > 1:
            with ProcessPoolExecutor(self.workers, mp_context=mp.get_context("fork"), initializer=_init,
                                     initargs=(btf, None)) as pool:
                # At most workers + 1 chunks in flight: pool.map would queue every decoded
                # chunk in this process when the consumer is slower than the decoders.
                pending = collections.deque()
                for bound in bounds:
                    pending.append((bound[0], pool.submit(_read_chunk, bound)))
                    if len(pending) > self.workers:
                        yield self._checked(*pending.popleft())
                while pending:
                    yield self._checked(*pending.popleft())
        else:
            for a, b in bounds:
                yield a, btf.read_encoded(slice(a, b))

    @staticmethod
    def _checked(first: int, future):
        block = future.result()
        if isinstance(block, str):
            raise BTFError(block)
        return first, block

    def columns(self, texels: np.ndarray) -> np.ndarray:
        for t, dest in self._kept:
            if np.array_equal(t, texels):
                return dest
        raise ValueError("StreamingSource.columns: texels were not requested up front")

    def project(self, u: np.ndarray, *, chunk: int = 0, energy: bool = False):
        """Second pass: coefficients accumulated as sum over sample chunks of U_c^T X_c."""
        k, P = u.shape[1], self.btf.n_pixels
        acc = np.zeros((k, 3 * P), np.float32)
        gram = np.zeros((3, 3))
        step = 3 * _TEXELS_PER_GEMM
        for s0, block in self._chunks():
            x = self.curves(block.reshape(len(block), -1))
            uc = np.ascontiguousarray(u[s0:s0 + len(block)].T)
            # Column blocks: the product's temporary is k x step, not another k x 3P.
            for c0 in range(0, 3 * P, step):
                acc[:, c0:c0 + step] += uc @ x[:, c0:c0 + step]
            if energy:
                gram += colour_gram(x)
        return acc.reshape(k, P, 3), (self._energy(gram) if energy else None)

    def working_samples(self, rows) -> np.ndarray:
        try:
            return self._row_data[[self._rows[int(r)] for r in np.atleast_1d(rows)]]
        except KeyError:
            raise ValueError("StreamingSource.working_samples: rows were not requested up front") from None


def choose_source(btf: BTF, keep_texels: list, keep_rows, *, memory_budget: float, workers=None) -> _Source:
    """In memory when the stored values fit ``memory_budget`` bytes, else streamed."""
    if stored_bytes(btf) <= memory_budget:
        return InMemorySource(btf, workers=workers)
    return StreamingSource(btf, keep_texels, keep_rows, workers=workers)
