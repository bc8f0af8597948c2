"""The one BTF data model every stage speaks.

A BTF is S samples, each an H x W RGB image of the rectified material taken
under one (view, light) direction pair.  Pixel data is never required to be in
memory at once: read it in chunks of samples (``iter_chunks``) or of pixel rows
(``read_rows``).  Values handed out by ``read_samples``/``read_rows`` are float32
scene-linear in the working space (OCIO ``scene_linear`` role by default).

Implementations:

* :class:`ArrayBTF` -- in memory (tests, synthesis, reconstructions);
* :class:`FileBTF`  -- one image file per sample (manifest folders, UBO2003 data).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Iterator, Sequence

import numpy as np

from . import color
from .errors import BTFError
from .imageio import read_image, read_info
from .sampling import Sampling

__all__ = ["BTF", "ArrayBTF", "FileBTF", "validate_sampling", "check_finite"]


def validate_sampling(sampling: Sampling, names: Sequence[str]) -> Sampling:
    """Check directions are finite, theta in [0, 90], no (view, light) pair repeated.

    Returns the sampling with phi wrapped to [0, 360) (and phi = 0 at the pole).
    Raises BTFError naming the offending sample(s).
    """
    if len(sampling) == 0:
        raise BTFError("the BTF has no samples")
    both = np.concatenate([sampling.view, sampling.light], axis=1)
    for i in np.flatnonzero(~np.isfinite(both).all(axis=1))[:1]:
        raise BTFError(f"sample {names[i]}: direction is not a finite number")
    theta = both[:, [0, 2]]
    for i in np.flatnonzero(((theta < 0) | (theta > 90)).any(axis=1))[:1]:
        raise BTFError(f"sample {names[i]}: theta out of range [0, 90] deg (view {both[i, :2].tolist()}, light {both[i, 2:].tolist()})")
    phi = np.mod(both[:, [1, 3]], 360.0)
    phi[theta == 0] = 0.0  # azimuth is meaningless at the pole; make duplicates there detectable
    canon = np.stack([theta[:, 0], phi[:, 0], theta[:, 1], phi[:, 1]], axis=1)
    key = np.round(canon, 6)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    if (counts > 1).any():
        dup = key[first[np.argmax(counts > 1)]]
        where = np.flatnonzero((key == dup).all(axis=1))
        raise BTFError(f"samples {names[where[0]]} and {names[where[1]]} have the same view and light directions "
                       f"(view {dup[:2].tolist()}, light {dup[2:].tolist()})")
    return Sampling(canon[:, :2], canon[:, 2:])


def check_finite(pixels: np.ndarray, what: str, names: Sequence[str] | None = None) -> None:
    """Raise BTFError if ``pixels`` holds NaN, Inf or negative values.

    The message names ``what``, and when ``names`` labels the first axis (one name per
    sample) also the first offending sample.
    """
    if pixels.dtype.kind != "f":
        return
    for bad, problem in ((~np.isfinite(pixels), "NaN or Inf"),
                         (pixels < 0, "negative numbers (radiance must be >= 0)")):
        if bad.any():
            where = ""
            if names is not None and pixels.ndim >= 1 and len(names) == pixels.shape[0]:
                first = int(np.argmax(bad.reshape(pixels.shape[0], -1).any(axis=1)))
                where = f" sample {names[first]}"
            raise BTFError(f"{what}{where}: pixel values include {problem}")


@dataclass
class BTF:
    """Base class: directions, size, colour space; subclasses supply pixels.

    Attributes
    ----------
    sampling : Sampling, S (view, light) pairs in degrees.
    width, height : int, texels.
    color_space : str, OCIO name of the stored encoding (what files on disk are in).
    bit_depth : str, stored encoding's type: "uint8", "uint16", "half" or "float".
    names : list[str], one label per sample for error messages (e.g. its file name).
    interpolated : (S,) bool, True for samples filled in rather than measured.
    working_space, ocio_config : where decoded values go.
    metadata : dict of extra keys carried through (e.g. physical size).
    path : the file or folder the BTF was opened from, as given (:func:`usdbtf.io.open_btf`
        sets it; errors and provenance name it); "" for a BTF made in memory.
    """

    sampling: Sampling
    width: int
    height: int
    color_space: str
    bit_depth: str = "float"
    names: list = field(default_factory=list)
    interpolated: np.ndarray | None = None
    working_space: str = color.WORKING_SPACE
    ocio_config: str | None = None
    metadata: dict = field(default_factory=dict)
    path: str = ""

    def __post_init__(self):
        if not self.names:
            self.names = [f"#{i}" for i in range(len(self.sampling))]
        if self.interpolated is None:
            self.interpolated = np.zeros(len(self.sampling), bool)
        if self.width <= 0 or self.height <= 0:
            raise BTFError(f"image size must be positive, got {self.width}x{self.height}")
        self.sampling = validate_sampling(self.sampling, self.names)

    # -- sizes -------------------------------------------------------------
    @property
    def n_samples(self) -> int:
        return len(self.sampling)

    @property
    def n_pixels(self) -> int:
        return self.width * self.height

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(S, H, W, 3)"""
        return (self.n_samples, self.height, self.width, 3)

    # -- colour ------------------------------------------------------------
    @property
    def integer_decoder(self) -> color.IntegerDecoder | None:
        """The verified table decode for integer encodings, else None."""
        if self.bit_depth in ("uint8", "uint16"):
            return color.integer_decoder(self.color_space, 8 if self.bit_depth == "uint8" else 16,
                                          self.working_space, self.ocio_config)
        return None

    def decode(self, encoded: np.ndarray, what: str = "", names: Sequence[str] | None = None) -> np.ndarray:
        """Stored encoding (..., 3) -> float32 working space (..., 3).

        ``names`` labels the first axis for error messages (default: this BTF's sample
        names when the first axis has one entry per sample)."""
        dec = self.integer_decoder
        if dec is not None:
            return dec.decode(encoded)
        if names is None and encoded.ndim >= 1 and encoded.shape[0] == self.n_samples:
            names = self.names
        check_finite(encoded, what or "BTF", names)
        return color.processor(self.color_space, self.working_space, self.ocio_config).apply(encoded)

    # -- pixel access (subclasses implement read_encoded) ------------------
    def read_encoded(self, indices, rows: tuple[int, int] | None = None) -> np.ndarray:
        """Stored values of samples ``indices``: (n, h, W, 3) in the native dtype."""
        raise NotImplementedError

    def read_samples(self, indices) -> np.ndarray:
        """(n, H, W, 3) float32 working-space images of samples ``indices``."""
        idx = np.atleast_1d(np.arange(self.n_samples)[indices])
        return self.decode(self.read_encoded(idx), what=f"samples {self.names[idx[0]]}..{self.names[idx[-1]]}")

    def iter_chunks(self, chunk: int = 256) -> Iterator[tuple[slice, np.ndarray]]:
        """Yield (slice of sample indices, (n, H, W, 3) float32) over all samples."""
        for start in range(0, self.n_samples, chunk):
            sl = slice(start, min(start + chunk, self.n_samples))
            yield sl, self.read_samples(sl)

    def read_rows(self, y0: int, y1: int) -> np.ndarray:
        """Pixel chunk: rows y0..y1 of every sample, (S, y1 - y0, W, 3) float32 working space."""
        return self.decode(self.read_encoded(np.arange(self.n_samples), rows=(y0, y1)), what=f"rows {y0}..{y1}")


