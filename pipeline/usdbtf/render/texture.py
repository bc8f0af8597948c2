"""Coefficient textures for the renderer: texel-major, mip-mapped, filtered.

Equation 2 needs, per shaded point, the 3 x k coefficients at its texture position.  They
are held texel-major, ``(H, W, 3, k)`` float32 in the stored (decorrelated) channels, the
colour matrix applied to the shaded colour instead (linear, so exact), so one bilinear tap
is one contiguous row and each channel's dot with the blended basis row runs over contiguous
memory (measured 2.3x faster than a (k, 3) layout); memory is ``H * W * k * 12`` bytes plus a
third for mip levels (built on first use, 2 x 2 box filter).

Only what a frame samples is decoded (issue 39): each mip level is cut into tiles of
:attr:`CoefficientTexture.tile` texels a side, and a frame first asks for the tiles its taps
touch (:meth:`CoefficientTexture.needed`, :meth:`CoefficientTexture.hold`), which are then made
in one pass over the stored codes (a lazily read asset, ``read_btf(..., lazy=True)``: each page
decoded once).  Level 0's tiles hold the stored codes (``3 k`` bytes a texel for 8-bit codes),
de-quantised per tap; a level n >= 1's tiles are cut from each coefficient plane de-quantised
and box-filtered n times (the same float32 operations per texel as boxing the whole texel-major
level 0, so the same values bit for bit).  A frame holds the tiles of its own taps, not a
level's ``H_n * W_n * k * 12`` bytes.  A whole level (:meth:`CoefficientTexture.level`) is still
built when asked for, and taps then read it.

Texture coordinates follow USD: ``st`` in [0, 1], s to the right, t *up*; texel (row i,
column j) of the image (row 0 at the top) is centred at ``s = (j + 0.5) / W``,
``t = 1 - (i + 0.5) / H``.
"""
from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np

from ..compress.format import CompressedBTF
from ..compress.parallel import in_threads
from ..resources import release_free_heap

__all__ = ["CoefficientTexture", "TILE", "merge_needed"]

#: Texels a side of a level's tiles (:meth:`CoefficientTexture.hold`): a 64 x 64 tile of k = 48
#: is 0.6 MB of codes at level 0, 2.4 MB of floats above; small enough that a frame's tiles
#: follow the region it samples, large enough that a frame's tiles number hundreds, not tens of
#: thousands (one cut per tile, coefficient and channel while they are made).
TILE = 64


