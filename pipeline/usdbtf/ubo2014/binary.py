"""Bounded little-endian reading of Bonn's binary BTF files: signature, meta data, directions.

Every read is checked against the file's size before it happens, so a damaged header
(a count of 4 billion views, a truncated block) is one BTFError naming the file, the
block and the offset -- never a huge allocation or a short read.  Large blocks are not
read at all: :meth:`Cursor.array` returns a read-only view of a memory map.

File layout (all little-endian; cgbonn/btflib ``read_common_header.m``,
``read_meta_data.m``, ``read_bidir_sampling.m``; zeroeffects/btf ``btf.hh``)::

    signature          "!DFMF08FCR", "!FMF12FCER", ... (see SIGNATURES), no terminator
    meta data          uint32 size (bytes of this block, itself included), uint32 version,
                       char[80] measurement setup, char[80] image sensor, char[80] light source,
                       float32 ppmm (pixels per mm), float32[3] RGB scale factor,
                       version > 1: uint32 cosine flag,
                       version > 2: uint32 n, char[n] measurement XML,
                       version > 3: uint32 channels, per channel uint32 n, char[n] name
    directions         uint32 nV; per view: float32 theta, phi (radians), uint32 nL,
                       float32[nL][2] light theta, phi (the same list for every view)
    size               uint32 width, uint32 height
    rotations          (signatures ending in "R") uint32 n, float32[n][3][3]
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import BTFError

__all__ = ["SIGNATURES", "MAX_SIGNATURE", "Cursor", "BonnHeader", "sniff_signature", "read_meta",
           "read_directions", "read_common_header"]

#: Every signature a public reference reader accepts -> (format, header flag).  The flag is
#: btflib's: FMF "12FCE" files carry an extended header, the BDI signature a compression byte.
#: btflib lists "!DFMF08FCR" and "!FMF12FCER" only; zeroeffects/btf also reads them without
#: the trailing "R" (no rotation block), so both spellings are accepted.
SIGNATURES = {
    "!DFMF08FCR": ("DFMF", False),
    "!DFMF08FC": ("DFMF", False),
    "!FMF12FCER": ("FMF", True),
    "!FMF12FCE": ("FMF", True),
    "!FMF06FCR": ("FMF", False),
    "!FMF06FC": ("FMF", False),
    "!PVF06FCR": ("PVF", False),
    "!PVF06FC": ("PVF", False),
    "!BDIF06R2!": ("BDI", True),
}
MAX_SIGNATURE = max(map(len, SIGNATURES))
_SCALAR_TYPES = {2: np.dtype("<f2"), 4: np.dtype("<f4"), 8: np.dtype("<f8")}


def sniff_signature(head: bytes) -> str | None:
    """The longest known signature ``head`` starts with (btflib's rule), or None."""
    best = None
    for sig in SIGNATURES:
        if head.startswith(sig.encode("ascii")) and (best is None or len(sig) > len(best)):
            best = sig
    return best


class Cursor:
    """A read position in ``path`` with every access checked against the file size.

    ``block`` arguments name the part of the file being read; they appear in errors.
    """

    def __init__(self, path: Path, data: np.ndarray):
        self.path = path
        self.data = data            # the whole file, a read-only uint8 memory map
        self.size = int(data.size)
        self.pos = 0

    def fail(self, block: str, problem: str) -> BTFError:
        return BTFError(f"{self.path}: {block}: {problem}")

    def need(self, nbytes: int, block: str) -> None:
        if nbytes < 0 or self.pos + nbytes > self.size:
            raise self.fail(block, f"truncated: needs {nbytes} bytes at offset {self.pos}, "
                                   f"but the file ends at {self.size}")

    def bytes(self, n: int, block: str) -> bytes:
        self.need(n, block)
        out = self.data[self.pos:self.pos + n].tobytes()
        self.pos += n
        return out

    def _unpack(self, fmt: str, block: str):
        n = struct.calcsize(fmt)
        return struct.unpack(fmt, self.bytes(n, block))

    def u8(self, block: str) -> int:
        return self._unpack("<B", block)[0]

    def u32(self, block: str) -> int:
        return self._unpack("<I", block)[0]

    def i32(self, block: str) -> int:
        return self._unpack("<i", block)[0]

    def f32(self, count: int, block: str) -> np.ndarray:
        return np.frombuffer(self.bytes(4 * count, block), "<f4").astype(np.float64)

    def text(self, n: int, block: str) -> str:
        return self.bytes(n, block).split(b"\0", 1)[0].decode("latin-1").strip()

    def scalar_type(self, size: int, block: str) -> np.dtype:
        try:
            return _SCALAR_TYPES[size]
        except KeyError:
            raise self.fail(block, f"scalar size {size} bytes is not 2 (half), 4 (float) or 8 (double)") from None

    def array(self, dtype: np.dtype, shape: tuple, block: str) -> np.ndarray:
        """A read-only (memory-mapped) view of the next ``prod(shape)`` values; no copy."""
        count = int(np.prod(shape, dtype=object))
        nbytes = count * dtype.itemsize
        self.need(nbytes, block)
        view = self.data[self.pos:self.pos + nbytes].view(dtype).reshape(shape)
        self.pos += nbytes
        return view

    def skip(self, nbytes: int, block: str) -> None:
        self.need(nbytes, block)
        self.pos += nbytes


@dataclass
class BonnHeader:
    """What the common header of a Bonn BTF file says.

    views, lights : (nV, 2), (nL, 2) float64 (theta, phi) in radians, as stored.
    channel_names : list[str]; ``cosine_flag``: the data were multiplied by cos(theta_light).
    rotations : (n, 3, 3) float64, local frame rotations (recorded, not applied: neither
        reference reader applies them).
    """

    signature: str
    format: str
    header_flag: bool
    meta_version: int = 0
    measurement_setup: str = ""
    image_sensor: str = ""
    light_source: str = ""
    ppmm: float = 0.0
    rgb_scale_factor: tuple = (1.0, 1.0, 1.0)
    cosine_flag: bool = False
    xml_bytes: int = 0
    channel_names: list = field(default_factory=lambda: ["R", "G", "B"])
    views: np.ndarray | None = None
    lights: np.ndarray | None = None
    width: int = 0
    height: int = 0
    rotations: np.ndarray | None = None

    @property
    def n_channels(self) -> int:
        return len(self.channel_names)

    @property
    def n_views(self) -> int:
        return len(self.views)

    @property
    def n_lights(self) -> int:
        return len(self.lights)


def read_meta(cur: Cursor, h: BonnHeader) -> None:
    """The meta-data block (btflib ``read_meta_data``), checked against its own size field."""
    block = "meta data block"
    start = cur.pos
    size = cur.u32(block)
    h.meta_version = cur.u32(block)
    h.measurement_setup = cur.text(80, block)
    h.image_sensor = cur.text(80, block)
    h.light_source = cur.text(80, block)
    h.ppmm = float(cur.f32(1, block)[0])
    h.rgb_scale_factor = tuple(float(x) for x in cur.f32(3, block))
    if h.meta_version > 1:
        h.cosine_flag = bool(cur.u32(block))
    if h.meta_version > 2:
        n = cur.u32(block)
        cur.skip(n, f"{block} (measurement XML)")
        h.xml_bytes = n
    if h.meta_version > 3:
        n = cur.u32(block)
        if n == 0 or n * 4 > size:
            raise cur.fail(block, f"channel count {n} is impossible in a {size}-byte block")
        h.channel_names = [cur.text(cur.u32(block), f"{block} (channel names)") for _ in range(n)]
        if n != 3:  # multispectral BTFs exist; usdbtf's data model is RGB
            raise cur.fail(block, f"{n} channels ({', '.join(h.channel_names)}); only RGB (3 channels) is supported")
    if cur.pos - start != size:
        raise cur.fail(block, f"declares {size} bytes but its fields take {cur.pos - start} "
                              f"(meta-data version {h.meta_version})")


def read_directions(cur: Cursor, h: BonnHeader) -> None:
    """View and light directions (btflib ``read_bidir_sampling``): radians, as stored.

    Every view must list the same lights (btflib reads the first list and skips the rest;
    here they are compared, so a file with view-dependent lights is refused, not misread).
    """
    block = "direction table"
    nv = cur.u32(block)
    if nv == 0 or nv * 12 > cur.size - cur.pos:
        raise cur.fail(block, f"view count {nv} does not fit in the file")
    views = np.empty((nv, 2))
    lights = None
    for v in range(nv):
        views[v] = cur.f32(2, f"{block} (view {v})")
        nl = cur.u32(f"{block} (view {v})")
        if nl == 0 or nl * 8 > cur.size - cur.pos:
            raise cur.fail(f"{block} (view {v})", f"light count {nl} does not fit in the file")
        these = cur.f32(2 * nl, f"{block} (view {v} lights)").reshape(nl, 2)
        if lights is None:
            lights = these
        elif these.shape != lights.shape or not np.array_equal(these, lights):
            raise cur.fail(f"{block} (view {v})", f"lists {nl} lights that differ from view 0's {len(lights)}; "
                                                  "only one light list shared by all views is supported (as in btflib)")
    h.views, h.lights = views, lights


def read_size(cur: Cursor, h: BonnHeader) -> None:
    h.width = cur.u32("image size")
    h.height = cur.u32("image size")
    if h.width == 0 or h.height == 0:
        raise cur.fail("image size", f"{h.width}x{h.height} texels")


def read_rotations(cur: Cursor, h: BonnHeader) -> None:
    n = cur.u32("rotation block")
    if n * 36 > cur.size - cur.pos:
        raise cur.fail("rotation block", f"{n} rotations do not fit in the file")
    h.rotations = cur.f32(9 * n, "rotation block").reshape(n, 3, 3)


def read_common_header(cur: Cursor, h: BonnHeader) -> None:
    """Meta data, directions, size and (signature ending in "R") rotations."""
    read_meta(cur, h)
    read_directions(cur, h)
    read_size(cur, h)
    if h.signature.endswith("R"):
        read_rotations(cur, h)
