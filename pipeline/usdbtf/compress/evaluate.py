"""Evaluation: the error of what is stored, on held-out texels and as a curve over k.

Both use the paper's percent error (Fig. 3: "the sum of the differences between original
and reconstructed pixels divided by the sum of the original pixels"), here as
100 sum|x - x'| / sum x over working-space (scene-linear) values, reconstructed by Eq. (2)
from the stored -- quantised, encoded and decoded -- representation.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .curve import error_curve
from .format import CompressedBTF, working_coefficient_texels
from .metrics import ErrorSums
from .parallel import rows_apply, rows_gemm
from .texels import Texels

__all__ = ["HeldOut", "held_out_set", "held_out_error", "error_curve"]


@dataclass(frozen=True)
class HeldOut:
    """The texels error estimates are made on, with their true values.

    Attributes
    ----------
    texels : (n,) int, sorted texel indices.
    truth : (S, n, 3) float32 values there in the compress's working domain (scene-linear
        working space when the domain is linear; :func:`held_out_error` measures in
        scene-linear either way).
    disjoint : True when none of them was used in the fit (an out-of-sample estimate).
    """

    texels: np.ndarray
    truth: np.ndarray
    disjoint: bool
    encode: object = None
    _truths: dict = field(default_factory=dict, repr=False)

    def encoded(self, linear: np.ndarray) -> np.ndarray:
        """Scene-linear working-space values -> the input file's values, normalised to [0, 1]
        for integer files (clipped and rounded the way a file of that depth holds them)."""
        return self.encode(linear)

    def truth_in(self, domain, error_domain: str) -> np.ndarray:
        """The truth in scene-linear (``error_domain`` "linear") or as the file's values
        ("encoded"), from :attr:`truth` in the working ``domain``; computed once (rate control
        and the evaluation ask again and again)."""
        key = (domain, error_domain)
        if key not in self._truths:
            linear = self._truths.get((domain, "linear"))
            if linear is None:
                linear = domain.inverse(self.truth)
                self._truths[(domain, "linear")] = linear
            if error_domain == "encoded":
                self._truths[key] = self.encoded(linear)
        return self._truths[key]


def held_out_set(source, texels: Texels) -> HeldOut:
    """The evaluation texels and their true values.

    Parameters
    ----------
    source : where the data is read (see :mod:`.source`).
    texels : ``texels.evaluation`` are read; ``texels.held_out`` says whether they are disjoint
        from the fit.

    Returns
    -------
    HeldOut : truth (S, n, 3) float32 in working space (scene-linear).
    """
    ev = texels.evaluation
    truth = source.to_working(source.columns(ev)).reshape(source.btf.n_samples, len(ev), 3)
    return HeldOut(ev, truth, texels.held_out, file_encoder(source.btf))


def file_encoder(btf):
    """callable(working-space float (..., 3)) -> ``btf``'s file values as float32, normalised
    to [0, 1] for integer depths: what "error on the encoded values" compares."""
    from .. import colour
    from ..manifest import encode_for_file

    to_file = colour.processor(btf.working_space, btf.color_space, btf.ocio_config)
    top = np.float32({"uint8": 255.0, "uint16": 65535.0}.get(btf.bit_depth, 1.0))
    def encode(lin: np.ndarray) -> np.ndarray:
        return rows_apply(lambda block: encode_for_file(block, to_file, btf.bit_depth).astype(np.float32) / top,
                          lin, np.empty(lin.shape, np.float32))

    return encode


def held_out_error(cbtf: CompressedBTF, held: HeldOut, k: int | None = None, domain: str = "linear") -> ErrorSums:
    """Error of the stored representation, cut to its first ``k`` components, on the held-out
    texels over all samples.

    Parameters
    ----------
    cbtf : the stored representation (what a reader of its files gets).
    held : texels and their working-space truth (S, n, 3).
    k : components used (default all).
    domain : "linear" (scene-linear working space) or "encoded" (the input file's values,
        the reconstruction encoded as a file would hold it).

    Returns
    -------
    ErrorSums : ``percent`` (the paper's metric), ``rmse`` (linear units), ``psnr()``.
    """
    k = cbtf.k if k is None else k
    coeff = working_coefficient_texels(cbtf, held.texels, k)                     # (k, n, 3)
    rec = rows_gemm(cbtf.basis_values(k), coeff.reshape(k, -1)).reshape(held.truth.shape)
    sums = ErrorSums()
    dom = cbtf.domain
    truth = held.truth_in(dom, domain)                              # scene-linear, whatever the domain
    rec = rows_apply(dom.inverse, rec, rec)
    if domain == "encoded":
        rec = held.encoded(rec)
    sums.add(truth, rec)
    return sums
