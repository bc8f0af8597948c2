"""Image files through OpenImageIO: read with clear errors, write with the colour space declared.

Pixel data here is in the file's own encoding (integer codes or floats); colour
conversion lives in :mod:`usdbtf.colour`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from .errors import BTFError

__all__ = ["ImageInfo", "read_info", "read_image", "write_image", "BIT_DEPTHS", "numpy_dtype"]

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


def _one_line(text: str) -> str:
    """OIIO/libpng messages can span lines; errors here are one line."""
    return " ".join(str(text).split())


def _open(path) -> "oiio.ImageInput":
    path = os.fspath(path)
    inp = oiio.ImageInput.open(path)
    if inp is None:
        msg = oiio.geterror()
        if not os.path.isfile(path):  # checked only on failure: a stat per image adds up over 10^4 images
            raise BTFError(f"{path}: image file not found")
        raise BTFError(f"{path}: cannot read image ({_one_line(msg) or 'unknown format'})")
    return inp


def _info(path, inp) -> ImageInfo:
    spec = inp.spec()
    return ImageInfo(os.fspath(path), spec.width, spec.height, spec.nchannels, str(spec.format),
                     spec.get_string_attribute("oiio:ColorSpace", ""))


def read_info(path) -> ImageInfo:
    """Header only: size, channels, bit depth, declared colour space."""
    inp = _open(path)
    try:
        return _info(path, inp)
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
            raise BTFError(f"{path}: image data is corrupt or truncated ({_one_line(inp.geterror() or oiio.geterror())})")
    finally:
        inp.close()
    data = np.asarray(data)
    if data.ndim == 2:
        data = data[:, :, None]
    if data.shape[-1] == 1:
        data = np.repeat(data, 3, axis=-1)
    return data, info


def write_image(path, pixels: np.ndarray, *, color_space: str, attributes: dict | None = None,
                file_type: str | None = None) -> int:
    """Write ``pixels`` (H, W, C) as-is (its dtype is the file's bit depth) and return the file size.

    ``color_space`` is recorded as ``oiio:ColorSpace`` (and in the file's own colour
    metadata where the format has some).  Format options go in ``attributes``, e.g.
    ``{"Compression": "jpeg:90"}`` or ``{"png:compressionLevel": 9}``.  ``file_type`` (an
    extension such as "jxl") chooses the format when ``path`` has no extension, e.g. an
    in-memory file ``/proc/self/fd/N``; by default the path's extension decides.
    """
    path = Path(path)
    pixels = np.ascontiguousarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[:, :, None]
    type_name = {np.dtype(v): k for k, v in BIT_DEPTHS.items()}.get(pixels.dtype)
    if type_name is None:
        raise BTFError(f"{path}: cannot write pixel type {pixels.dtype}")
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], type_name)
    spec.attribute("oiio:ColorSpace", color_space)
    # OIIO stamps the current time into EXR/TIFF headers; a fixed stamp keeps outputs
    # byte-identical for identical inputs (the project's determinism rule).  Only there:
    # elsewhere the attribute would add an EXIF block (~300-450 bytes a JPEG/JPEG XL file).
    if (f".{file_type}" if file_type else path.suffix).lower() in _TIMESTAMPED:
        spec.attribute("DateTime", FIXED_DATETIME)
    for key, value in (attributes or {}).items():
        spec.attribute(key, value)
    out = oiio.ImageOutput.create(file_type or str(path))
    if out is None:
        raise BTFError(f"{path}: no image writer for this file type ({oiio.geterror()})")
    try:
        if not out.open(str(path), spec):
            raise BTFError(f"{path}: cannot open for writing ({out.geterror()})")
        if not out.write_image(pixels):
            raise BTFError(f"{path}: write failed ({out.geterror()})")
    finally:
        out.close()
    return path.stat().st_size
