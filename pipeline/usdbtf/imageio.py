"""Image files through OpenImageIO: read with clear errors, write with the colour space declared.

Pixel data here is in the file's own encoding (integer codes or floats); colour
conversion lives in :mod:`usdbtf.color`.
"""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from .errors import BTFError, IOFailure, UsageError, one_line

__all__ = ["ImageInfo", "read_info", "read_attribute", "read_image", "read_rgba", "write_image", "encode_image", "encode_png_smallest",
           "encode_png_rle", "png_filtered_rows", "decode_image", "write_encoded", "PNG_FILTERS", "memory_file", "BIT_DEPTHS", "numpy_dtype", "oiio_error", "native_stderr_captured"]

log = logging.getLogger(__name__)

FIXED_DATETIME = "1970:01:01 00:00:00"
_TIMESTAMPED = {".exr", ".sxr", ".mxr", ".tif", ".tiff"}

# Bit depths usdbtf reads and writes, by OIIO type name.
BIT_DEPTHS = {"uint8": np.uint8, "uint16": np.uint16, "half": np.float16, "float": np.float32}


def numpy_dtype(bit_depth: str):
    try:
        return BIT_DEPTHS[bit_depth]
    except KeyError:
        raise BTFError(f"unsupported bit depth {bit_depth!r}; expected one of {', '.join(BIT_DEPTHS)}") from None


@dataclass(frozen=True)
class ImageInfo:
    """What the header of an image file says.

    ``bit_depth`` is an OIIO type name ("uint8", "uint16", "half", "float");
    ``color_space`` is the file's ``oiio:ColorSpace`` attribute or "" if absent.
    """

    path: str
    width: int
    height: int
    channels: int
    bit_depth: str
    color_space: str


def oiio_error(*sources) -> str:
    """OIIO's error for a failed call, as one line: the first non-empty ``geterror()`` of
    ``sources`` (ImageInput, ImageOutput, ImageBuf), else OIIO's global error.  The global
    one is always retrieved, which clears it (OIIO prints unretrieved errors at exit).
    OIIO's messages can span lines (libpng's and OIIO's text joined by a newline)."""
    own = next((text for text in (s.geterror() for s in sources) if text), "")
    pending = oiio.geterror()
    return one_line(own or pending)


# fd 2 while native readers run: (lock, [depth, saved fd 2, capture fd]); see native_stderr_captured.
_CAPTURE_LOCK = threading.Lock()
_CAPTURE = [0, -1, -1]


@contextlib.contextmanager
def native_stderr_captured():
    """Run OIIO's readers with the process's file descriptor 2 caught in an in-memory file.

    libpng (inside OIIO) prints ``libpng error: ...`` / ``libpng warning: ...`` straight on
    the C stderr, beside the error OIIO returns with the same text: a failed read would
    print two lines.  Caught here, libpng's lines become debug records of this module's
    logger (``-v`` shows them); anything else that reached fd 2 meanwhile (another thread's
    output) is written back to fd 2 when the last nested or concurrent capture ends.
    """
    with _CAPTURE_LOCK:
        if _CAPTURE[0] == 0:
            with contextlib.suppress(Exception):
                sys.stderr.flush()      # Python's buffered text goes out before fd 2 moves
            try:
                saved = os.dup(2)
            except OSError:             # no fd 2 at all (a daemon): nothing to keep off it
                saved = -1
            if saved >= 0:
                capture = os.memfd_create("usdbtf-stderr", os.MFD_CLOEXEC)
                _CAPTURE[1:] = [saved, capture]
                os.dup2(capture, 2)
        _CAPTURE[0] += 1
    try:
        yield
    finally:
        with _CAPTURE_LOCK:
            _CAPTURE[0] -= 1
            if _CAPTURE[0] == 0 and _CAPTURE[1] >= 0:
                with contextlib.suppress(Exception):
                    sys.stderr.flush()
                saved, capture = _CAPTURE[1:]
                _CAPTURE[1:] = [-1, -1]
                os.dup2(saved, 2)
                os.close(saved)
                size = os.lseek(capture, 0, os.SEEK_END)
                caught = os.pread(capture, size, 0) if size else b""
                os.close(capture)
                _release(caught)


