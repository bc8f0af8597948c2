"""Texture files of a packaged asset: portable copies, data tagging, formats for renderers.

Every texture a package writes is either *colour* (the fallback's diffuse and specular
colours, the thumbnail: sRGB or scene-linear, declared as such) or *data* (the BTF's basis
and coefficient codes, the GPU tables and packs, the fallback's roughness and normal
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
         values (``value = code * scale + bias`` still holds exactly), GPU packs and data
         maps as the normalised values a sampler returns from the PNG (float32), colour
         maps converted to linear Rec.709 half floats (declared ``lin_rec709_scene``).

Mip levels are box-filtered averages; averaging codes is averaging values, because
de-quantisation is affine.  Reading level 0 back gives the written codes bit for bit.
"""
from __future__ import annotations

import shutil
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..compress.codecs import Codec
from ..compress.format import CompressedBTF, basis_file, coefficient_file
from ..errors import BTFError
from ..imageio import write_image

__all__ = ["DATA", "PORTABLE", "TEXTURE_FORMATS", "USDZ_FORMATS", "Texture", "TextureSet", "mark_png_data",
           "portable_copy", "package_textures"]

#: OIIO colour-space name for data files.
DATA = "data"
#: Extensions every USD consumer (and the usdz spec) reads; other codecs are re-encoded.
PORTABLE = {".png", ".jpg", ".jpeg", ".exr"}
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Chunks that would make a reader colour-convert the codes.
_COLOUR_CHUNKS = {b"gAMA", b"sRGB", b"iCCP", b"cHRM", b"cICP"}
_GAMMA_ONE = 100000
TEXTURE_FORMATS = ("png", "tx", "exr")
#: Formats a .usdz may hold (its spec: PNG, JPEG, EXR, AVIF).
USDZ_FORMATS = ("png", "exr")
#: What a texture holds: BTF codes, [0, 1]-normalised data (GPU packs, roughness, normals),
#: float data (GPU tables, half-float codes), sRGB-encoded colour.
KINDS = ("codes", "unorm", "float", "srgb")
_TILE = 64


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def mark_png_data(path: Path) -> None:
    """Rewrite the PNG at ``path`` so its pixels read as data: colour chunks dropped, a gAMA
    of 1.0 after IHDR.  Only ancillary chunks change; the image data is untouched bytes."""
    path = Path(path)
    blob = path.read_bytes()
    if not blob.startswith(_PNG_SIGNATURE):
        raise BTFError(f"{path}: not a PNG file")
    out, pos = [_PNG_SIGNATURE], len(_PNG_SIGNATURE)
    while pos + 8 <= len(blob):
        length, kind = struct.unpack(">I", blob[pos:pos + 4])[0], blob[pos + 4:pos + 8]
        end = pos + 12 + length
        if end > len(blob):
            raise BTFError(f"{path}: truncated PNG chunk {kind!r}")
        if kind not in _COLOUR_CHUNKS:
            out.append(blob[pos:end])
        if kind == b"IHDR":
            out.append(_chunk(b"gAMA", struct.pack(">I", _GAMMA_ONE)))
        pos = end
        if kind == b"IEND":
            break
    path.write_bytes(b"".join(out))


def portable_copy(src: Path, dst_no_ext: Path) -> str:
    """Copy ``src`` (PNG/JPEG/EXR) or re-encode it as PNG (same integer codes) next to
    ``dst_no_ext``.  Returns the suffix."""
    suffix = src.suffix.lower()
    if suffix in PORTABLE:
        shutil.copyfile(src, dst_no_ext.with_suffix(suffix))
        return suffix
    pixels = Codec.read(src)
    if pixels.dtype not in (np.uint8, np.uint16):
        raise BTFError(f"{src}: cannot re-encode {pixels.dtype} texture as PNG")
    write_image(dst_no_ext.with_suffix(".png"), pixels, color_space=DATA, attributes={"png:compressionLevel": 6})
    return ".png"


