"""A UsdPreviewSurface stand-in for a BTF: mean albedo texture and a fitted roughness.

Any Hydra renderer understands UsdPreviewSurface, none understands a BTF out of the
box, so the packaged Material carries both.  The stand-in is fitted to the BTF itself:

* **albedo** (per texel): the median over lights of ``I / cos(theta_l)`` at the views
  nearest the normal, divided by ``white_level`` (what a white Lambertian lit head-on
  reads in the data; 1.0 unless the source records it).  The median ignores the few
  lights that hit a highlight or a cast shadow.
* **roughness** (one value): the texel-mean apparent BRDF over every sample, fitted by
  non-negative least squares as ``a cos(theta_l) + s * GGX(alpha = roughness^2)``
  for each roughness on a grid; the best fit wins.
"""
from __future__ import annotations

import numpy as np

from ..compress.format import CompressedBTF, working_coefficient_texels
from ..sampling import to_vectors

#: Albedo texture: display-referred 8-bit sRGB, what UsdUVTexture decodes with sourceColorSpace "sRGB".
ALBEDO_SPACE = "sRGB Encoded Rec.709 (sRGB)"
_ROUGHNESS_GRID = np.round(np.linspace(0.05, 1.0, 39), 4)


def albedo_samples(cbtf: CompressedBTF, max_light_theta: float = 60.0, most: int = 48) -> np.ndarray:
    """Indices of the samples the albedo is estimated from: the view ring nearest the
    normal, lights no lower than ``max_light_theta`` degrees; at most ``most`` of them,
    evenly spread (a median over ~50 lights is as robust as over 1000, and 20x cheaper)."""
    view_theta = cbtf.sampling.view[:, 0]
    near = view_theta <= view_theta.min() + 1e-6
    sel = np.flatnonzero(near & (cbtf.sampling.light[:, 0] <= max_light_theta))
    sel = sel if len(sel) else np.flatnonzero(near)
    if len(sel) > most:
        sel = sel[np.linspace(0, len(sel) - 1, most).round().astype(int)]
    return sel


def mean_albedo(cbtf: CompressedBTF, *, white_level: float = 1.0, rows_per_chunk: int = 64) -> np.ndarray:
    """(H, W, 3) float32 working-space albedo estimate, streamed over texel rows."""
    sel = albedo_samples(cbtf)
    cos_l = np.maximum(np.cos(np.radians(cbtf.sampling.light[sel, 0])), 0.1).astype(np.float32)
    # Divide by cos once, in the basis rows: (k, n), so each texel's n values come out
    # contiguous and the median runs along the last axis.
    rows = (cbtf.basis_values()[sel] / cos_l[:, None]).T
    out = np.empty((cbtf.height, cbtf.width, 3), np.float32)
    for y0 in range(0, cbtf.height, rows_per_chunk):
        y1 = min(y0 + rows_per_chunk, cbtf.height)
        c = working_coefficient_texels(cbtf, slice(y0 * cbtf.width, y1 * cbtf.width))   # (k, h*W, 3)
        per_texel = c.reshape(cbtf.k, -1).T @ rows                           # (h*W*3, n)
        out[y0:y1] = np.median(per_texel, axis=1).reshape(y1 - y0, cbtf.width, 3)
    return np.clip(out / white_level, 0.0, 1.0)


def _ggx_lobe(view: np.ndarray, light: np.ndarray, roughness: float) -> np.ndarray:
    """(S,) GGX specular times cos(theta_l) for unit (S, 3) directions (F and G folded into the scale)."""
    alpha2 = max(roughness, 0.02) ** 4
    h = view + light
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    nh = np.clip(h[:, 2], 0.0, 1.0)
    d = alpha2 / (np.pi * (nh * nh * (alpha2 - 1.0) + 1.0) ** 2)
    return d / (4.0 * np.maximum(view[:, 2], 0.1))


def fit_roughness(cbtf: CompressedBTF) -> tuple[float, float]:
    """(roughness, relative residual) of the best diffuse + GGX fit to the mean apparent BRDF."""
    mean_c = np.stack([st.values().reshape(-1, 3).mean(axis=0) for st in cbtf.coefficients])   # (k, 3)
    mean_c = mean_c @ np.asarray(cbtf.color_matrix).T
    brdf = (cbtf.basis_values().astype(np.float64) @ mean_c).mean(axis=1)                    # (S,) grey
    view, light = to_vectors(cbtf.sampling.view), to_vectors(cbtf.sampling.light)
    keep = (cbtf.sampling.view[:, 0] <= 70) & (cbtf.sampling.light[:, 0] <= 75)
    if keep.sum() < 3:
        keep[:] = True
    cos_l = np.maximum(light[keep, 2], 0.0)
    norm = float(np.linalg.norm(brdf[keep])) or 1.0
    best = (1.0, np.inf)
    for r in _ROUGHNESS_GRID:
        design = np.stack([cos_l, _ggx_lobe(view[keep], light[keep], float(r)) * cos_l], axis=1)
        coef, *_ = np.linalg.lstsq(design, brdf[keep], rcond=None)
        coef = np.maximum(coef, 0.0)   # a negative specular weight is not a surface
        resid = float(np.linalg.norm(design @ coef - brdf[keep])) / norm
        if resid < best[1] - 1e-12:
            best = (float(r), resid)
    return best
