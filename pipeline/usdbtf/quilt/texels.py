"""A quilted compressed BTF as copies of its source's texels: per-texel work done once.

A quilt copies source texels: every output texel holds the stored codes of the source texel
its position map (``quilt_positions.exr``, :mod:`.folder`) names.  Anything derived texel by
texel from the codes (the UsdPreviewSurface fit, the GPU packs, encoded maps) is therefore
the same at every copy of a source texel, so it is computed once per distinct source texel
(a few thousand) and gathered through the map (millions of atlas texels).

:func:`quilt_texels` reads the map of a quilted folder and returns a :class:`QuiltTexels`:
a *compact* compressed BTF, one row of the distinct source texels (taken from the quilt's
own codes, so the source folder is not needed), and the (H, W) index of each quilt texel
into it.  It returns None -- and the caller takes the per-texel path -- for a BTF that is
not a quilt, a quilt without a position map (written before the map existed), a map that
does not fit the textures, or a lossy codec (a re-encoded quilt's codes are no longer its
source's).  The map is checked against the codes themselves, so an answer gathered through
it is the answer computed per texel.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..compress.codecs import Stored, get_codec
from ..compress.format import CompressedBTF
from ..compress.parallel import in_threads
from ..errors import BTFError
from .folder import POSITION_MAP

__all__ = ["QuiltTexels", "quilt_texels", "distinct_texels"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class QuiltTexels:
    """A quilt's texels as its distinct source texels.

    compact : CompressedBTF, 1 x N texels: each distinct source texel once (its codes, scale
        and bias as the quilt stores them; no encoded bytes).
    index : (H, W) int32, the quilt texel's texel in ``compact`` (its column).
    """

    compact: CompressedBTF
    index: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the quilt."""
        return self.index.shape

    def multiplicity(self) -> np.ndarray:
        """(N,) float64: how many quilt texels each of ``compact``'s texels stands for."""
        return np.bincount(self.index.reshape(-1), minlength=self.compact.width * self.compact.height).astype(np.float64)

    def gather(self, values: np.ndarray) -> np.ndarray:
        """(H, W, ...) per quilt texel from ``values`` (1, N, ...): an image of ``compact``."""
        values = np.asarray(values)
        return np.take(values.reshape(values.shape[1], *values.shape[2:]), self.index, axis=0)


def distinct_texels(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, index): ``first`` (N,) the flat position of a texel of each distinct key (in key
    order), ``index`` (same shape as ``keys``, int32) each texel's distinct key number.

    ``keys`` are non-negative integers; when they are dense (a quilt's source texel numbers)
    this is two passes over a table of them instead of a sort of millions of texels."""
    flat = keys.ravel()
    size = int(flat.max()) + 1 if flat.size else 0
    if size > 4 * flat.size + 1024:                   # sparse keys: sort
        _, first, inverse = np.unique(flat, return_index=True, return_inverse=True)
        return first, inverse.reshape(keys.shape).astype(np.int32)
    present = np.zeros(size, bool)
    present[flat] = True
    number = (np.cumsum(present) - 1).astype(np.int32)
    some = np.empty(size, np.int64)
    # Which copy a key keeps does not matter: the codes of all its copies are checked equal.
    some[flat] = np.arange(flat.size)
    return some[present], number[keys]


def _map_keys(pixels: np.ndarray) -> np.ndarray | None:
    """(H, W) int64 source texel keys ``row * (max column + 1) + column`` from the position
    map's pixels (R column, G row), or None when they are not non-negative integers below
    2^24 (a damaged map)."""
    x, y = pixels[..., 0], pixels[..., 1]
    for c in (x, y):
        if not (np.isfinite(c).all() and c.min() >= 0 and c.max() < 2**24 and (c == np.floor(c)).all()):
            return None
    return y.astype(np.int64) * (int(x.max()) + 1) + x.astype(np.int64)


def _texel_bytes(pixels: np.ndarray) -> np.ndarray:
    """(H*W,) void view of (H, W, C) pixels: one element per texel (its C codes' bytes), so a
    gather moves texels, not single codes."""
    flat = np.ascontiguousarray(pixels).reshape(-1, pixels.shape[-1])
    return flat.view(np.dtype((np.void, flat.shape[1] * flat.itemsize))).ravel()


def _codes_agree(cbtf: CompressedBTF, first: np.ndarray, index: np.ndarray) -> bool:
    """True when every coefficient texture's codes equal, at every texel, the codes of its
    distinct texel (one pass over the codes, a texture per thread at a time)."""
    flat_index = index.ravel()

    def agree(st) -> bool:
        texels = _texel_bytes(st.pixels)
        return np.array_equal(texels[first][flat_index].view(np.uint8), texels.view(np.uint8))

    return all(in_threads(agree, cbtf.coefficients))


def quilt_texels(cbtf: CompressedBTF, folder) -> QuiltTexels | None:
    """The :class:`QuiltTexels` of ``cbtf`` read from the quilted folder ``folder``, or None
    (module docstring: a debug message says why a quilt is processed per texel)."""
    from ..imageio import read_image

    if "quilt" not in cbtf.info:
        return None
    where = f"{folder}" if folder is not None else "the quilted BTF in memory"
    path = Path(folder) / POSITION_MAP if folder is not None else None
    if path is None or not path.is_file():
        log.debug(f"{where}: a quilt without a position map ({POSITION_MAP}); fitting the fallback and "
                  "packing the GPU textures texel by texel")
        return None
    if not get_codec(cbtf.codec).lossless:
        log.debug(f"{where}: {cbtf.codec} codes were re-encoded when quilted, so they are not copies of "
                  "the source's; per-texel work runs on every texel")
        return None
    try:
        pixels, _ = read_image(path)
    except BTFError as exc:            # the map only saves work: without it the answer is the same
        log.warning(f"{exc}; per-texel work runs on every texel")
        return None
    keys = _map_keys(pixels) if pixels.shape[:2] == (cbtf.height, cbtf.width) else None
    if keys is None:
        log.warning(f"{path}: not a position map of this {cbtf.width}x{cbtf.height} quilt; per-texel work "
                    "runs on every texel")
        return None
    first, index = distinct_texels(keys)
    if not _codes_agree(cbtf, first, index):
        log.warning(f"{path}: the coefficient codes are not copies of the texels this map names; per-texel "
                    "work runs on every texel")
        return None
    compact = replace(cbtf, width=len(first), height=1, encoded=None, curve=None, coefficients=[
        Stored(st.pixels.reshape(-1, st.pixels.shape[-1])[first][None], st.scale, st.bias)
        for st in cbtf.coefficients])
    log.debug(f"{where}: {cbtf.width}x{cbtf.height} texels copy {len(first)} source texels; per-texel work "
              "runs on those and is gathered through the position map")
    return QuiltTexels(compact, index)
