"""Texture files of a packaged asset: portable copies, data tagging, formats for renderers.

Every texture a package writes is either *colour* (the fallback's diffuse and specular
colours, the thumbnail: sRGB or scene-linear, declared as such) or *data* (the BTF's basis
and coefficient codes, the GPU tables and pages, the fallback's roughness and normal
maps).  USD says which through the attribute's ``colorSpace`` (``raw`` for data) and
UsdUVTexture's ``sourceColorSpace``; the files say it too, as far as their format can:
EXR and TIFF carry ``oiio:ColorSpace = data``, and PNG, which has no word for data, gets a
``gAMA`` chunk of 1.0 and no sRGB/ICC/chromaticity chunks, so no reader applies an sRGB
decode to codes (OIIO reads such a PNG as linear, not ``srgb_rec709_scene``).

``--texture-format`` (:class:`TextureSet`) decides the files renderers get:

``png``  as written: PNG (EXR for float data), what every USD consumer and usdz reads;
``tx``   tiled (64x64), mip-mapped TIFF through OIIO's ``make_texture`` (``maketx``), the
         pixel type unchanged, so level 0 holds the same codes;
``exr``  tiled, mip-mapped OpenEXR through ``make_texture``: the BTF's codes as float32
         values (``value = code * scale + bias`` still holds exactly), GPU pages and data
         maps as the normalised values a sampler returns from the PNG (float32), colour
         maps converted to linear Rec.709 half floats (declared ``lin_rec709_scene``).

Mip levels are box-filtered averages; averaging codes is averaging values, because
de-quantisation is affine.  Reading level 0 back gives the written codes bit for bit.
"""
from __future__ import annotations

import logging
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...compress.codecs import codec_map, get_codec
from ...compress.format import CompressedBTF, basis_file, coefficient_file, encoded_textures
from ...compress.parallel import cpu_count, iter_processes
from ...errors import BTFError
from ...imageio import decode_image, encode_image, native_stderr_captured, oiio_error, write_encoded
from ...progress import track
from .formats import TEXTURE_FORMATS

__all__ = ["DATA", "PORTABLE", "TEXTURE_FORMATS", "USDZ_FORMATS", "Texture", "TextureSet", "png_as_data",
           "portable_bytes", "package_textures", "encode_in_workers"]

log = logging.getLogger(__name__)

#: OIIO colour-space name for data files.
DATA = "data"
#: Extensions every USD consumer (and the usdz spec) reads; other codecs are re-encoded.
PORTABLE = {".png", ".jpg", ".jpeg", ".exr"}
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Chunks that would make a reader colour-convert the codes.
_COLOUR_CHUNKS = {b"gAMA", b"sRGB", b"iCCP", b"cHRM", b"cICP"}
_GAMMA_ONE = 100000
#: Formats a .usdz may hold (its spec: PNG, JPEG, EXR, AVIF).
USDZ_FORMATS = ("png", "exr")
#: What a texture holds: BTF codes, [0, 1]-normalised data (GPU pages, roughness, normals),
#: float data (GPU tables, half-float codes), sRGB-encoded colour.
KINDS = ("codes", "unorm", "float", "srgb")
_TILE = 64


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def png_as_data(blob: bytes, where: str = "PNG") -> bytes:
    """The PNG file ``blob`` with its pixels marked as data: colour chunks dropped, a gAMA of
    1.0 after IHDR.  Only ancillary chunks change; the image data is untouched bytes."""
    if not blob.startswith(_PNG_SIGNATURE):
        raise BTFError(f"{where}: not a PNG file")
    out, pos = [_PNG_SIGNATURE], len(_PNG_SIGNATURE)
    while pos + 8 <= len(blob):
        length, kind = struct.unpack(">I", blob[pos:pos + 4])[0], blob[pos + 4:pos + 8]
        end = pos + 12 + length
        if end > len(blob):
            raise BTFError(f"{where}: truncated PNG chunk {kind!r}")
        if kind not in _COLOUR_CHUNKS:
            out.append(blob[pos:end])
        if kind == b"IHDR":
            out.append(_chunk(b"gAMA", struct.pack(">I", _GAMMA_ONE)))
        pos = end
        if kind == b"IEND":
            break
    return b"".join(out)


def portable_bytes(data: bytes, suffix: str, where: str) -> tuple[bytes, str]:
    """(bytes, suffix) of a texture file every USD consumer reads: ``data`` itself when it is
    PNG/JPEG/EXR (``suffix``), else re-encoded as PNG holding the same integer codes."""
    suffix = suffix.lower()
    if suffix in PORTABLE:
        return data, suffix
    pixels = decode_image(data)
    if pixels.dtype not in (np.uint8, np.uint16):
        raise BTFError(f"{where}: cannot re-encode {pixels.dtype} texture as PNG")
    return encode_image(pixels, "png", color_space=DATA, attributes={"png:compressionLevel": 6}), ".png"


