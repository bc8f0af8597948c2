"""Where compression gets its data: all stored values in memory, or streamed from disk.

Every source answers the same questions, so the solver does not care which it has:

* ``columns(texels)``      -> (S, 3 n) float32, curve-decoded values of some texels (the fit,
                              the held-out evaluation set);
* ``project(u, mix, ks)``  -> coefficients (k, P, 3) of every texel (+ ||X||^2), see
                              :mod:`.projection`;
* ``working_samples(rows)``-> (r, P, 3) float32 working-space images (the error curve);
* ``close()``              -> releases what it holds (a spill file, a cluster); sources are
                              context managers.

Values are "curve-decoded": integer codes through the per-channel curve of the OCIO
decode; the 3x3 primaries matrix (``matrix``) is left to the caller, who folds it into the
colour ``mix`` of the projection instead of applying it to S x P pixels.

:class:`InMemorySource` decodes every file once into a block-major array of the stored
type (0.53 GB for 90 x 120 samples at 128^2, 8 bit) and makes passes over it.
:class:`StreamingSource` never holds more than a few chunks of samples: its first pass
decodes every file, keeps the requested texel columns and sample rows, and writes the
stored values to an anonymous spill file (:mod:`.spill`) when the disk has room; the
projection then reads the spill back (or, without one, decodes the files again).
``choose_source`` picks by a memory budget; :mod:`.distributed` adds a source whose passes
run on a Dask cluster.

All of them project through the same fixed pieces in the same order
(:class:`~.projection.WorkPlan`, :class:`~.projection.ProjectionTotal`), so the
coefficients -- and every file written from them -- are bit-identical whichever source,
chunk size, memory budget or cluster was used.
"""
from __future__ import annotations

import collections
import dataclasses
import threading

import numpy as np

from .. import color
from ..atomic import raise_if_interrupted
from ..errors import BTFError
from ..lifetime import forked_pool
from ..model import BTF, FileBTF
from .convert import Conversion, Scratch, TripleConversion, TripleSlots
from .domain import LINEAR
from .load import _STATE, BlockedData, _init, decodes_in_workers, default_workers, load_encoded, stored_dtype
from .parallel import cpu_count, in_threads, one_blas_thread, rows_apply, thread_map
from .projection import ProjectionTotal, ShardSums, TileProjector, WorkPlan
from .spill import Spill

#: Bytes of stored values the streaming source decodes per chunk (whole projection tiles);
#: up to workers + 1 chunks are in flight.
CHUNK_BYTES = 64e6

__all__ = ["InMemorySource", "StreamingSource", "kept_values", "choose_source", "stored_bytes", "tile_samples",
           "work_plan", "itemsize"]


def itemsize(btf: BTF) -> int:
    """Bytes per stored channel value."""
    return stored_dtype(btf).itemsize


def stored_bytes(btf: BTF) -> int:
    """Bytes the stored values of ``btf`` take in their own type."""
    return btf.n_samples * btf.n_pixels * 3 * itemsize(btf)


def work_plan(btf: BTF) -> WorkPlan:
    """The tiles, shards and blocks every source projects ``btf`` through."""
    return WorkPlan.for_shape(btf.n_samples, btf.n_pixels, itemsize(btf))


def tile_samples(btf: BTF) -> int:
    """Samples per projection tile (:meth:`.projection.WorkPlan.for_shape`)."""
    return work_plan(btf).tile


