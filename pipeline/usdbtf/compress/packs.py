"""The pure layout of the coefficient packs the packaged asset ships, and what they cost.

A pack ``p = 3 g + c`` is an (H, W, 4) tile holding colour channel ``c`` of coefficient
layers ``4g .. 4g+3`` as their stored integer codes (uint8/uint16) or halves; the GPU
pages of the packaged asset (``usdbtf.gpu.tables``, which lays these packs out as tiles of
atlas pages, and ``usdbtf.usd.asset.storm.add_gpu_textures``, which encodes the pages) are these
packs and nothing else.  This module sits in ``compress`` so that rate control can measure
the bytes it ships without importing ``gpu`` (layers: docs/architecture.md).

What :func:`shipped_pack_bytes` and :func:`shipped_basis_bytes` measure (issue 39): each pack
encoded on its own exactly as the asset encodes a page (8-bit: RGBA PNG, :func:`encode_png_page`; 16-bit: float32 code / 65535 and half: as they are, OpenEXR zip), and the
basis codes as the asset ships them: integer codes as the 8-bit basis page, the asset's
``gpu/basis.png`` byte for byte (schema 4, :func:`basis_page`); half codes group-major as
float32 OpenEXR zip in rows of the tables' width, as ``gpu/tables.exr`` holds them.  The packs
are a probe, not the asset's files: the asset's pages hold several packs each (one PNG stream
per page; issue 39 measured per-pack PNG totals within 2.4..3.5 % of the paged files on
metal_flakes with libpng level 6, and the paged files 1.02x the per-pack total with the run-length
encoder; rate control calibrates the ratio by packaging).
"""
from __future__ import annotations

import numpy as np

from ..errors import BTFError

__all__ = ["MAX_CODE", "pack_count", "coefficient_packs", "shipped_pack_bytes", "shipped_basis_bytes",
           "basis_codes_group_major", "basis_block_bytes", "BASIS_CODE_OFFSET", "basis_code_offset", "encode_png_page",
           "pack_bytes_by_k", "default_lods", "page_breaks", "ShippedPacks", "BASIS_PAGE_ROWS", "basis_page",
           "basis_page_codes", "basis_page_column", "basis_page_bytes", "ships_basis_page", "PNG_DATA_CHUNK_BYTES"]

#: Largest code of each storage type: what a GPU's normalised read divides by.
MAX_CODE = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0, np.dtype(np.float16): 1.0}
#: Width (texels) of the rows the tables texture holds the basis codes in (gpu.tables.TABLE_WIDTH).
TABLE_WIDTH = 512


