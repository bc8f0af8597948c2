"""Where compression gets its data: all stored values in memory, or streamed from disk.

Both sources answer the same three questions, so the solver does not care which it has:

* ``columns(texels)``      -> (S, 3 n) float32, curve-decoded values of some texels (the fit,
                              the held-out evaluation set);
* ``project(u, mix, ks)``  -> coefficients (k, P, 3) of every texel (+ ||X||^2), see
                              :class:`~.projection.TileProjector`;
* ``working_samples(rows)``-> (r, P, 3) float32 working-space images (the error curve).

Values are "curve-decoded": integer codes through the per-channel curve of the OCIO
decode; the 3x3 primaries matrix (``matrix``) is left to the caller, who folds it into the
colour ``mix`` of the projection instead of applying it to S x P pixels.

:class:`InMemorySource` decodes every file once into a block-major array of the stored
type (0.53 GB for 90 x 120 samples at 128^2, 8 bit) and makes passes over it.
:class:`StreamingSource` never holds more than a chunk of samples: it decodes the files
twice (pass 1 keeps only the requested texel columns and sample rows; pass 2 accumulates
the projection chunk by chunk).  ``choose_source`` picks by a memory budget.

Both project through the same fixed tiles (:func:`tile_samples` samples x one
:data:`~.load.DEFAULT_BLOCK`-texel block, summed in sample order: the fixed reduction of
:mod:`.projection`), so the coefficients -- and every file written from them -- are
bit-identical whichever source, chunk size or memory budget was used.
"""
from __future__ import annotations

import collections
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from .. import colour
from ..errors import BTFError
from ..model import BTF, FileBTF
from .curve import curve_samples
from .factored import FactoredSource, uses_factors
from .load import BlockedData, _forkable, _init, default_workers, load_encoded, texel_blocks
from .options import CompressOptions
from .projection import TileProjector, project_block
from .texels import Texels

#: Bytes of stored values the streaming source holds per chunk (whole projection tiles);
#: up to workers + 1 chunks are in flight.
CHUNK_BYTES = 64e6
#: A projection tile holds at most this many samples, fewer when that many samples of stored
#: values would pass _TILE_ROW_BYTES (the streaming source must hold a whole tile's samples).
_MAX_TILE_SAMPLES = 128
_TILE_ROW_BYTES = 64e6

__all__ = ["InMemorySource", "StreamingSource", "choose_source", "load_source", "stored_bytes", "tile_samples"]


def _itemsize(btf: BTF) -> int:
    return {"uint8": 1, "uint16": 2, "half": 2, "float": 4}[btf.bit_depth]


def stored_bytes(btf: BTF) -> int:
    """Bytes the stored values of ``btf`` take in their own type."""
    return btf.n_samples * btf.n_pixels * 3 * _itemsize(btf)


