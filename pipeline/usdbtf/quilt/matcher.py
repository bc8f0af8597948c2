"""Overlap error of one output block against every source block position, by FFT.

For a template ``T`` (B x B x C features, zero outside the overlap mask ``M``) and source
features ``F`` (Hs x Ws x C), the error of placing source block ``s`` is::

    E(s) = sum_p M(p) ||F(s+p)||^2  -  2 sum_p sum_c T_c(p) F_c(s+p)  +  sum_p M(p) ||T(p)||^2

The first two terms are cross-correlations, evaluated together as one frequency-domain
product summed over C + 1 channels (``||F||^2`` paired with ``M``, ``F_c`` with ``-2 T_c``) and
one inverse FFT.  The source spectra are computed once; per block only the template's
C + 1 channels are transformed, and since a template is nonzero on B of the Hs rows the row
transform runs on those B rows only.  Cyclic correlation is exact for the positions
``0 <= s <= Hs - B`` (no wrap-around), which are the candidates.
"""
from __future__ import annotations

import numpy as np

__all__ = ["Matcher"]


class Matcher:
    """Precomputed source spectra for blocks of side ``block``.

    features : (Hs, Ws, C) float32 source features.
    """

    def __init__(self, features: np.ndarray, block: int):
        feats = np.ascontiguousarray(features, np.float32)
        self.height, self.width, self.channels = feats.shape
        self.block = block
        planes = np.concatenate([np.einsum("hwc,hwc->hw", feats, feats)[None], feats.transpose(2, 0, 1)])
        self._spectra = np.fft.rfft2(planes)                     # (C + 1, Hs, Ws//2 + 1) complex64
        self.n_candidates = (self.height - block + 1, self.width - block + 1)

    def errors(self, template: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(Hs - B + 1, Ws - B + 1) float32 overlap errors (>= 0).

        template : (B, B, C) features of the already-filled output texels (any values where
                   ``mask`` is False: they are zeroed here).  mask : (B, B) bool.
        """
        m = mask.astype(np.float32)
        planes = np.empty((self.channels + 1, self.block, self.block), np.float32)
        planes[0] = m
        np.multiply(template.transpose(2, 0, 1), -2.0 * m, out=planes[1:])
        rows = np.fft.rfft(planes, n=self.width, axis=2)          # only the B nonzero rows
        spec = np.fft.fft(rows, n=self.height, axis=1)             # (C + 1, Hs, Ws//2 + 1)
        total = np.einsum("chw,chw->hw", spec.conj(), self._spectra)
        corr = np.fft.irfft2(total, s=(self.height, self.width))
        const = float(np.einsum("hwc,hwc,hw->", template, template, m, dtype=np.float64))
        err = corr[:self.n_candidates[0], :self.n_candidates[1]] + np.float32(const)
        return np.maximum(err, 0.0, out=err)
