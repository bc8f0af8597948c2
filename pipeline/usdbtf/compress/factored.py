"""Compress straight from a factorisation: the source behind ``usdbtf compress FILE.btf``.

A UBO2014 DFMF file (or an FMF sibling) already is a low-rank factorisation: per channel c of
a decorrelated colour model, channel values X_c = A_c B_c^T with A_c over the S samples and
B_c over the T texels (``UBO2014BTF.factors``).  Expanding it into S images to compress them
again multiplies those factors out S x T times; this source works from the factors instead.
:func:`uses_factors` selects it for any input that exposes factors, unless
``CompressOptions.expand_factors`` (``--expand-factors``) asks for the expansion.

It answers the questions every source answers (:mod:`.source`), plus the fit:

``fit``
    When the decode after the product is linear (:func:`.factor_algebra.linear_decode`:
    colour models 0, 1, 3, 4, no dynamic-range restore, a matrix to the working space), the
    solver is rsvd and the clamp is negligible (below): the exact top-k SVD of the whole data
    matrix from small QR and Gram products of the factors (:func:`.factor_algebra.exact_fit`).
    Otherwise -- the paper solver, a clamp that matters, or a nonlinear decode such as
    UBO2014's colour model 11 (log Y, U/Y, V/Y), whose exp(log Y) makes the luminance matrix
    full-rank even though its logarithm is not -- the basis is fitted as for any input, on the
    fitting texels' decoded values (:func:`.fit.fit_basis`).
``project``
    Linear decode: exact, (U^T Q) h(t) per texel (:func:`.factor_algebra.exact_coefficients`),
    plus the clamp's share when it is not negligible (below).
    Nonlinear: weighted least squares on m leverage-sampled samples of every texel
    (:mod:`.row_sampling`; m = ``factor_rows``, default 16 k; m >= S is the exact projection).
``columns`` / ``working_samples``
    The reader's own values (its decode, clamp included), from the factors with this
    module's products: the reader multiplies out fixed 128-sample x 8192-texel tiles per
    request, far more than a few fitting texels or curve samples need.

**The clamp.**  The reader sets negative decoded values to 0 (a truncated factorisation
rings below zero), which is not linear.  The linear path measures how much of the fitting
texels' energy the clamp changes.  Above :data:`CLAMP_NEGLIGIBLE` the clamp's share of every
texel's coefficients is solved on sampled rows like the nonlinear path's (added to the exact
projection of the product); above :data:`CLAMP_TOLERANCE` the basis, too, is fitted on the
decoded (clamped) values instead of taken from the product's SVD.  The nonlinear path works on
clamped values throughout.  Either way the error the output's metadata reports is measured on
held-out texels against the reader's values, clamp included.

Memory: the factors in float32, Q (S x K float64) on the exact path, the fitting and
held-out columns (as for any input), one texel block of sampled rows, and the coefficients.
"""
from __future__ import annotations

import numpy as np

from ..errors import BTFError
from ..model import BTF
from ..resources import require_memory
from .factor_algebra import FactorFrame, exact_coefficients, exact_fit, linear_decode, mix_planes, working_map
from .fit import BasisFit, fit_basis
from .options import CompressOptions
from .row_sampling import default_rows, leverage_rows, solve_operators
from .source import Closable

__all__ = ["FactoredSource", "uses_factors", "CLAMP_TOLERANCE", "CLAMP_NEGLIGIBLE"]

#: Bytes of float32 values one expansion step produces (the decode makes ~3 temporaries of it).
_STEP_BYTES = 32e6
#: The exact basis of the factor product is used while the reader's clamp changes at most this
#: share of the data's energy (measured on the fitting texels); past it, the product's SVD is
#: the wrong basis for the clamped images and the basis is fitted on decoded values instead.
CLAMP_TOLERANCE = 1e-3
#: Below this share (0.1 % in RMS terms) the clamp's effect on the coefficients is not solved
#: for at all: the exact path then never decodes a pixel beyond the fitting texels.
CLAMP_NEGLIGIBLE = 1e-6


def uses_factors(btf: BTF, options: CompressOptions) -> bool:
    """True when ``btf`` exposes a 3-channel factorisation and its decode (``factors`` and
    ``channels_to_rgb``, :class:`~usdbtf.ubo2014.UBO2014BTF`) and ``--expand-factors`` is off."""
    f = getattr(btf, "factors", None)
    return (not options.expand_factors and f is not None and len(f.channels) == 3
            and callable(getattr(btf, "channels_to_rgb", None)))


