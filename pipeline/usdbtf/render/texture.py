"""Coefficient textures for the renderer: texel-major, mip-mapped, filtered.

Equation 2 needs, per shaded point, the 3 x k coefficients at its texture position.  They
are held texel-major, ``(H, W, 3, k)`` float32 in the stored (decorrelated) channels, the
colour matrix applied to the shaded colour instead (linear, so exact), so one bilinear tap
is one contiguous row and each channel's dot with the blended basis row runs over contiguous
memory (measured 2.3x faster than a (k, 3) layout); memory is ``H * W * k * 12`` bytes plus a
third for mip levels (built on first use, 2 x 2 box filter).

Only the levels a frame samples are built (issue 39): a level n >= 1 with no finer level held
is made coefficient plane by plane from the stored codes (de-quantised and box-filtered n
times per plane: the same float32 operations per texel as boxing the whole level 0, so the
same values bit for bit), so a frame that samples levels 2.. never holds level 0's
``H * W * k * 12`` bytes, and a lazily read asset (``read_btf(..., lazy=True)``) decodes its
pages once per level built, one at a time.  Level 0, when a tap needs it, is held as the
stored codes, texel-major (``H * W * k * 3`` bytes for 8-bit codes, a quarter of the floats),
and a tap de-quantises the texels it reads (the same float32 operations, so the same values).

Texture coordinates follow USD: ``st`` in [0, 1], s to the right, t *up*; texel (row i,
column j) of the image (row 0 at the top) is centred at ``s = (j + 0.5) / W``,
``t = 1 - (i + 0.5) / H``.
"""
from __future__ import annotations

import threading

import numpy as np

from ..compress.format import CompressedBTF
from ..compress.parallel import in_threads

__all__ = ["CoefficientTexture"]


