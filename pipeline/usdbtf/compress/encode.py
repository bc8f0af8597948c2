"""Encoding: quantised textures -> the codec's bytes, in memory, and what a reader will see.

Nothing here touches a disk: the codec writes into an anonymous in-memory file
(:func:`.codecs.memory_file`).  Lossy codecs are decoded back, so the encoded result holds
exactly the values any reader of its files gets -- rate control then measures the error of
what is stored, and the writer copies the bytes without encoding twice.
"""
from __future__ import annotations

from dataclasses import replace

from .codecs import Codec, Stored, codec_map, get_codec
from .format import (CompressedBTF, EncodedTextures, decode_basis, encode_basis, encode_files, encoded_textures, encoder,
                     truncate)

__all__ = ["encode", "truncate_encoded", "encode_coefficients", "encode_first"]


def encode(cbtf: CompressedBTF) -> CompressedBTF:
    """Encode every texture of ``cbtf`` with its codec.

    Parameters
    ----------
    cbtf : quantised textures (:func:`.quantise.quantise`), not yet encoded.

    Returns
    -------
    A new CompressedBTF with ``encoded`` (the file bytes), ``info["bytes"]`` (their sizes:
    basis, coefficients, payload, per_coefficient) and, for a lossy codec, the coefficient
    textures and basis as decoded from those bytes.  ``cbtf`` is not changed.
    """
    codec = encoder(cbtf)
    enc = encoded_textures(cbtf)
    basis_data, data = enc.basis, enc.coefficients
    if not codec.lossless:
        cbtf = replace(cbtf, coefficients=[Stored(px, st.scale, st.bias)
                                           for px, st in zip(codec_map(codec, Codec.decode, data), cbtf.coefficients)])
    return _with_basis(cbtf, data, basis_data)


def encode_coefficients(cbtf: CompressedBTF) -> tuple[bytes, ...]:
    """The bytes of every coefficient texture of a quantised ``cbtf``, without its basis: what
    :func:`encode` writes for them (lossless codecs only: a lossy codec's textures are also
    decoded back, by :func:`encode`).  Rate control measures them first and then encodes the
    basis once, for the components they leave room for (:func:`encode_first`)."""
    if not get_codec(cbtf.codec).lossless:
        raise ValueError(f"encode_coefficients: {cbtf.codec} is lossy; use encode")
    return tuple(encode_files(cbtf, basis=False)[1])


def encode_first(cbtf: CompressedBTF, k: int, coefficient_bytes) -> CompressedBTF:
    """The first ``k`` components of a quantised ``cbtf``, encoded, given the bytes of its
    coefficient textures (:func:`encode_coefficients`): only the basis image (whose layout
    depends on k) is encoded here.  The same bytes as ``truncate_encoded(encode(cbtf), k)``,
    one basis encode (~1 s at paper scale, JPEG XL effort 7) fewer."""
    return _with_basis(truncate(cbtf, k), coefficient_bytes[:k])


def truncate_encoded(cbtf: CompressedBTF, k: int) -> CompressedBTF:
    """The first ``k`` components of an encoded ``cbtf``: the coefficient textures' bytes are
    kept, only the basis image (whose layout depends on k) is encoded again."""
    return _with_basis(truncate(cbtf, k), cbtf.encoded.coefficients[:k])


def _with_basis(cbtf: CompressedBTF, coefficient_bytes, basis_bytes: bytes | None = None) -> CompressedBTF:
    """``cbtf`` with its basis encoded (``basis_bytes`` when already encoded; decoded back for
    a lossy codec) and ``coefficient_bytes`` as its coefficient textures' bytes."""
    data = encode_basis(cbtf) if basis_bytes is None else basis_bytes
    if not get_codec(cbtf.codec).lossless:
        cbtf = replace(cbtf, basis=Stored(decode_basis(data, cbtf), cbtf.basis.scale, cbtf.basis.bias))
    enc = EncodedTextures(cbtf.codec, data, tuple(coefficient_bytes),
                          (cbtf.basis.pixels, *(st.pixels for st in cbtf.coefficients)))
    return replace(cbtf, encoded=enc, info={**cbtf.info, "bytes": enc.sizes()})