class _Tiles(NamedTuple):
    """The held tiles of one level: ``slot`` (tiles of the level,) int64, each tile's index in
    ``pool`` or -1 (not held); ``pool`` (held, T, T, 3, k): stored codes (level 0) or float32
    (levels >= 1); a tile at the level's right or bottom edge is padded with repeated edge texels
    that no tap reads.  Replaced whole, never changed, so shading threads read one consistently."""

    slot: np.ndarray
    pool: np.ndarray


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
        #: Levels in the order they were first built, and how: whole ("level 0", "planes", "box",
        #: "gathered"), or their first tiles ("codes": level 0's stored codes, "planes": cut from
        #: de-quantised, boxed coefficient planes).
        self.built: list[tuple[int, str]] = []
        #: Texels a side of a tile (set before the first frame).
        self.tile = TILE
        #: Tiles made so far per level ({level: count}, over every pass): what a test counts.
        self.tiles_made: dict[int, int] = {}
        self._held: dict[int, _Tiles] = {}        # the tiles held per level
        self._dequant = None                      # level 0's (scale, bias) (3, k) float32, with its tiles
        self._lock = threading.RLock()            # shading threads may ask for new tiles at once

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
                level = _plane_level(self._cbtf.coefficients.__getitem__, self._shape, self.k, n)
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

    def _tap_texels(self, n: int, idx: np.ndarray) -> np.ndarray:
        """(p, 3, k) texels at flat indices ``idx`` of level ``n``."""
        if n == 0 and self.map is not None:
            return np.take(self._texels, self.map.ravel()[idx], axis=0)
        if not self._tiled(n):
            return np.take(self.level(n).reshape(-1, 3, self.k), idx, axis=0)
        held, T = self._held[n], self.tile                 # made by shade's _have, if not held before
        y, x = np.divmod(idx, self.level_shape(n)[1])
        slot = held.slot[self._tile_of(n, y, x)]
        out = np.take(held.pool.reshape(-1, 3, self.k), (slot * T + y % T) * T + x % T, axis=0)
        if n == 0:                                     # codes: exactly _texel_major's operations
            scale, bias = self._dequant
            out = out.astype(np.float32)
            out *= scale
            out += bias
        return out

    def _have(self, n: int, idx: np.ndarray) -> None:
        """Make the tiles of level ``n`` holding texels ``idx`` (any shape) that are not held, in one
        pass, and keep them: for a caller that did not :meth:`hold` what it shades."""
        if self._tiled(n):
            ids = np.unique(self._tile_ids(n, idx))
            held = self._held.get(n)
            if held is None or (held.slot[ids] < 0).any():
                self.hold({n: ids}, keep=True)

    def _tiled(self, n: int) -> bool:
        """Level ``n``'s taps read tiles: no texel map, and neither it nor a finer level held whole."""
        return self.map is None and not any(m <= n for m in self.levels)

    def _tile_ids(self, n: int, idx: np.ndarray) -> np.ndarray:
        """Tile ids (``row * tiles across + column``) of flat texel indices ``idx`` of level ``n``."""
        return self._tile_of(n, *np.divmod(idx, self.level_shape(n)[1]))

    def _tile_of(self, n: int, y: np.ndarray, x: np.ndarray) -> np.ndarray:
        """Tile ids of level ``n``'s texels at rows ``y``, columns ``x`` (a tap's, already split)."""
        return (y // self.tile) * -(-self.level_shape(n)[1] // self.tile) + x // self.tile

    def needed(self, st: np.ndarray, lod: np.ndarray | None = None) -> dict[int, np.ndarray]:
        """{level: sorted unique tile ids} that :meth:`shade` of points ``st`` (m, 2) at ``lod``
        (m,) reads, for :meth:`hold` (none for a texel-mapped texture: it has no tiles)."""
        if self.map is not None:
            return {}
        found: dict[int, list] = {}
        for level, pick, _ in self._picks(lod, len(st)):
            found.setdefault(level, []).append(np.unique(self._tile_ids(level, self._taps(level, st[pick])[0])))
        return {n: np.unique(np.concatenate(ids)) for n, ids in sorted(found.items())}

    def hold(self, needed: dict[int, np.ndarray], keep: bool = False) -> None:
        """Hold the tiles ``needed`` ({level: tile ids}, :meth:`needed`): those not held are made
        in one pass over the stored codes (a lazily read asset's pages each decoded once, then
        released); tiles of other levels, or not listed, are dropped unless ``keep``.  Levels
        read whole (:meth:`_tiled`) are left out."""
        with self._lock:
            plan = {}
            for n in sorted(needed):
                if not self._tiled(n):
                    continue
                ids = np.unique(np.asarray(needed[n], np.int64))
                old = self._held.get(n)
                held = np.flatnonzero(old.slot >= 0) if old is not None else np.zeros(0, np.int64)
                new = np.setdiff1d(ids, held)
                kept = held if keep else np.intersect1d(ids, held)
                if len(new) or len(kept) < len(held):
                    plan[n] = (kept, new)
            if not keep:
                for n in [m for m in self._held if m not in needed]:
                    del self._held[n]
            for n, (kept, new) in plan.items():             # the kept tiles moved to the front
                old = self._held.pop(n, None)
                h, w = self.level_shape(n)
                slot = np.full(-(-h // self.tile) * -(-w // self.tile), -1, np.int64)
                slot[kept] = np.arange(len(kept))
                slot[new] = np.arange(len(kept), len(kept) + len(new))
                dtype = np.float32 if n else (old.pool.dtype if old is not None else None)
                pool = None if dtype is None else np.empty((len(kept) + len(new), self.tile, self.tile, 3, self.k),
                                                           dtype)
                if len(kept):
                    pool[:len(kept)] = old.pool[old.slot[kept]]
                plan[n] = (_Tiles(slot, pool), new, len(kept))
            made = {n: p for n, p in plan.items() if len(p[1])}
            if made:
                plan.update(self._make(made))
            for n, (tiles, new, _) in sorted(plan.items()):
                if len(new):
                    if n not in self.tiles_made:
                        self.built.append((n, "planes" if n else "codes"))
                    self.tiles_made[n] = self.tiles_made.get(n, 0) + len(new)
                self._held[n] = tiles

    def _make(self, plan: dict) -> dict:
        """Fill the new tiles of ``plan`` ({level: (_Tiles, new tile ids, their first slot)}) in
        one pass over the first k coefficients: level 0's cut from the codes, a level n's from
        each coefficient plane de-quantised and boxed n times.  Returns ``plan`` (level 0's pool
        allocated here, in the codes' widest storage type)."""
        T, top = self.tile, max(plan)
        scale, bias = np.empty((3, self.k), np.float32), np.empty((3, self.k), np.float32)
        coefficients = self._cbtf.coefficients
        for i in range(self.k):
            st = coefficients[i]                      # a lazy asset's: each page read once, in order
            scale[:, i], bias[:, i] = st.scale.astype(np.float32), st.bias.astype(np.float32)
            if 0 in plan:
                tiles, new, at = plan[0]
                dtype = st.pixels.dtype if tiles.pool is None else np.result_type(tiles.pool.dtype, st.pixels.dtype)
                if tiles.pool is None:
                    tiles = tiles._replace(pool=np.empty((at + len(new), T, T, 3, self.k), dtype))
                elif dtype != tiles.pool.dtype:          # a uint8 texture beside uint16 ones
                    tiles = tiles._replace(pool=tiles.pool.astype(dtype))
                plan[0] = (tiles, new, at)
                tiles.pool[at:, :, :, :, i] = _cut(st.pixels, new, T)
            if top >= 1:
                for c, plane in enumerate(_planes(st)):
                    for n in range(1, top + 1):
                        plane = _box(plane)
                        if n in plan:
                            tiles, new, at = plan[n]
                            tiles.pool[at:, :, :, c, i] = _cut(plane, new, T)
        if 0 in plan:
            self._dequant = (scale, bias)
        self._release()
        # The pass's pages, packs and planes go back to the system, so the next material's pass
        # (or the shading) does not peak on top of them (issue 42's :func:`release_free_heap`).
        release_free_heap()
        return plan

    def _picks(self, lod: np.ndarray | None, m: int):
        """The trilinear filter's levels for ``m`` points at ``lod`` (m,) (None or <= 0: level 0,
        bilinear): (level, the points that read it, their weight (float32)) per level read."""
        if lod is None:
            lod = np.zeros(m)
        lod = np.clip(lod, 0.0, self.max_level)
        base = np.floor(lod).astype(np.int64)
        frac = (lod - base).astype(np.float32)
        for n in np.unique(base):
            sel = np.flatnonzero(base == n)
            for level, scale in ((int(n), 1.0 - frac[sel]), (int(n) + 1, frac[sel])):
                use = scale > 0
                if use.any() and level <= self.max_level:
                    yield level, sel[use], scale[use]

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
        r = rows.astype(np.float32)
        for level, pick, scale in self._picks(lod, len(rows)):
            idx, wt = self._taps(level, st[pick])
            self._have(level, idx)
            rp = r[pick]
            for tap in range(4):
                coeffs = self._tap_texels(level, idx[tap])                       # (p, 3, k)
                val = np.einsum("pk,pck->pc", rp, coeffs)
                out[pick] += (wt[tap] * scale)[:, None].astype(np.float32) * val
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
        for c, plane in enumerate(_planes(coefficient(i))):   # a lazily read asset: read here, dropped after
            for _ in range(n):
                plane = _box(plane)
            out[:, :, c, i] = plane
    return out


def _planes(st):
    """The three (H, W) float32 planes of a Stored coefficient, de-quantised as
    :func:`_texel_major` does (code x float32 scale + float32 bias, in float32), one at a time."""
    scale, bias = st.scale.astype(np.float32), st.bias.astype(np.float32)
    for c in range(3):
        plane = np.multiply(st.pixels[:, :, c], scale[c:c + 1], dtype=np.float32)
        plane += bias[c:c + 1]
        yield plane


def _cut(image: np.ndarray, ids: np.ndarray, T: int) -> np.ndarray:
    """(len(ids), T, T, ...) tiles ``ids`` (``row * tiles across + column``) of ``image`` (h, w, ...),
    the edge row and column repeated past the image's edge."""
    h, w = image.shape[:2]
    ty, tx = np.divmod(np.asarray(ids, np.int64), -(-w // T))
    rows = np.minimum(ty[:, None] * T + np.arange(T), h - 1)
    cols = np.minimum(tx[:, None] * T + np.arange(T), w - 1)
    return image[rows[:, :, None], cols[:, None, :]]


def merge_needed(*needs: dict) -> dict[int, np.ndarray]:
    """{level: sorted unique tile ids} of several :meth:`CoefficientTexture.needed` answers."""
    out: dict[int, list] = {}
    for need in needs:
        for n, ids in need.items():
            out.setdefault(n, []).append(np.asarray(ids, np.int64))
    return {n: np.unique(np.concatenate(ids)) for n, ids in sorted(out.items())}


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