def tile_samples(btf: BTF) -> int:
    """Samples per projection tile: 128, halved (down to 8) while 128 samples of stored
    values would pass 64 MB.  A function of the data's shape only, never of the source,
    so every source sums the same tiles."""
    per_sample = btf.n_pixels * 3 * _itemsize(btf)
    t = _MAX_TILE_SAMPLES
    while t > 8 and t * per_sample > _TILE_ROW_BYTES:
        t //= 2
    return t


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
        return x if self.matrix is None else colour.mix_rgb(x, self.matrix)

    def working_mix(self, colour: np.ndarray) -> np.ndarray:
        """The projection's colour mix: ``colour`` (3, 3, acting on working-space RGB) after
        the decode's primaries matrix."""
        m = np.eye(3) if self.matrix is None else self.matrix.astype(np.float64)
        return np.asarray(colour, np.float64) @ m

    def _projector(self, u, mix, ks, energy) -> TileProjector:
        return TileProjector(u, mix, ks, self.curves, tile_samples(self.btf), energy=energy)

    def set_domain(self, domain) -> None:
        """From now on answer in the working ``domain`` (:mod:`.domain`): values are
        ``domain.forward`` of the working-space values, per channel, so the primaries matrix
        moves into the curves (it must act before the curve) and the colour mix is the
        colour rotation alone.  A linear domain changes nothing."""
        if domain.is_linear:
            return
        self._to_domain_kept(domain)
        decode, matrix = self.curves, self.matrix
        self.curves = lambda raw: domain.forward(decode(raw) if matrix is None else colour.mix_rgb(decode(raw), matrix))
        self.matrix = None

    def _to_domain_kept(self, domain) -> None:
        """Convert values a source already holds (streaming: its kept columns and rows)."""


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

    def project(self, u: np.ndarray, mix: np.ndarray, ks, *, energy: bool = False):
        """Coefficients (k, P, 3) (see :class:`~.projection.TileProjector`) and, if ``energy``, ||Y||^2
        (the working-space energy when ``mix`` is the working matrix times an orthogonal one)."""
        proj = self._projector(u, mix, ks, energy)
        coeff = np.zeros((u.shape[1], self.stored.n_pixels, 3), np.float32)
        for a, b in texel_blocks(self.stored.n_pixels, self.stored.block):
            proj.store(project_block(proj, self.stored.span(a, b)), coeff, a, b)
        return coeff, proj.energy

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
    Memory: the kept columns (S x 3 n float32) + up to workers + 1 chunks of stored values +
    the coefficients (k x 3P float32).
    """

    kind = "streaming"

    def __init__(self, btf: BTF, keep_texels: list, keep_rows, *, workers: int | None = None,
                 chunk_bytes: float = CHUNK_BYTES):
        super().__init__(btf)
        # Whole projection tiles per chunk, as many as fit ``chunk_bytes`` of stored values.
        tile = tile_samples(btf)
        self.chunk = tile * int(max(1, chunk_bytes // (tile * btf.n_pixels * 3 * _itemsize(btf))))
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

    def _to_domain_kept(self, domain) -> None:
        for _, dest in self._kept:
            dest[:] = domain.forward(self.to_working(dest))
        self._row_data[:] = domain.forward(self._row_data)

    def columns(self, texels: np.ndarray) -> np.ndarray:
        for t, dest in self._kept:
            if np.array_equal(t, texels):
                return dest
        raise ValueError("StreamingSource.columns: texels were not requested up front")

    def project(self, u: np.ndarray, mix: np.ndarray, ks, *, energy: bool = False):
        """Second pass: the same tiles as :meth:`InMemorySource.project`, chunk by chunk."""
        proj = self._projector(u, mix, ks, energy)
        blocks = texel_blocks(self.btf.n_pixels)
        accs = [proj.zeros(b - a) for a, b in blocks]
        for s0, block in self._chunks():
            flat = block.reshape(len(block), -1)
            for t0 in range(0, len(block), proj.tile):
                rows = flat[t0:t0 + proj.tile]
                for (a, b), acc in zip(blocks, accs):
                    proj.add(acc, s0 + t0, rows[:, 3 * a:3 * b])
        # Block by block, freeing each accumulator as it is copied: the peak stays near
        # one set of coefficients (np.zeros pages are committed only when written).
        coeff = np.zeros((u.shape[1], self.btf.n_pixels, 3), np.float32)
        for n, (a, b) in enumerate(blocks):
            proj.store(accs[n], coeff, a, b)
            accs[n] = None
        return coeff, proj.energy

    def working_samples(self, rows) -> np.ndarray:
        try:
            return self._row_data[[self._rows[int(r)] for r in np.atleast_1d(rows)]]
        except KeyError:
            raise ValueError("StreamingSource.working_samples: rows were not requested up front") from None


def choose_source(btf: BTF, keep_texels: list, keep_rows, *, memory_budget: float, workers=None,
                  chunk_bytes: float = CHUNK_BYTES) -> _Source:
    """In memory when the stored values fit ``memory_budget`` bytes, else streamed in chunks
    of about ``chunk_bytes`` stored bytes.  Either gives bit-identical projections."""
    if stored_bytes(btf) <= memory_budget:
        return InMemorySource(btf, workers=workers)
    return StreamingSource(btf, keep_texels, keep_rows, workers=workers, chunk_bytes=chunk_bytes)


def load_source(btf: BTF, texels: Texels, options: CompressOptions) -> _Source:
    """The load step: where one compress reads its data from (:func:`choose_source`).

    Parameters
    ----------
    btf : the BTF; its files are decoded (all at once, or streamed twice in chunks).
    texels : the fitting and evaluation texels, whose columns a streaming source keeps on its
        first pass (with the error curve's sample rows, :func:`.curve.curve_samples`).
    options : ``memory_budget`` (bytes of stored values held in memory, else streamed),
        ``chunk_bytes``, ``workers``.

    Returns
    -------
    InMemorySource or StreamingSource : answers ``columns`` (S, 3 n), ``project`` and
    ``working_samples`` (r, P, 3) the same way, bit for bit.  An input that exposes a
    factorisation gets a :class:`~.factored.FactoredSource` instead (unless
    ``options.expand_factors``): the same questions, answered from the factors.
    """
    if uses_factors(btf, options) and options.domain in ("auto", "linear"):
        return FactoredSource(btf, options)       # transcoding's algebra holds in a linear domain only
    return choose_source(btf, [texels.fit, texels.evaluation], curve_samples(btf.n_samples),
                         memory_budget=options.memory_budget, workers=options.workers, chunk_bytes=options.chunk_bytes)
