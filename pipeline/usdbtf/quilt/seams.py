"""Seam error: mean squared difference between neighbouring output texels that were not
neighbours in the source (a quilting seam runs between them).

For a position map the seam pairs are the horizontally or vertically adjacent output
texels ``a, b`` whose source texels are not adjacent the same way.  The error of one
(view, light) image is the mean over seam pairs and colour channels of ``(I(a) - I(b))^2``;
averaged over all S samples it is, with image features (see :mod:`.features`),
``mean ||f(a) - f(b)||^2 / (3 S)`` -- no image is ever reconstructed.
"""
from __future__ import annotations

import numpy as np

__all__ = ["seam_pairs", "seam_error_all_samples", "pair_error", "seam_error_images", "natural_neighbour_error"]


def seam_pairs(positions: np.ndarray, source_width: int, *, wrap: bool = False,
               labels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Flat output indices (a, b) of seam pairs.

    positions : (H, W) int source flat indices.  wrap : include the pairs across the output's
    right/left and bottom/top edges (tileable output).  labels : (H, W) int, only pairs with
    equal non-negative labels count (atlas charts: texels of different charts are not
    neighbours on the surface).
    """
    H, W = positions.shape
    idx = np.arange(H * W).reshape(H, W)
    pairs = []
    for axis, step in ((1, 1), (0, source_width)):
        a, b = idx, np.roll(idx, -1, axis=axis)
        pa, pb = positions, np.roll(positions, -1, axis=axis)
        if not wrap:
            a, b, pa, pb = ((t[:, :-1] if axis == 1 else t[:-1]) for t in (a, b, pa, pb))
        natural = pb == pa + step
        if axis == 1:
            natural &= (pa % source_width) != source_width - 1   # the next source column exists
        seam = ~natural
        if labels is not None:
            la = labels.ravel()
            seam &= (la[a] >= 0) & (la[a] == la[b])
        pairs.append((a[seam], b[seam]))
    return np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])


def seam_error_all_samples(positions: np.ndarray, image_features: np.ndarray, source_width: int,
                           n_samples: int, *, wrap: bool = False, labels=None) -> float:
    """Seam error averaged over every (view, light) sample, from image features (P, 3k)."""
    a, b = seam_pairs(positions, source_width, wrap=wrap, labels=labels)
    flat = positions.ravel()
    return pair_error(image_features, flat[a], flat[b], n_samples)


def pair_error(image_features: np.ndarray, src_a: np.ndarray, src_b: np.ndarray, n_samples: int,
               chunk: int = 65536) -> float:
    """Mean over pairs of source texels (a, b) of the squared image difference, averaged over
    channels and all n_samples (view, light) samples; 0 for no pairs."""
    if len(src_a) == 0:
        return 0.0
    total = 0.0
    for s in range(0, len(src_a), chunk):
        d = image_features[src_a[s:s + chunk]] - image_features[src_b[s:s + chunk]]
        total += float(np.einsum("nd,nd->", d, d, dtype=np.float64))
    return total / (len(src_a) * 3 * n_samples)


def natural_neighbour_error(image_features: np.ndarray, source_width: int, source_height: int,
                            n_samples: int) -> float:
    """The same mean squared difference as :func:`pair_error` over the sample's own horizontal and
    vertical neighbours: what a seam costs when it is invisible (a seam error near it means the
    seams look like the material)."""
    idx = np.arange(source_width * source_height).reshape(source_height, source_width)
    a = np.concatenate([idx[:, :-1].ravel(), idx[:-1].ravel()])
    b = np.concatenate([idx[:, 1:].ravel(), idx[1:].ravel()])
    return pair_error(image_features, a, b, n_samples)


def seam_error_images(positions: np.ndarray, images: np.ndarray, *, wrap: bool = False) -> np.ndarray:
    """(n,) seam error of each of ``images`` (n, Hs, Ws, 3) quilted with ``positions``."""
    n, hs, ws, _ = images.shape
    a, b = seam_pairs(positions, ws, wrap=wrap)
    flat = positions.ravel()
    src = images.reshape(n, hs * ws, 3)
    d = src[:, flat[a]] - src[:, flat[b]]
    return np.einsum("npc,npc->n", d, d, dtype=np.float64) / max(1, 3 * len(a))