def pack_count(k: int) -> int:
    """Coefficient packs (RGBA tiles) holding the first ``k`` basis vectors."""
    return 3 * -(-k // 4)


def default_lods(k: int) -> list[int]:
    """Levels of detail for ``k`` vectors: k, then halvings down to no fewer than 4 (what
    ``package`` writes unless told otherwise; ``usd.asset.lod`` names them)."""
    levels, n = [], k // 2
    while n >= 4 and len(levels) < 3:
        levels.append(n)
        n //= 2
    return levels


def page_breaks(k: int, lods=()) -> list[int]:
    """Pack indices where a page must begin: where each level of detail in ``lods`` (basis
    counts) ends, so that a level's packs fill whole pages."""
    return sorted({pack_count(n) for n in lods if 0 < n < k})


def _range_dtype(layers, first: int) -> np.dtype:
    """The storage type of packs holding ``layers`` (Stored, the first being layer ``first``):
    the widest of their codes; BTFError for types that cannot share a texture."""
    dtypes = {np.dtype(st.pixels.dtype) for st in layers}
    dtype = np.dtype(np.float16) if np.dtype(np.float16) in dtypes else \
        np.dtype(np.uint16) if np.dtype(np.uint16) in dtypes else np.dtype(np.uint8)
    if not dtypes <= set(MAX_CODE) or (np.dtype(np.float16) in dtypes and len(dtypes) > 1):
        raise BTFError(f"coefficient textures {first}..{first + len(layers) - 1}: cannot pack storage "
                       f"types {sorted(str(d) for d in dtypes)} into one texture")
    return dtype


def _ranges(k: int, breaks: list[int]) -> list[tuple[int, int]]:
    """(first group, end group) of each run of packs that shares one storage type."""
    groups = -(-k // 4)
    bounds = sorted({0, groups, *(b // 3 for b in breaks)})
    return list(zip(bounds, bounds[1:]))


def coefficient_packs(cbtf, k: int, breaks: list[int]) -> tuple[list, np.ndarray, np.ndarray]:
    """Coefficient packs of the first ``k`` layers of ``cbtf`` (a CompressedBTF), a list of
    (H, W, 4) arrays, plus per-pack (scale, bias), each (P, 4), for normalised GPU reads.  The
    packs between two ``breaks`` (pack indices: where pages must begin) share one storage
    type, the widest of their codes (uint8 codes in a uint16 pack keep their values: the
    scale follows the type), so storage types never split a level's pages.  Layers past
    ``k`` in a group's last pack are 0."""
    packs, scales, biases = [], [], []
    for start, end in _ranges(k, breaks):
        dtype = _range_dtype(cbtf.coefficients[4 * start:min(4 * end, k)], 4 * start)
        for g in range(start, end):
            for c in range(3):
                pix = np.zeros((cbtf.height, cbtf.width, 4), dtype)
                scale, bias = np.zeros(4), np.zeros(4)
                for j, st in enumerate(cbtf.coefficients[4 * g:min(4 * g + 4, k)]):
                    pix[:, :, j] = st.pixels[:, :, c]
                    scale[j], bias[j] = float(st.scale[c]) * MAX_CODE[dtype], float(st.bias[c])
                packs.append(pix)
                scales.append(scale)
                biases.append(bias)
    return packs, np.asarray(scales), np.asarray(biases)


def encode_png_page(pixels: np.ndarray) -> bytes:
    """An 8-bit RGBA page or pack (H, W, 4) as the asset's PNG: libpng's adaptive row filter
    and zlib's run-length strategy (:func:`~usdbtf.imageio.encode_png_rle`; 0.908x the bytes of
    the earlier OIIO level-6 encoding on the pages and basis pages of two paper-scale assets,
    the same pixels).  Alpha is the fourth coefficient layer, not coverage: stored as it is,
    unassociated (Storm's PNG reader takes the file's values as they are)."""
    from ..imageio import encode_png_rle

    return encode_png_rle(pixels)


def _encode_pack(pixels: np.ndarray) -> bytes:
    """One pack (H, W, 4) encoded as the asset encodes a page of it (usd.asset.storm.add_gpu_textures)."""
    from ..imageio import encode_image

    if pixels.dtype != np.uint8:
        if pixels.dtype == np.uint16:
            pixels = (pixels.astype(np.float64) / 65535.0).astype(np.float32)
        return encode_image(pixels, "exr", color_space="data", attributes={"compression": "zip"})
    return encode_png_page(pixels)


def shipped_pack_bytes(cbtf, k: int | None = None) -> list[int]:
    """Bytes of each coefficient pack of the first ``k`` (default all) layers, encoded on its
    own as the asset encodes pages (module docstring): a list of ``pack_count(k)`` ints, pack
    ``3 g + c`` at index ``3 g + c``.  The first ``k'`` layers ship ``sum(result[:pack_count(k')])``:
    a group of four layers shares its three packs, so the shipped bytes grow in steps of
    four layers.  Deterministic (same codes -> same bytes)."""
    k = min(cbtf.k if k is None else k, cbtf.k)
    packs, _, _ = coefficient_packs(cbtf, k, [])
    return [len(_encode_pack(p)) for p in packs]


def pack_bytes_by_k(per_pack, k: int) -> np.ndarray:
    """(k,) int64 shipped pack bytes of the first 1..k layers from :func:`shipped_pack_bytes`'s
    per-pack bytes (at least ``pack_count(k)`` of them): element ``n - 1`` is the sum of the
    first ``pack_count(n)`` packs, a partial group's three packs counted fully (they ship
    whole), so the result is constant over each group of four layers and steps at 1, 5, 9, ...
    What rate control adds to the basis's bytes for a budget of the asset's files."""
    per_pack = np.asarray(per_pack, np.int64)
    if len(per_pack) < pack_count(k):
        raise ValueError(f"{len(per_pack)} packs measured; the first {k} layers need {pack_count(k)}")
    totals = np.cumsum(per_pack)
    return totals[np.array([pack_count(n) for n in range(1, k + 1)], np.int64) - 1]


class ShippedPacks:
    """Shipped bytes of the coefficient packs of ``cbtf``'s first k layers, for any k, as the
    asset with its default levels of detail ships them: each run of packs between the page
    breaks of :func:`default_lods` (k) in the widest storage type of its codes (a 16-bit first
    level makes PNG pages EXR ones, so the bytes of a pack depend on k), a partial last group
    with its missing layers zero.  Each distinct pack (group, channel, type, layers) is
    encoded once (:func:`_encode_pack`) and remembered: calling it for many k costs the packs
    that change."""

    def __init__(self, cbtf):
        self.cbtf = cbtf
        self._bytes: dict = {}

    def __call__(self, k: int) -> int:
        cbtf = self.cbtf
        k = min(k, cbtf.k)
        total = 0
        for start, end in _ranges(k, page_breaks(k, default_lods(k))):
            dtype = _range_dtype(cbtf.coefficients[4 * start:min(4 * end, k)], 4 * start)
            for g in range(start, end):
                n = min(4, k - 4 * g)
                for c in range(3):
                    key = (g, c, dtype.str, n)
                    if key not in self._bytes:
                        pix = np.zeros((cbtf.height, cbtf.width, 4), dtype)
                        for j in range(n):
                            pix[:, :, j] = cbtf.coefficients[4 * g + j].pixels[:, :, c]
                        self._bytes[key] = len(_encode_pack(pix))
                    total += self._bytes[key]
        return total


#: Added to integer basis codes in the GPU tables (schema version 3, issue 39): 2^23 + code
#: (code < 2^16) is exact in float32 with one exponent for every code, so the texel's bytes
#: are the code's own (fixed point) and OpenEXR zip compresses them 8.8 % smaller than the
#: bare codes, whose exponent follows their magnitude (k 190 paper-scale basis: 853,328
#: against 935,306 bytes, benchmarks/history/packaging.md, "Issue 39: the shipped codec").  Readers subtract it (the basis
#: block's first texel .w; 0 in older tables and for half codes, which are not integers).
BASIS_CODE_OFFSET = 2.0 ** 23


def basis_code_offset(dtype) -> float:
    """What the GPU tables add to basis codes of storage type ``dtype``: BASIS_CODE_OFFSET for
    integer codes, 0 for halves."""
    return 0.0 if np.dtype(dtype) == np.float16 else BASIS_CODE_OFFSET


def basis_codes_group_major(cbtf, k: int) -> np.ndarray:
    """The stored basis codes of the first ``k`` vectors, group-major as the GPU tables hold
    them: (ceil(k/4) * S, 4) float32, row ``g S + s`` = vectors 4g..4g+3 of sample s, each
    code plus :func:`basis_code_offset` (vectors past k are code 0 plus it).  Exact: integer
    codes below 2^16 plus 2^23 are below 2^24; halves as they are."""
    S = cbtf.n_samples
    groups = -(-k // 4)
    offset = basis_code_offset(cbtf.basis.pixels.dtype)
    codes = np.full((S, groups * 4), offset, np.float32)
    codes[:, :k] = cbtf.basis.pixels[:, :k, 0].astype(np.float64) + offset
    return codes.reshape(S, groups, 4).transpose(1, 0, 2).reshape(-1, 4)


def shipped_basis_bytes(cbtf, k: int | None = None) -> int:
    """Bytes of the first ``k`` (default all) basis vectors' codes as the packaged asset ships
    them: integer codes on a V x L sampling as the 8-bit basis page (``gpu/basis.png``, schema
    4, :func:`basis_page_bytes`: the file itself); half codes (or another sampling) group-major
    as float32 OpenEXR zip in rows of TABLE_WIDTH texels (the basis block of ``gpu/tables.exr``
    without the tables' other blocks; the last row padded with zeros).  Deterministic."""
    k = min(cbtf.k if k is None else k, cbtf.k)
    if ships_basis_page(cbtf):
        return basis_page_bytes(cbtf, k)
    return basis_block_bytes(basis_codes_group_major(cbtf, k))


def ships_basis_page(cbtf) -> bool:
    """Whether the packaged asset ships ``cbtf``'s basis codes as the 8-bit basis page (schema
    4: integer codes on a V x L sampling) rather than in the GPU tables (half codes, which are
    not two bytes of an integer)."""
    from .format import cross_layout

    return np.dtype(cbtf.basis.pixels.dtype) != np.float16 and cross_layout(cbtf.sampling) is not None


def basis_block_bytes(block: np.ndarray) -> int:
    """Bytes of group-major basis code texels ``block`` (N, 4) float32 encoded alone as the GPU
    tables encode them: float32 OpenEXR zip in rows of TABLE_WIDTH texels, the last row padded
    with zeros.  Deterministic."""
    from ..imageio import encode_image

    rows = -(-len(block) // TABLE_WIDTH)
    image = np.zeros((rows * TABLE_WIDTH, 4), np.float32)
    image[:len(block)] = block
    return len(encode_image(image.reshape(rows, TABLE_WIDTH, 4), "exr", color_space="data",
                            attributes={"compression": "zip"}))


#: Image rows a column of groups of the 8-bit basis page fills at most (a GPU page's height,
#: ``gpu.tables.PAGE_SIZE``): groups past it start a new column of ``lights`` texels.
BASIS_PAGE_ROWS = 16384


def basis_page(codes: np.ndarray, views: int, lights: int) -> np.ndarray:
    """Integer basis codes as an 8-bit RGBA image Storm reads exactly: the packaged asset's
    basis page (``gpu/basis.png``, schema 4; Storm reads a 16-bit PNG as 8 bits, so each code
    is two bytes).

    Parameters
    ----------
    codes : (S, n) integer codes, 0 <= code < 2^16, S = views * lights samples view-major
        (sample ``v * lights + l``).
    views, lights : V and L of the cross sampling.

    Returns
    -------
    (rows, columns, 4) uint8: group g (vectors 4g..4g+3 in RGBA; vectors past n code 0) as a
    V x L image of the high bytes above a V x L image of the low bytes (image rows from the
    top: views down, lights across, so PNG's 2-D filters predict each byte from its
    neighbouring directions), groups down a column, then the next column to the right: as
    few columns as BASIS_PAGE_ROWS rows allow (``BASIS_PAGE_ROWS // (2 V)`` groups each),
    evenly filled (:func:`basis_page_column`: a nearly empty last column beside a full one
    cost 11 % more bytes, metal_flakes 64^2 k 365).  The layout
    measured smallest of six (``benchmarks/probes/basis8_layouts.py``: 0.713x the schema-3
    float32 EXR block at k 190 on metal_flakes, paper sampling, 32^2).
    """
    codes = np.asarray(codes)
    S, n = codes.shape
    if S != views * lights:
        raise BTFError(f"basis page: {S} samples are not {views} views x {lights} lights")
    if codes.size and (codes.min() < 0 or codes.max() >= 2**16):
        raise BTFError("basis page: codes must lie in 0..65535")
    groups = -(-n // 4)
    per_column = basis_page_column(groups, views)
    # uint16 (the codes' range, checked above), not int64: a paper-scale page at k 242 held
    # ~100 MB of int64 temporaries inside rate control's packagings (issue 42's 1.2 GB).
    padded = np.zeros((S, groups * 4), np.uint16)
    padded[:, :n] = codes
    planes = padded.reshape(views, lights, groups, 4).transpose(2, 0, 1, 3)            # (G, V, L, 4)
    stacked = np.concatenate([(planes >> 8).astype(np.uint8), (planes & 255).astype(np.uint8)],
                             axis=1)                                                    # (G, 2V, L, 4)
    columns = -(-groups // per_column)
    rows = 2 * views * min(groups, per_column)
    image = np.zeros((rows, columns * lights, 4), np.uint8)
    for g in range(groups):
        y0, x0 = (g % per_column) * 2 * views, (g // per_column) * lights
        image[y0:y0 + 2 * views, x0:x0 + lights] = stacked[g]
    return image


def basis_page_column(groups: int, views: int) -> int:
    """Groups per column of a basis page of ``groups`` groups (:func:`basis_page`): the
    columns as few as BASIS_PAGE_ROWS rows allow, evenly filled.  The shader computes the same
    from the tables' group count (glsl/btf_core.glsl, btfShadeLight)."""
    most = BASIS_PAGE_ROWS // (2 * views)
    if most < 1:
        raise BTFError(f"basis page: {views} views do not fit {BASIS_PAGE_ROWS} rows")
    columns = max(1, -(-groups // most))
    return max(1, -(-groups // columns))


def basis_page_codes(image: np.ndarray, views: int, lights: int, n: int, groups: int | None = None) -> np.ndarray:
    """The (S, n) int64 codes of the first ``n`` vectors :func:`basis_page` laid out, read back
    from its image (rows, columns, 4) of 8-bit values (uint8 as a PNG reads back); ``groups``:
    the groups the page holds (default ceil(n / 4)), which decide its columns; BTFError if it
    is too small."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 4:
        raise BTFError(f"basis page: expected 8-bit RGBA texels, got {image.dtype} {image.shape}")
    wanted = -(-n // 4)
    per_column = basis_page_column(wanted if groups is None else groups, views)
    out = np.zeros((wanted, views, lights, 4), np.int64)
    for g in range(wanted):
        y0, x0 = (g % per_column) * 2 * views, (g // per_column) * lights
        block = image[y0:y0 + 2 * views, x0:x0 + lights].astype(np.int64)
        if block.shape[:2] != (2 * views, lights):
            raise BTFError(f"basis page of {image.shape[1]}x{image.shape[0]} texels does not hold group {g}")
        out[g] = block[:views] * 256 + block[views:]
    return out.transpose(1, 2, 0, 3).reshape(views * lights, wanted * 4)[:, :n]


#: Bytes the packaged asset adds to every PNG it writes: a gAMA chunk of 1.0 (12 bytes of
#: chunk framing, 4 of data) that marks the pixels as data (``usd.asset.textures.png_as_data``).
PNG_DATA_CHUNK_BYTES = 16


def basis_page_bytes(cbtf, k: int | None = None) -> int:
    """Bytes of the first ``k`` (default all) basis vectors' integer codes as :func:`basis_page`
    encoded by :func:`encode_png_page`, plus the chunk the asset adds (PNG_DATA_CHUNK_BYTES):
    the size of a schema-4 asset's ``gpu/basis.png``.  Deterministic."""
    from .format import cross_layout

    if not ships_basis_page(cbtf):
        raise BTFError("basis page: needs integer codes on a V x L sampling")
    k = min(cbtf.k if k is None else k, cbtf.k)
    return len(encode_png_page(basis_page(cbtf.basis.pixels[:, :k, 0], *cross_layout(cbtf.sampling)))) + PNG_DATA_CHUNK_BYTES
