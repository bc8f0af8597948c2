"""The compressed BTF: basis + coefficient textures + a small metadata file.

Folder layout (``btf-compressed/1``)::

    btf-compressed.json     metadata (below)
    basis.<ext>             the S x k basis as one single-channel image, laid out per
                            ``basis.layout`` in the metadata:
                              "columns": S rows x k columns, row s = sample s, column i = vector i;
                              "tiles":   when the sampling is every light for every view (V x L,
                                         view-major), vector i is a V x L tile (row = view,
                                         column = light), tiles in row-major order on a grid of
                                         ``grid`` = [rows, cols]; unused tiles are zero.  Neighbouring
                                         lights and views sit side by side, which the codec's
                                         predictor exploits (-24 % bytes vs columns on paper data).
    coeff/c000.<ext> ...    one H x W x 3 texture per basis vector, energy order (c000 first);
                            codec ``jxlp``: one H x 3W single-channel image each, the
                            three channels side by side (planar, :mod:`.codecs`)
    error_curve.csv/.png    percent error vs k (diagnostics, not counted in the stored bytes)

Reconstruction (equation 2 of Koudelka et al. 2003, with a colour matrix)::

    U[s, i]    = basis[s, i] * basis_scale[i] + basis_bias[i]
    c_i(x, y)  = coeff_i[y, x, :] * coeff_scale[i, :] + coeff_bias[i, :]
    d_s(x, y)  = color_matrix @ sum_i U[s, i] * c_i(x, y)          (working domain)
    I_s(x, y)  = domain.inverse(d_s(x, y)), per channel            (working space, linear)

``color_matrix`` is the 3x3 that takes the stored (decorrelated) coefficient
channels to working-space RGB: identity for the paper solver.  ``domain`` (format
``btf-compressed/1.1``) is the working-domain curve the basis was fitted in
(:mod:`.domain`): ``{"curve": "power", "gamma": G}`` (inverse d^G) or ``{"curve": "srgb"}``
(the sRGB decoding curve), negative d clamped to 0 first.  Without it (``btf-compressed/1``)
the domain is linear and I = d.  Interpolated directions blend basis rows before the curve.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import __version__, jsontext
from ..errors import BTFError
from ..sampling import Sampling
from .codecs import Codec, Stored, codec_map, get_codec
from .domain import LINEAR, Domain
from ..numeric import single_blas_thread

__all__ = ["FORMAT", "METADATA", "CompressedBTF", "EncodedTextures", "write_textures", "write_metadata",
           "metadata_document", "metadata_text", "read_compressed", "reconstruct", "reconstruct_rows",
           "working_coefficients", "FORMAT_DOMAIN",
           "working_coefficient_texels", "folder_bytes", "digest_without_platform", "basis_layout", "encode_basis", "encode_files", "decode_basis",
           "encoded_textures", "basis_to_image", "image_to_basis", "cross_layout", "truncate", "write_basis"]

FORMAT = "btf-compressed/1"
#: The format of a folder with a non-linear working domain (older readers refuse it).
FORMAT_DOMAIN = "btf-compressed/1.1"
METADATA = "btf-compressed.json"


@dataclass(frozen=True)
class EncodedTextures:
    """The codec bytes of a compressed BTF's textures, exactly as its folder holds them.

    Made in memory (:func:`encoded_textures`, or the encoding step :func:`.encode.encode`),
    so a writer copies bytes instead of encoding again.

    Attributes
    ----------
    codec : name of the codec that made them.
    basis : bytes of the basis image.
    coefficients : tuple of k bytes, coefficient texture i at i.
    pixels : the stored arrays they encode, basis first: :meth:`describes` checks them by
        identity, so bytes are never written for a representation they no longer describe.
    """

    codec: str
    basis: bytes
    coefficients: tuple
    pixels: tuple

    def sizes(self) -> dict:
        """Byte counts as the metadata records them: basis, coefficients, payload (their sum),
        per_coefficient."""
        per = [len(c) for c in self.coefficients]
        return {"basis": len(self.basis), "coefficients": int(sum(per)), "payload": len(self.basis) + int(sum(per)),
                "per_coefficient": per}

    def describes(self, cbtf: "CompressedBTF") -> bool:
        """True when ``cbtf`` holds exactly the arrays these bytes were encoded from."""
        return (self.codec == cbtf.codec and len(self.coefficients) == cbtf.k and self.pixels[0] is cbtf.basis.pixels
                and all(a is st.pixels for a, st in zip(self.pixels[1:], cbtf.coefficients)))


@dataclass
class CompressedBTF:
    """A BTF as a basis and coefficient textures.

    Attributes
    ----------
    sampling : Sampling, S directions (one per basis row).
    basis : Stored, pixels (S, k, 1).
    coefficients : list of k Stored, pixels (H, W, 3), energy order.
    color_matrix : (3, 3) float64, stored channels -> working-space RGB.
    codec : str, how the textures are stored.
    working_space : OCIO name of the space reconstructions are in.
    source : dict, the input's "color_space", "bit_depth", "path" (decompress writes this encoding).
    info : dict, everything else recorded in the metadata (solver, errors, bytes, provenance...).
    encoded : EncodedTextures of these textures when they were encoded in memory (``compress``),
        else None (a writer then encodes them).
    curve : the error curve (:func:`.curve.error_curve`) ``compress`` measured, written beside
        the textures; None when not measured (e.g. a folder that was read).
    domain : the working-domain curve (:mod:`.domain`); every reconstruction applies its
        inverse after the dot product and the colour matrix.
    quick_encode : encode at the codec's quick effort (:meth:`.codecs.Codec.quick`: a run
        that asked for no size); readers see the same values either way.
    """

    sampling: Sampling
    width: int
    height: int
    basis: Stored
    coefficients: list
    color_matrix: np.ndarray
    codec: str
    working_space: str
    source: dict
    interpolated: np.ndarray | None = None
    ocio_config: str | None = None
    info: dict = field(default_factory=dict)
    encoded: EncodedTextures | None = None
    curve: dict | None = None
    domain: Domain = LINEAR
    quick_encode: bool = False

    @property
    def k(self) -> int:
        return len(self.coefficients)

    @property
    def n_samples(self) -> int:
        return len(self.sampling)

    def basis_values(self, k: int | None = None) -> np.ndarray:
        """(S, k) float32 de-quantised basis."""
        k = self.k if k is None else k
        b = self.basis
        return (b.pixels[:, :k, 0].astype(np.float32) * b.scale[:k].astype(np.float32)
                + b.bias[:k].astype(np.float32))

    def coefficient_values(self, k: int | None = None) -> np.ndarray:
        """(k, H, W, 3) float32 de-quantised coefficient textures."""
        k = self.k if k is None else k
        out = np.empty((k, self.height, self.width, 3), np.float32)
        for i in range(k):
            out[i] = self.coefficients[i].values()
        return out


@single_blas_thread
def reconstruct(cbtf: CompressedBTF, indices=slice(None), *, k: int | None = None,
                coefficients: np.ndarray | None = None) -> np.ndarray:
    """Working-space images of samples ``indices`` from the first ``k`` basis vectors.

    Returns (n, H, W, 3) float32, scene-linear (the domain's inverse curve applied after the
    dot product).  ``coefficients`` (k, H, W, 3), from :func:`working_coefficients`, may be
    passed to avoid recomputing them per chunk.
    """
    k = cbtf.k if k is None else min(k, cbtf.k)
    idx = np.atleast_1d(np.arange(cbtf.n_samples)[indices])
    return reconstruct_rows(cbtf, cbtf.basis_values(k)[idx], coefficients)


@single_blas_thread
def reconstruct_rows(cbtf: CompressedBTF, rows: np.ndarray, coefficients: np.ndarray | None = None) -> np.ndarray:
    """Working-space images (n, H, W, 3) float32 for basis rows ``rows`` (n, k) -- measured
    rows or rows blended for an interpolated direction (blended in the domain, before the
    curve): ``domain.inverse(rows . c)``."""
    k = rows.shape[1]
    coeff = working_coefficients(cbtf, k) if coefficients is None else coefficients[:k]
    flat = np.asarray(rows, np.float32) @ coeff.reshape(k, -1)       # (n, H*W*3)
    return cbtf.domain.inverse(flat).reshape(len(rows), cbtf.height, cbtf.width, 3)


def working_coefficients(cbtf: CompressedBTF, k: int | None = None) -> np.ndarray:
    """(k, H, W, 3) float32 de-quantised coefficients with the colour matrix applied.

    The matrix acts on colour and the basis on samples, so applying it to the k
    coefficient textures once is exact and far cheaper than to every reconstruction.
    This is what :func:`reconstruct` dots the basis rows with.
    """
    coeff = cbtf.coefficient_values(k)
    m = np.asarray(cbtf.color_matrix, np.float32)
    if not np.array_equal(m, np.eye(3, dtype=np.float32)):
        coeff = coeff @ m.T
    return coeff


def working_coefficient_texels(cbtf: CompressedBTF, texels, k: int | None = None) -> np.ndarray:
    """(k, n, 3) float32 working-space coefficients of some texels only (a slice or an index
    array into the H*W texels, row-major): :func:`working_coefficients` restricted to them,
    element for element, without holding all k full-size textures (k x 3P float32 is
    0.47 GB at 512^2, k = 150)."""
    k = cbtf.k if k is None else k
    idx = np.arange(cbtf.width * cbtf.height)[texels]
    out = np.empty((k, len(idx), 3), np.float32)
    for i, st in enumerate(cbtf.coefficients[:k]):
        out[i] = st.pixels.reshape(-1, st.pixels.shape[-1])[idx].astype(np.float32) * st.scale.astype(np.float32) \
            + st.bias.astype(np.float32)
    m = np.asarray(cbtf.color_matrix, np.float32)
    if not np.array_equal(m, np.eye(3, dtype=np.float32)):
        out = out @ m.T
    return out


def _floats(a) -> list:
    return np.asarray(a, np.float64).ravel().tolist()


def cross_layout(sampling: Sampling) -> tuple[int, int] | None:
    """(V, L) when the sampling is every one of L lights for each of V views, view-major."""
    S = len(sampling)
    first = np.flatnonzero(np.any(np.diff(sampling.view, axis=0) != 0, axis=1))
    L = int(first[0]) + 1 if len(first) else S
    if L == 0 or S % L:
        return None
    V = S // L
    views = sampling.view.reshape(V, L, 2)
    lights = sampling.light.reshape(V, L, 2)
    if not (np.all(views == views[:, :1]) and np.all(lights == lights[:1])):
        return None
    return V, L


def basis_layout(sampling: Sampling, k: int, codec: str = "jxl") -> dict:
    """How the basis is laid out in its image: tiles where a predictive codec can use them;
    the paper's uncompressed image keeps plain columns."""
    cross = cross_layout(sampling)
    if cross is None or cross[0] == 1 or cross[1] == 1 or not get_codec(codec).lossless:
        return {"kind": "columns"}
    V, L = cross
    cols = int(np.ceil(np.sqrt(k * V / L)))          # roughly square image
    rows = int(np.ceil(k / cols))
    return {"kind": "tiles", "views": V, "lights": L, "grid": [rows, cols]}


