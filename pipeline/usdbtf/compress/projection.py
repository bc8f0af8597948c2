"""Projection: the coefficients c = U^T b of every texel (section III of Koudelka et al. 2003:
"all pixels in the input BTF are projected onto the linear apparent BRDF basis").

The work is cut the same way whoever does it (:class:`WorkPlan`, a function of the data's
shape only):

* a **tile** is ``tile`` consecutive samples x one texel block (the
  :data:`~.load.DEFAULT_BLOCK` texels a source stores together); its contribution is one GEMM
  of a fixed shape, U_t^T Y_t (:meth:`TileProjector.partial`);
* a **shard** is :data:`TILES_PER_SHARD` consecutive tiles of samples (the last one short):
  the unit a distributed worker decodes and projects.

**Reduction order (fixed).**  For every texel block, each shard's tiles are summed in float32,
in sample order, starting from zero (:class:`ShardSums`); the shards' sums are then added to
the block's coefficients in shard order, starting from zero (:class:`ProjectionTotal`).  The
energy ||Y||^2 is summed the same way in float64 (tiles within a shard, then blocks in
order, each over its shards in order).  Every source follows this order -- in memory one
block at a time, streamed one chunk of samples at a time, on a Dask cluster one shard (and
group of blocks) per task, reduced by the client as the shards arrive -- so the
coefficients, and every file written from them, are bit-identical however and wherever the
samples were read.  (Summing all tiles in one run instead would not be: float addition is
not associative.)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import color
from .convert import Scratch
from .load import DEFAULT_BLOCK, texel_blocks
from .parallel import one_blas_thread

__all__ = ["TILES_PER_SHARD", "WorkPlan", "TileProjector", "TilePartial", "ShardSums", "ProjectionTotal", "project"]

#: Projection tiles per shard of samples (1024 samples with 512-sample tiles).
TILES_PER_SHARD = 2
#: A projection tile holds at most this many samples, fewer when that many samples of stored
#: values would pass _TILE_ROW_BYTES (a streaming source holds a whole tile's samples).
#: Long tiles: each tile's products are added to accumulators of k x 3 x block floats that
#: do not stay in cache, so the additions cost memory traffic per tile (with 128-sample
#: tiles they took longer than the GEMMs at UBO2014's size; 512 samples: 23 -> 17 s at 256^2).
_MAX_TILE_SAMPLES = 512
_TILE_ROW_BYTES = 256e6


@dataclass(frozen=True)
class WorkPlan:
    """How the data matrix (S samples x P texels) is cut into tiles, shards and blocks.

    A function of the data's shape and storage type only (:meth:`for_shape`), never of the
    source, the chunk size, the memory budget or the number of workers: every way of
    reading the data sums the same pieces in the same order.

    Attributes
    ----------
    n_samples, n_pixels : S, P.
    tile : samples per tile (512, halved down to 8 while a tile's samples of stored values
        would pass 256 MB).
    block : texels per block (:data:`~.load.DEFAULT_BLOCK`, or P when smaller).
    """

    n_samples: int
    n_pixels: int
    tile: int
    block: int

    @classmethod
    def for_shape(cls, n_samples: int, n_pixels: int, itemsize: int) -> "WorkPlan":
        """The plan for S samples of P texels stored in ``itemsize``-byte channels."""
        tile = _MAX_TILE_SAMPLES
        while tile > 8 and tile * n_pixels * 3 * itemsize > _TILE_ROW_BYTES:
            tile //= 2
        return cls(n_samples, n_pixels, tile, max(1, min(DEFAULT_BLOCK, n_pixels)))

    @property
    def shard(self) -> int:
        """Samples per shard."""
        return self.tile * TILES_PER_SHARD

    def shards(self) -> list[tuple[int, int]]:
        """(first, end) sample ranges of the shards, in order."""
        return [(a, min(a + self.shard, self.n_samples)) for a in range(0, self.n_samples, self.shard)]

    def blocks(self) -> list[tuple[int, int]]:
        """(first, end) texel ranges of the blocks, in order."""
        return texel_blocks(self.n_pixels, self.block)

    def tiles(self, a: int, b: int) -> list[tuple[int, int]]:
        """(first, end) sample ranges of the tiles in samples a..b (a at a tile boundary)."""
        return [(t, min(t + self.tile, b)) for t in range(a, b, self.tile)]


@dataclass(frozen=True)
class TilePartial:
    """One tile's contribution: ``products`` as :meth:`TileProjector.zeros` lays out the
    accumulators (None for a plane projected on no vector), and ``energy`` = ||Y_t||^2
    (float64 sum; None unless the projector measures energy)."""

    products: list
    energy: float | None


class TileProjector:
    """Coefficients of every texel, accumulated tile by tile.

    Y is the curve-decoded data with the 3x3 colour ``mix`` applied to each texel
    (y = mix @ x: the decode's primaries matrix and the colour decorrelation in one), split
    into colour planes j = 0, 1, 2.  Plane j is projected on the first ``ks[j]`` basis
    vectors only, C_j = U[:, :k_j]^T Y_j: decorrelated chroma planes need far fewer vectors
    than luminance, and the vectors they do not need are never computed (their coefficients
    are zero).

    u : (S, k) float32 basis; mix : (3, 3); ks : three ints <= k; curves : stored -> float32;
    tile : samples per tile; energy : also measure ||Y||^2 (float64) of every tile.
    """

    def __init__(self, u: np.ndarray, mix: np.ndarray, ks, curves, tile: int, *, energy: bool = False):
        S = u.shape[0]
        self.k = u.shape[1]
        self.ks = [int(kj) for kj in ks]
        self.mix = np.ascontiguousarray(mix, dtype=np.float32)
        self.curves = curves
        self.tile = tile
        # Every plane on all k vectors: one GEMM per tile on the interleaved data, whose
        # (k, 3 n) result is already the coefficients' layout.  Otherwise one per plane.
        self.interleaved = len(set(self.ks)) == 1
        #: Interleaved without energy, the colour mix acts on the coefficients once, after the
        #: sums (:meth:`ProjectionTotal.result`): U^T (X mix^T) = (U^T X) mix^T per texel, so
        #: a 3 x 3 product per texel and component (k P) replaces one per texel and sample
        #: (S P, 72x as many at paper scale: a tenth of the projection, issue 42).
        self.mix_after = self.interleaved and not energy
        widths = self.ks[:1] if self.interleaved else self.ks
        # Per-tile basis panels (k_j, t), contiguous: the same GEMM operands in every source.
        self.panels = [[np.ascontiguousarray(u[s0:s0 + tile, :kj].T) for s0 in range(0, S, tile)]
                       for kj in widths]
        self.energy = energy
        self._scratch = Scratch()

    def zeros(self, n: int) -> list[np.ndarray]:
        """Accumulators of one texel block of n texels: (k, 3 n) interleaved, or (k_j, n)
        float32 per plane."""
        if self.interleaved:
            return [np.zeros((self.ks[0], 3 * n), np.float32)]
        return [np.zeros((kj, n), np.float32) for kj in self.ks]

    def accumulate(self, s0: int, raw: np.ndarray, accs: list) -> float | None:
        """Add the tile of samples s0.. of one texel block to its accumulators: acc += U_t^T Y_t
        (one float32 addition of each product element per tile).

        raw : (t, 3 n) stored values of the block's texels (rows may be strided), t <= tile,
            s0 a multiple of ``tile``.
        accs : the block's accumulators as :meth:`zeros` lays them out.

        Returns ||Y_t||^2 (float64), or None without energy.

        The GEMMs run on one BLAS thread whoever calls (a compress, a Dask task, a test):
        some kernels round a product differently on several threads.
        """
        with one_blas_thread():
            return self._accumulate(s0, raw, accs)

    def _accumulate(self, s0: int, raw: np.ndarray, accs: list) -> float | None:
        t, n = raw.shape[0], raw.shape[1] // 3
        tile = s0 // self.tile
        # Intermediates in this thread's reused arrays (fresh tile-sized arrays cost page
        # faults, see .convert); each product is added before the thread's next one.
        x = self.curves(raw, out=self._scratch.get("x", raw.shape))
        if self.interleaved:
            # Per texel y = mix @ x (OpenCV's SIMD transform is 4x faster than a K = 3 GEMM),
            # or x as it is when the mix comes after the sums.
            y = x if self.mix_after else color.mix_rgb(x, self.mix, out=self._scratch.get("y", raw.shape))
            if self.ks[0]:
                accs[0] += np.matmul(self.panels[0][tile], y, out=self._scratch.get("p", (self.ks[0], 3 * n)))
        else:
            # Plane by plane (t, n), only the planes projected on some vector (and all three
            # to measure energy): a plane is one row of the mix, one OpenCV transform.
            energy = 0.0
            for j, kj in enumerate(self.ks):
                if not kj and not self.energy:
                    continue
                y = color.mix_channel(x, self.mix[j], out=self._scratch.get("y", (t, n)))
                if kj:
                    accs[j] += np.matmul(self.panels[j][tile], y, out=self._scratch.get("p", (kj, n)))
                if self.energy:
                    energy += _energy(y)
            return energy if self.energy else None
        return _energy(y) if self.energy else None

    def partial(self, s0: int, raw: np.ndarray) -> TilePartial:
        """The tile of samples s0.. of one texel block alone: :meth:`accumulate` into zeros."""
        n = raw.shape[1] // 3
        accs = self.zeros(n)
        energy = self.accumulate(s0, raw, accs)
        widths = self.ks[:1] if self.interleaved else self.ks
        return TilePartial([acc if kj else None for acc, kj in zip(accs, widths)], energy)

    def add_into(self, acc: list, coeff: np.ndarray, a: int, b: int) -> None:
        """Add a block's accumulators to ``coeff`` (k, P, 3) at texels a..b (elementwise
        float32 additions: the layout does not change a bit of the sums)."""
        if self.interleaved:
            coeff[:self.ks[0], a:b, :] += acc[0].reshape(self.ks[0], b - a, 3)
            return
        for j, kj in enumerate(self.ks):
            if kj:
                coeff[:kj, a:b, j] += acc[j]


def _energy(y: np.ndarray) -> float:
    """||y||^2 of a float32 array, summed in float64."""
    flat = y.reshape(1, -1)
    return float(np.einsum("ij,ij->", flat, flat, dtype=np.float64))


class ShardSums:
    """One shard's sums over some consecutive texel blocks: for each block, the shard's tiles
    summed in sample order from zero (float32 products, float64 energy).  Plain arrays, so a
    Dask worker can return it.

    Parameters
    ----------
    projector : the tiles' basis panels, colour mix and curves.
    blocks : (first, end) texel ranges of consecutive blocks of the :class:`WorkPlan`.
    """

    def __init__(self, projector: TileProjector, blocks):
        self.blocks = [(int(a), int(b)) for a, b in blocks]
        self.accs = [projector.zeros(b - a) for a, b in self.blocks]
        self.energy = np.zeros(len(self.blocks)) if projector.energy else None

    def reset(self) -> None:
        """Back to zero, for the next shard (in place: fresh zeroed arrays cost a page fault,
        and a TLB shootdown across threads, per page on their first write)."""
        for accs in self.accs:
            for acc in accs:
                acc.fill(0)
        if self.energy is not None:
            self.energy.fill(0)

    def add_tile(self, projector: TileProjector, s0: int, rows: np.ndarray, which=None) -> None:
        """Add the tile of samples s0.. (the next one in sample order).

        rows : (t, 3 m) stored values of texels blocks[0][0].. of those samples (rows may be
            strided), m >= the texels of every block here.
        which : indices of the blocks to add it to (default all); threads may add the same
            tile to disjoint sets of blocks at once.
        """
        first = self.blocks[0][0]
        for i in range(len(self.blocks)) if which is None else which:
            a, b = self.blocks[i]
            energy = projector.accumulate(s0, rows[:, 3 * (a - first):3 * (b - first)], self.accs[i])
            if self.energy is not None:
                self.energy[i] += energy


class ProjectionTotal:
    """The coefficients (k, P, 3) float32 and ||Y||^2: every block's shard sums added in shard
    order, starting from zero.  :meth:`add` refuses a shard out of order, so no caller can
    change the arithmetic by accident."""

    def __init__(self, projector: TileProjector, plan: WorkPlan):
        self.projector, self.plan = projector, plan
        self.coeff = np.zeros((projector.k, plan.n_pixels, 3), np.float32)
        n_blocks = len(plan.blocks())
        self._next = [0] * n_blocks
        self._energy = np.zeros((len(plan.shards()), n_blocks)) if projector.energy else None

    def add(self, shard: int, sums: ShardSums) -> None:
        """Add shard ``shard``'s sums (each of their blocks must expect this shard next).
        Threads may add sums of disjoint blocks at once."""
        for i, (a, b) in enumerate(sums.blocks):
            n = a // self.plan.block
            if self._next[n] != shard:
                raise RuntimeError(f"projection: block {n} got shard {shard}, expected shard {self._next[n]}")
            self.projector.add_into(sums.accs[i], self.coeff, a, b)
            self._next[n] += 1
            if self._energy is not None:
                self._energy[shard, n] = sums.energy[i]

    def result(self) -> tuple[np.ndarray, float | None]:
        """(coefficients (k, P, 3) float32, ||Y||^2 or None); every shard must be in."""
        n_shards = len(self.plan.shards())
        if any(n != n_shards for n in self._next):
            raise RuntimeError("projection: not every shard was added")
        coeff = self.coeff
        if self.projector.mix_after:       # (a new array: OpenCV documents no in-place transform)
            coeff = color.mix_rgb(coeff, self.projector.mix)
        energy = None
        if self._energy is not None:
            energy = 0.0
            for n in range(self._energy.shape[1]):
                for shard in range(n_shards):
                    energy += float(self._energy[shard, n])
        return coeff, energy


def project(source, basis: np.ndarray, color_matrix: np.ndarray, planes, *, energy: bool = False):
    """Project every texel of ``source`` onto the basis, in the decorrelated colour frame.

    c(t) = U^T b(t) per colour plane (the paper's projection; Eq. (2) reconstructs
    I = U c), with b(t) in working space rotated by ``color_matrix``: the source folds
    the decode's primaries matrix and the rotation into one 3 x 3 mix per texel.

    Parameters
    ----------
    source : a source of :mod:`.source` (or :mod:`.distributed`).
    basis : (S, k) float32 U.
    color_matrix : (3, 3) R, stored planes = working RGB @ R.
    planes : (k_0, k_1, k_2) components to project per plane (the rest are zero).
    energy : also return ||Y||^2 (working space, linear units squared).

    Returns
    -------
    coefficients : (k, P, 3) float32, texels row-major.
    energy : float, or None unless asked for.
    """
    return source.project(basis, source.working_mix(np.asarray(color_matrix).T), planes, energy=energy)
