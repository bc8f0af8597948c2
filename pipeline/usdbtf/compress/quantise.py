"""Quantisation: the float factors of a BTF -> stored integers (or halves) + de-quantisation.

:class:`Factorisation` is the state the later steps share: what the fit and the projection
made of the BTF, before anything is rounded.  :func:`quantise` keeps its first k
components with one of the :data:`QUANTISERS` (chosen by :attr:`CompressOptions.quantiser`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import color
from ..model import BTF
from .codecs import Stored, quantize_half, quantize_minmax, quantize_uniform
from .domain import LINEAR, Domain
from .format import CompressedBTF
from .options import CompressOptions
from .parallel import in_threads

__all__ = ["Factorisation", "quantise", "QUANTISERS", "basis_steps"]


@dataclass(frozen=True)
class Factorisation:
    """A BTF as float factors, I_s(t) = R sum_i U[s, i] c_i(t) (Eq. (2) with a colour matrix).

    Attributes
    ----------
    btf : the source BTF (sampling, size, colour space and path are recorded from it).
    basis : (S, k) float32 U, orthonormal columns, energy order.
    coefficients : (k, P, 3) float32 c, decorrelated colour planes, texels row-major;
        components a plane was not projected on are zero.
    color_matrix : (3, 3) float64 R, stored planes -> working-space RGB.
    total_energy : float, ||X||^2 of the whole BTF in working space (linear units squared;
        partly estimated): the rate-distortion residual outside the k components.
    planes : (k_0, k_1, k_2) components projected per colour plane.
    step : the uniform quantisation step already chosen for a plain k, or None (rate control
        chooses k and step; or the quantiser has no step).
    domain : the working-domain curve (:mod:`.domain`) basis and coefficients live in; the
        energies are in its units.
    """

    btf: BTF
    basis: np.ndarray
    coefficients: np.ndarray
    color_matrix: np.ndarray
    total_energy: float
    planes: tuple
    step: float | None = None
    domain: Domain = LINEAR

    @property
    def k(self) -> int:
        return self.basis.shape[1]


def _uniform(basis: np.ndarray, coeff: np.ndarray, textures: list, step: float, dead_zone: bool,
             eight_bit_factor: float = 1.0):
    """One uniform step for every coefficient (sparse colour planes rounded with a dead zone
    when ``dead_zone``, :func:`.codecs.uniform_codes`; a channel a little over 8 bits at the
    step coarser on its own up to ``eight_bit_factor``, :func:`.codecs.quantize_uniform`);
    basis column i gets step / sigma_i
    (reverse water-filling, see :mod:`.ratedist`), rounded to nearest (a dead zone on the
    basis columns measured no gain: ``benchmarks/probes/issue39_deadzone.py``)."""
    energy = np.einsum("kpc,kpc->k", coeff, coeff, dtype=np.float64)
    return _quantize_basis_columns(basis, basis_steps(step, energy, basis)), in_threads(
        lambda t: quantize_uniform(t, step, dead_zone, eight_bit_factor), textures)


def _minmax(basis: np.ndarray, coeff: np.ndarray, textures: list, step: float, dead_zone: bool,
            eight_bit_factor: float = 1.0):
    """The paper's storage: each texture min-max scaled to 8 bits, each basis vector too."""
    st = quantize_minmax(basis[None, :, :], per_channel=True)      # channels = columns
    return Stored(st.pixels[0][:, :, None], st.scale, st.bias), in_threads(
        lambda t: quantize_minmax(t, per_channel=False), textures)


def _half(basis: np.ndarray, coeff: np.ndarray, textures: list, step: float, dead_zone: bool,
          eight_bit_factor: float = 1.0):
    """Half floats with a power-of-two scale per channel: no quantisation step at all."""
    st = quantize_half(basis[None, :, :])                              # channels = basis columns
    return Stored(st.pixels[0][:, :, None], st.scale, st.bias), in_threads(quantize_half, textures)


#: name -> quantiser(basis (S, k), coefficients (k, P, 3), k textures (H, W, 3), step, dead_zone,
#:         eight_bit_factor) -> (basis Stored (S, k, 1), k coefficient Stored).  Only "uniform"
#:         has a step, a dead zone and the 8-bit fit (:attr:`.options.CompressOptions.dead_zone`,
#:         ``eight_bit_factor``); the others ignore them.
QUANTISERS = {"uniform": _uniform, "minmax": _minmax, "half": _half}


def quantise(f: Factorisation, k: int, step: float, options: CompressOptions) -> CompressedBTF:
    """The first ``k`` components of ``f`` as stored values, not yet encoded.

    Parameters
    ----------
    f : the factorisation.
    k : components to keep (<= f.k).
    step : uniform quantisation step (working-space linear units); ignored by the other
        quantisers.
    options : ``quantiser``, ``dead_zone`` and ``codec_name`` decide how and for what.

    Returns
    -------
    CompressedBTF with basis (S, k, 1) and k coefficient textures (H, W, 3), their
    de-quantisation scale and bias, and the source's colour and sampling metadata.
    """
    btf = f.btf
    textures = [f.coefficients[i].reshape(btf.height, btf.width, 3) for i in range(k)]
    basis, coeffs = QUANTISERS[options.quantiser](f.basis[:, :k], f.coefficients[:k], textures, step,
                                                   options.dead_zone, options.eight_bit_factor)
    return CompressedBTF(
        sampling=btf.sampling, width=btf.width, height=btf.height, basis=basis, coefficients=coeffs,
        color_matrix=f.color_matrix, codec=options.codec_name, quick_encode=options.quick_encode,
        working_space=color.resolve_space(btf.working_space, btf.ocio_config),
        source={"color_space": btf.color_space, "bit_depth": btf.bit_depth,
                "path": btf.path},
        interpolated=btf.interpolated, ocio_config=btf.ocio_config, domain=f.domain)


def _quantize_basis_columns(u: np.ndarray, steps: np.ndarray) -> Stored:
    """Uniform per-column steps; 16-bit when any column needs more than 256 levels."""
    q = np.rint(u / steps.astype(np.float32)).astype(np.int64)
    lo = q.min(axis=0)
    span = int((q.max(axis=0) - lo).max())
    dtype = np.uint8 if span < 256 else np.uint16
    return Stored((q - lo).astype(dtype)[:, :, None], steps.astype(np.float64), lo * steps.astype(np.float64))


def basis_steps(step: float, energy: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(k,) quantisation steps of the basis columns: step / sigma_i, sigma_i^2 = ``energy``
    (the components' coefficient energies), capped at each column's span and kept within
    16 bits."""
    sigma = np.sqrt(np.maximum(energy, 1e-300))
    # A column whose coefficients are all zero needs no precision: cap its step at its span.
    colspan = u.max(axis=0) - u.min(axis=0)
    steps = np.minimum(step / sigma, np.where(colspan > 0, colspan, 1.0))
    # Keep every column within 16 bits (only binds for huge dynamic range).
    span = (u.max(axis=0) - u.min(axis=0)) / steps
    return np.where(span >= 2**16 - 2, (u.max(axis=0) - u.min(axis=0)) / (2**16 - 2), steps)