def _reset_after_fork() -> None:
    """In a forked child (compress's decode workers): a fresh lock, in case another thread
    held it at the fork, and fd 2 given back if a capture was open then (its thread does
    not exist in the child, so it would never end)."""
    global _CAPTURE_LOCK
    _CAPTURE_LOCK = threading.Lock()
    if _CAPTURE[0] and _CAPTURE[1] >= 0:
        os.dup2(_CAPTURE[1], 2)
        os.close(_CAPTURE[1])
        os.close(_CAPTURE[2])
    _CAPTURE[:] = [0, -1, -1]


os.register_at_fork(after_in_child=_reset_after_fork)


def _release(caught: bytes) -> None:
    """libpng's lines to the debug log, the rest back to fd 2 as it came."""
    others = []
    for line in caught.splitlines(keepends=True):
        if line.startswith(b"libpng "):
            log.debug("%s", line.decode(errors="replace").strip())
        else:
            others.append(line)
    if others:
        os.write(2, b"".join(others))


def _open(path) -> "oiio.ImageInput":
    path = os.fspath(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        msg = oiio_error()
        # Checked only on failure: a stat per image adds up over 10^4 images.
        if os.path.isdir(path):
            raise IOFailure(f"{path}: is a folder, not an image file")
        if not os.path.isfile(path):
            raise BTFError(f"{path}: image file not found")
        if not os.access(path, os.R_OK):
            raise IOFailure(f"{path}: permission denied")
        raise BTFError(f"{path}: cannot read image ({msg or 'unknown format'})")
    return inp


def _info(path, inp) -> ImageInfo:
    spec = inp.spec()
    return ImageInfo(os.fspath(path), spec.width, spec.height, spec.nchannels, str(spec.format),
                     spec.get_string_attribute("oiio:ColorSpace", ""))


def read_info(path) -> ImageInfo:
    """Header only: size, channels, bit depth, declared colour space."""
    with native_stderr_captured():
        inp = _open(path)
        try:
            return _info(path, inp)
        finally:
            inp.close()


def read_attribute(path, name: str) -> str:
    """The string attribute ``name`` of the image at ``path``'s header ("" when absent), e.g. a
    PNG text chunk a writer put there through :func:`write_image`'s ``attributes``."""
    with native_stderr_captured():
        inp = _open(path)
        try:
            return inp.spec().get_string_attribute(name, "")
        finally:
            inp.close()


def read_image(path, *, expect: tuple[int, int] | None = None, rows: tuple[int, int] | None = None):
    """Read the RGB channels of ``path`` in the file's native pixel type.

    Parameters
    ----------
    expect : (width, height) the caller requires, checked against the header.
    rows : (y0, y1) to read only scanlines y0 <= y < y1 (a pixel chunk).

    Returns
    -------
    pixels : (h, W, 3) array, dtype per the file (uint8, uint16, float16 or float32).
             Greyscale files are expanded to three equal channels; alpha is dropped.
    info : ImageInfo
    """
    with native_stderr_captured():
        data, info = _read_pixels(path, expect, rows)
    data = np.asarray(data)
    if data.ndim == 2:
        data = data[:, :, None]
    if data.shape[-1] == 1:
        data = np.repeat(data, 3, axis=-1)
    return data, info


def _read_pixels(path, expect, rows):
    """OIIO's pixels of ``path`` and its :class:`ImageInfo` (see :func:`read_image`)."""
    inp = _open(path)
    try:
        info = _info(path, inp)
        if info.bit_depth not in BIT_DEPTHS:
            raise BTFError(f"{path}: unsupported bit depth {info.bit_depth} (need 8/16-bit integer, half or float)")
        if info.channels not in (1, 3, 4):
            raise BTFError(f"{path}: unsupported channel count {info.channels} (need 1 = grey, 3 = RGB or 4 = RGBA)")
        if expect is not None and (info.width, info.height) != tuple(expect):
            raise BTFError(f"{path}: image is {info.width}x{info.height}, expected {expect[0]}x{expect[1]}")
        nch = 1 if info.channels == 1 else 3
        if rows is None:
            data = inp.read_image(0, 0, 0, nch, info.bit_depth)
        else:
            y0, y1 = rows
            data = inp.read_scanlines(0, 0, y0, y1, 0, 0, nch, info.bit_depth)
        if data is None or inp.has_error:
            # libjpeg fills a truncated file with grey and only flags the error: check the flag too.
            raise BTFError(f"{path}: image data is corrupt or truncated ({oiio_error(inp)})")
    finally:
        inp.close()
    return data, info


def write_image(path, pixels: np.ndarray, *, color_space: str, attributes: dict | None = None,
                allow_non_finite: bool = False, file_type: str | None = None) -> int:
    """Write ``pixels`` (H, W, C) as-is (its dtype is the file's bit depth) and return the file size.

    ``color_space`` is recorded as ``oiio:ColorSpace`` (and in the file's own colour
    metadata where the format has some).  Format options go in ``attributes``, e.g.
    ``{"Compression": "jpeg:90"}`` or ``{"png:compressionLevel": 9}``.

    Float pixels must be finite: nothing non-finite is ever written (a NaN here comes from
    bad input that slipped through, and is reported as such).  ``allow_non_finite`` is for
    tests that craft damaged input files.  Failures of the writer
    itself (permission, disk full) raise :class:`~usdbtf.errors.IOFailure`.
    ``file_type`` (an extension such as "jxl") chooses the format when ``path`` has no
    extension, e.g. an in-memory file ``/proc/self/fd/N``; by default the path's extension decides.
    """
    path = Path(path)
    pixels = np.ascontiguousarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    type_name = {np.dtype(v): k for k, v in BIT_DEPTHS.items()}.get(pixels.dtype)
    if type_name is None:
        raise BTFError(f"{path}: cannot write pixel type {pixels.dtype}")
    if pixels.dtype.kind == "f" and not allow_non_finite and not np.isfinite(pixels).all():
        bad = np.argwhere(~np.isfinite(pixels))[0]
        raise BTFError(f"{path}: refusing to write NaN or infinite values (first at pixel x={bad[1]}, y={bad[0]}, "
                       f"channel {bad[2]}); an input holds non-finite data")
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], type_name)
    spec.attribute("oiio:ColorSpace", color_space)
    # OIIO stamps the current time into EXR/TIFF headers; a fixed stamp keeps outputs
    # byte-identical for identical inputs (the project's determinism rule).  Only there:
    # elsewhere the attribute would add an EXIF block (~300-450 bytes a JPEG/JPEG XL file).
    if (f".{file_type}" if file_type else path.suffix).lower() in _TIMESTAMPED:
        spec.attribute("DateTime", FIXED_DATETIME)
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    if not _in_memory(path):
        _check_room(path, pixels.nbytes)
    out = oiio.ImageOutput.create(file_type or str(path))
    if out is None:
        raise UsageError(f"{path}: no image writer for this file type ({oiio_error()})")
    try:
        if not out.open(str(path), spec):
            raise IOFailure(f"{path}: cannot open for writing ({oiio_error(out) or _os_reason(path)})")
        if not out.write_image(pixels):
            raise IOFailure(f"{path}: write failed ({oiio_error(out) or _os_reason(path)})")
    finally:
        if not out.close():
            problem = oiio_error(out)
            if problem and sys.exc_info()[0] is None:
                raise IOFailure(f"{path}: write failed ({problem})")
    size = path.stat().st_size
    if not _in_memory(path):
        _check_written(path, size)
    return size