def basis_to_image(pixels: np.ndarray, layout: dict) -> np.ndarray:
    """(S, k, 1) stored basis -> the image written to disk."""
    if layout["kind"] == "columns":
        return pixels
    V, L, (rows, cols) = layout["views"], layout["lights"], layout["grid"]
    k = pixels.shape[1]
    tiles = np.zeros((rows * cols, V, L), pixels.dtype)
    tiles[:k] = pixels[:, :, 0].T.reshape(k, V, L)
    return tiles.reshape(rows, cols, V, L).transpose(0, 2, 1, 3).reshape(rows * V, cols * L, 1)


def image_to_basis(image: np.ndarray, layout: dict, k: int) -> np.ndarray:
    """Inverse of :func:`basis_to_image`: -> (S, k, 1)."""
    if layout["kind"] == "columns":
        return image[:, :k, :1]
    V, L, (rows, cols) = layout["views"], layout["lights"], layout["grid"]
    tiles = image[:, :, 0].reshape(rows, V, cols, L).transpose(0, 2, 1, 3).reshape(rows * cols, V * L)
    return np.ascontiguousarray(tiles[:k].T)[:, :, None]


def coefficient_file(codec: Codec, i: int) -> str:
    """Relative path of coefficient texture ``i``."""
    return f"coeff/c{i:03d}.{codec.ext}"


