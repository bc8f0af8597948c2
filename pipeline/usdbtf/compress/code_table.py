"""8-bit file codes of scene-linear values by table: what :func:`usdbtf.manifest.encode_for_file`
computes through OpenColorIO, at about half its cost.

The error "on the encoded values" encodes every reconstruction the way the input's files
hold it: OpenColorIO's transform to the file's space, clipped to [0, 1], times 255, rounded.
That transform is a primaries matrix (none for sRGB files into a Rec.709 working space), then
the same curve on each channel, so after the matrix a code is a step function of each
channel's value with 255 steps: the code of v is the number of steps at or below v.
OpenColorIO's own transform places the steps (:func:`_steps`: a bisection over float32 bit
patterns, every probe encoded by OpenColorIO), and the lookup finds them by the value's bit
pattern: for v >= 0 the float32 bits increase with v, so ``bits >> shift`` numbers buckets of
consecutive floats, a table gives each bucket's code at its first float and the one step
(if any) inside it, and ``code = base[bucket] + (v >= step[bucket])``.  (Issue 42: the
held-out evaluation's encode was 9 of its 25 ms per block of 256 samples.)

Not bit for bit OpenColorIO's codes: OpenColorIO's float32 curve is not monotone within a few
float32 steps of a code's edge (0.0031883 -> 10, 10, 11, 11, 10, 11, 10, 11 over consecutive
floats), and its matrix rounds its own way.  The table places each edge where OpenColorIO
first reaches the code; every float32 in [0, 1.01] through the per-channel sRGB curve gives
233 codes one away in 1.07e9, and through the matrix of sRGB files into the working space 2-3
in 786,432 smooth values, none more than one away.  The error sums move in their sixth
significant digit; no file is written from these codes.

:meth:`CodeTable.build` checks the table against OpenColorIO on every step's two sides and on
values spread over [-0.1, 2], with the channels on different values (a transform that mixes
them beyond its matrix shows there), and returns None when a code is more than one away or
more than :data:`_TOLERANCE` of the spread values differ; the caller then encodes through
OpenColorIO.
"""
from __future__ import annotations

import functools

import numpy as np

from .. import color
from ..manifest import encode_for_file

__all__ = ["CodeTable", "code_table", "file_code_table", "file_codes"]

#: Bucket = float32 bits >> shift; tried from the coarsest until no bucket holds two steps.
_SHIFTS = (15, 14, 13, 12)
#: Values checked against OpenColorIO beside the steps' two sides (fixed: no randomness).
_CHECKS = 1 << 16
#: The share of the spread check values that may get a code one away from OpenColorIO's.
_TOLERANCE = 1e-3


@functools.lru_cache(maxsize=16)
def code_table(src: str, dst: str, config: str | None, bit_depth: str, matrix: tuple | None) -> "CodeTable | None":
    """:meth:`CodeTable.build` of the processor ``src`` -> ``dst`` (``matrix``: the files'
    decode matrix as nested tuples, or None), built once per process."""
    return CodeTable.build(color.processor(src, dst, config), bit_depth,
                           None if matrix is None else np.array(matrix, np.float32))


