"""How coefficient textures and the basis are stored on disk.

Every stored image holds integers (or half floats) plus a per-channel affine
de-quantisation ``value = stored * scale + bias``, recorded in the metadata, so a
renderer (or UsdUVTexture's scale/bias) can undo it.

Codecs
------
``jxlp``  (default) uniform-step integers, lossless JPEG XL at effort 7, each coefficient
          texture **planar**: one single-channel H x 3W image, the three decorrelated colour
          planes side by side (JPEG XL's 3-channel lossless path models the very unequal
          decorrelated channels badly: planar files are 20-25 % smaller, effort 7 ~9 % more;
          issue 16's research, ``benchmarks/probes/research/``).  Readers see (H, W, 3) as ever.
``jxl``   the same integers as one RGB JPEG XL per texture at effort 2 (the default before
          issue 16): within ~15% of the entropy of the quantised symbols.
``png``   the same integers, lossless PNG: larger, readable everywhere.
``exr``   half floats with a power-of-two scale per channel, ZIP: no quantisation beyond
          half precision (11 significant bits), any magnitude float32 holds.
``jpeg``  the paper: each texture min-max scaled to [0, 1], 8-bit JPEG (quality 90,
          4:4:4); basis min-max scaled per vector into one uncompressed 8-bit TIFF.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BTFError
from ..imageio import encode_image, memory_file, read_image
from .options import CODEC_NAMES

__all__ = ["Codec", "CODECS", "get_codec", "codec_map", "Stored", "quantize_uniform", "uniform_codes", "DEAD_ZONE_OFFSET", "quantize_minmax", "quantize_half",
           "memory_file", "to_planar"]


@dataclass(frozen=True)
class Stored:
    """Integers (or halves) ready to write, with their de-quantisation.

    pixels : (H, W, C) storage array (uint8, uint16 or float16).
    scale, bias : (C,) float64, ``value = pixels * scale + bias``.
    """

    pixels: np.ndarray
    scale: np.ndarray
    bias: np.ndarray

    def values(self) -> np.ndarray:
        """(H, W, C) float32 de-quantised values, computed exactly as every reader does."""
        return (self.pixels.astype(np.float32) * self.scale.astype(np.float32)
                + self.bias.astype(np.float32))


#: Rounding offset of the dead-zone quantiser (issue 39): a sparse channel's code is
#: sign(t) floor(|t| + DEAD_ZONE_OFFSET), t = value / step, instead of rint(t) (offset 0.5).
#: The zero bin widens to |t| < 0.75 and every other threshold moves 0.25 steps outwards:
#: fewer non-zero codes for a little more error, and the bytes saved buy components.  Chosen
#: on paper-scale factorisations of metal_flakes, satin_weave and pebbles at their asset
#: budgets (``benchmarks/probes/issue39_deadzone.py``: offsets 0.15..0.42, every plane or
#: only the sparse ones).
DEAD_ZONE_OFFSET = 0.25
#: A channel is sparse, and gets the dead zone, when rint leaves more than this fraction of
#: its codes zero; denser (high-rate) channels keep rint, where a dead zone's error
#: (((1 - f)^3 + f^3) / 3 step^2 against step^2 / 12) costs more than its bytes save.
DEAD_ZONE_SPARSE = 0.5


def uniform_codes(t: np.ndarray, dead_zone: bool = False) -> np.ndarray:
    """Integer codes (as floats) of values already divided by the step, ``t`` (..., C):
    ``rint(t)``; with ``dead_zone``, each channel (last axis) where rint leaves more than
    :data:`DEAD_ZONE_SPARSE` of the codes zero is rounded towards zero with
    :data:`DEAD_ZONE_OFFSET` instead.  Reconstruction is code * step either way (no reader
    change)."""
    q = np.rint(t)
    if not dead_zone:
        return q
    n = max(int(np.prod(t.shape[:-1])), 1)
    sparse = np.count_nonzero(q.reshape(-1, t.shape[-1]) == 0, axis=0) > DEAD_ZONE_SPARSE * n
    if not sparse.any():
        return q
    return np.where(sparse, np.copysign(np.floor(np.abs(t) + DEAD_ZONE_OFFSET), t), q)


def _eight_bit_steps(values: np.ndarray, step: np.ndarray, q: np.ndarray, dead_zone: bool,
                     factor: float) -> tuple[np.ndarray, np.ndarray]:
    """(step, codes) with each channel of ``q`` (codes of ``values`` at ``step``) whose codes
    span more than 255 and at most 255 ``factor`` re-rounded at the smallest coarser step of its
    own (growing by 1/256 from span / 255 x the step) whose codes span at most 255 (8 bits);
    the other channels as they are."""
    flat = q.reshape(-1, q.shape[-1])
    span = flat.max(axis=0) - flat.min(axis=0)
    step, q = step.copy(), q.copy()
    for c in np.flatnonzero((span > 255) & (span <= 255 * factor)):
        grow = span[c] / 255.0
        while True:
            trial = step[c] * grow
            codes = uniform_codes(values[..., c:c + 1] / np.float32(trial), dead_zone)[..., 0].astype(np.int64)
            if int(codes.max()) - int(codes.min()) <= 255:
                break
            grow *= 1.0 + 1.0 / 256.0
        step[c], q[..., c] = trial, codes
    return step, q


def quantize_uniform(values: np.ndarray, step, dead_zone: bool = False, eight_bit_factor: float = 1.0) -> Stored:
    """Round ``values`` (H, W, C) to multiples of ``step`` (scalar or (C,)), stored as unsigned ints.

    ``dead_zone``: round sparse channels towards zero (:func:`uniform_codes`; rate control's
    budgets, issue 39).  ``eight_bit_factor`` > 1: a channel whose codes span more than 255
    but at most ``255 * eight_bit_factor`` (257 to 511 levels at the default 2) gets a coarser
    step of its own that fits 8 bits (:data:`.options.EIGHT_BIT_STEP_FACTOR`, byte budgets);
    the stored scale is each channel's step.  The integer range decides the bit depth: 8-bit when every channel fits in 256
    levels, else 16-bit.  Raises BTFError if a channel needs more than 16 bits.
    """
    step = np.array(np.broadcast_to(np.asarray(step, np.float64), (values.shape[-1],)))
    q = uniform_codes(values / step.astype(np.float32), dead_zone).astype(np.int64)
    if eight_bit_factor > 1.0:
        step, q = _eight_bit_steps(values, step, q, dead_zone, eight_bit_factor)
    lo = q.reshape(-1, q.shape[-1]).min(axis=0)
    hi = q.reshape(-1, q.shape[-1]).max(axis=0)
    span = int((hi - lo).max())
    if span >= 2**16:
        raise BTFError(f"quantisation step too fine: {span + 1} levels do not fit in 16 bits")
    dtype = np.uint8 if span < 256 else np.uint16
    return Stored((q - lo).astype(dtype), step.copy(), lo * step)


def quantize_minmax(values: np.ndarray, *, per_channel: bool, bits: int = 8) -> Stored:
    """The paper's scaling: map [min, max] to the full integer range (jointly or per channel)."""
    flat = values.reshape(-1, values.shape[-1]).astype(np.float64)
    lo, hi = flat.min(axis=0), flat.max(axis=0)
    if not per_channel:
        lo, hi = np.full_like(lo, lo.min()), np.full_like(hi, hi.max())
    top = 2**bits - 1
    scale = np.where(hi > lo, (hi - lo) / top, 1.0)
    q = np.rint((flat - lo) / scale).clip(0, top)
    dtype = np.uint8 if bits == 8 else np.uint16
    return Stored(q.astype(dtype).reshape(values.shape), scale, lo)