def basis_file(codec: Codec) -> str:
    """Relative path of the basis image."""
    return f"basis.{codec.basis_ext}"


def encoder(cbtf: CompressedBTF) -> Codec:
    """The codec ``cbtf``'s textures are encoded with: its format at the effort its run asked
    for (``cbtf.quick_encode``: :meth:`.codecs.Codec.quick`)."""
    codec = get_codec(cbtf.codec)
    return codec.quick() if cbtf.quick_encode else codec


def encode_basis(cbtf: CompressedBTF) -> bytes:
    """The basis image's file bytes (layout per :func:`basis_layout`), encoded in memory."""
    layout = basis_layout(cbtf.sampling, cbtf.k, cbtf.codec)
    image = Stored(basis_to_image(cbtf.basis.pixels, layout), cbtf.basis.scale, cbtf.basis.bias)
    return encoder(cbtf).encode(image, "data", basis=True)


def decode_basis(data: bytes, cbtf: CompressedBTF) -> np.ndarray:
    """(S, k, 1) stored basis from the basis image's bytes (inverse of :func:`encode_basis`)."""
    return image_to_basis(Codec.decode(data, channels=1), basis_layout(cbtf.sampling, cbtf.k, cbtf.codec), cbtf.k)


def encoded_textures(cbtf: CompressedBTF) -> EncodedTextures:
    """The bytes of every texture of ``cbtf``: ``cbtf.encoded`` when it still describes
    ``cbtf``, else encoded now (:func:`encode_files`)."""
    if cbtf.encoded is not None and cbtf.encoded.describes(cbtf):
        return cbtf.encoded
    basis, coeff = encode_files(cbtf)
    return EncodedTextures(cbtf.codec, basis, tuple(coeff), (cbtf.basis.pixels, *(st.pixels for st in cbtf.coefficients)))