class CodeTable:
    """callable(scene-linear float32 (..., 3)) -> uint8 codes (..., 3), as
    ``encode_for_file(x, processor, "uint8")`` gives them.

    Attributes
    ----------
    shift : bucket = float32 bits >> shift.
    base : (3, n_buckets) uint8, the code at each bucket's first float, per channel.
    step : (3, n_buckets) float32, the value of the step inside each bucket (+inf: none).
    shared : True when the three channels' tables are equal (one lookup serves all).
    unmix : (3, 3) float32 applied to each colour before the lookup (the inverse of the
        decode's primaries matrix), or None.
    """

    def __init__(self, shift: int, base: np.ndarray, step: np.ndarray, unmix: np.ndarray | None = None):
        self.shift, self.base, self.step, self.unmix = shift, base, step, unmix
        self.shared = bool(np.array_equal(base[0], base[1]) and np.array_equal(base[0], base[2])
                           and np.array_equal(step[0], step[1]) and np.array_equal(step[0], step[2]))
        self._last = base.shape[1] - 1
        # Interleaved channels: one flat table, entry bucket * 3 + channel.
        self._base_flat = np.ascontiguousarray(base.T).reshape(-1)
        self._step_flat = np.ascontiguousarray(step.T).reshape(-1)

    @classmethod
    def build(cls, processor, bit_depth: str, matrix: np.ndarray | None = None) -> "CodeTable | None":
        """The table of ``processor`` (working space -> the file's space) for ``bit_depth``
        files, or None where no table gives OpenColorIO's codes to within the module's
        tolerance (not 8-bit, a transform that mixes channels beyond ``matrix`` or does not
        rise with the value, steps too close for the buckets).

        ``matrix`` : (3, 3) the files' decode matrix (working = matrix @ curve-decoded), or
        None when the decode is per channel.
        """
        if bit_depth != "uint8":
            return None

        def codes(x: np.ndarray) -> np.ndarray:
            return encode_for_file(np.ascontiguousarray(x, np.float32).reshape(-1, 3), processor, bit_depth)

        unmix = None
        curve_codes = codes
        if matrix is not None:
            unmix = np.linalg.inv(np.asarray(matrix, np.float64)).astype(np.float32)
            matrix = np.asarray(matrix, np.float32)
            # The steps of the curves alone: OpenColorIO given colours the matrix made.
            curve_codes = lambda v: codes(color.mix_rgb(np.ascontiguousarray(v, np.float32).reshape(-1, 3), matrix))
        steps = _steps(curve_codes)
        if steps is None:
            return None
        steps = _shared_curve(steps)
        for shift in _SHIFTS:
            table = cls._tabulated(steps, shift, unmix)
            if table is not None and table._agrees(codes, steps, matrix):
                return table
        return None

    @classmethod
    def _tabulated(cls, steps: np.ndarray, shift: int, unmix: np.ndarray | None = None) -> "CodeTable | None":
        """The table for ``steps`` (3, 255) float32 (the smallest value of each code 1..255)
        with buckets of ``shift`` bits, or None when a bucket holds two steps."""
        bits = steps.view(np.int32) >> shift                                 # (3, 255) bucket of each step
        if any(len(np.unique(b)) != len(b) for b in bits):
            return None
        n_buckets = int(bits.max()) + 2                                       # the last bucket: code 255 throughout
        base = np.empty((3, n_buckets), np.uint8)
        step = np.full((3, n_buckets), np.inf, np.float32)
        first = np.arange(n_buckets, dtype=np.int64) << shift                  # bits of each bucket's first float
        for c in range(3):
            base[c] = np.searchsorted(steps[c].view(np.int32).astype(np.int64), first, side="right")
            inside = steps[c].view(np.int32).astype(np.int64) > (bits[c].astype(np.int64) << shift)
            step[c, bits[c][inside]] = steps[c][inside]
            # A step on a bucket's first float is counted by base already (searchsorted, right).
        return cls(shift, base, step, unmix)

    def __call__(self, linear: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(linear, np.float32)
        if x.size % 3:
            raise ValueError(f"expected interleaved RGB, got shape {x.shape}")
        if self.unmix is not None:
            x = color.mix_rgb(x, self.unmix)
        bucket = x.view(np.int32) >> self.shift          # negative values: negative buckets, clipped to 0
        np.clip(bucket, 0, self._last, out=bucket)
        if self.shared:
            base, step = self.base[0], self.step[0]
        else:
            by_channel = bucket.reshape(-1, 3)           # interleaved: channel = index % 3
            by_channel *= 3
            by_channel += np.arange(3, dtype=np.int32)
            base, step = self._base_flat, self._step_flat
        out = base.take(bucket)
        out += x >= step.take(bucket)
        return out

    def _agrees(self, codes, steps: np.ndarray, matrix: np.ndarray | None) -> bool:
        """True when the table gives OpenColorIO's codes (``codes``: working space -> codes)
        to within one on both sides of every step (curve values, taken through ``matrix``
        into the working space) and on :data:`_CHECKS` values per channel spread over
        [-0.1, 2], with the channels on different values, and exactly on all but
        :data:`_TOLERANCE` of those."""
        sides = np.concatenate([steps.T, np.nextafter(steps, np.float32(-np.inf)).T])     # (510, 3) curve values
        if matrix is not None:
            sides = color.mix_rgb(sides, matrix)
        ramp = np.concatenate([np.linspace(-0.1, 0.0, 64), np.geomspace(1e-6, 2.0, _CHECKS - 64)]).astype(np.float32)
        spread = np.concatenate([np.stack([ramp, ramp[::-1], np.roll(ramp, _CHECKS // 3)], axis=-1),
                                 [[0, 0, 0], [1, 1, 1], [1e4, 1e4, 1e4]]]).astype(np.float32)
        off_sides = self(sides).astype(np.int16) - codes(sides).reshape(sides.shape)
        off_spread = self(spread).astype(np.int16) - codes(spread).reshape(spread.shape)
        return (int(np.abs(off_sides).max()) <= 1 and int(np.abs(off_spread).max()) <= 1
                and np.count_nonzero(off_spread) <= _TOLERANCE * off_spread.size)


def _shared_curve(steps: np.ndarray, ulps: int = 32) -> np.ndarray:
    """``steps`` (3, 255) with the channels' median on every row when they lie within ``ulps``
    float32 steps of each other (one curve for all three, found through a matrix that rounds
    each channel its own way: one lookup serves them, 1.8x faster), else as they are."""
    bits = steps.view(np.int32)
    if int((bits.max(axis=0) - bits.min(axis=0)).max()) > ulps:
        return steps
    return np.repeat(np.median(steps, axis=0, keepdims=True).astype(np.float32), 3, axis=0)


def _steps(codes) -> np.ndarray | None:
    """(3, 255) float32: per channel, a non-negative float32 where the code first reaches j, for
    j = 1..255 (bisection over bit patterns, every probe encoded by ``codes``), or None when
    1.0e4 does not reach code 255 or the codes do not rise with the value.

    Each channel is probed on grey colours (all three channels on its probe value): a matrix
    keeps grey grey, so what ``codes`` rounds through one changes no channel's code."""
    top_bits = int(np.float32(1.0e4).view(np.int32))
    if not np.all(codes(np.full((1, 3), 1.0e4, np.float32)) == 255) or np.any(codes(np.zeros((1, 3), np.float32))):
        return None
    want = np.arange(1, 256, dtype=np.int64)                                 # (255,) code sought
    steps = np.empty((3, 255), np.float32)
    for c in range(3):
        lo = np.zeros(255, np.int64)                                         # bits with code < want (0.0: code 0)
        hi = np.full(255, top_bits, np.int64)                                # bits with code >= want
        while np.any(hi - lo > 1):
            mid = (lo + hi) // 2
            grey = np.repeat(mid.astype(np.int32).view(np.float32)[:, None], 3, axis=1)
            up = codes(grey).reshape(255, 3)[:, c] >= want
            hi = np.where(up, mid, hi)
            lo = np.where(up, lo, mid)
        steps[c] = hi.astype(np.int32).view(np.float32)
    if np.any(np.diff(steps.view(np.int32), axis=1) <= 0):
        return None
    return steps


def file_code_table(btf) -> "CodeTable | None":
    """The :class:`CodeTable` of ``btf``'s files (8-bit, decoded exactly by a table and
    matrix: :attr:`usdbtf.model.BTF.integer_decoder`), or None: encode through OpenColorIO."""
    dec = btf.integer_decoder if btf.bit_depth == "uint8" else None
    if dec is None or not dec.exact:
        return None
    matrix = None if dec.matrix is None else tuple(map(tuple, np.asarray(dec.matrix, np.float64).tolist()))
    return code_table(btf.working_space, btf.color_space, btf.ocio_config, btf.bit_depth, matrix)


def file_codes(btf):
    """callable(working-space float32 (..., 3), or rows of interleaved RGB) -> ``btf``'s file
    values as its files hold them, in the files' own dtype (codes for integer depths), in the
    same shape: by the files' :class:`CodeTable` where one serves, else through OpenColorIO
    (:func:`usdbtf.manifest.encode_for_file`)."""
    table = file_code_table(btf)
    if table is not None:
        return table
    to_file = color.processor(btf.working_space, btf.color_space, btf.ocio_config)
    return lambda lin: encode_for_file(lin.reshape(-1, 3), to_file, btf.bit_depth).reshape(lin.shape)
