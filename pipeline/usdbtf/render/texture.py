"""Coefficient textures for the renderer: texel-major, mip-mapped, filtered.

Equation 2 needs, per shaded point, the 3 x k coefficients at its texture position.  They
are held texel-major, ``(H, W, 3, k)`` float32 in the stored (decorrelated) channels, the
colour matrix applied to the shaded colour instead (linear, so exact), so one bilinear tap
is one contiguous row and each channel's dot with the blended basis row runs over contiguous
memory (measured 2.3x faster than a (k, 3) layout); memory is ``H * W * k * 12`` bytes plus a
third for mip levels (built on first use, 2 x 2 box filter).

Texture coordinates follow USD: ``st`` in [0, 1], s to the right, t *up*; texel (row i,
column j) of the image (row 0 at the top) is centred at ``s = (j + 0.5) / W``,
``t = 1 - (i + 0.5) / H``.
"""
from __future__ import annotations

import threading

import numpy as np

from ..compress.format import CompressedBTF

__all__ = ["CoefficientTexture"]


class CoefficientTexture:
    """Texel-major coefficients of ``cbtf`` (first ``k``); ``wrap`` "repeat" or "clamp"."""

    def __init__(self, cbtf: CompressedBTF, k: int, wrap: str = "clamp"):
        self.k = k
        self.wrap = wrap
        # The colour matrix is applied to shaded colours (:meth:`shade`), not to the texture:
        # it is linear, so that is exact, and it keeps this build to one pass over the data.
        matrix = np.asarray(cbtf.color_matrix, np.float32)
        self.matrix = None if np.array_equal(matrix, np.eye(3, dtype=np.float32)) else matrix
        H, W = cbtf.height, cbtf.width
        level = np.empty((H, W, 3, k), np.float32)
        rows = max(1, min(H, (1 << 22) // (W * 3 * k)))          # row blocks of ~16 MB
        block = np.empty((k, rows * W * 3), np.float32)           # reused: no fresh pages per block
        for y0 in range(0, H, rows):
            y1 = min(H, y0 + rows)
            n = (y1 - y0) * W * 3
            for i, st in enumerate(cbtf.coefficients[:k]):        # exactly Stored.values(), on these rows
                out = block[i, :n].reshape(y1 - y0, W, 3)
                np.multiply(st.pixels[y0:y1], st.scale.astype(np.float32), out=out, casting="unsafe")
                out += st.bias.astype(np.float32)
            # One 2-D transpose (k, texels * 3) -> (texels * 3, k) into place (a 4-D transposing
            # assignment is ~10x slower: it reads across cache lines).
            level[y0:y1].reshape(n, k)[:] = block[:, :n].T
        self.levels = [level]
        self._lock = threading.Lock()             # shading threads may ask for a new mip level at once

    @property
    def height(self) -> int:
        return self.levels[0].shape[0]

    @property
    def width(self) -> int:
        return self.levels[0].shape[1]

    def level(self, n: int) -> np.ndarray:
        """Mip level ``n`` (H_n, W_n, 3, k), built on demand; sizes halve (rounded up) to 1 x 1."""
        if n < len(self.levels):
            return self.levels[n]
        with self._lock:
            return self._build_level(n)

    def _build_level(self, n: int) -> np.ndarray:
        while len(self.levels) <= n:
            prev = self.levels[-1]
            h, w = prev.shape[:2]
            if h == 1 and w == 1:
                return prev
            pad = np.pad(prev, ((0, h % 2), (0, w % 2), (0, 0), (0, 0)), mode="edge")
            self.levels.append(0.25 * (pad[0::2, 0::2] + pad[1::2, 0::2] + pad[0::2, 1::2] + pad[1::2, 1::2]))
        return self.levels[n]

    @property
    def max_level(self) -> int:
        return int(np.ceil(np.log2(max(self.height, self.width, 1))))

    def _taps(self, n: int, st: np.ndarray):
        """Bilinear taps at level n: flat texel indices (4, m) and weights (4, m)."""
        lv = self.level(n)
        h, w = lv.shape[:2]
        x = st[:, 0] * w - 0.5
        y = (1.0 - st[:, 1]) * h - 0.5
        x0, y0 = np.floor(x), np.floor(y)
        fx, fy = x - x0, y - y0
        x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
        if self.wrap == "repeat":
            xs, ys = (x0 % w, (x0 + 1) % w), (y0 % h, (y0 + 1) % h)
        else:
            xs = (np.clip(x0, 0, w - 1), np.clip(x0 + 1, 0, w - 1))
            ys = (np.clip(y0, 0, h - 1), np.clip(y0 + 1, 0, h - 1))
        idx = np.stack([ys[0] * w + xs[0], ys[0] * w + xs[1], ys[1] * w + xs[0], ys[1] * w + xs[1]])
        wt = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy])
        return idx, wt

    def shade(self, rows: np.ndarray, st: np.ndarray, lod: np.ndarray | None = None) -> np.ndarray:
        """(m, 3) = sum over filter taps q of weight_q * rows @ coefficients_q.

        rows : (m, k) blended basis rows; st : (m, 2); lod : (m,) mip level of detail
        (log2 texels per pixel; None or <= 0: bilinear on level 0, else trilinear).
        """
        out = np.zeros((len(rows), 3), np.float32)
        if lod is None:
            lod = np.zeros(len(rows))
        lod = np.clip(lod, 0.0, self.max_level)
        base = np.floor(lod).astype(np.int64)
        frac = (lod - base).astype(np.float32)
        r = rows.astype(np.float32)
        for n in np.unique(base):
            sel = np.flatnonzero(base == n)
            for level, scale in ((int(n), 1.0 - frac[sel]), (int(n) + 1, frac[sel])):
                use = scale > 0
                if not use.any() or level > self.max_level:
                    continue
                pick = sel[use]
                flat = self.level(level).reshape(-1, 3, self.k)
                idx, wt = self._taps(level, st[pick])
                rp = r[pick]
                for tap in range(4):
                    coeffs = np.take(flat, idx[tap], axis=0)                     # (p, 3, k)
                    val = np.einsum("pk,pck->pc", rp, coeffs)
                    out[pick] += (wt[tap] * scale[use])[:, None].astype(np.float32) * val
        if self.matrix is not None:                      # stored channels -> working-space RGB
            out = np.einsum("dc,pc->pd", self.matrix, out)
        return out
