"""The data blocks of the four Bonn BTF formats, parsed into lazy decoders.

Each ``parse_*`` reads a format's header and block table from a :class:`~.binary.Cursor`
(checking every count against the file size and the header) and returns a decoder whose
``channels(samples, t0, t1)`` multiplies out the stored channel values of some samples
over texels ``t0 .. t1`` -- before the colour model is inverted -- as channel planes
(nC, n, t1 - t0) float32: the colour model then runs on contiguous planes.  Nothing large is read at
parse time: blocks are memory-mapped views.

Index conventions (cgbonn/btflib ``decode_*_texture.m``; 0-based here):

* sample s = v nL + l (view-major: all lights of view 0 first), v and l the positions in
  the file's view and light tables;
* texel t = y W + x, row y = 0 the image's *top* row (btflib keeps file row 0 on top;
  zeroeffects/btf and btf-extractor flip the rows);
* channel c of a (channel, ...) interleaved block is the fastest index.

Layouts after the common header (all row-major, scalars of the block's ``scalar size``):

``DFMF`` (decorrelated full matrix factorisation; btflib ``read_ubo_dfmf.m``)
    uint32 k_max, int32 colour model, float32[3] colour mean, float32[3][3] colour matrix;
    per channel: uint8 scalar size, uint32 k, uint32 rows, uint32 cols, S[k], U[rows][k],
    SxV[cols][k].  Channel values X = U SxV^T; rows = nL nV (U over samples, the usual
    arrangement) or W H (U over texels).
``FMF`` (full matrix factorisation; ``read_ubo_fmf.m``)
    ("12FCE" signatures) uint8 header version; >= 1: uint32 dynamic-range reduction;
    >= 2: uint32 w, h and a w x h half-float height map.  Then uint32 k, uint8 scalar
    size, uint32 k (again), uint32 rows, uint32 cols, S[k], U[rows][k], SxV[cols][k] with
    rows = nC nL nV (row c + nC s) or nC W H (row c + nC t): one factorisation of all channels.
``PVF`` (per-view PCA; ``read_ubo_pvf.m``)
    uint32 k, uint32 view slots (a legacy variant puts int32 301074, k, W, H, slots before
    a bare direction table); per view: uint8 scalar size, uint32 k, uint32 weights,
    uint32 dimension, eigenvalues[k], mean[dimension], C[dimension][k], W[weights][k];
    dimension = nC nL (weights over texels) or nC W H (weights over lights).
``BDI`` (bidirectional images, uncompressed; ``read_ubo_bdi.m``)
    uint32 width, height, scan lines per chunk, uint8 compression (0 full, 2 sparse;
    1 = bzip2 is not supported, as in btflib), uint8 mask[H][W] (byte y W + x: the layout
    btflib's writer produces), rotations; then chunks of ``W x lines`` ABRDFs, each chunk
    a uint32 byte count and half floats [abrdf][nV][nL][nC].  A sparse BDI stores only the
    texels whose mask byte is non-zero, in texel order; the others decode as 0.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .binary import (BonnHeader, Cursor, read_common_header, read_directions, read_meta, read_rotations,
                     read_size)
from .color_models import check_model

__all__ = ["ChannelFactors", "Factorisation", "FactorDecoder", "PVFDecoder", "BDIDecoder", "PARSERS"]

_PVF_LEGACY_MAGIC = 301074
_FINITE_CHUNK = 1 << 24  # values per finiteness check: bounded temporaries on any file size


def _check_finite(array: np.ndarray, cur: Cursor, block: str) -> None:
    """Raise BTFError naming ``block`` (and the first bad row) if ``array`` holds NaN or Inf."""
    flat = array.reshape(-1) if array.flags.c_contiguous else np.ascontiguousarray(array).reshape(-1)
    for a in range(0, flat.size, _FINITE_CHUNK):
        part = flat[a:a + _FINITE_CHUNK]
        if not np.isfinite(part).all():
            first = a + int(np.argmax(~np.isfinite(part)))
            row = first // array.shape[-1] if array.ndim > 1 else first
            raise cur.fail(block, f"holds NaN or Inf (first at row {row})")


def _end_of_data(cur: Cursor) -> None:
    if cur.pos != cur.size:
        raise cur.fail("end of data", f"{cur.size - cur.pos} unexpected bytes after the last block "
                                      f"(offset {cur.pos}); the header and the blocks disagree")


# --------------------------------------------------------------------------- factorisations


@dataclass(frozen=True)
class ChannelFactors:
    """One channel's factors: its values are ``samples @ texels.T`` (S x T).

    samples : (S, k) stored dtype, memory-mapped (possibly a strided view); row s = v nL + l.
    texels : (T, k) stored dtype; row t = y W + x, y = 0 the top row.
    singular_values : (k,) as stored (already folded into one of the two sides).
    blocks : (sample block, texel block) names in the file, for messages.
    """

    samples: np.ndarray
    texels: np.ndarray
    singular_values: np.ndarray
    blocks: tuple = ("", "")

    @property
    def k(self) -> int:
        return self.samples.shape[1]


@dataclass
class Factorisation:
    """A file's factors, exposed so that transcoding can work on them without expanding images.

    kind : "DFMF" (one factorisation per decorrelated channel) or "FMF" (one for all
        channels: the channels share one side, and each takes every nC-th row of the other).
    channels : per colour channel, :class:`ChannelFactors`.
    color_model, color_mean, color_matrix : the decorrelation to invert after multiplying out
        (see :mod:`.color_models`); model 0 for FMF.
    dynamic_range_reduction : FMF's flag: the channels hold log(value + eps).
    """

    kind: str
    channels: tuple
    color_model: int = 0
    color_mean: np.ndarray = field(default_factory=lambda: np.zeros(3))
    color_matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    dynamic_range_reduction: int = 0
    _float: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def component_counts(self) -> list[int]:
        return [ch.k for ch in self.channels]

    def float32(self, c: int, side: str) -> np.ndarray:
        """Channel c's ``side`` ("samples" or "texels") as contiguous float32, converted once
        and kept (memory in proportion to the factors, not to the images)."""
        src = getattr(self.channels[c], side)
        key = id(src)  # FMF's shared side is one object: converted once for all channels
        if key not in self._float:
            self._float[key] = np.ascontiguousarray(src, dtype=np.float32)
        return self._float[key]

    def expand(self, samples: np.ndarray, t0: int, t1: int) -> np.ndarray:
        """(nC, n, t1 - t0) float32 channel planes of ``samples`` over texels t0..t1.

        Products are computed on fixed, aligned tiles (:data:`SAMPLE_TILE` samples x
        :data:`TEXEL_TILE` texels) whatever the request, so a value does not depend on
        which other samples or rows were asked for with it: any chunking of a pass over
        the data reads bit-identical values."""
        nc = len(self.channels)
        out = np.empty((nc, len(samples), t1 - t0), np.float32)
        n_samples = self.channels[0].samples.shape[0]
        for j, rows, local in _tiles_of(samples, SAMPLE_TILE):
            s0, s1 = j * SAMPLE_TILE, min((j + 1) * SAMPLE_TILE, n_samples)
            for a in range(t0 - t0 % TEXEL_TILE, t1, TEXEL_TILE):
                b = min(a + TEXEL_TILE, self.channels[0].texels.shape[0])
                lo, hi = max(a, t0), min(b, t1)
                for c in range(nc):
                    tile = self.float32(c, "samples")[s0:s1] @ self.float32(c, "texels")[a:b].T
                    out[c, rows, lo - t0:hi - t0] = tile[local, lo - a:hi - a]
        return out


#: Fixed tile sizes of every product (see :meth:`Factorisation.expand`).
SAMPLE_TILE = 128
TEXEL_TILE = 8192


def _tiles_of(samples: np.ndarray, size: int):
    """Yield (tile j, positions in ``samples`` that fall in it, their offsets in the tile)."""
    tiles = samples // size
    for j in np.unique(tiles):
        rows = np.flatnonzero(tiles == j)
        yield int(j), rows, samples[rows] - j * size


class FactorDecoder:
    """Decoder of a DFMF or FMF file: channel values are products of the factors."""

    def __init__(self, factors: Factorisation):
        self.factors = factors

    def channels(self, samples: np.ndarray, t0: int, t1: int) -> np.ndarray:
        return self.factors.expand(samples, t0, t1)

    def check_finite(self, cur: Cursor) -> None:
        seen = set()
        for ch in self.factors.channels:
            for arr, block in ((ch.samples, ch.blocks[0]), (ch.texels, ch.blocks[1])):
                if id(arr) not in seen:
                    seen.add(id(arr))
                    _check_finite(arr, cur, block)

    def describe(self) -> dict:
        f = self.factors
        return {"components": f.component_counts, "scalar": _scalar_name(f.channels[0].samples.dtype),
                "color_model": f.color_model, "dynamic_range_reduction": f.dynamic_range_reduction}


def _scalar_name(dtype) -> str:
    return {2: "half", 4: "float", 8: "double"}[np.dtype(dtype).itemsize]


def _orientation(rows: int, cols: int, n_samples: int, n_texels: int, cur: Cursor, block: str) -> bool:
    """True when U runs over samples (rows = S), False when over texels; else BTFError.
    When S == T both fit and btflib takes U over samples; so does this."""
    if rows == n_samples and cols == n_texels:
        return True
    if rows == n_texels and cols == n_samples:
        return False
    raise cur.fail(block, f"matrix is {rows} x {cols}, but the header's {n_samples} samples "
                          f"(lights x views) and {n_texels} texels (width x height) need "
                          f"{n_samples} x {n_texels} or {n_texels} x {n_samples}")


def parse_dfmf(cur: Cursor, h: BonnHeader) -> FactorDecoder:
    read_common_header(cur, h)
    block = "DFMF header"
    k_max = cur.u32(block)
    model = cur.i32(block)
    mean = cur.f32(3, block)
    matrix = cur.f32(9, block).reshape(3, 3)
    check_model(model, f"{cur.path}: {block}")
    if not (np.isfinite(mean).all() and np.isfinite(matrix).all()):
        raise cur.fail(block, "colour mean or matrix holds NaN or Inf")
    S, T = h.n_views * h.n_lights, h.width * h.height
    channels = []
    for c in range(h.n_channels):
        b = f"channel {c} factor block"
        dtype = cur.scalar_type(cur.u8(b), b)
        k, rows, cols = cur.u32(b), cur.u32(b), cur.u32(b)
        if k == 0 or k > k_max:
            raise cur.fail(b, f"component count {k} disagrees with the header's maximum of {k_max}")
        over_samples = _orientation(rows, cols, S, T, cur, b)
        sv = cur.array(dtype, (k,), f"{b} (singular values)")
        u = cur.array(dtype, (rows, k), f"{b} (U)")
        sxv = cur.array(dtype, (cols, k), f"{b} (S*V)")
        names = (f"{b} (U)", f"{b} (S*V)")
        channels.append(ChannelFactors(u, sxv, sv, names) if over_samples
                        else ChannelFactors(sxv, u, sv, names[::-1]))
    _end_of_data(cur)
    return FactorDecoder(Factorisation("DFMF", tuple(channels), model, mean, matrix))


def parse_fmf(cur: Cursor, h: BonnHeader) -> FactorDecoder:
    read_common_header(cur, h)
    block = "FMF header"
    version = cur.u8(block) if h.header_flag else 0
    drr = cur.u32(block) if version >= 1 else 0
    if version >= 2:
        hw, hh = cur.u32(block), cur.u32(block)
        cur.skip(2 * hw * hh, f"{block} (height map)")
    if version >= 3:
        raise cur.fail(block, f"unknown header version {version} (btflib reads 0..2)")
    k0 = cur.u32(block)
    b = "factor block"
    dtype = cur.scalar_type(cur.u8(b), b)
    k, rows, cols = cur.u32(b), cur.u32(b), cur.u32(b)
    if k != k0 or k == 0:
        raise cur.fail(b, f"component count {k} disagrees with the header's {k0}")
    nc, S, T = h.n_channels, h.n_views * h.n_lights, h.width * h.height
    if rows % nc:
        raise cur.fail(b, f"{rows} rows are not a multiple of the {nc} channels")
    over_samples = _orientation(rows // nc, cols, S, T, cur, b)
    sv = cur.array(dtype, (k,), f"{b} (singular values)")
    u = cur.array(dtype, (rows, k), f"{b} (U)")
    sxv = cur.array(dtype, (cols, k), f"{b} (S*V)")
    _end_of_data(cur)
    names = (f"{b} (U)", f"{b} (S*V)")
    channels = tuple(ChannelFactors(u[c::nc], sxv, sv, names) if over_samples
                     else ChannelFactors(sxv, u[c::nc], sv, names[::-1]) for c in range(nc))
    return FactorDecoder(Factorisation("FMF", channels, dynamic_range_reduction=drr))


# --------------------------------------------------------------------------- per-view PCA


class PVFDecoder:
    """Per view v: values = C W^T + mean, over texels or over lights (see module docstring)."""

    def __init__(self, views: list, n_channels: int, n_lights: int, over_texels: bool):
        self.views = views            # per view: (eigenvalues, mean, C, W, block name)
        self.nc = n_channels
        self.nl = n_lights
        self.over_texels = over_texels

    def channels(self, samples: np.ndarray, t0: int, t1: int) -> np.ndarray:
        # Per view and fixed texel tile, every light at once: fixed GEMM shapes, so values do
        # not depend on the request (as in Factorisation.expand).
        nc, nl = self.nc, self.nl
        out = np.empty((nc, len(samples), t1 - t0), np.float32)
        for v, rows, lights in _tiles_of(samples, nl):
            _, mean, comp, weights, _ = self.views[v]
            n_texels = (len(weights) if self.over_texels else len(comp) // nc)
            for a in range(t0 - t0 % TEXEL_TILE, t1, TEXEL_TILE):
                b = min(a + TEXEL_TILE, n_texels)
                lo, hi = max(a, t0), min(b, t1)
                if self.over_texels:   # C rows c + nC l; weights over texels
                    vals = weights[a:b].astype(np.float32) @ comp.astype(np.float32).T + mean.astype(np.float32)
                    vals = vals.reshape(b - a, nl, nc).transpose(2, 1, 0)              # (nC, nL, texels)
                else:                  # C rows c + nC t; weights over lights
                    vals = comp[nc * a:nc * b].astype(np.float32) @ weights.astype(np.float32).T
                    vals += mean[nc * a:nc * b, None].astype(np.float32)
                    vals = vals.reshape(b - a, nc, nl).transpose(1, 2, 0)              # (nC, nL, texels)
                out[:, rows, lo - t0:hi - t0] = vals[:, lights, lo - a:hi - a]
        return out

    def check_finite(self, cur: Cursor) -> None:
        for ev, mean, comp, weights, block in self.views:
            for arr, part in ((mean, "mean"), (comp, "components"), (weights, "weights")):
                _check_finite(arr, cur, f"{block} ({part})")

    def describe(self) -> dict:
        return {"components": [int(v[2].shape[1]) for v in self.views], "scalar": _scalar_name(self.views[0][2].dtype),
                "color_model": 0, "dynamic_range_reduction": 0}


def parse_pvf(cur: Cursor, h: BonnHeader) -> PVFDecoder:
    cur.need(4, "PVF header")
    legacy = int(cur.data[cur.pos:cur.pos + 4].view("<i4")[0]) == _PVF_LEGACY_MAGIC
    block = "PVF header"
    if legacy:
        cur.skip(4, block)
        k_file = cur.u32(block)
        h.width, h.height = cur.u32(block), cur.u32(block)
        slots = cur.u32(block)
        read_directions(cur, h)
        if h.width == 0 or h.height == 0:
            raise cur.fail(block, f"{h.width}x{h.height} texels")
    else:
        read_common_header(cur, h)
        k_file, slots = cur.u32(block), cur.u32(block)
    if slots != h.n_views:
        raise cur.fail(block, f"{slots} view slots for the header's {h.n_views} views")
    nc, nl, T = h.n_channels, h.n_lights, h.width * h.height
    views, over_texels = [], None
    for v in range(slots):
        b = f"view {v} PCA block"
        dtype = cur.scalar_type(cur.u8(b), b)
        k, n_weights, dim = cur.u32(b), cur.u32(b), cur.u32(b)
        if k == 0 or k > k_file:
            raise cur.fail(b, f"component count {k} disagrees with the header's {k_file}")
        if dim == nc * nl and n_weights == T:
            this = True
        elif dim == nc * T and n_weights == nl:
            this = False
        else:
            raise cur.fail(b, f"dimension {dim} and {n_weights} weights fit neither {nc * nl} x {T} "
                              f"(channels x lights, texels) nor {nc * T} x {nl} (channels x texels, lights)")
        if over_texels is not None and this != over_texels:
            raise cur.fail(b, "arranged differently from view 0")
        over_texels = this
        ev = cur.array(dtype, (k,), f"{b} (eigenvalues)")
        mean = cur.array(dtype, (dim,), f"{b} (mean)")
        comp = cur.array(dtype, (dim, k), f"{b} (components)")
        weights = cur.array(dtype, (n_weights, k), f"{b} (weights)")
        views.append((ev, mean, comp, weights, b))
    _end_of_data(cur)
    return PVFDecoder(views, nc, nl, bool(over_texels))


# --------------------------------------------------------------------------- raw ABRDFs


class BDIDecoder:
    """Uncompressed ABRDF chunks; a sample image gathers one value per ABRDF from every chunk."""

    def __init__(self, chunks: list, per_chunk: int, storage: np.ndarray | None, n_lights: int):
        self.chunks = chunks          # (n_abrdf, nV, nL, nC) float16 views, in storage order
        self.per_chunk = per_chunk    # ABRDFs per full chunk
        self.storage = storage        # (T,) storage index of texel t, -1 missing; None = full
        self.nl = n_lights

    def channels(self, samples: np.ndarray, t0: int, t1: int) -> np.ndarray:
        v_idx, l_idx = np.divmod(samples, self.nl)
        nc = self.chunks[0].shape[-1]
        out = np.zeros((nc, len(samples), t1 - t0), np.float32)
        if self.storage is None:
            present = np.arange(t0, t1)
            s0, count = t0, t1 - t0
        else:
            present = t0 + np.flatnonzero(self.storage[t0:t1] >= 0)
            if present.size == 0:
                return out
            s0, count = int(self.storage[present[0]]), len(present)
        got = np.empty((count, len(samples), nc), np.float32)   # ABRDF-major, as stored
        pos = 0
        while pos < count:
            j, off = divmod(s0 + pos, self.per_chunk)
            n = min(count - pos, self.chunks[j].shape[0] - off)
            got[pos:pos + n] = self.chunks[j][off:off + n][:, v_idx, l_idx, :]
            pos += n
        out[:, :, present - t0] = got.transpose(2, 1, 0)
        return out

    def check_finite(self, cur: Cursor) -> None:
        """Not at open: a BDI holds every image (tens of GB); values are checked when read."""

    def describe(self) -> dict:
        stored = sum(c.shape[0] for c in self.chunks)
        return {"components": None, "scalar": "half", "color_model": 0, "dynamic_range_reduction": 0,
                "stored_texels": stored}


def parse_bdi(cur: Cursor, h: BonnHeader) -> BDIDecoder:
    read_meta(cur, h)
    read_directions(cur, h)
    read_size(cur, h)
    block = "BDI header"
    lines = cur.u32(block)
    if lines == 0:
        raise cur.fail(block, "0 scan lines per chunk")
    compression = cur.u8(block) if h.header_flag else 1
    if compression not in (0, 2):
        raise cur.fail(block, f"compression {compression} is not supported (0 = full and 2 = sparse "
                              "uncompressed are; 1 = bzip2 is not, in btflib either)")
    mask = cur.array(np.dtype(np.uint8), (h.height * h.width,), f"{block} (mask)")
    read_rotations(cur, h)
    nc, nv, nl = h.n_channels, h.n_views, h.n_lights
    if compression == 0:
        storage, stored = None, h.width * h.height
    else:
        present = mask != 0
        stored = int(present.sum())
        storage = np.where(present, np.cumsum(present) - 1, -1).astype(np.int64)
    per_chunk = h.width * lines
    abrdf_bytes = nc * nv * nl * 2
    chunks = []
    for j in range(-(-stored // per_chunk)):
        b = f"chunk {j}"
        n = min(per_chunk, stored - j * per_chunk)
        nbytes = cur.u32(b)
        if nbytes != n * abrdf_bytes:
            raise cur.fail(b, f"holds {nbytes} bytes; {n} ABRDFs of {nv} x {nl} x {nc} half floats need "
                              f"{n * abrdf_bytes}")
        chunks.append(cur.array(np.dtype("<f2"), (n, nv, nl, nc), b))
    _end_of_data(cur)
    return BDIDecoder(chunks, per_chunk, storage, nl)


PARSERS = {"DFMF": parse_dfmf, "FMF": parse_fmf, "PVF": parse_pvf, "BDI": parse_bdi}