def encode_in_workers(encode, items, label: str, *, forkable: bool = True) -> list:
    """``[encode(x) for x in items]`` over the CPUs, in the order of ``items``, with a progress
    bar ``label``: for the atlas-sized textures of a package (GPU packs, fallback maps), whose
    encoding is its longest step on a large mesh.  OpenImageIO holds the GIL while it encodes,
    so the encodes run in forked processes (:func:`~usdbtf.compress.parallel.iter_processes`);
    on threads when ``forkable`` is false (``encode`` writes OpenEXR, whose thread pool does
    not survive a fork).  The bytes do not depend on where they were encoded."""
    items = list(items)
    if forkable:
        results = iter_processes(encode, items)
    else:
        results = _threads_in_order(encode, items)
    try:
        return list(track(results, label, len(items), logger=log))
    finally:
        # An exception raised outside the generator (a SIGTERM in the progress bar) leaves it
        # suspended inside its pool: closing it stops the pool now, not when it is collected.
        results.close()


def _threads_in_order(fn, items):
    """``fn`` over ``items`` on the CPUs' threads, results in order as they come."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max(1, min(cpu_count(), len(items)))) as pool:
        yield from pool.map(fn, items)


def package_textures(cbtf: CompressedBTF, textures: "TextureSet") -> tuple[str, list[str]]:
    """Add the basis and the k coefficient textures of ``cbtf`` to ``textures`` (as BTF codes):
    the bytes its folder holds (``cbtf.encoded``, e.g. as :func:`usdbtf.usd.asset.package.read_input`
    or ``compress`` made them), portable (:func:`portable_bytes`), else encoded now from the
    stored codes (lossless codecs only: re-encoding decoded JPEG codes would change them).
    Returns the names (in ``textures``) of the basis and of the coefficient textures."""
    codec = get_codec(cbtf.codec)
    if not (cbtf.encoded is not None and cbtf.encoded.describes(cbtf)) and not codec.lossless:
        raise BTFError(f"a {codec.name}-coded compressed BTF is packaged from the bytes of its files: "
                       "give its folder (or compress's result), not codes read from them")
    enc = encoded_textures(cbtf)
    name = basis_file(codec)
    data, suffix = portable_bytes(enc.basis, Path(name).suffix, name)
    basis = textures.add("basis" + suffix, data, "codes")
    blobs, ext = enc.coefficients, None
    if codec.planar:
        # The asset's coefficient textures are RGB (H, W, 3), what every shader samples: the
        # planar files are re-laid out from their codes, losslessly, as PNG.
        png = get_codec("png")
        blobs, ext = codec_map(png, lambda st: png.encode(st, "data"), cbtf.coefficients), ".png"
    coeffs = []
    for i, blob in enumerate(blobs):
        rel = Path(coefficient_file(codec, i))
        rel = rel if ext is None else rel.with_suffix(ext)
        data, suffix = portable_bytes(blob, rel.suffix, str(rel))
        coeffs.append(textures.add(str(rel.with_suffix(suffix)), data, "codes"))
    return basis, coeffs


@dataclass(frozen=True)
class Texture:
    """A texture as the layers name it.  ``path``: asset path relative to the layers
    ("./<stem>_textures/..."); ``color_space``: the USD colour space of the file attribute
    ("raw" for data); ``source_color_space``: UsdUVTexture's ``sourceColorSpace``."""

    path: str
    color_space: str
    source_color_space: str


@dataclass(frozen=True)
class _File:
    """A file of a :class:`TextureSet`: ``data`` stored under ``written`` (its name as added),
    then, for a ``kind`` texture in a tiled format, converted by maketx to its final name."""

    written: str
    data: bytes
    kind: str | None


