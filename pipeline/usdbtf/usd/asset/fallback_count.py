"""The fallback fits a budget of the asset counts with: fitted on half the texel rows (issue 42).

``compress --max-bytes`` budgets every file the packaged asset's full ``lod`` loads, the
fallback maps among them, so its rate control packages a near choice to measure them
(:func:`usdbtf.usd.asset.package.asset_overhead`).  Fitting both fallbacks (UsdPreviewSurface
and OpenPBR) was about half of the mode's CPU time at paper scale, and the maps are only
counted: ``usdbtf package`` fits the final choice's own.  So the count fits bands of
:data:`BAND_ROWS` texel rows out of every :data:`BAND_PERIOD` (rows 0-15, 32-47, ... : half
the texels, spread over the whole image so that a material whose look drifts across it is
sampled everywhere), encodes the banded maps as they ship, and scales their bytes by the rows
left out.  The fits are per texel but for two material-wide brightness factors, which the
bands' texels estimate.

Measured on the seven presets' paper-scale assets (`benchmarks/probes/fallback_band_count.py`):
the banded maps' bytes scaled up are 1.001-1.023x the whole maps' (a band's first row is
predicted from a row it does not touch, and a smaller PNG pays its code tables over fewer
bytes), so the asset lands at most that much of its fallback maps (up to 0.2 % of the
budget) below where a whole fit would put it; at 64^2 (two bands) +4.0 %.  A contiguous block
in the middle measured 0.95-1.07x (a half or a quarter of the rows), bands of 8 rows in 32
1.02-1.07x, blocks each a file of its own 1.03-1.24x.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...compress.format import CompressedBTF, Stored

__all__ = ["BAND_ROWS", "BAND_PERIOD", "BandFits", "band_rows", "banded", "fit_bands", "fit_fallbacks"]

#: Texel rows fitted in every :data:`BAND_PERIOD`, from the band's first.
BAND_ROWS = 16
BAND_PERIOD = 32


@dataclass(frozen=True)
class BandFits:
    """Fallback fits of a compressed BTF's bands (:func:`banded`).

    fits : (UsdPreviewSurface fit, OpenPBR fit, fit errors), as ``package``'s
        ``fallback_fits`` takes them: maps of the bands' rows only.
    scale : texel rows of the image per row fitted (the factor the maps' bytes are scaled by).
    """

    fits: tuple
    scale: float


def band_rows(height: int) -> np.ndarray | None:
    """(n,) int, the texel rows the count fits: rows ``y`` with ``y % BAND_PERIOD < BAND_ROWS``;
    None for an image of fewer than two periods (fitted whole: there is little to save)."""
    if height < 2 * BAND_PERIOD:
        return None
    return np.flatnonzero(np.arange(height) % BAND_PERIOD < BAND_ROWS)


def banded(cbtf: CompressedBTF, rows: np.ndarray) -> CompressedBTF:
    """``cbtf`` cut to its texel ``rows`` (an image ``len(rows)`` rows high, the rows stacked
    in order): the same basis, codes and metadata; no encoded bytes or error curve."""
    coefficients = [Stored(st.pixels[rows], st.scale, st.bias) for st in cbtf.coefficients]
    return replace(cbtf, height=len(rows), coefficients=coefficients, encoded=None, curve=None)


def fit_fallbacks(cbtf: CompressedBTF, white_level: float, texel_weights=None) -> tuple:
    """(UsdPreviewSurface fit, OpenPBR fit, both fits' errors) of ``cbtf``: ``package``'s
    ``fallback_fits``, fitted as every asset fits them (the OpenPBR fit starts from the
    UsdPreviewSurface's normals; the errors at held-out samples,
    :func:`usdbtf.usd.asset.openpbr.fit_errors`).  ``texel_weights`` (P,): how many texels
    each of ``cbtf``'s stands for (a quilt's compact source texels), else None."""
    from ...openpbr import fit_openpbr
    from ...svbrdf import fit_svbrdf
    from .openpbr import fit_errors

    preview = fit_svbrdf(cbtf, white_level=white_level, texel_weights=texel_weights)
    open_pbr = fit_openpbr(cbtf, svbrdf=preview, white_level=white_level, texel_weights=texel_weights)
    return preview, open_pbr, fit_errors(cbtf, preview, open_pbr)


def fit_bands(cbtf: CompressedBTF, white_level: float) -> BandFits | None:
    """Both fallback fits of ``cbtf``'s bands (:func:`band_rows`) and their fit errors, as
    ``package`` computes them for a whole image (:func:`fit_fallbacks`); None when the image is
    fitted whole."""
    rows = band_rows(cbtf.height)
    if rows is None:
        return None
    return BandFits(fit_fallbacks(banded(cbtf, rows), white_level), cbtf.height / len(rows))