@contextlib.contextmanager
def memory_file():
    """An anonymous in-memory file (Linux ``memfd_create``): yields (fd, "/proc/self/fd/N"),
    a path any library can open; it vanishes when closed, leaving nothing on any disk."""
    fd = os.memfd_create("usdbtf-image", os.MFD_CLOEXEC)
    try:
        yield fd, f"/proc/self/fd/{fd}"
    finally:
        os.close(fd)


def encode_image(pixels: np.ndarray, file_type: str, *, color_space: str, attributes: dict | None = None) -> bytes:
    """The bytes :func:`write_image` would write to a ``file_type`` file (an extension, e.g.
    "png"), encoded into an in-memory file: byte for byte the same writer and options."""
    with memory_file() as (fd, path):
        size = write_image(path, pixels, color_space=color_space, attributes=attributes, file_type=file_type)
        return os.pread(fd, size, 0)


#: libpng's filter choices :func:`encode_png_smallest` tries (OIIO "png:filter"): 0 = libpng's
#: default (adaptive: per row the filter of least absolute sum), 8 = PNG_FILTER_NONE.  Smooth
#: images favour the filters, noise-like ones (later coefficients, fitted maps of a noisy
#: material) none (k 190 paper-scale packs at level 6: adaptive 1,990,351, none 1,937,117, the
#: smaller per pack 1,914,031 bytes; level 9 1,950,121 at 6x the encode time;
#: benchmarks/history/packaging.md, "Issue 39: the shipped codec").
PNG_FILTERS = (0, 8)


