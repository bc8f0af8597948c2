"""Exact basis and coefficients of a factorised BTF whose decode is linear, from the factors alone.

A DFMF file stores, per channel c of a decorrelated colour model, the channel values
X_c = A_c B_c^T (A_c over samples, S x k_c; B_c over texels, T x k_c).  When everything the
reader does after that product is linear -- colour models 0 (RGB), 1 (YUV), 3 (PCA: a matrix
plus a mean) and 4 (YCoCg), no dynamic-range restore, the light-cosine division (a scale per
sample), an OCIO conversion to the working space that is a 3 x 3 matrix -- working-space
channel i of texel t is

    x_i(t) = sum_c mix[i, c] A'_c b_c(t)        (S,)

with A'_c = diag(r) A_c (r the per-sample scale) and constant "channels" for the offsets (the
PCA mean: A' = r, b = 1; an offset of the OCIO conversion: A' = 1, b = 1).  So the data
matrix X (S x 3T, column 3 t + i) is A' Z, A' = [A'_0 | A'_1 | ...] (S x K, K = sum k_c,
about 250 for UBO2014), and:

* QR: A' = Q R, so X = Q H with H = R Z (K x 3T), computed one texel block at a time;
* basis: the left singular vectors of X are Q V, V the eigenvectors of H H^T (K x K, summed
  over texel blocks in float64; with fit.py's HDR weights when the texel norms call for them);
* coefficients of any orthonormal U: U^T x_i(t) = (U^T Q) h_i(t), a (k x K) (K,) product per
  texel and channel.

Costs O(S K^2) (the QR) + O(T K^2) (Gram, H) + O(T K k) (coefficients); memory: the factors,
Q (S x K float64) and one texel block of H -- never an image.

What is *not* linear is not done here: the reader's clamp of negative values to 0 (see
:mod:`.factored` for how that is handled), colour models with logarithms (9-12) or products
(5, 6), and FMF's dynamic-range restore; :func:`linear_decode` returns None for those, after
checking the reader's own decode against the linear map it probed.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import color
from .fit import BasisFit, norm_weights, signal_only
from .linalg import fix_signs

__all__ = ["LinearDecode", "linear_decode", "working_map", "mix_planes", "FactorFrame", "exact_fit",
           "exact_coefficients", "TEXEL_BLOCK"]

#: Texels per block of H (3 x K x block float64: ~25 MB at K = 256).
TEXEL_BLOCK = 4096
#: Relative agreement a probed linear map must reach with the decode it stands for.
_LINEAR_TOLERANCE = 1e-5
_PROBE_SAMPLES = 64
_PROBE_TEXELS = 16


@dataclass(frozen=True)
class LinearDecode:
    """A factorised BTF's working-space pixels as a linear function of its factors.

    samples : per channel, (S, k_c) float64 sample factors with the per-sample scale applied.
    texels : per channel, (T, k_c) float32 texel factors.
    mix : (3, C) float64, working channel i = sum_c mix[i, c] samples[c] @ texels[c].T.
    to_working, working_offset : (3, 3) and (3,) float64, the colour-space conversion (file
        RGB -> working RGB = to_working @ rgb + working_offset).
    """

    samples: tuple
    texels: tuple
    mix: np.ndarray
    to_working: np.ndarray
    working_offset: np.ndarray


def linear_decode(btf) -> LinearDecode | None:
    """The linear map from ``btf.factors`` to working-space pixels, or None when the decode is
    not linear.

    Probed from the reader's own ``channels_to_rgb`` (without its clamp) and the OCIO
    conversion: unit and zero channel values give the colour matrix, offset and per-sample
    scale; random values (negative ones too) must then agree with the map to 1e-5 relative,
    or the decode counts as nonlinear.

    Parameters
    ----------
    btf : a BTF with ``factors`` (a :class:`~usdbtf.ubo2014.Factorisation` of 3 channels) and
        ``channels_to_rgb(planes, samples, clamp=...)`` (:class:`~usdbtf.ubo2014.UBO2014BTF`).
    """
    f = btf.factors
    S, nc = btf.n_samples, len(f.channels)
    model = _model_map(btf, S, nc)
    work = working_map(btf)
    if model is None or work is None:
        return None
    scale, matrix, offset = model
    w_matrix, w_offset = work
    samples = [scale[:, None] * f.float32(c, "samples").astype(np.float64) for c in range(nc)]
    texels = [f.float32(c, "texels") for c in range(nc)]
    mix = [w_matrix @ matrix]
    ones = np.ones((btf.n_pixels, 1), np.float32)
    if np.any(w_matrix @ offset):           # the colour model's offset, scaled per sample like the rest
        samples.append(scale[:, None])
        texels.append(ones)
        mix.append((w_matrix @ offset)[:, None])
    if np.any(w_offset):                    # an offset of the colour-space conversion, not scaled
        samples.append(np.ones((S, 1)))
        texels.append(ones)
        mix.append(w_offset[:, None])
    return LinearDecode(tuple(samples), tuple(texels), np.concatenate(mix, axis=1), w_matrix, w_offset)


def _model_map(btf, S: int, nc: int):
    """(scale (S,), matrix (3, nc), offset (3,)) with rgb(s) = scale[s] (matrix c + offset) for
    the reader's decode after the product, or None when it is not of that form."""
    probe = np.zeros((nc, S, nc + 1), np.float32)
    for c in range(nc):
        probe[c, :, c] = 1.0
    with np.errstate(all="ignore"):
        out = btf.channels_to_rgb(probe, np.arange(S), clamp=False).astype(np.float64)    # (3, S, nc + 1)
    if out.shape[0] != 3 or not np.isfinite(out).all():
        return None
    off = out[:, :, nc]                                                                      # (3, S)
    per = out[:, :, :nc] - off[:, :, None]                                                   # (3, S, nc)
    ref = int(np.argmax(np.abs(per).sum(axis=(0, 2))))
    matrix = per[:, ref, :]
    if not np.any(matrix):
        return None
    scale = np.einsum("isc,ic->s", per, matrix) / np.sum(matrix * matrix)
    offset = off[:, ref] / scale[ref] if scale[ref] else np.zeros(3)
    # Every sample's map must be this one scaled ...
    if not (_agree(per, scale[None, :, None] * matrix[:, None, :]) and _agree(off, scale[None, :] * offset[:, None])):
        return None
    # ... and reproduce the decode on random values (a log or product model will not).
    rng = np.random.default_rng(0)
    idx = np.sort(rng.choice(S, size=min(S, _PROBE_SAMPLES), replace=False))
    values = rng.standard_normal((nc, len(idx), _PROBE_TEXELS)).astype(np.float32)
    with np.errstate(all="ignore"):
        got = btf.channels_to_rgb(values.copy(), idx, clamp=False).astype(np.float64)
    want = scale[idx][None, :, None] * (np.einsum("ic,cnt->int", matrix, values.astype(np.float64))
                                        + offset[:, None, None])
    return (scale, matrix, offset) if _agree(got, want) else None


