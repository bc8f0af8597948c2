"""Fill missing BTF samples by barycentric interpolation over the sampled hemisphere.

Koudelka et al. 2003 replaced the frames the robot arm obstructed "with images linearly
interpolated from the closest available samples".  Here a missing sample (view v,
light l) is filled from available samples that share its view, interpolating over the
light hemisphere; when that view has fewer than three available lights, from samples
that share its light, interpolating over the view hemisphere; failing both, it is a copy
of the nearest available sample (smallest view angle + light angle).

Interpolation over a hemisphere: among the ``k`` available directions nearest to the
query (great-circle angle), the spherical triangles that contain the query are those
whose barycentric weights (solving ``[a b c] w = q`` for unit vectors) are all >= 0;
the one with the smallest perimeter is used and its weights are normalised to sum to 1.
A query outside every candidate triangle (on or beyond the outermost ring) is
interpolated along the nearest triangle edge (clamped weights whose direction comes
closest to the query); with fewer than three directions, inverse-angle weights.

Pure functions over directions; pixels are combined by the caller
(:func:`combine`), so filling streams over samples.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from .errors import BTFError
from .sampling import Sampling, to_vectors

__all__ = ["FillSource", "spherical_weights", "plan_fill", "combine"]

_EPS = 1e-9


@dataclass(frozen=True)
class FillSource:
    """How one missing sample is made: ``sum(weights[i] * image[sources[i]])``.

    target : index of the missing sample.
    sources : (m,) indices of available samples, m in 1..3.
    weights : (m,) float64, >= 0, summing to 1.
    method : "light" (over the light hemisphere at the same view), "view" (over views at
        the same light) or "nearest".
    """

    target: int
    sources: np.ndarray
    weights: np.ndarray
    method: str


def _angles(q: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip(dirs @ q, -1.0, 1.0))


def spherical_weights(query: np.ndarray, dirs: np.ndarray, k: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric interpolation weights of unit vector ``query`` (3,) from ``dirs`` (M, 3).

    Returns (indices (m,), weights (m,)) with m = min(3, M); see the module docstring.
    """
    m = len(dirs)
    if m == 0:
        raise ValueError("no directions to interpolate from")
    ang = _angles(query, dirs)
    near = np.argsort(ang, kind="stable")[:min(k, m)]
    if ang[near[0]] < 1e-9:                       # the query is itself available
        return near[:1], np.ones(1)
    if m >= 3:
        triples = np.array(list(combinations(range(len(near)), 3)))
        tri = dirs[near][triples]                          # (T, 3 vertices, 3)
        mats = np.transpose(tri, (0, 2, 1))                # columns are the vertices
        det = np.linalg.det(mats)
        usable = np.abs(det) > 1e-8
        w = np.full((len(triples), 3), -1.0)
        w[usable] = np.linalg.solve(mats[usable], np.broadcast_to(query, (int(usable.sum()), 3))[..., None])[..., 0]
        inside = usable & (w >= -_EPS).all(axis=1) & (w.sum(axis=1) > 0)
        if inside.any():
            perim = (np.arccos(np.clip(np.einsum("ti,ti->t", tri[:, 0], tri[:, 1]), -1, 1))
                     + np.arccos(np.clip(np.einsum("ti,ti->t", tri[:, 1], tri[:, 2]), -1, 1))
                     + np.arccos(np.clip(np.einsum("ti,ti->t", tri[:, 2], tri[:, 0]), -1, 1)))
            best = np.flatnonzero(inside)[np.argmin(perim[inside])]
            wb = np.clip(w[best], 0.0, None)
            return near[triples[best]], wb / wb.sum()
        if usable.any():
            # Outside every candidate triangle (e.g. on the outermost ring, which lies just
            # outside the great-circle arcs between its own points): the triangle whose
            # clamped weights reproduce the closest direction, i.e. interpolation along the
            # nearest edge.
            wc = np.clip(w, 0.0, None)
            wc[~usable] = 0.0
            total = wc.sum(axis=1)
            ok = usable & (total > 0)
            wc[ok] /= total[ok, None]
            recon = np.einsum("tv,tvi->ti", wc, tri)
            recon /= np.maximum(np.linalg.norm(recon, axis=1, keepdims=True), 1e-12)
            miss = np.where(ok, np.arccos(np.clip(recon @ query, -1.0, 1.0)), np.inf)
            best = int(np.argmin(miss))
            keep = wc[best] > 0
            return near[triples[best]][keep], wc[best][keep]
    nearest = near[:min(3, m)]
    inv = 1.0 / ang[nearest]
    return nearest, inv / inv.sum()


def _groups(directions: np.ndarray) -> dict:
    """Rounded direction -> list of sample indices sharing it (phi ignored at the pole)."""
    key = np.round(directions, 6)
    key[key[:, 0] == 0, 1] = 0.0
    groups: dict = {}
    for i, kk in enumerate(map(tuple, key)):
        groups.setdefault(kk, []).append(i)
    return groups


def plan_fill(sampling: Sampling, available: np.ndarray) -> list[FillSource]:
    """A :class:`FillSource` for every sample where ``available`` (S,) bool is False.

    Raises BTFError when no sample at all is available.
    """
    available = np.asarray(available, bool)
    if len(available) != len(sampling):
        raise ValueError("available mask and sampling differ in length")
    if not available.any():
        raise BTFError("no sample is available to fill the missing ones from")
    views, lights = to_vectors(sampling.view), to_vectors(sampling.light)
    by_view, by_light = _groups(sampling.view), _groups(sampling.light)
    view_key = {i: k for k, idx in by_view.items() for i in idx}
    light_key = {i: k for k, idx in by_light.items() for i in idx}
    have = np.flatnonzero(available)
    out = []
    for t in np.flatnonzero(~available):
        for method, group, dirs in (("light", by_view[view_key[t]], lights), ("view", by_light[light_key[t]], views)):
            cand = np.array([i for i in group if available[i]], np.int64)
            if len(cand) >= 3:
                idx, w = spherical_weights(dirs[t], dirs[cand])
                out.append(FillSource(int(t), cand[idx], w, method))
                break
        else:
            dist = _angles(views[t], views[have]) + _angles(lights[t], lights[have])
            out.append(FillSource(int(t), have[[int(np.argmin(dist))]], np.ones(1), "nearest"))
    return out


def combine(source: FillSource, images: np.ndarray) -> np.ndarray:
    """The filled image: weights . images, for ``images`` (m, H, W, 3) of ``source.sources``."""
    return np.tensordot(source.weights.astype(np.float32), np.asarray(images, np.float32), axes=1)