def encode_files(cbtf: CompressedBTF, indices=None, *, basis: bool = True) -> tuple[bytes | None, list[bytes]]:
    """(the basis image's bytes, the bytes of coefficient textures ``indices``, default all),
    encoded in one pool (:func:`.codecs.codec_map`), the basis first: the longest single
    encode does not run alone on one core after the others.  ``basis=False``: the
    coefficient textures alone, and None for the basis (rate control encodes the basis once
    it knows how many components the textures' bytes leave room for)."""
    codec = encoder(cbtf)
    indices = range(len(cbtf.coefficients)) if indices is None else indices
    jobs = [lambda: encode_basis(cbtf)] if basis else []
    jobs += [lambda i=i: codec.encode(cbtf.coefficients[i], "data") for i in indices]
    done = codec_map(codec, lambda job: job(), jobs)
    return (done[0], done[1:]) if basis else (None, done)


def write_textures(cbtf: CompressedBTF, folder: Path) -> dict:
    """Write basis and coefficient textures into an existing folder; returns byte counts
    (:meth:`EncodedTextures.sizes`).  ``cbtf`` is not changed."""
    enc = encoded_textures(cbtf)
    codec = get_codec(cbtf.codec)
    (folder / "coeff").mkdir(exist_ok=True)
    for i, data in enumerate(enc.coefficients):
        (folder / coefficient_file(codec, i)).write_bytes(data)
    (folder / basis_file(codec)).write_bytes(enc.basis)
    return enc.sizes()


