"""GPU layout of a compressed BTF: one float "tables" texture and RGBA coefficient pages.

The layout is documented texel by texel at the top of ``glsl/btf_core.glsl`` (the shader
that reads it); this module writes it.  Pure arrays in, arrays out:

* ``tables`` (R, TABLE_WIDTH, 4) float32: a header, the basis's de-quantisation (each
  vector's scale and bias: the shader de-quantises, so the asset holds the compressed basis
  itself and nothing else needs to, :func:`unpack`), a point-location table for the view and
  for the light hemisphere (the triangulations of :mod:`usdbtf.render.hemisphere`, so the GPU
  interpolates exactly as the CPU renderer does), the de-quantisation of every pack, the colour
  matrix and the directory of the packs (which page, where).  The blocks are found through the
  header.  Half basis codes (not two bytes of an integer) stay in the tables as schema 3 put
  every basis there: group-major, 4 vectors per texel, one group's S samples after the other,
  last, from the first row of an OpenEXR zip chunk (16 rows), so the file costs the other
  blocks plus the codes compressed on their own.  A level of detail of n < k vectors gets
  tables of its own (``GpuLayout.lod_tables``, issue 39): the same blocks with only its n
  basis vectors and its packs' entries;
* ``basis_page`` (schema 4, integer codes): the codes as 8-bit high and low planes, each
  group's V x L samples as an image (:func:`usdbtf.compress.packs.basis_page`), in page slot
  :data:`BASIS_PAGE`; the basis block's first texel .w is :data:`BASIS_IN_PAGE` (2^23 or 0:
  the codes are in the tables, schema 3 and older, which every reader still takes).  A level
  of detail of n vectors gets its own (``GpuLayout.lod_basis_pages``), so it loads no basis
  vector it does not draw.  Why: Storm reads a 16-bit PNG as 8 bits; the 8-bit page took
  0.713x the schema-3 float32 EXR block of the same codes (metal_flakes, paper sampling, k 190,
  ``benchmarks/probes/basis8_layouts.py``), the smallest of six 8-bit layouts;
* coefficient *packs*, 3 * ceil(k / 4) tiles (H, W, 4): pack ``p = 3 g + c`` holds colour
  channel ``c`` of basis vectors ``4g .. 4g+3`` as the stored integer codes (uint8/uint16)
  or halves, so a page written as PNG/EXR reproduces the compressed values exactly.  Energy
  order makes a level of detail of k' vectors the first ``3 * ceil(k' / 4)`` packs;
* ``pages``: the packs laid out as tiles of at most ``MAX_PAGES - 1`` atlas textures
  (``pages``; the last page slot is the basis page's), so a material binds at most
  ``1 + MAX_PAGES`` = 16 samplers for any k: the
  limit of the GPUs studios preview on (Metal's Hgi allows 31 per stage, GL without bindless
  textures 16 to 32).  A page ends where a level of detail ends (``lods``), so a level loads
  only its own pages, and where the storage type changes.  The shader filters a pack itself
  (bilinear from four texel fetches, wrapped or clamped inside its own tile), so tiles need
  no padding and no sampler state or GPU filter (anisotropy, mip maps) changes a value.

The tables and pages are the packaged asset's one copy of the BTF (issue 39): :func:`unpack`
reads the stored codes back from them, bit for bit, for every CPU consumer.  Why these
layouts (``benchmarks/bench_asset_bytes.py``, paper sampling at 128^2, RESULTS.md): the RGBA
packs were the smallest PNG pages of three layouts (in tall pages: planar single-channel tiles
+8.6..8.7 %, RGB tiles +11..14 %) and need the fewest texel fetches (3 per coefficient, against
12 and 4);
the basis codes group-major in float32 OpenEXR (zip) took 1.58 MB against 2.67 MB sample-major
and 7.28 MB as float32 values (the asset's former 16-bit basis.png: 1.53 MB, which Storm would
read as 8 bits); schema 4's 8-bit basis page takes one page slot (module list above).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..compress.format import CompressedBTF, cross_layout
from ..compress.packs import (MAX_CODE as _MAX_CODE, TABLE_WIDTH, basis_block_bytes, basis_code_offset,
                              basis_codes_group_major, basis_page, basis_page_codes, coefficient_packs as _pack,
                              pack_count, page_breaks, ships_basis_page)
from ..errors import BTFError

__all__ = ["MAX_PAGES", "BASIS_PAGE", "BASIS_IN_PAGE", "page_slots", "PAGE_SIZE", "TABLE_WIDTH", "GpuLayout", "gpu_layout", "pack_count", "page_breaks",
           "page_plan", "with_wrap", "HemisphereTable", "Pages", "PAGE_TEXELS", "unpack", "unpack_lazy", "LazyCodes",
           "storage_dtype", "basis_bytes", "basis_in_page"]

#: Page samplers a material binds: with the tables, 16 samplers, for every k.  Slots 0 ..
#: MAX_PAGES - 2 hold coefficient pages; with an integer basis (schema 4) the last slot,
#: :data:`BASIS_PAGE`, holds the basis codes (``compress.packs.basis_page``).
MAX_PAGES = 15
#: The page slot of the 8-bit basis page (schema 4).
BASIS_PAGE = MAX_PAGES - 1
#: The basis head's code offset (texel basisOffset .w) that says "the codes are in page slot
#: BASIS_PAGE, 8-bit high and low planes" (schema 4); 2^23 (schema 3) or 0 say "in the tables".
BASIS_IN_PAGE = -1.0
#: Largest width and height of a page (texels): what GL 4.x and Metal GPUs all sample.
PAGE_SIZE = 16384
#: Texels a page holds at most while the sampler budget allows more pages: a large atlas's
#: packs spread over several pages, so pages are built and encoded a few at a time, on
#: every CPU (one 16384-texel page of a quilted sphere took 13 s to encode on one core).
PAGE_TEXELS = 4096 * 4096
_GRID = 32
#: Rows of one OpenEXR zip chunk (ZIP_COMPRESSION: 16 scanlines compressed together).
_ZIP_ROWS = 16
_HEADER = 4


def storage_dtype(max_code: float, where: str = "GPU tables") -> np.dtype:
    """The storage type whose largest code is ``max_code`` (what the tables record)."""
    for dtype, code in _MAX_CODE.items():
        if float(max_code) == code:
            return dtype
    raise BTFError(f"{where}: unknown storage type (largest code {max_code!r})")


@dataclass
class GpuLayout:
    """tables : (R, TABLE_WIDTH, 4) float32.  pages : :class:`Pages`, (H, W, 4) arrays (uint8,
    uint16 or float16) built when read, the packs as tiles (module docstring).  k : basis vectors on the
    GPU.  first_packs : the first pack of each page (ascending, first_packs[0] = 0).
    lod_tables : {n: tables of the first n vectors} for each level of detail n < k the layout
    was made for: the same blocks as ``tables`` with only their basis vectors and packs."""

    tables: np.ndarray
    pages: list
    k: int
    first_packs: list
    lod_tables: dict = field(default_factory=dict)
    #: (rows, cols, 4) uint8 basis page of the k vectors (schema 4, page slot BASIS_PAGE), or
    #: None where the tables hold the codes (half codes; schema 3 assets).
    basis_page: np.ndarray | None = None
    #: {n: basis page of the first n vectors} per lower level of detail (as lod_tables).
    lod_basis_pages: dict = field(default_factory=dict)

    def slots(self, n: int | None = None) -> list:
        """The page slots a material binds for the first ``n`` (default k) vectors
        (:func:`page_slots`)."""
        return page_slots(self.pages, self.first_packs, self.k, n, self.basis_page, self.lod_basis_pages)

    def pages_for(self, k: int) -> int:
        """How many pages (from the first) hold the packs of the first ``k`` basis vectors."""
        return sum(1 for first in self.first_packs if first < pack_count(min(k, self.k)))


def page_slots(pages, first_packs: list, k: int, n: int | None, basis, lod_basis: dict) -> list:
    """The MAX_PAGES page slots a material binds for the first ``n`` (default ``k``) of ``k``
    vectors: their coefficient pages (``pages[p]``, those whose first pack is one of theirs)
    from slot 0, their basis page (``basis`` for k, ``lod_basis[n]`` for a lower level, None
    where the tables hold the codes) in slot BASIS_PAGE, None elsewhere.  ``pages`` and the
    basis pages may be arrays or file names (``usd.asset.storm.GpuTextures``)."""
    n = k if n is None else min(int(n), k)
    out = [None] * MAX_PAGES
    for p, first in enumerate(first_packs):
        if first < pack_count(n):
            out[p] = pages[p]
    own = basis if n == k else lod_basis.get(n, basis)
    if own is not None:
        out[BASIS_PAGE] = own
    return out


class _Texels:
    """Appends RGBA texels to a 1-D table; returns the address of each block."""

    def __init__(self):
        self.blocks: list[np.ndarray] = [np.zeros((_HEADER, 4), np.float32)]
        self.size = _HEADER

    def add(self, texels) -> int:
        block = np.asarray(texels, np.float32).reshape(-1, 4)
        address = self.size
        self.blocks.append(block)
        self.size += len(block)
        return address

    def pad_to(self, offset: int, multiple: int) -> None:
        """Zero texels until ``size + offset`` is a multiple of ``multiple``."""
        gap = -(self.size + offset) % multiple
        if gap:
            self.add(np.zeros((gap, 4), np.float32))

    def image(self) -> np.ndarray:
        flat = np.concatenate(self.blocks)
        rows = -(-len(flat) // TABLE_WIDTH)
        out = np.zeros((rows * TABLE_WIDTH, 4), np.float32)
        out[:len(flat)] = flat
        return out.reshape(rows, TABLE_WIDTH, 4)


@dataclass
class HemisphereTable:
    """Point location over one triangulated hemisphere, as texels (see btf_core.glsl)."""

    origin: np.ndarray        # (2,) disc coordinates of the grid's corner
    cell: float               # cell size, disc units
    candidates: np.ndarray    # (grid, grid, 4 * texels) triangle ids, -1 = none
    triangles: np.ndarray     # (T, 3, 4) texels per triangle
    boundary: np.ndarray      # (E, 2, 4) texels per boundary edge

    @classmethod
    def from_triangulation(cls, tri) -> "HemisphereTable":
        """From a :class:`usdbtf.render.hemisphere.Triangulation`."""
        pts, tris = tri.points, tri.triangles
        origin = pts.min(axis=0) - 1e-6
        cell = (float(np.max(pts.max(axis=0) - origin)) + 2e-6) / _GRID
        lists = [[[] for _ in range(_GRID)] for _ in range(_GRID)]
        corners = pts[tris]                                           # (T, 3, 2)
        if len(tris):
            lo = np.floor((corners.min(axis=1) - origin) / cell).astype(int).clip(0, _GRID - 1)
            hi = np.floor((corners.max(axis=1) - origin) / cell).astype(int).clip(0, _GRID - 1)
            for t, ((x0, y0), (x1, y1)) in enumerate(zip(lo, hi)):
                for gy in range(y0, y1 + 1):
                    for gx in range(x0, x1 + 1):
                        lists[gy][gx].append(t)
        depth = max(1, max(len(c) for row in lists for c in row))
        width = 4 * -(-depth // 4)
        candidates = np.full((_GRID, _GRID, width), -1.0, np.float32)
        for gy in range(_GRID):
            for gx in range(_GRID):
                candidates[gy, gx, :len(lists[gy][gx])] = lists[gy][gx]
        texels = np.zeros((len(tris), 3, 4), np.float64)
        if len(tris):
            a = corners[:, 0]
            inverse = np.linalg.inv(np.stack([corners[:, 1] - a, corners[:, 2] - a], axis=2))   # (T, 2, 2)
            texels[:, 0] = np.c_[a, tris[:, 0], tris[:, 1]]
            texels[:, 1] = inverse.reshape(-1, 4)
            texels[:, 2, 0] = tris[:, 2]
        edges = tri.boundary if len(tri.boundary) else np.zeros((1, 2), np.int64)   # one direction: a point
        bound = np.zeros((len(edges), 2, 4), np.float64)
        bound[:, 0] = np.c_[pts[edges[:, 0]], pts[edges[:, 1]]]
        bound[:, 1, :2] = edges
        return cls(origin, cell, candidates, texels, bound)

    def write(self, table: _Texels) -> int:
        """Append to ``table``; returns the address of this hemisphere's header."""
        grid_at = table.add(self.candidates)
        tri_at = table.add(self.triangles) if len(self.triangles) else table.size
        bound_at = table.add(self.boundary)
        return table.add([[self.origin[0], self.origin[1], self.cell, _GRID],
                          [self.candidates.shape[2] // 4, len(self.triangles), len(self.boundary), 0],
                          [grid_at, tri_at, bound_at, 0]])


def page_plan(n_packs: int, width: int, height: int, breaks: list[int], dtypes=None):
    """Where ``n_packs`` tiles of ``width`` x ``height`` texels go: a new page at every break
    (pack index), at every change of storage type (``dtypes``, one per pack) and when a page
    is full (``PAGE_SIZE``); tiles fill a page column by column, in as few columns as
    ``PAGE_SIZE`` rows allow (tall pages: smaller PNG files).  Returns ([(first pack, end, columns, rows)] per page, directory (P, 4):
    page, tile column x0, tile row y0 (image rows from the top), 0; :func:`gpu_layout` sets the
    fourth to the largest code of the pack's storage type)."""
    if height > PAGE_SIZE or width > PAGE_SIZE:
        raise BTFError(f"coefficient textures of {width}x{height} texels do not fit a {PAGE_SIZE}-texel GPU page")
    # As many tiles as PAGE_TEXELS holds, more where the page count must stay in the sampler
    # budget: every segment between breaks may end in a part-filled page.
    fit = (PAGE_SIZE // width) * (PAGE_SIZE // height)
    segments = 1 + len([b for b in breaks if 0 < b < n_packs])
    spread = -(-n_packs // max(1, BASIS_PAGE - segments))
    per_page = min(fit, max(1, PAGE_TEXELS // (width * height), spread))
    dtypes = [None] * n_packs if dtypes is None else list(dtypes)
    plan, start = [], 0
    directory = np.zeros((n_packs, 4), np.float32)
    for p in range(1, n_packs + 1):
        if p < n_packs and p not in breaks and dtypes[p] == dtypes[start] and p - start < per_page:
            continue
        n = p - start
        # As few tile columns as the page height allows, filled column by column: a PNG row
        # then runs through one tile (or a few), whose texels its filters predict from; square
        # pages of 128^2 tiles took 5.1-5.5 % more bytes (benchmarks/RESULTS.md, issue 39).
        cols = -(-n // (PAGE_SIZE // height))
        rows = -(-n // cols)
        for j in range(n):
            directory[start + j] = [len(plan), (j // rows) * width, (j % rows) * height, 0]
        plan.append((start, p, cols, rows))
        start = p
    return plan, directory


class Pages(Sequence):
    """The coefficient pages, each built when it is read (``pages[i]``, iteration): a quilt's
    pages are atlas-sized, and a writer that encodes them a few at a time holds only those.

    packs : the packs (H, W, 4) or, with ``gather`` (a quilt's
    :meth:`usdbtf.quilt.texels.QuiltTexels.gather`), (1, N, 4) packs of its compact source
    texels, each gathered to ``shape`` (H, W) straight into its tile; plan, directory : as
    :func:`page_plan` returns them."""

    def __init__(self, packs: list, plan: list, directory: np.ndarray, shape, gather=None):
        self._packs, self._plan, self._directory = packs, plan, directory
        self._shape, self._gather = shape, gather

    def __len__(self) -> int:
        return len(self._plan)

    def dtype(self, i: int) -> np.dtype:
        """The dtype of page ``i`` (its packs'), without building it."""
        return self._packs[self._plan[i][0]].dtype

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        first, end, cols, rows = self._plan[i]
        h, w = self._shape
        page = np.zeros((rows * h, cols * w, 4), self._packs[first].dtype)
        for p in range(first, end):
            _, x0, y0, _ = (int(v) for v in self._directory[p])
            page[y0:y0 + h, x0:x0 + w] = self._packs[p] if self._gather is None else self._gather(self._packs[p])
        return page


def _pages(packs: list, breaks: list[int], gather=None, shape=None) -> tuple[Pages, list, np.ndarray]:
    """``packs`` laid out on pages as :func:`page_plan` says (see :class:`Pages`).  Returns
    (pages, first pack of each page, directory)."""
    h, w = shape if gather is not None else packs[0].shape[:2]
    plan, directory = page_plan(len(packs), w, h, breaks, [p.dtype for p in packs])
    return Pages(packs, plan, directory, (h, w), gather), [first for first, *_ in plan], directory


def gpu_layout(cbtf: CompressedBTF, k: int | None = None, lods=(), wrap: str = "clamp",
               texels=None) -> GpuLayout:
    """The tables texture and coefficient pages for the first ``k`` (default all) basis
    vectors of ``cbtf``, which must sample every light at every view; pages break where the
    levels of detail ``lods`` (basis counts) end; ``wrap`` ("clamp" or "repeat"): how the
    shader filters at a tile's edges.  ``texels`` (a :class:`usdbtf.quilt.texels.QuiltTexels`
    of ``cbtf``): the packs are made from its compact source texels and gathered through its
    index (the same codes, without every quilt-sized pack in memory at once)."""
    from ..render.hemisphere import Triangulation   # OpenCV: imported only when needed

    layout = cross_layout(cbtf.sampling)
    if layout is None:
        raise BTFError("the GPU preview needs every light at every view (a V x L sampling, view-major); "
                       f"this BTF's {cbtf.n_samples} samples are not")
    if wrap not in ("clamp", "repeat"):
        raise BTFError(f"wrap must be 'clamp' or 'repeat', got {wrap!r}")
    V, L = layout
    k = min(cbtf.k if k is None else k, cbtf.k)
    views = Triangulation.from_directions(cbtf.sampling.view[::L], "view directions")
    lights = Triangulation.from_directions(cbtf.sampling.light[:L], "light directions")
    breaks = page_breaks(k, lods)
    if texels is None:
        packs, scales, biases = _pack(cbtf, k, breaks)
        pages, first_packs, directory = _pages(packs, breaks)
    else:
        packs, scales, biases = _pack(texels.compact, k, breaks)
        pages, first_packs, directory = _pages(packs, breaks, texels.gather, (cbtf.height, cbtf.width))
    if len(pages) > BASIS_PAGE:
        raise BTFError(f"k = {k} coefficient textures of {cbtf.width}x{cbtf.height} texels need {len(pages)} GPU "
                       f"pages; a material binds at most {BASIS_PAGE} beside its basis (use a smaller k or texture)")

    directory[:, 3] = [_MAX_CODE[np.dtype(pages.dtype(page))] for page in directory[:, 0].astype(int)]
    hemispheres = (HemisphereTable.from_triangulation(views), HemisphereTable.from_triangulation(lights))

    def tables_for(n: int) -> np.ndarray:
        return _tables(cbtf, n, (V, L), hemispheres, scales, biases, directory, wrap)

    # A level of detail's own tables and basis page: the basis and the packs' entries of its n
    # vectors only, so a lower lod loads no basis vector it does not draw (issue 39).
    levels = sorted({int(n) for n in lods if 0 < n < k}, reverse=True)
    in_page = ships_basis_page(cbtf)
    return GpuLayout(tables_for(k), pages, k, first_packs, {n: tables_for(n) for n in levels},
                     basis_page(cbtf.basis.pixels[:, :k, 0], V, L) if in_page else None,
                     {n: basis_page(cbtf.basis.pixels[:, :n, 0], V, L) for n in levels} if in_page else {})


def _tables(cbtf: CompressedBTF, k: int, cross: tuple[int, int], hemispheres: tuple, scales: np.ndarray,
            biases: np.ndarray, directory: np.ndarray, wrap: str) -> np.ndarray:
    """The tables texture (R, TABLE_WIDTH, 4) of the first ``k`` vectors: header, their basis
    block, the view and light ``hemispheres`` (HemisphereTable), the de-quantisation
    (``scales``, ``biases``: (P, 4) per pack) and ``directory`` (P, 4) rows of their packs
    (the first ``pack_count(k)``), the colour matrix (module docstring)."""
    V, L = cross
    groups = -(-k // 4)
    packs = pack_count(k)
    table = _Texels()
    view_at = hemispheres[0].write(table)
    light_at = hemispheres[1].write(table)
    dequant_at = table.add(np.stack([scales[:packs], biases[:packs]], axis=1))
    matrix_at = table.add(np.c_[np.asarray(cbtf.color_matrix, np.float64), np.zeros(3)])
    directory_at = table.add(directory[:packs])
    # Codes in the tables (half codes) last, from the first row of an OpenEXR zip chunk: the
    # file is then the other blocks' chunks plus the codes' chunks, each compressed alone, so
    # the tables of a level of n vectors cost the codes of its n vectors (basis_bytes(t, n))
    # plus blocks no larger than the full tables' (its share, usdbtf.usd.asset.lod).
    in_page = ships_basis_page(cbtf)
    if not in_page:
        table.pad_to(-(1 + 2 * groups), _ZIP_ROWS * TABLE_WIDTH)
    basis_at = table.add(_basis_block(cbtf, k, groups, in_page))
    image = table.image()
    flat = image.reshape(-1, 4)
    flat[0] = [TABLE_WIDTH, V, L, groups]
    flat[1] = [k, basis_at, view_at, light_at]
    flat[2] = [dequant_at, matrix_at, *cbtf.domain.shader_code]
    flat[3] = [directory_at, cbtf.width, cbtf.height, 1.0 if wrap == "repeat" else 0.0]
    if table.size >= 2**24:
        raise BTFError(f"GPU tables need {table.size} texels; addresses must stay below 2^24 (float precision)")
    return image


def _basis_block(cbtf: CompressedBTF, k: int, groups: int, in_page: bool = False) -> np.ndarray:
    """The tables' basis block (texels, 4): (largest code of its storage type, S, groups,
    offset), then per group g the scale and the bias of vectors 4g..4g+3 (float32, as
    ``CompressedBTF.basis_values`` rounds them), then the stored codes plus ``offset``
    (:func:`usdbtf.compress.packs.basis_code_offset`) group-major (texel 1 + 2 groups + g S + s:
    vectors 4g..4g+3 of sample s; vectors past k are code 0).  ``in_page`` (schema 4): no
    codes; offset :data:`BASIS_IN_PAGE` (they are in the basis page)."""
    b = cbtf.basis
    S = cbtf.n_samples
    dtype = np.dtype(b.pixels.dtype)
    if dtype not in _MAX_CODE:
        raise BTFError(f"basis stored as {dtype}: the GPU tables hold uint8, uint16 or half codes")
    scale = np.zeros(groups * 4, np.float32)
    bias = np.zeros(groups * 4, np.float32)
    scale[:k], bias[:k] = b.scale[:k], b.bias[:k]
    head = np.array([[_MAX_CODE[dtype], S, groups, BASIS_IN_PAGE if in_page else basis_code_offset(dtype)]],
                    np.float32)
    dequant = np.stack([scale.reshape(groups, 4), bias.reshape(groups, 4)], axis=1).reshape(-1, 4)
    return np.concatenate([head, dequant] + ([] if in_page else [basis_codes_group_major(cbtf, k)]))


def basis_in_page(tables: np.ndarray) -> bool:
    """Whether ``tables`` (as written) say their basis codes are in the basis page (schema 4)."""
    flat = np.asarray(tables, np.float32).reshape(-1, 4)
    return float(flat[int(flat[1, 1]), 3]) == BASIS_IN_PAGE


def basis_bytes(tables: np.ndarray, n: int | None = None) -> int:
    """Bytes of the first ``n`` (default all) basis vectors' stored codes read from a tables
    texture, encoded alone as the tables encode them: group-major, float32 OpenEXR zip in rows
    of TABLE_WIDTH texels, vectors past ``n`` in its last group 0 (what
    :func:`usdbtf.compress.packs.shipped_basis_bytes` measures on a compressed BTF).  What the
    full lod spends on the basis of vectors ``n+1..k`` is ``basis_bytes(t) - basis_bytes(t, n)``
    (a lower lod's share, :func:`usdbtf.usd.asset.lod.lod_share`).  Deterministic.  Tables
    whose codes are in the basis page (:func:`basis_in_page`) hold none: the page files' own
    bytes are what a level spends there."""
    if basis_in_page(tables):
        raise BTFError("GPU tables: the basis codes are in the basis page (count its file's bytes)")
    flat = np.asarray(tables, np.float32).reshape(-1, 4)
    groups, stored_k, basis_at = int(flat[0, 3]), int(flat[1, 0]), int(flat[1, 1])
    n = stored_k if n is None else min(int(n), stored_k)
    S, used, offset = int(flat[basis_at, 1]), -(-n // 4), flat[basis_at, 3]
    at = basis_at + 1 + 2 * groups
    block = flat[at:at + used * S].copy().reshape(used, S, 4)
    block[used - 1, :, n - 4 * (used - 1):] = offset         # code 0
    return basis_block_bytes(block.reshape(-1, 4))


def _codes(values: np.ndarray, max_code: float, where: str, normalised: bool = True) -> np.ndarray:
    """Stored codes from texel values as a texture file holds them: integer pixels as they
    are; floats (EXR, or a tiled conversion) as the normalised read code / max_code (the
    codes themselves when not ``normalised``: the tables' basis), or half values (max_code 1).
    BTFError unless they are exactly codes of that storage type."""
    dtype = storage_dtype(max_code, where)
    if values.dtype.kind in "ui":
        if values.dtype != dtype and not (dtype == np.uint16 and values.dtype == np.uint8):
            raise BTFError(f"{where}: {values.dtype} texels where the tables say {dtype} codes")
        return values.astype(dtype)
    if dtype == np.float16:
        codes = values.astype(np.float16)
        exact = np.array_equal(codes.astype(np.float64), values.astype(np.float64))
    else:
        scaled = values.astype(np.float64) * (max_code if normalised else 1.0)
        codes_f = np.rint(scaled)
        exact = bool(np.all(np.abs(scaled - codes_f) < 0.25)) and codes_f.min(initial=0) >= 0 \
            and codes_f.max(initial=0) <= max_code
        codes = codes_f.astype(dtype)
    if not exact:
        raise BTFError(f"{where}: texels are not {dtype} codes (a lossy re-encode?)")
    return codes


class LazyCodes(Sequence):
    """The ``k`` coefficient code textures of :func:`unpack`, each assembled from its three
    packs when asked for (``codes[i]``, (h, w, 3)): a reader that wants one at a time (the
    renderer building a mip level plane by plane) never holds them all.

    pages : a sequence whose item ``i`` reads page ``i`` (e.g. caching the last one: walked in
    order, each page is then decoded once per pass).  The last group's three packs are kept
    (the four vectors of a group share them); :meth:`release` drops them and, where ``pages``
    has one, calls its ``release``.  Values are bit for bit :func:`unpack`'s."""

    def __init__(self, flat: np.ndarray, directory_at: int, width: int, height: int, k: int, pages):
        self._flat, self._directory_at, self._k, self._pages = flat, directory_at, k, pages
        self._shape = (height, width)
        self._group: tuple[int, list] | None = None
        #: Packs read (page, pack) so far: what a test counts.
        self.reads: list[tuple[int, int]] = []

    def __len__(self) -> int:
        return self._k

    @property
    def shape(self) -> tuple[int, int]:
        """(h, w) texels of each texture (from the tables: nothing read)."""
        return self._shape

    def _tiles(self, g: int) -> list[np.ndarray]:
        if self._group is None or self._group[0] != g:
            self._group = None                   # the last group's packs go before this one's are cut
            h, w = self._shape
            tiles = []
            for c in range(3):
                p = 3 * g + c
                page, x0, y0, code = self._flat[self._directory_at + p]
                if int(page) >= len(self._pages):
                    raise BTFError(f"coefficient pack {p} is on page {int(page)}; {len(self._pages)} page(s) given")
                tile = np.asarray(self._pages[int(page)])[int(y0):int(y0) + h, int(x0):int(x0) + w]
                if tile.shape[:2] != (h, w) or tile.ndim != 3 or tile.shape[2] != 4:
                    raise BTFError(f"page {int(page)} does not hold coefficient pack {p} ({w}x{h} RGBA tile)")
                tiles.append(_codes(tile, float(code), f"page {int(page)}"))   # a new array: the page may go
                self.reads.append((int(page), p))
            self._group = (g, tiles)
        return self._group[1]

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        if not 0 <= i < self._k:
            raise IndexError(i)
        tiles = self._tiles(i // 4)
        return np.stack([t[:, :, i % 4] for t in tiles], axis=2).astype(np.result_type(*tiles))

    def release(self) -> None:
        self._group = None
        if hasattr(self._pages, "release"):
            self._pages.release()


def _directory(tables: np.ndarray, k: int | None, basis_page=None):
    """(flat tables (N, 4), k, basis codes (S, k, 1), directory address, width, height);
    ``basis_page``: the 8-bit basis page (or a callable returning it) where the tables say
    the codes are in it (schema 4)."""
    flat = np.asarray(tables, np.float32).reshape(-1, 4)
    if len(flat) < _HEADER:
        raise BTFError("GPU tables: too small for a header")
    groups, stored_k = int(flat[0, 3]), int(flat[1, 0])
    k = stored_k if k is None else int(k)
    if not 1 <= k <= stored_k:
        raise BTFError(f"GPU tables hold {stored_k} basis vectors, {k} asked for")
    basis_at, directory_at = int(flat[1, 1]), int(flat[3, 0])
    width, height = int(flat[3, 1]), int(flat[3, 2])
    max_code, S, block_groups = float(flat[basis_at, 0]), int(flat[basis_at, 1]), int(flat[basis_at, 2])
    # 2^23 for integer codes (schema 3), 0 before and for halves; BASIS_IN_PAGE: in the basis page (schema 4)
    offset = float(flat[basis_at, 3])
    if block_groups != groups:
        raise BTFError("GPU tables: the basis block does not match the header (written by an older usdbtf?)")
    dtype = storage_dtype(max_code, "GPU tables basis")
    if offset == BASIS_IN_PAGE and dtype != np.float16:
        if basis_page is None:
            raise BTFError("GPU tables: the basis codes are in the basis page, and none was given")
        page = basis_page() if callable(basis_page) else basis_page
        V, L = int(flat[0, 1]), int(flat[0, 2])
        # 8-bit texels as a PNG holds them, or floats byte / 255 (a tiled EXR conversion)
        codes = basis_page_codes(_codes(np.asarray(page), 255.0, "GPU basis page"), V, L, k, groups)
        if codes.max(initial=0) > max_code:
            raise BTFError(f"GPU basis page: codes above {max_code:g} for {dtype} storage")
        return flat, k, codes.astype(dtype)[:, :, None], directory_at, width, height
    if offset not in (0.0, basis_code_offset(dtype)):
        raise BTFError(f"GPU tables: basis code offset {offset!r} (written by a newer usdbtf?)")
    at = basis_at + 1 + 2 * groups
    codes = flat[at:at + groups * S].reshape(groups, S, 4).transpose(1, 0, 2).reshape(S, groups * 4)[:, :k]
    codes = codes.astype(np.float64) - offset
    basis = _codes(codes, max_code, "GPU tables basis", normalised=False)
    return flat, k, basis[:, :, None], directory_at, width, height


def unpack_lazy(tables: np.ndarray, pages, k: int | None = None, basis_page=None) -> tuple[np.ndarray, LazyCodes]:
    """As :func:`unpack`, the coefficient codes a :class:`LazyCodes` (nothing read from
    ``pages`` yet)."""
    flat, k, basis, directory_at, width, height = _directory(tables, k, basis_page)
    return basis, LazyCodes(flat, directory_at, width, height, k, pages)


def unpack(tables: np.ndarray, pages: list, k: int | None = None,
           basis_page=None) -> tuple[np.ndarray, list[np.ndarray]]:
    """The stored codes :func:`gpu_layout` packed, read back from its textures.

    Parameters
    ----------
    tables : (R, TABLE_WIDTH, 4) float32, the tables texture as written.
    pages : the first pages, (H, W, 4) arrays as read from their files (uint8 codes, or floats:
        code / largest code, or halves); enough of them for the ``k`` vectors asked for.
    k : basis vectors to read (default all the tables hold).
    basis_page : (rows, cols, 4) uint8, the basis page (page slot BASIS_PAGE) of these tables,
        or a callable returning it: needed where the tables say the codes are in it (schema 4,
        integer codes); tables that hold the codes themselves (schema 3, halves) ignore it.

    Returns
    -------
    (basis (S, k, 1) codes in their storage type, k coefficient textures (h, w, 3) codes):
    bit for bit what the compressed BTF stored (a uint8 texture packed beside uint16 ones comes
    back as uint16 holding the same values: reconstructions are identical).
    """
    basis, codes = unpack_lazy(tables, pages, k, basis_page)
    # LazyCodes reads a group's three packs once for its four vectors: the same lookups, checks
    # and values as reading pack by pack (a uint8 pack beside uint16 ones promotes the texture).
    return basis, list(codes)


def with_wrap(layout: GpuLayout, wrap: str) -> GpuLayout:
    """``layout`` with its tiles filtered as ``wrap`` ("clamp" or "repeat"; tables texel 3.w)."""
    if wrap not in ("clamp", "repeat"):
        raise BTFError(f"wrap must be 'clamp' or 'repeat', got {wrap!r}")
    tables = layout.tables.copy()
    tables.reshape(-1, 4)[3, 3] = 1.0 if wrap == "repeat" else 0.0
    lod_tables = {n: t.copy() for n, t in layout.lod_tables.items()}
    for t in lod_tables.values():
        t.reshape(-1, 4)[3, 3] = tables.reshape(-1, 4)[3, 3]
    return GpuLayout(tables, layout.pages, layout.k, layout.first_packs, lod_tables, layout.basis_page,
                     layout.lod_basis_pages)