def encode_png_smallest(pixels: np.ndarray, *, color_space: str, level: int, attributes: dict | None = None) -> bytes:
    """The smaller of the :data:`PNG_FILTERS` PNG encodings of ``pixels`` (the first on a tie:
    deterministic) at zlib ``level``; ``attributes``: further OIIO attributes for both.  The
    pixels a reader decodes are the same whichever filter wins: only the bytes differ."""
    best = None
    for png_filter in PNG_FILTERS:
        attrs = {**(attributes or {}), "png:compressionLevel": level}
        if png_filter:
            attrs["png:filter"] = png_filter
        data = encode_image(pixels, "png", color_space=color_space, attributes=attrs)
        if best is None or len(data) < len(best):
            best = data
    return best


def png_filtered_rows(raw: np.ndarray, bpp: int, previous: np.ndarray | None = None) -> np.ndarray:
    """Every PNG filter (0 none, 1 sub, 2 up, 3 average, 4 Paeth) applied to every row of ``raw``.

    Parameters
    ----------
    raw : (rows, row_bytes) uint8 unfiltered scanlines.
    bpp : bytes per pixel (at least 1): how far back "sub" looks.
    previous : (row_bytes,) uint8 the scanline above the first row (None: the image's first row,
        whose "up" neighbour is zero).

    Returns
    -------
    (5, rows, row_bytes) uint8: the filtered bytes (PNG filters read unfiltered rows only, so the
    rows are independent: computed at once).
    """
    x = raw.astype(np.int16)
    up = np.zeros_like(x)
    up[1:] = x[:-1]
    if previous is not None:
        up[0] = previous
    left, upleft = np.zeros_like(x), np.zeros_like(x)
    left[:, bpp:], upleft[:, bpp:] = x[:, :-bpp], up[:, :-bpp]
    p = left + up - upleft
    pa, pb, pc = np.abs(p - left), np.abs(p - up), np.abs(p - upleft)
    paeth = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, upleft))
    preds = (np.zeros_like(x), left, up, (left + up) >> 1, paeth)
    return np.stack([((x - pred) & 255).astype(np.uint8) for pred in preds])


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")


#: Unfiltered bytes :func:`encode_png_rle` filters at once: bounds its memory (~30 bytes of
#: int16 temporaries per byte: 4 MiB at once held ~130 MB a call, 1 MiB ~35 MB) on atlas and
#: basis pages; the file's bytes do not depend on it (one deflate stream, no flush between).
_PNG_ROWS_BYTES = 1 << 20