class Closable:
    """A source as a context manager: leaving the ``with`` block calls :meth:`close`, which
    releases what the source holds (a spill file, a cluster; nothing by default)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """Release what the source holds (nothing here)."""


class _Source(Closable):
    """Shared decode plumbing: per-channel curves now, the 3x3 matrix later; in a working
    domain, one table per channel from stored code to domain value where the decode allows."""

    def __init__(self, btf: BTF):
        self.btf = btf
        self.plan = work_plan(btf)
        dec = btf.integer_decoder
        self._decoder = dec if dec is not None and dec.exact else None
        if self._decoder is not None:
            self._decode, self.matrix = dec.decode_curves, dec.matrix
        else:
            def decode(block, out=None):
                x = btf.decode(block.reshape(block.shape[0], -1, 3)).reshape(block.shape)
                if out is None:
                    return x
                out[...] = x
                return out

            self._decode, self.matrix = decode, None
        #: Stored values -> curve-decoded float32 (then, after :meth:`set_domain`, domain values).
        self.curves = Conversion(self._decode)
        self._domain_curves: dict = {}
        self._triple_slots = None

    def to_working(self, x: np.ndarray) -> np.ndarray:
        """(..., 3 n) or (..., 3) curve-decoded values -> working space."""
        return x if self.matrix is None else color.mix_rgb(x, self.matrix)

    def working_mix(self, color: np.ndarray) -> np.ndarray:
        """The projection's colour mix: ``color`` (3, 3, acting on working-space RGB) after
        the decode's primaries matrix."""
        m = np.eye(3) if self.matrix is None else self.matrix.astype(np.float64)
        return np.asarray(color, np.float64) @ m

    def projector(self, u, mix, ks, energy) -> TileProjector:
        return TileProjector(u, mix, ks, self.curves, self.plan.tile, energy=energy)

    #: The working domain the answers are in (:meth:`set_domain`).
    domain = LINEAR

    def curves_in(self, domain):
        """callable: stored values (..., 3 n) -> ``domain.forward`` of their working-space
        values (float32, same shape; the primaries matrix included).

        Integer codes whose decode has no matrix (sRGB, Rec.709-primaried files) go through
        one table per channel, ``forward`` of the decode's table: a lookup per value instead
        of a lookup, a power and a clamp (the projection at UBO2014's size converts 10^10
        values), and the same float32 value for a code wherever and however it is converted.
        """
        if self.domain is not LINEAR:
            raise RuntimeError("curves_in: the source already answers in a working domain")
        if domain not in self._domain_curves:
            dec = self._decoder
            if dec is not None and self.matrix is None:
                table = dec if domain.is_linear else dataclasses.replace(dec, lut=domain.forward(dec.lut))
                self._domain_curves[domain] = Conversion(table.decode_curves)
            else:
                nonnegative = dec is not None and bool(np.all(dec.lut >= 0)) and \
                    (self.matrix is None or bool(np.all(self.matrix >= 0)))
                if dec is not None and dec.bits == 8 and self.matrix is not None and not domain.is_linear:
                    # Each distinct code triple converted once (.convert.TripleConversion); the
                    # candidate domains share one numbering of the triples.
                    if self._triple_slots is None:
                        self._triple_slots = TripleSlots()
                    self._domain_curves[domain] = TripleConversion(self._decode, self.matrix, domain,
                                                                   nonnegative=nonnegative, slots=self._triple_slots)
                else:
                    self._domain_curves[domain] = Conversion(self._decode, self.matrix, domain, nonnegative=nonnegative)
        return self._domain_curves[domain]

    def set_domain(self, domain) -> None:
        """From now on answer in the working ``domain`` (:mod:`.domain`): values are
        ``domain.forward`` of the working-space values, per channel, so the primaries matrix
        moves into the curves (it must act before the curve) and the colour mix is the
        colour rotation alone (:meth:`curves_in`).  A linear domain changes nothing."""
        if domain.is_linear:
            return
        self.curves = self.curves_in(domain)
        self.matrix = None
        self.domain = domain

    def raw_columns(self, texels: np.ndarray) -> np.ndarray:
        """(S, 3 n) stored values of sorted ``texels`` (for :meth:`curves_in`), without handing
        them over (the working-domain choice reads the fitting and evaluation columns in
        each candidate's domain before the fit and the evaluation take them)."""
        raise NotImplementedError

    def _decoded(self, raw: np.ndarray) -> np.ndarray:
        """(S, 3 n) stored values -> the curves' float32 values (on every core)."""
        return rows_apply(self.curves, raw, np.empty(raw.shape, np.float32), into=True)