def working_map(btf):
    """(matrix (3, 3), offset (3,)) float64 of OCIO's conversion from the BTF's colour space to
    its working space (working = matrix @ rgb + offset), or None when it is not affine
    (checked on random colours to 1e-5 relative)."""
    proc = color.processor(btf.color_space, btf.working_space, btf.ocio_config)
    base = proc.apply(np.zeros((1, 3), np.float32))[0].astype(np.float64)
    matrix = (proc.apply(np.eye(3, dtype=np.float32)).astype(np.float64) - base).T          # column c = image of e_c
    values = np.random.default_rng(1).standard_normal((256, 3)).astype(np.float32) * 4
    got = proc.apply(values).astype(np.float64)
    return (matrix, base) if _agree(got, values.astype(np.float64) @ matrix.T + base) else None


def mix_planes(matrix: np.ndarray, planes: np.ndarray, offset=None) -> np.ndarray:
    """``matrix @ rgb + offset`` on colour planes: (3, ...) float32 in, (3, ...) float32 out,
    as float32 multiply-adds plane by plane (planar data: no interleaving, no K = 3 GEMM)."""
    m = np.asarray(matrix, np.float32)
    out = np.empty(planes.shape, np.float32)
    for j in range(3):
        np.multiply(planes[0], m[j, 0], out=out[j])
        for i in (1, 2):
            if m[j, i]:
                out[j] += planes[i] * m[j, i]
        if offset is not None and offset[j]:
            out[j] += np.float32(offset[j])
    return out


def _agree(got: np.ndarray, want: np.ndarray) -> bool:
    return bool(np.isfinite(got).all() and
                np.all(np.abs(got - want) <= _LINEAR_TOLERANCE * np.maximum(np.abs(want), 1.0)))


