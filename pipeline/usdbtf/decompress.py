"""``decompress``: a compressed BTF's reconstruction, as a BTF and as a manifest folder.

    >>> from usdbtf.compress import read_compressed
    >>> from usdbtf.decompress import DecompressOptions, decompress, write_decompress
    >>> result = decompress(read_compressed("pebbles_c"), DecompressOptions(samples="0-99", k=16))
    >>> result.btf.read_samples([0])           # (1, H, W, 3) working space, reconstructed now
    >>> write_decompress(result, "pebbles_recon")

Nothing is reconstructed until it is read: a whole reconstruction is S x H x W x 12 bytes,
so :attr:`DecompressResult.btf` reconstructs the samples asked for (Eq. 2 of the paper,
:func:`usdbtf.compress.reconstruct`) and :func:`write_decompress` streams them in chunks into
a manifest folder in the source's colour space and bit depth.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .compress.decompress import parse_samples
from .compress.format import CompressedBTF, reconstruct
from .errors import UsageError
from .model import BTF
from .resources import require_memory
from .numeric import single_blas_thread

__all__ = ["DecompressOptions", "DecompressResult", "ReconstructedBTF", "decompress", "write_decompress"]

#: Reconstructions made at a time when writing.
CHUNK = 128


@dataclass(frozen=True)
class DecompressOptions:
    """samples : which samples, e.g. "0-99,200" (:func:`~usdbtf.compress.decompress.parse_samples`;
    None: all); k : use only the first k basis vectors (None: all of them)."""

    samples: str | None = None
    k: int | None = None


@dataclass
class ReconstructedBTF(BTF):
    """The reconstruction of samples ``indices`` of ``compressed`` from its first ``k`` basis
    vectors, made when read: float32 working-space values (``bit_depth`` "float")."""

    compressed: CompressedBTF | None = None
    indices: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    k: int | None = None

    def read_encoded(self, indices, rows=None) -> np.ndarray:
        idx = np.atleast_1d(np.arange(self.n_samples)[indices])
        images = reconstruct(self.compressed, self.indices[idx], k=self.k)
        return images if rows is None else images[:, rows[0]:rows[1]]


@dataclass
class DecompressResult:
    """compressed : the source; indices : (n,) sample indices reconstructed, ascending; k :
    basis vectors used (None: all).  :attr:`btf` is the reconstruction, evaluated lazily."""

    compressed: CompressedBTF
    indices: np.ndarray
    k: int | None

    @property
    def btf(self) -> ReconstructedBTF:
        c = self.compressed
        return ReconstructedBTF(c.sampling.subset(self.indices), c.width, c.height, color_space=c.working_space,
                                interpolated=c.interpolated[self.indices], working_space=c.working_space,
                                ocio_config=c.ocio_config, metadata={"reconstructed_from_k": self.k or c.k},
                                compressed=c, indices=self.indices, k=self.k)


@single_blas_thread
def decompress(compressed: CompressedBTF, options: DecompressOptions | None = None) -> DecompressResult:
    """The reconstruction of ``options.samples`` of ``compressed`` from its first ``options.k``
    basis vectors, checked (UsageError for indices or a k out of range; the memory a written
    chunk needs) but not yet evaluated."""
    options = options or DecompressOptions()
    idx = parse_samples(options.samples, compressed.n_samples)
    if options.k is not None and not (1 <= options.k <= compressed.k):
        raise UsageError(f"--k must be in 1..{compressed.k}")
    k = options.k or compressed.k
    # The k working-space coefficient textures, and a chunk of reconstructions.
    require_memory(compressed.width * compressed.height * 3 * 4 * (k + min(CHUNK, len(idx))), "decompressing")
    return DecompressResult(compressed, idx, options.k)


def write_decompress(result: DecompressResult, path) -> None:
    """Write the reconstruction as a manifest folder at ``path`` (atomically), in the source's
    colour space and bit depth (:func:`usdbtf.compress.decompress.decompress_to_folder`)."""
    from .compress import decompress as folder_writer

    folder_writer.decompress_to_folder(result.compressed, path, samples=result.indices, k=result.k, chunk=CHUNK)