def write_basis(cbtf: CompressedBTF, folder: Path) -> int:
    """Write the basis image (layout per :func:`basis_layout`); returns its bytes."""
    enc = cbtf.encoded
    data = enc.basis if enc is not None and enc.describes(cbtf) else encode_basis(cbtf)
    (folder / basis_file(get_codec(cbtf.codec))).write_bytes(data)
    return len(data)


def truncate(cbtf: CompressedBTF, k: int) -> CompressedBTF:
    """The first ``k`` components (coefficients are energy-ordered, so this is a level of detail).
    Not encoded: :func:`.encode.truncate_encoded` keeps the bytes of an encoded one."""
    if not 1 <= k <= cbtf.k:
        raise BTFError(f"cannot keep {k} of {cbtf.k} basis vectors")
    b = cbtf.basis
    basis = Stored(np.ascontiguousarray(b.pixels[:, :k]), b.scale[:k], b.bias[:k])
    return replace(cbtf, basis=basis, coefficients=list(cbtf.coefficients[:k]), info=dict(cbtf.info), encoded=None)


def metadata_document(cbtf: CompressedBTF) -> dict:
    """The JSON document describing ``cbtf`` (file names follow :func:`write_textures`)."""
    codec = get_codec(cbtf.codec)
    doc = {
        "format": FORMAT if cbtf.domain.is_linear else FORMAT_DOMAIN,
        "usdbtf_version": __version__,
        "width": cbtf.width, "height": cbtf.height, "k": cbtf.k, "n_samples": cbtf.n_samples,
        "codec": cbtf.codec,
        "working_space": cbtf.working_space,
        "ocio_config": cbtf.ocio_config,
        "source": cbtf.source,
        "color_matrix": [_floats(r) for r in cbtf.color_matrix],
        **({} if cbtf.domain.is_linear else {"domain": cbtf.domain.metadata()}),
        "basis": {"file": basis_file(codec), "scale": _floats(cbtf.basis.scale),
                  "bias": _floats(cbtf.basis.bias), "bit_depth": str(cbtf.basis.pixels.dtype),
                  "layout": basis_layout(cbtf.sampling, cbtf.k, cbtf.codec)},
        "coefficients": [{"file": coefficient_file(codec, i), "scale": _floats(s.scale), "bias": _floats(s.bias),
                          "bit_depth": str(s.pixels.dtype)} for i, s in enumerate(cbtf.coefficients)],
        "samples": {"view": np.asarray(cbtf.sampling.view, np.float64).tolist(),
                    "light": np.asarray(cbtf.sampling.light, np.float64).tolist(),
                    "interpolated": [int(i) for i in np.flatnonzero(cbtf.interpolated)]
                    if cbtf.interpolated is not None else []},
    }
    doc.update({key: v for key, v in cbtf.info.items() if key not in doc})
    return doc


_SIZE_MARK = -987654321  # unique placeholder for the metadata file's own size


def metadata_text(cbtf: CompressedBTF, sizes: dict | None = None) -> str:
    """The metadata file's text; its own size is recorded in it (``bytes.metadata``).

    ``sizes`` (from :func:`write_textures`) replaces the recorded ``bytes``; by default
    ``cbtf.info["bytes"]`` is kept.  Encoded once with a placeholder that is then replaced by
    the final size (the JSON for 10^4 sample directions is ~0.7 MB: encoding it twice would
    cost ~0.15 s).  ``cbtf`` is not changed.
    """
    doc = metadata_document(cbtf)
    recorded = (doc.get("bytes") or {}) if sizes is None else sizes
    doc["bytes"] = dict(recorded, metadata=_SIZE_MARK)
    text = jsontext.dumps(doc) + "\n"
    base = len(text.encode()) - len(str(_SIZE_MARK))
    size = base + 1
    while len(str(size)) + base != size:  # the number's own digits count too
        size = base + len(str(size))
    return text.replace(str(_SIZE_MARK), str(size), 1)