class InMemorySource(_Source):
    """Every stored value in memory, block-major (see :mod:`.load`)."""

    kind = "in-memory"

    def __init__(self, btf: BTF, *, workers: int | None = None):
        super().__init__(btf)
        self.stored: BlockedData = load_encoded(btf, workers=workers, block=self.plan.block)
        self.nbytes = self.stored.nbytes

    def raw_columns(self, texels: np.ndarray) -> np.ndarray:
        """(S, 3 n) stored values of sorted ``texels``: runs of consecutive texels (split at
        storage-block edges) copied as stored."""
        texels = np.asarray(texels)
        breaks = np.flatnonzero((np.diff(texels) != 1) | (texels[1:] % self.stored.block == 0)) + 1
        starts, ends = np.r_[0, breaks], np.r_[breaks, len(texels)]
        raw = np.empty((self.stored.n_samples, 3 * len(texels)), self.stored.blocks.dtype)
        for s0, e0 in zip(starts, ends):
            raw[:, 3 * s0:3 * e0] = self.stored.span(int(texels[s0]), int(texels[e0 - 1]) + 1)
        return raw

    def columns(self, texels: np.ndarray) -> np.ndarray:
        """(S, 3 n) float32 after the curves for sorted ``texels``."""
        return self._decoded(self.raw_columns(texels))

    def project(self, u: np.ndarray, mix: np.ndarray, ks, *, energy: bool = False):
        """Coefficients (k, P, 3) (see :mod:`.projection`) and, if ``energy``, ||Y||^2
        (the working-space energy when ``mix`` is the working matrix times an orthogonal one).
        One block at a time (its stored values are contiguous), each over its shards in order."""
        proj = self.projector(u, mix, ks, energy)
        total = ProjectionTotal(proj, self.plan)

        def block(ab):
            raw = self.stored.span(*ab)
            sums = ShardSums(proj, [ab])
            for n, (s0, s1) in enumerate(self.plan.shards()):
                for t0, t1 in self.plan.tiles(s0, s1):
                    sums.add_tile(proj, t0, raw[t0:t1])
                total.add(n, sums)
                sums.reset()

        with one_blas_thread():       # blocks on one thread per core, each GEMM on one
            in_threads(block, self.plan.blocks())
        return total.result()

    def working_samples(self, rows) -> np.ndarray:
        """(n, P, 3) float32 working-space images of samples ``rows``."""
        return self.to_working(self.curves(self._held().samples(rows)))

    def row_chunks(self):
        """Yield (first sample, (n, 3 P) stored values) tile by tile, in sample order (a
        pass over every texel: :class:`.fit.ImagePasses`)."""
        for a, b in self.plan.tiles(0, self.btf.n_samples):
            yield a, self._held().samples(slice(a, b)).reshape(b - a, -1)

    def release_values(self) -> None:
        """Drop every stored value (the anonymous mapping they live in goes back to the
        system): compress's last steps need none of them (issue 42: at paper scale they are
        0.53 GB of the run's 1.2 GB)."""
        self.stored = None

    def _held(self) -> BlockedData:
        if self.stored is None:
            raise BTFError("the source's stored values were released")
        return self.stored


def kept_values(block: np.ndarray, a: int, keep_texels: list, keep_rows: np.ndarray):
    """What a first pass keeps of samples a.. (``block``: (n, H, W, 3) stored values): the
    stored values of each kept texel set ((n, 3 m) per set) and of the kept sample rows
    ({sample: (P, 3)}): copies, no arithmetic."""
    n = len(block)
    flat = block.reshape(n, -1, 3)
    cols = [np.ascontiguousarray(flat[:, t, :]).reshape(n, -1) for t in keep_texels]
    return cols, {int(i): flat[i - a].copy() for i in keep_rows if a <= i < a + n}


#: A decode worker's chunk array, reused from chunk to chunk (fresh ones fault in new pages).
_CHUNK = Scratch()