class FactoredSource(Closable):
    """Compression's data from a factorisation (see the module docstring).

    Values it hands out are already in the working space: ``to_working`` is the identity and
    ``working_mix(color)`` is ``color``.
    """

    kind = "factors"

    def __init__(self, btf: BTF, options: CompressOptions):
        f = btf.factors
        self.btf = btf
        self.options = options
        self._samples = [f.float32(c, "samples") for c in range(3)]
        self._texels = [f.float32(c, "texels") for c in range(3)]
        K = sum(a.shape[1] for a in self._samples)
        unique = {id(a): a.nbytes for a in self._samples + self._texels}
        require_memory(sum(unique.values()) + btf.n_samples * (K + 2) * 8 * 2 + 8 * _STEP_BYTES,
                       f"transcoding {self._where()} from its factors")
        self.linear = linear_decode(btf)
        self._affine = working_map(btf)
        self.frame = FactorFrame(self.linear) if self.linear is not None else None
        self.nbytes = sum(unique.values()) + (self.frame.q.nbytes if self.frame is not None else 0)
        self._record = {"basis": None, "coefficients": None}
        self._clamped = 0          # values the clamp changed at the sampled rows (linear path)
        self._share = None         # the clamp's energy share on the fitting texels (linear path)

    # -- the questions every source answers ----------------------------------------------
    def to_working(self, x: np.ndarray) -> np.ndarray:
        return x

    def working_mix(self, color: np.ndarray) -> np.ndarray:
        return np.asarray(color, np.float64)

    def values(self, samples: np.ndarray, texels) -> np.ndarray:
        """(n, t, 3) float32 working-space values of ``samples`` x ``texels`` (a slice or an
        index array), decoded as the reader decodes them (colour model, cosine, clamp, OCIO)."""
        samples = np.asarray(samples)
        rgb = self.btf.channels_to_rgb(self._planes(samples, texels), samples)
        return self.btf.decode(np.moveaxis(rgb, 0, -1), what=self._where())

    def _planes(self, samples: np.ndarray, texels) -> np.ndarray:
        """(3, n, t) float32 channel values (the factor products) of ``samples`` x ``texels``."""
        return np.stack([a[samples] @ b[texels].T for a, b in zip(self._samples, self._texels)])

    def columns(self, texels: np.ndarray) -> np.ndarray:
        """(S, 3 n) float32 working-space values of ``texels`` (interleaved channels)."""
        texels = np.asarray(texels)
        S = self.btf.n_samples
        out = np.empty((S, 3 * len(texels)), np.float32)
        step = self._rows_per_step(len(texels))
        for s0 in range(0, S, step):
            s1 = min(s0 + step, S)
            out[s0:s1] = self.values(np.arange(s0, s1), texels).reshape(s1 - s0, -1)
        return out

    def working_samples(self, rows) -> np.ndarray:
        """(r, P, 3) float32 working-space images of samples ``rows``."""
        rows = np.atleast_1d(np.asarray(rows))
        out = np.empty((len(rows), self.btf.n_pixels, 3), np.float32)
        step = self._rows_per_step(self.btf.n_pixels)
        for a in range(0, len(rows), step):
            out[a:a + step] = self.values(rows[a:a + step], slice(None))
        return out

    # -- fit and projection from the factors ---------------------------------------------
    def fit(self, texels: np.ndarray, k: int, options: CompressOptions) -> BasisFit:
        """The basis: exact from the factors when the decode is linear, the solver rsvd and the
        reader's clamp changes at most :data:`CLAMP_TOLERANCE` of the energy of ``texels``;
        else fitted on the decoded values of ``texels`` as for any input (:func:`.fit.fit_basis`)."""
        if self.frame is not None:
            self._share = self._clamp_share(texels)
            self._record["clamp_energy_share_on_fit_texels"] = self._share
            if options.solver == "rsvd" and self._share <= CLAMP_TOLERANCE:
                self._record["basis"] = "exact SVD of the factor product (all texels)"
                return exact_fit(self.frame, k, self.btf.n_pixels, texels)
        self._record["basis"] = f"{options.solver} fit on the decoded values of {len(texels)} texels"
        return fit_basis(self.columns(texels), k, options)

    def _clamp_share(self, texels: np.ndarray) -> float:
        """||clamped - unclamped||^2 / ||clamped||^2 over ``texels`` x every sample (working space):
        how much of the data the reader's clamp changes (linear decode only)."""
        lin = self.linear
        clamped = changed = 0.0
        step = self._rows_per_step(len(texels))
        for s0 in range(0, self.btf.n_samples, step):
            rows = np.arange(s0, min(s0 + step, self.btf.n_samples))
            rgb = self.btf.channels_to_rgb(self._planes(rows, texels), rows, clamp=False)
            neg = mix_planes(lin.to_working, np.maximum(-rgb, 0.0))
            kept = mix_planes(lin.to_working, np.maximum(rgb, 0.0), lin.working_offset)
            changed += float(np.einsum("jrn,jrn->", neg, neg, dtype=np.float64))
            clamped += float(np.einsum("jrn,jrn->", kept, kept, dtype=np.float64))
        return changed / clamped if clamped > 0 else 0.0

    def project(self, u: np.ndarray, mix: np.ndarray, ks, *, energy: bool = False):
        """Coefficients (k, P, 3) float32 of every texel on ``u`` (plane j on its first
        ``ks[j]`` vectors, after the colour ``mix``) and, with ``energy``, ||Y||^2 (exact on
        the linear path up to the clamp's share, estimated from the sampled rows otherwise)."""
        S, P = self.btf.n_samples, self.btf.n_pixels
        m = self.options.factor_rows or default_rows(u.shape[1], S)
        rows, weights = leverage_rows(u, m, self.options.seed)
        solved = ("every sample (exact)" if len(rows) == S else
                  {"least_squares_on_samples": int(len(rows)), "draws": int(m), "of": int(S), "sampling": "leverage"})
        mix = np.asarray(mix, np.float64)
        if self.frame is None:
            coeff = np.zeros((u.shape[1], P, 3), np.float32)
            total = self._solve_on_rows(u, ks, rows, weights, coeff, lambda sl: self._decoded_rows(rows, sl, mix))
            self._record["coefficients"] = {"solved_on": solved}
            return coeff, (total if energy else None)
        coeff, total = exact_coefficients(self.frame, u, mix, ks, n_texels=P, energy=energy)
        if self._share is not None and self._share <= CLAMP_NEGLIGIBLE:
            self._record["coefficients"] = {"product": "exact from the factors",
                                            "clamp": "negligible on the fitting texels: not applied"}
            return coeff, total
        self._clamped = 0
        extra = self._solve_on_rows(u, ks, rows, weights, coeff, lambda sl: self._clamp_rows(rows, sl, mix))
        self._record["coefficients"] = {"product": "exact from the factors",
                                        "clamp": {"solved_on": solved, "clamped_fraction_of_sampled_values":
                                                  float(self._clamped / (3 * len(rows) * P))}}
        return coeff, (total + extra if energy else None)

    def _solve_on_rows(self, u, ks, rows, weights, coeff, sampled) -> float:
        """Add to ``coeff`` the weighted least-squares coefficients (:mod:`.row_sampling`) of
        what ``sampled(texel slice)`` decodes at ``rows`` -- (3, n_rows, n) colour planes and
        each row's energy contribution -- one texel block at a time.  Returns the estimated
        energy (the rows' contributions, weighted)."""
        ops = solve_operators(u, rows, weights, ks)
        P = self.btf.n_pixels
        width = max(256, int(_STEP_BYTES // (12 * len(rows))) // 256 * 256)
        total = 0.0
        for a in range(0, P, width):
            sl = slice(a, min(a + width, P))
            y, row_energy = sampled(sl)
            for j, op in enumerate(ops):
                if op is not None:
                    coeff[:op.shape[0], sl, j] += op @ y[j]
            total += float(row_energy @ weights)
        return total

    def _decoded_rows(self, rows, sl, mix):
        """The reader's values at ``rows`` x texels ``sl``, mixed: (3, n, t) planes and ||y_row||^2.

        When the conversion to the working space is affine (as between linear spaces) it is
        applied on the planes, folded into ``mix``; otherwise through OCIO like ``values``."""
        if self._affine is None:
            y = np.einsum("ji,rni->jrn", mix.astype(np.float32), self.values(rows, sl))
        else:
            rgb = self.btf.channels_to_rgb(self._planes(rows, sl), rows)
            if not np.isfinite(rgb).all():
                raise BTFError(f"{self._where()}: decoded values include NaN or Inf (a factor product "
                               "overflows the colour model's exp)")
            matrix, offset = self._affine
            y = mix_planes(mix @ matrix, rgb, mix @ offset)
        return y, np.einsum("jrn,jrn->r", y, y, dtype=np.float64)

    def _clamp_rows(self, rows, sl, mix):
        """What the reader's clamp adds at ``rows`` x texels ``sl`` (working space, mixed):
        (3, n, t) planes, zero where nothing was clamped, and each row's energy change
        ||y + y_clamp||^2 - ||y||^2."""
        rgb = self.btf.channels_to_rgb(self._planes(rows, sl), rows, clamp=False)
        neg = np.maximum(-rgb, 0.0)
        self._clamped += int(np.count_nonzero(neg))
        to_mixed = mix @ self.linear.to_working
        y_clamp = mix_planes(to_mixed, neg)
        y = mix_planes(to_mixed, rgb, mix @ self.linear.working_offset)
        change = np.einsum("jrn,jrn->r", y_clamp, 2 * y + y_clamp, dtype=np.float64)
        return y_clamp, change

    # -- what the output records -------------------------------------------------------------
    @property
    def provenance(self) -> dict:
        """How the output was made from the factors (recorded under provenance.transcoded)."""
        f = self.btf.factors
        return {"from": "factors", "format": self.btf.metadata.get("format"),
                "signature": self.btf.metadata.get("signature"), "components": [int(k) for k in f.component_counts],
                "color_model": int(f.color_model), "dynamic_range_reduction": int(f.dynamic_range_reduction),
                "decode": "linear" if self.linear is not None else "nonlinear", **self._record}

    def _where(self) -> str:
        return str(self.btf.metadata.get("_path") or getattr(self.btf, "source", "") or "input BTF")

    def _rows_per_step(self, n_texels: int) -> int:
        return int(max(1, _STEP_BYTES // (12 * max(n_texels, 1))))