def package_textures(cbtf: CompressedBTF, src: Path, textures: "TextureSet") -> tuple["Texture", list["Texture"]]:
    """Copy/re-encode the basis and the k coefficient textures from the compressed folder
    ``src`` into ``textures`` (as BTF codes).  Returns (basis, coefficients)."""
    from ..compress.codecs import get_codec

    codec = get_codec(cbtf.codec)
    dst = textures.folder
    (dst / "coeff").mkdir(parents=True, exist_ok=True)
    basis = textures.add("basis" + portable_copy(src / basis_file(codec), dst / "basis"), "codes")
    coeffs = []
    for i in range(cbtf.k):
        rel = Path(coefficient_file(codec, i))
        suffix = portable_copy(src / rel, dst / rel.with_suffix(""))
        coeffs.append(textures.add(str(rel.with_suffix(suffix)), "codes"))
    return basis, coeffs


@dataclass(frozen=True)
class Texture:
    """A texture as the layers name it.  ``path``: asset path relative to the layers
    ("./<stem>_textures/..."); ``color_space``: the USD colour space of the file attribute
    ("raw" for data); ``source_color_space``: UsdUVTexture's ``sourceColorSpace``."""

    path: str
    color_space: str
    source_color_space: str


class TextureSet:
    """Textures written into ``folder`` (which the layers name ``./<rel>``), converted to
    ``fmt`` (:data:`TEXTURE_FORMATS`) as they are added."""

    def __init__(self, folder: Path, rel: str, fmt: str = "png"):
        if fmt not in TEXTURE_FORMATS:
            raise BTFError(f"texture format {fmt!r}: choose from {', '.join(TEXTURE_FORMATS)}")
        self.folder, self.rel, self.fmt = Path(folder), rel, fmt

    def add(self, name: str, kind: str) -> Texture:
        """Finish the file ``folder/name`` (just written) as a ``kind`` texture (:data:`KINDS`);
        returns how the layers must name and declare it."""
        if kind not in KINDS:
            raise ValueError(f"texture kind {kind!r}")
        src = self.folder / name
        if self.fmt != "png":
            name = str(Path(name).with_suffix("." + self.fmt))
            dst = self.folder / name
            tmp = dst.with_name(f".{dst.name}.maketx{dst.suffix}")
            _make_texture(src, tmp, kind, self.fmt)
            src.unlink()
            tmp.replace(dst)
        elif src.suffix.lower() == ".png" and kind != "srgb":
            mark_png_data(src)
        path = f"./{self.rel}/{name}"
        if kind != "srgb":
            return Texture(path, "raw", "raw")
        if self.fmt == "exr":
            return Texture(path, "lin_rec709_scene", "raw")
        return Texture(path, "srgb_rec709_scene", "sRGB")


def _make_texture(src: Path, dst: Path, kind: str, fmt: str) -> None:
    """``maketx`` ``src`` into a tiled, mip-mapped ``dst`` (TIFF for "tx", OpenEXR for "exr")."""
    import OpenImageIO as oiio

    read_config = oiio.ImageSpec()
    read_config.attribute("oiio:UnassociatedAlpha", 1)      # RGBA packs: alpha is a data layer
    buf = oiio.ImageBuf(str(src), 0, 0, read_config)
    if buf.has_error or not buf.read():
        raise BTFError(f"{src}: cannot read texture for conversion ({' '.join(buf.geterror().split())})")
    space = DATA
    if fmt == "exr":
        buf, space = _exr_values(buf, kind, src)
    elif kind == "srgb":
        space = "srgb_rec709_scene"
    buf.specmod().attribute("oiio:ColorSpace", space)
    if kind != "srgb":
        buf.specmod().alpha_channel = -1       # a data layer: maketx would clamp an alpha to [0, 1]
    config = oiio.ImageSpec()
    for key, value in (("maketx:fileformatname", "tiff" if fmt == "tx" else "exr"), ("maketx:filtername", "box"),
                       ("maketx:ignore_unassoc", 1), ("tile_width", _TILE), ("tile_height", _TILE),
                       ("compression", "zip"), ("DateTime", "2000:01:01 00:00:00")):
        config.attribute(key, value)
    if not oiio.ImageBufAlgo.make_texture(oiio.MakeTxTexture, buf, str(dst), config):
        raise BTFError(f"{dst}: maketx failed ({' '.join(oiio.geterror().split())})")


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
        from ..colour import processor

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
