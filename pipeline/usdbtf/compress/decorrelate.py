"""Colour decorrelation: rotate each texel's k x 3 coefficients onto the colour principal axes.

The paper shares one basis by R, G and B and stores the three channels as they are.  Their
coefficients are strongly correlated (most texels vary in brightness more than in hue),
so the default solver rotates them by the 3 x 3 PCA of the sampled coefficients: plane 0
(luminance-like) then carries almost all the energy and planes 1, 2 (chroma) need far
fewer components (:func:`planes_in_use`).  The rotation R is orthonormal, so squared
errors are the same in both frames, and reconstruction applies it once per coefficient
texture (``color_matrix`` in the format).
"""
from __future__ import annotations

import numpy as np

from .. import color

__all__ = ["color_decorrelation", "rotate_color", "planes_in_use", "PLANE_TOLERANCE"]

#: A colour plane's component is projected while zeroing it would add more than this
#: fraction of one component's quantisation noise (n step^2 / 12), estimated on the sample.
PLANE_TOLERANCE = 0.01


def color_decorrelation(coeff: np.ndarray) -> np.ndarray:
    """The colour rotation R: eigenvectors of the 3 x 3 Gram sum_t,i c_ti c_ti^T.

    Parameters
    ----------
    coeff : (k, n, 3) float32 working-space coefficients of sampled texels.

    Returns
    -------
    (3, 3) float64 orthonormal R, columns = colour principal axes, largest eigenvalue first,
    each column's largest-magnitude entry positive.  Stored planes are ``coeff @ R``.
    """
    evals, vecs = np.linalg.eigh(_color_gram(coeff))
    vecs = vecs[:, np.argsort(evals)[::-1]]
    vecs *= np.sign(vecs[np.argmax(np.abs(vecs), axis=0), [0, 1, 2]])
    return vecs


def rotate_color(coeff: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``coeff @ m`` for (k, n, 3) float32 coefficients, in place, one component at a time
    (a float64 or full-size temporary would double the peak memory).  Returns ``coeff``."""
    for i in range(len(coeff)):
        coeff[i] = color.mix_rgb(coeff[i], m.T)
    return coeff


def _color_gram(coeff: np.ndarray) -> np.ndarray:
    """3x3 float64 sum of c c^T over every texel and component of ``coeff`` (k, P, 3),
    one component at a time (a float64 copy of the whole array would be 2x its size)."""
    gram = np.zeros((3, 3))
    for plane in coeff:
        flat = plane.astype(np.float64)
        gram += flat.T @ flat
    return gram


def planes_in_use(sampled: np.ndarray, step: float) -> tuple[int, int, int]:
    """Per decorrelated colour plane, how many leading components to project.

    A coefficient c rounds to zero when |c| < step / 2; zeroing one that would round away
    adds step (2 |c| - step) to the squared error.  Plane j keeps components up to the last
    one where that excess, averaged over the sampled texels, passes PLANE_TOLERANCE
    step^2 / 12; later ones are (almost) all zero once quantised.

    Parameters
    ----------
    sampled : (k, n, 3) float32 decorrelated coefficients of sampled texels.
    step : the uniform quantisation step (working-space linear units).

    Returns
    -------
    (k_0, k_1, k_2) : components to project per plane, k_0 >= 1.
    """
    excess = np.maximum(2.0 * np.abs(sampled) / step - 1.0, 0.0).mean(axis=1)      # (k, 3), in step^2
    used = excess > PLANE_TOLERANCE / 12.0
    ks = [int(np.flatnonzero(used[:, j])[-1]) + 1 if used[:, j].any() else 0 for j in range(3)]
    ks[0] = max(ks[0], 1)
    return tuple(ks)