def write_metadata(cbtf: CompressedBTF, folder: Path, sizes: dict | None = None) -> int:
    """Write the metadata file (:func:`metadata_text`); returns its bytes."""
    text = metadata_text(cbtf, sizes)
    (folder / METADATA).write_text(text)
    return len(text.encode())


def _read_texture(entry, shape: tuple[int, int], channels: int | None = None, codec: Codec | None = None) -> np.ndarray:
    """A stored texture's pixels, checked against the expected (height, width) and for
    non-finite half floats (a planar codec's file unpacked to (H, W, 3) first)."""
    px = Codec.read(entry.file, channels=channels)
    if codec is not None:
        px = codec.texture(px, shape)
    if px.shape[:2] != shape:
        raise BTFError(f"{entry.file}: texture is {px.shape[1]}x{px.shape[0]}, expected {shape[1]}x{shape[0]}")
    if px.dtype.kind == "f" and not np.isfinite(px).all():
        raise BTFError(f"{entry.file}: stored values include NaN or Inf")
    return px


def read_compressed(folder) -> CompressedBTF:
    """Open a compressed BTF folder (reads every texture; they are small).

    The metadata is checked first (:func:`usdbtf.compress.validate.check_metadata`), so a
    damaged folder is one error naming the file and the key, before anything is allocated.
    """
    from .validate import check_metadata

    folder = Path(folder)
    path = folder / METADATA
    if not os.path.lexists(path):
        raise BTFError(f"{path}: not a compressed BTF (metadata file missing)")
    doc = jsontext.load(path, "compressed-BTF metadata file")
    meta = check_metadata(doc, folder, path)
    k, layout, S = meta.k, meta.layout, len(meta.sampling)
    want = (layout["views"] * layout["grid"][0], layout["lights"] * layout["grid"][1]) \
        if layout["kind"] == "tiles" else (S, k)
    image = Codec.read(meta.basis.file, channels=1)
    if image.shape[:2] != want:
        raise BTFError(f"{meta.basis.file}: basis image is {image.shape[1]}x{image.shape[0]}, expected "
                       f"{want[1]}x{want[0]} for k = {k}, {S} samples, layout {layout}")
    if image.dtype.kind == "f" and not np.isfinite(image).all():
        raise BTFError(f"{meta.basis.file}: stored values include NaN or Inf")
    basis = Stored(image_to_basis(image, layout, k), meta.basis.scale, meta.basis.bias)
    coeffs = [Stored(_read_texture(e, (meta.height, meta.width), codec=meta.codec), e.scale, e.bias)
              for e in meta.coefficients]
    return CompressedBTF(meta.sampling, meta.width, meta.height, basis, coeffs, meta.color_matrix, meta.codec.name,
                         meta.working_space, meta.source, meta.interpolated, meta.ocio_config, meta.info,
                         domain=meta.domain)


def folder_bytes(folder) -> int:
    """Bytes of every file under ``folder``."""
    return sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(folder) for f in fs)


def digest_without_platform(folder) -> tuple[str, dict]:
    """(SHA-256 over every file of a compressed folder, the metadata's ``provenance.numeric``
    left out; that record): equal for two folders exactly when everything the numeric
    platform decides is equal (``tests/test_numeric.py``, ``benchmarks/bench_numeric.py``).
    Raises KeyError when the metadata records no platform."""
    import hashlib
    import json

    folder = Path(folder)
    h = hashlib.sha256()
    platform = None
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        data = path.read_bytes()
        if path.name == METADATA:
            doc = json.loads(data)
            platform = doc["provenance"].pop("numeric")
            data = json.dumps(doc, sort_keys=True).encode()
        h.update(path.relative_to(folder).as_posix().encode() + b"\0" + data + b"\0")
    return h.hexdigest(), platform
