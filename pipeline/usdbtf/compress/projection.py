"""Projection: the coefficients c = U^T b of every texel (section III of Koudelka et al. 2003:
"all pixels in the input BTF are projected onto the linear apparent BRDF basis").

The unit of work is a **tile**: ``tile`` consecutive samples x one texel block (the
:data:`~.load.DEFAULT_BLOCK` texels a source stores together).  A tile's contribution is one
GEMM of a fixed shape, U_t^T Y_t (:meth:`TileProjector.partial`).

**Reduction order (fixed).**  A texel block's coefficients are its tiles' partials summed in
float32, in sample order, starting from zero: ``acc = 0; acc += P_0; acc += P_1; ...``
(:meth:`TileProjector.accumulate`).  Every source follows it -- in memory one block at a
time over all its tiles (:func:`project_block`), streamed one chunk of samples at a time
over all blocks -- so the coefficients, and every file written from them, are bit-identical
however the samples were read.  A distributed run keeps the same bytes by returning each
tile's partial (per shard of samples, or per texel block) and reducing them in this order.
Summing a shard's tiles first and then the shards would not be bit-identical.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["TileProjector", "TilePartial", "project", "project_block"]


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
    tile : samples per tile; energy : also sum ||Y||^2 (float64) over the tiles added.
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
        widths = self.ks[:1] if self.interleaved else self.ks
        # Per-tile basis panels (k_j, t), contiguous: the same GEMM operands in every source.
        self.panels = [[np.ascontiguousarray(u[s0:s0 + tile, :kj].T) for s0 in range(0, S, tile)]
                       for kj in widths]
        self.energy = 0.0 if energy else None

    def zeros(self, n: int) -> list[np.ndarray]:
        """Accumulators of one texel block of n texels: (k, 3 n) interleaved, or (k_j, n)
        float32 per plane."""
        if self.interleaved:
            return [np.zeros((self.ks[0], 3 * n), np.float32)]
        return [np.zeros((kj, n), np.float32) for kj in self.ks]

    def partial(self, s0: int, raw: np.ndarray) -> TilePartial:
        """The tile of samples s0.. of one texel block: U_t^T Y_t, without accumulating.

        raw : (t, 3 n) stored values of the block's texels (rows may be strided), t <= tile,
            s0 a multiple of ``tile``.
        """
        t, n = raw.shape[0], raw.shape[1] // 3
        x = self.curves(raw)
        tile = s0 // self.tile
        if self.interleaved:
            # Per texel y = mix @ x; OpenCV's SIMD transform is 4x faster than a K = 3 GEMM.
            y = cv2.transform(x.reshape(t, n, 3), self.mix).reshape(t, 3 * n)
            products = [self.panels[0][tile] @ y if self.ks[0] else None]
        else:
            y = np.matmul(self.mix, x.reshape(-1, 3).T)                  # (3, t n): planar
            products = [self.panels[j][tile] @ y[j].reshape(t, n) if kj else None for j, kj in enumerate(self.ks)]
        energy = None
        if self.energy is not None:
            flat = y.reshape(1, -1)
            energy = float(np.einsum("ij,ij->", flat, flat, dtype=np.float64))
        return TilePartial(products, energy)

    def accumulate(self, acc: list, part: TilePartial) -> None:
        """Add a tile's partial to a texel block's accumulators ``acc`` (in place): the
        reduction step, to be applied in sample order starting from :meth:`zeros`."""
        for a, p in zip(acc, part.products):
            if p is not None:
                a += p
        if self.energy is not None:
            self.energy += part.energy

    def add(self, acc: list, s0: int, raw: np.ndarray) -> None:
        """:meth:`partial` then :meth:`accumulate`: add the tile of samples s0.. to ``acc``."""
        self.accumulate(acc, self.partial(s0, raw))

    def store(self, acc: list, coeff: np.ndarray, a: int, b: int) -> None:
        """Write a block's accumulators into ``coeff`` (k, P, 3) at texels a..b."""
        if self.interleaved:
            coeff[:self.ks[0], a:b, :] = acc[0].reshape(self.ks[0], b - a, 3)
            return
        for j, kj in enumerate(self.ks):
            coeff[:kj, a:b, j] = acc[j]


def project_block(projector: TileProjector, raw: np.ndarray) -> list[np.ndarray]:
    """Coefficients of one texel block from all its samples: every tile in sample order,
    summed from zero (the fixed reduction).

    Parameters
    ----------
    projector : the tiles' basis panels and colour mix.
    raw : (S, 3 n) stored values of the block's n texels, all samples.

    Returns
    -------
    The block's accumulators (see :meth:`TileProjector.zeros`); :meth:`TileProjector.store`
    puts them into the (k, P, 3) coefficients.
    """
    acc = projector.zeros(raw.shape[1] // 3)
    for s0 in range(0, raw.shape[0], projector.tile):
        projector.add(acc, s0, raw[s0:s0 + projector.tile])
    return acc


def project(source, basis: np.ndarray, colour_matrix: np.ndarray, planes, *, energy: bool = False):
    """Project every texel of ``source`` onto the basis, in the decorrelated colour frame.

    c(t) = U^T b(t) per colour plane (the paper's projection; Eq. (2) reconstructs
    I = U c), with b(t) in working space rotated by ``colour_matrix``: the source folds
    the decode's primaries matrix and the rotation into one 3 x 3 mix per texel.

    Parameters
    ----------
    source : an :class:`~.source.InMemorySource` or :class:`~.source.StreamingSource`.
    basis : (S, k) float32 U.
    colour_matrix : (3, 3) R, stored planes = working RGB @ R.
    planes : (k_0, k_1, k_2) components to project per plane (the rest are zero).
    energy : also return ||Y||^2 (working space, linear units squared).

    Returns
    -------
    coefficients : (k, P, 3) float32, texels row-major.
    energy : float, or None unless asked for.
    """
    return source.project(basis, source.working_mix(np.asarray(colour_matrix).T), planes, energy=energy)