class CoefficientTexture:
    """Texel-major coefficients of ``cbtf`` (first ``k``); ``wrap`` "repeat" or "clamp".

    ``texel_map`` (H, W) int, optional: the texture is H x W texels, texel (i, j) being
    ``cbtf``'s texel ``texel_map[i, j]`` (flat, row-major) -- a quilt as the copies of its
    distinct source texels (:class:`usdbtf.quilt.texels.QuiltTexels`).  Level 0 is then never
    held: its taps are gathered from ``cbtf``'s texels, and a mip level is built from level-0
    rows gathered a band at a time, so memory follows the levels a frame samples, not the
    H x W x k level 0 (the same values, bit for bit, as from the full texture).
    """

    def __init__(self, cbtf: CompressedBTF, k: int, wrap: str = "clamp", texel_map: np.ndarray | None = None):
        self.k = k
        self.wrap = wrap
        # The colour matrix is applied to shaded colours (:meth:`shade`), not to the texture:
        # it is linear, so that is exact, and it keeps this build to one pass over the data.
        matrix = np.asarray(cbtf.color_matrix, np.float32)
        self.matrix = None if np.array_equal(matrix, np.eye(3, dtype=np.float32)) else matrix
        self.map = None if texel_map is None else np.asarray(texel_map)
        self._cbtf = cbtf
        self.levels = {}
        if self.map is None:
            self._texels = None                   # level 0 and the rest: built when first sampled
            self._shape = (cbtf.height, cbtf.width)
        else:
            self._texels = _texel_major(cbtf, k).reshape(-1, 3, k)
            self._shape = self.map.shape
        #: Levels in the order they were built, and how ("level 0", "codes", "planes", "box", "gathered").
        self.built: list[tuple[int, str]] = []
        self._codes0 = None                       # level 0 as codes (h * w, 3, k), built when a tap needs it
        self._lock = threading.Lock()             # shading threads may ask for a new mip level at once

    @property
    def height(self) -> int:
        return self._shape[0]

    @property
    def width(self) -> int:
        return self._shape[1]

    def level_shape(self, n: int) -> tuple[int, int]:
        """(H_n, W_n): sizes halve (rounded up) per level."""
        h, w = self._shape
        for _ in range(n):
            h, w = -(-h // 2), -(-w // 2)
        return h, w

    def level(self, n: int) -> np.ndarray:
        """Mip level ``n`` (H_n, W_n, 3, k), built on demand; sizes halve (rounded up) to 1 x 1."""
        n = min(n, self.max_level)
        if n not in self.levels:
            with self._lock:
                if n not in self.levels:
                    self.levels[n] = self._build_level(n)
        return self.levels[n]

    def _build_level(self, n: int) -> np.ndarray:
        below = [m for m in self.levels if m < n]
        if not below and self.map is None:
            self.built.append((n, "level 0" if n == 0 else "planes"))
            if n == 0:
                level = _texel_major(self._cbtf, self.k)
            else:
                planes = (self._cbtf.coefficients.__getitem__ if self._codes0 is None else
                          lambda i: self._codes0[1][i])
                level = _plane_level(planes, self._shape, self.k, n)
            self._release()
            return level
        if not below:                  # gathered level 0: stream it a band at a time, a band per thread
            self.built.append((n, "gathered"))
            h, w = self.level_shape(n)
            out = np.empty((h, w, 3, self.k), np.float32)
            band = max(1, 32 >> n)

            def fill(y0):
                out[y0:y0 + band] = self._rows(n, y0, min(h, y0 + band))

            in_threads(fill, range(0, h, band))
            return out
        m = max(below)
        while m < n:
            self.levels[m + 1] = _box(self.levels[m])
            self.built.append((m + 1, "box"))
            m += 1
        return self.levels[n]

    def _rows(self, n: int, y0: int, y1: int) -> np.ndarray:
        """Rows y0..y1 of level ``n`` (not necessarily held) as _box computes them."""
        if n in self.levels:
            return self.levels[n][y0:y1]
        if n == 0:
            return np.take(self._texels, self.map[y0:y1], axis=0)
        h = self.level_shape(n - 1)[0]
        rows = self._rows(n - 1, 2 * y0, min(h, 2 * y1))
        if 2 * y1 > h:                                # the edge row repeated, as np.pad's "edge"
            rows = np.concatenate([rows, rows[-1:]])
        return _box(rows)

    @property
    def max_level(self) -> int:
        return int(np.ceil(np.log2(max(self.height, self.width, 1))))

    def _release(self) -> None:
        release = getattr(self._cbtf.coefficients, "release", None)
        if release is not None:                      # a lazily read asset: its pages are not kept
            release()

    def _level0_codes(self):
        """(codes (h * w, 3, k), [Stored-like views per coefficient], scale (3, k) float32,
        bias (3, k) float32) of level 0, built on first use."""
        if self._codes0 is None:
            with self._lock:
                if self._codes0 is None:
                    self.built.append((0, "codes"))
                    self._codes0 = _texel_major_codes(self._cbtf, self.k)
                    self._release()
        return self._codes0

    def _tap_texels(self, n: int, idx: np.ndarray) -> np.ndarray:
        """(p, 3, k) texels at flat indices ``idx`` of level ``n``."""
        if n == 0 and self.map is not None:
            return np.take(self._texels, self.map.ravel()[idx], axis=0)
        if n == 0 and 0 not in self.levels:
            codes, _, scale, bias = self._level0_codes()
            out = np.take(codes, idx, axis=0).astype(np.float32)    # exactly _texel_major's values
            out *= scale
            out += bias
            return out
        return np.take(self.level(n).reshape(-1, 3, self.k), idx, axis=0)

    def _taps(self, n: int, st: np.ndarray):
        """Bilinear taps at level n: flat texel indices (4, m) and weights (4, m)."""
        h, w = self.level_shape(n)
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
                idx, wt = self._taps(level, st[pick])
                rp = r[pick]
                for tap in range(4):
                    coeffs = self._tap_texels(level, idx[tap])                   # (p, 3, k)
                    val = np.einsum("pk,pck->pc", rp, coeffs)
                    out[pick] += (wt[tap] * scale[use])[:, None].astype(np.float32) * val
        if self.matrix is not None:                      # stored channels -> working-space RGB
            out = np.einsum("dc,pc->pd", self.matrix, out)
        return out


def _plane_level(coefficient, shape: tuple, k: int, n: int) -> np.ndarray:
    """Mip level ``n`` (H_n, W_n, 3, k) float32 of the first ``k`` coefficients, made one
    coefficient plane at a time: ``coefficient(i)`` (a Stored: pixels (H, W, 3), scale, bias;
    ``shape`` = (H, W)); each plane de-quantised as :func:`_texel_major` does (code x float32
    scale + float32 bias, in float32) and box-filtered ``n`` times (:func:`_box`), the same
    operations per texel as boxing the texel-major level 0, so the same values.  Holds one
    coefficient's codes and one plane at a time (plus the level)."""
    h, w = shape
    for _ in range(n):
        h, w = -(-h // 2), -(-w // 2)
    out = np.empty((h, w, 3, k), np.float32)
    for i in range(k):
        st = coefficient(i)                 # a lazily read asset: read here, dropped after
        scale, bias = st.scale.astype(np.float32), st.bias.astype(np.float32)
        for c in range(3):
            plane = np.multiply(st.pixels[:, :, c], scale[c:c + 1], dtype=np.float32)
            plane += bias[c:c + 1]
            for _ in range(n):
                plane = _box(plane)
            out[:, :, c, i] = plane
    return out


class _CodesView:
    """Coefficient ``i`` of texel-major codes, as a Stored reads (pixels (H, W, 3), scale, bias)."""

    def __init__(self, codes, shape, i, scale, bias):
        self.pixels = codes.reshape(shape + codes.shape[1:])[:, :, :, i]
        self.scale, self.bias = scale, bias


def _texel_major_codes(cbtf: CompressedBTF, k: int):
    """Level 0 as stored codes: (codes (H * W, 3, k) in the widest storage type of the first
    ``k`` coefficients, [per coefficient a view with pixels (H, W, 3), scale, bias],
    scale (3, k) float32, bias (3, k) float32).  ``codes * scale + bias`` in float32 is
    :func:`_texel_major` (a uint8 code held as uint16 or a half as float32 converts exactly)."""
    H, W = cbtf.height, cbtf.width
    coefficients = cbtf.coefficients
    first = coefficients[0]
    dtype = first.pixels.dtype
    codes = np.empty((H * W, 3, k), dtype)
    scale, bias = np.empty((3, k), np.float32), np.empty((3, k), np.float32)
    scales, biases = [], []
    for i in range(k):
        st = first if i == 0 else coefficients[i]          # a lazy asset's: each read once, in order
        if np.result_type(codes.dtype, st.pixels.dtype) != codes.dtype:
            codes = codes.astype(np.result_type(codes.dtype, st.pixels.dtype))
        codes[:, :, i] = st.pixels.reshape(H * W, 3)
        scale[:, i], bias[:, i] = st.scale.astype(np.float32), st.bias.astype(np.float32)
        scales.append(np.asarray(st.scale))
        biases.append(np.asarray(st.bias))
    views = [_CodesView(codes, (H, W), i, scales[i], biases[i]) for i in range(k)]
    return codes, views, scale, bias


def _texel_major(cbtf: CompressedBTF, k: int) -> np.ndarray:
    """(H, W, 3, k) float32 de-quantised coefficients of ``cbtf``, texel-major."""
    H, W = cbtf.height, cbtf.width
    coefficients = list(cbtf.coefficients[:k])               # a lazy asset's: read once, not per block
    level = np.empty((H, W, 3, k), np.float32)
    rows = max(1, min(H, (1 << 22) // (W * 3 * k)))          # row blocks of ~16 MB
    block = np.empty((k, rows * W * 3), np.float32)           # reused: no fresh pages per block
    for y0 in range(0, H, rows):
        y1 = min(H, y0 + rows)
        n = (y1 - y0) * W * 3
        for i, st in enumerate(coefficients):                 # exactly Stored.values(), on these rows
            out = block[i, :n].reshape(y1 - y0, W, 3)
            np.multiply(st.pixels[y0:y1], st.scale.astype(np.float32), out=out, casting="unsafe")
            out += st.bias.astype(np.float32)
        # One 2-D transpose (k, texels * 3) -> (texels * 3, k) into place (a 4-D transposing
        # assignment is ~10x slower: it reads across cache lines).
        level[y0:y1].reshape(n, k)[:] = block[:, :n].T
    return level


def _box(level: np.ndarray) -> np.ndarray:
    """The next mip level of (h, w, 3, k) texels: 2 x 2 box, the last row / column repeated
    when the size is odd -- ``0.25 * (p00 + p10 + p01 + p11)`` of the edge-padded level, in
    that order, without making the padded copy (a level can be hundreds of MB)."""
    h, w = level.shape[:2]
    out = np.empty((-(-h // 2), -(-w // 2)) + level.shape[2:], level.dtype)
    for r0, r1, ro in _pairs(h):
        for c0, c1, co in _pairs(w):
            o = out[ro, co]
            np.add(level[r0, c0], level[r1, c0], out=o)
            o += level[r0, c1]
            o += level[r1, c1]
            o *= 0.25
    return out


def _pairs(n: int) -> list[tuple[slice, slice, slice]]:
    """(first of a pair, second of a pair, output) slices along an axis of ``n`` texels: the
    even pairs, and for an odd ``n`` the last texel paired with itself."""
    even = n - n % 2
    pairs = [(slice(0, even, 2), slice(1, even, 2), slice(0, even // 2))]
    if n % 2:
        pairs.append((slice(n - 1, n), slice(n - 1, n), slice(even // 2, even // 2 + 1)))
    return pairs