def encode_png_rle(pixels: np.ndarray, *, row_filter: str | int = "adaptive", strategy: int = zlib.Z_RLE,
                   level: int = 9, bit_depth: int = 8) -> bytes:
    """An 8-bit PNG of ``pixels`` written here, not through OIIO: what the packaged asset's
    coefficient pages and basis page are (issue 39).

    Coefficient codes are noise-like integers: deflate's string matches find little in them, and
    its default strategy spends bits on short matches that Huffman-coded literals and runs of one
    byte code better.  Z_RLE (matches at distance 1 only) with libpng's adaptive row filter made
    the pages and basis page of two paper-scale assets 0.908x the bytes of libpng's level 6 (the
    smaller of adaptive and no filter), in a third of its CPU time (1.05 s against 3.30 s for the
    ten files; ``benchmarks/probes/page_codecs.py``).  Any PNG reader decodes the same pixels.

    Parameters
    ----------
    pixels : (H, W) gray or (H, W, C) uint8, C in {1, 2, 3, 4} (gray, gray-alpha, RGB, RGBA:
        alpha unassociated, stored as it is).  With ``bit_depth`` < 8, gray values below
        2^bit_depth packed at 1, 2 or 4 bits.
    row_filter : "adaptive" (per row the filter of least sum of absolute signed bytes, the
        lowest filter type on a tie: libpng's heuristic) or one PNG filter type 0..4 for every row.
    strategy, level : zlib's (memLevel 9, a 32 KiB window).

    Returns
    -------
    bytes : signature, IHDR, one IDAT, IEND; nothing else (no colour chunks: callers mark data
        with ``usd.asset.textures.png_as_data``).  Deterministic for one zlib build.
    """
    pixels = np.asarray(pixels)
    if pixels.dtype != np.uint8 or pixels.ndim not in (2, 3) or (pixels.ndim == 3 and not 1 <= pixels.shape[2] <= 4):
        raise BTFError(f"PNG: expected (H, W[, 1-4]) uint8 pixels, got {pixels.dtype} {pixels.shape}")
    h, w = pixels.shape[:2]
    channels = 1 if pixels.ndim == 2 else pixels.shape[2]
    if bit_depth not in (1, 2, 4, 8) or (bit_depth < 8 and (channels != 1 or int(pixels.max(initial=0)) >> bit_depth)):
        raise BTFError(f"PNG: bit depth {bit_depth} cannot hold these pixels")
    if bit_depth < 8:
        per = 8 // bit_depth
        padded = np.zeros((h, -(-w // per) * per), np.uint8)
        padded[:, :w] = pixels.reshape(h, w)
        shifts = (bit_depth * np.arange(per - 1, -1, -1)).astype(np.uint8)
        raw = np.bitwise_or.reduce(padded.reshape(h, -1, per) << shifts, axis=2).astype(np.uint8)
    else:
        raw = pixels.reshape(h, w * channels)
    bpp = max(1, channels * bit_depth // 8)
    z = zlib.compressobj(level, zlib.DEFLATED, 15, 9, strategy)
    idat, step = [], max(1, _PNG_ROWS_BYTES // max(raw.shape[1], 1))
    for y in range(0, h, step):
        rows = png_filtered_rows(raw[y:y + step], bpp, raw[y - 1] if y else None)
        if row_filter == "adaptive":
            kinds = np.argmin(np.minimum(rows, 256 - rows.astype(np.int16)).sum(axis=2, dtype=np.int64), axis=0)
        else:
            kinds = np.full(rows.shape[1], int(row_filter))
        picked = rows[kinds, np.arange(rows.shape[1])]
        idat.append(z.compress(np.concatenate([kinds.astype(np.uint8)[:, None], picked], axis=1).tobytes()))
    idat.append(z.flush())
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[channels]
    header = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([bit_depth, colour_type, 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", header) + _png_chunk(b"IDAT", b"".join(idat))
            + _png_chunk(b"IEND", b""))


def write_encoded(path, data: bytes) -> int:
    """Write an image file's bytes (:func:`encode_image`) to ``path`` after checking that they
    fit (free space, the file-size limit, which would otherwise end the process with
    SIGXFSZ); returns the size."""
    path = Path(path)
    free, limit = _room(path.parent)
    if free is not None and free < len(data):
        raise IOFailure(f"{path}: no space left on the device (needs {len(data)} bytes, {free} free)")
    if limit is not None and limit < len(data):
        raise IOFailure(f"{path}: file size limit exceeded (needs {len(data)} bytes, the limit is {limit})")
    path.write_bytes(data)
    return len(data)


def decode_image(data: bytes) -> np.ndarray:
    """The pixels :func:`read_image` reads from an image file's ``data`` (read in memory)."""
    with memory_file() as (fd, path):
        os.write(fd, data)
        return read_image(path)[0]


def _in_memory(path: Path) -> bool:
    """An anonymous in-memory file (``/proc/self/fd/N`` of a memfd): no file system to check."""
    return path.parent == Path("/proc/self/fd")


def _room(folder: Path) -> tuple[int | None, int | None]:
    """(bytes free on ``folder``'s file system, this process's file size limit), None when unknown."""
    import resource

    try:
        st = os.statvfs(folder)
        free = st.f_bavail * st.f_frsize
    except OSError:
        free = None
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return free, (None if limit == resource.RLIM_INFINITY else limit)


def _check_room(path: Path, raw_bytes: int) -> None:
    """Refuse a write that cannot fit: some image writers (libpng, small OpenEXR files)
    do not report a full disk and leave a truncated file, and libjpeg exits the process.
    The bound is the raw pixel size plus the formats' worst-case overhead."""
    need = int(raw_bytes * 1.02) + 65536
    free, limit = _room(path.parent)
    if free is not None and free < need:
        raise IOFailure(f"{path}: no space left on the device (needs up to {need} bytes, {free} free)")
    if limit is not None and limit < need:
        raise IOFailure(f"{path}: file size limit exceeded (needs up to {need} bytes, the limit is {limit})")


def _check_written(path: Path, size: int) -> None:
    """A file that ends exactly at the size limit, or a file system left with no room, may
    hold a truncated image the writer did not report."""
    free, limit = _room(path.parent)
    if limit is not None and size >= limit:
        raise IOFailure(f"{path}: file size limit exceeded (the file reached the limit of {limit} bytes)")
    if free == 0:
        raise IOFailure(f"{path}: no space left on the device (the file may be truncated)")


def _os_reason(path: Path) -> str:
    """Why a file cannot be written, when the writer did not say."""
    folder = path.parent
    if not folder.is_dir():
        return "its folder does not exist"
    if not os.access(folder, os.W_OK):
        return "permission denied"
    return "unknown error"


def read_rgba(path):
    """(H, W, 4) pixels of a GPU texture (usdbtf.gpu.tables: the tables, the coefficient pages)
    in the file's own type, level 0 of a tiled file (:func:`read_image` returns RGB only; the
    packs and tables use all four channels)."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)       # the fourth layer is data, not coverage
    with native_stderr_captured():
        inp = oiio.ImageInput.open(str(path), config)
        if inp is None:
            raise BTFError(f"{path}: cannot open GPU texture ({oiio_error()})")
        try:
            spec = inp.spec()
            if spec.nchannels != 4:
                raise BTFError(f"{path}: GPU texture has {spec.nchannels} channels, expected 4 (RGBA)")
            data = inp.read_image(0, 0, 0, 4, spec.format) if spec.tile_width else _scanline_bands(inp, spec)
            if data is None or inp.has_error:
                raise BTFError(f"{path}: GPU texture is corrupt or truncated ({oiio_error(inp)})")
        finally:
            inp.close()
    return np.asarray(data)


def _scanline_bands(inp, spec, rows: int = 256):
    """(H, W, 4) pixels of an open scanline image read ``rows`` scanlines at a time into one
    array (None on a read error): OIIO's PNG reader, asked for the whole image, decodes it into
    a buffer of its own before copying it out, so a 64 MB coefficient page peaked at 128 MB
    (issue 39: a render's page reads); in bands it peaks at the array and one band."""
    data = None
    for y in range(spec.y, spec.y + spec.height, rows):
        band = inp.read_scanlines(0, 0, y, min(spec.y + spec.height, y + rows), 0, 0, 4, spec.format)
        if band is None or inp.has_error:
            return None
        band = np.asarray(band)
        if data is None:
            data = np.empty((spec.height, spec.width, 4), band.dtype)
        data[y - spec.y:y - spec.y + len(band)] = band.reshape(len(band), spec.width, 4)
    return data