class TextureSet:
    """A texture folder's files, held in memory until :meth:`write`: each texture converted to
    ``fmt`` (:data:`TEXTURE_FORMATS`) as it is added, as far as memory allows -- PNG data
    tagging is done on the bytes; the tiled, mip-mapped ``tx``/``exr`` files are made by OIIO's
    ``make_texture``, which writes only to files (through a temporary file beside its
    target), so :meth:`write` makes them from the added bytes."""

    def __init__(self, fmt: str = "png"):
        if fmt not in TEXTURE_FORMATS:
            raise BTFError(f"texture format {fmt!r}: choose from {', '.join(TEXTURE_FORMATS)}")
        self.fmt = fmt
        self.files: dict[str, _File] = {}
        self.kinds: dict[str, str] = {}

    def add(self, name: str, data: bytes, kind: str) -> str:
        """Add the texture file ``name`` (its bytes ``data``) as a ``kind`` texture (:data:`KINDS`);
        returns its final name in the folder (the suffix follows ``fmt``)."""
        if kind not in KINDS:
            raise ValueError(f"texture kind {kind!r}")
        final = name
        if self.fmt != "png":
            final = str(Path(name).with_suffix("." + self.fmt))
        elif name.lower().endswith(".png") and kind != "srgb":
            data = png_as_data(data, name)
        self.files[final] = _File(name, data, kind if self.fmt != "png" else None)
        self.kinds[final] = kind
        return final

    def add_file(self, name: str, data: bytes) -> str:
        """A file stored as it is (a thumbnail, a MaterialX document); returns ``name``."""
        self.files[name] = _File(name, data, None)
        return name

    def texture(self, name: str, rel: str) -> Texture:
        """How layers beside a folder ``rel`` name and declare the texture ``name``."""
        kind = self.kinds[name]
        path = f"./{rel}/{name}"
        if kind != "srgb":
            return Texture(path, "raw", "raw")
        if self.fmt == "exr":
            return Texture(path, "lin_rec709_scene", "raw")
        return Texture(path, "srgb_rec709_scene", "sRGB")

    def write(self, folder: Path) -> None:
        """Create ``folder`` with every file (making the tiled formats' files now)."""
        folder = Path(folder)
        folder.mkdir(parents=True)
        for final, f in track(self.files.items(), "writing textures", len(self.files), logger=log):
            src = folder / f.written
            src.parent.mkdir(parents=True, exist_ok=True)
            write_encoded(src, f.data)
            if f.kind is not None:
                dst = folder / final
                tmp = dst.with_name(f".{dst.name}.maketx{dst.suffix}")
                _make_texture(src, tmp, f.kind, self.fmt)
                src.unlink()
                tmp.replace(dst)


def _make_texture(src: Path, dst: Path, kind: str, fmt: str) -> None:
    """``maketx`` ``src`` into a tiled, mip-mapped ``dst`` (TIFF for "tx", OpenEXR for "exr")."""
    import OpenImageIO as oiio

    read_config = oiio.ImageSpec()
    read_config.attribute("oiio:UnassociatedAlpha", 1)      # RGBA packs: alpha is a data layer
    buf = oiio.ImageBuf(str(src), 0, 0, read_config)
    with native_stderr_captured():
        if buf.has_error or not buf.read():
            raise BTFError(f"{src}: cannot read texture for conversion ({oiio_error(buf)})")
    space = DATA
    if fmt == "exr":
        buf, space = _exr_values(buf, kind, src)
    elif kind == "srgb":
        space = "srgb_rec709_scene"
    buf.specmod().attribute("oiio:ColorSpace", space)
    if kind != "srgb":
        buf.specmod().alpha_channel = -1       # a data layer: maketx would clamp an alpha to [0, 1]
    config = oiio.ImageSpec()
    # mipmap_metadata: every MIP level keeps the fixed DateTime (without it maketx drops the
    # metadata of levels 1.., and the TIFF writer stamps them with the current time: a .tx
    # would differ from run to run).
    for key, value in (("maketx:fileformatname", "tiff" if fmt == "tx" else "exr"), ("maketx:filtername", "box"),
                       ("maketx:ignore_unassoc", 1), ("maketx:mipmap_metadata", 1), ("tile_width", _TILE),
                       ("tile_height", _TILE), ("compression", "zip"), ("DateTime", "2000:01:01 00:00:00")):
        config.attribute(key, value)
    if not oiio.ImageBufAlgo.make_texture(oiio.MakeTxTexture, buf, str(dst), config):
        raise BTFError(f"{dst}: maketx failed ({oiio_error()})")


def _exr_values(buf, kind: str, src: Path):
    """(float ImageBuf, OIIO colour space) holding what an OpenEXR texture of ``kind`` stores."""
    import OpenImageIO as oiio

    fmt = buf.spec().format
    integer = fmt in (oiio.UINT8, oiio.UINT16)
    if kind == "codes" and integer:
        pixels = buf.get_pixels(fmt)             # the codes themselves, not normalised
        out = oiio.ImageBuf(oiio.ImageSpec(buf.spec().width, buf.spec().height, buf.spec().nchannels, oiio.FLOAT))
        out.set_pixels(oiio.ROI(), np.asarray(pixels, np.float32))
        return out, DATA
    if kind == "srgb":
        from ...color import processor

        rgb = np.asarray(buf.get_pixels(oiio.FLOAT), np.float32)
        lin = processor("sRGB Encoded Rec.709 (sRGB)", "Linear Rec.709 (sRGB)").apply(rgb[..., :3].copy())
        out = oiio.ImageBuf(oiio.ImageSpec(buf.spec().width, buf.spec().height, 3, oiio.HALF))
        out.set_pixels(oiio.ROI(), lin.astype(np.float16))
        return out, "lin_rec709_scene"
    if integer:                                   # normalised, as a sampler reads the PNG
        return oiio.ImageBufAlgo.copy(buf, oiio.FLOAT), DATA
    if fmt not in (oiio.HALF, oiio.FLOAT):
        raise BTFError(f"{src}: cannot store {fmt} pixels as an OpenEXR texture")
    return buf, DATA