def _first_pass_chunk(btf: BTF, a: int, b: int, keep_texels: list, keep_rows: np.ndarray, spill: Spill | None,
                      chunk: int = 1, reuse: bool = False):
    """Decode samples a..b: :func:`kept_values`, and the whole chunk written to ``spill`` in its
    slot (a // chunk).  Runs in a decode worker (``reuse``: into the worker's one chunk array,
    kept between chunks) or in the caller."""
    if reuse and isinstance(btf, FileBTF):
        out = _CHUNK.get("chunk", (b - a, btf.height, btf.width, 3), stored_dtype(btf))
        block = btf.read_encoded(slice(a, b), out=out)
    else:
        block = btf.read_encoded(slice(a, b))
    if spill is not None:
        spill.write(a // chunk, block)
    return kept_values(block, a, keep_texels, keep_rows)


def _first_pass_worker(bounds):
    state = _STATE
    try:
        return _first_pass_chunk(state["btf"], *bounds, *state["out"], reuse=True)
    except BTFError as exc:
        return str(exc)


def _read_chunk(bounds):
    btf, (start, stop) = _STATE["btf"], bounds
    try:
        return np.stack([btf.read_one(i) for i in range(start, stop)])
    except BTFError as exc:
        return str(exc)


class _KeptSource(_Source):
    """A source that keeps, from a first pass, only some texels' columns and some samples
    (streamed, distributed), as stored values: ``columns`` decodes a set and hands it over,
    ``working_samples`` decodes the rows (in the working domain of the moment, as in memory)."""

    def _keep(self, keep_texels: list, keep_rows) -> tuple[list, np.ndarray]:
        """Allocate what the first pass fills; returns (texel sets, rows) as arrays."""
        S = self.btf.n_samples
        dtype = stored_dtype(self.btf)
        keep_texels = [np.asarray(t) for t in keep_texels]
        rows = np.asarray(keep_rows, dtype=int)
        self._kept = [(t, np.empty((S, 3 * len(t)), dtype)) for t in keep_texels]
        self._kept_lock = threading.Lock()
        self._rows = {int(r): n for n, r in enumerate(rows)}
        self._row_data = np.empty((len(rows), self.btf.n_pixels, 3), dtype)
        self.nbytes = sum(d.nbytes for _, d in self._kept) + self._row_data.nbytes
        return keep_texels, rows

    def _store(self, a: int, cols: list, rows: dict) -> None:
        """Store :func:`kept_values` of samples a.. (copies of stored values)."""
        for (_, dest), c in zip(self._kept, cols):
            dest[a:a + len(c)] = c
        for i, image in rows.items():
            self._row_data[self._rows[i]] = image

    def _kept_set(self, texels: np.ndarray, *, hand_over: bool) -> np.ndarray:
        # Under a lock: the fitting and the held-out sets may be handed over from two
        # threads at once, and a deletion between another thread's search and its own
        # deletion would remove the wrong set, or none (an IndexError).
        with self._kept_lock:
            for n, (t, raw) in enumerate(self._kept):
                if np.array_equal(t, texels):
                    if hand_over:
                        del self._kept[n]
                    return raw
        raise ValueError(f"{type(self).__name__}: texels were not requested up front (or were handed over)")

    def columns(self, texels: np.ndarray) -> np.ndarray:
        """(S, 3 n) float32 curve-decoded values of ``texels``, one of the sets requested up
        front, handed over: the source forgets them (they are decoded for one use, and
        holding the fit's columns through the projection would cost their size again)."""
        return self._decoded(self._kept_set(texels, hand_over=True))

    def raw_columns(self, texels: np.ndarray) -> np.ndarray:
        return self._kept_set(texels, hand_over=False)

    def release(self, texels: np.ndarray) -> None:
        """Forget the kept columns of ``texels`` (a fit over every texel no longer needs the
        fitting sample's: 0.13 GB at paper scale)."""
        self._kept_set(texels, hand_over=True)

    def working_samples(self, rows) -> np.ndarray:
        """(n, P, 3) float32 working-space images of samples ``rows`` (requested up front)."""
        try:
            idx = [self._rows[int(r)] for r in np.atleast_1d(rows)]
        except KeyError:
            raise ValueError(f"{type(self).__name__}.working_samples: rows were not requested up front") from None
        return self.to_working(self.curves(self._row_data[idx]))


class StreamingSource(_KeptSource):
    """Decode once (twice without room for a spill file), holding a few chunks of samples.

    ``keep_texels`` (lists of sorted texel arrays) and ``keep_rows`` (sample indices) are
    collected during the first pass; ``columns`` and ``working_samples`` answer only those.
    The first pass also writes the stored values to an anonymous spill file (:mod:`.spill`,
    direct I/O where the file system allows) when ``spill`` and the temporary folder has room;
    :meth:`project` reads it back, a few
    chunks ahead in a thread, else decodes the files again.
    Memory: the kept columns (S x 3 n float32) + up to workers + 1 chunks of stored values +
    twice the coefficients (k x 3P float32: the total and one shard's sums).
    """

    kind = "streaming"

    def __init__(self, btf: BTF, keep_texels: list, keep_rows, *, workers: int | None = None,
                 chunk_bytes: float = CHUNK_BYTES, spill: bool = True):
        super().__init__(btf)
        # Whole projection tiles per chunk, as many as fit ``chunk_bytes`` of stored values.
        tile = self.plan.tile
        self.chunk = tile * int(max(1, chunk_bytes // (tile * btf.n_pixels * 3 * itemsize(btf))))
        # One decode process more than asked for when spilling: each process waits for its
        # direct writes (a 246 MB chunk at UBO2014's size takes 0.2 s to write), and the extra
        # one decodes meanwhile (UBO2014 size: first pass 32.4 -> 29.3 s, decoding alone 24.8 s).
        asked = workers or default_workers()
        self.workers = asked + (1 if spill and asked > 1 else 0)
        keep_texels, rows = self._keep(keep_texels, keep_rows)
        n_chunks = -(-btf.n_samples // self.chunk)
        self._spill = Spill.create(n_chunks, self.chunk * btf.n_pixels * 3 * itemsize(btf)) if spill else None
        if self._spill is not None:
            self.kind = "streaming, spilled"
        try:
            for a, (cols, kept_rows) in self._first_pass(keep_texels, rows):
                self._store(a, cols, kept_rows)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        if self._spill is not None:
            self._spill.close()
            self._spill = None

    def _bounds(self) -> list[tuple[int, int]]:
        S = self.btf.n_samples
        return [(a, min(a + self.chunk, S)) for a in range(0, S, self.chunk)]

    def _parallel(self, bounds) -> bool:
        return decodes_in_workers(self.btf) and self.workers > 1 and len(bounds) > 1

    def _first_pass(self, keep_texels, rows):
        """Yield (first sample, (kept columns, kept rows)) per chunk, in sample order."""
        bounds = self._bounds()
        if not self._parallel(bounds):
            for a, b in bounds:
                yield a, _first_pass_chunk(self.btf, a, b, keep_texels, rows, self._spill, self.chunk)
            return
        yield from self._in_pool(_first_pass_worker, bounds, (keep_texels, rows, self._spill, self.chunk))

    def _in_pool(self, fn, bounds, extra):
        """Yield (first sample, fn's result) over ``bounds``, in order, from forked decode
        workers: at most workers + 1 chunks in flight (pool.map would queue every result in
        this process when the consumer is slower than the decoders)."""
        with forked_pool(self.workers, initializer=_init, initargs=(self.btf, extra)) as pool:
            pending = collections.deque()
            for bound in bounds:
                pending.append((bound[0], pool.submit(fn, bound)))
                if len(pending) > self.workers:
                    yield self._checked(*pending.popleft())
            while pending:
                yield self._checked(*pending.popleft())

    def _chunks(self):
        """Yield (first sample, (n, 3 P) stored values) over all samples, in order: from the
        spill file, else decoded again."""
        btf, bounds = self.btf, self._bounds()
        width, dtype = btf.n_pixels * 3, stored_dtype(btf)
        if self._spill is not None:
            pieces = [(n, (b - a) * width * dtype.itemsize) for n, (a, b) in enumerate(bounds)]
            for (a, _), (_, raw) in zip(bounds, self._spill.read_ahead(pieces)):
                yield a, raw.view(dtype).reshape(-1, width)
        elif self._parallel(bounds):
            for a, block in self._in_pool(_read_chunk, bounds, None):
                yield a, block.reshape(len(block), -1)
        else:
            for a, b in bounds:
                yield a, btf.read_encoded(slice(a, b)).reshape(b - a, -1)

    def row_chunks(self):
        """Yield (first sample, (n, 3 P) stored values) chunk by chunk (whole tiles), in
        sample order: from the spill file, else decoded again (:class:`.fit.ImagePasses`)."""
        yield from self._chunks()

    @staticmethod
    def _checked(first: int, future):
        result = future.result()
        raise_if_interrupted()
        if isinstance(result, str):
            raise BTFError(result)
        return first, result

    def project(self, u: np.ndarray, mix: np.ndarray, ks, *, energy: bool = False):
        """Second pass: the same shards and blocks as :meth:`InMemorySource.project`, chunk by
        chunk (a shard's sums for every block are added to the total when the shard ends)."""
        proj = self.projector(u, mix, ks, energy)
        total = ProjectionTotal(proj, self.plan)
        blocks = self.plan.blocks()
        # Each tile's blocks on one thread per core (disjoint sets of blocks), each GEMM on one.
        parts = [p for p in np.array_split(np.arange(len(blocks)), min(len(blocks), cpu_count())) if len(p)]
        shard, sums = -1, None
        with one_blas_thread(), thread_map(len(parts)) as tmap:
            for s0, flat in self._chunks():
                for t0 in range(0, len(flat), proj.tile):
                    n = (s0 + t0) // self.plan.shard
                    if n != shard:
                        if sums is None:
                            sums = ShardSums(proj, blocks)
                        else:
                            total.add(shard, sums)
                            sums.reset()          # reused: see ShardSums.reset
                        shard = n
                    rows = flat[t0:t0 + proj.tile]
                    tmap(lambda which: sums.add_tile(proj, s0 + t0, rows, which), parts)
        total.add(shard, sums)
        return total.result()


def choose_source(btf: BTF, keep_texels: list, keep_rows, *, memory_budget: float, workers=None,
                  chunk_bytes: float = CHUNK_BYTES, spill: bool = True, beside: float = 0) -> _Source:
    """In memory when the stored values and ``beside`` bytes (what the run holds with them)
    fit ``memory_budget`` bytes, else streamed in chunks of about ``chunk_bytes`` stored
    bytes.  Either gives bit-identical projections."""
    if stored_bytes(btf) + beside <= memory_budget:
        return InMemorySource(btf, workers=workers)
    return StreamingSource(btf, keep_texels, keep_rows, workers=workers, chunk_bytes=chunk_bytes, spill=spill)