class FactorFrame:
    """X = Q H: the orthonormal sample frame Q of a :class:`LinearDecode` and the texel
    blocks of H (see the module docstring).

    Attributes
    ----------
    q : (S, K) float64, orthonormal columns.
    """

    def __init__(self, decode: LinearDecode):
        a = np.concatenate(decode.samples, axis=1)
        self.q, r = np.linalg.qr(a)
        edges = np.cumsum([0] + [s.shape[1] for s in decode.samples])
        self._r = [np.ascontiguousarray(r[:, a0:a1]) for a0, a1 in zip(edges[:-1], edges[1:])]
        self._texels = decode.texels
        self._mix = decode.mix

    @property
    def rank(self) -> int:
        """K, the columns of Q."""
        return self.q.shape[1]

    def block(self, texels) -> np.ndarray:
        """(3, K, n) float64 h_i(t) of ``texels`` (a slice or an index array), x_i(t) = Q h_i(t)."""
        parts = [rc @ tc[texels].astype(np.float64).T for rc, tc in zip(self._r, self._texels)]   # (K, n) each
        h = np.zeros((3,) + parts[0].shape)
        for i in range(3):
            for c, part in enumerate(parts):
                if self._mix[i, c]:
                    h[i] += self._mix[i, c] * part
        return h


def _blocks(n_texels: int, size: int = TEXEL_BLOCK):
    return [slice(a, min(a + size, n_texels)) for a in range(0, n_texels, size)]


def exact_fit(frame: FactorFrame, k: int, n_texels: int, fit_texels: np.ndarray) -> BasisFit:
    """The top-k left singular vectors of the whole data matrix X = Q H, from H H^T.

    Texel norms are ||h(t)|| (Q is orthonormal); when they span more than fit.py's
    HDR_NORM_RANGE the Gram is weighted as :func:`~.fit.fit_weights` weights a fit, with a
    second pass over the blocks.

    Parameters
    ----------
    frame : the factor frame.
    k : basis vectors wanted (at most K are found).
    n_texels : T.
    fit_texels : (n,) texels whose coefficients the fit reports (``BasisFit.coefficients``,
        used by the colour and step choices like an rsvd fit's).

    Returns
    -------
    BasisFit : basis (S, k) float32 (signs fixed), singular values of the (weighted) X,
    coefficients (k, 3 n) float32 working space, interleaved.
    """
    K = frame.rank
    gram = np.zeros((K, K))
    norms = np.empty(n_texels)
    for sl in _blocks(n_texels):
        h = frame.block(sl)
        norms[sl] = np.sqrt(np.einsum("ikn,ikn->n", h, h))
        for hi in h:
            gram += hi @ hi.T
    weights = norm_weights(norms)
    if weights is not None:
        gram[:] = 0
        for sl in _blocks(n_texels):
            for hi in frame.block(sl):
                hw = hi * weights[sl]
                gram += hw @ hw.T
    evals, vecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1][:min(k, K)]
    sv = np.sqrt(np.maximum(evals[order], 0.0))
    u = np.ascontiguousarray(frame.q @ vecs[:, order], dtype=np.float32)
    fix_signs(u)
    coeff, _ = exact_coefficients(frame, u, np.eye(3), (u.shape[1],) * 3, fit_texels=fit_texels)
    fit = BasisFit(u, sv, coeff.reshape(u.shape[1], -1), weights is not None)
    return signal_only(fit)


def exact_coefficients(frame: FactorFrame, u: np.ndarray, mix: np.ndarray, ks, *, n_texels: int | None = None,
                       fit_texels: np.ndarray | None = None, energy: bool = False):
    """Coefficients of every texel (or of ``fit_texels``) on the basis ``u``, exactly.

    c_j(t) = U[:, :k_j]^T y_j(t), y(t) = mix @ x(t): the projection of :mod:`.projection`
    computed as (U^T Q) (mix h(t)).

    Parameters
    ----------
    frame : the factor frame.
    u : (S, k) float32 basis.
    mix : (3, 3) colour mix applied to working-space RGB (the projection's).
    ks : (k_0, k_1, k_2) components per plane (the rest stay zero).
    n_texels : T, for all texels; or ``fit_texels`` (n,) for those only.
    energy : also return ||Y||^2 (float64; exact, Q being orthonormal).

    Returns
    -------
    coefficients : (k, n, 3) float32; energy : float or None.
    """
    blocks = _blocks(n_texels) if fit_texels is None else [np.asarray(fit_texels)]
    n = n_texels if fit_texels is None else len(fit_texels)
    lq = u.astype(np.float64).T @ frame.q                                  # (k, K)
    mix = np.asarray(mix, np.float64)
    coeff = np.zeros((u.shape[1], n, 3), np.float32)
    total = 0.0 if energy else None
    at = 0
    for sel in blocks:
        h = frame.block(sel)
        y = np.einsum("ji,ikn->jkn", mix, h)
        width = h.shape[2]
        for j, kj in enumerate(ks):
            if kj:
                coeff[:kj, at:at + width, j] = lq[:kj] @ y[j]
        if energy:
            total += float(np.einsum("jkn,jkn->", y, y))
        at += width
    return coeff, total