def quantize_half(values: np.ndarray) -> Stored:
    """Half floats with a power-of-two scale per channel (exact to apply and undo).

    Each channel's largest magnitude lands in [2^14, 2^15), inside half's range (max 65504)
    and far from its subnormals: HDR data neither overflows nor flushes to zero.
    """
    flat = values.reshape(-1, values.shape[-1]).astype(np.float64)
    peak = np.abs(flat).max(axis=0)
    exponent = np.where(peak > 0, np.floor(np.log2(np.where(peak > 0, peak, 1.0))) - 14, 0)
    scale = np.exp2(exponent)
    return Stored((values / scale.astype(np.float32)).astype(np.float16), scale, np.zeros_like(scale))


@dataclass(frozen=True)
class Codec:
    """A file format for stored textures.  ``attributes`` are OIIO writer options."""

    name: str
    ext: str
    attributes: dict
    basis_ext: str
    basis_attributes: dict
    lossless: bool
    planar: bool = False         # coefficient textures as one H x 3W single-channel image

    def encode(self, stored: Stored, color_space: str, *, basis: bool = False) -> bytes:
        """The file's bytes for ``stored.pixels``, encoded in memory (no file is created).

        Byte for byte what :meth:`write` puts on disk: the same OpenImageIO writer, given
        an anonymous in-memory file with the format named explicitly.
        """
        attrs = self.basis_attributes if basis else self.attributes
        ext = self.basis_ext if basis else self.ext
        pixels = stored.pixels if basis or not self.planar else to_planar(stored.pixels)
        data = encode_image(pixels, ext, color_space=color_space, attributes=attrs)
        if ext == "jxl" and len(data) < _JXL_MIN_READABLE:
            # OpenImageIO's JPEG XL reader needs 128 bytes to recognise a file; a constant
            # texture compresses below that.  A description box (useful anyway) pads it.
            data = encode_image(pixels, ext, color_space=color_space,
                                attributes=dict(attrs, ImageDescription=_DESCRIPTION))
        return data

    def write(self, path: Path, stored: Stored, color_space: str, *, basis: bool = False) -> int:
        """Write ``stored.pixels`` to ``path`` (see :meth:`encode`); returns bytes on disk."""
        data = self.encode(stored, color_space, basis=basis)
        Path(path).write_bytes(data)
        return len(data)

    @staticmethod
    def decode(data: bytes, channels: int | None = None) -> np.ndarray:
        """Stored integers/halves (H, W, C) back from a file's bytes, as :meth:`read` gives them."""
        with memory_file() as (fd, path):
            os.write(fd, data)
            return Codec.read(path, channels)

    def fastest(self) -> "Codec":
        """The same format at its quickest lossless setting (JPEG XL effort 1: ~12x faster
        than effort 2 for ~10 % more bytes on 1024^2 textures); other codecs unchanged.
        For large outputs where encode time dominates, e.g. quilted atlases."""
        if self.ext != "jxl":
            return self
        # Planar (single-channel) files at effort 1 do not decode (libjxl, measured with OIIO
        # 3.2): effort 2 for them.
        effort = 2 if self.planar else 1
        return Codec(self.name, self.ext, dict(self.attributes, **{"jpegxl:effort": effort}), self.basis_ext,
                     self.basis_attributes, self.lossless, self.planar)

    def quick(self) -> "Codec":
        """The same format at the effort a run that asked for no size uses (``--effort
        auto`` with a plain k, :attr:`.options.CompressOptions.quick_encode`): JPEG XL effort
        2 for the coefficient textures, 3 for the basis image; other codecs unchanged.

        At paper scale (pebbles, k = 150, ``benchmarks/bench_effort.py``) effort 2 encodes the
        coefficient textures 8x faster than effort 7 for 7.5 % more bytes, and the basis at 3
        3.6x faster for 9 % more (RESULTS, "Compression speed against its floor")."""
        if self.ext != "jxl":
            return self
        return Codec(self.name, self.ext, dict(self.attributes, **{"jpegxl:effort": min(2, self.effort)}),
                     self.basis_ext, dict(self.basis_attributes, **{"jpegxl:effort": min(3, self.basis_effort)}),
                     self.lossless, self.planar)

    @property
    def forkable(self) -> bool:
        """True when this format's files may be encoded and decoded in forked processes
        (:func:`codec_map`): not OpenEXR, whose process-wide thread pool a forked child
        inherits without its threads (an EXR write or read there can deadlock)."""
        return "exr" not in (self.ext, self.basis_ext)

    @property
    def effort(self) -> int | None:
        """JPEG XL effort of the coefficient textures (None for other formats)."""
        return self.attributes.get("jpegxl:effort")

    @property
    def basis_effort(self) -> int | None:
        """JPEG XL effort of the basis image (None for other formats)."""
        return self.basis_attributes.get("jpegxl:effort")

    def texture(self, pixels: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
        """A coefficient texture as read from its file -> (H, W, 3) (planar files unpacked)."""
        if not self.planar:
            return pixels
        H, W = shape
        if pixels.shape[:2] != (H, 3 * W):
            return pixels                  # the caller's shape check names the file
        return np.ascontiguousarray(pixels[:, :, 0].reshape(H, 3, W).transpose(0, 2, 1))

    @staticmethod
    def read(path: Path, channels: int | None = None) -> np.ndarray:
        """Stored integers/halves back, (H, W, C)."""
        pixels, _ = read_image(path)
        if channels == 1:
            pixels = pixels[:, :, :1]
        return pixels


# jxl: effort 2 for the many coefficient textures (effort 7 saves ~13 % at 10x the time);
# effort 3 for the single basis image, where it saves ~8 % for 0.1 s.  jxlp: effort 7 for
# both (at the paper's bytes the bytes buy components: the issue 16 research measured it).
_JXL = {"jpegxl:distance": 0.0, "jpegxl:effort": 2}
_JXL7 = {"jpegxl:distance": 0.0, "jpegxl:effort": 7}
_JXL_MIN_READABLE = 128
_DESCRIPTION = ("usdbtf compressed-BTF texture: integer codes; value = code * scale + bias, "
                "scale and bias per channel in btf-compressed.json")
CODECS = {
    "jxlp": Codec("jxlp", "jxl", _JXL7, "jxl", _JXL7, True, planar=True),
    "jxl": Codec("jxl", "jxl", _JXL, "jxl", dict(_JXL, **{"jpegxl:effort": 3}), True),
    "png": Codec("png", "png", {"png:compressionLevel": 6}, "png", {"png:compressionLevel": 6}, True),
    "exr": Codec("exr", "exr", {"compression": "zip"}, "exr", {"compression": "zip"}, True),
    "jpeg": Codec("jpeg", "jpg", {"Compression": "jpeg:90", "jpeg:subsampling": "4:4:4"}, "tif",
                  {"compression": "none"}, False),
}

if tuple(CODECS) != CODEC_NAMES:
    raise ImportError(f"usdbtf.compress.codecs: CODECS {tuple(CODECS)} differ from options.CODEC_NAMES {CODEC_NAMES}")


def to_planar(pixels: np.ndarray) -> np.ndarray:
    """(H, W, 3) -> (H, 3W, 1): the three channels side by side (``jxlp``'s file layout)."""
    return np.ascontiguousarray(np.concatenate([pixels[:, :, c] for c in range(pixels.shape[2])], axis=1)[:, :, None])


def codec_map(codec: Codec, fn, items) -> list:
    """``[fn(x) for x in items]`` for image encodes or decodes in ``codec``: in forked processes
    where the codec allows (OpenImageIO holds the GIL while it codes, so threads would run one
    at a time), else on threads.  The bytes do not depend on where they were coded."""
    from .parallel import in_processes, in_threads

    return (in_processes if codec.forkable else in_threads)(fn, items)


def get_codec(name: str) -> Codec:
    try:
        return CODECS[name]
    except KeyError:
        raise BTFError(f"unknown codec {name!r}; choose from {', '.join(CODECS)}") from None

