"""Equation 2 at arbitrary directions: blend 3 view x 3 light basis rows, then one dot.

``I = sum_j w_j U[s_j] . c`` with the 9 samples ``s_j = view_i * L + light_l`` of the view
triangle and the light triangle that contain the local directions and ``w_j`` the products
of their barycentric weights (:mod:`.hemisphere`).  The rows are blended first (9 k
multiply-adds), so the coefficients are touched once per filter tap.

Lights beyond the outermost measured ring: the measured images include the light's
foreshortening (cos theta_l), so the value at the nearest measured boundary point is scaled
by ``cos theta_l / cos theta_boundary`` -- continuous at the boundary and zero at the horizon.
Views beyond it use the boundary value unscaled.
"""
from __future__ import annotations

import numpy as np

from ..compress.format import CompressedBTF, cross_layout
from ..errors import BTFError
from .hemisphere import Triangulation

__all__ = ["BasisInterpolator"]


class BasisInterpolator:
    """Blended basis rows for local (view, light) directions of a V x L compressed BTF."""

    def __init__(self, cbtf: CompressedBTF, k: int):
        layout = cross_layout(cbtf.sampling)
        if layout is None:
            raise BTFError("rendering needs every light at every view (a V x L sampling, view-major); "
                           f"this compressed BTF's {cbtf.n_samples} samples are not")
        self.views_count, self.lights_count = layout
        self.k = k
        self.basis = np.ascontiguousarray(cbtf.basis_values(k), np.float32)          # (S, k)
        self.views = Triangulation.from_directions(cbtf.sampling.view[::self.lights_count], "view directions")
        self.lights = Triangulation.from_directions(cbtf.sampling.light[:self.lights_count], "light directions")

    def view_weights(self, view_local: np.ndarray):
        """(indices (n, 3), weights (n, 3)) of the view triangle of each local view direction."""
        idx, w, _ = self.views.weights(view_local)
        return idx, w

    def light_weights(self, light_local: np.ndarray):
        """(indices (n, 3), weights (n, 3)) of the light triangle, weights including the
        foreshortening fall-off beyond the measured region (module docstring)."""
        idx, w, used = self.lights.weights(light_local)
        v = np.asarray(light_local, np.float64)
        cos_q = v[:, 2] / np.maximum(np.linalg.norm(v, axis=1), 1e-300)
        cos_b = np.cos(np.radians(used))
        fade = np.where(cos_q < cos_b, np.clip(cos_q, 0.0, None) / np.maximum(cos_b, 1e-12), 1.0)
        return idx, w * fade[:, None]

    def accumulate(self, rows: np.ndarray, view, light, scale: np.ndarray | float = 1.0) -> np.ndarray:
        """rows (n, k) += scale * sum of the 9 weighted basis rows.

        view, light : (indices, weights) from :meth:`view_weights` / :meth:`light_weights`.
        scale : (n,) or scalar light intensity (irradiance x 1 / (pi W), usdbtf.photometry,
        shadowing included).
        """
        (iv, wv), (il, wl) = view, light
        samples = (iv[:, :, None] * self.lights_count + il[:, None, :]).reshape(len(iv), 9)
        weights = (wv[:, :, None] * wl[:, None, :]).reshape(len(iv), 9) * np.reshape(scale, (-1, 1))
        rows += np.einsum("nj,njk->nk", weights.astype(np.float32), self.basis[samples])
        return rows