@dataclass
class ArrayBTF(BTF):
    """A BTF held in memory: ``data`` (S, H, W, 3) in ``color_space`` with dtype per ``bit_depth``."""

    data: np.ndarray | None = None

    @classmethod
    def from_linear(cls, sampling: Sampling, data: np.ndarray, **kw) -> "ArrayBTF":
        """Wrap float32 working-space images (S, H, W, 3)."""
        data = np.asarray(data, dtype=np.float32)
        if data.ndim != 4 or data.shape[-1] != 3 or data.shape[0] != len(sampling):
            raise BTFError(f"expected (S={len(sampling)}, H, W, 3) pixels, got {data.shape}")
        check_finite(data, "in-memory BTF", [f"#{i}" for i in range(len(data))])
        kw.setdefault("working_space", color.WORKING_SPACE)
        return cls(sampling=sampling, width=data.shape[2], height=data.shape[1], color_space=kw["working_space"],
                   bit_depth="float", data=data, **kw)

    def read_encoded(self, indices, rows=None):
        idx = np.arange(self.n_samples)[indices]
        block = self.data[idx]
        return block if rows is None else block[:, rows[0]:rows[1]]


@dataclass
class FileBTF(BTF):
    """One image file per sample, e.g. a manifest folder or a UBO2003 folder.

    ``paths`` lists the S image files in sample order.  Every image must be
    ``width`` x ``height``, 1/3/4 channels, and share ``bit_depth``.
    """

    paths: list = field(default_factory=list)

    def __post_init__(self):
        if len(self.paths) != len(self.sampling):
            raise BTFError(f"{len(self.paths)} image paths for {len(self.sampling)} samples")
        if not self.names:
            self.names = [os.path.basename(p) for p in self.paths]
        super().__post_init__()
        for p in self.paths:
            if not os.path.isfile(p):
                raise BTFError(f"{p}: image file not found")

    @classmethod
    def probe(cls, paths, sampling, color_space: str | None, **kw) -> "FileBTF":
        """Build from the first image's header (size, bit depth, declared colour space)."""
        if not paths:
            raise BTFError("the BTF has no samples")
        info = read_info(paths[0])
        if info.bit_depth not in ("uint8", "uint16", "half", "float"):
            raise BTFError(f"{paths[0]}: unsupported bit depth {info.bit_depth}")
        space = color_space or info.color_space or ("sRGB Encoded Rec.709 (sRGB)" if info.bit_depth == "uint8" else "scene_linear")
        kw.setdefault("width", info.width)
        kw.setdefault("height", info.height)
        return cls(sampling=sampling, color_space=space, bit_depth=info.bit_depth, paths=list(paths), **kw)

    def read_one(self, i: int, rows=None) -> np.ndarray:
        """Stored values of sample i, (h, W, 3), with size and bit depth checked."""
        return self.read_file(self.paths[i], rows)

    def read_file(self, path, rows=None) -> np.ndarray:
        """Stored values of the image file ``path`` (h, W, 3), checked against this BTF's
        size and bit depth (subclasses that hand OIIO another path per sample use this)."""
        pixels, info = read_image(path, expect=(self.width, self.height), rows=rows)
        if info.bit_depth != self.bit_depth:
            raise BTFError(f"{path}: bit depth {info.bit_depth} differs from the dataset's {self.bit_depth}")
        if pixels.dtype.kind == "f":
            check_finite(pixels, path)
        return pixels

    def read_encoded(self, indices, rows=None, out: np.ndarray | None = None):
        """Stored values of samples ``indices`` (see :meth:`BTF.read_encoded`), into ``out``
        when given ((n, h, W, 3) of the stored dtype: a decode worker reuses one array for
        every chunk instead of faulting in fresh pages for each)."""
        idx = np.atleast_1d(np.arange(self.n_samples)[indices])
        h = self.height if rows is None else rows[1] - rows[0]
        first = self.read_one(int(idx[0]), rows)
        if out is None:
            out = np.empty((len(idx), h, self.width, 3), first.dtype)
        out[0] = first
        for n, i in enumerate(idx[1:], start=1):
            out[n] = self.read_one(int(i), rows)
        return out
