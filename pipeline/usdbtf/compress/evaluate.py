"""Evaluation: the error of what is stored, on held-out texels and as a curve over k.

Both use the paper's percent error (Fig. 3: "the sum of the differences between original
and reconstructed pixels divided by the sum of the original pixels"), here as
100 sum|x - x'| / sum x over scene-linear values or the input file's values, reconstructed by
Eq. (2) from the stored -- quantised, encoded and decoded -- representation.  The estimate
stands for every texel: held-out texels for those not fitted, a sample of the fitted ones
for those (reconstructed better, in-sample), each weighted by its stratum's share.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .code_table import file_codes
from .curve import error_curve
from .format import CompressedBTF, working_coefficient_texels
from .metrics import ErrorSums
from .parallel import in_threads, one_blas_thread, rows_apply
from .texels import Texels

#: Samples per block of the held-out error (fixed: the sums do not depend on the CPUs).
_EVAL_BLOCK = 256

__all__ = ["HeldOut", "held_out_set", "held_out_error", "held_out_errors", "error_curve"]


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
    in_sample : a sample of the fitted texels (a :class:`HeldOut` of its own, not disjoint),
        or None when ``texels`` are every texel.
    weights : (held-out, in-sample) texels of the image each sampled texel stands for.
    codes : (S, n, 3) uint8 or uint16, the input files' own codes there, when the source
        stores them (integer files): the encoded truth as the files hold it, with no
        conversion back from :attr:`truth` (issue 42: that conversion was a third of a plain
        compress's evaluation).  None: the encoded truth is converted from :attr:`truth`.
    """

    texels: np.ndarray
    truth: np.ndarray
    disjoint: bool
    encode: object = None
    _codes: dict = field(default_factory=dict, repr=False)
    in_sample: "HeldOut | None" = None
    weights: tuple = (1.0, 0.0)
    codes: np.ndarray | None = None

    def encoded(self, linear: np.ndarray) -> np.ndarray:
        """Scene-linear working-space values -> the input file's values, normalised to [0, 1]
        for integer files (clipped and rounded the way a file of that depth holds them)."""
        return self.encode(linear)

    def truth_block(self, domain, error_domain: str, samples: slice) -> np.ndarray:
        """The truth of ``samples`` in scene-linear (``error_domain`` "linear") or as the
        file's values ("encoded", normalised): the files' own :attr:`codes` where kept, else
        converted from :attr:`truth` in the working ``domain`` once per block and kept (rate
        control asks again and again)."""
        if error_domain != "encoded":
            return domain.inverse(self.truth[samples])
        top, dtype = getattr(self.encode, "top", None), getattr(self.encode, "code_dtype", None)
        if self.codes is not None:
            return self.codes[samples].astype(np.float32) / np.float32(top)
        key = (domain, samples.start, samples.stop)
        if key in self._codes:
            kept = self._codes[key]
            return kept if dtype is None else kept.astype(np.float32) / np.float32(top)
        values = self.encoded(domain.inverse(self.truth[samples]))
        # Integer files' values are kept as their codes (a quarter of the float32 size for
        # 8-bit): code / top gives back the same float32 values.
        self._codes[key] = values if dtype is None else np.rint(values * np.float32(top)).astype(dtype)
        return values


def held_out_set(source, texels: Texels) -> HeldOut:
    """The evaluation texels and their true values.

    Parameters
    ----------
    source : where the data is read (see :mod:`.source`).
    texels : ``texels.evaluation`` are read; ``texels.held_out`` says whether they are disjoint
        from the fit; ``texels.in_sample`` (fitted texels) too when they are.

    Returns
    -------
    HeldOut : truth (S, n, 3) float32 in working space (scene-linear); ``in_sample`` the
    same of ``texels.in_sample``, and the two strata's weights.
    """
    encode = file_encoder(source.btf)
    shape = lambda ev: (source.btf.n_samples, len(ev), 3)

    def truth(ev: np.ndarray) -> dict:
        # The codes first: a source that keeps only some texels' columns hands them over
        # (forgets them) when they are decoded.
        codes = _file_codes(source, ev, encode)
        return {"truth": source.to_working(source.columns(ev)).reshape(shape(ev)),
                "codes": None if codes is None else codes.reshape(shape(ev))}

    ev = texels.evaluation
    if not texels.held_out or texels.in_sample is None:
        return HeldOut(ev, disjoint=texels.held_out, encode=encode, **truth(ev))
    inner = HeldOut(texels.in_sample, disjoint=False, encode=encode, **truth(texels.in_sample))
    n_fit = len(texels.fit)
    return HeldOut(ev, disjoint=True, encode=encode, in_sample=inner,
                   weights=((source.btf.n_pixels - n_fit) / len(ev), n_fit / len(texels.in_sample)), **truth(ev))


