"""What quilting compares: per-texel feature vectors built from the coefficient textures.

Two feature sets come from one compressed BTF (Koudelka et al. 2003, section IV: "instead of
comparing image intensities ... we simply compare coefficients"):

* **matching features** (block search, the costly part): the leading ``m`` working-space
  coefficient textures, each normalised to unit energy and weighted by its basis vector's
  singular value, ``f_i = c_i * sigma_i / ||c_i||``.  For an orthonormal basis this is just
  ``c_i`` up to one global factor, i.e. the image-space error over *all* samples restricted to
  the m strongest components;
* **image features** (boundary cuts and seam metrics, evaluated on a few hundred texels at a
  time): all k coefficients mapped through ``G^(1/2)``, ``G = U^T U``, so that
  ``||f(a) - f(b)||^2 = sum_s ||I_s(a) - I_s(b)||^2`` exactly -- the squared difference of the
  two texels summed over every (view, light) sample and colour channel (equation 2).
"""
from __future__ import annotations

import numpy as np

from ..compress.format import CompressedBTF, working_coefficients
from ..errors import BTFError

__all__ = ["vector_energies", "matching_features", "image_features", "gram_sqrt"]


def vector_energies(cbtf: CompressedBTF) -> tuple[np.ndarray, str]:
    """(k,) float64 energy of each basis vector's contribution (sigma_i^2, any common scale),
    and where it came from: the metadata's ``energies`` or ``singular_values`` when recorded
    (compress records the fit's singular values), else computed from textures and basis."""
    k = cbtf.k
    for key, square in (("energies", False), ("singular_values", True)):
        values = cbtf.info.get(key)
        if isinstance(values, list) and len(values) >= k:
            e = np.asarray(values[:k], np.float64)
            if np.all(np.isfinite(e)) and np.all(e >= 0):
                return (e ** 2 if square else e), key
    u = cbtf.basis_values(k).astype(np.float64)
    e = np.array([np.einsum("ijc,ijc->", c, c, dtype=np.float64) for c in working_coefficients(cbtf, k)])
    return e * np.einsum("si,si->i", u, u), "computed"


def matching_features(cbtf: CompressedBTF, m: int) -> np.ndarray:
    """(H, W, 3m) float32: coefficient textures 0..m-1 (working space), each scaled to energy sigma_i^2."""
    if not 1 <= m <= cbtf.k:
        raise BTFError(f"--m must be in 1..{cbtf.k} (the compressed BTF has k = {cbtf.k})")
    coeff = working_coefficients(cbtf, m)                                      # (m, H, W, 3)
    tex_energy = np.einsum("ihwc,ihwc->i", coeff, coeff, dtype=np.float64)
    energy, _ = vector_energies(cbtf)
    weight = np.sqrt(np.where(tex_energy > 0, energy[:m] / np.maximum(tex_energy, 1e-300), 0.0))
    weight /= max(float(weight.max()), 1e-300)       # one common scale: only ratios matter
    feats = coeff * weight.astype(np.float32)[:, None, None, None]
    return np.ascontiguousarray(feats.transpose(1, 2, 3, 0).reshape(cbtf.height, cbtf.width, 3 * m))


def gram_sqrt(basis: np.ndarray) -> np.ndarray:
    """Symmetric square root of ``basis.T @ basis`` ((k, k) float64) for a (S, k) basis."""
    g = basis.astype(np.float64).T @ basis.astype(np.float64)
    evals, vecs = np.linalg.eigh(g)
    return (vecs * np.sqrt(np.clip(evals, 0.0, None))) @ vecs.T


def image_features(cbtf: CompressedBTF) -> np.ndarray:
    """(H*W, 3k) float32 features whose squared distances are image-space squared
    differences summed over all S samples and the three channels (see module docstring)."""
    k = cbtf.k
    coeff = working_coefficients(cbtf, k)                                      # (k, H, W, 3)
    root = gram_sqrt(cbtf.basis_values(k)).astype(np.float32)
    texel = coeff.reshape(k, -1, 3).transpose(1, 2, 0)                         # (P, 3, k)
    return np.ascontiguousarray((texel @ root).reshape(-1, 3 * k))