def _file_codes(source, texels: np.ndarray, encode) -> np.ndarray | None:
    """(S, 3 n) the input files' integer codes of ``texels`` as the source stores them, or
    None when it stores something else (floats, a shaped input's filtered values, factors)."""
    raw_columns = getattr(source, "raw_columns", None)
    if encode.code_dtype is None or raw_columns is None:
        return None
    raw = raw_columns(texels)
    return raw if raw.dtype == encode.code_dtype else None


def file_encoder(btf):
    """callable(working-space float (..., 3)) -> ``btf``'s file values as float32, normalised
    to [0, 1] for integer depths: what "error on the encoded values" compares."""
    top = np.float32({"uint8": 255.0, "uint16": 65535.0}.get(btf.bit_depth, 1.0))
    to_codes = file_codes(btf)        # 8-bit files by table where one serves (.code_table: half the cost)

    def encode(lin: np.ndarray) -> np.ndarray:
        return rows_apply(lambda block: to_codes(block).astype(np.float32) / top, lin, np.empty(lin.shape, np.float32))

    encode.top = float(top)
    encode.code_dtype = {"uint8": np.uint8, "uint16": np.uint16}.get(btf.bit_depth)
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
    return held_out_errors(cbtf, held, k, (domain,))[0]


def held_out_errors(cbtf: CompressedBTF, held: HeldOut, k: int | None = None,
                    domains=("linear", "encoded")) -> list:
    """:func:`held_out_error` in each of ``domains``, from one reconstruction per block of
    samples (the same sums, bit for bit, as one call per domain).  With an in-sample stratum
    (``held.in_sample``), each stratum's sums weighted by the texels it stands for."""
    sums = _stratum_errors(cbtf, held, k, domains)
    if held.in_sample is None:
        return sums
    inner = _stratum_errors(cbtf, held.in_sample, k, domains)
    out = []
    for outside, fitted in zip(sums, inner):
        both = ErrorSums()
        both.merge_scaled(outside, held.weights[0])
        both.merge_scaled(fitted, held.weights[1])
        out.append(both)
    return out


def _stratum_errors(cbtf: CompressedBTF, held: HeldOut, k: int | None, domains) -> list:
    """Unweighted :class:`ErrorSums` over ``held``'s own texels, one per domain."""
    k = cbtf.k if k is None else k
    coeff = working_coefficient_texels(cbtf, held.texels, k).reshape(k, -1)      # (k, n * 3)
    basis = cbtf.basis_values(k)                                                  # (S, k)
    dom = cbtf.domain
    n = held.truth.shape[0]
    shape = held.truth.shape[1:]

    def block(a: int) -> list:
        # One block of samples at a time (a reconstruction of every sample at once would be
        # as large as the held-out truth again, twice with the encoded copy).
        sl = slice(a, min(a + _EVAL_BLOCK, n))
        linear = dom.inverse(basis[sl] @ coeff).reshape((-1,) + shape)   # scene-linear, whatever the domain
        parts = []
        for domain in domains:
            part = ErrorSums()
            part.add(held.truth_block(dom, domain, sl), held.encoded(linear) if domain == "encoded" else linear)
            parts.append(part)
        return parts

    sums = [ErrorSums() for _ in domains]
    with one_blas_thread():                                           # the sums as on any machine
        blocks = in_threads(block, range(0, n, _EVAL_BLOCK))
    for parts in blocks:                                              # added in block order
        for total, part in zip(sums, parts):
            total.merge(part)
    return sums
